/*
 * test_path_state.c - nf_path_state (nisflow/policy.h) carries a path's boost and moments with
 * the same bits as the calls it stands for (nf_guide_mixture_prob, nf_guide_roulette_survival,
 * nf_guide_boost, nf_depth_moment_*), along random paths; the pass's depth turns the mixture
 * off deeper; NULL is a no-op.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include <cmocka.h>

#include "nf_test_support.h"
#include "policy_atoms.h"

/* A path of random events, followed once through nf_path_state and once through the calls. */
static void test_same_bits_as_the_calls(void **state)
{
    (void)state;
    nf_guide_policy pol;
    nf_guide_policy_init(&pol);
    nft_rng rng;
    nft_rng_seed(&rng, 42, 1);
    for (int path = 0; path < 2000; ++path) {
        const uint32_t pass_depth = (uint32_t)path % NF_GUIDE_DEPTHS;
        nf_path_state ps;
        nf_path_start(&ps);
        float boost = 1.0f;
        nf_depth_moment dm[NF_GUIDE_DEPTHS];
        for (uint32_t k = 0; k < NF_GUIDE_DEPTHS; ++k)
            nf_depth_moment_start(&dm[k], k);
        float beta = 1.0f;
        nf_path_add(&ps, 0, 0.3f, 0.3f);
        nf_depth_moment_add(dm, NF_GUIDE_DEPTHS, 0, 0.3f, 0.3f);
        for (uint32_t depth = 1; depth <= 8; ++depth) {
            const int guided = pass_depth == 0 || depth <= pass_depth;
            const float g = nf_path_mixture_prob(&ps, &pol, depth, pass_depth);
            assert_true(g == (guided ? nf_guide_mixture_prob(&pol, boost) : 0.0f));
            const float q = nf_path_survival(&ps, &pol, beta);
            assert_true(q == nf_guide_roulette_survival(&pol, beta, boost));
            const float c = 2.0f * nft_rng_float(&rng), c_plain = 2.0f * nft_rng_float(&rng);
            nf_path_add(&ps, depth, c, c_plain);
            nf_depth_moment_add(dm, NF_GUIDE_DEPTHS, depth, c, c_plain);
            if (depth >= 3) {
                nf_path_survived(&ps, &pol, depth, beta, q);
                nf_depth_moment_roulette(dm, NF_GUIDE_DEPTHS, &pol, depth, beta, q);
            }
            /* a delta lobe now and then: both densities 0 */
            const int delta = nft_rng_float(&rng) < 0.1f;
            const float p_bsdf = delta ? 0.0f : 0.05f + nft_rng_float(&rng);
            const float p_flow = 0.05f + 3.0f * nft_rng_float(&rng);
            const float p_mix = delta ? 0.0f : g * p_flow + (1.0f - g) * p_bsdf;
            nf_path_scatter(&ps, depth, p_bsdf, p_mix, g);
            nf_depth_moment_scatter(dm, NF_GUIDE_DEPTHS, depth, p_bsdf, p_mix, g);
            boost = nf_guide_boost(boost, p_bsdf, p_mix, g);
            beta *= 0.3f + nft_rng_float(&rng);
            assert_true(ps.boost == boost);
            assert_memory_equal(ps.moments, dm, sizeof dm);
        }
    }
}

/* The pass's depth: the mixture is on up to it and off deeper; 0 guides every depth. */
static void test_pass_depth(void **state)
{
    (void)state;
    nf_guide_policy pol;
    nf_guide_policy_init(&pol);
    nf_path_state ps;
    nf_path_start(&ps);
    assert_true(ps.boost == 1.0f);
    for (uint32_t k = 0; k < NF_GUIDE_DEPTHS; ++k)
        assert_int_equal(ps.moments[k].depth, k);
    assert_true(nf_path_mixture_prob(&ps, &pol, 1, 1) == pol.mixture_prob);
    assert_true(nf_path_mixture_prob(&ps, &pol, 2, 1) == 0.0f);
    assert_true(nf_path_mixture_prob(&ps, &pol, 9, 0) == pol.mixture_prob);
    /* The named zeros: a pass of NF_EVERY_DEPTH guides a deep vertex; the moment at
     * NF_MOMENT_PLAIN measures the policy that guides none (a guided scatter at depth 1
     * moves its ratio, not its boost: p_bsdf / p_mix = 1/4, exact in float). */
    assert_true(nf_path_mixture_prob(&ps, &pol, 50, NF_EVERY_DEPTH) == pol.mixture_prob);
    assert_int_equal(ps.moments[NF_MOMENT_PLAIN].depth, 0);
    nf_path_scatter(&ps, 1, 0.2f, 0.8f, pol.mixture_prob);
    assert_true(ps.moments[NF_MOMENT_PLAIN].ratio == 0.25f);
    assert_true(ps.moments[NF_MOMENT_PLAIN].boost == 1.0f);
    assert_true(ps.moments[1].ratio == 1.0f && ps.moments[1].boost == 0.25f);
    assert_true(ps.boost == 0.25f);
}

/* NULL states are no-ops, and the calls that answer answer 0. */
static void test_null(void **state)
{
    (void)state;
    nf_guide_policy pol;
    nf_guide_policy_init(&pol);
    nf_path_start(NULL);
    nf_path_survived(NULL, &pol, 3, 1.0f, 0.5f);
    nf_path_scatter(NULL, 1, 1.0f, 1.0f, 0.5f);
    nf_path_add(NULL, 1, 1.0f, 1.0f);
    assert_true(nf_path_mixture_prob(NULL, &pol, 1, 0) == 0.0f);
    assert_true(nf_path_survival(NULL, &pol, 1.0f) == 0.0f);
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_same_bits_as_the_calls),
    cmocka_unit_test(test_pass_depth),
    cmocka_unit_test(test_null),
)
