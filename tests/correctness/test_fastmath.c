/*
 * test_fastmath.c - the error bounds that src/kernels/fastmath.h documents, measured against
 * double-precision libm over each function's stated domain. fastmath.h is header-only and
 * internal, so this test includes it directly.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>

#include "nf_test_main.h"
#include <math.h>

#include "../../src/kernels/fastmath.h"

#define PI 3.14159265358979323846

/* The bound every approximation documents: 3e-7, five float ulps at 1. Each test sweeps its
 * domain densely enough (>= 10^6 points) that a polynomial's worst case cannot hide between
 * samples: the error curves oscillate on scales of ~1e-2 of the reduced range. */
#define BOUND 3e-7

static void test_exp_relative_error(void **state)
{
    (void)state;
    double worst = 0.0;
    for (int i = 0; i <= 2000000; ++i) {
        float x = (float)(-87.0 + 175.0 * i / 2000000.0);
        double ref = exp((double)x);
        worst = fmax(worst, fabs((double)nf_fast_exp(x) - ref) / ref);
    }
    print_message("nf_fast_exp: worst relative error %.3g\n", worst);
    assert_true(worst < BOUND);
    /* outside the domain the input is clamped: finite, positive, no overflow */
    assert_true(isfinite(nf_fast_exp(1000.0f)) && nf_fast_exp(-1000.0f) > 0.0f);
}

static void test_log_error(void **state)
{
    (void)state;
    double worst_abs = 0.0, worst_rel = 0.0;
    for (int i = 0; i <= 2000000; ++i) {
        float x = (float)exp(-69.0 + 138.0 * i / 2000000.0); /* 1e-30 .. 1e30 */
        double ref = log((double)x), err = fabs((double)nf_fast_log(x) - ref);
        if (fabs(ref) <= 1.0)
            worst_abs = fmax(worst_abs, err);
        else
            worst_rel = fmax(worst_rel, err / fabs(ref));
    }
    print_message("nf_fast_log: worst absolute error %.3g (|log| <= 1), relative %.3g\n",
                  worst_abs, worst_rel);
    assert_true(worst_abs < BOUND);
    assert_true(worst_rel < BOUND);
    assert_true(nf_fast_log(1.0f) == 0.0f);
}

static void test_sincos_error(void **state)
{
    (void)state;
    double worst = 0.0, worst_small = 0.0;
    for (int i = 0; i <= 2000000; ++i) {
        float t = (float)(-1.0 + 2.0 * i / 2000000.0);
        float s, c;
        nf_fast_sincos_turns(t, &s, &c);
        double a = 2.0 * PI * (double)t;
        worst = fmax(worst, fmax(fabs(s - sin(a)), fabs(c - cos(a))));
    }
    /* Near zero the sine must be relatively accurate: the library divides by sin(theta). */
    for (float t = 1e-9f; t < 1e-2f; t *= 1.001f) {
        float s, c;
        nf_fast_sincos_turns(t, &s, &c);
        double ref = sin(2.0 * PI * (double)t);
        worst_small = fmax(worst_small, fabs(s - ref) / ref);
    }
    print_message("nf_fast_sincos_turns: worst absolute error %.3g, relative near 0 %.3g\n",
                  worst, worst_small);
    assert_true(worst < BOUND);
    assert_true(worst_small < BOUND);
}

static void test_atan2_error(void **state)
{
    (void)state;
    double worst = 0.0, worst_small = 0.0;
    for (int i = 0; i < 2000000; ++i) {
        double a = -PI + 2.0 * PI * (i + 0.5) / 2000000.0;
        float y = (float)(3.0 * sin(a)), x = (float)(3.0 * cos(a));
        double ref = atan2((double)y, (double)x);
        worst = fmax(worst, fabs((double)nf_fast_atan2(y, x) - ref));
    }
    for (float y = 1e-9f; y < 1e-2f; y *= 1.001f) {
        double ref = atan2((double)y, 1.0);
        worst_small = fmax(worst_small, fabs((double)nf_fast_atan2(y, 1.0f) - ref) / ref);
    }
    print_message("nf_fast_atan2: worst absolute error %.3g rad, relative near 0 %.3g\n",
                  worst, worst_small);
    assert_true(worst < BOUND);
    assert_true(worst_small < BOUND);
    /* the conventions the parameterization relies on */
    assert_true(nf_fast_atan2(0.0f, 0.0f) == 0.0f);
    assert_true(nf_fast_atan2(0.0f, -1.0f) > 3.1415925f);
    assert_true(nf_fast_atan2(-1e-30f, 1.0f) <= 0.0f);
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_exp_relative_error),
    cmocka_unit_test(test_log_error),
    cmocka_unit_test(test_sincos_error),
    cmocka_unit_test(test_atan2_error),
)
