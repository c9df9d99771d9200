/*
 * test_medium_input.c - bad contexts at points in a participating medium (normal exactly
 * zero, nisflow/model.h): phase_g NaN, infinite or beyond NF_PHASE_G_MAX there, and normals
 * that are neither zero nor usable (NaN, too short), in the last element of a batch that
 * mixes valid medium and surface contexts. Every entry point that takes contexts refuses
 * them with NF_ERROR_INVALID_ARGUMENT and a message naming the index and the field, writes
 * no output and leaves the model (parameters, bytes, step count) and the guide's store as
 * they were. And what is not refused: a surface's phase_g, whatever it holds.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <nisflow/nisflow.h>

#include "nf_test_support.h"
#include "gradient.h"
#include "shading_point.h"

enum { N = 24 }; /* above the tiled threshold: the tile and the per-sample paths both validate */

typedef struct batch {
    nf_context ctx[N];
    float u[2 * N], dir[3 * N], weight[N];
} batch;

/* Even elements in a medium (g across its range), odd ones on surfaces whose phase_g holds
 * garbage that must never matter. */
static void make_batch(batch *b)
{
    nft_rng r;
    nft_rng_seed(&r, 17u, 4u);
    for (int i = 0; i < N; ++i) {
        nft_random_context(&r, &b->ctx[i]);
        if (i % 2 == 0) {
            memset(b->ctx[i].normal, 0, sizeof b->ctx[i].normal);
            b->ctx[i].phase_g = -NF_PHASE_G_MAX + 2.0f * NF_PHASE_G_MAX * (float)i / N;
        } else {
            const float garbage[3] = {NAN, INFINITY, 1e30f};
            b->ctx[i].phase_g = garbage[(i / 2) % 3];
        }
        b->u[2 * i] = nft_rng_float(&r);
        b->u[2 * i + 1] = nft_rng_float(&r);
        nft_random_unit_vector(&r, b->dir + 3 * i);
        b->weight[i] = 0.5f + nft_rng_float(&r);
    }
}

/* The bad last contexts: (a point in a medium with) phase_g bad, or a bad normal. */
enum { BAD_COUNT = 9 };

static nf_context bad_context(const nf_context *good, int which, const char **field)
{
    nf_context c = *good;
    memset(c.normal, 0, sizeof c.normal);
    const float bad_g[6] = {NAN, INFINITY, -INFINITY, 1.0f, -0.995f, 1e30f};
    *field = "phase_g";
    if (which < 6) {
        c.phase_g = bad_g[which];
        return c;
    }
    c.phase_g = 0.5f;
    *field = "normal";
    if (which == 6)
        c.normal[1] = NAN; /* the other components zero: still not a medium */
    else if (which == 7)
        c.normal[2] = 1e-20f; /* non-zero but too short to normalize */
    else
        c.normal[0] = -INFINITY;
    return c;
}

/* The call failed as it must: status, and a message of its own naming the element. */
static void expect_refused(nf_status st, const char *call, int which, size_t at,
                           const char *field)
{
    const char *msg = nf_last_error_message();
    char index[32];
    snprintf(index, sizeof index, "[%zu]", at);
    if (st != NF_ERROR_INVALID_ARGUMENT || !strstr(msg, field) || !strstr(msg, index))
        fail_msg("%s with bad context %d: status %s, message \"%s\" (wanted %s%s)", call, which,
                 nf_status_string(st), msg, index, field);
}

static void test_batches_refuse_bad_medium_contexts(void **state)
{
    (void)state;
    static batch good, bad;
    make_batch(&good);
    nf_model *m = nft_make_model(NF_PRESET_SMALL, NF_PRIOR_COSINE);
    assert_int_equal(nft_randomize_params(m, 0.3f, 5u), NF_OK);
    static float dir[3 * N], pdf[N];
    size_t count = nf_model_param_count(m);
    float *grad = malloc(count * sizeof *grad);
    assert_non_null(grad);
    /* the good batch works everywhere (so the refusals below are the bad element's) */
    assert_int_equal(nf_sample(m, N, good.ctx, good.u, dir, pdf), NF_OK);
    assert_int_equal(nf_pdf(m, N, good.ctx, good.dir, pdf), NF_OK);
    for (int i = 0; i < N; ++i)
        assert_true(isfinite(pdf[i]) && pdf[i] > 0.0f);
    assert_int_equal(nf_loss_gradient(m, N, good.ctx, good.dir, good.weight, NULL, grad), NF_OK);
    nft_snapshot snap = nft_snapshot_of(m);
    for (int which = 0; which < BAD_COUNT; ++which) {
        const char *field;
        bad = good;
        bad.ctx[N - 1] = bad_context(&good.ctx[N - 2], which, &field);
        for (size_t n = 1; n <= N; n += N - 1) { /* alone, and at the end of a batch */
            const nf_context *ctx = bad.ctx + N - n;
            nft_fill_sentinel(dir, 3 * N);
            nft_fill_sentinel(pdf, N);
            expect_refused(nf_sample(m, n, ctx, bad.u, dir, pdf), "nf_sample", which, n - 1, field);
            assert_true(nft_untouched(dir, 3 * N) && nft_untouched(pdf, N));
            expect_refused(nf_pdf(m, n, ctx, bad.dir, pdf), "nf_pdf", which, n - 1, field);
            assert_true(nft_untouched(pdf, N));
            expect_refused(nf_loss_gradient(m, n, ctx, bad.dir, bad.weight, NULL, grad),
                           "nf_loss_gradient", which, n - 1, field);
            expect_refused(nf_train_step(m, n, ctx, bad.dir, bad.weight, NULL), "nf_train_step",
                           which, n - 1, field);
            assert_true(nft_snapshot_equal(m, &snap));
        }
        nf_shading_point sp, before;
        assert_int_equal(nf_point_prepare(m, &good.ctx[0], NULL, &sp), NF_OK);
        before = sp;
        nf_status st = nf_point_prepare(m, &bad.ctx[N - 1], NULL, &sp);
        assert_int_equal(st, NF_ERROR_INVALID_ARGUMENT);
        assert_non_null(strstr(nf_last_error_message(), field));
        assert_memory_equal(&sp, &before, sizeof sp);
        assert_true(nft_prior_pdf(m, &bad.ctx[N - 1], good.dir) == -1.0f);
    }
    nft_snapshot_free(&snap);
    free(grad);
    nf_model_destroy(m);
}

/* The guide's store takes contexts too: a refused nf_guide_add_samples adds nothing. */
static void test_guide_refuses_bad_medium_contexts(void **state)
{
    (void)state;
    static batch good, bad;
    make_batch(&good);
    nf_model *m = nft_make_model(NF_PRESET_SMALL, NF_PRIOR_COSINE);
    nf_guide_config gc;
    nf_guide_config_init(&gc);
    nf_guide *g = NULL;
    assert_int_equal(nf_guide_create(m, &gc, &g), NF_OK);
    assert_int_equal(nf_guide_add_samples(g, N, NULL, good.ctx, good.dir, good.weight, NULL),
                     NF_OK);
    for (int which = 0; which < BAD_COUNT; ++which) {
        const char *field;
        bad = good;
        bad.ctx[N - 1] = bad_context(&good.ctx[N - 2], which, &field);
        expect_refused(nf_guide_add_samples(g, N, NULL, bad.ctx, bad.dir, bad.weight, NULL),
                       "nf_guide_add_samples", which, N - 1, field);
    }
    assert_int_equal(nf_guide_train_pass(g, NULL, NULL, NULL), NF_OK);
    nf_guide_stats s;
    assert_int_equal(nf_guide_get_stats(g, &s), NF_OK);
    assert_true(s.samples == N); /* the good call's samples only */
    nf_guide_destroy(g);
    nf_model_destroy(m);
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_batches_refuse_bad_medium_contexts),
    cmocka_unit_test(test_guide_refuses_bad_medium_contexts),
)
