/*
 * test_options.c - the command line reaches the model: --prior-epsilon (used by the paper
 * study's sweep) is parsed, range-checked, and ends up in the created model's config, and
 * leaving it out keeps the library's default; --phi-map (the seam study's) and --sh-bands
 * (the equal-time study's) likewise; --guide-max-boost is parsed and range-checked, and
 * --throughput-roulette switches the roulette; --light-mis-depth is parsed and range-checked.
 */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include <cmocka.h>

#include "guide.h"
#include "options.h"
#include "scene.h"

static int parse(options *o, const char *a, const char *b, tr_error *err)
{
    char *argv[] = {"nf_tracer", "--scene", "x.xml", (char *)a, (char *)b, NULL};
    return options_parse(a ? (b ? 5 : 4) : 3, argv, o, err);
}

/* Each of `bad` given to `flag` is refused, with a message that names the flag. */
static void assert_refused(const char *flag, const char *const *bad, size_t count)
{
    options o;
    tr_error err;
    for (size_t i = 0; i < count; ++i) {
        err.msg[0] = '\0';
        assert_false(parse(&o, flag, bad[i], &err));
        assert_non_null(strstr(err.msg, flag));
    }
}

/* The Cornell box, the scene every model below is created for. */
static void load_cornell(scene *s)
{
    tr_error err;
    char path[1024];
    snprintf(path, sizeof path, "%s/cornell-box/scene.xml", TRACER_SCENES_DIR);
    if (!scene_load(path, s, &err))
        fail_msg("%s", err.msg);
}

/* The config of the model guide_create makes from gs (the model itself in *keep when asked
 * for, else destroyed). */
static nf_config created_config(const scene *s, const guide_settings *gs, nf_model **keep)
{
    tr_error err;
    nf_model *model = NULL;
    if (!guide_create(s, gs, &model, &err))
        fail_msg("%s", err.msg);
    nf_config cfg;
    nf_model_config(model, &cfg);
    if (keep)
        *keep = model;
    else
        nf_model_destroy(model);
    return cfg;
}

static void test_prior_epsilon_is_parsed_and_range_checked(void **state)
{
    (void)state;
    options o;
    tr_error err;
    assert_true(parse(&o, NULL, NULL, &err));
    assert_true(o.prior_epsilon < 0.0f); /* not given: the library's default */
    assert_true(parse(&o, "--prior-epsilon", "0.25", &err));
    assert_true(o.prior_epsilon == 0.25f);
    assert_true(parse(&o, "--prior-epsilon", "1", &err));
    const char *const bad[] = {"0", "-0.1", "1.5", "nan", "abc", ""};
    assert_refused("--prior-epsilon", bad, sizeof bad / sizeof bad[0]);
}

static void test_guide_max_boost_is_parsed_and_range_checked(void **state)
{
    (void)state;
    options o;
    tr_error err;
    assert_true(parse(&o, NULL, NULL, &err));
    assert_true(o.guide_max_boost == 0.0f); /* not given: no cap */
    assert_true(parse(&o, "--guide-max-boost", "10", &err));
    assert_true(o.guide_max_boost == 10.0f);
    assert_true(parse(&o, "--guide-max-boost", "0", &err));
    assert_true(o.guide_max_boost == 0.0f);
    const char *const bad[] = {"-1", "1e7", "nan", "abc", ""};
    assert_refused("--guide-max-boost", bad, sizeof bad / sizeof bad[0]);
}

static void test_throughput_roulette_is_a_switch(void **state)
{
    (void)state;
    options o;
    tr_error err;
    assert_true(parse(&o, NULL, NULL, &err));
    assert_int_equal(o.throughput_roulette, 0); /* default: roulette_survival's rule */
    assert_true(parse(&o, "--throughput-roulette", NULL, &err));
    assert_int_equal(o.throughput_roulette, 1);
}

static void test_light_mis_depth_is_parsed_and_range_checked(void **state)
{
    (void)state;
    options o;
    tr_error err;
    assert_true(parse(&o, NULL, NULL, &err));
    assert_int_equal(o.light_mis_depth, 0); /* not given: the mixture's weighting everywhere */
    assert_true(parse(&o, "--light-mis-depth", "2", &err));
    assert_int_equal(o.light_mis_depth, 2);
    const char *const bad[] = {"-1", "1.5", "abc", ""};
    assert_refused("--light-mis-depth", bad, sizeof bad / sizeof bad[0]);
}

static void test_phi_map_is_parsed_and_reaches_the_model(void **state)
{
    (void)state;
    options o;
    tr_error err;
    assert_true(parse(&o, NULL, NULL, &err));
    assert_int_equal(o.phi_interval, 0);
    assert_true(parse(&o, "--phi-map", "interval", &err));
    assert_int_equal(o.phi_interval, 1);
    assert_true(parse(&o, "--phi-map", "circular", &err));
    assert_int_equal(o.phi_interval, 0);
    err.msg[0] = '\0';
    assert_false(parse(&o, "--phi-map", "torus", &err));
    assert_non_null(strstr(err.msg, "--phi-map"));

    scene s;
    load_cornell(&s);
    for (int interval = 0; interval < 2; ++interval) {
        guide_settings gs = guide_default_settings(GUIDE_PRIOR_COSINE);
        gs.phi_interval = interval;
        nf_config cfg = created_config(&s, &gs, NULL);
        assert_int_equal(cfg.phi_map, interval ? NF_PHI_INTERVAL : NF_PHI_CIRCULAR);
    }
    scene_free(&s);
}

static void test_created_model_carries_the_epsilon(void **state)
{
    (void)state;
    scene s;
    load_cornell(&s);
    nf_config defaults;
    nf_config_init(&defaults, NF_PRESET_SMALL);
    const float wanted[] = {-1.0f, 0.001f, 0.25f};
    for (size_t i = 0; i < 3; ++i) {
        guide_settings gs = guide_default_settings(GUIDE_PRIOR_COSINE);
        gs.prior_epsilon = wanted[i];
        nf_config cfg = created_config(&s, &gs, NULL);
        assert_true(cfg.prior_epsilon == (wanted[i] < 0.0f ? defaults.prior_epsilon : wanted[i]));
    }
    scene_free(&s);
}

static void test_sh_bands_are_parsed_and_reach_the_model(void **state)
{
    (void)state;
    options o;
    tr_error err;
    assert_true(parse(&o, NULL, NULL, &err));
    assert_true(o.sh_bands < 0); /* not given: the preset's */
    assert_true(parse(&o, "--sh-bands", "0", &err));
    assert_int_equal(o.sh_bands, 0);
    assert_true(parse(&o, "--sh-bands", "6", &err));
    assert_int_equal(o.sh_bands, 6);
    const char *const bad[] = {"-1", "7", "2.5", "two", ""};
    assert_refused("--sh-bands", bad, sizeof bad / sizeof bad[0]);

    scene s;
    load_cornell(&s);
    nf_config defaults;
    nf_config_init(&defaults, NF_PRESET_SMALL);
    const int wanted[] = {-1, 0, 2};
    for (size_t i = 0; i < 3; ++i) {
        guide_settings gs = guide_default_settings(GUIDE_PRIOR_COSINE);
        gs.sh_bands = wanted[i];
        nf_model *model = NULL;
        nf_config cfg = created_config(&s, &gs, &model);
        assert_int_equal(cfg.sh_bands, wanted[i] < 0 ? defaults.sh_bands : (uint32_t)wanted[i]);
        /* A position-only model still samples and evaluates (no SH rows in its input). */
        nf_context ctx = {{0.1f, 0.2f, 0.3f}, {0.0f, 0.0f, 1.0f}, {0.0f, 1.0f, 0.0f}};
        float u[2] = {0.3f, 0.7f}, dir[3], pdf = 0.0f, back = 0.0f;
        assert_int_equal(nf_sample(model, 1, &ctx, u, dir, &pdf), NF_OK);
        assert_int_equal(nf_pdf(model, 1, &ctx, dir, &back), NF_OK);
        /* A fresh model is a well-conditioned flow: model.h bounds the relative difference
         * by 1e-4 away from the poles; 1e-3 leaves room for a direction near one. */
        assert_true(pdf > 0.0f && fabsf(back - pdf) <= 1e-3f * pdf);
        nf_model_destroy(model);
    }
    scene_free(&s);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_guide_max_boost_is_parsed_and_range_checked),
        cmocka_unit_test(test_throughput_roulette_is_a_switch),
        cmocka_unit_test(test_light_mis_depth_is_parsed_and_range_checked),
        cmocka_unit_test(test_prior_epsilon_is_parsed_and_range_checked),
        cmocka_unit_test(test_created_model_carries_the_epsilon),
        cmocka_unit_test(test_phi_map_is_parsed_and_reaches_the_model),
        cmocka_unit_test(test_sh_bands_are_parsed_and_reach_the_model),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
