/*
 * test_peaks.c - image_lower_peaks (base/peaks.h): a lone peak takes its brightest
 * neighbour's value, anywhere in the image (corners and borders have fewer neighbours);
 * a peak shared by two pixels, dark pixels and an image of one pixel stay as they are.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>

#include "peaks.h"

enum { W = 5, H = 4 };

static void fill(double *img, double v)
{
    for (size_t i = 0; i < (size_t)W * H; ++i)
        img[i] = v;
}

static void test_lone_peak_takes_brightest_neighbour(void **state)
{
    (void)state;
    /* Every position: interior, border and corner. */
    for (size_t at = 0; at < (size_t)W * H; ++at) {
        double in[W * H], out[W * H];
        fill(in, 0.1);
        size_t x = at % W;
        in[at] = 1000.0;
        /* One neighbour brighter than the rest: the right one, or the left at the border. */
        size_t nb = x + 1 < W ? at + 1 : at - 1;
        in[nb] = 0.5;
        image_lower_peaks(in, W, H, out);
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
    fill(in, 0.0);
    in[1 * W + 1] = 7.0;
    in[1 * W + 2] = 7.0; /* two equal neighbours: neither is brighter than all the others */
    in[3 * W + 4] = -1.0; /* below its neighbours: kept */
    image_lower_peaks(in, W, H, out);
    for (size_t i = 0; i < (size_t)W * H; ++i)
        assert_true(out[i] == in[i]);
}

static void test_one_pixel_and_one_row(void **state)
{
    (void)state;
    double one = 3.0, kept = 0.0;
    image_lower_peaks(&one, 1, 1, &kept);
    assert_true(kept == 3.0);
    double row[3] = {1.0, 9.0, 2.0}, low[3];
    image_lower_peaks(row, 3, 1, low);
    assert_true(low[0] == 1.0 && low[1] == 2.0 && low[2] == 2.0);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_lone_peak_takes_brightest_neighbour),
        cmocka_unit_test(test_shared_peak_and_dark_pixels_stay),
        cmocka_unit_test(test_one_pixel_and_one_row),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
