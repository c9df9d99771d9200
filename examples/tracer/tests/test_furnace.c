/*
 * test_furnace.c - unbiasedness of the whole estimator: white-furnace scenes, with guiding
 * on and every prior.
 *
 * A corner (floor and two walls) with a sphere in it, all white (albedo 1) two-sided
 * diffuse, a glass sphere, a thin glass sheet and a half-transparent white leaf (a mask),
 * under a constant environment of radiance 1: the radiance leaving every surface
 * is exactly 1, so every pixel's expectation is 1, however many bounces a path takes and
 * however its directions were sampled. Any bias of the mixture density, of its use in MIS,
 * of the delta/non-delta bookkeeping or of Russian roulette shows up as a mean != 1. (An
 * open corner rather than a deep box: a barely trained flow with a uniform prior multiplies
 * the throughput by up to ~1.6 per bounce, and over the dozens of bounces inside a box the
 * estimator becomes too heavy-tailed for a test of a few thousand paths.)
 *
 * Also: environment maps are importance-sampled with the density that MIS assumes.
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

#include "integrator.h"
#include "model_setup.h"
#include "render.h"
#include "scene.h"
#include "training.h"

#include "mixed_scene.h"
#include "test_guided.h"

/* 24 x 24 pixels at 16 paths each: a standard error of about 0.4% for the cosine prior, so
 * that a 5% bias is caught. Small enough to run in seconds under the sanitizers too. */
#define SIZE 24
#define SPP 16

static const char *furnace_xml(const char *environment)
{
    static char xml[4096];
    snprintf(xml, sizeof xml,
        "<scene version=\"3.0.0\">\n"
        "<integrator type=\"path\"><integer name=\"max_depth\" value=\"-1\"/></integrator>\n"
        "<sensor type=\"perspective\"><float name=\"fov\" value=\"50\"/>\n"
        "  <transform name=\"to_world\"><lookat origin=\"0.6, 0.4, 1.8\" target=\"-0.2, -0.3, -0.3\" up=\"0, 1, 0\"/></transform>\n"
        "  <film type=\"hdrfilm\"><integer name=\"width\" value=\"%d\"/><integer name=\"height\" value=\"%d\"/></film>\n"
        "</sensor>\n"
        "<bsdf type=\"twosided\" id=\"white\"><bsdf type=\"diffuse\"><rgb name=\"reflectance\" value=\"1\"/></bsdf></bsdf>\n"
        "<shape type=\"rectangle\"><transform name=\"to_world\"><translate z=\"-1\"/></transform><ref id=\"white\"/></shape>\n"
        "<shape type=\"rectangle\"><transform name=\"to_world\"><rotate y=\"1\" angle=\"90\"/><translate x=\"-1\"/></transform><ref id=\"white\"/></shape>\n"
        "<shape type=\"rectangle\"><transform name=\"to_world\"><rotate x=\"1\" angle=\"90\"/><translate y=\"-1\"/></transform><ref id=\"white\"/></shape>\n"
        "<shape type=\"sphere\"><point name=\"center\" value=\"0.1, -0.5, -0.4\"/><float name=\"radius\" value=\"0.4\"/><ref id=\"white\"/></shape>\n"
        /* Glass conserves energy too (radiance inside is eta^2 times larger and scaled back
         * on the way out), and takes the delta paths. */
        "<shape type=\"sphere\"><point name=\"center\" value=\"-0.5, -0.7, 0.2\"/><float name=\"radius\" value=\"0.25\"/>"
        "<bsdf type=\"dielectric\"/></shape>\n"
        /* A thin glass sheet (reflects or passes unbent, losslessly) and a white leaf of
         * opacity 0.5 (the mask's alpha test lets half the rays through) conserve it too. */
        "<shape type=\"rectangle\"><transform name=\"to_world\"><scale value=\"0.3\"/><rotate x=\"1\" angle=\"-60\"/>"
        "<translate x=\"0.35\" y=\"-0.25\" z=\"0.1\"/></transform><bsdf type=\"thindielectric\"/></shape>\n"
        "<shape type=\"rectangle\"><transform name=\"to_world\"><scale value=\"0.35\"/><rotate y=\"1\" angle=\"40\"/>"
        "<translate x=\"-0.3\" y=\"0.1\"/></transform><bsdf type=\"mask\"><float name=\"opacity\" value=\"0.5\"/>"
        "<ref id=\"white\"/></bsdf></shape>\n"
        "%s\n"
        "</scene>\n", SIZE, SIZE, environment);
    return xml;
}

/* The acceptance rule: |mean - 1| below 4 standard errors. For an unbiased estimator that
 * rejects with probability 6e-5; a bias larger than 4 standard errors is caught. The
 * standard error is itself estimated, which the generous 4 (instead of ~2.6 for 1%)
 * absorbs. The seeds are fixed, so the outcome is reproducible. */
static int consistent_with_one(double mean, double se)
{
    return fabs(mean - 1.0) < 4.0 * se;
}

static void furnace(const char *environment, int guided, model_prior prior, int spp,
                    double *mean, double *se)
{
    scene s;
    tr_error err;
    if (!scene_load_string(furnace_xml(environment), TRACER_TEST_TMP_DIR, &s, &err))
        fail_msg("%s", err.msg);
    tracer t = test_tracer(&s, guided, prior, 4);
    image img;
    test_render(&t, spp, 11, &img, NULL);
    image_stats(&img, mean, se);
    image_free(&img);
    nf_model_destroy((nf_model *)t.model);
    scene_free(&s);
}

#define CONSTANT_ENV "<emitter type=\"constant\"><rgb name=\"radiance\" value=\"1\"/></emitter>"

/* spp_factor: the uniform priors start far from the integrand (half their directions are
 * below the surface) and need more samples for the same standard error. */
static void run(const char *label, const char *env, int guided, model_prior prior,
                int spp_factor)
{
    double mean, se;
    furnace(env, guided, prior, SPP * spp_factor, &mean, &se);
    printf("  %-28s mean %.5f +- %.5f\n", label, mean, se);
    if (!consistent_with_one(mean, se))
        fail_msg("%s: the furnace gives %g +- %g instead of 1", label, mean, se);
    /* The test must be able to see a bias of 5%: */
    assert_false(consistent_with_one(mean * 1.05, se));
}

static void test_furnace_unguided(void **state)
{
    (void)state;
    run("unguided", CONSTANT_ENV, 0, MODEL_PRIOR_COSINE, 1);
}

static void test_furnace_guided_cosine(void **state)
{
    (void)state;
    run("guided, cosine prior", CONSTANT_ENV, 1, MODEL_PRIOR_COSINE, 1);
}

static void test_furnace_guided_uniform_direction(void **state)
{
    (void)state;
    run("guided, uniform-direction", CONSTANT_ENV, 1, MODEL_PRIOR_UNIFORM_DIRECTION, 8);
}

static void test_furnace_guided_uniform_angle(void **state)
{
    (void)state;
    run("guided, uniform-angle", CONSTANT_ENV, 1, MODEL_PRIOR_UNIFORM_ANGLE, 8);
}

static void test_furnace_guided_bsdf_prior(void **state)
{
    (void)state;
    run("guided, bsdf prior", CONSTANT_ENV, 1, MODEL_PRIOR_BSDF, 1);
}

/* A lat-long map of constant radiance 1 is a furnace too; it takes the envmap code paths
 * (lookup, importance sampling, density). */
static void write_envmap(const char *name, int w, int h, int constant)
{
    image m;
    tr_error err;
    char path[1024];
    assert_true(image_alloc(&m, w, h, &err));
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            float *p = image_pixel(&m, x, y);
            float v = 0.05f + (float)((x * 7 + y * 13) % 17) * (y < h / 3 ? 3.0f : 0.1f);
            p[0] = constant ? 1.0f : v;
            p[1] = constant ? 1.0f : 0.5f * v;
            p[2] = constant ? 1.0f : 0.25f * v + 0.01f;
        }
    snprintf(path, sizeof path, "%s/%s", TRACER_TEST_TMP_DIR, name);
    if (!image_write_exr(&m, path, &err))
        fail_msg("%s", err.msg);
    image_free(&m);
}

static void test_furnace_envmap_guided(void **state)
{
    (void)state;
    write_envmap("white.exr", 32, 16, 1);
    run("guided, cosine, envmap", "<emitter type=\"envmap\"><string name=\"filename\" value=\"white.exr\"/>"
        "<transform name=\"to_world\"><rotate x=\"1\" angle=\"30\"/></transform></emitter>",
        1, MODEL_PRIOR_COSINE, 1);
}

static void test_envmap_sampling_density(void **state)
{
    (void)state;
    /* An uneven map: importance sampling must estimate its integral over the sphere, and
     * the density of each sample must be what light_pdf_env (used by MIS) reports. */
    write_envmap("uneven.exr", 64, 32, 0);
    scene s;
    tr_error err;
    const char *xml = furnace_xml("<emitter type=\"envmap\"><string name=\"filename\" value=\"uneven.exr\"/>"
                                  "<float name=\"scale\" value=\"2\"/>"
                                  "<transform name=\"to_world\"><rotate z=\"1\" angle=\"20\"/></transform></emitter>");
    if (!scene_load_string(xml, TRACER_TEST_TMP_DIR, &s, &err))
        fail_msg("%s", err.msg);
    /* The exact integral of the piecewise-constant map: sum of value x solid angle. */
    double exact = 0.0;
    const image *m = &s.env.map;
    for (int y = 0; y < m->height; ++y) {
        double t0 = 3.14159265358979 * y / m->height, t1 = 3.14159265358979 * (y + 1) / m->height;
        double omega = 2.0 * 3.14159265358979 / m->width * (cos(t0) - cos(t1));
        for (int x = 0; x < m->width; ++x)
            exact += 2.0 * image_pixel(m, x, y)[0] * omega;
    }
    /* The environment is the last light entry; pick it directly with u_pick close to 1. */
    rng r = rng_seed(3, RNG_TEST, 0, 0);
    double sum = 0.0;
    const int n = 200000;
    int mismatches = 0;
    float pick = (float)distrib1d_pmf(&s.lights, s.nlights - 1);
    for (int i = 0; i < n; ++i) {
        light_sample ls;
        if (!light_sample_from(&s, v3(0.0f, 0.0f, 0.0f), 0.9999999f, rng_next(&r), rng_next(&r), &ls))
            continue;
        /* The direction goes through float trigonometry and back: a sample within a float
         * rounding of a pixel edge may land in the neighbouring pixel. That must stay rare
         * (a few in 1e4); anything systematic would show up in most samples. */
        if (fabsf(light_pdf_env(&s, ls.wi) - ls.pdf) > 1e-3f * ls.pdf)
            ++mismatches;
        sum += ls.radiance.r / (ls.pdf / pick);
    }
    double estimate = sum / n;
    printf("  envmap integral: exact %.5f, importance-sampled %.5f, %d density mismatches\n",
           exact, estimate, mismatches);
    assert_true(mismatches < n / 1000);
    /* Samples proportional to luminance of an RGB map whose red/luminance ratio is nearly
     * constant: the estimator's relative standard error is far below 0.1%; 0.5% allows for
     * the +0.01 blue offset. */
    assert_float_equal(estimate, exact, 5e-3 * exact);
    scene_free(&s);
}

/* Materials the furnace cannot hold (they lose energy): plastic (its coating is a delta
 * lobe inside a guided vertex), rough conductors and rough plastic, lit by an area light and
 * the sky. Guided and unguided renders must agree within their noise. */
static void test_guided_matches_unguided(void **state)
{
    (void)state;
    scene s;
    tr_error err;
    if (!scene_load_string(MIXED_SCENE_XML, TRACER_TEST_TMP_DIR, &s, &err))
        fail_msg("%s", err.msg);
    image img[2];
    for (int guided = 0; guided < 2; ++guided) {
        tracer t = test_tracer(&s, guided, MODEL_PRIOR_COSINE, 4);
        test_render(&t, 4 * SPP, 100 + (uint64_t)guided, &img[guided], NULL);
        nf_model_destroy((nf_model *)t.model);
    }
    /* Pixel by pixel differences: the image's own structure cancels, what remains is the
     * noise of the two estimators (independent seeds). */
    image diff;
    assert_true(image_alloc(&diff, s.width, s.height, &err));
    double mean_unguided = 0.0;
    size_t n = (size_t)s.width * (size_t)s.height * 3u;
    for (size_t i = 0; i < n; ++i) {
        diff.data[i] = img[1].data[i] - img[0].data[i];
        mean_unguided += img[0].data[i] / (double)n;
    }
    double d, se;
    image_stats(&diff, &d, &se); /* green channel: the colours are correlated anyway */
    printf("  unguided mean %.5f, guided - unguided %.5f +- %.5f\n", mean_unguided, d, se);
    /* 4 standard errors, as in the furnace; and the test must see a 5% bias. */
    assert_true(fabs(d) < 4.0 * se);
    assert_true(0.05 * mean_unguided > 4.0 * se);
    image_free(&diff);
    image_free(&img[0]);
    image_free(&img[1]);
    scene_free(&s);
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_furnace_unguided),
    cmocka_unit_test(test_furnace_guided_cosine),
    cmocka_unit_test(test_furnace_guided_uniform_direction),
    cmocka_unit_test(test_furnace_guided_uniform_angle),
    cmocka_unit_test(test_furnace_guided_bsdf_prior),
    cmocka_unit_test(test_furnace_envmap_guided),
    cmocka_unit_test(test_envmap_sampling_density),
    cmocka_unit_test(test_guided_matches_unguided),
)
