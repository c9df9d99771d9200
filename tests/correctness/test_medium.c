/*
 * test_medium.c - contexts at points in a participating medium (normal exactly zero,
 * nisflow/model.h): the cosine prior's Henyey-Greenstein branch (docs/theory.md section 2,
 * "Media").
 *   - a fresh model's density at a medium point is the analytic eps-mixed phase function to
 *     1e-3 relative, for g from -0.9 to 0.9, through every entry point (batches small and
 *     tiled, with surface contexts in the same tile, shading points, nf_model_prior_pdf);
 *   - what nf_sample returns agrees with nf_pdf and the analytic density, and its samples
 *     have the phase function's mean cosine;
 *   - the density integrates to one (deterministic quadrature) for fresh and randomized
 *     models, and nf_sample draws from it (chi-square), for every g above;
 *   - training at medium contexts runs and lowers the held-out loss, and one model learns
 *     different lobes in a medium and on a surface at the same place and wo;
 *   - validation: a zero normal is a medium, phase_g is checked there and only there.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <nisflow/nisflow.h>

#include "nf_test_support.h"
#include "gradient.h"
#include "shading_point.h"

/* Asymmetries from strongly backward to strongly forward, the range a renderer's media use. */
static const float all_g[] = {-0.9f, -0.5f, 0.0f, 0.5f, 0.9f};
#define G_COUNT (sizeof all_g / sizeof all_g[0])

enum { N = 64 }; /* a batch: above the tiled threshold, so nf_pdf runs the tile kernels */

/* A point in a medium at a random position with a random wo and asymmetry g. */
static nf_context medium_context(nft_rng *r, float g)
{
    nf_context c;
    memset(&c, 0, sizeof c);
    for (int a = 0; a < 3; ++a)
        c.position[a] = nft_rng_float(r);
    nft_random_unit_vector(r, c.wo);
    c.phase_g = g;
    return c;
}

/* Relative difference, against the analytic value b. */
static double rel(double a, double b) { return fabs(a - b) / b; }

/* ---- a fresh model is the phase function ----------------------------------------------------- */

/* The contract: the HG prior alone equals the analytic phase function to 1e-3. The
 * float path carries the direction through the square (theta/pi, phi/2pi) with ~1e-6 rad of
 * rounding; the log-density's slope 3 |g| sin(a) / (1 + g^2 - 2 g cos a) is at most ~14 per
 * radian at |g| = 0.9, so ~2e-5 is expected (measured 1.6e-5) and 1e-3 is the bound. */
#define FRESH_TOLERANCE 1e-3

static void test_fresh_model_is_the_phase_function(void **state)
{
    nf_model *m = *state;
    nf_config cfg;
    assert_int_equal(nf_model_get_config(m, &cfg), NF_OK);
    nft_rng r;
    nft_rng_seed(&r, 7u, 1u);
    static nf_context ctx[N];
    static float dir[3 * N], batch[N], single[N], point[N];
    double worst = 0.0;
    for (size_t k = 0; k < G_COUNT; ++k) {
        for (int rep = 0; rep < 4; ++rep) {
            /* Even lanes in a medium, odd lanes on surfaces (garbage phase_g, never read). */
            for (int i = 0; i < N; ++i) {
                if (i % 2 == 0) {
                    ctx[i] = medium_context(&r, all_g[k]);
                } else {
                    nft_random_context(&r, &ctx[i]);
                    ctx[i].phase_g = NAN;
                }
                nft_random_unit_vector(&r, dir + 3 * i);
            }
            /* the peak and the back of the lobe */
            for (int a = 0; a < 3; ++a) {
                dir[a] = -ctx[0].wo[a];
                dir[6 + a] = ctx[2].wo[a];
            }
            assert_int_equal(nf_pdf(m, N, ctx, dir, batch), NF_OK);
            for (int i = 0; i < N; ++i)
                assert_int_equal(nf_pdf(m, 1, ctx + i, dir + 3 * i, single + i), NF_OK);
            for (int i = 0; i < N; i += 2) {
                nf_shading_point sp;
                assert_int_equal(nf_point_prepare(m, &ctx[i], NULL, &sp), NF_OK);
                assert_int_equal(nf_point_pdf(m, &sp, 1, dir + 3 * i, point + i), NF_OK);
                double want = nft_prior_density(NF_PRIOR_COSINE, cfg.prior_epsilon, &ctx[i],
                                                 dir + 3 * i);
                float prior = nft_prior_pdf(m, &ctx[i], dir + 3 * i);
                const double got[4] = {batch[i], single[i], point[i], prior};
                static const char *names[4] = {"nf_pdf (tiled)", "nf_pdf (n = 1)",
                                               "nf_point_pdf", "nf_model_prior_pdf"};
                for (int j = 0; j < 4; ++j) {
                    worst = fmax(worst, rel(got[j], want));
                    if (!(rel(got[j], want) <= FRESH_TOLERANCE))
                        fail_msg("g = %g, lane %d: %s %.9g, analytic %.9g", (double)all_g[k], i,
                                 names[j], got[j], want);
                }
            }
        }
    }
    print_message("fresh model vs analytic HG: worst relative difference %.3g\n", worst);
}

/* ---- sampling ------------------------------------------------------------------------------ */

/* nf_sample at medium points: the pdf it returns is nf_pdf's (1e-4 relative away from the
 * poles, model.h's promise for well-conditioned flows) and the analytic one (1e-3, as above);
 * the mean cosine to d = -wo is the mixture's, (1 - eps) g. With 64 x 64 samples per g the
 * mean of a cosine (standard deviation <= 1) has a standard error <= 1/64: 0.06 is four of
 * them, and a sampler drawing around wo instead of -wo would miss by 2 (1 - eps) |g|. */
static void test_sample_matches_pdf_and_phase_function(void **state)
{
    nf_model *m = *state;
    nf_config cfg;
    assert_int_equal(nf_model_get_config(m, &cfg), NF_OK);
    nft_rng r;
    nft_rng_seed(&r, 8u, 2u);
    static nf_context ctx[N];
    static float u[2 * N], dir[3 * N], pdf_s[N], pdf_e[N];
    for (size_t k = 0; k < G_COUNT; ++k) {
        double sum_cos = 0.0;
        int count = 0;
        for (int rep = 0; rep < N; ++rep) {
            nf_context c = medium_context(&r, all_g[k]);
            for (int i = 0; i < N; ++i) {
                ctx[i] = c;
                u[2 * i] = nft_rng_float(&r);
                u[2 * i + 1] = nft_rng_float(&r);
            }
            if (rep % 2) {
                /* n = 1: the shading-point path; else tiled */
                for (int i = 0; i < N; ++i)
                    assert_int_equal(nf_sample(m, 1, ctx + i, u + 2 * i, dir + 3 * i, pdf_s + i),
                                     NF_OK);
            } else {
                assert_int_equal(nf_sample(m, N, ctx, u, dir, pdf_s), NF_OK);
            }
            assert_int_equal(nf_pdf(m, N, ctx, dir, pdf_e), NF_OK);
            for (int i = 0; i < N; ++i) {
                const float *w = dir + 3 * i;
                assert_true(fabs(nft_length3f(w) - 1.0) <= 1e-5);
                double want = nft_prior_density(NF_PRIOR_COSINE, cfg.prior_epsilon, &c, w);
                if (!(rel(pdf_s[i], want) <= FRESH_TOLERANCE))
                    fail_msg("g = %g: sampled pdf %.9g, analytic %.9g", (double)all_g[k],
                             (double)pdf_s[i], want);
                if (nft_sin_theta(w) > 1e-2 && !(rel(pdf_s[i], pdf_e[i]) <= 1e-4))
                    fail_msg("g = %g: nf_sample pdf %.9g, nf_pdf %.9g", (double)all_g[k],
                             (double)pdf_s[i], (double)pdf_e[i]);
                sum_cos -= (double)(w[0] * c.wo[0] + w[1] * c.wo[1] + w[2] * c.wo[2]);
                ++count;
            }
        }
        double mean = sum_cos / count, want = (1.0 - cfg.prior_epsilon) * all_g[k];
        print_message("g = %+.1f: mean cosine to -wo %.4f, expected %.4f\n", (double)all_g[k],
                      mean, want);
        assert_true(fabs(mean - want) < 0.06);
    }
}

/* ---- normalization -------------------------------------------------------------------------- */

/* Randomized parameters: uniform in [-RANDOM_SCALE, RANDOM_SCALE], test_normalization's scale
 * (densities over a factor ~100, no spikes a fixed grid cannot resolve). */
#define RANDOM_SCALE 0.3f

/* test_normalization's tolerance on a grid twice as fine: the midpoint rule's error is
 * O(h^2), and at |g| = 0.9 the phase function's peak (0.1 rad wide) on the library's pole is
 * the roughest case. Measured there (randomized model, g = 0.9, d = +z): |I - 1| = 2.5e-3 on
 * 192 x 384, 6.2e-4 on 384 x 768, 1.6e-4 on 768 x 1536, 3.9e-5 on 1536 x 3072 (O(h^2) towards
 * 1); 384 x 768 leaves a margin of 3. A density wrong by a constant factor (a missing
 * 1 - g^2, a Jacobian) errs by 1e-2 or more. */
#define THETA_RES 384u
#define PHI_RES 768u
#define NORMALIZATION_TOLERANCE 2e-3

/* Medium contexts whose lobe points at the library's pole (wo = -z, so d = +z), at the phi
 * seam (d in the x-z plane, phi just below 2 pi), and elsewhere. */
static nf_context normalization_context(int which, float g)
{
    nf_context c;
    memset(&c, 0, sizeof c);
    const float wo[3][3] = {{0.0f, 0.0f, -1.0f}, {-0.8f, 0.001f, -0.6f}, {0.3f, -0.5f, 0.81f}};
    for (int a = 0; a < 3; ++a) {
        c.position[a] = 0.2f + 0.3f * (float)which;
        c.wo[a] = wo[which][a];
    }
    c.phase_g = g;
    return c;
}

static void test_normalization(void **state)
{
    (void)state;
    nf_model *fresh = nft_make_model(NF_PRESET_SMALL, NF_PRIOR_COSINE);
    nf_model *randomized = nft_make_model(NF_PRESET_SMALL, NF_PRIOR_COSINE);
    assert_int_equal(nft_randomize_params(randomized, RANDOM_SCALE, 31u), NF_OK);
    /* a frame that puts the library's poles and seam inside the quadrature grid */
    const double s = sqrt(0.5), rotated[3][3] = {{s, 0.0, -s}, {0.0, 1.0, 0.0}, {s, 0.0, s}};
    double worst = 0.0;
    for (size_t k = 0; k < G_COUNT; ++k) {
        for (int c = 0; c < 3; ++c) {
            nf_context ctx = normalization_context(c, all_g[k]);
            double fi =
                nft_integrate_model(fresh, &ctx, THETA_RES, PHI_RES, c == 0 ? rotated : NULL);
            double ri = nft_integrate_model(randomized, &ctx, THETA_RES, PHI_RES, NULL);
            worst = fmax(worst, fmax(fabs(fi - 1.0), fabs(ri - 1.0)));
            if (!(fabs(fi - 1.0) <= NORMALIZATION_TOLERANCE) ||
                !(fabs(ri - 1.0) <= NORMALIZATION_TOLERANCE))
                fail_msg("g = %g, context %d: integral fresh %.6f, randomized %.6f",
                         (double)all_g[k], c, fi, ri);
        }
    }
    print_message("medium contexts: worst |integral - 1| = %.2e\n", worst);
    nf_model_destroy(fresh);
    nf_model_destroy(randomized);
}

/* ---- chi-square ------------------------------------------------------------------------------ */

/* test_sampling's harness: 16 x 32 cells, 8 x 8 quadrature points each, Sidak-corrected
 * over the runs here (5 g x fresh / randomized). The quadrature's relative error in the
 * expected counts (~1e-3) adds ~N d^2 < 1 to a statistic whose standard deviation is
 * ~sqrt(2 dof) ~ 25; 1e-2 on the integral catches gross errors only (the normalization is
 * checked to 2e-3 above). */
#define CHI2_RUNS 10u
#define CHI2_SAMPLES 50000u

static void test_chi2(void **state)
{
    (void)state;
    for (int randomized = 0; randomized < 2; ++randomized) {
        nf_model *m = nft_make_model(NF_PRESET_SMALL, NF_PRIOR_COSINE);
        if (randomized)
            assert_int_equal(nft_randomize_params(m, RANDOM_SCALE, 41u), NF_OK);
        for (size_t k = 0; k < G_COUNT; ++k) {
            char name[96];
            snprintf(name, sizeof name, "medium_g%+.1f_%s", (double)all_g[k],
                     randomized ? "randomized" : "fresh");
            nf_context ctx = normalization_context(2, all_g[k]);
            nft_chi2_params p = nft_chi2_defaults(name);
            p.sample_count = CHI2_SAMPLES;
            p.run_count = CHI2_RUNS;
            p.seed = 5000u + 10u * (uint64_t)k + (uint64_t)randomized;
            p.integral_tolerance = 1e-2;
            nft_chi2_result r;
            if (!nft_chi2_model(&p, m, &ctx, &r))
                fail_msg("%s", r.message);
            print_message("%s\n", r.message);
        }
        nf_model_destroy(m);
    }
}

/* ---- training ---------------------------------------------------------------------------------- */

#define KAPPA 10.0

static double vmf_pdf(const double mu[3], const float dir[3])
{
    double len = nft_length3f(dir), c = 0.0;
    for (int a = 0; a < 3; ++a)
        c += mu[a] * dir[a] / len;
    return KAPPA / (2.0 * NFT_PI * (1.0 - exp(-2.0 * KAPPA))) * exp(KAPPA * (c - 1.0));
}

/* Two lobes: around mu[0] at the medium contexts, around mu[1] at the surface contexts. */
static const double lobe_axis[2][3] = {{0.6, 0.0, 0.8}, {-0.48, 0.6, 0.64}};

/* Contexts 2k (in a medium, g = 0.5) and 2k + 1 (a surface) share position and wo. */
enum { PLACES = 4, CONTEXTS = 2 * PLACES };

static void training_contexts(nf_context ctx[CONTEXTS])
{
    nft_rng r;
    nft_rng_seed(&r, 51u, 1u);
    for (int k = 0; k < PLACES; ++k) {
        nf_context m = medium_context(&r, 0.5f), s = m;
        s.normal[2] = 1.0f;
        s.phase_g = NAN; /* never read */
        ctx[2 * k] = m;
        ctx[2 * k + 1] = s;
    }
}

static int in_medium(const nf_context *c)
{
    return c->normal[0] == 0.0f && c->normal[1] == 0.0f && c->normal[2] == 0.0f;
}

/* The held-out NLL (unit weights) of samples drawn from the contexts' own lobes, for the
 * medium (group 0) or surface (group 1) contexts. */
static double held_out_loss(const nf_model *m, int group, size_t n, const nf_context *ctx,
                            const float *dir)
{
    static nf_context c[4096];
    static float d[3 * 4096], w[4096];
    size_t count = 0;
    for (size_t i = 0; i < n; ++i)
        if (in_medium(&ctx[i]) == (group == 0)) {
            c[count] = ctx[i];
            memcpy(d + 3 * count, dir + 3 * i, 3 * sizeof(float));
            w[count++] = 1.0f;
        }
    float *grad = malloc(nf_model_param_count(m) * sizeof *grad), loss = 0.0f;
    assert_non_null(grad);
    assert_int_equal(nf_loss_gradient(m, count, c, d, w, &loss, grad), NF_OK);
    free(grad);
    return loss;
}

/* Training as a renderer would: directions from the model, weights target / pdf, the batch
 * mixing medium and surface contexts (so the tiles mix them). The medium's start is the
 * phase function around -wo (g = 0.5), a poor fit to the lobe, as the cosine lobe is on the
 * surfaces. Best possible held-out loss: the vMF's entropy, 0.535 nats for kappa = 10.
 * Measured (small preset, lr 5e-3, 300 steps of 256): medium 3.644 -> 0.621 (sample entropy
 * 0.561), surface 1.896 -> 0.590 (0.544). Asserted: each group's loss
 * drops by at least 0.5 nats and ends within 0.4 of its held-out sample's entropy, so the
 * model learned two different lobes where only the normal's encoding tells them apart. */
static void test_training_at_medium_contexts(void **state)
{
    (void)state;
    enum { HELD_OUT = 4000, STEPS = 300, BATCH = 256 };
    static nf_context ctx[CONTEXTS], held_ctx[HELD_OUT], bctx[BATCH];
    static float held_dir[3 * HELD_OUT], u[2 * BATCH], dir[3 * BATCH], pdf[BATCH],
        weight[BATCH];
    training_contexts(ctx);
    nf_config cfg = nft_config(NF_PRESET_SMALL, NF_PRIOR_COSINE);
    cfg.learning_rate = 5e-3f;
    nf_model *m = nft_model_from(&cfg);
    nft_rng r;
    nft_rng_seed(&r, 52u, 2u);
    double entropy[2] = {0.0, 0.0};
    int counts[2] = {0, 0};
    for (int i = 0; i < HELD_OUT; ++i) {
        held_ctx[i] = ctx[i % CONTEXTS];
        int group = in_medium(&held_ctx[i]) ? 0 : 1;
        nft_vmf_sample(&r, lobe_axis[group], KAPPA, held_dir + 3 * i);
        entropy[group] -= log(vmf_pdf(lobe_axis[group], held_dir + 3 * i));
        counts[group]++;
    }
    double before[2], after[2];
    for (int g = 0; g < 2; ++g) {
        entropy[g] /= counts[g];
        before[g] = held_out_loss(m, g, HELD_OUT, held_ctx, held_dir);
    }
    for (int s = 0; s < STEPS; ++s) {
        for (int i = 0; i < BATCH; ++i) {
            bctx[i] = ctx[nft_rng_u32(&r) % CONTEXTS];
            u[2 * i] = nft_rng_float(&r);
            u[2 * i + 1] = nft_rng_float(&r);
        }
        assert_int_equal(nf_sample(m, BATCH, bctx, u, dir, pdf), NF_OK);
        for (int i = 0; i < BATCH; ++i)
            weight[i] = (float)(vmf_pdf(lobe_axis[in_medium(&bctx[i]) ? 0 : 1], dir + 3 * i) /
                                pdf[i]);
        float loss;
        assert_int_equal(nf_train_step(m, BATCH, bctx, dir, weight, &loss), NF_OK);
        assert_true(isfinite(loss));
    }
    for (int g = 0; g < 2; ++g) {
        after[g] = held_out_loss(m, g, HELD_OUT, held_ctx, held_dir);
        print_message("%s: held-out loss before %.4f, after %.4f; sample entropy %.4f\n",
                      g == 0 ? "medium" : "surface", before[g], after[g], entropy[g]);
        assert_true(before[g] - after[g] >= 0.5);
        assert_true(after[g] - entropy[g] <= 0.4);
    }
    nf_model_destroy(m);
}

/* ---- validation ------------------------------------------------------------------------------ */

static void test_medium_contexts_are_validated(void **state)
{
    nf_model *m = *state;
    nft_rng r;
    nft_rng_seed(&r, 9u, 3u);
    float dir[3] = {0.0f, 0.6f, 0.8f}, pdf = -1.0f;
    nf_shading_point sp;
    /* accepted: |g| up to NF_PHASE_G_MAX, and negative zeros as the normal */
    const float good[] = {0.0f, NF_PHASE_G_MAX, -NF_PHASE_G_MAX, 0.5f};
    for (size_t k = 0; k < sizeof good / sizeof good[0]; ++k) {
        nf_context c = medium_context(&r, good[k]);
        c.normal[1] = -0.0f;
        assert_int_equal(nf_pdf(m, 1, &c, dir, &pdf), NF_OK);
        assert_true(pdf > 0.0f && isfinite(pdf));
        assert_int_equal(nf_point_prepare(m, &c, NULL, &sp), NF_OK);
    }
    /* refused at a medium point: g beyond the limit or not finite */
    const float bad[] = {NAN, INFINITY, -INFINITY, 1.0f, -1.0f, 0.995f, -0.9901f};
    for (size_t k = 0; k < sizeof bad / sizeof bad[0]; ++k) {
        nf_context c = medium_context(&r, bad[k]);
        pdf = -1.0f;
        assert_int_equal(nf_pdf(m, 1, &c, dir, &pdf), NF_ERROR_INVALID_ARGUMENT);
        assert_non_null(strstr(nf_last_error_message(), "phase_g"));
        assert_int_equal(nf_point_prepare(m, &c, NULL, &sp), NF_ERROR_INVALID_ARGUMENT);
        assert_true(nft_prior_pdf(m, &c, dir) < 0.0f);
    }
    /* on a surface phase_g is never read: any value is accepted */
    for (size_t k = 0; k < sizeof bad / sizeof bad[0]; ++k) {
        nf_context c;
        nft_random_context(&r, &c);
        c.phase_g = bad[k];
        assert_int_equal(nf_pdf(m, 1, &c, dir, &pdf), NF_OK);
    }
    /* a normal that is neither zero nor usable is still refused */
    nf_context c = medium_context(&r, 0.0f);
    c.normal[2] = 1e-20f;
    assert_int_equal(nf_pdf(m, 1, &c, dir, &pdf), NF_ERROR_INVALID_ARGUMENT);
    c.normal[2] = NAN;
    assert_int_equal(nf_pdf(m, 1, &c, dir, &pdf), NF_ERROR_INVALID_ARGUMENT);
}

NFT_TEST_MAIN(
    NFT_WITH_MODEL(test_fresh_model_is_the_phase_function),
    NFT_WITH_MODEL(test_sample_matches_pdf_and_phase_function),
    cmocka_unit_test(test_normalization),
    cmocka_unit_test(test_chi2),
    cmocka_unit_test(test_training_at_medium_contexts),
    NFT_WITH_MODEL(test_medium_contexts_are_validated),
)
