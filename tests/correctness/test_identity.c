/*
 * test_identity.c - a fresh model is the identity flow (docs/theory.md section 4): its density is
 * its prior's, nf_model_prior_pdf agrees with the analytic densities of docs/theory.md section 2, and
 * with the uniform-angle prior nf_sample maps u to (theta, phi) = (pi u0, 2 pi u1). Also the
 * version and status strings.
 */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <nisflow/nisflow.h>

#include "nf_test_support.h"

static const nf_prior_kind all_priors[4] = {NF_PRIOR_UNIFORM_DIRECTION, NF_PRIOR_UNIFORM_ANGLE,
                                            NF_PRIOR_COSINE, NF_PRIOR_CUSTOM};

/* The relative tolerance of "equal up to float rounding" at a direction. The fresh flow is
 * an identity spline per layer, evaluated in float: a few dozen operations of relative error
 * 2^-24 each, ~2e-6 together; 2e-5 leaves a factor 10. The library also carries theta as
 * s0 = theta/pi in float, whose absolute rounding (2^-24 near s0 = 1, a few roundings)
 * moves sin(theta) by ~pi * 4 * 2^-24 / sin(theta) = 7.5e-7 / sin(theta) relative, which
 * matters only near the poles; 2e-6 / sin(theta) bounds it. */
static double rounding_tolerance(const float dir[3])
{
    return 2e-5 + 2e-6 / fmax(nft_sin_theta(dir), 1e-3);
}

/* The library evaluates the prior at the direction rebuilt from s = (theta/pi, phi/2pi) in
 * float, which moves it by up to ~4 roundings of 2^-24 times pi (~1e-6 rad allowing for the
 * float trig). Where the prior density has a slope (the cosine lobe, most of all at its
 * horizon where the density is only eps/(4 pi)) this moves the density by slope * 1e-6. */
#define DIRECTION_ERROR 1e-6

/* |grad_w p| of the analytic prior at dir (the prior's slope on the sphere). */
static double prior_slope(nf_prior_kind prior, float eps, const nf_context *ctx,
                          const float dir[3])
{
    if (prior == NF_PRIOR_COSINE)
        return (1.0 - eps) / NFT_PI;
    if (prior == NF_PRIOR_CUSTOM) {
        /* d/dw of (1 - eps) (e+1)/(2 pi) max(0, c)^e, c the cosine to the lobe axis. */
        const double e = NFT_PHONG_EXPONENT;
        double c = fmax(nft_phong_cosine(ctx, dir), 0.0);
        return (1.0 - eps) * (e + 1.0) / (2.0 * NFT_PI) * e * pow(c, e - 1.0);
    }
    return 0.0;
}

/* The absolute tolerance for comparing a fresh model's density to the analytic one. */
static double density_tolerance(nf_prior_kind prior, float eps, const nf_context *ctx,
                                const float dir[3], double analytic)
{
    return rounding_tolerance(dir) * analytic +
           prior_slope(prior, eps, ctx, dir) * DIRECTION_ERROR;
}

/* Directions that stress the parameterization: near and at the poles, on the phi seam and
 * just below phi = 2 pi, plus the normal itself, its opposite and its horizon. */
static int special_directions(const nf_context *ctx, float out[][3], int max)
{
    const double phi_below = 2.0 * NFT_PI - 1e-4;
    const double d[][3] = {
        {1e-3, 0.0, 1.0},     {0.0, -2e-3, -1.0}, {0.3, 0.0, 0.9},   {1.0, 0.0, 0.0},
        {-1.0, 0.0, 0.0},     {0.0, 1.0, 0.0},    {0.0, -1.0, 0.0},  {0.5, -1e-7, 0.5},
        {cos(phi_below), sin(phi_below), 0.2}, {0.7 * cos(phi_below), 0.7 * sin(phi_below), -0.7},
    };
    int count = 0;
    for (size_t i = 0; i < sizeof d / sizeof d[0] && count < max; ++i, ++count) {
        double len = sqrt(d[i][0] * d[i][0] + d[i][1] * d[i][1] + d[i][2] * d[i][2]);
        for (int k = 0; k < 3; ++k)
            out[count][k] = (float)(d[i][k] / len);
    }
    if (count + 3 <= max) {
        double t[3], b[3], n[3], axis[3] = {ctx->normal[0], ctx->normal[1], ctx->normal[2]};
        nft_frame(axis, t, b, n);
        for (int k = 0; k < 3; ++k) {
            out[count][k] = (float)n[k];
            out[count + 1][k] = (float)-n[k];
            out[count + 2][k] = (float)(0.6 * t[k] + 0.8 * b[k]); /* on the horizon */
        }
        count += 3;
    }
    return count;
}

static void check_fresh_model(nf_preset preset, nf_prior_kind prior)
{
    enum { CONTEXTS = 64, PER = 32, N = CONTEXTS * PER };
    static nf_context ctx[N];
    static float dir[N][3];
    static float pdf[N];
    nf_model *m = nft_make_model(preset, prior);
    nf_config cfg;
    assert_int_equal(nf_model_get_config(m, &cfg), NF_OK);
    nft_rng r;
    nft_rng_seed(&r, 31337u, (uint64_t)prior);
    for (int c = 0; c < CONTEXTS; ++c) {
        nf_context base;
        if (c == 0)
            base = nft_context(0.5f, 0.5f, 0.5f, 0, 0, 1, 0.6f, 0, 0.8f);
        else if (c == 1)
            base = nft_context(0.0f, 1.0f, 0.5f, 0, 0, -1, 0, 0, -1);
        else if (c == 2)
            base = nft_context(2.0f, -1.0f, 0.5f, 1, 0, 0, 0.6f, 0, 0.8f);
        else if (c == 3)
            base = nft_context(0.1f, 0.2f, 0.3f, (float)cos(-1e-4), (float)sin(-1e-4), 0,
                               0.0f, 0.0f, 1.0f);
        else
            nft_random_context(&r, &base);
        float special[16][3];
        int ns = special_directions(&base, special, 16);
        for (int i = 0; i < PER; ++i) {
            ctx[c * PER + i] = base;
            if (i < ns)
                memcpy(dir[c * PER + i], special[i], sizeof special[i]);
            else
                nft_random_unit_vector(&r, dir[c * PER + i]);
        }
    }
    assert_int_equal(nf_pdf(m, N, ctx, &dir[0][0], pdf), NF_OK);
    for (int i = 0; i < N; ++i) {
        double analytic = nft_prior_density(prior, cfg.prior_epsilon, &ctx[i], dir[i]);
        float prior_pdf = nft_prior_pdf(m, &ctx[i], dir[i]);
        double tol = density_tolerance(prior, cfg.prior_epsilon, &ctx[i], dir[i], analytic);
        if (!(fabs(prior_pdf - analytic) <= tol) || !(fabs(pdf[i] - analytic) <= tol))
            fail_msg("prior %s, preset %d, sample %d: dir (%.9g, %.9g, %.9g), normal (%.9g, "
                     "%.9g, %.9g), wo (%.9g, %.9g, %.9g): nf_pdf %.9g, nf_model_prior_pdf %.9g, "
                     "analytic %.9g (tolerance %.2g)",
                     nft_prior_name(prior), (int)preset, i, dir[i][0], dir[i][1], dir[i][2],
                     ctx[i].normal[0], ctx[i].normal[1], ctx[i].normal[2], ctx[i].wo[0],
                     ctx[i].wo[1], ctx[i].wo[2], pdf[i], prior_pdf, analytic, tol);
    }
    nf_model_destroy(m);
}

static void test_fresh_density_is_prior(void **state)
{
    (void)state;
    for (int k = 0; k < 4; ++k) {
        check_fresh_model(NF_PRESET_SMALL, all_priors[k]);
        check_fresh_model(NF_PRESET_LARGE, all_priors[k]);
    }
}

/* Other epsilons of the defensive mixture reach nf_pdf and nf_model_prior_pdf. */
static void test_fresh_density_epsilon(void **state)
{
    (void)state;
    const float eps[3] = {1e-6f, 0.5f, 1.0f};
    nf_context ctx = nft_context(0.2f, 0.4f, 0.6f, 0.0f, 0.6f, 0.8f, 0.3f, 0.3f, 0.9f);
    for (int k = 2; k < 4; ++k)
        for (int e = 0; e < 3; ++e) {
            nf_config cfg = nft_config(NF_PRESET_SMALL, all_priors[k]);
            cfg.prior_epsilon = eps[e];
            nf_model *m = nft_model_from(&cfg);
            nft_rng r;
            nft_rng_seed(&r, 5u, (uint64_t)e);
            for (int i = 0; i < 256; ++i) {
                float w[3], p;
                nft_random_unit_vector(&r, w);
                assert_int_equal(nf_pdf(m, 1, &ctx, w, &p), NF_OK);
                double analytic = nft_prior_density(all_priors[k], eps[e], &ctx, w);
                double tol = density_tolerance(all_priors[k], eps[e], &ctx, w, analytic);
                if (!(fabs(p - analytic) <= tol) ||
                    !(fabs(nft_prior_pdf(m, &ctx, w) - analytic) <= tol))
                    fail_msg("prior %s, eps %g, dir (%.9g, %.9g, %.9g): nf_pdf %.9g, "
                             "nf_model_prior_pdf %.9g, analytic %.9g",
                             nft_prior_name(all_priors[k]), (double)eps[e], w[0], w[1], w[2],
                             p, nft_prior_pdf(m, &ctx, w), analytic);
            }
            nf_model_destroy(m);
        }
}

/* Exactly at the poles sin(theta) = 0: the uniform-angle density is the documented clamp
 * 1/(2 pi^2 NF_SIN_THETA_MIN), the others their (finite) analytic values. */
static void test_fresh_density_at_exact_poles(void **state)
{
    (void)state;
    const float poles[2][3] = {{0.0f, 0.0f, 1.0f}, {0.0f, 0.0f, -1.0f}};
    nf_context ctx = nft_context(0.5f, 0.5f, 0.5f, 0.0f, 0.6f, 0.8f, 0.0f, 0.0f, 1.0f);
    for (int k = 0; k < 4; ++k) {
        nf_model *m = nft_make_model(NF_PRESET_SMALL, all_priors[k]);
        nf_config cfg;
        assert_int_equal(nf_model_get_config(m, &cfg), NF_OK);
        for (int p = 0; p < 2; ++p) {
            float got;
            assert_int_equal(nf_pdf(m, 1, &ctx, poles[p], &got), NF_OK);
            double analytic = nft_prior_density(all_priors[k], cfg.prior_epsilon, &ctx,
                                                poles[p]);
            /* 1e-3: at the pole the library divides two quantities that both vanish (or
             * clamps); a looser bound than elsewhere, still far from 0 or infinity. */
            if (!isfinite(got) || !(fabs(got - analytic) <= 1e-3 * analytic))
                fail_msg("prior %s at pole z = %g: nf_pdf %.9g, expected %.9g",
                         nft_prior_name(all_priors[k]), (double)poles[p][2], got, analytic);
            float prior_pdf = nft_prior_pdf(m, &ctx, poles[p]);
            if (!(fabs(prior_pdf - analytic) <= 1e-3 * analytic))
                fail_msg("prior %s at pole z = %g: nf_model_prior_pdf %.9g, expected %.9g",
                         nft_prior_name(all_priors[k]), (double)poles[p][2], prior_pdf,
                         analytic);
        }
        nf_model_destroy(m);
    }
}

/* The library normalizes normal, wo and the direction: scaled vectors give the density of
 * the unit ones, for randomized models too (the conditioner sees them through SH). */
static void test_scaled_vectors_same_density(void **state)
{
    (void)state;
    for (int k = 0; k < 4; ++k) {
        nf_model *m = nft_make_model(NF_PRESET_SMALL, all_priors[k]);
        assert_int_equal(nft_randomize_params(m, 0.3f, 8u), NF_OK);
        nft_rng r;
        nft_rng_seed(&r, 17u, (uint64_t)k);
        for (int i = 0; i < 256; ++i) {
            nf_context c, s;
            float w[3], ws[3], p_unit, p_scaled;
            nft_random_context(&r, &c);
            nft_random_unit_vector(&r, w);
            s = c;
            for (int j = 0; j < 3; ++j) {
                s.normal[j] *= 2.5f;
                s.wo[j] *= 0.3f;
                ws[j] = w[j] * 7.0f;
            }
            assert_int_equal(nf_pdf(m, 1, &c, w, &p_unit), NF_OK);
            assert_int_equal(nf_pdf(m, 1, &s, ws, &p_scaled), NF_OK);
            /* Renormalizing a scaled float vector changes it by a few ulps (~3e-7); through
             * the randomized conditioner (parameters in [-0.3, 0.3]) and splines this moved
             * the density by at most 9e-6 relative in measurements; 1e-4 leaves room. The
             * cosine prior adds an ill-conditioned case: just above the horizon (n.w ~ 0)
             * its density is nearly the eps floor and changes by (1 - eps) 2 pi / (eps pi/2)
             * ~ 400 times the error of n.w, which carries the ulps of the normal and the
             * ~3e-7 of the sincos that rebuilds w from the latent point: 1.4e-4 measured at
             * such a sample (1e-5 before the tiled kernels reordered the MLP sums); 4e-4
             * allows for it. */
            double tol = (all_priors[k] == NF_PRIOR_COSINE ? 4e-4 : 1e-4) +
                         2e-6 / fmax(nft_sin_theta(w), 1e-3);
            if (!(fabs(p_unit - p_scaled) <= tol * p_unit))
                fail_msg("prior %s: scaled vectors change the density: %.9g vs %.9g",
                         nft_prior_name(all_priors[k]), p_unit, p_scaled);
        }
        nf_model_destroy(m);
    }
}

/* With the uniform-angle prior the latent point is u itself, and the fresh flow is the
 * identity, so u maps to (theta, phi) = (pi u0, 2 pi u1). */
static void test_fresh_uniform_angle_sample_map(void **state)
{
    (void)state;
    enum { N = 8192 };
    static nf_context ctx[N];
    static float u[2 * N], dir[3 * N], pdf[N];
    nf_model *m = nft_make_model(NF_PRESET_SMALL, NF_PRIOR_UNIFORM_ANGLE);
    nft_rng r;
    nft_rng_seed(&r, 2718u, 1u);
    nft_random_queries(&r, N, ctx, u);
    /* The edges of the square: the poles and the seam. */
    const float edge[6][2] = {{0.0f, 0.0f},        {0.0f, 0.5f},          {0.5f, 0.0f},
                              {0.5f, 0x1.fffffep-1f}, {0x1.fffffep-1f, 0.25f}, {1e-6f, 0.999f}};
    for (int k = 0; k < 6; ++k) {
        u[2 * k] = edge[k][0];
        u[2 * k + 1] = edge[k][1];
    }
    assert_int_equal(nf_sample(m, N, ctx, u, dir, pdf), NF_OK);
    for (int i = 0; i < N; ++i) {
        double theta, phi;
        const float *w = dir + 3 * i;
        nft_direction_angles(w, &theta, &phi);
        double want_theta = NFT_PI * u[2 * i], want_phi = 2.0 * NFT_PI * u[2 * i + 1];
        /* phi is compared on the circle (2 pi - tiny and 0 are neighbours). */
        double dphi = fabs(phi - want_phi);
        dphi = fmin(dphi, 2.0 * NFT_PI - dphi);
        /* Angles from float components are good to ~1e-7 rad; the identity splines add a
         * few float roundings of s (~1e-7 each, times pi or 2 pi). 1e-5 rad is ~30 times
         * that. phi is undefined at the poles, its error grows as 1e-7 / sin(theta). */
        double st = nft_sin_theta(w);
        if (!(fabs(theta - want_theta) <= 1e-5) ||
            (st > 1e-3 && !(dphi * st <= 1e-5)))
            fail_msg("u = (%.9g, %.9g): theta %.9g (want %.9g), phi %.9g (want %.9g)",
                     u[2 * i], u[2 * i + 1], theta, want_theta, phi, want_phi);
        /* The pdf it returns is the uniform-angle density 1/(2 pi^2 sin theta). */
        double analytic = nft_prior_density(NF_PRIOR_UNIFORM_ANGLE, 0.0f, &ctx[i], w);
        if (st > 1e-2 && !(fabs(pdf[i] - analytic) <= rounding_tolerance(w) * analytic))
            fail_msg("u = (%.9g, %.9g): pdf %.9g, want %.9g", u[2 * i], u[2 * i + 1], pdf[i],
                     analytic);
    }
    nf_model_destroy(m);
}

static void test_version_string(void **state)
{
    (void)state;
    char want[64];
    snprintf(want, sizeof want, "%d.%d.%d", NF_VERSION_MAJOR, NF_VERSION_MINOR,
             NF_VERSION_PATCH);
    const char *v = nf_version_string();
    assert_non_null(v);
    assert_string_equal(v, want);
    /* Static storage: the same pointer every time. */
    assert_ptr_equal(v, nf_version_string());
}

static void test_status_strings(void **state)
{
    (void)state;
    const nf_status codes[9] = {NF_OK,           NF_ERROR_INVALID_ARGUMENT, NF_ERROR_OUT_OF_MEMORY,
                                NF_ERROR_IO,     NF_ERROR_FORMAT,           NF_ERROR_NUMERIC,
                                NF_ERROR_STALE,  NF_ERROR_CAPACITY,         NF_ERROR_BUSY};
    /* The enumerators have fixed ABI values. */
    for (int i = 0; i < 9; ++i)
        assert_int_equal((int)codes[i], i);
    const char *unknown = nf_status_string((nf_status)9);
    assert_non_null(unknown);
    assert_string_equal(unknown, "unknown status");
    assert_string_equal(nf_status_string((nf_status)1000), "unknown status");
    assert_string_equal(nf_status_string((nf_status)-1), "unknown status");
    for (int i = 0; i < 9; ++i) {
        const char *s = nf_status_string(codes[i]);
        assert_non_null(s);
        assert_true(strlen(s) > 0);
        assert_string_not_equal(s, unknown);
        for (int j = 0; j < i; ++j)
            assert_string_not_equal(s, nf_status_string(codes[j]));
    }
    /* Nothing has failed on this thread yet. */
    assert_string_equal(nf_last_error_message(), "");
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_status_strings),
    cmocka_unit_test(test_version_string),
    cmocka_unit_test(test_fresh_density_is_prior),
    cmocka_unit_test(test_fresh_density_epsilon),
    cmocka_unit_test(test_fresh_density_at_exact_poles),
    cmocka_unit_test(test_scaled_vectors_same_density),
    cmocka_unit_test(test_fresh_uniform_angle_sample_map),
)
