/*
 * test_path_input.c - bad input to nf_path_training_samples (path.h): every refusal is
 * NF_ERROR_INVALID_ARGUMENT with a message naming the function, the vertex and the field, and
 * writes nothing (no sample, no count). Covered: NULL pointers, vertex counts above
 * NF_PATH_MAX_VERTICES and near SIZE_MAX, NaN, +-Inf and negative values in every channel of
 * every RGB field, emitted_mis outside [0, 1], and every refused context (tests/support's
 * nft_bad_context) and direction of a learned vertex. Also what is *not* refused: a
 * non-learned vertex's context, direction and f_over_p are not read, and -0 is >= 0.
 */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include <float.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

#include <nisflow/nisflow.h>

#include "nf_test_support.h"

/* The floats of one context, which the sentinel checks walk. */
#define NF_CTX_FLOATS (sizeof(nf_context) / sizeof(float))

#define N 5
#define CAP 8
#define SIZE_SENTINEL ((size_t)0x5eed5eedu)

/* A valid path of N vertices, every one learned and lit, so that any refusal is the bad
 * field's doing. */
static void good_path(nf_path_vertex *v)
{
    memset(v, 0, N * sizeof *v);
    for (int j = 0; j < N; ++j) {
        v[j].ctx = nft_context(0.1f * (float)j, 0.2f, 0.3f, 0.0f, 0.0f, 1.0f, 0.0f, 0.6f, 0.8f);
        v[j].dir[0] = 0.6f;
        v[j].dir[2] = 0.8f;
        for (int c = 0; c < 3; ++c) {
            v[j].f_over_p[c] = 0.5f;
            v[j].beta[c] = 0.5f;
            v[j].direct[c] = 0.25f;
            v[j].emitted[c] = 1.0f;
        }
        v[j].emitted_mis = 0.5f;
        v[j].learn = 1;
    }
}

typedef struct outputs {
    nf_context ctx[CAP];
    float dir[3 * CAP];
    float weight[CAP];
    size_t vertex[CAP];
    size_t count;
} outputs;

static void fill(outputs *o)
{
    nft_fill_sentinel((float *)o->ctx, NF_CTX_FLOATS * CAP);
    nft_fill_sentinel(o->dir, 3 * CAP);
    nft_fill_sentinel(o->weight, CAP);
    for (int i = 0; i < CAP; ++i)
        o->vertex[i] = SIZE_SENTINEL;
    o->count = SIZE_SENTINEL;
}

static void assert_untouched(const outputs *o)
{
    assert_true(nft_untouched((const float *)o->ctx, NF_CTX_FLOATS * CAP));
    assert_true(nft_untouched(o->dir, 3 * CAP));
    assert_true(nft_untouched(o->weight, CAP));
    for (int i = 0; i < CAP; ++i)
        assert_int_equal(o->vertex[i], SIZE_SENTINEL);
    assert_int_equal(o->count, SIZE_SENTINEL);
}

/* The call on v refuses, names the function and every string in `expect`, writes nothing. */
static void assert_refused(const nf_path_vertex *v, size_t n, const char *expect1,
                           const char *expect2)
{
    outputs o;
    fill(&o);
    nf_status st = nf_path_training_samples(n, v, CAP, o.ctx, o.dir, o.weight, o.vertex, &o.count);
    const char *msg = nf_last_error_message();
    if (st != NF_ERROR_INVALID_ARGUMENT)
        fail_msg("status %d (expected invalid argument) for %s %s", (int)st, expect1,
                 expect2 ? expect2 : "");
    assert_non_null(strstr(msg, "nf_path_training_samples"));
    if (!strstr(msg, expect1) || (expect2 && !strstr(msg, expect2)))
        fail_msg("message \"%s\" does not name \"%s\" / \"%s\"", msg, expect1,
                 expect2 ? expect2 : "");
    assert_untouched(&o);
}

static void assert_accepted(const nf_path_vertex *v, size_t n)
{
    outputs o;
    fill(&o);
    assert_int_equal(
        nf_path_training_samples(n, v, CAP, o.ctx, o.dir, o.weight, o.vertex, &o.count), NF_OK);
    assert_true(o.count <= n);
}

static void test_null_and_counts(void **state)
{
    (void)state;
    nf_path_vertex v[N];
    good_path(v);
    outputs o;
    fill(&o);
    assert_int_equal(nf_path_training_samples(N, v, CAP, o.ctx, o.dir, o.weight, o.vertex, NULL),
                     NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "count_out"));
    assert_refused(NULL, N, "vertices is NULL", NULL);

    const char *names[3] = {"ctx_out", "dir_out", "weight_out"};
    for (int k = 0; k < 3; ++k) {
        fill(&o);
        nf_status st =
            nf_path_training_samples(N, v, CAP, k == 0 ? NULL : o.ctx, k == 1 ? NULL : o.dir,
                                     k == 2 ? NULL : o.weight, o.vertex, &o.count);
        assert_int_equal(st, NF_ERROR_INVALID_ARGUMENT);
        assert_non_null(strstr(nf_last_error_message(), names[k]));
        assert_untouched(&o);
    }

    const size_t absurd[3] = {NF_PATH_MAX_VERTICES + 1u, SIZE_MAX / sizeof(nf_path_vertex) + 1u,
                              SIZE_MAX};
    for (int k = 0; k < 3; ++k)
        assert_refused(v, absurd[k], "vertex_count", NULL);
    /* Exactly NF_PATH_MAX_VERTICES zeroed vertices are fine (and give nothing). */
    static nf_path_vertex many[NF_PATH_MAX_VERTICES];
    assert_accepted(many, NF_PATH_MAX_VERTICES);
}

static void test_bad_rgb_fields(void **state)
{
    (void)state;
    const float bad[5] = {NAN, INFINITY, -INFINITY, -1.0f, -FLT_TRUE_MIN};
    const char *field_names[4] = {"direct", "beta", "emitted", "f_over_p"};
    nf_path_vertex v[N];
    char vname[32], fname[32];
    int refused = 0;
    for (int j = 0; j < N; ++j)
        for (int f = 0; f < 4; ++f)
            for (int c = 0; c < 3; ++c)
                for (int b = 0; b < 5; ++b) {
                    good_path(v);
                    float *field = f == 0   ? v[j].direct
                                   : f == 1 ? v[j].beta
                                   : f == 2 ? v[j].emitted
                                            : v[j].f_over_p;
                    field[c] = bad[b];
                    snprintf(vname, sizeof vname, "vertices[%d]", j);
                    snprintf(fname, sizeof fname, "%s[%d]", field_names[f], c);
                    assert_refused(v, N, vname, fname);
                    ++refused;
                }
    assert_int_equal(refused, N * 4 * 3 * 5);

    /* -0 is >= 0: accepted. */
    good_path(v);
    v[2].beta[1] = -0.0f;
    v[3].direct[0] = -0.0f;
    assert_accepted(v, N);
}

static void test_bad_emitted_mis(void **state)
{
    (void)state;
    const float bad[6] = {NAN, INFINITY, -INFINITY, -0.25f, 1.0f + FLT_EPSILON, 2.0f};
    nf_path_vertex v[N];
    for (int j = 0; j < N; ++j)
        for (int b = 0; b < 6; ++b) {
            good_path(v);
            v[j].emitted_mis = bad[b];
            char vname[32];
            snprintf(vname, sizeof vname, "vertices[%d]", j);
            assert_refused(v, N, vname, "emitted_mis");
        }
    good_path(v);
    v[0].emitted_mis = 0.0f;
    v[1].emitted_mis = 1.0f;
    assert_accepted(v, N);
}

/* A learned vertex needs a valid context and direction; a vertex that learns nothing may
 * leave them (and f_over_p) as anything: they are not read. */
static void test_learned_vertex_context_and_direction(void **state)
{
    (void)state;
    nf_path_vertex v[N];
    good_path(v);
    const nf_context good = v[3].ctx;
    for (int which = 0; which < NFT_BAD_CONTEXTS; ++which) {
        char what[96];
        good_path(v);
        v[3].ctx = nft_bad_context(&good, which, what, sizeof what);
        /* nft_bad_context's order: 27 non-finite components of position, normal, wo, then
         * tiny normals and wo's alternately. */
        int field = which < 27 ? which / 9 : 1 + (which - 27) % 2;
        const char *part = field == 0 ? "ctx.position" : field == 1 ? "ctx.normal" : "ctx.wo";
        if (which == 27)
            part = "ctx.phase_g"; /* a zero normal: a vertex in a medium, with phase_g NaN */
        assert_true(what[0] != '\0');
        assert_refused(v, N, "vertices[3]", part);
        /* The same context on a vertex that learns nothing is not read. */
        v[3].learn = 0;
        assert_accepted(v, N);
    }

    const float bad_dirs[6][3] = {{0.0f, 0.0f, 0.0f},      {1e-16f, 1e-16f, 1e-16f},
                                  {NAN, 0.0f, 1.0f},       {0.0f, INFINITY, 0.0f},
                                  {0.0f, 0.0f, -INFINITY}, {1e-38f, 0.0f, 0.0f}};
    for (int k = 0; k < 6; ++k) {
        good_path(v);
        memcpy(v[4].dir, bad_dirs[k], sizeof v[4].dir);
        assert_refused(v, N, "vertices[4]", "dir");
        v[4].learn = 0;
        assert_accepted(v, N);
    }

    /* A specular vertex with garbage in its sample fields. */
    good_path(v);
    v[1].learn = 0;
    v[1].ctx.normal[0] = NAN;
    v[1].dir[2] = INFINITY;
    v[1].f_over_p[0] = -1.0f;
    assert_accepted(v, N);
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_null_and_counts),
    cmocka_unit_test(test_bad_rgb_fields),
    cmocka_unit_test(test_bad_emitted_mis),
    cmocka_unit_test(test_learned_vertex_context_and_direction),
)
