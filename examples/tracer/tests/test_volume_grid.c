/*
 * test_volume_grid.c - heterogeneous media below the integrator: .vol grids (their lookup and
 * every refusal of a bad file, which must name the file and what is wrong), delta and ratio
 * tracking against analytic transmittance, and the loader's refusals of bad
 * <medium type="heterogeneous"> input. The furnace with a grid medium is in test_media.c.
 */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include <cmocka.h>

#include "nf_test_main.h"

#include "medium.h"
#include "scene.h"
#include "volume_grid.h"

#include "scene_errors.h"
#include "vol_file.h"

static unsigned char bytes[48 + 4 * 4096];

/* Parses `size` bytes of the buffer, which must fail with every fragment in the message. */
static void expect_vol_error(size_t size, ...)
{
    volume_grid g;
    tr_error err;
    if (volume_grid_parse(bytes, size, "bad.vol", "density", 0.0f, 1e30f, &g, &err)) {
        volume_grid_free(&g);
        fail_msg("a bad grid was accepted");
    }
    assert_null(g.data);
    assert_non_null(strstr(err.msg, "bad.vol: "));
    va_list ap;
    va_start(ap, size);
    const char *lacks = missing_fragment(err.msg, ap);
    va_end(ap);
    if (lacks)
        fail_msg("error message\n  %s\nlacks '%s'", err.msg, lacks);
}

static void test_bad_files(void **state)
{
    (void)state;
    float v[8] = {0, 1, 2, 3, 4, 5, 6, 7};
    size_t ok = vol_bytes(bytes, 2, 2, 2, 1, v);
    expect_vol_error(20, "shorter than the 48-byte header", NULL);
    expect_vol_error(ok - 4, "takes 80 bytes; the file has 76 (truncated)", NULL);
    bytes[ok] = 0;
    expect_vol_error(ok + 1, "the file has 81 (trailing bytes)", NULL);
    bytes[0] = 'X';
    expect_vol_error(ok, "does not start with 'VOL'", NULL);
    vol_bytes(bytes, 2, 2, 2, 1, v);
    bytes[3] = 2;
    expect_vol_error(ok, "version 2 is not supported", NULL);
    vol_bytes(bytes, 2, 2, 2, 1, v);
    put_u32(bytes + 4, 2);
    expect_vol_error(ok, "encoding 2 is not supported", NULL);
    vol_bytes(bytes, 2, 2, 2, 1, v);
    put_u32(bytes + 12, 0);
    expect_vol_error(ok, "size 2 x 0 x 2 is not positive", NULL);
    put_u32(bytes + 12, 0xffffffffu);
    expect_vol_error(ok, "size 2 x -1 x 2 is not positive", NULL);
    vol_bytes(bytes, 2, 2, 2, 1, v);
    put_u32(bytes + 20, 6);
    expect_vol_error(ok, "6 channels is not supported (1 or 3)", NULL);
    vol_bytes(bytes, 2, 2, 2, 1, v);
    put_u32(bytes + 8, 1u << 15);
    put_u32(bytes + 12, 1u << 15);
    expect_vol_error(ok, "more than the", NULL);
    /* 2^25 x 2^25 x 2^24 values, 2^74, which a product of all four sizes wraps to 0: the
     * header alone then looked like a whole file (found by fuzz_volume_grid) */
    vol_bytes(bytes, 2, 2, 2, 1, v);
    put_u32(bytes + 8, 1u << 25);
    put_u32(bytes + 12, 1u << 25);
    put_u32(bytes + 16, 1u << 24);
    expect_vol_error(48, "more than the", NULL);
    v[1] = NAN;
    vol_bytes(bytes, 2, 2, 2, 1, v);
    expect_vol_error(ok, "the density of cell (1, 0, 0), channel 0, is nan", NULL);
    v[1] = 1.0f;
    v[2] = -0.5f;
    vol_bytes(bytes, 2, 2, 2, 1, v);
    expect_vol_error(ok, "the density of cell (0, 1, 0), channel 0, is -0.5",
                     "must be finite and lie in [0, 1e+30]", NULL);
    v[2] = 2.0f;
    v[6] = INFINITY;
    vol_bytes(bytes, 2, 2, 2, 1, v);
    expect_vol_error(ok, "cell (0, 1, 1)", "is inf", NULL);
    /* And from a file: a missing one is named. */
    volume_grid g;
    tr_error err;
    assert_false(volume_grid_read(TRACER_TEST_TMP_DIR "/no-such.vol", "density", 0.0f, 1.0f,
                                  &g, &err));
    assert_non_null(strstr(err.msg, "no-such.vol: cannot open the volume grid"));
}

/* drjit's texture convention: cell centres at (i + 1/2) / n, trilinear between, clamped. */
static void test_lookup(void **state)
{
    (void)state;
    float v[8] = {0, 1, 2, 3, 4, 5, 6, 7}; /* value = x + 2 y + 4 z */
    size_t size = vol_bytes(bytes, 2, 2, 2, 1, v);
    volume_grid g;
    tr_error err;
    assert_true(volume_grid_parse(bytes, size, "g.vol", "density", 0.0f, 10.0f, &g, &err));
    assert_float_equal(g.max, 7.0f, 0.0f);
    for (int k = 0; k < 8; ++k) {
        vec3 u = v3(0.25f + 0.5f * (float)(k & 1), 0.25f + 0.5f * (float)(k >> 1 & 1),
                    0.25f + 0.5f * (float)(k >> 2));
        assert_float_equal(volume_grid_eval1(&g, u), v[k], 1e-6f);
    }
    assert_float_equal(volume_grid_eval1(&g, v3(0.5f, 0.5f, 0.5f)), 3.5f, 1e-6f);
    /* between the centres: linear in each axis (0.375 is a quarter of the way) */
    assert_float_equal(volume_grid_eval1(&g, v3(0.375f, 0.25f, 0.25f)), 0.25f, 1e-6f);
    assert_float_equal(volume_grid_eval1(&g, v3(0.25f, 0.625f, 0.25f)), 1.5f, 1e-6f);
    /* clamped outside the edge cells' centres and outside the cube */
    assert_float_equal(volume_grid_eval1(&g, v3(0.1f, 0.1f, 0.1f)), 0.0f, 0.0f);
    assert_float_equal(volume_grid_eval1(&g, v3(-3.0f, 0.9f, 7.0f)), 6.0f, 0.0f);
    assert_float_equal(volume_grid_eval1(&g, v3(NAN, 0.9f, 0.9f)), 6.0f, 0.0f);
    g.nearest = 1;
    assert_float_equal(volume_grid_eval1(&g, v3(0.3f, 0.8f, 0.1f)), 2.0f, 0.0f);
    assert_float_equal(volume_grid_eval1(&g, v3(0.5f, 0.49f, 1.0f)), 5.0f, 0.0f);
    volume_grid_free(&g);
    /* three channels; a one-channel grid gives grey */
    float c[6] = {0.1f, 0.2f, 0.3f, 0.5f, 0.6f, 0.7f};
    size = vol_bytes(bytes, 2, 1, 1, 3, c);
    assert_true(volume_grid_parse(bytes, size, "c.vol", "albedo", 0.0f, 1.0f, &g, &err));
    rgb a = volume_grid_eval_rgb(&g, v3(0.5f, 0.5f, 0.5f));
    assert_float_equal(a.r, 0.3f, 1e-6f);
    assert_float_equal(a.g, 0.4f, 1e-6f);
    assert_float_equal(a.b, 0.5f, 1e-6f);
    volume_grid_free(&g);
}

/* A grid of two cells along x, densities A and B, scaled by S and stretched to [0, 2] in the
 * world: the extinction is S A for x < 0.5, linear up to S B at x = 1.5, S B beyond. */
#define A 0.2f
#define B 0.6f
#define S 1.5f

static void ramp_medium(medium *m, placed_grid *pg)
{
    float v[2] = {A, B};
    size_t size = vol_bytes(bytes, 2, 1, 1, 1, v);
    tr_error err;
    memset(pg, 0, sizeof *pg);
    assert_true(volume_grid_parse(bytes, size, "ramp.vol", "density", 0.0f, 1e30f, &pg->grid,
                                  &err));
    pg->to_local[0][0] = 0.5f; /* u = x / 2, v = y, w = z */
    pg->to_local[1][1] = 1.0f;
    pg->to_local[2][2] = 1.0f;
    memset(m, 0, sizeof *m);
    m->density = pg;
    m->scale = S;
    m->majorant = S * B;
    m->albedo = rgb_make(0.9f, 0.5f, 0.25f);
}

/* The optical depth from world x = 0 to x (0 <= x <= 2) of ramp_medium. */
static double ramp_depth(double x)
{
    double a = S * A, b = S * B, slope = (b - a) / 1.0;
    double d = a * fmin(x, 0.5);
    if (x > 0.5) {
        double e = fmin(x, 1.5) - 0.5;
        d += a * e + 0.5 * slope * e * e;
    }
    if (x > 1.5)
        d += b * (x - 1.5);
    return d;
}

/* Unbiased tracking: ratio tracking's mean and delta tracking's passing fraction equal
 * exp(-depth) across the grid, and delta tracking scatters before the middle with probability
 * 1 - exp(-depth(1)) (a lookup of the nearest cell would give 0.26 there instead of 0.31);
 * a scattering carries the albedo. Tolerance: 4 standard errors of the N estimates (fails
 * by chance with probability 6e-5; the seed is fixed). */
static void test_tracking(void **state)
{
    (void)state;
    medium m;
    placed_grid pg;
    ramp_medium(&m, &pg);
    const int n = 200000;
    rng r = rng_seed(3, RNG_TEST, 0, 0);
    const vec3 o = v3(-1.0f, 0.5f, 0.5f), d = v3(1.0f, 0.0f, 0.0f);
    double s = 0.0, s2 = 0.0, pass = 0.0, before_middle = 0.0;
    for (int i = 0; i < n; ++i) {
        double t = medium_segment_transmittance(&m, o, d, 4.0f, &r).r;
        s += t;
        s2 += t * t;
        float x;
        rgb w;
        if (medium_sample_flight(&m, rgb_gray(1.0f), o, d, 4.0f, &r, &x, &w)) {
            before_middle += x < 2.0f;
            assert_true(x >= 1.0f && x <= 3.0f); /* inside the grid: from 1 to 3 */
            assert_float_equal(w.g, 0.5f, 0.0f);
        } else {
            pass += 1.0;
            assert_float_equal(w.r, 1.0f, 0.0f);
        }
    }
    const double tr = exp(-ramp_depth(2.0)), mid = 1.0 - exp(-ramp_depth(1.0));
    double mean = s / n, se = sqrt((s2 / n - mean * mean) / n);
    printf("  ratio tracking %.5f +- %.5f, expected %.5f\n", mean, se, tr);
    assert_true(fabs(mean - tr) < 4.0 * se);
    double p = pass / n, sp = sqrt(tr * (1.0 - tr) / n);
    printf("  delta tracking passes %.5f, expected %.5f +- %.5f\n", p, tr, sp);
    assert_true(fabs(p - tr) < 4.0 * sp);
    double q = before_middle / n, sq = sqrt(mid * (1.0 - mid) / n);
    printf("  scatters before the middle %.5f, expected %.5f +- %.5f\n", q, mid, sq);
    assert_true(fabs(q - mid) < 4.0 * sq);
    /* Outside the grid's cube nothing happens and nothing is drawn. */
    rng before = r;
    rgb t = medium_segment_transmittance(&m, v3(-1.0f, 2.0f, 0.5f), d, 4.0f, &r);
    assert_float_equal(t.r, 1.0f, 0.0f);
    assert_memory_equal(&before, &r, sizeof r);
    volume_grid_free(&pg.grid);
}

/* A scene with one heterogeneous medium (body %s) in a null cube. */
static const char *grid_xml(const char *body)
{
    static char xml[4096];
    snprintf(xml, sizeof xml,
        "<scene version=\"3.0.0\">\n"
        "<sensor type=\"perspective\"><float name=\"fov\" value=\"40\"/></sensor>\n"
        "<medium type=\"heterogeneous\" id=\"m\">\n%s\n</medium>\n"
        "<shape type=\"cube\"><bsdf type=\"null\"/><ref name=\"interior\" id=\"m\"/></shape>\n"
        "</scene>\n", body);
    return xml;
}

#define GRID(name, file, extra)                                                                \
    "<volume type=\"gridvolume\" name=\"" name "\"><string name=\"filename\" value=\"" file   \
    "\"/>" extra "</volume>"

static void test_bad_media(void **state)
{
    (void)state;
    float grey[8] = {0, 1, 2, 3, 4, 5, 6, 7}, rgb3[24];
    for (int i = 0; i < 24; ++i)
        rgb3[i] = 0.5f;
    write_vol("grey.vol", 2, 2, 2, 1, grey);
    write_vol("colour.vol", 2, 2, 2, 3, rgb3);
    grey[5] = -1.0f;
    write_vol("negative.vol", 2, 2, 2, 1, grey);
    grey[5] = 0.5f;
    write_vol("bright.vol", 2, 2, 2, 1, grey); /* 2, 3, ... as albedos */

    scene s;
    tr_error err;
    if (!scene_load_string(grid_xml(GRID("sigma_t", "grey.vol", "") GRID("albedo", "colour.vol", "")
                                    "<float name=\"scale\" value=\"2\"/>"),
                           TRACER_TEST_TMP_DIR, &s, &err))
        fail_msg("%s", err.msg);
    assert_int_equal(s.nmedia, 1);
    assert_float_equal(s.media[0].majorant, 14.0f, 0.0f);
    assert_non_null(s.media[0].albedo_grid);
    scene_free(&s);

    expect_error(grid_xml(""), "<string>:3:", "needs sigma_t as <volume", NULL);
    expect_error(grid_xml("<float name=\"sigma_t\" value=\"1\"/>"), "<string>:4:",
                 "must be a <volume type=\"gridvolume\">", "homogeneous", NULL);
    expect_error(grid_xml(GRID("sigma_t", "colour.vol", "")), "<string>:4:",
                 "3 channels: only a grey extinction", NULL);
    expect_error(grid_xml(GRID("sigma_t", "negative.vol", "")), "<string>:4:", "negative.vol: ",
                 "the density of cell (1, 0, 1), channel 0, is -1", NULL);
    expect_error(grid_xml(GRID("sigma_t", "grey.vol", "") GRID("albedo", "bright.vol", "")),
                 "bright.vol: ", "the albedo of cell (0, 1, 0), channel 0, is 2", "[0, 1]",
                 NULL);
    expect_error(grid_xml(GRID("sigma_t", "missing.vol", "")), "missing.vol: cannot open",
                 NULL);
    expect_error(grid_xml("<volume type=\"gridvolume\" name=\"sigma_t\"/>"),
                 "missing parameter 'filename'", NULL);
    expect_error(grid_xml("<volume type=\"constvolume\" name=\"sigma_t\"/>"),
                 "unsupported volume type 'constvolume' (gridvolume)", NULL);
    expect_error(grid_xml(GRID("sigma_t", "grey.vol",
                               "<string name=\"filter_type\" value=\"cubic\"/>")),
                 "filter_type 'cubic' is not supported", NULL);
    expect_error(grid_xml(GRID("sigma_t", "grey.vol",
                               "<string name=\"wrap_mode\" value=\"repeat\"/>")),
                 "wrap_mode 'repeat' is not supported (clamp)", NULL);
    expect_error(grid_xml(GRID("sigma_t", "grey.vol",
                               "<boolean name=\"use_grid_bbox\" value=\"true\"/>")),
                 "use_grid_bbox = true is not supported", NULL);
    expect_error(grid_xml(GRID("sigma_t", "grey.vol",
                               "<transform name=\"to_world\"><scale x=\"0\"/></transform>")),
                 "to_world is not invertible", NULL);
    expect_error(grid_xml(GRID("sigma_t", "grey.vol", "<float name=\"max_value\" value=\"1\"/>")),
                 "unsupported parameter 'max_value'", NULL);
    expect_error(grid_xml(GRID("sigma_t", "grey.vol", "") "<float name=\"scale\" value=\"-1\"/>"),
                 "scale = -1", NULL);
    expect_error(grid_xml(GRID("sigma_t", "grey.vol", "") "<float name=\"albedo\" value=\"2\"/>"),
                 "albedo = 2", NULL);
    expect_error(grid_xml(GRID("sigma_t", "grey.vol", "") "<float name=\"scale\" value=\"1e30\"/>"),
                 "scale x the density's maximum = 7e+30", NULL);
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_bad_files),
    cmocka_unit_test(test_lookup),
    cmocka_unit_test(test_tracking),
    cmocka_unit_test(test_bad_media),
)
