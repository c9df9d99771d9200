/*
 * test_deprecated.c - the names 0.8.1 renamed (CHANGELOG.md) still answer as the new ones,
 * until 0.10 removes them: same results, same statuses.
 */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "nf_test_support.h"

/* The calls below are the deprecated ones on purpose. */
#if defined(__GNUC__) || defined(__clang__)
#pragma GCC diagnostic ignored "-Wdeprecated-declarations"
#endif

static nf_context test_context(void)
{
    nf_context c = {{0.2f, -0.4f, 0.1f}, {0.0f, 0.6f, 0.8f}, {0.3f, 0.0f, 0.95f}, 0.0f};
    return c;
}

/* The model's names: parameters, their count, the learning rate, the configuration. */
static void test_model_names(void **state)
{
    nf_model *m = *state;
    assert_int_equal(nft_randomize_params(m, 0.3f, 5), NF_OK);
    const size_t n = nf_model_param_count(m);
    assert_true(n > 0 && nf_param_count(m) == n);
    float *a = malloc(n * sizeof *a), *b = malloc(n * sizeof *b);
    assert_non_null(a);
    assert_non_null(b);
    assert_int_equal(nf_model_get_params(m, a), NF_OK);
    assert_int_equal(nf_get_params(m, b), NF_OK);
    assert_memory_equal(a, b, n * sizeof *a);
    b[0] += 0.5f;
    assert_int_equal(nf_set_params(m, b), NF_OK);
    assert_int_equal(nf_model_get_params(m, a), NF_OK);
    assert_true(a[0] == b[0]);
    b[1] = NAN; /* refused as by the new name, the model unchanged */
    assert_int_equal(nf_set_params(m, b), NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_get_params(m, b), NF_OK);
    assert_memory_equal(a, b, n * sizeof *a);
    assert_int_equal(nf_set_learning_rate(m, 1e-3f), NF_OK);
    assert_int_equal(nf_set_learning_rate(m, -1.0f), NF_ERROR_INVALID_ARGUMENT);
    nf_config x, y;
    assert_int_equal(nf_model_get_config(m, &x), NF_OK);
    assert_int_equal(nf_model_config(m, &y), NF_OK);
    assert_memory_equal(&x, &y, sizeof x);
    assert_int_equal(nf_model_config(m, NULL), NF_ERROR_INVALID_ARGUMENT);
    free(a);
    free(b);
}

/* nf_prior_pdf is nf_model_prior_pdf's density, -1 where it refuses. */
static void test_prior_pdf(void **state)
{
    nf_model *m = *state;
    nf_context c = test_context();
    const float dir[3] = {0.1f, 0.5f, 0.8f}, zero[3] = {0.0f, 0.0f, 0.0f};
    float q = 0.0f;
    assert_int_equal(nf_model_prior_pdf(m, &c, dir, &q), NF_OK);
    assert_true(q > 0.0f && nf_prior_pdf(m, &c, dir) == q);
    assert_true(nf_prior_pdf(m, &c, zero) == -1.0f);
    assert_true(nf_prior_pdf(NULL, &c, dir) == -1.0f);
}

/* The batch forms of the shading points, one direction per point. */
static void test_point_batches(void **state)
{
    nf_model *m = *state;
    assert_int_equal(nft_randomize_params(m, 0.3f, 9), NF_OK);
    nf_shading_point p[2];
    nf_context c[2] = {test_context(), test_context()};
    c[1].position[0] = 0.7f;
    for (int i = 0; i < 2; ++i)
        assert_int_equal(nf_point_prepare(m, &c[i], NULL, &p[i]), NF_OK);
    const float u[4] = {0.1f, 0.2f, 0.7f, 0.9f};
    float d0[6], d1[6], p0[2], p1[2], e0[2], e1[2];
    assert_int_equal(nf_point_sample_batch(m, 2, p, u, d0, p0), NF_OK);
    assert_int_equal(nf_points_sample(m, 2, p, u, d1, p1), NF_OK);
    assert_memory_equal(d0, d1, sizeof d0);
    assert_memory_equal(p0, p1, sizeof p0);
    assert_int_equal(nf_point_pdf_batch(m, 2, p, d0, e0), NF_OK);
    assert_int_equal(nf_points_pdf(m, 2, p, d0, e1), NF_OK);
    assert_memory_equal(e0, e1, sizeof e0);
    assert_int_equal(nf_points_pdf(m, 2, NULL, d0, e1), NF_ERROR_INVALID_ARGUMENT);
}

/* The depth of a guided kind is the kind itself: every depth, then 1 and 2; 0 beyond. */
static void test_depth_of(void **state)
{
    (void)state;
    assert_int_equal(NF_GUIDE_DEPTHS, 3);
    for (uint32_t k = 0; k < NF_GUIDE_DEPTHS; ++k)
        assert_int_equal(nf_guide_depth_of(k), k);
    assert_int_equal(nf_guide_depth_of(3), 0);
    assert_int_equal(nf_guide_depth_of(UINT32_MAX), 0);
}

NFT_TEST_MAIN(
    NFT_WITH_MODEL(test_model_names),
    NFT_WITH_MODEL(test_prior_pdf),
    NFT_WITH_MODEL(test_point_batches),
    cmocka_unit_test(test_depth_of),
)
