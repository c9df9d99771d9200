/*
 * test_interiors.c - what Bitterli's interiors need of the loader: files of scene version
 * < 2.0.0 upgraded as Mitsuba 3 upgrades them, the mask BSDF (an alpha test, also from a
 * PNG's alpha channel), the thin and the rough dielectric, the bumpmap, the disk shape, meshes with no
 * usable triangle skipped with a warning, and the two shipped interiors loading as they
 * were distributed.
 */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include <cmocka.h>
#include <stb_image_write.h>

#include "nf_test_main.h"

#include "mesh.h"
#include "scene.h"
#include "scene_errors.h"

#define OLD_SENSOR                                                                               \
    "<sensor type=\"perspective\"><float name=\"fov\" value=\"40\"/>"                            \
    "<transform name=\"toWorld\"><lookAt origin=\"0, 0, 5\" target=\"0, 0, 0\" up=\"0, 1, 0\"/>" \
    "</transform><film type=\"hdrfilm\"><integer name=\"width\" value=\"8\"/>"                   \
    "<integer name=\"height\" value=\"8\"/><boolean name=\"banner\" value=\"false\"/></film>"   \
    "</sensor>\n"
#define SENSOR                                                                                   \
    "<sensor type=\"perspective\"><float name=\"fov\" value=\"40\"/><film type=\"hdrfilm\">"   \
    "<integer name=\"width\" value=\"8\"/><integer name=\"height\" value=\"8\"/></film>"         \
    "</sensor>\n"

static void load(const char *xml, scene *s)
{
    tr_error err;
    if (!scene_load_string(xml, TRACER_TEST_TMP_DIR, s, &err))
        fail_msg("%s", err.msg);
}

/* ---- Version 0.5 files ------------------------------------------------------------------------ */

static const char *const old_scene =
    "<scene version=\"0.5.0\">\n"
    "<integrator type=\"path\"><integer name=\"maxDepth\" value=\"7\"/></integrator>\n" OLD_SENSOR
    "<bsdf type=\"diffuse\" id=\"_wall\"><rgb name=\"diffuseReflectance\" value=\"0.2\"/></bsdf>\n"
    "<bsdf type=\"roughplastic\" id=\"floor\"><float name=\"intIOR\" value=\"1.7\"/>"
    "<texture name=\"diffuseReflectance\" type=\"checkerboard\"><float name=\"uscale\" value=\"4\"/>"
    "<float name=\"voffset\" value=\"0.5\"/></texture></bsdf>\n"
    "<shape type=\"rectangle\"><ref id=\"_wall\"/></shape>\n"
    "<shape type=\"cube\"><ref id=\"floor\"/><boolean name=\"flipNormals\" value=\"true\"/></shape>\n"
    "</scene>\n";

static void test_version_0_5_is_upgraded(void **state)
{
    (void)state;
    scene s;
    load(old_scene, &s);
    assert_true(s.upgraded);
    assert_int_equal(s.upgraded_from[1], 5);
    assert_int_equal(s.max_depth, 7); /* maxDepth -> max_depth */
    /* A diffuse's diffuse_reflectance is its reflectance; the reserved id "_wall" was
     * renamed in its definition and its reference alike. */
    const bsdf *wall = &s.bsdfs[s.shapes[0].bsdf], *floor = &s.bsdfs[s.shapes[1].bsdf];
    assert_int_equal(wall->type, BSDF_DIFFUSE);
    assert_float_equal(wall->diffuse->value.g, 0.2f, 0.0f);
    assert_float_equal(floor->ior, 1.7f / 1.000277f, 1e-6f); /* intIOR -> int_ior */
    /* uscale 4 and voffset 0.5 became to_uv: u' = 4 u, v' = v + 0.5. */
    assert_float_equal(floor->diffuse->uv[0][0], 4.0f, 0.0f);
    assert_float_equal(floor->diffuse->uv[1][2], 0.5f, 0.0f);
    assert_float_equal(floor->diffuse->uv[0][2], 0.0f, 0.0f);
    scene_free(&s);
}

static void test_version_2_is_not_upgraded(void **state)
{
    (void)state;
    /* The same names in a file of today's format are unknown parameters. */
    char xml[4096];
    snprintf(xml, sizeof xml, "%s", old_scene);
    memcpy(strstr(xml, "0.5.0"), "2.0.0", 5);
    expect_error(xml, "<string>:2:", "unsupported parameter 'maxDepth'", NULL);
    /* Mitsuba's loop does not look at the letter after a run of capitals: aBcD -> a_bcD. */
    expect_error("<scene version=\"0.5.0\"><integrator type=\"path\">"
                 "<integer name=\"aBcD\" value=\"1\"/></integrator></scene>",
                 "unsupported parameter 'a_bcD'", NULL);
    expect_error("<scene version=\"0.5\"/>", "the version must be three numbers", NULL);
    expect_error("<scene version=\"1.x.0\"/>", "the version must be three numbers", NULL);
}

/* ---- The mask BSDF ------------------------------------------------------------------------------ */

/* Of n rays crossing a masked unit square, how many it stops (scene_occluded) and how many
 * meet it (scene_intersect). */
static void count_blocked(const scene *s, int n, int *occluded, int *met)
{
    *occluded = *met = 0;
    for (int i = 0; i < n; ++i) {
        /* Origins spread over the square's middle, all directions straight down -z. */
        float x = -0.5f + (float)(i % 97) / 97.0f, y = -0.5f + (float)(i / 97 % 89) / 89.0f;
        ray r = {v3(x, y, 1.0f + 1e-3f * (float)(i / 8633)), v3(0.0f, 0.0f, -1.0f), 3.0f};
        hit h;
        *occluded += scene_occluded(s, &r);
        *met += scene_intersect(s, &r, &h);
    }
}

static void test_mask_constant_opacity(void **state)
{
    (void)state;
    scene s;
    load("<scene version=\"3.0.0\">" SENSOR
         "<shape type=\"rectangle\"><bsdf type=\"mask\"><float name=\"opacity\" value=\"0.3\"/>"
         "<bsdf type=\"diffuse\"/></bsdf></shape></scene>",
         &s);
    assert_non_null(s.shapes[0].opacity);
    assert_int_equal(s.bsdfs[s.shapes[0].bsdf].type, BSDF_DIFFUSE);
    const int n = 40000;
    int occluded, met;
    count_blocked(&s, n, &occluded, &met);
    /* Binomial(40000, 0.3): standard deviation 92, so 5 sigma is +-460 (+-0.0115). */
    assert_true(fabs(occluded / (double)n - 0.3) < 0.0115);
    assert_true(fabs(met / (double)n - 0.3) < 0.0115);
    scene_free(&s);
}

static void test_mask_from_png_alpha(void **state)
{
    (void)state;
    /* A 2 x 1 RGBA image: left texel opaque red, right texel transparent white. */
    char png[1024];
    const unsigned char texels[8] = {255, 0, 0, 255, 255, 255, 255, 0};
    snprintf(png, sizeof png, "%s/leaf.png", TRACER_TEST_TMP_DIR);
    assert_true(stbi_write_png(png, 2, 1, 4, texels, 8));
    scene s;
    load("<scene version=\"3.0.0\">" SENSOR
         "<shape type=\"rectangle\"><bsdf type=\"mask\"><texture type=\"bitmap\" name=\"opacity\">"
         "<string name=\"filename\" value=\"leaf.png\"/><string name=\"filter_type\" value=\"nearest\"/>"
         "</texture><bsdf type=\"diffuse\"/></bsdf></shape></scene>",
         &s);
    const texture *t = s.shapes[0].opacity;
    assert_non_null(t);
    /* Alpha, not the colour's luminance (the white texel would be opaque, the red one 0.2). */
    assert_float_equal(texture_eval_opacity(t, 0.25f, 0.5f), 1.0f, 0.0f);
    assert_float_equal(texture_eval_opacity(t, 0.75f, 0.5f), 0.0f, 0.0f);
    /* The rectangle's u runs along x: rays through its left half stop, the right half is
     * clear. Half the rays of count_blocked cross each side (x - (-0.5) < 0.5 or not). */
    int occluded, met;
    count_blocked(&s, 8633, &occluded, &met);
    assert_int_equal(occluded, met);
    assert_true(fabs(occluded / 8633.0 - 0.5) < 0.02); /* 97 columns: 48 or 49 of them */
    scene_free(&s);
    expect_error("<scene version=\"3.0.0\">" SENSOR
                 "<shape type=\"rectangle\"><bsdf type=\"mask\"/></shape></scene>",
                 "mask needs a nested <bsdf> or <ref>", NULL);
    expect_error("<scene version=\"3.0.0\">" SENSOR
                 "<shape type=\"rectangle\"><bsdf type=\"mask\"><bsdf type=\"diffuse\"/></bsdf>"
                 "<emitter type=\"area\"><rgb name=\"radiance\" value=\"1\"/></emitter></shape></scene>",
                 "a shape with a mask material cannot emit", NULL);
}

/* ---- The thin dielectric ------------------------------------------------------------------------ */

static void test_thin_dielectric(void **state)
{
    (void)state;
    scene s;
    load("<scene version=\"3.0.0\">" SENSOR
         "<shape type=\"rectangle\"><bsdf type=\"thindielectric\">"
         "<float name=\"int_ior\" value=\"1.5\"/><float name=\"ext_ior\" value=\"1\"/>"
         "<rgb name=\"specular_transmittance\" value=\"0.5, 0.6, 0.7\"/></bsdf></shape></scene>",
         &s);
    const bsdf *b = &s.bsdfs[s.shapes[0].bsdf];
    assert_int_equal(b->type, BSDF_THINDIELECTRIC);
    assert_true(bsdf_transmits(b));
    assert_false(bsdf_has_smooth_part(b));
    bsdf_point bp;
    bsdf_point_init(&bp, b, 0.5f, 0.5f);
    /* At normal incidence one face reflects R = ((1.5 - 1) / 2.5)^2 = 0.04 and the sheet
     * 2R / (1 + R) = 0.076923, from either side. The lobe numbers are stratified, so the
     * reflected share is that probability within 1 / n, plus the float Fresnel's rounding:
     * 1e-4 allows both and is far from the single face's 0.04. */
    for (int side = 0; side < 2; ++side) {
        const vec3 wo = v3(0.0f, 0.0f, side ? -1.0f : 1.0f);
        const int n = 100000;
        int reflected = 0;
        for (int i = 0; i < n; ++i) {
            bsdf_sample smp;
            assert_true(bsdf_sample_dir(&bp, wo, ((float)i + 0.5f) / (float)n, 0.3f, 0.7f, &smp));
            assert_true(smp.delta);
            if (smp.wi.z * wo.z > 0.0f) {
                ++reflected;
                assert_float_equal(smp.weight.g, 1.0f, 0.0f); /* specular_reflectance 1 */
            } else {
                assert_float_equal(smp.wi.z, -wo.z, 0.0f); /* straight through, unbent */
                assert_float_equal(smp.weight.b, 0.7f, 1e-6f);
            }
        }
        assert_true(fabs(reflected / (double)n - 0.076923) < 1e-4);
    }
    scene_free(&s);
    expect_error("<scene version=\"3.0.0\">" SENSOR
                 "<shape type=\"rectangle\"><bsdf type=\"twosided\"><bsdf type=\"thindielectric\"/>"
                 "</bsdf></shape></scene>",
                 "a twosided dielectric makes no sense", NULL);
}

/* ---- The rough dielectric -------------------------------------------------------------------------- */

/* roughdielectric loads with Mitsuba 3's defaults (Beckmann, alpha 0.1, int_ior 1.5046 over
 * ext_ior 1.000277), transmits, is guided (it has a non-delta part), and takes the
 * roughness parameters of the other rough materials; test_bsdf.c checks its sampling. */
static void test_rough_dielectric(void **state)
{
    (void)state;
    scene s;
    load("<scene version=\"3.0.0\">" SENSOR
         "<shape type=\"rectangle\"><bsdf type=\"roughdielectric\"/></shape>"
         "<shape type=\"rectangle\"><bsdf type=\"roughdielectric\">"
         "<string name=\"distribution\" value=\"ggx\"/><float name=\"alpha\" value=\"0.3\"/>"
         "<float name=\"int_ior\" value=\"1.33\"/></bsdf></shape></scene>",
         &s);
    const bsdf *a = &s.bsdfs[s.shapes[0].bsdf], *b = &s.bsdfs[s.shapes[1].bsdf];
    assert_int_equal(a->type, BSDF_ROUGHDIELECTRIC);
    assert_int_equal(a->distribution, MF_BECKMANN);
    assert_float_equal(a->alpha, 0.1f, 0.0f);
    assert_float_equal(a->ior, 1.5046f / 1.000277f, 1e-6f);
    assert_true(bsdf_transmits(a) && bsdf_has_smooth_part(a));
    assert_int_equal(b->distribution, MF_GGX);
    assert_float_equal(b->alpha, 0.3f, 0.0f);
    assert_float_equal(b->ior, 1.33f / 1.000277f, 1e-6f);
    scene_free(&s);
    expect_error("<scene version=\"3.0.0\">" SENSOR
                 "<shape type=\"rectangle\"><bsdf type=\"roughdielectric\">"
                 "<float name=\"alpha_u\" value=\"0.1\"/><float name=\"alpha_v\" value=\"0.2\"/>"
                 "</bsdf></shape></scene>",
                 "anisotropic roughness", NULL);
}

/* ---- The disk ------------------------------------------------------------------------------------- */

static void test_disk(void **state)
{
    (void)state;
    mesh m;
    tr_error err;
    assert_true(mesh_make_disk(&m, &err));
    double area = 0.0;
    for (uint32_t t = 0; t < m.ntris; ++t) {
        const uint32_t *i = m.idx + 3 * t;
        vec3 c = v3_cross(v3_sub(m.p[i[1]], m.p[i[0]]), v3_sub(m.p[i[2]], m.p[i[0]]));
        area += 0.5 * v3_length(c);
        assert_true(c.z > 0.0f); /* facing +z, as Mitsuba's disk */
    }
    /* The area is the unit disk's (float vertices: 1e-5 relative). */
    assert_true(fabs(area / 3.14159265358979 - 1.0) < 1e-5);
    for (uint32_t i = 0; i < m.nverts; ++i) {
        assert_float_equal(m.p[i].z, 0.0f, 0.0f);
        assert_true(v3_length(m.p[i]) < 1.001f);
    }
    mesh_free(&m);
    /* An emitting disk of radius 0.5 (scale) is one light of area pi / 4. */
    scene s;
    load("<scene version=\"3.0.0\">" SENSOR
         "<shape type=\"disk\"><transform name=\"to_world\"><scale value=\"0.5\"/></transform>"
         "<emitter type=\"area\"><rgb name=\"radiance\" value=\"1\"/></emitter></shape></scene>",
         &s);
    double lit = 0.0;
    for (uint32_t t = 0; t < s.shapes[0].m.ntris; ++t)
        lit += s.shapes[0].tri_area[t];
    assert_true(fabs(lit / (3.14159265358979 / 4.0) - 1.0) < 1e-5);
    scene_free(&s);
}

/* ---- Meshes without area --------------------------------------------------------------------------- */

static void test_mesh_without_area_is_skipped(void **state)
{
    (void)state;
    char obj[1024];
    snprintf(obj, sizeof obj, "%s/flat.obj", TRACER_TEST_TMP_DIR);
    write_text(obj, "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n"); /* three points on a line */
    scene s;
    load("<scene version=\"3.0.0\">" SENSOR
         "<shape type=\"obj\"><string name=\"filename\" value=\"flat.obj\"/></shape>\n"
         "<shape type=\"rectangle\"/></scene>",
         &s);
    assert_int_equal(s.nshapes, 1);
    assert_int_equal(s.nwarnings, 1);
    assert_non_null(strstr(s.warnings[0], "<string>:2: skipped the shape 'flat.obj'"));
    scene_free(&s);
}

/* ---- The bumpmap ---------------------------------------------------------------------------------- */

/* The gradient a bump map uses is the derivative of the texture's own bilinear lookup: central
 * differences of texture_eval's luminance agree with it, through a rotating to_uv too. */
static void test_bump_gradient_is_the_lookups_derivative(void **state)
{
    (void)state;
    char png[1024];
    unsigned char texels[5 * 4 * 3];
    for (int i = 0; i < 5 * 4 * 3; ++i)
        texels[i] = (unsigned char)((i * 73 + 19) % 251);
    snprintf(png, sizeof png, "%s/bumps.png", TRACER_TEST_TMP_DIR);
    assert_true(stbi_write_png(png, 5, 4, 3, texels, 15));
    scene s;
    load("<scene version=\"3.0.0\">" SENSOR
         "<shape type=\"rectangle\"><bsdf type=\"bumpmap\"><texture type=\"bitmap\">"
         "<string name=\"filename\" value=\"bumps.png\"/><boolean name=\"raw\" value=\"true\"/>"
         "<transform name=\"to_uv\"><rotate value=\"0, 0, 1\" angle=\"30\"/>"
         "<scale x=\"2\" y=\"3\"/></transform></texture><bsdf type=\"diffuse\"/></bsdf></shape></scene>",
         &s);
    const texture *t = s.bsdfs[s.shapes[0].bsdf].bump;
    assert_non_null(t);
    int checked = 0;
    for (int k = 0; k < 40; ++k) {
        float u = 0.013f + 0.0247f * (float)k, v = 0.91f - 0.0211f * (float)k, g[2];
        texture_eval_gradient(t, u, v, g);
        /* h = 1e-4 in (u, v) is at most 0.0036 texels after to_uv: a difference rarely
         * straddles a texel centre, where the bilinear lookup kinks; such points are
         * skipped by asking the two one-sided differences to agree first. Away from kinks
         * they differ by h times the lookup's curvature (~0.007 here) plus rounding. */
        const float h = 1e-4f;
        for (int a = 0; a < 2; ++a) {
            float du = a == 0 ? h : 0.0f, dv = a == 1 ? h : 0.0f;
            float f0 = rgb_luminance(texture_eval(t, u, v));
            float fp = rgb_luminance(texture_eval(t, u + du, v + dv));
            float fm = rgb_luminance(texture_eval(t, u - du, v - dv));
            float fwd = (fp - f0) / h, bwd = (f0 - fm) / h;
            if (fabsf(fwd - bwd) > 2e-2f * (1.0f + fabsf(fwd)))
                continue;
            /* Float rounding of values below 1 over h = 1e-4 is about 1e-3 of slope. */
            assert_true(fabsf(g[a] - 0.5f * (fwd + bwd)) <= 1e-2f * (1.0f + fabsf(g[a])));
            ++checked;
        }
    }
    assert_true(checked >= 60);
    scene_free(&s);
}

/* A height ramp along u tilts the rectangle's normal towards -u by atan(scale g / |dp/du|),
 * Mitsuba 3's bumpmap, and only where the material has one. */
static void test_bumpmap_tilts_the_normal(void **state)
{
    (void)state;
    char png[1024];
    unsigned char ramp[256];
    for (int i = 0; i < 256; ++i)
        ramp[i] = (unsigned char)i;
    snprintf(png, sizeof png, "%s/ramp.png", TRACER_TEST_TMP_DIR);
    assert_true(stbi_write_png(png, 256, 1, 1, ramp, 256));
    for (int use_ref = 0; use_ref < 2; ++use_ref) {
        scene s;
        char xml[4096];
        snprintf(xml, sizeof xml,
                 "<scene version=\"3.0.0\">" SENSOR "%s"
                 "<shape type=\"rectangle\"><bsdf type=\"twosided\"><bsdf type=\"bumpmap\">%s"
                 "<float name=\"scale\" value=\"2\"/><bsdf type=\"diffuse\"/></bsdf></bsdf></shape>"
                 "<shape type=\"rectangle\"><transform name=\"to_world\"><translate z=\"-1\"/>"
                 "</transform></shape></scene>",
                 use_ref ? "<texture type=\"bitmap\" id=\"h\"><string name=\"filename\" "
                           "value=\"ramp.png\"/><boolean name=\"raw\" value=\"true\"/></texture>"
                         : "",
                 use_ref ? "<ref id=\"h\"/>"
                         : "<texture type=\"bitmap\" name=\"height\"><string name=\"filename\" "
                           "value=\"ramp.png\"/><boolean name=\"raw\" value=\"true\"/></texture>");
        load(xml, &s);
        for (int shape = 0; shape < 2; ++shape) {
            hit h = {1.0f, shape, 0, 0.3f, 0.2f};
            ray r = {v3(0.0f, 0.0f, 1.0f), v3(0.0f, 0.0f, -1.0f), INFINITY};
            surface sf;
            scene_surface(&s, &h, &r, &sf);
            assert_true(sf.u > 0.1f && sf.u < 0.9f); /* away from the ramp's wrap-around */
            if (shape == 1) { /* no bump map: the interpolated normal */
                assert_float_equal(sf.ns.x, 0.0f, 0.0f);
                assert_float_equal(sf.ns.z, 1.0f, 1e-6f);
                continue;
            }
            /* dp/du = (2, 0, 0); the ramp rises 1/255 a texel, 256/255 per unit of u. */
            const float a = 2.0f * 256.0f / 255.0f;
            assert_float_equal(sf.ns.x, -a / sqrtf(a * a + 4.0f), 1e-5f);
            assert_float_equal(sf.ns.y, 0.0f, 1e-6f);
            assert_float_equal(sf.ns.z, 2.0f / sqrtf(a * a + 4.0f), 1e-5f);
        }
        scene_free(&s);
    }
    expect_error("<scene version=\"3.0.0\">" SENSOR
                 "<shape type=\"rectangle\"><bsdf type=\"bumpmap\"><bsdf type=\"diffuse\"/></bsdf>"
                 "</shape></scene>",
                 "bumpmap needs a nested <texture> or a <ref> to one", NULL);
    expect_error("<scene version=\"3.0.0\">" SENSOR
                 "<shape type=\"rectangle\"><bsdf type=\"bumpmap\"><texture type=\"checkerboard\"/>"
                 "<texture type=\"checkerboard\"/><bsdf type=\"diffuse\"/></bsdf></shape></scene>",
                 "bumpmap takes one texture", NULL);
    expect_error("<scene version=\"3.0.0\">" SENSOR
                 "<shape type=\"rectangle\"><bsdf type=\"bumpmap\"><texture type=\"checkerboard\"/>"
                 "<bsdf type=\"null\"/></bsdf></shape></scene>",
                 "a bumpmap over the null material", NULL);
    expect_error("<scene version=\"3.0.0\">" SENSOR
                 "<shape type=\"rectangle\"><bsdf type=\"bumpmap\"><texture type=\"checkerboard\"/>"
                 "</bsdf></shape></scene>",
                 "bumpmap needs a nested <bsdf> or <ref>", NULL);
}

/* ---- The shipped interiors, as Bitterli distributes them ------------------------------------------ */


static void test_living_room(void **state)
{
    (void)state;
    scene s;
    load_shipped("living-room", &s);
    assert_true(s.upgraded);
    assert_int_equal(s.width, 1280);
    assert_int_equal(s.max_depth, 65);
    assert_int_equal(s.env.kind, ENV_ENVMAP);
    assert_int_equal(s.nwarnings, 0);
    int masked = 0;
    for (int i = 0; i < s.nshapes; ++i)
        masked += s.shapes[i].opacity != NULL && s.shapes[i].opacity->alpha.data != NULL;
    assert_true(masked >= 1); /* the plant's leaves, by leaf.png's alpha */
    scene_free(&s);
}

static void test_modern_hall(void **state)
{
    (void)state;
    scene s;
    load_shipped("modern-hall", &s);
    assert_true(s.upgraded);
    int disks = 0, emitters = 0;
    for (int i = 0; i < s.nshapes; ++i) {
        disks += s.shapes[i].m.ntris == 64;
        emitters += s.shapes[i].emissive;
    }
    assert_int_equal(disks, 5);
    assert_int_equal(emitters, 13);
    scene_free(&s);
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_version_0_5_is_upgraded),
    cmocka_unit_test(test_version_2_is_not_upgraded),
    cmocka_unit_test(test_mask_constant_opacity),
    cmocka_unit_test(test_mask_from_png_alpha),
    cmocka_unit_test(test_thin_dielectric),
    cmocka_unit_test(test_rough_dielectric),
    cmocka_unit_test(test_disk),
    cmocka_unit_test(test_mesh_without_area_is_skipped),
    cmocka_unit_test(test_bump_gradient_is_the_lookups_derivative),
    cmocka_unit_test(test_bumpmap_tilts_the_normal),
    cmocka_unit_test(test_living_room),
    cmocka_unit_test(test_modern_hall),
)
