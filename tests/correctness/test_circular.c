/*
 * test_circular.c - NF_PHI_CIRCULAR (docs/theory.md section 4): phi is a coordinate on the
 * circle. The last phi layer turns phi by raw / K of the circle after its spline, every phi
 * spline has equal end slopes, and the conditioners see phi through a
 * one-blob that wraps around. What this file proves that the shared tests (run once per phi
 * map, tests/CMakeLists.txt) do not: the turn's sign, size and place, the density's continuity
 * across phi = 0 (with NF_PHI_INTERVAL as the negative control that shows the check can
 * fail), and that the turn moves mass across the seam.
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

static nf_model *make(nf_preset preset, nf_prior_kind prior, nf_phi_map map)
{
    nf_config cfg = nft_config(preset, prior);
    cfg.phi_map = map;
    nf_model *m = nft_model_from(&cfg);
    return m;
}

/* Sets the bias of the last phi layer's last conditioner output (layer (L - 1) & ~1: phi
 * layers are the even ones), which NF_PHI_CIRCULAR reads as the turn's raw value
 * (NF_PHI_INTERVAL as the slope at phi = 2 pi). The bias is the last float of the layer's
 * block (train.h, nf_model_get_params). */
static void set_turn_raw(nf_model *m, float raw)
{
    nf_config cfg;
    assert_int_equal(nf_model_get_config(m, &cfg), NF_OK);
    size_t count = nf_model_param_count(m), per_layer = count / cfg.coupling_layers;
    float *p = malloc(count * sizeof *p);
    assert_non_null(p);
    assert_int_equal(nf_model_get_params(m, p), NF_OK);
    size_t layer = (cfg.coupling_layers - 1u) & ~1u;
    p[(layer + 1u) * per_layer - 1u] = raw;
    assert_int_equal(nf_model_set_params(m, p), NF_OK);
    free(p);
}

/* A fresh model whose turn is half the circle (raw K / 2) is the prior turned
 * by pi about z: every other layer is the identity, so p(w) = q(R(-pi) w), R(-pi) (x, y, z) =
 * (-x, -y, z). Checked against nf_model_prior_pdf for both presets and the cosine prior, whose
 * density depends on phi, at 2,000 directions in 8 contexts, with the tolerance of
 * test_identity.c's "equal up to float rounding" (2e-5 relative; 2e-6 / sin(theta) near the
 * poles; the cosine lobe's slope times the ~1e-6 rad by which the float round trip moves a
 * direction). A turn of the wrong sign or size (or none) misses by far more. */
static void test_half_turn_is_the_prior_turned(void **state)
{
    (void)state;
    for (int preset = 0; preset < 2; ++preset) {
        nf_model *m = make((nf_preset)preset, NF_PRIOR_COSINE, NF_PHI_CIRCULAR);
        nf_config cfg;
        assert_int_equal(nf_model_get_config(m, &cfg), NF_OK);
        set_turn_raw(m, 0.5f * (float)cfg.spline_bins);
        nft_rng r;
        nft_rng_seed(&r, 41u, (uint64_t)preset);
        double worst = 0.0;
        int far = 0;
        for (int i = 0; i < 2000; ++i) {
            nf_context ctx;
            nft_random_context(&r, &ctx);
            float w[3], turned[3];
            nft_random_unit_vector(&r, w);
            turned[0] = -w[0];
            turned[1] = -w[1];
            turned[2] = w[2];
            float p, q = nft_prior_pdf(m, &ctx, turned), q_unturned = nft_prior_pdf(m, &ctx, w);
            assert_int_equal(nf_pdf(m, 1, &ctx, w, &p), NF_OK);
            double tol = 2e-5 + 2e-6 / fmax(nft_sin_theta(w), 1e-3) +
                         1e-6 * 2.0 / NFT_PI / fmax(q, 1e-30);
            double rel = fabs((double)p - q) / q;
            worst = fmax(worst, rel / tol);
            far += fabs((double)q_unturned - q) > 0.1 * q;
            if (rel > tol)
                fail_msg("preset %d, direction %d: pdf %.9g, prior turned by pi %.9g", preset, i,
                         (double)p, (double)q);
        }
        print_message("preset %d: a half turn gives the prior turned by pi, worst %.3g of the "
                      "tolerance; %d of 2000 directions where turning changes the prior by "
                      "> 10%%\n",
                      preset, worst, far);
        assert_true(far > 1000); /* the comparison can tell a turned prior from the prior */
        nf_model_destroy(m);
    }
}

/* The density just above phi = 0 against just below phi = 2 pi (1e-6 rad on each side), at
 * 512 random (context, theta) of randomized models, through nf_pdf's tile path (a batch) and
 * its shading-point path (one direction per call): returns the number of pairs that differ by
 * more than `limit` relative. */
static int seam_jumps(const nf_model *m, uint64_t seed, double limit, double *worst)
{
    enum { N = 512 };
    static nf_context ctx[2 * N];
    static float dir[6 * N], pdf[2 * N];
    nft_rng r;
    nft_rng_seed(&r, seed, 3u);
    const double delta = 1e-6;
    for (int i = 0; i < N; ++i) {
        nf_context c;
        nft_random_context(&r, &c);
        double theta = 0.1 + (NFT_PI - 0.2) * nft_rng_double(&r);
        for (int side = 0; side < 2; ++side) {
            double phi = side ? 2.0 * NFT_PI - delta : delta;
            ctx[2 * i + side] = c;
            dir[6 * i + 3 * side] = (float)(sin(theta) * cos(phi));
            dir[6 * i + 3 * side + 1] = (float)(sin(theta) * sin(phi));
            dir[6 * i + 3 * side + 2] = (float)cos(theta);
        }
    }
    assert_int_equal(nf_pdf(m, 2 * N, ctx, dir, pdf), NF_OK);
    int jumps = 0;
    *worst = 0.0;
    for (int i = 0; i < N; ++i) {
        float single[2];
        for (int side = 0; side < 2; ++side)
            assert_int_equal(nf_pdf(m, 1, &ctx[2 * i + side], dir + 6 * i + 3 * side,
                                    &single[side]),
                             NF_OK);
        double rel = fabs((double)pdf[2 * i] - pdf[2 * i + 1]) / pdf[2 * i];
        double rel_single = fabs((double)single[0] - single[1]) / single[0];
        *worst = fmax(*worst, fmax(rel, rel_single));
        jumps += rel > limit || rel_single > limit;
    }
    return jumps;
}

/* Continuity across phi = 0. Randomized models (parameters uniform in +-0.3) have
 * log-density slopes of a few per radian, up to ~100 near the cosine lobe's horizon, so
 * 2e-6 rad apart their densities agree to ~2e-4 (measured 2.5e-4 at worst; 2.4e-3 at 2e-5
 * rad apart: the difference shrinks with the distance, as a continuous density's must):
 * 1e-3 is allowed. NF_PHI_INTERVAL models are discontinuous there (the slopes at phi = 0 and
 * 2 pi are independent outputs): the same check must find jumps beyond 1e-2 in most pairs,
 * or it could not fail. */
static void test_density_continuous_across_seam(void **state)
{
    (void)state;
    const nf_prior_kind priors[3] = {NF_PRIOR_UNIFORM_DIRECTION, NF_PRIOR_COSINE,
                                     NF_PRIOR_CUSTOM};
    for (int preset = 0; preset < 2; ++preset)
        for (int k = 0; k < 3; ++k)
            for (int map = 0; map < 2; ++map) {
                nf_model *m = make((nf_preset)preset, priors[k], (nf_phi_map)map);
                assert_int_equal(nft_randomize_params(m, 0.3f, 70u + 3u * (uint64_t)k +
                                                                   (uint64_t)preset),
                                 NF_OK);
                double worst;
                int circular = map == NF_PHI_CIRCULAR;
                int jumps = seam_jumps(m, 90u + (uint64_t)k, circular ? 1e-3 : 1e-2, &worst);
                print_message("%s, preset %d, %s: largest relative jump across phi = 0 %.3g, "
                              "%d of 512 pairs beyond %g\n",
                              nft_prior_name(priors[k]), preset,
                              nft_phi_map_name((nf_phi_map)map), worst, jumps,
                              circular ? 1e-3 : 1e-2);
                if (circular && jumps > 0)
                    fail_msg("circular model: %d jumps across phi = 0 (largest %.3g)", jumps,
                             worst);
                if (!circular && jumps < 100)
                    fail_msg("interval model: only %d jumps across phi = 0; the check is "
                             "blind",
                             jumps);
                nf_model_destroy(m);
            }
}

/* Mass crosses the seam: the cosine lobe of a normal at phi = pi (-x) lies in the middle of
 * the square, and a half turn carries it onto phi = 0, as a quarter of the probability (the
 * lobe's share within 45 degrees of -x, measured by sampling) must move with it. Counts, out
 * of 20,000 samples, those within 45 degrees of +x (the seam) and of -x. */
static void test_turn_carries_mass_across_seam(void **state)
{
    (void)state;
    enum { N = 20000 };
    static nf_context ctx[N];
    static float u[2 * N], dir[3 * N];
    nf_model *m = make(NF_PRESET_SMALL, NF_PRIOR_COSINE, NF_PHI_CIRCULAR);
    nft_rng r;
    nft_rng_seed(&r, 7u, 7u);
    for (int i = 0; i < N; ++i) {
        ctx[i] = nft_context(0.5f, 0.5f, 0.5f, -1, 0, 0, -1, 0, 0);
        u[2 * i] = nft_rng_float(&r);
        u[2 * i + 1] = nft_rng_float(&r);
    }
    int near_seam[2] = {0, 0}, near_back[2] = {0, 0};
    for (int turned = 0; turned < 2; ++turned) {
        set_turn_raw(m, turned ? 4.0f : 0.0f); /* K = 8: half a turn */
        assert_int_equal(nf_sample(m, N, ctx, u, dir, NULL), NF_OK);
        for (int i = 0; i < N; ++i) {
            near_seam[turned] += dir[3 * i] > 0.70710678f;
            near_back[turned] += dir[3 * i] < -0.70710678f;
        }
    }
    print_message("within 45 degrees of +x / of -x: %d / %d before the turn, %d / %d after\n",
                  near_seam[0], near_back[0], near_seam[1], near_back[1]);
    /* The cosine lobe puts 1 - cos^2(45 deg) = half its mass within 45 degrees of the normal;
     * with eps = 0.01 of uniform mass, ~10,000 of 20,000 samples, and the rest far from +x. */
    assert_true(near_back[0] > 9000 && near_seam[0] < 500);
    assert_true(near_seam[1] == near_back[0] && near_back[1] == near_seam[0]);
    nf_model_destroy(m);
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_half_turn_is_the_prior_turned),
    cmocka_unit_test(test_density_continuous_across_seam),
    cmocka_unit_test(test_turn_carries_mass_across_seam),
)
