/*
 * test_schedule_subsets.c - passes of a fixed number of paths (nisflow/schedule.h): an image
 * larger than a pass is rendered in interleaved subsets that cover every pixel once per
 * cycle, its measured grid stays out of the image, a short budget still covers the image, the
 * combination of subsets is each pixel's mean, and a path that is not finite is left out and
 * counted instead of stopping the job.
 */
#include <math.h>
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "nf_test_support.h"

/* 10,800 pixels in passes of 1,024 paths: about 12 subsets. */
enum { W = 120, H = 90, PIXELS = W * H, PASS = 1024 };

static nf_schedule *make_schedule(nf_guide *g, uint32_t w, uint32_t h, double budget)
{
    nf_schedule_config sc;
    nf_schedule_config_init(&sc);
    sc.width = w;
    sc.height = h;
    sc.budget = budget;
    sc.pass_paths = PASS;
    nf_schedule *s = NULL;
    assert_int_equal(nf_schedule_create(g, &sc, &s), NF_OK);
    return s;
}

/* Each pixel's true value: distinct across a row and down a column. */
static float truth(uint32_t i) { return 1.0f + (float)(i % 7u) / 7.0f + (float)(i / W % 5u); }

/* The measured paths are the first plan.measured_ ones: they see `measured`, which must never
 * reach the image; the others see their pixel's truth times `scale[j]`. */
static void fill(const nf_pass_plan *plan, float *rgb, float *moments, const float *scale,
                 float measured)
{
    for (uint32_t j = 0; j < plan->paths; ++j) {
        float v = j < plan->measured_ ? measured : truth(nf_pass_pixel(plan, j));
        if (scale)
            v *= scale[j];
        rgb[3 * j] = rgb[3 * j + 1] = rgb[3 * j + 2] = v;
        for (uint32_t m = 0; moments && m < NF_GUIDE_DEPTHS; ++m)
            moments[m * plan->paths + j] = v * v;
    }
}

/* Every `stride` consecutive passes put one image path through each pixel; the measured grid
 * lies inside the image, the same in every pass, no pixel twice; no pass exceeds pass_paths. */
static void test_subsets_cover_each_pixel_once(void **state)
{
    (void)state;
    nf_schedule *s = make_schedule(NULL, W, H, 1e9);
    float *rgb = calloc(3 * PASS, sizeof *rgb);
    int *hits = calloc(PIXELS, sizeof *hits);
    unsigned char *mark = calloc(PIXELS, 1);
    nf_pass_plan plan, first;
    assert_int_equal(nf_schedule_next(s, 0.0, NULL, &first), NF_OK);
    const uint32_t stride = first.stride_, measured = first.measured_;
    assert_true(stride > 1 && measured > 0 && measured <= PASS / 16);
    plan = first;
    for (uint32_t p = 0; p < 2 * stride; ++p) {
        if (p > 0)
            assert_int_equal(nf_schedule_next(s, 0.0, NULL, &plan), NF_OK);
        assert_true(plan.paths <= PASS && plan.measured_ == measured);
        for (uint32_t j = 0; j < measured; ++j) {
            uint32_t i = nf_pass_pixel(&plan, j);
            assert_true(i < PIXELS);
            assert_int_equal(i, nf_pass_pixel(&first, j));
            if (p == 0) { /* no pixel measured twice */
                assert_int_equal(mark[i], 0);
                mark[i] = 1;
            }
        }
        for (uint32_t j = measured; j < plan.paths; ++j)
            hits[nf_pass_pixel(&plan, j)]++;
        if (p == stride - 1 || p == 2 * stride - 1)
            for (uint32_t i = 0; i < PIXELS; ++i)
                assert_int_equal(hits[i], p == stride - 1 ? 1 : 2);
        assert_int_equal(nf_schedule_add_pass(s, &plan, rgb, NULL, 1.0, 1.0, NULL), NF_OK);
    }
    assert_int_equal(nf_pass_pixel(&plan, plan.paths), 0u); /* out of range */
    assert_int_equal(nf_pass_pixel(NULL, 0), 0u);
    free(mark);
    free(hits);
    free(rgb);
    nf_schedule_destroy(s);
}

/* An image that fits a pass is one pass, path j through pixel j. */
static void test_small_image_is_whole(void **state)
{
    (void)state;
    nf_schedule *s = make_schedule(NULL, 32, 32, 1.0);
    nf_pass_plan plan;
    assert_int_equal(nf_schedule_next(s, 0.0, NULL, &plan), NF_OK);
    assert_int_equal(plan.paths, 32 * 32);
    for (uint32_t j = 0; j < plan.paths; ++j)
        assert_int_equal(nf_pass_pixel(&plan, j), j);
    nf_schedule_destroy(s);
}

/* A budget shorter than a pass still renders a cycle of subsets, and every pixel of the
 * image is its truth (noise-free paths: the mean is exact to float rounding, 1e-6 relative);
 * the measured paths, which see 1000, never reach it. */
static void test_short_budget_covers_the_image(void **state)
{
    (void)state;
    nf_schedule *s = make_schedule(NULL, W, H, 1e-3);
    float *rgb = calloc(3 * PASS, sizeof *rgb), *out = calloc(3 * PIXELS, sizeof *out);
    uint32_t passes = 0, stride = 0;
    for (;; ++passes) {
        nf_pass_plan plan;
        assert_int_equal(nf_schedule_next(s, 5.0 * passes, NULL, &plan), NF_OK);
        if (plan.todo == NF_TODO_STOP)
            break;
        stride = plan.stride_;
        fill(&plan, rgb, NULL, NULL, 1000.0f);
        assert_int_equal(nf_schedule_add_pass(s, &plan, rgb, NULL, 5.0, 5.0, NULL), NF_OK);
    }
    assert_true(stride > 1);
    assert_int_equal(passes, stride);
    assert_int_equal(nf_schedule_combine(s, NULL, out, NULL), NF_OK);
    for (uint32_t i = 0; i < PIXELS; ++i)
        assert_true(fabsf(out[3 * i] - truth(i)) <= 1e-6f * truth(i));
    free(out);
    free(rgb);
    nf_schedule_destroy(s);
}

/* With a guide and noisy passes of every kind (each path its truth times a factor in
 * [0.5, 1.5), mean 1): training, guided and plain subsets combine into an image where every
 * pixel is a weighted mean of its paths, so within [0.5, 1.5] of its truth, and the image's
 * mean within 2 % of the truth's (about 40,000 paths with a relative spread of 0.29 each: a
 * standard error of 0.15 %; uneven weights raise it a few times, 2 % is still more than 5 of
 * them). A path with a NaN and one with a negative moment are left out and counted. */
static void test_subsets_combine_to_the_mean(void **state)
{
    (void)state;
    nf_config cfg = nft_config(NF_PRESET_SMALL, NF_PRIOR_COSINE);
    nf_model *m = nft_model_from(&cfg);
    nf_guide_config gc = nft_guide_config(64, 16, 1);
    nf_guide *g = NULL;
    assert_int_equal(nf_guide_create(m, &gc, &g), NF_OK);
    nf_model_destroy(m);
    nf_schedule *s = make_schedule(g, W, H, 48.0);
    float *rgb = calloc(3 * PASS, sizeof *rgb), *mom = calloc(NF_GUIDE_DEPTHS * PASS, sizeof *mom);
    float *scale = calloc(PASS, sizeof *scale), *out = calloc(3 * PIXELS, sizeof *out);
    nft_rng r;
    nft_rng_seed(&r, 11, 1);
    int kinds[3] = {0, 0, 0}, bad = 0;
    for (uint32_t n = 0;; ++n) {
        nf_pass_plan plan;
        assert_int_equal(nf_schedule_next(s, (double)n, NULL, &plan), NF_OK);
        if (plan.todo == NF_TODO_STOP)
            break;
        kinds[plan.todo]++;
        for (uint32_t j = 0; j < plan.paths; ++j)
            scale[j] = 0.5f + nft_rng_float(&r);
        fill(&plan, rgb, mom, scale, 2.0f);
        if (n == 20) { /* two bad image paths */
            rgb[3 * (plan.paths - 1) + 1] = NAN;
            mom[2 * plan.paths + plan.paths - 2] = -1.0f;
            bad = 2;
        }
        assert_int_equal(nf_schedule_add_pass(s, &plan, rgb, mom, 1.0, 1.0, NULL), NF_OK);
    }
    assert_true(kinds[NF_TODO_TRAIN] > 0 && kinds[NF_TODO_GUIDED] > 0 && kinds[NF_TODO_PLAIN] > 0);
    nf_schedule_report rep;
    assert_int_equal(nf_schedule_combine(s, NULL, out, &rep), NF_OK);
    assert_int_equal(rep.dropped, (uint64_t)bad);
    double sum = 0.0, want = 0.0;
    for (uint32_t i = 0; i < PIXELS; ++i) {
        float t = truth(i);
        assert_true(out[3 * i] >= 0.5f * t && out[3 * i] <= 1.5f * t);
        sum += out[3 * i];
        want += t;
    }
    assert_true(fabs(sum / want - 1.0) < 0.02);
    assert_true(rep.train_weight > 0.0 && rep.train_weight < 1.0);
    free(out);
    free(scale);
    free(mom);
    free(rgb);
    nf_schedule_destroy(s);
    nf_guide_destroy(g);
}

/* pass_paths out of range is refused by name. */
static void test_pass_paths_refused(void **state)
{
    (void)state;
    nf_schedule_config sc;
    nf_schedule_config_init(&sc);
    sc.width = sc.height = 64;
    sc.budget = 1.0;
    sc.pass_paths = 1023;
    nf_schedule *s = NULL;
    assert_int_equal(nf_schedule_create(NULL, &sc, &s), NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "pass_paths"));
    assert_null(s);
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_subsets_cover_each_pixel_once),
    cmocka_unit_test(test_small_image_is_whole),
    cmocka_unit_test(test_short_budget_covers_the_image),
    cmocka_unit_test(test_subsets_combine_to_the_mean),
    cmocka_unit_test(test_pass_paths_refused),
)
