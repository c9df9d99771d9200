/*
 * test_spline.c - the monotone rational-quadratic spline of docs/theory.md section 3 through the
 * public nf_spline_forward / nf_spline_inverse: an independent double-precision reference written
 * from the equations of docs/theory.md, exact end points, round trips, derivatives against finite
 * differences, the identity at zero raw parameters, monotonicity, and the inverse's dydx.
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
#include "blocks.h"

#define MAX_RAW (3u * NF_MAX_SPLINE_BINS + 1u)

/* One float ulp at 1: the absolute rounding unit of values in [0.5, 1). */
#define ULP1 (1.0 / 16777216.0) /* 2^-24 */

/* ---- reference implementation of docs/theory.md section 3, in double ------------------------- */

typedef struct ref_spline {
    uint32_t bins;
    double x[NF_MAX_SPLINE_BINS + 1], y[NF_MAX_SPLINE_BINS + 1], d[NF_MAX_SPLINE_BINS + 1];
} ref_spline;

static void ref_knots(uint32_t bins, const float *raw, double *knots)
{
    const double m = 1e-3;
    double top = raw[0], sum = 0.0, e[NF_MAX_SPLINE_BINS];
    for (uint32_t i = 1; i < bins; ++i)
        top = fmax(top, raw[i]);
    for (uint32_t i = 0; i < bins; ++i)
        sum += (e[i] = exp((double)raw[i] - top));
    knots[0] = 0.0;
    for (uint32_t i = 0; i < bins; ++i)
        knots[i + 1] = knots[i] + m + (1.0 - bins * m) * e[i] / sum;
    knots[bins] = 1.0;
}

static double ref_softplus(double a)
{
    return a > 0.0 ? a + log1p(exp(-a)) : log1p(exp(a));
}

static void ref_build(uint32_t bins, const float *raw, ref_spline *s)
{
    const double m = 1e-3, c = log(exp(1.0 - m) - 1.0);
    s->bins = bins;
    ref_knots(bins, raw, s->x);
    ref_knots(bins, raw + bins, s->y);
    for (uint32_t k = 0; k <= bins; ++k)
        s->d[k] = m + ref_softplus((double)raw[2 * bins + k] + c);
}

static uint32_t ref_bin(const ref_spline *s, double x)
{
    uint32_t k = 0;
    while (k + 1 < s->bins && x >= s->x[k + 1])
        ++k;
    return k;
}

static void ref_forward(const ref_spline *s, double x, double *y, double *dydx)
{
    uint32_t k = ref_bin(s, x);
    double w = s->x[k + 1] - s->x[k], h = s->y[k + 1] - s->y[k];
    double d0 = s->d[k], d1 = s->d[k + 1];
    double xi = (x - s->x[k]) / w, sk = h / w;
    double D = sk + (d1 + d0 - 2.0 * sk) * xi * (1.0 - xi);
    *y = s->y[k] + h * (sk * xi * xi + d0 * xi * (1.0 - xi)) / D;
    *dydx = sk * sk * (d1 * xi * xi + 2.0 * sk * xi * (1.0 - xi) + d0 * (1.0 - xi) * (1.0 - xi)) /
            (D * D);
}

/* The smallest bin width or height of the bin that x falls in (the conditioning of the bin). */
static double ref_bin_scale(const ref_spline *s, double x)
{
    uint32_t k = ref_bin(s, x);
    return fmin(s->x[k + 1] - s->x[k], s->y[k + 1] - s->y[k]);
}

/* Distance from x to the nearest interior knot. */
static double ref_knot_distance(const ref_spline *s, double x)
{
    double best = 1.0;
    for (uint32_t k = 1; k < s->bins; ++k)
        best = fmin(best, fabs(x - s->x[k]));
    return best;
}

/* d log(dydx) / dx at x: how fast the derivative changes, i.e. how much a small error in x or
 * in the knots (which shifts xi) changes it. l = 2 log s + log P - 2 log D with
 * P = d1 xi^2 + 2 s xi (1 - xi) + d0 (1 - xi)^2. */
static double ref_dlogd_dx(const ref_spline *s, double x)
{
    uint32_t k = ref_bin(s, x);
    double w = s->x[k + 1] - s->x[k], h = s->y[k + 1] - s->y[k];
    double d0 = s->d[k], d1 = s->d[k + 1], sk = h / w, xi = (x - s->x[k]) / w;
    double sum = d1 + d0 - 2.0 * sk;
    double P = d1 * xi * xi + 2.0 * sk * xi * (1.0 - xi) + d0 * (1.0 - xi) * (1.0 - xi);
    double dP = 2.0 * d1 * xi + 2.0 * sk * (1.0 - 2.0 * xi) - 2.0 * d0 * (1.0 - xi);
    double D = sk + sum * xi * (1.0 - xi), dD = sum * (1.0 - 2.0 * xi);
    return fabs(dP / P - 2.0 * dD / D) / w;
}

/* The tolerance of the derivative at x, relative: the library's knots are off by up to
 * ~(K + 8) 2^-24 (absolute; K float additions of widths <= 1, plus the softmax's rounding).
 * That shifts xi, moving log(dydx) by |d log(dydx)/dx| times it, and changes s = h/w and the
 * bin's scale by that over the bin's smallest width or height, which moves log(dydx) by at
 * most ~4x as much (dydx is a ratio of quadratics in s). A factor 4 on top for the
 * evaluation's own roundings and the first-order estimate. */
static double ref_dydx_tolerance(const ref_spline *s, double x)
{
    double knot_error = (s->bins + 8) * ULP1;
    /* Near a knot the library may place x in the neighbouring bin: take the worse of the
     * bins within knot_error of x. */
    double lo = fmax(x - knot_error, 0.0), hi = fmin(x + knot_error, 1.0);
    double slope = fmax(ref_dlogd_dx(s, lo), ref_dlogd_dx(s, hi));
    double scale = fmin(ref_bin_scale(s, lo), ref_bin_scale(s, hi));
    return 4.0 * knot_error * (slope + 4.0 / scale) + 1e-6;
}

/* Backward-error scale of the inverse's quadratic at the solution x: the solve computes
 * a = h (s - d0) + t S, b = h d0 - t S, c = -s t (S = d0 + d1 - 2 s, t = y - y_k) in float,
 * each with a few roundings relative to the magnitudes of its terms; a backward-stable root
 * solves a quadratic perturbed by that much, and the residual of the quadratic divided by
 * D(xi) is the error in y (y - y_k - t = residual / D). Returns
 * (h |s - d0| + 2 t |S| + h d0 + s t) / D in units of y; the round trip's tolerance in y is a
 * few ulps of 1 times this plus the evaluation's own rounding. */
static double ref_solve_scale(const ref_spline *s, double x)
{
    uint32_t k = ref_bin(s, x);
    double w = s->x[k + 1] - s->x[k], h = s->y[k + 1] - s->y[k];
    double d0 = s->d[k], d1 = s->d[k + 1], sk = h / w, xi = (x - s->x[k]) / w;
    double sum = d1 + d0 - 2.0 * sk, D = sk + sum * xi * (1.0 - xi);
    double t = h * (sk * xi * xi + d0 * xi * (1.0 - xi)) / D;
    return (h * fabs(sk - d0) + 2.0 * t * fabs(sum) + h * d0 + sk * t) / D;
}

/* ---- random inputs ------------------------------------------------------------------------ */

static void random_raw(nft_rng *r, uint32_t bins, float scale, float *raw)
{
    for (uint32_t i = 0; i < 3 * bins + 1; ++i)
        raw[i] = scale * (2.0f * nft_rng_float(r) - 1.0f);
}

static const uint32_t bin_choices[] = {2, 3, 8, 16, 64};
#define BIN_CHOICES (sizeof bin_choices / sizeof bin_choices[0])

/* Scales of the raw parameters: 0.5 is close to the identity, 3 is a typical trained spline,
 * 20 saturates the softmax and softplus (bins of the minimum width 1e-3, derivatives of 1e-3
 * and of ~20). */
static const float scale_choices[] = {0.5f, 3.0f, 20.0f};
#define SCALE_CHOICES (sizeof scale_choices / sizeof scale_choices[0])

/* The random splines a test runs on: `per_pair` of each pair of bin_choices x scales (the
 * scale_choices when scales is NULL), in that order, drawn from one seeded stream, each with
 * its double reference. The stream (r) is the test's too, for the points it draws on a
 * spline. */
typedef struct spline_case {
    nft_rng r;
    int next, count, per_pair;
    const float *scales;
    size_t scale_count;
    int index; /* the spline's number within its pair */
    uint32_t bins;
    float scale;
    float raw[MAX_RAW];
    ref_spline ref;
} spline_case;

static void spline_cases_begin(spline_case *c, uint64_t seed, int per_pair, const float *scales,
                               size_t scale_count)
{
    nft_rng_seed(&c->r, seed, 1u);
    c->next = 0;
    c->per_pair = per_pair;
    c->scales = scales ? scales : scale_choices;
    c->scale_count = scales ? scale_count : SCALE_CHOICES;
    c->count = per_pair * (int)(BIN_CHOICES * c->scale_count);
}

/* Draws the next case; 0 after the last. */
static int spline_cases_next(spline_case *c)
{
    if (c->next == c->count)
        return 0;
    size_t pair = (size_t)(c->next / c->per_pair);
    c->index = c->next++ % c->per_pair;
    c->bins = bin_choices[pair / c->scale_count];
    c->scale = c->scales[pair % c->scale_count];
    random_raw(&c->r, c->bins, c->scale, c->raw);
    ref_build(c->bins, c->raw, &c->ref);
    return 1;
}

/* Prints the raw parameters of a failing spline, so the failure can be reproduced. */
static void print_raw(uint32_t bins, const float *raw)
{
    print_error("  raw (%u bins):", bins);
    for (uint32_t k = 0; k < 3 * bins + 1; ++k)
        print_error(" %.9g", (double)raw[k]);
    print_error("\n");
}

/* ---- tests ----------------------------------------------------------------------------------- */

/* y and dydx against the double reference at 10^4+ random points of random splines. */
static void test_forward_matches_reference(void **state)
{
    (void)state;
    spline_case c;
    spline_cases_begin(&c, 1001u, 40, NULL, 0);
    double worst_y = 0.0, worst_d = 0.0;
    int points = 0;
    while (spline_cases_next(&c)) {
        for (int i = 0; i < 60; ++i, ++points) {
            float x = nft_rng_float(&c.r);
            float y, dydx;
            assert_int_equal(nf_spline_forward(c.bins, c.raw, x, &y, &dydx), NF_OK);
            double ry, rd;
            ref_forward(&c.ref, x, &ry, &rd);
            /* The library's knots are off by up to ~(K + 8) 2^-24 (see
             * ref_dydx_tolerance); a knot shift moves y by at most (1 + dydx) times as
             * much, and the evaluation adds a few ulps: factor 2. */
            double tol_y = 2.0 * (c.bins + 8) * ULP1 * (1.0 + rd);
            double tol_d = ref_dydx_tolerance(&c.ref, x);
            double ey = fabs(y - ry), ed = fabs(dydx - rd) / rd;
            worst_y = fmax(worst_y, ey / tol_y);
            worst_d = fmax(worst_d, ed / tol_d);
            if (ey > tol_y || ed > tol_d)
                fail_msg("bins %u scale %g x %.9g: y %.9g vs ref %.12g (tol %.3g), dydx "
                         "%.9g vs ref %.12g (rel %.3g, tol %.3g)",
                         c.bins, (double)c.scale, (double)x, (double)y, ry,
                         tol_y, (double)dydx, rd, ed, tol_d);
            assert_true(y >= 0.0f && y <= 1.0f);
            assert_true(dydx > 0.0f && isfinite(dydx));
        }
    }
    assert_true(points >= 10000);
    print_message("reference: %d points, worst error / tolerance: y %.3f, dydx %.3f\n", points,
                  worst_y, worst_d);
}

typedef nf_status (*spline_fn)(uint32_t bins, const float *raw, float in, float *out,
                               float *dydx);

/* f(0) = 0 and f(1) = 1 exactly for every kind of spline, and inputs outside [0,1] are
 * clamped to them: the spline fixes both end points, so its inverse must too. */
static void check_end_points(const char *name, spline_fn f)
{
    spline_case c;
    spline_cases_begin(&c, 1002u, 50, NULL, 0);
    int bad = 0;
    while (spline_cases_next(&c)) {
        float v0, v1, lo, hi;
        assert_int_equal(f(c.bins, c.raw, 0.0f, &v0, NULL), NF_OK);
        assert_int_equal(f(c.bins, c.raw, 1.0f, &v1, NULL), NF_OK);
        assert_int_equal(f(c.bins, c.raw, -0.5f, &lo, NULL), NF_OK);
        assert_int_equal(f(c.bins, c.raw, 7.0f, &hi, NULL), NF_OK);
        if (v0 != 0.0f || v1 != 1.0f || lo != 0.0f || hi != 1.0f) {
            if (bad++ < 5)
                print_error("bins %u scale %g spline %d: %s(0) = %a, %s(1) = %a, %s(-0.5) = %a, "
                            "%s(7) = %a\n",
                            c.bins, (double)c.scale, c.index, name, (double)v0, name,
                            (double)v1, name, (double)lo, name, (double)hi);
            if (bad <= 2)
                print_raw(c.bins, c.raw);
        }
    }
    if (bad)
        fail_msg("%d of %d splines do not map the end points exactly (%s)", bad, c.count, name);
}

static void test_forward_end_points_exact(void **state)
{
    (void)state;
    check_end_points("forward", nf_spline_forward);
}

static void test_inverse_end_points_exact(void **state)
{
    (void)state;
    check_end_points("inverse", nf_spline_inverse);
}

/* forward(inverse(y)) = y and inverse(forward(x)) = x on 10^4 points per range of parameters.
 * The tolerance in y is the backward-error bound of ref_solve_scale (8 ulps of 1 times the
 * quadratic's scale) plus the rounding of the two forward evaluations (4 ulps of 1 each) and of
 * x to float (dydx times ulp(x)); in x it is that divided by dydx plus 2 ulps of x: the
 * inverse of a flat stretch is ill-conditioned, and no float solve can do better. */
static void check_round_trip(float scale, uint64_t seed)
{
    spline_case c;
    spline_cases_begin(&c, seed, 50, &scale, 1);
    double worst = 0.0;
    int points = 0, bad = 0;
    while (spline_cases_next(&c)) {
        for (int i = 0; i < 50; ++i, ++points) {
            float x = nft_rng_float(&c.r), y, dydx, x2, dydx2, y2;
            assert_int_equal(nf_spline_forward(c.bins, c.raw, x, &y, &dydx), NF_OK);
            assert_int_equal(nf_spline_inverse(c.bins, c.raw, y, &x2, &dydx2), NF_OK);
            assert_int_equal(nf_spline_forward(c.bins, c.raw, x2, &y2, NULL), NF_OK);
            double tol_y = ULP1 * (8.0 * ref_solve_scale(&c.ref, x) + 8.0 + dydx);
            double tol_x = tol_y / dydx + 2.0 * FLT_EPSILON * x;
            double ey = fabs((double)y2 - y), ex = fabs((double)x2 - x);
            worst = fmax(worst, fmax(ey / tol_y, ex / tol_x));
            if (ey > tol_y || ex > tol_x) {
                if (bad++ < 5) {
                    print_error("bins %u scale %g: x %.9g -> y %.9g -> x %.9g -> y %.9g "
                                "(dydx %.4g; tol y %.3g, x %.3g)\n",
                                c.bins, (double)c.scale, (double)x, (double)y, (double)x2,
                                (double)y2, (double)dydx, tol_y, tol_x);
                    print_raw(c.bins, c.raw);
                }
            }
        }
    }
    print_message("round trip, |raw| <= %g: %d points, worst error / tolerance %.3f\n",
                  (double)scale, points, worst);
    if (bad)
        fail_msg("%d of %d round trips are off by more than the tolerance", bad, points);
}

static void test_round_trip_moderate(void **state)
{
    (void)state;
    check_round_trip(0.5f, 1003u);
    check_round_trip(3.0f, 1013u);
}

static void test_round_trip_extreme(void **state)
{
    (void)state;
    check_round_trip(20.0f, 1023u);
}

/* dydx against central differences of the library's own y, away from the knots (where the
 * second derivative jumps), and continuity of dydx across the knots. */
static void test_derivative_finite_differences(void **state)
{
    (void)state;
    /* Moderate parameters: bins wide enough to hold points 2h from every knot. */
    static const float moderate[] = {2.0f};
    spline_case c;
    spline_cases_begin(&c, 1004u, 60, moderate, 1);
    const double h = 1.0 / 4096.0;
    int checked = 0;
    double worst = 0.0, worst_knot = 0.0;
    while (spline_cases_next(&c)) {
        for (int i = 0; i < 40; ++i) {
            float x = (float)(2.0 * h + (1.0 - 4.0 * h) * nft_rng_double(&c.r));
            if (ref_knot_distance(&c.ref, x) < 2.5 * h)
                continue; /* x +- 2h must stay inside one bin: the RQ pieces are smooth */
            float xs[4] = {(float)(x - 2.0 * h), (float)(x - h), (float)(x + h),
                           (float)(x + 2.0 * h)};
            float ys[4], yc, dydx;
            for (int k = 0; k < 4; ++k)
                assert_int_equal(nf_spline_forward(c.bins, c.raw, xs[k], &ys[k], NULL), NF_OK);
            assert_int_equal(nf_spline_forward(c.bins, c.raw, x, &yc, &dydx), NF_OK);
            /* The steps actually taken (x +- h rounded to float), in double. */
            double fd1 = ((double)ys[2] - ys[1]) / ((double)xs[2] - xs[1]);
            double fd2 = ((double)ys[3] - ys[0]) / ((double)xs[3] - xs[0]);
            /* Central differences err by ~ h^2 y'''/6; fd2 errs four times as much, so
             * |fd2 - fd1| ~ 3x the truncation error of fd1 (a Richardson estimate): twice
             * that covers it with a factor 6. Each y carries <= 4 ulps of 1 of rounding,
             * so fd1 has a rounding error <= 8 2^-24 / (2h), and fd2 half that, which the
             * Richardson term may carry too: 3x. dydx itself is good to its own
             * tolerance (ref_dydx_tolerance). */
            double tol = 2.0 * fabs(fd2 - fd1) + 3.0 * 8.0 * ULP1 / (2.0 * h) +
                         ref_dydx_tolerance(&c.ref, x) * dydx;
            double err = fabs(fd1 - dydx);
            worst = fmax(worst, err / tol);
            ++checked;
            if (err > tol)
                fail_msg("bins %u x %.9g: dydx %.9g, central difference %.9g (h %g, "
                         "tol %.3g)",
                         c.bins, (double)x, (double)dydx, fd1, h, tol);
        }
        /* At each interior knot the derivative is continuous (d_k on both sides), even
         * though the second derivative jumps: compare dydx one float step to either side
         * with the reference's d_k, to the reference test's tolerance. */
        for (uint32_t k = 1; k < c.bins; ++k) {
            float knot = (float)c.ref.x[k];
            float side[2] = {nextafterf(knot, 0.0f), nextafterf(knot, 1.0f)};
            for (int j = 0; j < 2; ++j) {
                float y, d;
                assert_int_equal(nf_spline_forward(c.bins, c.raw, side[j], &y, &d), NF_OK);
                double tol = ref_dydx_tolerance(&c.ref, side[j]);
                worst_knot = fmax(worst_knot, fabs(d - c.ref.d[k]) / (tol * c.ref.d[k]));
                if (fabs(d - c.ref.d[k]) > tol * c.ref.d[k])
                    fail_msg("bins %u knot %u at %.9g: dydx %.9g at %.9g, d_k %.9g (tol "
                             "%.3g)",
                             c.bins, k, c.ref.x[k], (double)d, (double)side[j], c.ref.d[k], tol);
            }
        }
    }
    assert_true(checked > 5000);
    print_message("finite differences: %d points, worst error / tolerance %.3f; at knots %.3f\n",
                  checked, worst, worst_knot);
}

/* All raw parameters zero: the identity, y == x and dydx == 1 within a few ulps. */
static void test_identity_at_zero(void **state)
{
    (void)state;
    float raw[MAX_RAW];
    memset(raw, 0, sizeof raw);
    double worst_y = 0.0, worst_d = 0.0;
    for (size_t b = 0; b < BIN_CHOICES; ++b) {
        uint32_t bins = bin_choices[b];
        for (int i = 0; i <= 4096; ++i) {
            float x = (float)i / 4096.0f, y, dydx, xi, dydx_inv;
            assert_int_equal(nf_spline_forward(bins, raw, x, &y, &dydx), NF_OK);
            assert_int_equal(nf_spline_inverse(bins, raw, x, &xi, &dydx_inv), NF_OK);
            /* "A few ulps": the knots k/K are sums of m + (1 - K m)/K in float (exact for
             * power-of-two K, a few roundings otherwise), the derivatives 1 = m + softplus(c)
             * carry an ulp or two, and with them the identity is y = y_k + h xi to rounding:
             * y within 4 ulps of 1 (absolute), dydx within 4 FLT_EPSILON of 1. */
            double tol_y = 4.0 * ULP1, tol_d = 4.0 * FLT_EPSILON;
            worst_y = fmax(worst_y, fabs((double)y - x) / tol_y);
            worst_d = fmax(worst_d, fabs((double)dydx - 1.0) / tol_d);
            if (fabs((double)y - x) > tol_y || fabs((double)dydx - 1.0) > tol_d ||
                fabs((double)xi - x) > tol_y || fabs((double)dydx_inv - 1.0) > tol_d)
                fail_msg("bins %u x %.9g: y %.9g dydx %.9g; inverse %.9g dydx %.9g", bins,
                         (double)x, (double)y, (double)dydx, (double)xi, (double)dydx_inv);
        }
    }
    print_message("identity: worst error / tolerance: y %.3f, dydx %.3f\n", worst_y, worst_d);
}

/* Monotone on a fine grid: y never decreases by more than the rounding of one evaluation (a
 * bin's value at its right end is y_k + N/D in float, not exactly the next knot, so across a
 * knot the float spline may step back by a few ulps: 4 ulps of 1 allowed), and it strictly
 * increases wherever the reference says the exact rise exceeds 16 ulps of 1 (smaller rises
 * drown in rounding: the flattest stretches of extreme splines have dydx ~ 1e-7). */
static void test_monotone(void **state)
{
    (void)state;
    spline_case c;
    spline_cases_begin(&c, 1005u, 8, NULL, 0);
    const double slack = 4.0 * ULP1, resolvable = 16.0 * ULP1;
    int strict_checks = 0;
    while (spline_cases_next(&c)) {
        const int n = 16384;
        float prev = 0.0f;
        double prev_ref = 0.0, dummy;
        for (int i = 0; i <= n; ++i) {
            float x = (float)i / (float)n, y, dydx;
            assert_int_equal(nf_spline_forward(c.bins, c.raw, x, &y, &dydx), NF_OK);
            assert_true(y >= 0.0f && y <= 1.0f && dydx > 0.0f);
            double ry;
            ref_forward(&c.ref, x, &ry, &dummy);
            if (i > 0) {
                if ((double)y < (double)prev - slack)
                    fail_msg("bins %u scale %g: y(%.9g) = %.9g < previous %.9g", c.bins,
                             (double)c.scale, (double)x, (double)y, (double)prev);
                if (ry - prev_ref > resolvable) {
                    ++strict_checks;
                    if (!(y > prev))
                        fail_msg("bins %u scale %g: y(%.9g) = %.9g <= previous %.9g "
                                 "though the exact rise is %.3g",
                                 c.bins, (double)c.scale, (double)x, (double)y,
                                 (double)prev, ry - prev_ref);
                }
            }
            prev = y;
            prev_ref = ry;
        }
    }
    assert_true(strict_checks > 100000);
}

/* The inverse is monotone too: on a fine grid of y, x never decreases by more than the
 * round-trip tolerance of check_round_trip at that point (an inverse that is accurate to
 * that tolerance cannot step back further), and it strictly increases wherever the exact
 * inverse rises by more than twice that tolerance. */
static void test_inverse_monotone(void **state)
{
    (void)state;
    spline_case c;
    spline_cases_begin(&c, 1008u, 8, NULL, 0);
    int bad = 0, strict_checks = 0;
    while (spline_cases_next(&c)) {
        const int n = 16384;
        float prev = 0.0f;
        for (int i = 0; i <= n; ++i) {
            float y = (float)i / (float)n, x, dydx;
            assert_int_equal(nf_spline_inverse(c.bins, c.raw, y, &x, &dydx), NF_OK);
            assert_true(x >= 0.0f && x <= 1.0f && dydx > 0.0f);
            double tol_y = ULP1 * (8.0 * ref_solve_scale(&c.ref, x) + 8.0 + dydx);
            double tol_x = tol_y / dydx + 2.0 * FLT_EPSILON * x;
            if (i > 0) {
                if ((double)x < (double)prev - tol_x && bad++ < 5)
                    print_error("bins %u scale %g: inverse(%.9g) = %.9g < previous "
                                "%.9g (tol %.3g)\n",
                                c.bins, (double)c.scale, (double)y, (double)x,
                                (double)prev, tol_x);
                /* The exact rise over the step 1/n is >= (1/n) / max dydx; use the
                 * derivative at x as its estimate only when it is unambiguous. */
                if ((1.0 / n) / dydx > 2.0 * tol_x + 1e-4) {
                    ++strict_checks;
                    if (!(x > prev) && bad++ < 5)
                        print_error("bins %u scale %g: inverse(%.9g) = %.9g <= previous "
                                    "%.9g\n",
                                    c.bins, (double)c.scale, (double)y, (double)x,
                                    (double)prev);
                }
            }
            prev = x;
        }
    }
    assert_true(strict_checks > 10000);
    if (bad)
        fail_msg("the inverse decreased %d times", bad);
}

/* The inverse's dydx is the forward derivative at the solution. */
static void test_inverse_derivative(void **state)
{
    (void)state;
    spline_case c;
    spline_cases_begin(&c, 1006u, 20, NULL, 0);
    while (spline_cases_next(&c)) {
        for (int i = 0; i < 50; ++i) {
            float y = nft_rng_float(&c.r), x, d_inv, y2, d_fwd;
            assert_int_equal(nf_spline_inverse(c.bins, c.raw, y, &x, &d_inv), NF_OK);
            assert_int_equal(nf_spline_forward(c.bins, c.raw, x, &y2, &d_fwd), NF_OK);
            /* The same function at the same x: equal up to the evaluation's rounding,
             * unless x sits on a knot and the two calls pick neighbouring c.bins; dydx
             * is continuous there, so both agree to the reference test's tolerance. */
            double tol = ref_dydx_tolerance(&c.ref, x);
            if (fabs((double)d_inv - d_fwd) > tol * d_fwd)
                fail_msg("bins %u: inverse(%.9g) = %.9g with dydx %.9g, forward dydx "
                         "%.9g",
                         c.bins, (double)y, (double)x, (double)d_inv, (double)d_fwd);
            /* And it is the reference's derivative at x. */
            double ry, rd;
            ref_forward(&c.ref, x, &ry, &rd);
            if (fabs((double)d_inv - rd) > tol * rd)
                fail_msg("bins %u: inverse dydx %.9g at x %.9g, reference %.9g", c.bins,
                         (double)d_inv, (double)x, rd);
        }
    }
}

/* The knots follow the formulas of docs/theory.md: the library's spline passes through the
 * reference's knots (x_k, y_k) of random and extreme parameters. */
static void test_knots_interpolated(void **state)
{
    (void)state;
    nft_rng r;
    nft_rng_seed(&r, 1007u, 1u);
    float raw[MAX_RAW];
    ref_spline ref;
    for (int spline = 0; spline < 200; ++spline) {
        uint32_t bins = bin_choices[spline % BIN_CHOICES];
        random_raw(&r, bins, spline < 100 ? 3.0f : 20.0f, raw);
        ref_build(bins, raw, &ref);
        for (uint32_t k = 1; k < bins; ++k) {
            float y, dydx;
            assert_int_equal(nf_spline_forward(bins, raw, (float)ref.x[k], &y, &dydx), NF_OK);
            /* (float)x_k is within half an ulp of x_k; the library's own knot within ~K ulps
             * of 1; the value moves by (1 + dydx) times that (as in the reference test). */
            double tol = 2.0 * (bins + 8) * ULP1 * (1.0 + ref.d[k]);
            if (fabs((double)y - ref.y[k]) > tol)
                fail_msg("bins %u knot %u: x_k %.9g, y %.9g, reference y_k %.9g", bins, k,
                         ref.x[k], (double)y, ref.y[k]);
        }
    }
}

/* Invalid arguments are refused (and the outputs untouched). */
static void test_invalid_arguments(void **state)
{
    (void)state;
    float raw[MAX_RAW];
    memset(raw, 0, sizeof raw);
    float y = 42.0f;
    assert_int_equal(nf_spline_forward(1, raw, 0.5f, &y, NULL), NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_spline_forward(NF_MAX_SPLINE_BINS + 1, raw, 0.5f, &y, NULL),
                     NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_spline_forward(8, NULL, 0.5f, &y, NULL), NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_spline_forward(8, raw, 0.5f, NULL, NULL), NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_spline_forward(8, raw, NAN, &y, NULL), NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_spline_inverse(8, raw, INFINITY, &y, NULL), NF_ERROR_INVALID_ARGUMENT);
    raw[5] = NAN;
    assert_int_equal(nf_spline_forward(8, raw, 0.5f, &y, NULL), NF_ERROR_INVALID_ARGUMENT);
    assert_true(y == 42.0f);
    /* The largest bin count works. */
    memset(raw, 0, sizeof raw);
    assert_int_equal(nf_spline_forward(NF_MAX_SPLINE_BINS, raw, 0.25f, &y, NULL), NF_OK);
    assert_true(fabsf(y - 0.25f) < 1e-5f); /* identity, see test_identity_at_zero */
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_forward_matches_reference),
    cmocka_unit_test(test_forward_end_points_exact),
    cmocka_unit_test(test_inverse_end_points_exact),
    cmocka_unit_test(test_round_trip_moderate),
    cmocka_unit_test(test_round_trip_extreme),
    cmocka_unit_test(test_derivative_finite_differences),
    cmocka_unit_test(test_identity_at_zero),
    cmocka_unit_test(test_monotone),
    cmocka_unit_test(test_inverse_monotone),
    cmocka_unit_test(test_inverse_derivative),
    cmocka_unit_test(test_knots_interpolated),
    cmocka_unit_test(test_invalid_arguments),
)
