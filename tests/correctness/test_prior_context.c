/*
 * test_prior_context.c - the context pointer custom prior callbacks receive (model.h,
 * nf_prior_callbacks): the caller's own &ctx[i] for nf_sample, nf_pdf, nf_loss_gradient,
 * nf_train_step and nf_model_prior_pdf, at every batch size (the per-sample and the tiled paths) and
 * on every instruction set the CPU runs; through shading points, the context inside the
 * caller's nf_shading_point. A renderer relies on `ctx - base` being the sample's index.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "nf_test_support.h"
#include "gradient.h"
#include "point_batch.h"
#include "shading_point.h"

/* Every pointer a callback received since the last reset: inside [lo, hi) and on an element
 * boundary of `stride` bytes, or counted as outside. */
typedef struct recorder {
    const char *lo, *hi;
    size_t stride;
    size_t calls, outside;
    const nf_context *first_outside;
} recorder;

static recorder rec;

static void expect_range(const void *base, size_t count, size_t stride)
{
    rec.lo = (const char *)base;
    rec.hi = (const char *)base + count * stride;
    rec.stride = stride;
    rec.calls = rec.outside = 0;
    rec.first_outside = NULL;
}

static void record(const nf_context *ctx)
{
    const char *p = (const char *)ctx;
    rec.calls += 1;
    if (p < rec.lo || p >= rec.hi || (size_t)(p - rec.lo) % rec.stride != 0) {
        if (!rec.outside)
            rec.first_outside = ctx;
        rec.outside += 1;
    }
}

/* The tests' Phong lobe, recording the context pointer. */
static float rec_sample(void *user, const nf_context *ctx, float u0, float u1, float dir[3])
{
    record(ctx);
    return nft_phong_sample(user, ctx, u0, u1, dir);
}

static float rec_pdf(void *user, const nf_context *ctx, const float dir[3])
{
    record(ctx);
    return nft_phong_pdf(user, ctx, dir);
}

static const float exponent = NFT_PHONG_EXPONENT;

static nf_prior_callbacks rec_callbacks(void)
{
    nf_prior_callbacks cb = {rec_sample, rec_pdf, (void *)&exponent};
    return cb;
}

static nf_model *make_model(nf_isa isa)
{
    nf_config cfg;
    nf_config_init(&cfg, NF_PRESET_SMALL);
    nft_apply_phi_map(&cfg);
    cfg.prior = NF_PRIOR_CUSTOM;
    cfg.custom_prior = rec_callbacks();
    cfg.isa = isa;
    nf_model *m = NULL;
    return nf_model_create(&cfg, &m) == NF_OK ? m : NULL;
}

static void check_recorded(const char *what, size_t n)
{
    if (rec.calls == 0 || rec.outside != 0)
        fail_msg("%s (n = %zu): %zu of %zu callback contexts outside the caller's array (first "
                 "%p, array [%p, %p))",
                 what, n, rec.outside, rec.calls, (const void *)rec.first_outside,
                 (const void *)rec.lo, (const void *)rec.hi);
}

#define N_MAX 37u /* two full tiles of 16 and a partial one */

/* Batch sizes: the per-sample paths (1, 2; the gradient's up to 3), the tiled paths from 3
 * (sampling) and 4 (gradient), a full tile and a partial last tile. */
static const size_t sizes[] = {1, 2, 3, 4, 16, N_MAX};

static void check_batch_entry_points(nf_model *m)
{
    static nf_context ctx[N_MAX];
    static float u[2 * N_MAX], dir[3 * N_MAX], pdf[N_MAX], w[N_MAX];
    nft_rng r;
    nft_rng_seed(&r, 11u, 3u);
    for (size_t i = 0; i < N_MAX; ++i) {
        nft_random_context(&r, &ctx[i]);
        u[2 * i] = nft_rng_float(&r);
        u[2 * i + 1] = nft_rng_float(&r);
        w[i] = 0.5f + nft_rng_float(&r);
    }
    size_t count = nf_model_param_count(m);
    float *grad = malloc(count * sizeof(float));
    assert_non_null(grad);
    for (size_t k = 0; k < sizeof sizes / sizeof sizes[0]; ++k) {
        size_t n = sizes[k];
        expect_range(ctx, n, sizeof(nf_context));
        assert_int_equal(nf_sample(m, n, ctx, u, dir, pdf), NF_OK);
        check_recorded("nf_sample", n);

        expect_range(ctx, n, sizeof(nf_context));
        assert_int_equal(nf_pdf(m, n, ctx, dir, pdf), NF_OK);
        check_recorded("nf_pdf", n);

        float loss = 0.0f;
        expect_range(ctx, n, sizeof(nf_context));
        assert_int_equal(nf_loss_gradient(m, n, ctx, dir, w, &loss, grad), NF_OK);
        check_recorded("nf_loss_gradient", n);
    }
    free(grad);

    expect_range(&ctx[5], 1, sizeof(nf_context));
    assert_true(nft_prior_pdf(m, &ctx[5], dir) > 0.0f);
    check_recorded("nf_model_prior_pdf", 1);
}

static void test_batch_calls_pass_the_callers_context(void **state)
{
    (void)state;
    const nf_isa isas[] = {NF_ISA_GENERIC, NF_ISA_AVX2, NF_ISA_AVX512};
    int ran = 0;
    for (size_t k = 0; k < sizeof isas / sizeof isas[0]; ++k) {
        nf_model *m = make_model(isas[k]);
        if (!m)
            continue; /* a CPU without the set (test_kernels checks the refusal) */
        check_batch_entry_points(m);
        nf_model_destroy(m);
        ++ran;
    }
    assert_true(ran >= 1);
}

static void test_training_passes_the_callers_context(void **state)
{
    (void)state;
    nf_model *m = make_model(NF_ISA_AUTO);
    assert_non_null(m);
    static nf_context ctx[N_MAX];
    static float dir[3 * N_MAX], w[N_MAX];
    nft_rng r;
    nft_rng_seed(&r, 12u, 3u);
    nft_random_samples(&r, N_MAX, ctx, dir, w, 0.0f);
    for (size_t k = 0; k < sizeof sizes / sizeof sizes[0]; ++k) {
        size_t n = sizes[k];
        float loss = 0.0f;
        expect_range(ctx, n, sizeof(nf_context));
        assert_int_equal(nf_train_step(m, n, ctx, dir, w, &loss), NF_OK);
        check_recorded("nf_train_step", n);
    }
    assert_int_equal(nf_model_step_count(m), sizeof sizes / sizeof sizes[0]);
    nf_model_destroy(m);
}

/* Shading points: the callbacks receive the point's copy of the context, which lies inside
 * the caller's nf_shading_point, whether the model's callbacks or the point's own are used. */
static void test_points_pass_the_points_context(void **state)
{
    (void)state;
    nf_model *m = make_model(NF_ISA_AUTO);
    assert_non_null(m);
    enum { P = 5 };
    static nf_shading_point points[P];
    nf_context ctx[P];
    float u[2 * P], dir[3 * P], pdf[P];
    nft_rng r;
    nft_rng_seed(&r, 13u, 3u);
    nf_prior_callbacks own = rec_callbacks();
    for (size_t i = 0; i < P; ++i) {
        nft_random_context(&r, &ctx[i]);
        u[2 * i] = nft_rng_float(&r);
        u[2 * i + 1] = nft_rng_float(&r);
        /* even points keep the model's callbacks, odd ones get their own */
        assert_int_equal(nf_point_prepare(m, &ctx[i], i % 2 ? &own : NULL, &points[i]), NF_OK);
    }
    for (size_t i = 0; i < P; ++i) {
        expect_range(&points[i], 1, sizeof(nf_shading_point));
        rec.stride = 1; /* anywhere inside the point */
        assert_int_equal(nf_point_sample(m, &points[i], 1, u + 2 * i, dir + 3 * i, pdf + i), NF_OK);
        check_recorded("nf_point_sample", 1);
        expect_range(&points[i], 1, sizeof(nf_shading_point));
        rec.stride = 1;
        assert_int_equal(nf_point_pdf(m, &points[i], 1, dir + 3 * i, pdf + i), NF_OK);
        check_recorded("nf_point_pdf", 1);
    }
    /* The batch forms, one point per call: point i's callbacks see a context inside points[i]. */
    for (size_t i = 0; i < P; ++i) {
        expect_range(&points[i], 1, sizeof(nf_shading_point));
        rec.stride = 1;
        assert_int_equal(nf_point_sample_batch(m, 1, &points[i], u + 2 * i, dir + 3 * i, pdf + i),
                         NF_OK);
        check_recorded("nf_point_sample_batch", 1);
        expect_range(&points[i], 1, sizeof(nf_shading_point));
        rec.stride = 1;
        assert_int_equal(nf_point_pdf_batch(m, 1, &points[i], dir + 3 * i, pdf + i), NF_OK);
        check_recorded("nf_point_pdf_batch", 1);
    }
    /* and a whole array at once. */
    expect_range(points, P, sizeof(nf_shading_point));
    rec.stride = 1;
    assert_int_equal(nf_point_sample_batch(m, P, points, u, dir, pdf), NF_OK);
    check_recorded("nf_point_sample_batch", P);
    expect_range(points, P, sizeof(nf_shading_point));
    rec.stride = 1;
    assert_int_equal(nf_point_pdf_batch(m, P, points, dir, pdf), NF_OK);
    check_recorded("nf_point_pdf_batch", P);
    nf_model_destroy(m);
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_batch_calls_pass_the_callers_context),
    cmocka_unit_test(test_training_passes_the_callers_context),
    cmocka_unit_test(test_points_pass_the_points_context),
)
