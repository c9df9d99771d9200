/*
 * test_guide_peaks.c - the reference without lone peaks (nf_guide_lower_peaks,
 * nisflow/schedule.h): a lone peak takes its brightest neighbour's value anywhere in the image
 * (corners and borders have fewer neighbours); a peak two pixels share, dark pixels and an
 * image of one pixel stay; random images match the definition computed the slow way; bad
 * input is refused with out untouched.
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
#include "schedule_atoms.h"

enum { W = 5, H = 4 };

static void fill(double *img, size_t n, double v)
{
    for (size_t i = 0; i < n; ++i)
        img[i] = v;
}

static void test_lone_peak_takes_brightest_neighbour(void **state)
{
    (void)state;
    /* Every position: interior, border and corner. */
    for (size_t at = 0; at < (size_t)W * H; ++at) {
        double in[W * H], out[W * H];
        fill(in, W * H, 0.1);
        size_t x = at % W;
        in[at] = 1000.0;
        /* One neighbour brighter than the rest: the right one, or the left at the border. */
        size_t nb = x + 1 < W ? at + 1 : at - 1;
        in[nb] = 0.5;
        assert_int_equal(nf_guide_lower_peaks(W, H, in, out), NF_OK);
        assert_true(out[at] == 0.5);
        for (size_t i = 0; i < (size_t)W * H; ++i)
            if (i != at)
                assert_true(out[i] == in[i]);
    }
}

static void test_shared_peak_and_dark_pixels_stay(void **state)
{
    (void)state;
    double in[W * H], out[W * H];
    fill(in, W * H, 0.0);
    in[1 * W + 1] = 7.0;
    in[1 * W + 2] = 7.0;  /* two equal neighbours: neither is brighter than all the others */
    in[3 * W + 4] = -1.0; /* below its neighbours: kept */
    assert_int_equal(nf_guide_lower_peaks(W, H, in, out), NF_OK);
    for (size_t i = 0; i < (size_t)W * H; ++i)
        assert_true(out[i] == in[i]);
}

static void test_one_pixel_one_row_one_column(void **state)
{
    (void)state;
    double one = 3.0, kept = 0.0;
    assert_int_equal(nf_guide_lower_peaks(1, 1, &one, &kept), NF_OK);
    assert_true(kept == 3.0);
    const double line[3] = {1.0, 9.0, 2.0};
    double low[3];
    assert_int_equal(nf_guide_lower_peaks(3, 1, line, low), NF_OK);
    assert_true(low[0] == 1.0 && low[1] == 2.0 && low[2] == 2.0);
    memset(low, 0, sizeof low);
    assert_int_equal(nf_guide_lower_peaks(1, 3, line, low), NF_OK);
    assert_true(low[0] == 1.0 && low[1] == 2.0 && low[2] == 2.0);
}

/* The definition, the slow way: the largest of the up to 8 neighbours, bounds checked. */
static double slow_lowered(const double *in, size_t w, size_t h, size_t x, size_t y)
{
    double peak = -INFINITY;
    for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
            long nx = (long)x + dx, ny = (long)y + dy;
            if ((dx || dy) && nx >= 0 && ny >= 0 && nx < (long)w && ny < (long)h)
                peak = fmax(peak, in[(size_t)ny * w + (size_t)nx]);
        }
    double v = in[y * w + x];
    return w * h == 1 ? v : fmin(v, peak);
}

/* 2,000 random images of 1x1 to 9x9, values drawn from few levels so that ties happen, match
 * the definition exactly (both only compare and copy: no rounding to tolerate). */
static void test_matches_definition(void **state)
{
    (void)state;
    uint64_t rng = 0x9e3779b97f4a7c15u;
    for (int trial = 0; trial < 2000; ++trial) {
        double in[81], out[81];
        rng = rng * 6364136223846793005u + 1442695040888963407u;
        size_t w = 1 + (size_t)(rng >> 60) % 9, h = 1 + (size_t)(rng >> 56) % 9;
        for (size_t i = 0; i < w * h; ++i) {
            rng = rng * 6364136223846793005u + 1442695040888963407u;
            in[i] = (double)((rng >> 40) % 5) - 1.0 + ((rng >> 33) % 2 ? 1e300 : 0.0);
        }
        assert_int_equal(nf_guide_lower_peaks(w, h, in, out), NF_OK);
        for (size_t y = 0; y < h; ++y)
            for (size_t x = 0; x < w; ++x)
                assert_true(out[y * w + x] == slow_lowered(in, w, h, x, y));
    }
}

static void test_refuses(void **state)
{
    (void)state;
    double in[W * H], out[W * H];
    fill(in, W * H, 1.0);
    fill(out, W * H, 42.0);
    /* An empty image needs no arrays. */
    assert_int_equal(nf_guide_lower_peaks(0, H, NULL, NULL), NF_OK);
    assert_int_equal(nf_guide_lower_peaks(W, 0, NULL, NULL), NF_OK);
    assert_int_equal(nf_guide_lower_peaks(W, H, NULL, out), NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "reference is NULL"));
    assert_int_equal(nf_guide_lower_peaks(W, H, in, NULL), NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "out is NULL"));
    assert_int_equal(nf_guide_lower_peaks(SIZE_MAX / 2, 3, in, out), NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "overflows"));
    /* In place and shifted by one pixel either way. */
    assert_int_equal(nf_guide_lower_peaks(W, H, in, in), NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "overlap"));
    assert_int_equal(nf_guide_lower_peaks(W, H - 1, in, in + W), NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_guide_lower_peaks(W, H - 1, in + W, in), NF_ERROR_INVALID_ARGUMENT);
    /* Adjacent arrays do not overlap. */
    assert_int_equal(nf_guide_lower_peaks(W, 2, in, in + 2 * W), NF_OK);
    fill(in, W * H, 1.0);
    const double bad[3] = {NAN, INFINITY, -INFINITY};
    for (int b = 0; b < 3; ++b) {
        in[2 * W + 3] = bad[b];
        assert_int_equal(nf_guide_lower_peaks(W, H, in, out), NF_ERROR_INVALID_ARGUMENT);
        assert_non_null(strstr(nf_last_error_message(), "pixel 13 (x 3, y 2)"));
    }
    for (size_t i = 0; i < (size_t)W * H; ++i)
        assert_true(out[i] == 42.0); /* refused calls write nothing */
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_lone_peak_takes_brightest_neighbour),
    cmocka_unit_test(test_shared_peak_and_dark_pixels_stay),
    cmocka_unit_test(test_one_pixel_one_row_one_column),
    cmocka_unit_test(test_matches_definition),
    cmocka_unit_test(test_refuses),
)
