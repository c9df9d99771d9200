/*
 * test_path.c - nf_path_training_samples (path.h): the training samples of a path against an
 * independent per-sample computation.
 *
 * The library walks the path backwards (S <- D + beta (H E + S)). The reference here writes
 * the radiance arriving along w_j forwards, as a sum over the later vertices k of what each
 * adds, carried back by the product of the throughput factors between them:
 *
 *     L_i(w_j) = E_j + sum_{k > j} (prod_{j < m < k} beta_m) (D_k + beta_k H_k E_k)
 *
 * and the weight as mean_c(f_over_p_j[c] L_i[c]), with no 1/q of vertex j itself (path.h's
 * Russian roulette convention). Covered: hand-made paths whose weights are worked out in the
 * comments (delta vertices, Russian roulette, MIS weights below 1, emission at several
 * depths), random paths of every shape, paths with no learned vertex, zero-weight samples
 * skipped, overflow and underflow, the full-buffer status writing nothing and the count query,
 * vertex order and vertex_out, and that nf_train_step accepts what the call returns. Bad
 * input is tests/robustness/test_path_input.c.
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

#define MAX_V 64
#define SIZE_SENTINEL ((size_t)0x5eed5eedu)

/* The library rounds a double-precision weight to float once (at most 2^-24 relative); its
 * double walk and this double reference differ by summation order, some 1e-15 relative for
 * these path lengths. 2^-23 relative is twice the float rounding and far below any mistake
 * in the formula (a missing 1/q, H or E changes weights by tens of percent). */
#define REL_TOL (1.0 / 8388608.0)

static void set_rgb(float v[3], float r, float g, float b)
{
    v[0] = r;
    v[1] = g;
    v[2] = b;
}

static void set_gray(float v[3], float x) { set_rgb(v, x, x, x); }

/* A learned vertex with a valid context and direction (distinct per index, so that the
 * copies can be told apart). */
static void make_learned(nf_path_vertex *v, int index)
{
    float t = (float)index;
    v->ctx = nft_context(0.1f * t, 0.2f, -0.3f, 0.0f, 0.0f, 1.0f, 0.6f, 0.0f, 0.8f);
    set_rgb(v->dir, 0.25f + 0.01f * t, -0.5f, 0.75f);
    v->learn = 1;
}

/* n learned vertices, zeroed but for gray f_over_p and beta. */
static void make_learned_path(nf_path_vertex *v, int n, float f_over_p, float beta)
{
    memset(v, 0, (size_t)n * sizeof *v);
    for (int j = 0; j < n; ++j) {
        make_learned(&v[j], j);
        set_gray(v[j].f_over_p, f_over_p);
        set_gray(v[j].beta, beta);
    }
}

/* The forward reference: the expected weight of vertex j in double. */
static double reference_weight(const nf_path_vertex *v, size_t n, size_t j)
{
    double w = 0.0;
    for (int c = 0; c < 3; ++c) {
        double li = (double)v[j].emitted_mis * v[j].emitted[c];
        for (size_t k = j + 1; k < n; ++k) {
            double carry = 1.0;
            for (size_t m = j + 1; m < k; ++m)
                carry *= v[m].beta[c];
            li += carry *
                  (v[k].direct[c] + (double)v[k].beta[c] * v[k].emitted_mis * v[k].emitted[c]);
        }
        w += (double)v[j].f_over_p[c] * li;
    }
    return w / 3.0;
}

typedef struct result {
    nf_context ctx[MAX_V];
    float dir[3 * MAX_V];
    float weight[MAX_V];
    size_t vertex[MAX_V];
    size_t count;
} result;

static nf_status run(const nf_path_vertex *v, size_t n, size_t capacity, result *r)
{
    nft_fill_sentinel((float *)r->ctx, NF_CTX_FLOATS * MAX_V);
    nft_fill_sentinel(r->dir, 3 * MAX_V);
    nft_fill_sentinel(r->weight, MAX_V);
    for (size_t i = 0; i < MAX_V; ++i)
        r->vertex[i] = SIZE_SENTINEL;
    r->count = SIZE_SENTINEL;
    return nf_path_training_samples(n, v, capacity, r->ctx, r->dir, r->weight, r->vertex,
                                    &r->count);
}

static void assert_rel_close(double got, double want)
{
    double err = fabs(got - want), tol = REL_TOL * fabs(want);
    if (!(err <= tol))
        fail_msg("weight %.9g, expected %.9g (relative error %.3g)", got, want, err / fabs(want));
}

/* Every written sample against the reference, the expected set of vertices in order, and
 * nothing written past count. */
static void check_against_reference(const nf_path_vertex *v, size_t n, const result *r)
{
    size_t expected = 0;
    for (size_t j = 0; j < n; ++j) {
        if (!v[j].learn)
            continue;
        double w = reference_weight(v, n, j);
        /* Weights beyond FLT_MAX or rounding to 0 in float are dropped (path.h). */
        if (!(w > 0.0) || w > (double)FLT_MAX || (float)w == 0.0f)
            continue;
        assert_true(expected < r->count);
        assert_int_equal(r->vertex[expected], j);
        assert_memory_equal(&r->ctx[expected], &v[j].ctx, sizeof(nf_context));
        assert_memory_equal(&r->dir[3 * expected], v[j].dir, 3 * sizeof(float));
        assert_true(isfinite(r->weight[expected]) && r->weight[expected] > 0.0f);
        assert_rel_close(r->weight[expected], w);
        ++expected;
    }
    assert_int_equal(r->count, expected);
    assert_true(nft_untouched((const float *)(r->ctx + expected), NF_CTX_FLOATS * (MAX_V - expected)));
    assert_true(nft_untouched(r->dir + 3 * expected, 3 * (MAX_V - expected)));
    assert_true(nft_untouched(r->weight + expected, MAX_V - expected));
    for (size_t i = expected; i < MAX_V; ++i)
        assert_int_equal(r->vertex[i], SIZE_SENTINEL);
}

/* ---- hand-made paths ------------------------------------------------------------------------ */

/* Three vertices, gray:
 *   v0 diffuse, learned: f_over_p = beta = 0.5, direct 0.1, its ray finds no emission;
 *   v1 a mirror (delta, not learned): beta 0.8, no light sampling, its ray hits an emitter of
 *      radiance 1 with MIS weight 1 (after a delta bounce only the scattering could find it);
 *   v2 on that emitter, learned, Russian roulette with q = 0.5: f_over_p 0.25, beta 0.5;
 *      direct 0.2; its ray escapes to an environment of radiance 2, MIS weight 0.5.
 * Backward: j = 2: L_i = 2 + 0 = 2, weight 0.25 * 2 = 0.5;  S = 0.2 + 0.5 (0.5 * 2) = 0.7.
 *           j = 1: S = 0 + 0.8 (1 * 1 + 0.7) = 1.36.
 *           j = 0: L_i = 0 + 1.36, weight 0.5 * 1.36 = 0.68.
 * With 1/q in its own weight, v2 would give 1.0; without the later 1/q in S, v0 would give
 * 0.5 * 0.8 * (1 + 0.2 + 0.25 * 0.5 * 2) = 0.58. */
static void test_hand_made_gray(void **state)
{
    (void)state;
    nf_path_vertex v[3];
    memset(v, 0, sizeof v);
    make_learned(&v[0], 0);
    set_gray(v[0].f_over_p, 0.5f);
    set_gray(v[0].beta, 0.5f);
    set_gray(v[0].direct, 0.1f);
    v[0].emitted_mis = 1.0f;
    set_gray(v[1].beta, 0.8f);
    set_gray(v[1].emitted, 1.0f);
    v[1].emitted_mis = 1.0f;
    make_learned(&v[2], 2);
    set_gray(v[2].f_over_p, 0.25f);
    set_gray(v[2].beta, 0.5f);
    set_gray(v[2].direct, 0.2f);
    set_gray(v[2].emitted, 2.0f);
    v[2].emitted_mis = 0.5f;

    result r;
    assert_int_equal(run(v, 3, MAX_V, &r), NF_OK);
    assert_int_equal(r.count, 2);
    assert_int_equal(r.vertex[0], 0);
    assert_int_equal(r.vertex[1], 2);
    assert_rel_close(r.weight[0], 0.68);
    assert_rel_close(r.weight[1], 0.25);
    check_against_reference(v, 3, &r);
}

/* Colour: the weight is the mean of the channels of f_over_p * L_i, not the product of means.
 * Two vertices: v0 learned, f_over_p (1, 0, 0) (a red surface), beta (2, 0, 0);
 * v1 ends the path (beta 0), direct (0, 3, 0) (green light only), emitted by v0's ray
 * (0.5, 0.5, 0.5) with H = 0.25. L_i(w_0) = E_0 + S_1 = (0.5, 3.5, 0.5);
 * weight = mean(1 * 0.5, 0, 0) = 1/6. A luminance-of-products mistake would give
 * mean(f) mean(L_i) = (1/3)(1.5) = 0.5. */
static void test_hand_made_colour(void **state)
{
    (void)state;
    nf_path_vertex v[2];
    memset(v, 0, sizeof v);
    make_learned(&v[0], 0);
    set_rgb(v[0].f_over_p, 1.0f, 0.0f, 0.0f);
    set_rgb(v[0].beta, 2.0f, 0.0f, 0.0f);
    set_gray(v[0].emitted, 0.5f);
    v[0].emitted_mis = 0.25f;
    set_rgb(v[1].direct, 0.0f, 3.0f, 0.0f);

    result r;
    assert_int_equal(run(v, 2, MAX_V, &r), NF_OK);
    assert_int_equal(r.count, 1);
    assert_int_equal(r.vertex[0], 0);
    assert_rel_close(r.weight[0], 1.0 / 24.0);
    check_against_reference(v, 2, &r);
}

/* Emission found at several depths, MIS-weighted at its own vertex as upstream (the rule
 * that weighed it only upstream would give 1.0625, 1.625, 2, 2). Four learned vertices,
 * gray, f_over_p = beta = 0.5, H = 0.5 everywhere, emission E_j = j + 1 found by each ray, no
 * direct light.
 *   S_4 = 0
 *   j = 3: L_i = 0.5 * 4 = 2,          weight 1;      S = 0.5 * 2 = 1
 *   j = 2: L_i = 0.5 * 3 + 1 = 2.5,    weight 1.25;   S = 1.25
 *   j = 1: L_i = 0.5 * 2 + 1.25,       weight 1.125;  S = 1.125
 *   j = 0: L_i = 0.5 * 1 + 1.125,      weight 0.8125 */
static void test_emission_at_several_depths(void **state)
{
    (void)state;
    nf_path_vertex v[4];
    make_learned_path(v, 4, 0.5f, 0.5f);
    for (int j = 0; j < 4; ++j) {
        set_gray(v[j].emitted, (float)(j + 1));
        v[j].emitted_mis = 0.5f;
    }
    result r;
    assert_int_equal(run(v, 4, MAX_V, &r), NF_OK);
    assert_int_equal(r.count, 4);
    const double want[4] = {0.8125, 1.125, 1.25, 1.0};
    for (int j = 0; j < 4; ++j) {
        assert_int_equal(r.vertex[j], j);
        assert_rel_close(r.weight[j], want[j]);
    }
    check_against_reference(v, 4, &r);
}

/* ---- random paths --------------------------------------------------------------------------- */

/* A random value of an RGB field: often exactly 0 (no light, a black channel), sometimes
 * large (1/q of a roulette, a bright emitter). */
static float random_field(nft_rng *g)
{
    float u = nft_rng_float(g);
    if (u < 0.25f)
        return 0.0f;
    if (u < 0.35f)
        return 1.0f / (0.05f + nft_rng_float(g)); /* a 1/q between 1 and 20 */
    return 2.0f * nft_rng_float(g);
}

static void random_path(nft_rng *g, nf_path_vertex *v, size_t n)
{
    memset(v, 0, n * sizeof *v);
    for (size_t j = 0; j < n; ++j) {
        int delta = nft_rng_float(g) < 0.2f;
        if (!delta && nft_rng_float(g) < 0.8f) {
            v[j].learn = 1;
            nft_random_context(g, &v[j].ctx);
            nft_random_unit_vector(g, v[j].dir);
        }
        float q = nft_rng_float(g) < 0.3f ? 0.1f + 0.9f * nft_rng_float(g) : 1.0f;
        for (int c = 0; c < 3; ++c) {
            v[j].f_over_p[c] = v[j].learn ? random_field(g) : 0.0f;
            /* beta = f_over_p / q where learned; a delta lobe's own weight elsewhere. */
            v[j].beta[c] = (v[j].learn ? v[j].f_over_p[c] : random_field(g)) / q;
            v[j].direct[c] = delta ? 0.0f : random_field(g);
            v[j].emitted[c] = random_field(g);
        }
        v[j].emitted_mis = delta ? 1.0f : nft_rng_float(g);
    }
    /* Some paths end at their last vertex (absorbed or killed after next-event estimation). */
    if (n > 0 && nft_rng_float(g) < 0.5f) {
        set_gray(v[n - 1].beta, 0.0f);
        set_gray(v[n - 1].emitted, 0.0f);
        v[n - 1].learn = 0;
    }
}

static void test_random_paths(void **state)
{
    (void)state;
    nft_rng g;
    nft_rng_seed(&g, 7, 1);
    nf_path_vertex v[MAX_V];
    size_t samples = 0, paths_without = 0;
    for (int it = 0; it < 3000; ++it) {
        size_t n = nft_rng_u32(&g) % 24;
        random_path(&g, v, n);
        result r;
        assert_int_equal(run(v, n, MAX_V, &r), NF_OK);
        check_against_reference(v, n, &r);
        samples += r.count;
        paths_without += r.count == 0;
        /* The same call again gives the same bits. */
        result again;
        assert_int_equal(run(v, n, MAX_V, &again), NF_OK);
        assert_int_equal(again.count, r.count);
        assert_memory_equal(again.weight, r.weight, r.count * sizeof(float));
    }
    /* The generator exercises both outcomes (thousands of samples, and paths with none). */
    assert_true(samples > 10000);
    assert_true(paths_without > 100);
}

/* ---- edge cases ----------------------------------------------------------------------------- */

/* No learned vertex: NF_OK, count 0, nothing written; likewise vertex_count 0 (vertices may
 * then be NULL). */
static void test_no_learned_vertex(void **state)
{
    (void)state;
    nf_path_vertex v[3];
    memset(v, 0, sizeof v);
    for (int j = 0; j < 3; ++j) {
        set_gray(v[j].beta, 0.5f);
        set_gray(v[j].direct, 1.0f);
        set_gray(v[j].emitted, 1.0f);
        v[j].emitted_mis = 1.0f;
    }
    result r;
    assert_int_equal(run(v, 3, MAX_V, &r), NF_OK);
    assert_int_equal(r.count, 0);
    check_against_reference(v, 3, &r);
    assert_int_equal(run(NULL, 0, MAX_V, &r), NF_OK);
    assert_int_equal(r.count, 0);
    check_against_reference(v, 0, &r);
}

/* A learned vertex whose path found no light gives no sample, and a black f_over_p neither;
 * the vertices around them still do. */
static void test_zero_weights_skipped(void **state)
{
    (void)state;
    nf_path_vertex v[4];
    make_learned_path(v, 4, 0.5f, 0.5f);
    set_gray(v[1].emitted, 1.0f); /* found by v1's ray: v0 and v1 see light */
    v[1].emitted_mis = 1.0f;
    set_gray(v[0].f_over_p, 0.0f); /* ... but v0's f_over_p is black */
    /* v2 and v3 find nothing after them. */
    result r;
    assert_int_equal(run(v, 4, MAX_V, &r), NF_OK);
    assert_int_equal(r.count, 1);
    assert_int_equal(r.vertex[0], 1);
    assert_rel_close(r.weight[0], 0.5);
    check_against_reference(v, 4, &r);
}

/* Weights beyond FLT_MAX (finite factors whose product overflows) and weights that round to 0
 * in float are dropped; finite weights near both ends are kept, and the call succeeds. */
static void test_overflow_and_underflow(void **state)
{
    (void)state;
    nf_path_vertex v[12];
    make_learned_path(v, 12, FLT_MAX, FLT_MAX);
    for (int j = 0; j < 12; ++j)
        v[j].emitted_mis = 1.0f;
    set_gray(v[11].emitted, 1.0f);
    /* Vertex 11: weight FLT_MAX * 1, kept (exactly FLT_MAX); every earlier one overflows a
     * float; from some depth on, the double walk itself overflows to Inf. */
    result r;
    assert_int_equal(run(v, 12, MAX_V, &r), NF_OK);
    assert_int_equal(r.count, 1);
    assert_int_equal(r.vertex[0], 11);
    assert_true(r.weight[0] == FLT_MAX);

    /* A zero factor in front of a tail that overflows even a double: vertex 1's beta is 0 (its
     * path "ended", yet vertices follow: a renderer's bookkeeping may leave them) and vertices
     * 2..11 multiply FLT_MAX ten times (1e385). Vertex 0 still gets exactly what lies before
     * the zero: L_i = E_0 + D_1 = 1 + 1, weight 0.5 * 2 = 1; vertex 1 gets L_i = E_1 + S_2 =
     * Inf, dropped. A walk computing 0 * Inf would give NaN for vertex 0 and lose it (the
     * fuzz target found that; fuzz/corpus/path/zero_beta_before_overflow). */
    set_rgb(v[0].f_over_p, 0.75f, 0.0f, 0.75f);
    set_gray(v[0].emitted, 1.0f);
    set_gray(v[0].beta, 1.0f);
    set_gray(v[1].beta, 0.0f);
    set_gray(v[1].direct, 1.0f);
    set_gray(v[11].direct, FLT_MAX);
    assert_int_equal(run(v, 12, MAX_V, &r), NF_OK);
    assert_int_equal(r.count, 2);
    assert_int_equal(r.vertex[0], 0);
    assert_rel_close(r.weight[0], (0.75 * 2.0 + 0.75 * 2.0) / 3.0);
    assert_int_equal(r.vertex[1], 11);

    /* A black channel of f_over_p in front of an L_i that overflowed in that channel alone:
     * vertex 0, f_over_p (1, 0, 1); vertices 1..11 learn nothing and scatter with beta
     * (0.5, FLT_MAX, 0.5); vertex 11's ray finds emission 1 (H = 1). Red and blue: L_i =
     * 0.5^10 (0.5 * 1) = 2^-11; green overflows to Inf but counts 0 * Inf = 0. Weight
     * (2^-11 + 0 + 2^-11) / 3 = 2^-10 / 3. */
    memset(v, 0, sizeof v);
    make_learned(&v[0], 0);
    set_rgb(v[0].f_over_p, 1.0f, 0.0f, 1.0f);
    set_gray(v[0].beta, 1.0f);
    for (int j = 1; j < 12; ++j) {
        set_rgb(v[j].beta, 0.5f, FLT_MAX, 0.5f);
        v[j].emitted_mis = 1.0f;
    }
    set_gray(v[11].emitted, 1.0f);
    assert_int_equal(run(v, 12, MAX_V, &r), NF_OK);
    assert_int_equal(r.count, 1);
    assert_int_equal(r.vertex[0], 0);
    assert_rel_close(r.weight[0], ldexp(1.0, -10) / 3.0);

    /* Underflow: 1e-30 * 1e-30 rounds to 0 in float and is dropped; 1e-20 * 1e-20 * 3 / 3 =
     * 1e-40 is a denormal float, kept. */
    nf_path_vertex u[2];
    memset(u, 0, sizeof u);
    make_learned(&u[0], 0);
    make_learned(&u[1], 1);
    set_gray(u[0].f_over_p, 1e-30f);
    set_gray(u[0].emitted, 1e-30f);
    set_gray(u[1].f_over_p, 1e-20f);
    set_gray(u[1].emitted, 1e-20f);
    u[0].emitted_mis = u[1].emitted_mis = 1.0f; /* the emission counts whole */
    assert_int_equal(run(u, 2, MAX_V, &r), NF_OK);
    assert_int_equal(r.count, 1);
    assert_int_equal(r.vertex[0], 1);
    assert_true(r.weight[0] > 0.0f && r.weight[0] < FLT_MIN);
}

/* A full buffer: NF_ERROR_CAPACITY with the count needed, nothing else written; the count
 * query (capacity 0, NULL outputs); the retry with that capacity gives the full result. */
static void test_capacity(void **state)
{
    (void)state;
    nft_rng g;
    nft_rng_seed(&g, 11, 2);
    nf_path_vertex v[MAX_V];
    int checked = 0;
    for (int it = 0; it < 200; ++it) {
        size_t n = 1 + nft_rng_u32(&g) % 24;
        random_path(&g, v, n);
        result full;
        assert_int_equal(run(v, n, MAX_V, &full), NF_OK);
        size_t need = full.count;

        size_t count = SIZE_SENTINEL;
        assert_int_equal(nf_path_training_samples(n, v, 0, NULL, NULL, NULL, NULL, &count),
                         need > 0 ? NF_ERROR_CAPACITY : NF_OK);
        assert_int_equal(count, need);
        if (need == 0)
            continue;
        assert_non_null(strstr(nf_last_error_message(), "nf_path_training_samples"));

        result r;
        assert_int_equal(run(v, n, need - 1, &r), NF_ERROR_CAPACITY);
        assert_int_equal(r.count, need);
        assert_true(nft_untouched((const float *)r.ctx, NF_CTX_FLOATS * MAX_V));
        assert_true(nft_untouched(r.dir, 3 * MAX_V));
        assert_true(nft_untouched(r.weight, MAX_V));
        for (size_t i = 0; i < MAX_V; ++i)
            assert_int_equal(r.vertex[i], SIZE_SENTINEL);

        assert_int_equal(run(v, n, need, &r), NF_OK);
        assert_int_equal(r.count, need);
        assert_memory_equal(r.weight, full.weight, need * sizeof(float));
        assert_memory_equal(r.vertex, full.vertex, need * sizeof(size_t));
        ++checked;
    }
    assert_true(checked > 100);
}

/* vertex_out is optional: without it the other outputs are the same. */
static void test_vertex_out_optional(void **state)
{
    (void)state;
    nft_rng g;
    nft_rng_seed(&g, 5, 3);
    nf_path_vertex v[16];
    random_path(&g, v, 16);
    result a, b;
    assert_int_equal(run(v, 16, MAX_V, &a), NF_OK);
    nft_fill_sentinel(b.weight, MAX_V);
    assert_int_equal(nf_path_training_samples(16, v, MAX_V, b.ctx, b.dir, b.weight, NULL, &b.count),
                     NF_OK);
    assert_int_equal(b.count, a.count);
    assert_memory_equal(b.ctx, a.ctx, a.count * sizeof(nf_context));
    assert_memory_equal(b.dir, a.dir, 3 * a.count * sizeof(float));
    assert_memory_equal(b.weight, a.weight, a.count * sizeof(float));
}

/* The samples are accepted as they come by nf_train_step (contexts, directions and weights
 * pass its checks), including learned vertices with directions and normals of odd lengths. */
static void test_samples_train(void **state)
{
    nf_model *m = *state;
    nft_rng g;
    nft_rng_seed(&g, 3, 4);
    nf_path_vertex v[MAX_V];
    random_path(&g, v, MAX_V);
    for (int j = 0; j < MAX_V; j += 3)
        if (v[j].learn) {
            for (int c = 0; c < 3; ++c) {
                v[j].dir[c] *= 1e-14f; /* squared length 1e-28, above the 1e-30 limit */
                v[j].ctx.normal[c] *= 1e10f;
            }
        }
    result r;
    assert_int_equal(run(v, MAX_V, MAX_V, &r), NF_OK);
    assert_true(r.count > 5);
    float loss = -1.0f;
    assert_int_equal(nf_train_step(m, r.count, r.ctx, r.dir, r.weight, &loss), NF_OK);
    assert_true(isfinite(loss));
    assert_int_equal(nf_model_step_count(m), 1);
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_hand_made_gray),
    cmocka_unit_test(test_hand_made_colour),
    cmocka_unit_test(test_emission_at_several_depths),
    cmocka_unit_test(test_random_paths),
    cmocka_unit_test(test_no_learned_vertex),
    cmocka_unit_test(test_zero_weights_skipped),
    cmocka_unit_test(test_overflow_and_underflow),
    cmocka_unit_test(test_capacity),
    cmocka_unit_test(test_vertex_out_optional),
    NFT_WITH_MODEL(test_samples_train),
)
