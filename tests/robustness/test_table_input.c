/*
 * test_table_input.c - the tables of nisflow/table.h against bad input and overwritten tables
 * (their contract otherwise: tests/correctness/test_table.c).
 *   - refusals: NULL, a table never built, another model's, a stale one, NaN u, a zero
 *     direction, an unprepared point; a failed build leaves a built table as it was;
 *   - the cache of tables (nf_table_cache): an uninitialized or out-of-range config (each field),
 *     NULL, a medium context, an allocator that fails;
 *   - a table whose contents (after its identity) were overwritten with random bytes, NaN and
 *     infinities among them, is answered without reading outside itself (what the ASan
 *     build checks; the library guards its float-to-index conversions), as table.h states.
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

static void test_table_refusals(void **state)
{
    (void)state;
    nf_model *m = nft_random_model(), *other = nft_random_model();
    nft_rng r;
    nft_rng_seed(&r, 13u, 1u);
    nf_context ctx;
    nf_shading_point p;
    nft_random_point(m, &r, &ctx, &p);
    nf_direction_table t, never;
    memset(&never, 0, sizeof never);
    assert_int_equal(nf_table_build(m, &p, &t), NF_OK);
    const float u[2] = {0.3f, 0.6f}, nan_u[2] = {NAN, 0.5f}, zero[3] = {0, 0, 0};
    float dir[3], pdf;
    assert_int_equal(nf_table_build(NULL, &p, &t), NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_table_sample(m, NULL, u, dir, &pdf), NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_table_pdf(m, &t, NULL, &pdf), NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_table_sample(m, &never, u, dir, &pdf), NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "never built"));
    assert_int_equal(nf_table_sample(other, &t, u, dir, &pdf), NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "another model"));
    assert_int_equal(nf_table_sample(m, &t, nan_u, dir, &pdf), NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_table_pdf(m, &t, zero, &pdf), NF_ERROR_INVALID_ARGUMENT);

    /* A failed build (a point never prepared) leaves the built table as it was. */
    nf_direction_table before = t;
    nf_shading_point unprepared;
    memset(&unprepared, 0, sizeof unprepared);
    assert_int_equal(nf_table_build(m, &unprepared, &t), NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(memcmp(&before, &t, sizeof t), 0);
    assert_int_equal(nf_table_sample(m, &t, u, dir, &pdf), NF_OK);

    /* New parameters make the table stale, as they make the point. */
    assert_int_equal(nft_randomize_params(m, 0.5f, 12u), NF_OK);
    assert_int_equal(nf_table_sample(m, &t, u, dir, &pdf), NF_ERROR_STALE);
    assert_int_equal(nf_table_pdf(m, &t, ctx.normal, &pdf), NF_ERROR_STALE);
    assert_int_equal(nf_table_build(m, &p, &t), NF_ERROR_STALE);
    nf_model_destroy(m);
    nf_model_destroy(other);
}

static void test_overwritten_table(void **state)
{
    (void)state;
    nf_model *m = nft_random_model();
    nft_rng r;
    nft_rng_seed(&r, 17u, 1u);
    nf_context ctx;
    nf_shading_point p;
    nft_random_point(m, &r, &ctx, &p);
    nf_direction_table built;
    assert_int_equal(nf_table_build(m, &p, &built), NF_OK);
    /* The identity (magic, model, generation) stays; the rest is noise: random words,
     * and in one table of four, NaN, infinities and huge values in random places. */
    const size_t head = offsetof(nf_direction_table, frame_);
    const float specials[] = {NAN, INFINITY, -INFINITY, 3e38f, -3e38f, 0.0f, -0.0f, 1e-45f};
    for (int k = 0; k < 2000; ++k) {
        nf_direction_table t = built;
        unsigned char *bytes = (unsigned char *)&t;
        for (size_t b = head; b < sizeof t; ++b)
            bytes[b] = (unsigned char)nft_rng_u32(&r);
        if (k % 4 == 0) {
            float *f = (float *)(bytes + head);
            size_t nf = (sizeof t - head) / sizeof(float);
            for (int s = 0; s < 64; ++s)
                f[nft_rng_u32(&r) % nf] = specials[nft_rng_u32(&r) % 8];
        }
        t.medium_ = nft_rng_u32(&r);
        float u[2] = {nft_rng_float(&r), nft_rng_float(&r)}, dir[3], pdf, q, d[3];
        nft_random_unit_vector(&r, d);
        assert_int_equal(nf_table_sample(m, &t, u, dir, &pdf), NF_OK);
        assert_int_equal(nf_table_pdf(m, &t, d, &q), NF_OK);
    }
    nf_model_destroy(m);
}

static void *failing_alloc(void *user, size_t size)
{
    (void)user;
    (void)size;
    return NULL;
}

static void never_free(void *user, void *ptr)
{
    (void)user;
    (void)ptr;
    fail_msg("free called for memory never allocated");
}

static void test_cache_refusals(void **state)
{
    (void)state;
    nf_table_cache_config cfg, bad;
    nf_table_cache_config_init(&cfg);
    nf_table_cache *c = (nf_table_cache *)&cfg; /* must be set to NULL on failure */
    memset(&bad, 0, sizeof bad);
    assert_int_equal(nf_table_cache_create(&bad, &c), NF_ERROR_INVALID_ARGUMENT);
    assert_null(c);
    assert_non_null(strstr(nf_last_error_message(), "nf_table_cache_config_init"));
    struct {
        uint32_t *field, value;
        const char *name;
    } cases[] = {{&bad.capacity, 0, "capacity"},          {&bad.capacity, (1u << 24) + 1, "capacity"},
                 {&bad.position_cells, 0, "position_cells"}, {&bad.position_cells, 1025, "position_cells"},
                 {&bad.normal_cells, 2, "normal_cells"},   {&bad.normal_cells, 17, "normal_cells"}};
    for (size_t k = 0; k < sizeof cases / sizeof cases[0]; ++k) {
        bad = cfg;
        *cases[k].field = cases[k].value;
        assert_int_equal(nf_table_cache_create(&bad, &c), NF_ERROR_INVALID_ARGUMENT);
        assert_non_null(strstr(nf_last_error_message(), cases[k].name));
    }
    bad = cfg;
    bad.allocator.alloc = failing_alloc;
    assert_int_equal(nf_table_cache_create(&bad, &c), NF_ERROR_INVALID_ARGUMENT); /* no free */
    bad.allocator.free = never_free;
    assert_int_equal(nf_table_cache_create(&bad, &c), NF_ERROR_OUT_OF_MEMORY);
    assert_null(c);
    assert_int_equal(nf_table_cache_create(NULL, &c), NF_ERROR_INVALID_ARGUMENT);

    assert_int_equal(nf_table_cache_create(&cfg, &c), NF_OK);
    nf_model *m = nft_random_model();
    nf_context surface = nft_context(0.5f, 0.5f, 0.5f, 0, 0, 1, 0, 0, 1), medium = surface;
    medium.normal[2] = 0.0f;
    medium.phase_g = 0.3f;
    nf_context nan_pos = surface;
    nan_pos.position[1] = NAN;
    const nf_direction_table *t = (const nf_direction_table *)&cfg;
    assert_int_equal(nf_table_cache_find(c, m, &medium, 1, &t), NF_ERROR_INVALID_ARGUMENT);
    assert_null(t);
    assert_non_null(strstr(nf_last_error_message(), "medium"));
    assert_int_equal(nf_table_cache_find(c, m, &nan_pos, 1, &t), NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_table_cache_find(NULL, m, &surface, 1, &t), NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_table_cache_find(c, m, &surface, 1, NULL), NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_table_cache_get_stats(c, NULL), NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nft_cache_stats(c).builds, 0);
    nf_table_cache_destroy(c);
    nf_table_cache_destroy(NULL);
    nf_model_destroy(m);
}

NFT_TEST_MAIN(cmocka_unit_test(test_table_refusals), cmocka_unit_test(test_overwritten_table),
              cmocka_unit_test(test_cache_refusals), )
