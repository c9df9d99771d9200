/*
 * test_encoding.c - the conditioner's input encodings and the direction <-> square map
 * (docs/theory.md sections 1 and 5) through nf_encode_oneblob, nf_encode_sh, nf_direction_to_square
 * and nf_square_to_direction, against formulas written here in double.
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

#define SH_MAX (NF_MAX_SH_BANDS * NF_MAX_SH_BANDS)

/* ---- one-blob ------------------------------------------------------------------------------ */

/* Q of docs/theory.md section 5, in double. */
static double ref_q(double t, double bins)
{
    double u = fmin(fmax(t * bins, -1.0), 1.0);
    double q = 15.0 / 16.0 * u * (1.0 - 2.0 * u * u / 3.0 + u * u * u * u / 5.0) + 0.5;
    return fmin(fmax(q, 0.0), 1.0);
}

static double ref_oneblob(double v, uint32_t bins, uint32_t j)
{
    v = fmin(fmax(v, 0.0), 1.0);
    return ref_q((j + 1.0) / bins - v, bins) - ref_q((double)j / bins - v, bins);
}

/* The one-blob tolerance (absolute, per bin): the library forms v B in float (relative
 * rounding 2^-24, so an absolute error up to B 2^-24 in the kernel's argument), and Q's slope
 * is at most 15/16, so each Q moves by <= B 2^-24; the quartic polynomial and the subtraction
 * add a few ulps of 1. Two Qs per bin: 2 (B + 4) 2^-24. */
static double oneblob_tolerance(uint32_t bins)
{
    return 2.0 * (bins + 4.0) / 16777216.0;
}

static void test_oneblob_matches_formula(void **state)
{
    (void)state;
    static const uint32_t bin_counts[] = {2, 3, 7, 16, 32, 64};
    nft_rng r;
    nft_rng_seed(&r, 2001u, 1u);
    float out[NF_MAX_ONEBLOB_BINS + 1];
    double worst = 0.0;
    for (size_t b = 0; b < sizeof bin_counts / sizeof bin_counts[0]; ++b) {
        uint32_t bins = bin_counts[b];
        double tol = oneblob_tolerance(bins);
        for (int i = 0; i < 3000; ++i) {
            float v;
            if (i < 2 * (int)bins + 1)
                v = (float)i / (2.0f * (float)bins); /* bin edges and centres exactly */
            else if (i < 2 * (int)bins + 40)
                v = (float)(i - 2 * (int)bins) / 39.0f * 2.0f / (float)bins; /* near 0 */
            else
                v = nft_rng_float(&r);
            out[bins] = 12345.0f; /* sentinel: nothing is written past `bins` */
            nf_encode_oneblob(v, bins, out);
            assert_true(out[bins] == 12345.0f);
            int nonzero = 0;
            double sum = 0.0;
            for (uint32_t j = 0; j < bins; ++j) {
                double ref = ref_oneblob(v, bins, j), err = fabs(out[j] - ref);
                worst = fmax(worst, err / tol);
                if (err > tol)
                    fail_msg("B %u v %.9g bin %u: %.9g, formula %.12g", bins, (double)v, j,
                             (double)out[j], ref);
                /* In [0,1] up to the tolerance: the float quartic does not vanish exactly at
                 * the kernel's edge (Q(-1) rounds to 2^-25, not 0), so a bin next to the
                 * blob may come out as -2^-25. */
                if (!(out[j] >= -tol && out[j] <= 1.0 + tol))
                    fail_msg("B %u v %.9g bin %u: %.9g (%a) outside [0, 1]", bins, (double)v, j,
                             (double)out[j], (double)out[j]);
                nonzero += out[j] != 0.0f;
                sum += out[j];
            }
            if (nonzero > 3 || nonzero < 1)
                fail_msg("B %u v %.9g: %d non-zero bins", bins, (double)v, nonzero);
            /* The sum telescopes to Q((1 - v) B) - Q(-v B): exactly 1 when the kernel (radius
             * 1/B) lies inside [0,1], i.e. 1/B <= v <= 1 - 1/B. Up to B float terms of which
             * at most 3 are non-zero, each within the tolerance above. */
            double expect = ref_q(1.0 - v, bins) - ref_q(-(double)v, bins);
            if (fabs(sum - expect) > 3.0 * tol)
                fail_msg("B %u v %.9g: sum %.9g, expected %.9g", bins, (double)v, sum, expect);
            if (v >= 1.0f / (float)bins && v <= 1.0f - 1.0f / (float)bins &&
                fabs(sum - 1.0) > 3.0 * tol)
                fail_msg("B %u v %.9g well inside: sum %.9g != 1", bins, (double)v, sum);
        }
    }
    print_message("one-blob: worst error / tolerance %.3f\n", worst);
}

/* At the edges half of the kernel falls outside [0,1]: v = 0 and v = 1 sum to 1/2 (Q(0) =
 * 1/2), and values outside [0,1] are clamped to the edges. */
static void test_oneblob_edges(void **state)
{
    (void)state;
    float out[NF_MAX_ONEBLOB_BINS], clamped[NF_MAX_ONEBLOB_BINS];
    for (uint32_t bins = 2; bins <= NF_MAX_ONEBLOB_BINS; bins += 7) {
        double tol = 3.0 * oneblob_tolerance(bins); /* three non-zero terms, as above */
        for (int end = 0; end < 2; ++end) {
            nf_encode_oneblob((float)end, bins, out);
            double sum = 0.0;
            for (uint32_t j = 0; j < bins; ++j)
                sum += out[j];
            if (fabs(sum - 0.5) > tol)
                fail_msg("B %u v %d: sum %.9g, expected 1/2", bins, end, sum);
            /* Only the edge bin(s) are non-zero: the kernel reaches 1/B into the domain. */
            uint32_t edge = end ? bins - 1 : 0;
            assert_true(out[edge] > 0.4f);
            nf_encode_oneblob(end ? 3.5f : -2.0f, bins, clamped);
            assert_memory_equal(out, clamped, bins * sizeof(float));
        }
    }
    /* No-ops: bins 0 and out NULL must not crash or write. */
    out[0] = 7.0f;
    nf_encode_oneblob(0.5f, 0, out);
    assert_true(out[0] == 7.0f);
    nf_encode_oneblob(0.5f, 8, NULL);
}

/* Bin j sits at position j/B: the encoding's centre of mass sum_j (j + 1/2)/B out_j follows v
 * (within a quarter bin) for v well inside, where the whole kernel lies in [0,1]. */
static void test_oneblob_centre(void **state)
{
    (void)state;
    float out[NF_MAX_ONEBLOB_BINS];
    const uint32_t bins = 32;
    for (int i = 0; i <= 1000; ++i) {
        float v = 1.0f / bins + (1.0f - 2.0f / bins) * (float)i / 1000.0f;
        nf_encode_oneblob(v, bins, out);
        double centre = 0.0;
        for (uint32_t j = 0; j < bins; ++j)
            centre += (j + 0.5) / bins * out[j];
        /* The library's centre against the formula's, to three bins' tolerance (at most
         * three non-zero bins, weights (j + 1/2)/B <= 1). */
        double ref = 0.0;
        for (uint32_t j = 0; j < bins; ++j)
            ref += (j + 0.5) / bins * ref_oneblob(v, bins, j);
        if (fabs(centre - ref) > 3.0 * oneblob_tolerance(bins))
            fail_msg("v %.9g: centre %.9g, formula %.9g", (double)v, centre, ref);
        /* ... and the formula's centre is v to within a quarter bin: the bin-centre rule
         * applied to a symmetric kernel of radius 1/B errs by less than half a bin. */
        assert_true(fabs(ref - v) < 0.25 / bins);
    }
}

/* ---- spherical harmonics --------------------------------------------------------------------- */

/* Gauss-Legendre nodes and weights on [-1, 1] (Newton on P_n, in double). */
static void gauss_legendre(int n, double *x, double *w)
{
    for (int i = 0; i < n; ++i) {
        double z = cos(NFT_PI * (i + 0.75) / (n + 0.5)), dp = 1.0;
        for (int it = 0; it < 100; ++it) {
            double p0 = 1.0, p1 = z;
            for (int k = 2; k <= n; ++k) {
                double p2 = ((2.0 * k - 1.0) * z * p1 - (k - 1.0) * p0) / k;
                p0 = p1;
                p1 = p2;
            }
            dp = n * (z * p1 - p0) / (z * z - 1.0);
            double dz = p1 / dp;
            z -= dz;
            if (fabs(dz) < 1e-16)
                break;
        }
        x[i] = z;
        w[i] = 2.0 / ((1.0 - z * z) * dp * dp);
    }
}

/* The Legendre polynomial P_l(z), in double. */
static double legendre(int l, double z)
{
    double p0 = 1.0, p1 = z;
    if (l == 0)
        return 1.0;
    for (int k = 2; k <= l; ++k) {
        double p2 = ((2.0 * k - 1.0) * z * p1 - (k - 1.0) * p0) / k;
        p0 = p1;
        p1 = p2;
    }
    return p1;
}

/* The Gram matrix of the SH basis by quadrature: Gauss-Legendre in cos(theta) with n nodes is
 * exact for polynomials of degree 2n - 1, and a uniform phi grid of P points integrates
 * trigonometric polynomials of degree < P exactly. Products of two real SH of bands < L are
 * (in z) polynomials of degree <= 2L - 2 times sin^(m+m') and (in phi) trigonometric of degree
 * <= 2L - 2, so n = L and P = 2L suffice; we use n = 2L, P = 4L. The quadrature is then exact
 * and the Gram matrix differs from the identity only by the float rounding of the SH values
 * (2^-24 relative) and of the float directions (~6e-8, moving a band-l harmonic by ~l times
 * that): each entry within ~L * 1e-7 * sum |Y_a Y_b| w <= ~1e-6. Tolerance 1e-5. */
static void test_sh_orthonormal(void **state)
{
    (void)state;
    const uint32_t L = NF_MAX_SH_BANDS, count = L * L;
    const int n = 2 * (int)L, P = 4 * (int)L;
    double x[4 * NF_MAX_SH_BANDS], w[4 * NF_MAX_SH_BANDS];
    gauss_legendre(n, x, w);
    double gram[SH_MAX][SH_MAX];
    memset(gram, 0, sizeof gram);
    float y[SH_MAX];
    double weight_sum = 0.0;
    for (int i = 0; i < n; ++i) {
        double z = x[i], s = sqrt(fmax(0.0, 1.0 - z * z));
        for (int j = 0; j < P; ++j) {
            double phi = 2.0 * NFT_PI * (j + 0.5) / P, wt = w[i] * 2.0 * NFT_PI / P;
            float dir[3] = {(float)(s * cos(phi)), (float)(s * sin(phi)), (float)z};
            nf_encode_sh(dir, L, y);
            weight_sum += wt;
            for (uint32_t a = 0; a < count; ++a)
                for (uint32_t b = 0; b < count; ++b)
                    gram[a][b] += wt * (double)y[a] * y[b];
        }
    }
    assert_true(fabs(weight_sum - 4.0 * NFT_PI) < 1e-12); /* the quadrature's area */
    double worst = 0.0;
    for (uint32_t a = 0; a < count; ++a) {
        for (uint32_t b = 0; b < count; ++b) {
            double expect = a == b ? 1.0 : 0.0, err = fabs(gram[a][b] - expect);
            worst = fmax(worst, err);
            if (err > 1e-5)
                fail_msg("Gram[%u][%u] = %.9g, expected %g", a, b, gram[a][b], expect);
        }
    }
    print_message("SH Gram matrix (%u bands): worst |G - I| %.3g\n", L, worst);
}

/* Y_00 = 0.28209479 everywhere; each band's zonal harmonic (m = 0, at index l^2 + l) is
 * sqrt((2l+1)/(4 pi)) P_l(cos theta), a convention-free check of the ordering by l then m; the
 * band's power sum_m Y_lm^2 = (2l+1)/(4 pi) everywhere (addition theorem); parity
 * Y_lm(-w) = (-1)^l Y_lm(w); and fewer bands give a prefix of more bands. */
static void test_sh_values(void **state)
{
    (void)state;
    nft_rng r;
    nft_rng_seed(&r, 2002u, 1u);
    float y[SH_MAX], yn[SH_MAX], prefix[SH_MAX + 1];
    for (int i = 0; i < 2000; ++i) {
        float d[3], neg[3];
        if (i == 0) {
            d[0] = 0.0f, d[1] = 0.0f, d[2] = 1.0f;
        } else if (i == 1) {
            d[0] = 0.0f, d[1] = 0.0f, d[2] = -1.0f;
        } else {
            nft_random_unit_vector(&r, d);
        }
        for (int k = 0; k < 3; ++k)
            neg[k] = -d[k];
        nf_encode_sh(d, NF_MAX_SH_BANDS, y);
        nf_encode_sh(neg, NF_MAX_SH_BANDS, yn);
        /* Y_00 is a constant: its float value is the rounding of 1/(2 sqrt(pi)); 1 ulp. */
        assert_true(fabs(y[0] - 0.28209479177387814) <= 3e-8);
        double z = d[2];
        for (uint32_t l = 0; l < NF_MAX_SH_BANDS; ++l) {
            double norm = (2.0 * l + 1.0) / (4.0 * NFT_PI);
            double zonal = sqrt(norm) * legendre((int)l, z);
            /* Float rounding of the value (2^-24 relative of values <= ~1.5) and of the
             * float direction (moving the band-l value by <= ~l^2 6e-8): 1e-6. */
            if (fabs(y[l * l + l] - zonal) > 1e-6)
                fail_msg("Y_%u,0 at z = %.9g: %.9g, expected %.9g", l, z, (double)y[l * l + l],
                         zonal);
            double power = 0.0;
            for (uint32_t m = 0; m < 2 * l + 1; ++m) {
                double v = y[l * l + m];
                power += v * v;
                /* Parity: the negated float vector is exact, so only the SH's own rounding
                 * differs: 2 ulps of values <= ~1.5: 4e-7. */
                double parity = (l % 2) ? -v : v;
                if (fabs(yn[l * l + m] - parity) > 4e-7)
                    fail_msg("band %u index %u: Y(-w) = %.9g, expected %.9g", l, m,
                             (double)yn[l * l + m], parity);
            }
            /* Relative: 2l+1 values each with ~2^-23 relative error after squaring, plus the
             * direction's rounding: 1e-5 relative. */
            if (fabs(power - norm) > 1e-5 * norm)
                fail_msg("band %u at (%g, %g, %g): power %.9g, expected %.9g", l, (double)d[0],
                         (double)d[1], (double)d[2], power, norm);
        }
        for (uint32_t bands = 0; bands <= NF_MAX_SH_BANDS; ++bands) {
            prefix[bands * bands] = -99.0f; /* sentinel */
            nf_encode_sh(d, bands, prefix);
            assert_true(prefix[bands * bands] == -99.0f);
            if (bands)
                assert_memory_equal(prefix, y, bands * bands * sizeof(float));
        }
    }
}

/* nf_encode_sh of a non-unit vector equals that of the normalized vector; a zero or
 * non-finite vector yields zeros. */
static void test_sh_normalizes(void **state)
{
    (void)state;
    nft_rng r;
    nft_rng_seed(&r, 2003u, 1u);
    static const float scales[] = {1e-6f, 0.01f, 0.5f, 3.7f, 1000.0f, 1e12f};
    float unit_sh[SH_MAX], scaled_sh[SH_MAX];
    for (int i = 0; i < 500; ++i) {
        float d[3];
        nft_random_unit_vector(&r, d);
        nf_encode_sh(d, NF_MAX_SH_BANDS, unit_sh);
        for (size_t s = 0; s < sizeof scales / sizeof scales[0]; ++s) {
            float v[3] = {d[0] * scales[s], d[1] * scales[s], d[2] * scales[s]};
            nf_encode_sh(v, NF_MAX_SH_BANDS, scaled_sh);
            for (uint32_t k = 0; k < SH_MAX; ++k) {
                /* Scaling and renormalizing in float moves the unit vector by a few ulps
                 * (~2e-7), which moves a harmonic of band <= 5 by <= ~25 times that; plus the
                 * value's own rounding: 1e-5. */
                if (fabs(scaled_sh[k] - unit_sh[k]) > 1e-5)
                    fail_msg("scale %g index %u: %.9g vs unit %.9g", (double)scales[s], k,
                             (double)scaled_sh[k], (double)unit_sh[k]);
            }
        }
    }
    const float zero[3] = {0.0f, 0.0f, 0.0f}, bad[3] = {NAN, 0.0f, 1.0f};
    nf_encode_sh(zero, NF_MAX_SH_BANDS, scaled_sh);
    for (uint32_t k = 0; k < SH_MAX; ++k)
        assert_true(scaled_sh[k] == 0.0f);
    nf_encode_sh(bad, NF_MAX_SH_BANDS, unit_sh);
    for (uint32_t k = 0; k < SH_MAX; ++k)
        assert_true(unit_sh[k] == 0.0f);
}

/* ---- the direction <-> square map ------------------------------------------------------------ */

static void test_square_round_trip(void **state)
{
    (void)state;
    nft_rng r;
    nft_rng_seed(&r, 2004u, 1u);
    for (int i = 0; i < 20000; ++i) {
        float d[3], s[2], back[3];
        nft_random_unit_vector(&r, d);
        nf_direction_to_square(d, s);
        assert_true(s[0] >= 0.0f && s[0] <= 1.0f && s[1] >= 0.0f && s[1] < 1.0f);
        /* s against docs/theory.md section 1 in double: theta/pi within a few float roundings of
         * values <= 1 (hypotf, atan2f, the division): 4 2^-24 absolute; phi/(2 pi) also goes
         * through the wrap phi + 2 pi, a rounding of values up to 2 pi (~1.3 2^-24 of s1 by
         * itself): 8 2^-24. Values wrapped across the seam (s1 near 0 vs 1) compare mod 1. */
        double theta, phi;
        nft_direction_angles(d, &theta, &phi);
        if (fabs(s[0] - theta / NFT_PI) > 4.0 / 16777216.0 ||
            (fabs(s[1] - phi / (2.0 * NFT_PI)) > 8.0 / 16777216.0 &&
             fabs(fabs(s[1] - phi / (2.0 * NFT_PI)) - 1.0) > 8.0 / 16777216.0))
            fail_msg("(%.9g, %.9g, %.9g) -> (%.9g, %.9g); expected (%.9g, %.9g)", (double)d[0],
                     (double)d[1], (double)d[2], (double)s[0], (double)s[1], theta / NFT_PI,
                     phi / (2.0 * NFT_PI));
        nf_square_to_direction(s, back);
        /* The direction from float angles: each component within a few ulps of 1 plus the
         * angles' rounding (s within 8 2^-24, times 2 pi): 1e-6. */
        for (int k = 0; k < 3; ++k)
            if (fabs(back[k] - d[k]) > 1e-6)
                fail_msg("(%.9g, %.9g, %.9g) -> (%.9g, %.9g) -> (%.9g, %.9g, %.9g)",
                         (double)d[0], (double)d[1], (double)d[2], (double)s[0], (double)s[1],
                         (double)back[0], (double)back[1], (double)back[2]);
        /* square -> direction -> square, away from the poles where phi is ill-defined. */
        float s2[2] = {nft_rng_float(&r), nft_rng_float(&r)}, w[3], s3[2];
        nf_square_to_direction(s2, w);
        double len = nft_length3f(w);
        assert_true(fabs(len - 1.0) < 1e-6); /* a unit vector, to float rounding */
        nf_direction_to_square(w, s3);
        double st = sin(NFT_PI * s2[0]);
        /* theta: a few roundings in each direction: 1e-6. phi: the direction's rounding of
         * 6e-8 in a component becomes 6e-8 / sin(theta) in phi: 1e-6 / sin(theta) / 2 pi. */
        if (fabs(s3[0] - s2[0]) > 1e-6)
            fail_msg("s0 %.9g -> %.9g", (double)s2[0], (double)s3[0]);
        if (st > 1e-3) {
            double e1 = fabs(s3[1] - s2[1]);
            e1 = fmin(e1, fabs(e1 - 1.0)); /* across the seam */
            if (e1 > 1e-6 / st)
                fail_msg("s (%.9g, %.9g) -> s1 %.9g", (double)s2[0], (double)s2[1],
                         (double)s3[1]);
        }
    }
}

static void test_square_poles_and_seam(void **state)
{
    (void)state;
    float s[2], d[3];
    const float north[3] = {0.0f, 0.0f, 1.0f}, south[3] = {0.0f, 0.0f, -1.0f};
    nf_direction_to_square(north, s);
    assert_true(s[0] == 0.0f);
    assert_true(s[1] >= 0.0f && s[1] < 1.0f);
    nf_direction_to_square(south, s);
    assert_true(s[0] == 1.0f);
    assert_true(s[1] >= 0.0f && s[1] < 1.0f);
    /* Non-unit poles too. */
    const float north_long[3] = {0.0f, 0.0f, 5.0f}, south_short[3] = {0.0f, 0.0f, -0.01f};
    nf_direction_to_square(north_long, s);
    assert_true(s[0] == 0.0f);
    nf_direction_to_square(south_short, s);
    assert_true(s[0] == 1.0f);

    /* The seam: (1, 0, 0) is phi = 0; just below 2 pi stays below 1 (not wrapped to 0). */
    const float east[3] = {1.0f, 0.0f, 0.0f};
    nf_direction_to_square(east, s);
    assert_true(s[1] == 0.0f && s[0] == 0.5f);
    for (int e = 10; e <= 145; e += 5) {
        /* phi = 2 pi - 2^-e (to first order): s1 = 1 - 2^-e / (2 pi), which rounds to 1 in
         * float for e >= 22 and must then be kept just below 1. */
        float below[3] = {1.0f, -ldexpf(1.0f, -e), 0.2f};
        nf_direction_to_square(below, s);
        if (!(s[1] < 1.0f && s[1] > 0.999f))
            fail_msg("y = -2^-%d: s1 = %.9g, expected just below 1", e, (double)s[1]);
        /* And just above 0 stays at the small end. */
        float above[3] = {1.0f, ldexpf(1.0f, -e), 0.2f};
        nf_direction_to_square(above, s);
        assert_true(s[1] >= 0.0f && s[1] < 0.01f);
    }
    /* The other way: s1 = 0 and s0 = 0 / 1 map to the axis and the poles. */
    const float s_east[2] = {0.5f, 0.0f}, s_north[2] = {0.0f, 0.3f}, s_south[2] = {1.0f, 0.7f};
    nf_square_to_direction(s_east, d);
    assert_true(fabs(d[0] - 1.0f) < 1e-7f && fabs(d[1]) < 1e-7f && fabs(d[2]) < 1e-7f);
    nf_square_to_direction(s_north, d);
    assert_true(d[2] == 1.0f && fabs(d[0]) < 1e-7f && fabs(d[1]) < 1e-7f);
    nf_square_to_direction(s_south, d);
    assert_true(d[2] == -1.0f && fabs(d[0]) < 1e-7f && fabs(d[1]) < 1e-7f);
}

/* theta = atan2(hypot(x, y), z) stays accurate near the poles, where acos(z) would lose all
 * precision: tiny angles from both poles, compared with double. */
static void test_square_theta_near_poles(void **state)
{
    (void)state;
    for (int e = 3; e <= 40; ++e) {
        double t = ldexp(1.0, -e); /* theta or pi - theta */
        for (int pole = 0; pole < 2; ++pole) {
            double theta = pole ? NFT_PI - t : t;
            float d[3] = {(float)(sin(theta) * 0.6), (float)(sin(theta) * 0.8),
                          (float)cos(theta)};
            double exact, phi;
            nft_direction_angles(d, &exact, &phi); /* of the float vector, in double */
            float s[2];
            nf_direction_to_square(d, s);
            if (pole == 0) {
                /* Near the north pole s0 = theta/pi is tiny and float keeps its relative
                 * precision: atan2f and the division, a few ulps: 1e-6 relative. (acos of the
                 * float z would be off by up to 100% here.) */
                if (fabs(s[0] - exact / NFT_PI) > 1e-6 * exact / NFT_PI)
                    fail_msg("theta %.9g: s0 %.9g, expected %.12g", exact, (double)s[0],
                             exact / NFT_PI);
            } else {
                /* Near the south pole s0 = 1 - t/pi: float resolves it to an ulp of 1
                 * (2^-24); a few roundings: 4 2^-24 absolute. */
                if (fabs(s[0] - exact / NFT_PI) > 4.0 / 16777216.0)
                    fail_msg("pi - theta %.9g: s0 %.9g, expected %.12g", t, (double)s[0],
                             exact / NFT_PI);
            }
            /* And phi is well defined as long as the vector has any x, y: atan2(0.8, 0.6). */
            if (d[0] != 0.0f && fabs(s[1] - atan2(0.8, 0.6) / (2.0 * NFT_PI)) > 1e-6)
                fail_msg("theta %.9g: s1 %.9g", exact, (double)s[1]);
        }
    }
    /* square_to_direction keeps sin(theta) accurate at both ends: relative 1e-6 (sin of a
     * folded argument, a few ulps). */
    for (int e = 2; e <= 24; ++e) {
        float s0s[2] = {ldexpf(1.0f, -e), 1.0f - ldexpf(1.0f, -e)};
        for (int k = 0; k < 2; ++k) {
            float s[2] = {s0s[k], 0.125f}, d[3];
            nf_square_to_direction(s, d);
            double expect = sin(NFT_PI * (double)s0s[k]), got = hypot(d[0], d[1]);
            if (fabs(got - expect) > 1e-6 * expect)
                fail_msg("s0 %.9g: sin(theta) %.9g, expected %.12g", (double)s0s[k], got,
                         expect);
        }
    }
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_oneblob_matches_formula),
    cmocka_unit_test(test_oneblob_edges),
    cmocka_unit_test(test_oneblob_centre),
    cmocka_unit_test(test_sh_orthonormal),
    cmocka_unit_test(test_sh_values),
    cmocka_unit_test(test_sh_normalizes),
    cmocka_unit_test(test_square_round_trip),
    cmocka_unit_test(test_square_poles_and_seam),
    cmocka_unit_test(test_square_theta_near_poles),
)
