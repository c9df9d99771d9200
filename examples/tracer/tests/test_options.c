/*
 * test_options.c - the command line: the defaults are the library's guide defaults and the
 * best configuration of docs/equal-time.md; --isa names the kernels; --variant settings (the studies' and the
 * ablations') are parsed, range-checked, and reach the options; the model settings among
 * them (prior epsilon, phi map, SH bands) reach the created model's config; nf_tracer and
 * nf_paper each refuse the other's protocol, naming the program that takes it.
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

#include "model_setup.h"
#include "options.h"
#include "scene.h"

/* `program`'s command line --scene x.xml [a [b]], parsed into o. */
static int parse_for(options_program program, options *o, const char *a, const char *b,
                     tr_error *err)
{
    char *argv[] = {"nf_tracer", "--scene", "x.xml", (char *)a, (char *)b, NULL};
    return options_parse(a ? (b ? 5 : 4) : 3, argv, program, o, err);
}

static int parse(options *o, const char *a, const char *b, tr_error *err)
{
    return parse_for(OPTIONS_TRACER, o, a, b, err);
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

/* The config of the model model_create_for_scene makes from gs (the model itself in *keep
 * when asked for, else destroyed). */
static nf_config created_config(const scene *s, const model_settings *gs, nf_model **keep)
{
    tr_error err;
    nf_model *model = NULL;
    if (!model_create_for_scene(s, gs, NULL, &model, &err))
        fail_msg("%s", err.msg);
    nf_config cfg;
    nf_model_get_config(model, &cfg);
    if (keep)
        *keep = model;
    else
        nf_model_destroy(model);
    return cfg;
}

/* --variant VALUE, parsed into o. */
static int variant(options *o, const char *value, tr_error *err)
{
    return parse(o, "--variant", value, err);
}

/* Each of `bad` given as --variant is refused, with a message that names `name`. */
static void assert_variant_refused(const char *name, const char *const *bad, size_t count)
{
    options o;
    tr_error err;
    for (size_t i = 0; i < count; ++i) {
        err.msg[0] = '\0';
        assert_false(variant(&o, bad[i], &err));
        assert_non_null(strstr(err.msg, name));
    }
}

static void test_defaults_are_the_best_configuration(void **state)
{
    (void)state;
    options o;
    tr_error err;
    assert_true(parse(&o, NULL, NULL, &err));
    /* The library's guide defaults, one home for them: */
    nf_guide_config gc;
    nf_guide_config_init(&gc);
    assert_true(o.guide.policy.mixture_prob == gc.policy.mixture_prob);
    assert_true(o.guide.policy.max_boost == gc.policy.max_boost);
    assert_int_equal(o.guide.policy.light_mis_depth, gc.policy.light_mis_depth);
    assert_true(o.guide.policy.min_roughness == gc.policy.min_roughness);
    assert_true(o.guide.clamp_quantile == gc.clamp_quantile);
    assert_true(o.guide.train_fraction == gc.train_fraction);
    /* and the tracer's own: a position-only model trained on the MIS-weighted emission. */
    assert_int_equal(o.sh_bands, 0);
    assert_int_equal(o.mis_training, 1);
    assert_int_equal(o.no_batching, 0);
    assert_int_equal(o.light_mis_bsdf, 0);
    assert_int_equal(o.phi_interval, 0);
    assert_true(o.prior_epsilon < 0.0f); /* the library's */
    assert_int_equal(o.isa, NF_ISA_AUTO);
}

/* nf_tracer renders in a time budget (30 s unless told) and refuses the paper's protocol;
 * nf_paper takes the protocol and refuses --time-budget; each message names the other
 * program. Both take the options they share. */
static void test_each_program_takes_its_protocol(void **state)
{
    (void)state;
    options o;
    tr_error err;
    assert_true(parse_for(OPTIONS_TRACER, &o, NULL, NULL, &err));
    assert_true(o.time_budget == 30.0f);
    assert_true(parse_for(OPTIONS_TRACER, &o, "--time-budget", "12.5", &err));
    assert_true(o.time_budget == 12.5f);
    static const char *const paper_only[][2] = {{"--iterations", "5"}, {"--batch", "64"},
                                                {"--spp", "4"},        {"--eval-every", "0"},
                                                {"--eval-spp", "2"},   {"--reference-mode", NULL}};
    for (size_t k = 0; k < sizeof paper_only / sizeof *paper_only; ++k) {
        err.msg[0] = '\0';
        assert_false(parse_for(OPTIONS_TRACER, &o, paper_only[k][0], paper_only[k][1], &err));
        assert_non_null(strstr(err.msg, paper_only[k][0]));
        assert_non_null(strstr(err.msg, "nf_paper"));
        assert_true(parse_for(OPTIONS_PAPER, &o, paper_only[k][0], paper_only[k][1], &err));
    }
    assert_true(parse_for(OPTIONS_PAPER, &o, "--spp", "4", &err));
    assert_int_equal(o.spp, 4);
    assert_true(o.time_budget == 0.0f);
    err.msg[0] = '\0';
    assert_false(parse_for(OPTIONS_PAPER, &o, "--time-budget", "10", &err));
    assert_non_null(strstr(err.msg, "nf_tracer"));
    assert_true(parse_for(OPTIONS_PAPER, &o, "--reference-mode", NULL, &err));
    assert_int_equal(o.guiding, 0);
    assert_int_equal(o.spp, 1024);
    assert_true(parse_for(OPTIONS_PAPER, &o, "--seed", "7", &err));
    assert_true(parse_for(OPTIONS_TRACER, &o, "--seed", "7", &err));
}

/* --isa names the library's kernels; anything else is refused with a message naming it. */
static void test_isa_is_parsed(void **state)
{
    (void)state;
    static const char *const names[] = {"auto", "generic", "avx2", "avx512"};
    static const nf_isa isas[] = {NF_ISA_AUTO, NF_ISA_GENERIC, NF_ISA_AVX2, NF_ISA_AVX512};
    options o;
    tr_error err;
    for (int k = 0; k < 4; ++k) {
        assert_true(parse(&o, "--isa", names[k], &err));
        assert_int_equal(o.isa, isas[k]);
    }
    const char *const bad[] = {"", "AVX2", "avx", "sse2", "avx512f"};
    assert_refused("--isa", bad, sizeof bad / sizeof bad[0]);
}

static void test_variants_are_parsed_and_range_checked(void **state)
{
    (void)state;
    options o;
    tr_error err;
    assert_true(variant(&o, "prior-epsilon=0.25", &err));
    assert_true(o.prior_epsilon == 0.25f);
    assert_true(variant(&o, "guide-max-boost=0,light-mis-depth=5,guide-prob=0.5", &err));
    assert_true(o.guide.policy.max_boost == 0.0f);
    assert_int_equal(o.guide.policy.light_mis_depth, 5);
    assert_true(o.guide.policy.mixture_prob == 0.5f);
    assert_true(variant(&o, "sh-bands=6,phi-interval,no-batching,all-emission", &err));
    assert_int_equal(o.sh_bands, 6);
    assert_int_equal(o.phi_interval, 1);
    assert_int_equal(o.no_batching, 1);
    assert_int_equal(o.mis_training, 0);
    assert_true(variant(&o, "paper", &err));
    assert_true(o.guide.policy.mixture_prob == 0.5f && o.guide.policy.max_boost == 0.0f);
    assert_true(o.sh_bands < 0 && o.mis_training == 0);
    const char *const eps[] = {"prior-epsilon=0", "prior-epsilon=1.5", "prior-epsilon=nan",
                               "prior-epsilon", "prior-epsilon="};
    assert_variant_refused("prior-epsilon", eps, sizeof eps / sizeof eps[0]);
    const char *const depth[] = {"light-mis-depth=-1", "light-mis-depth=1.5"};
    assert_variant_refused("light-mis-depth", depth, sizeof depth / sizeof depth[0]);
    const char *const sh[] = {"sh-bands=7", "sh-bands=two"};
    assert_variant_refused("sh-bands", sh, sizeof sh / sizeof sh[0]);
    const char *const other[] = {"no-batching=1", "plain-mixture"};
    assert_variant_refused("--variant", other, sizeof other / sizeof other[0]);
    /* Options that became variants or were deleted are refused by name. */
    const char *const none[] = {"0.5"};
    assert_refused("--guide-prob", none, 1);
    assert_refused("--throughput-roulette", none, 1);
}

static void test_phi_map_reaches_the_model(void **state)
{
    (void)state;
    scene s;
    load_cornell(&s);
    for (int interval = 0; interval < 2; ++interval) {
        model_settings gs = model_default_settings(MODEL_PRIOR_COSINE);
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
        model_settings gs = model_default_settings(MODEL_PRIOR_COSINE);
        gs.prior_epsilon = wanted[i];
        nf_config cfg = created_config(&s, &gs, NULL);
        assert_true(cfg.prior_epsilon == (wanted[i] < 0.0f ? defaults.prior_epsilon : wanted[i]));
    }
    scene_free(&s);
}

static void test_sh_bands_reach_the_model(void **state)
{
    (void)state;
    scene s;
    load_cornell(&s);
    nf_config defaults;
    nf_config_init(&defaults, NF_PRESET_SMALL);
    const int wanted[] = {-1, 0, 2};
    for (size_t i = 0; i < 3; ++i) {
        model_settings gs = model_default_settings(MODEL_PRIOR_COSINE);
        gs.sh_bands = wanted[i];
        nf_model *model = NULL;
        nf_config cfg = created_config(&s, &gs, &model);
        assert_int_equal(cfg.sh_bands, wanted[i] < 0 ? defaults.sh_bands : (uint32_t)wanted[i]);
        /* A position-only model still samples and evaluates (no SH rows in its input). */
        nf_context ctx = {{0.1f, 0.2f, 0.3f}, {0.0f, 0.0f, 1.0f}, {0.0f, 1.0f, 0.0f}, 0.0f};
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

NFT_TEST_MAIN(
    cmocka_unit_test(test_defaults_are_the_best_configuration),
    cmocka_unit_test(test_each_program_takes_its_protocol),
    cmocka_unit_test(test_variants_are_parsed_and_range_checked),
    cmocka_unit_test(test_isa_is_parsed),
    cmocka_unit_test(test_created_model_carries_the_epsilon),
    cmocka_unit_test(test_phi_map_reaches_the_model),
    cmocka_unit_test(test_sh_bands_reach_the_model),
)
