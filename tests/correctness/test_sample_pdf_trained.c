/*
 * test_sample_pdf_trained.c - model.h's bound on how far nf_sample's density and nf_pdf of the
 * returned direction may differ, on trained sharp flows: small models trained on samples of a
 * von Mises-Fisher lobe (kappa 3,000 and 20,000; cosine and uniform-direction priors) until
 * their peaks reach hundreds to thousands per sr, then 200,000 stratified samples each.
 *
 * nf_sample's density belongs to the exact latent point, nf_pdf's to the inverse of the float
 * direction; on a sharp flow the float round trip misses the latent point by up to ~100 ulps,
 * so the two differ, rarely by more than 2e-3. Randomized-parameter flows
 * (test_sampling.c) do not reach these densities, hence this file.
 *
 * NF_TEST_LONG=1 in the environment trains as the measurement that model.h quotes does
 * (10,000 steps of 256 per model, about 8 s), and NF_TEST_SEED=k draws other trainings; the default
 * (1,500 steps) keeps the test within a few seconds and already reaches peaks of several hundred
 * per sr.
 */
#include <float.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "nf_test_support.h"

enum { BATCH = 256, SAMPLES = 200000 };

typedef struct result {
    int beyond_2e3, beyond_1e2, compared;
    double worst, peak;
} result;

/* Trains a small model of `prior` on the lobe, then compares nf_sample's density with nf_pdf
 * of the returned direction over SAMPLES stratified u, away from the poles (sin theta > 1e-2,
 * where model.h's bounds apply). */
static result measure(nf_prior_kind prior, double kappa, int steps, uint64_t seed)
{
    static nf_context ctx[SAMPLES];
    static float u[2 * SAMPLES], dir[3 * SAMPLES], pdf_s[SAMPLES], pdf_p[SAMPLES];
    static float train_dir[3 * BATCH], weight[BATCH];
    const double raw_mu[3] = {0.3, -0.5, 0.8};
    double mu[3], len = sqrt(nft_dot3(raw_mu, raw_mu));
    for (int k = 0; k < 3; ++k)
        mu[k] = raw_mu[k] / len;
    const nf_context c = nft_context(0.3f, 0.5f, 0.7f, 0, 0, 1, 0.2f, 0.1f, 1);
    nf_config cfg = nft_config(NF_PRESET_SMALL, prior);
    cfg.learning_rate = 5e-3f;
    nf_model *m = nft_model_from(&cfg);
    nft_rng r;
    nft_rng_seed(&r, seed, 3u);
    for (int i = 0; i < BATCH; ++i) {
        ctx[i] = c;
        weight[i] = 1.0f;
    }
    for (int s = 0; s < steps; ++s) {
        for (int i = 0; i < BATCH; ++i)
            nft_vmf_sample(&r, mu, kappa, train_dir + 3 * i);
        assert_int_equal(nf_train_step(m, BATCH, ctx, train_dir, weight, NULL), NF_OK);
    }
    /* Stratified u: a 400 x 500 grid, jittered. */
    for (int i = 0; i < SAMPLES; ++i) {
        ctx[i] = c;
        u[2 * i] = (float)(((double)(i % 400) + nft_rng_double(&r)) / 400.0);
        u[2 * i + 1] = (float)(((double)(i / 400) + nft_rng_double(&r)) / 500.0);
    }
    assert_int_equal(nf_sample(m, SAMPLES, ctx, u, dir, pdf_s), NF_OK);
    assert_int_equal(nf_pdf(m, SAMPLES, ctx, dir, pdf_p), NF_OK);
    result res = {0, 0, 0, 0.0, 0.0};
    for (int i = 0; i < SAMPLES; ++i) {
        res.peak = fmax(res.peak, pdf_p[i]);
        if (!(nft_sin_theta(dir + 3 * i) > 1e-2))
            continue;
        ++res.compared;
        double rel = fabs((double)pdf_s[i] - (double)pdf_p[i]) / (double)pdf_p[i];
        res.beyond_2e3 += !(rel <= 2e-3);
        res.beyond_1e2 += !(rel <= 1e-2);
        res.worst = fmax(res.worst, rel);
    }
    nf_model_destroy(m);
    return res;
}

static void test_trained_sharp_flows(void **state)
{
    (void)state;
    const char *env = getenv("NF_TEST_LONG");
    const int steps = env && env[0] == '1' ? 10000 : 1500;
    const char *seed_env = getenv("NF_TEST_SEED"); /* other trainings, for measurements */
    const uint64_t seed = 9000u + (seed_env ? strtoull(seed_env, NULL, 10) : 0u) * 100u;
    const nf_prior_kind priors[2] = {NF_PRIOR_COSINE, NF_PRIOR_UNIFORM_DIRECTION};
    const double kappas[2] = {3000.0, 20000.0};
    int failures = 0;
    double peak_min = HUGE_VAL;
    for (int p = 0; p < 2; ++p) {
        for (int k = 0; k < 2; ++k) {
            result res =
                measure(priors[p], kappas[k], steps, seed + 10u * (uint64_t)p + (uint64_t)k);
            print_message("%s, kappa %.0f, %d steps: peak %.0f per sr; of %d samples %d "
                          "beyond 2e-3, %d beyond 1e-2; worst %.3g\n",
                          nft_prior_name(priors[p]), kappas[k], steps, res.peak, res.compared,
                          res.beyond_2e3, res.beyond_1e2, res.worst);
            peak_min = fmin(peak_min, res.peak);
            /* model.h's bound: at most 1 sample in 10,000 beyond 2e-3 and 1 in 25,000 beyond
             * 1e-2 (measured over 28 trainings, NF_TEST_SEED 0 to 6 and NF_TEST_LONG: up to 18
             * and 3 of 200,000 with NF_PHI_CIRCULAR, 11 and 4 with NF_PHI_INTERVAL), and no
             * sample beyond 0.8 (the largest single difference seen was 0.403 with
             * NF_PHI_CIRCULAR, 0.119 with NF_PHI_INTERVAL; twice that). The counts fail on any
             * regression of the kernels' inverse that loses a few more ulps. */
            if (res.beyond_2e3 * 10000 > res.compared || res.beyond_1e2 * 25000 > res.compared ||
                !(res.worst < 0.8))
                ++failures;
            /* Almost all samples are away from the poles. */
            assert_true(res.compared > SAMPLES * 9 / 10);
        }
    }
    /* The models must really be sharp, or the test proves nothing: peaks above 100 per sr
     * (the low end of model.h's range). */
    assert_true(peak_min > 100.0);
    assert_int_equal(failures, 0);
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_trained_sharp_flows),
)
