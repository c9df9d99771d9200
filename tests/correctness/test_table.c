/*
 * test_table.c - a shading point's flow tabulated (nisflow/table.h):
 *   - a table is a distribution: nf_table_sample draws from nf_table_pdf (chi-square, the
 *     density integrating to one), on surfaces and in a medium, for a randomized model;
 *   - a sample's density is nf_table_pdf's of the direction drawn, and a surface table puts
 *     nothing at or below the horizon;
 *   - the table follows the flow: at every cell's centre its density over the flow's is one
 *     constant, the normalization.
 * Bad input and overwritten tables: tests/robustness/test_table_input.c.
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include <nisflow/nisflow.h>

#include "nf_test_main.h"
#include "nf_test_support.h"
#include "point_batch.h"
#include "direction_table.h"
#include "shading_point.h"

/* The chi-square's callbacks over one table. */
typedef struct table_fn {
    const nf_model *m;
    const nf_direction_table *t;
} table_fn;

static int table_sample_fn(void *user, size_t n, const float *u, float *dir)
{
    const table_fn *f = user;
    for (size_t i = 0; i < n; ++i)
        if (nf_table_sample(f->m, f->t, u + 2 * i, dir + 3 * i, NULL) != NF_OK)
            return 1;
    return 0;
}

static int table_pdf_fn(void *user, size_t n, const float *dir, float *pdf)
{
    const table_fn *f = user;
    for (size_t i = 0; i < n; ++i)
        if (nf_table_pdf(f->m, f->t, dir + 3 * i, pdf + i) != NF_OK)
            return 1;
    return 0;
}

static nf_context medium_at(nft_rng *r)
{
    nf_context c;
    memset(&c, 0, sizeof c);
    for (int a = 0; a < 3; ++a)
        c.position[a] = nft_rng_float(r);
    nft_random_unit_vector(r, c.wo);
    c.phase_g = 0.6f;
    return c;
}

/* Run k's context: a random surface for the first `surfaces` runs, then a medium. */
static nf_context context_of_run(nft_rng *r, int k, int surfaces)
{
    nf_context ctx;
    if (k < surfaces)
        nft_random_context(r, &ctx);
    else
        ctx = medium_at(r);
    return ctx;
}

/* ---- a distribution --------------------------------------------------------------------------- */

static void test_table_is_a_distribution(void **state)
{
    (void)state;
    nf_model *m = nft_random_model();
    nft_rng r;
    nft_rng_seed(&r, 3u, 1u);
    enum { SURFACES = 3, RUNS = SURFACES + 1 };
    for (int k = 0; k < RUNS; ++k) {
        const nf_context ctx = context_of_run(&r, k, SURFACES);
        const nf_direction_table t = nft_table_at(m, &ctx);
        table_fn f = {m, &t};
        char name[32];
        snprintf(name, sizeof name, "table_%d", k);
        nft_chi2_params p = nft_chi2_defaults(name);
        p.run_count = RUNS;
        /* The table's density is constant over cells that the test's (theta, phi) grid cuts
         * at other lines; 16 x 16 quadrature points per cell keep the integral's error from
         * those cut cells below 2e-3 (measured 4e-4), inside the default 1e-2. */
        p.subdiv = 16;
        nft_chi2_result res;
        if (!nft_chi2_test(&p, table_sample_fn, table_pdf_fn, &f, &res))
            fail_msg("%s: %s", name, res.message);
    }
    nf_model_destroy(m);
}

static void test_sample_density_is_the_tables(void **state)
{
    (void)state;
    nf_model *m = nft_random_model();
    nft_rng r;
    nft_rng_seed(&r, 5u, 1u);
    enum { N = 4000, SURFACES = 3 };
    size_t edge = 0;
    for (int k = 0; k < SURFACES + 1; ++k) {
        const nf_context ctx = context_of_run(&r, k, SURFACES);
        const nf_direction_table t = nft_table_at(m, &ctx);
        float n[3];
        memcpy(n, ctx.normal, sizeof n);
        for (int i = 0; i < N; ++i) {
            float u[2] = {nft_rng_float(&r), nft_rng_float(&r)}, dir[3], p, q;
            assert_int_equal(nf_table_sample(m, &t, u, dir, &p), NF_OK);
            assert_int_equal(nf_table_pdf(m, &t, dir, &q), NF_OK);
            /* unit to float rounding (about 1e-7): the draw's normalization is one Newton
             * step, exact only for a length already within 1e-3 of 1 */
            assert_true(fabs(nft_length3f(dir) - 1.0) < 1e-6);
            if (k < SURFACES) { /* above the horizon, and nothing below it */
                float cos_n = (dir[0] * n[0] + dir[1] * n[1] + dir[2] * n[2]) /
                              (float)nft_length3f(n);
                assert_true(cos_n > -1e-6f);
                float below[3] = {dir[0] - 2 * cos_n * n[0], dir[1] - 2 * cos_n * n[1],
                                  dir[2] - 2 * cos_n * n[2]};
                float z;
                assert_int_equal(nf_table_pdf(m, &t, below, &z), NF_OK);
                assert_true(z == 0.0f || cos_n < 1e-4f);
            }
            assert_true(p > 0.0f && isfinite(p));
            /* A direction drawn within rounding of a cell's edge may be looked up in the
             * neighbour, whose density differs; elsewhere the two agree to rounding. */
            if (fabs(p - q) > 1e-4 * p)
                edge++;
        }
    }
    /* 4 x 4000 draws; an edge within 1e-6 of one of 48 cell lines: a few in ten thousand */
    assert_true(edge < 4 * N / 100);
    nf_model_destroy(m);
}

/* ---- the flow's ------------------------------------------------------------------------------- */

static void test_table_follows_the_flow(void **state)
{
    (void)state;
    nf_model *m = nft_random_model();
    nft_rng r;
    nft_rng_seed(&r, 9u, 1u);
    nf_context ctx;
    nf_shading_point p;
    nft_random_point(m, &r, &ctx, &p);
    nf_direction_table t;
    assert_int_equal(nf_table_build(m, &p, &t), NF_OK); /* from the point the test asks below */
    /* The cells' centres in the library's frame about the unit normal (Duff et al. 2017,
     * "Building an Orthonormal Basis, Revisited", as src/kernels/prior.h builds it). */
    double len = nft_length3f(ctx.normal), nn[3], tb[3], bb[3];
    for (int a = 0; a < 3; ++a)
        nn[a] = (float)(ctx.normal[a] / len);
    double sign = nn[2] >= 0.0 ? 1.0 : -1.0, fa = -1.0 / (sign + nn[2]), fc = nn[0] * nn[1] * fa;
    tb[0] = 1.0 + sign * nn[0] * nn[0] * fa, tb[1] = sign * fc, tb[2] = -sign * nn[0];
    bb[0] = fc, bb[1] = sign + nn[1] * nn[1] * fa, bb[2] = -nn[1];
    double lo = INFINITY, hi = 0.0;
    for (uint32_t i = 0; i < NF_TABLE_ROWS; ++i)
        for (uint32_t j = 0; j < NF_TABLE_COLS; ++j) {
            double a = (i + 0.5) / NF_TABLE_ROWS, phi = 6.283185307179586 * (j + 0.5) / NF_TABLE_COLS;
            double s = sqrt(a), c = sqrt(1.0 - a);
            float d[3];
            for (int k = 0; k < 3; ++k)
                d[k] = (float)(s * cos(phi) * tb[k] + s * sin(phi) * bb[k] + c * nn[k]);
            float flow, table;
            assert_int_equal(nf_point_pdf(m, &p, 1, d, &flow), NF_OK);
            assert_int_equal(nf_table_pdf(m, &t, d, &table), NF_OK);
            double ratio = table / (double)flow;
            lo = ratio < lo ? ratio : lo;
            hi = ratio > hi ? ratio : hi;
        }
    /* One constant: the table holds the flow's density at each centre, normalized. The test's
     * centres differ from the library's by float rounding of the frame and the angles (about
     * 1e-7 rad): that moves the flow's density by 3e-6 at most cells, and by 1e-4 at a cell
     * by the horizon where it is 1/200 of its mean and steep (measured). 2e-3 is the bound
     * that point.h states for the point path itself. */
    if (hi / lo - 1.0 > 2e-3)
        fail_msg("table / flow at the cells' centres spans %.6g to %.6g", lo, hi);
    nf_model_destroy(m);
}

/* ---- the stack ------------------------------------------------------------------------------- */

typedef struct stack_job {
    const nf_model *m;
    const nf_shading_point *sp;
    const nf_direction_table *t;
    int call; /* 0: nothing, 1: build, 2: sample, 3: pdf */
    nf_status status;
} stack_job;

static void *stack_thread(void *arg)
{
    stack_job *j = arg;
    float u[2] = {0.3f, 0.6f}, d[3] = {0.0f, 0.6f, 0.8f}, dir[3] = {0}, pdf = 0.0f;
    nf_direction_table local;
    memset(&local, 0, sizeof local);
    switch (j->call) {
    case 1: j->status = nf_table_build(j->m, j->sp, &local); break;
    case 2: j->status = nf_table_sample(j->m, j->t, u, dir, &pdf); break;
    case 3: j->status = nf_table_pdf(j->m, j->t, d, &pdf); break;
    default: j->status = NF_OK; break;
    }
    volatile float sink = dir[0] + pdf + local.rows_[0][0]; /* the same frame for every case */
    (void)sink;
    return NULL;
}

/* table.h's bounds: a build within 8 KiB (the table it builds, a row of directions and the
 * point kernel's share; measured 5.2 KiB with GCC 12), a draw or a density within 256 bytes
 * (measured 80-144). */
static void test_stack_bound(void **state)
{
    (void)state;
#if !NFT_STACK_CHECK
    skip();
#else
    static const size_t bound[4] = {0, 8192, 256, 256};
    for (int big = 0; big < 2; ++big) {
        nf_model *m = nft_make_model(big ? NF_PRESET_LARGE : NF_PRESET_SMALL, NF_PRIOR_COSINE);
        nf_context ctx = nft_context(0.2f, 0.4f, 0.6f, 0.0f, 0.6f, 0.8f, 0.0f, 0.0f, 1.0f);
        nf_shading_point sp;
        nf_direction_table t;
        assert_int_equal(nf_point_prepare(m, &ctx, NULL, &sp), NF_OK);
        assert_int_equal(nf_table_build(m, &sp, &t), NF_OK);
        stack_job j = {m, &sp, &t, 0, NF_OK};
        size_t base = nft_stack_used(stack_thread, &j, 256 * 1024);
        for (int call = 1; call <= 3; ++call) {
            j.call = call;
            size_t used = nft_stack_used(stack_thread, &j, 256 * 1024);
            assert_int_equal(j.status, NF_OK);
            size_t extra = used > base ? used - base : 0;
            print_message("%s preset: %s used %zu bytes of stack\n", big ? "large" : "small",
                          call == 1 ? "nf_table_build" : call == 2 ? "nf_table_sample"
                                                                   : "nf_table_pdf",
                          extra);
            assert_true(extra <= bound[call]);
        }
        nf_model_destroy(m);
    }
#endif
}

NFT_TEST_MAIN(cmocka_unit_test(test_table_is_a_distribution),
              cmocka_unit_test(test_sample_density_is_the_tables),
              cmocka_unit_test(test_table_follows_the_flow), cmocka_unit_test(test_stack_bound), )
