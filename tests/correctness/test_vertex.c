/*
 * test_vertex.c - one render thread's answers at path vertices (nisflow/vertex.h):
 *   - at a point, the same bits as a shading point's calls (a draw with the light's density in
 *     one call, two densities in one call);
 *   - by table: a cell without a table is answered at a point and noted, nf_vertex_build builds
 *     it, and the next vertex in the cell is answered from exactly the table the library's cache
 *     builds for it; a draw's density is the density of the drawn direction;
 *   - what always goes to a point: media, a vertex with its own prior, a config without tables;
 *   - a vertex set before the model trained answers NF_ERROR_STALE, never stale numbers;
 *   - refusals name the vertex functions: no vertex set, a bad route, NaN in u, a zero
 *     direction, an uninitialized or out-of-range config (allocation failures:
 *     test_alloc_failure).
 */
#include <math.h>
#include <string.h>

#include <nisflow/nisflow.h>

#include "nf_test_main.h"
#include "nf_test_support.h"
#include "direction_table.h"
#include "shading_point.h"

static nf_vertex *make_vertex(int tables)
{
    nf_vertex_config cfg;
    nf_vertex_config_init(&cfg);
    cfg.tables = (uint32_t)tables;
    cfg.capacity = 64;
    cfg.position_cells = 4;
    nf_vertex *v = NULL;
    if (nf_vertex_create(&cfg, &v) != NF_OK)
        fail_msg("nf_vertex_create: %s", nf_last_error_message());
    return v;
}

static nf_vertex_stats stats_of(const nf_vertex *v)
{
    nf_vertex_stats s;
    assert_int_equal(nf_vertex_get_stats(v, &s), NF_OK);
    return s;
}

static void test_at_a_point_the_bits_of_a_shading_point(void **state)
{
    (void)state;
    nf_model *m = nft_random_model();
    nf_vertex *v = make_vertex(1);
    nft_rng r;
    nft_rng_seed(&r, 7, 0);
    for (int k = 0; k < 40; ++k) {
        nf_context ctx;
        nft_random_context(&r, &ctx);
        if (k % 4 == 3)
            ctx.normal[0] = ctx.normal[1] = ctx.normal[2] = 0.0f; /* a medium */
        float u[2] = {nft_rng_float(&r), nft_rng_float(&r)}, dirs[6];
        nft_random_unit_vector(&r, dirs);
        nft_random_unit_vector(&r, dirs + 3);
        nf_shading_point sp;
        assert_int_equal(nf_point_prepare(m, &ctx, NULL, &sp), NF_OK);
        float d0[3], p0, l0, q0[2], d1[3], p1, l1, q1[2];
        assert_int_equal(nf_point_sample_and_pdf(m, &sp, u, d0, &p0, dirs, &l0), NF_OK);
        assert_int_equal(nf_point_pdf(m, &sp, 2, dirs, q0), NF_OK);
        /* NF_VERTEX_POINT, or a table route the first time a cell is seen: both at a point. */
        assert_int_equal(nf_vertex_set(v, m, &ctx, NULL, NF_VERTEX_POINT), NF_OK);
        assert_int_equal(nf_vertex_sample(v, u, d1, &p1, 1, dirs, &l1), NF_OK);
        assert_int_equal(nf_vertex_pdf(v, 2, dirs, q1), NF_OK);
        assert_int_equal(memcmp(d0, d1, sizeof d0), 0);
        assert_int_equal(memcmp(&p0, &p1, sizeof p0), 0);
        assert_int_equal(memcmp(&l0, &l1, sizeof l0), 0);
        assert_int_equal(memcmp(q0, q1, sizeof q0), 0);
        /* Without extra directions, and with two: the draw is the same. */
        float d2[3], p2, l2[2];
        assert_int_equal(nf_vertex_sample(v, u, d2, &p2, 2, dirs, l2), NF_OK);
        assert_int_equal(memcmp(d0, d2, sizeof d0), 0);
        assert_int_equal(memcmp(q0, l2, sizeof q0), 0);
    }
    nf_vertex_stats s = stats_of(v);
    assert_int_equal(s.points, 40);
    assert_int_equal(s.tables, 0);
    nf_vertex_destroy(v);
    nf_model_destroy(m);
}

static void test_by_table_after_the_cell_is_built(void **state)
{
    (void)state;
    nf_model *m = nft_random_model(); /* bounds [0, 1]^3 */
    nf_vertex *v = make_vertex(1);
    nf_context a = nft_context(0.30f, 0.60f, 0.26f, 0.05f, -0.1f, 1.0f, 0.3f, 0.2f, 0.9f);
    nf_context b = nft_context(0.45f, 0.70f, 0.262f, -0.1f, 0.1f, 1.0f, -0.5f, 0.1f, 0.4f);
    const float u[2] = {0.37f, 0.81f}, light[3] = {0.2f, -0.3f, 0.9f};
    /* First visit: no table yet, answered at a point, the cell noted. */
    assert_int_equal(nf_vertex_set(v, m, &a, NULL, NF_VERTEX_TABLE), NF_OK);
    nf_vertex_stats s = stats_of(v);
    assert_int_equal(s.points, 1);
    assert_int_equal(s.tables, 0);
    assert_int_equal(s.builds, 0);
    assert_int_equal(nf_vertex_build(v), NF_OK);
    assert_int_equal(stats_of(v).builds, 1);
    assert_int_equal(nf_vertex_build(v), NF_OK); /* nothing noted: nothing built */
    assert_int_equal(stats_of(v).builds, 1);
    /* b is in a's cell: its table, the one a cache of the same cells builds. */
    assert_int_equal(nf_vertex_set(v, m, &b, NULL, NF_VERTEX_TABLE), NF_OK);
    s = stats_of(v);
    assert_int_equal(s.tables, 1);
    nf_table_cache_config tc;
    nf_table_cache_config_init(&tc);
    tc.capacity = 64;
    tc.position_cells = 4;
    nf_table_cache *c = NULL;
    assert_int_equal(nf_table_cache_create(&tc, &c), NF_OK);
    const nf_direction_table *t = NULL;
    assert_int_equal(nf_table_cache_find(c, m, &b, 1, &t), NF_OK);
    assert_non_null(t);
    float d0[3], p0, l0, d1[3], p1, l1, back;
    assert_int_equal(nf_table_sample(m, t, u, d0, &p0), NF_OK);
    assert_int_equal(nf_table_pdf(m, t, light, &l0), NF_OK);
    assert_int_equal(nf_vertex_sample(v, u, d1, &p1, 1, light, &l1), NF_OK);
    assert_int_equal(memcmp(d0, d1, sizeof d0), 0);
    assert_int_equal(memcmp(&p0, &p1, sizeof p0), 0);
    assert_int_equal(memcmp(&l0, &l1, sizeof l0), 0);
    /* The density of a drawn direction is the density the draw reported. */
    assert_int_equal(nf_vertex_pdf(v, 1, d1, &back), NF_OK);
    assert_float_equal(back, p1, 1e-6f * p1); /* float rounding of the cell's lookup */
    /* The same context by NF_VERTEX_POINT: at a point, not the table. */
    assert_int_equal(nf_vertex_set(v, m, &b, NULL, NF_VERTEX_POINT), NF_OK);
    assert_int_equal(stats_of(v).points, 2);
    nf_table_cache_destroy(c);
    nf_vertex_destroy(v);
    nf_model_destroy(m);
}

static void test_what_goes_to_a_point(void **state)
{
    (void)state;
    nf_model *m = nft_random_model();
    nf_context wall = nft_context(0.30f, 0.60f, 0.26f, 0.0f, 0.0f, 1.0f, 0.3f, 0.2f, 0.9f);
    nf_context fog = wall;
    fog.normal[2] = 0.0f;
    fog.phase_g = 0.4f;
    /* Tables off: a wall goes to a point, and nothing is noted. */
    nf_vertex *off = make_vertex(0);
    for (int k = 0; k < 2; ++k) {
        assert_int_equal(nf_vertex_set(off, m, &wall, NULL, NF_VERTEX_TABLE), NF_OK);
        assert_int_equal(nf_vertex_build(off), NF_OK);
    }
    nf_vertex_stats s = stats_of(off);
    assert_int_equal(s.points, 2);
    assert_int_equal(s.builds, 0);
    nf_vertex_destroy(off);
    /* A medium: always a point, never noted. */
    nf_vertex *v = make_vertex(1);
    for (int k = 0; k < 2; ++k) {
        assert_int_equal(nf_vertex_set(v, m, &fog, NULL, NF_VERTEX_TABLE), NF_OK);
        assert_int_equal(nf_vertex_build(v), NF_OK);
    }
    s = stats_of(v);
    assert_int_equal(s.points, 2);
    assert_int_equal(s.builds, 0);
    nf_vertex_destroy(v);
    nf_model_destroy(m);
    /* A vertex with its own prior callbacks: a point, with them. */
    nf_config cfg = nft_config(NF_PRESET_SMALL, NF_PRIOR_CUSTOM);
    cfg.custom_prior = nft_phong_callbacks();
    nf_model *pm = nft_model_from(&cfg);
    nf_prior_callbacks own = nft_phong_callbacks();
    v = make_vertex(1);
    for (int k = 0; k < 2; ++k) {
        assert_int_equal(nf_vertex_set(v, pm, &wall, &own, NF_VERTEX_TABLE), NF_OK);
        assert_int_equal(nf_vertex_build(v), NF_OK);
    }
    s = stats_of(v);
    assert_int_equal(s.points, 2);
    assert_int_equal(s.builds, 0);
    nf_vertex_destroy(v);
    nf_model_destroy(pm);
}

static void test_a_trained_model_is_stale(void **state)
{
    (void)state;
    nf_model *m = nft_random_model();
    nf_context ctx = nft_context(0.30f, 0.60f, 0.26f, 0.0f, 0.0f, 1.0f, 0.3f, 0.2f, 0.9f);
    const float u[2] = {0.5f, 0.5f};
    for (int route = 0; route < 2; ++route) {
        nf_vertex *v = make_vertex(1);
        if (route == 1) { /* a table answers */
            assert_int_equal(nf_vertex_set(v, m, &ctx, NULL, NF_VERTEX_TABLE), NF_OK);
            assert_int_equal(nf_vertex_build(v), NF_OK);
        }
        assert_int_equal(nf_vertex_set(v, m, &ctx, NULL, (nf_vertex_route)route), NF_OK);
        assert_int_equal(stats_of(v).tables, (uint64_t)route);
        nft_rng r;
        nft_rng_seed(&r, 3, 0);
        nf_context tc[64];
        float dir[3 * 64], w[64];
        nft_random_samples(&r, 64, tc, dir, w, 0.1f);
        assert_int_equal(nf_train_step(m, 64, tc, dir, w, NULL), NF_OK);
        float d[3] = {9, 9, 9}, p = -1.0f;
        assert_int_equal(nf_vertex_sample(v, u, d, &p, 0, NULL, NULL), NF_ERROR_STALE);
        assert_true(d[0] == 9.0f && p == -1.0f); /* nothing written */
        assert_int_equal(nf_vertex_pdf(v, 1, dir, &p), NF_ERROR_STALE);
        assert_true(p == -1.0f);
        assert_non_null(strstr(nf_last_error_message(), "nf_vertex_pdf"));
        nf_vertex_destroy(v);
    }
    nf_model_destroy(m);
}

static void test_refusals(void **state)
{
    (void)state;
    nf_model *m = nft_random_model();
    nf_vertex *v = make_vertex(1);
    nf_context ctx = nft_context(0.30f, 0.60f, 0.26f, 0.0f, 0.0f, 1.0f, 0.3f, 0.2f, 0.9f);
    float u[2] = {0.5f, 0.5f}, d[3], p, zero[3] = {0, 0, 0};
    assert_int_equal(nf_vertex_sample(v, u, d, &p, 0, NULL, NULL), NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "nf_vertex_sample: no vertex is set"));
    assert_int_equal(nf_vertex_set(v, m, &ctx, NULL, (nf_vertex_route)2), NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "nf_vertex_set: route = 2"));
    nf_context bad = ctx;
    bad.position[1] = NAN;
    assert_int_equal(nf_vertex_set(v, m, &bad, NULL, NF_VERTEX_TABLE), NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "nf_vertex_set"));
    /* A refused set leaves no vertex to answer. */
    assert_int_equal(nf_vertex_pdf(v, 1, ctx.normal, &p), NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_vertex_set(v, m, &ctx, NULL, NF_VERTEX_POINT), NF_OK);
    u[1] = NAN;
    assert_int_equal(nf_vertex_sample(v, u, d, &p, 0, NULL, NULL), NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "nf_vertex_sample: u is not finite"));
    assert_int_equal(nf_vertex_pdf(v, 1, zero, &p), NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "nf_vertex_pdf"));
    assert_int_equal(nf_vertex_pdf(v, 0, NULL, NULL), NF_OK);
    assert_int_equal(nf_vertex_build(NULL), NF_ERROR_INVALID_ARGUMENT);
    nf_vertex_destroy(v);
    nf_vertex_destroy(NULL);
    /* Configs. */
    nf_vertex_config cfg;
    memset(&cfg, 0, sizeof cfg);
    nf_vertex *w = (nf_vertex *)&cfg;
    assert_int_equal(nf_vertex_create(&cfg, &w), NF_ERROR_INVALID_ARGUMENT);
    assert_null(w);
    assert_non_null(strstr(nf_last_error_message(), "nf_vertex_config_init"));
    nf_vertex_config_init(&cfg);
    cfg.tables = 2;
    assert_int_equal(nf_vertex_create(&cfg, &w), NF_ERROR_INVALID_ARGUMENT);
    nf_vertex_config_init(&cfg);
    cfg.normal_cells = 4; /* even */
    assert_int_equal(nf_vertex_create(&cfg, &w), NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "nf_vertex_create"));
    assert_int_equal(nf_vertex_create(NULL, NULL), NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_vertex_create(NULL, &w), NF_OK); /* the defaults */
    nf_vertex_destroy(w);
    nf_model_destroy(m);
}

NFT_TEST_MAIN(cmocka_unit_test(test_at_a_point_the_bits_of_a_shading_point),
              cmocka_unit_test(test_by_table_after_the_cell_is_built),
              cmocka_unit_test(test_what_goes_to_a_point),
              cmocka_unit_test(test_a_trained_model_is_stale),
              cmocka_unit_test(test_refusals))
