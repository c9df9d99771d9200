/*
 * test_table_cache.c - a render thread's tables by cells (nisflow/table.h, nf_table_cache):
 *   - a cell's table is built once and found again for any context in the cell, and it is the
 *     table of the cell's centre (the grid cell's centre on the plane's rounded offset, the
 *     normal cell's centre direction); a parallel plane in the same grid cell is another cell;
 *   - a wall along an axis is its cell's centre exactly, normal and plane, for any odd
 *     normal_cells;
 *   - other cells get other tables; a full bucket builds none and says so, and keeps its own;
 *   - new parameters, or another model, make the next find build again, never hand out a
 *     stale table;
 *   - refusals: NULL, an uninitialized or out-of-range config, a medium context; an allocator
 *     that fails gives NF_ERROR_OUT_OF_MEMORY.
 */
#include <stdio.h>
#include <string.h>

#include <nisflow/nisflow.h>

#include "nf_test_main.h"
#include "nf_test_support.h"
#include "direction_table.h"

static nf_table_cache *make_cache(uint32_t capacity, uint32_t position_cells, uint32_t normal_cells)
{
    nf_table_cache_config cfg;
    nf_table_cache_config_init(&cfg);
    cfg.capacity = capacity;
    cfg.position_cells = position_cells;
    cfg.normal_cells = normal_cells;
    nf_table_cache *c = NULL;
    if (nf_table_cache_create(&cfg, &c) != NF_OK)
        fail_msg("nf_table_cache_create: %s", nf_last_error_message());
    return c;
}

static const nf_direction_table *find(nf_table_cache *c, const nf_model *m, const nf_context *ctx,
                                      int build)
{
    const nf_direction_table *t = NULL;
    if (nf_table_cache_find(c, m, ctx, build, &t) != NF_OK)
        fail_msg("nf_table_cache_find: %s", nf_last_error_message());
    return t;
}

static void expect_stats(const nf_table_cache *c, uint64_t finds, uint64_t builds, uint64_t full)
{
    const nf_table_cache_stats s = nft_cache_stats(c);
    assert_int_equal(s.finds, finds);
    assert_int_equal(s.builds, builds);
    assert_int_equal(s.full, full);
}

static void test_a_cell_is_built_once(void **state)
{
    (void)state;
    nf_model *m = nft_random_model(); /* bounds [0, 1]^3 */
    nf_table_cache *c = make_cache(64, 4, 3);
    /* Two contexts in the cell [0.25, 0.5) x [0.5, 0.75) of x and y, normals near +z, on planes
     * z = 0.26 and 0.262 that round to the same sixteenth of a grid cell, 17 / 64. */
    nf_context a = nft_context(0.30f, 0.60f, 0.26f, 0.05f, -0.1f, 1.0f, 0.3f, 0.2f, 0.9f);
    nf_context b = nft_context(0.45f, 0.70f, 0.262f, -0.1f, 0.1f, 1.0f, -0.5f, 0.1f, 0.4f);
    assert_null(find(c, m, &a, 0));
    const nf_direction_table *ta = find(c, m, &a, 1);
    assert_non_null(ta);
    assert_ptr_equal(find(c, m, &b, 0), ta);
    assert_ptr_equal(find(c, m, &b, 1), ta);
    /* The cell's centre: (0.375, 0.625) on the plane z = 17 / 64, the normal +z (the middle of
     * 3 x 3), wo = it. */
    nf_context centre = nft_context(0.375f, 0.625f, 0.265625f, 0, 0, 1, 0, 0, 1);
    nf_direction_table expect = nft_table_at(m, &centre);
    assert_int_equal(memcmp(&expect, ta, sizeof expect), 0);
    expect_stats(c, 4, 1, 0);
    /* Another position cell, another normal cell: other tables. */
    nf_context far = nft_context(0.80f, 0.60f, 0.26f, 0.05f, -0.1f, 1.0f, 0.3f, 0.2f, 0.9f);
    nf_context tilted = nft_context(0.30f, 0.60f, 0.26f, 0.9f, 0.0f, 1.0f, 0.3f, 0.2f, 0.9f);
    nf_context parallel = nft_context(0.30f, 0.60f, 0.30f, 0.05f, -0.1f, 1.0f, 0.3f, 0.2f, 0.9f);
    const nf_direction_table *tf = find(c, m, &far, 1), *tt = find(c, m, &tilted, 1),
                             *tp = find(c, m, &parallel, 1);
    assert_true(tf != ta && tt != ta && tp != ta && tf != tt && tf != tp && tt != tp);
    assert_int_not_equal(memcmp(tf, ta, sizeof *ta), 0);
    nf_table_cache_destroy(c);
    nf_model_destroy(m);
}

static void test_axis_walls_are_centres(void **state)
{
    (void)state;
    nf_model *m = nft_random_model();
    for (uint32_t b = 1; b <= 15; b += 2) {
        nf_table_cache *c = make_cache(16, 2, b);
        /* A wall facing -y at y = 1, its normal exactly -y: the cell's normal is -y itself and
         * its centre on the wall (y = 1 is a multiple of the plane's step, 1/32). */
        nf_context wall = nft_context(0.2f, 1.0f, 0.7f, 0, -1, 0, 0.3f, -0.5f, 0.2f);
        nf_context centre = nft_context(0.25f, 1.0f, 0.75f, 0, -1, 0, 0, -1, 0);
        nf_direction_table expect = nft_table_at(m, &centre);
        if (memcmp(&expect, find(c, m, &wall, 1), sizeof expect) != 0)
            fail_msg("normal_cells %u: the wall's table is not its centre's", b);
        nf_table_cache_destroy(c);
    }
    nf_model_destroy(m);
}

static void test_a_full_bucket_builds_nothing(void **state)
{
    (void)state;
    nf_model *m = nft_random_model();
    nf_table_cache *c = make_cache(1, 8, 3);
    nf_context a = nft_context(0.1f, 0.1f, 0.1f, 0, 0, 1, 0, 0, 1);
    nf_context b = nft_context(0.9f, 0.9f, 0.9f, 0, 0, 1, 0, 0, 1);
    const nf_direction_table *ta = find(c, m, &a, 1);
    assert_non_null(ta);
    nf_direction_table kept = *ta;
    for (int k = 0; k < 3; ++k) {
        assert_null(find(c, m, &b, 1)); /* its bucket (the only slot) is a's */
        assert_ptr_equal(find(c, m, &a, 0), ta);
    }
    assert_int_equal(memcmp(&kept, ta, sizeof kept), 0);
    expect_stats(c, 7, 1, 3);
    nf_table_cache_destroy(c);
    nf_model_destroy(m);
}

static void test_new_parameters_rebuild(void **state)
{
    (void)state;
    nf_model *m = nft_random_model(), *other = nft_random_model();
    nf_table_cache *c = make_cache(64, 4, 3);
    nf_context a = nft_context(0.3f, 0.6f, 0.1f, 0, 0, 1, 0, 0, 1);
    const nf_direction_table *t = find(c, m, &a, 1);
    float u[2] = {0.4f, 0.7f}, dir[3], pdf;
    assert_int_equal(nf_table_sample(m, t, u, dir, &pdf), NF_OK);
    assert_int_equal(nft_randomize_params(m, 0.5f, 12u), NF_OK);
    assert_null(find(c, m, &a, 0)); /* forgotten, never handed out stale */
    t = find(c, m, &a, 1);
    assert_int_equal(nf_table_sample(m, t, u, dir, &pdf), NF_OK);
    assert_null(find(c, other, &a, 0)); /* another model: forgotten too */
    t = find(c, other, &a, 1);
    assert_int_equal(nf_table_sample(other, t, u, dir, &pdf), NF_OK);
    assert_int_equal(nft_cache_stats(c).builds, 3);
    nf_table_cache_destroy(c);
    nf_model_destroy(m);
    nf_model_destroy(other);
}

NFT_TEST_MAIN(cmocka_unit_test(test_a_cell_is_built_once),
              cmocka_unit_test(test_axis_walls_are_centres), cmocka_unit_test(test_a_full_bucket_builds_nothing),
              cmocka_unit_test(test_new_parameters_rebuild), )
