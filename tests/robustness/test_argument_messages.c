/*
 * test_argument_messages.c - what a caller learns from a refused call: the message names the
 * argument that was NULL, calls with n = 0 still check the model and the point they are
 * given, and a config nobody filled points at nf_config_init.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include <cmocka.h>

#include "nf_test_support.h"
#include "point_batch.h"
#include "shading_point.h"

static void assert_refused_naming(nf_status got, nf_status want, const char *text)
{
    assert_int_equal(got, want);
    if (!strstr(nf_last_error_message(), text))
        fail_msg("the message '%s' does not say '%s'", nf_last_error_message(), text);
}

static void test_null_arguments_are_named(void **state)
{
    nf_model *m = *state;
    nf_context ctx = nft_context(0.5f, 0.5f, 0.5f, 0, 0, 1, 0, 0, 1);
    float u[2] = {0.5f, 0.5f}, dir[3] = {0, 0, 1}, pdf;
    nf_shading_point sp;
    assert_int_equal(nf_point_prepare(m, &ctx, NULL, &sp), NF_OK);
    const nf_status bad = NF_ERROR_INVALID_ARGUMENT;
    assert_refused_naming(nf_sample(m, 1, &ctx, u, NULL, &pdf), bad, "nf_sample: dir is NULL");
    assert_refused_naming(nf_sample(m, 1, &ctx, NULL, dir, &pdf), bad, "nf_sample: u is NULL");
    assert_refused_naming(nf_pdf(m, 1, NULL, dir, &pdf), bad, "nf_pdf: ctx is NULL");
    assert_refused_naming(nf_pdf(m, 1, &ctx, dir, NULL), bad, "nf_pdf: pdf is NULL");
    assert_refused_naming(nf_point_prepare(m, &ctx, NULL, NULL), bad, "point is NULL");
    assert_refused_naming(nf_point_sample(m, &sp, 1, NULL, dir, &pdf), bad, "u is NULL");
    assert_refused_naming(nf_point_pdf(m, &sp, 1, dir, NULL), bad, "pdf is NULL");
    assert_refused_naming(nf_point_pdf_batch(m, 1, NULL, dir, &pdf), bad, "points is NULL");
    assert_refused_naming(nf_train_step(m, 1, &ctx, dir, NULL, NULL), bad, "weight is NULL");
    assert_refused_naming(nf_model_get_params(m, NULL), bad, "params is NULL");
    assert_refused_naming(nf_model_set_params(NULL, u), bad, "m is NULL");
}

static void test_empty_calls_check_the_rest(void **state)
{
    nf_model *m = *state;
    nf_context ctx = nft_context(0.5f, 0.5f, 0.5f, 0, 0, 1, 0, 0, 1);
    nf_shading_point sp;
    assert_int_equal(nf_point_prepare(m, &ctx, NULL, &sp), NF_OK);
    /* n = 0 with good arguments (arrays may be NULL) is a no-op... */
    assert_int_equal(nf_sample(m, 0, NULL, NULL, NULL, NULL), NF_OK);
    assert_int_equal(nf_point_pdf(m, &sp, 0, NULL, NULL), NF_OK);
    /* ...but the model and the point are checked. */
    assert_refused_naming(nf_sample(NULL, 0, NULL, NULL, NULL, NULL), NF_ERROR_INVALID_ARGUMENT,
                          "m is NULL");
    assert_refused_naming(nf_pdf(NULL, 0, NULL, NULL, NULL), NF_ERROR_INVALID_ARGUMENT,
                          "m is NULL");
    assert_refused_naming(nf_point_sample(m, NULL, 0, NULL, NULL, NULL),
                          NF_ERROR_INVALID_ARGUMENT, "point is NULL");
    nf_shading_point junk;
    memset(&junk, 0, sizeof junk);
    assert_refused_naming(nf_point_pdf(m, &junk, 0, NULL, NULL), NF_ERROR_INVALID_ARGUMENT,
                          "nf_point_prepare first");
    /* A point made stale by a step is stale with n = 0 too. */
    float dir[3] = {0, 0, 1}, w = 1.0f;
    assert_int_equal(nf_train_step(m, 1, &ctx, dir, &w, NULL), NF_OK);
    assert_refused_naming(nf_point_sample(m, &sp, 0, NULL, NULL, NULL), NF_ERROR_STALE,
                          "prepare it again");
}

static void test_zeroed_config_points_at_init(void **state)
{
    (void)state;
    nf_config cfg;
    memset(&cfg, 0, sizeof cfg);
    nf_model *m = NULL;
    assert_refused_naming(nf_model_create(&cfg, &m), NF_ERROR_INVALID_ARGUMENT,
                          "nf_config_init");
    assert_null(m);
}

NFT_TEST_MAIN(
    NFT_WITH_MODEL(test_null_arguments_are_named),
    NFT_WITH_MODEL(test_empty_calls_check_the_rest),
    cmocka_unit_test(test_zeroed_config_points_at_init),
)
