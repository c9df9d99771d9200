/*
 * test_guide_choice.c - guided or plain passes (nisflow/schedule.h): the relative variance of a
 * kind of pass about a reference, exactly and in expectation, and the choice of the next
 * pass: warm-up order, the cost rule, exploration, the fixed policy and bad input; and the
 * choice of how deep guided passes guide.
 */
#include <math.h>
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "nf_test_support.h"
#include "guide_internal.h"
#include "policy_atoms.h"
#include "schedule_atoms.h"

static nf_guide *make_guide(const nf_guide_config *gc)
{
    nf_config cfg = nft_config(NF_PRESET_SMALL, NF_PRIOR_COSINE);
    nf_model *m = nft_model_from(&cfg);
    nf_guide *g = NULL;
    assert_int_equal(nf_guide_create(m, gc, &g), NF_OK);
    nf_model_destroy(m);
    return g;
}

static nf_pass_measure measure(uint32_t passes, double seconds, double variance)
{
    nf_pass_measure m = {passes, seconds, variance};
    return m;
}

/* Two pixels over four passes, by hand: pixel 0 saw 0, 0, 0, 4 about a reference of 1
 * ((1 + 1 + 1 + 9) / 4 = 3, relative 3 / 1.01); pixel 1 saw 2 every time about 2 (0). A
 * third pixel whose kind saw nothing where the reference has light counts its whole
 * reference (0.25 / 0.26), where its own mean would say 0. */
static void test_variance_by_hand(void **state)
{
    (void)state;
    const double sum[3] = {4.0, 8.0, 0.0}, sum_sq[3] = {16.0, 16.0, 0.0};
    const double ref[3] = {1.0, 2.0, 0.5};
    double v = -1.0;
    assert_int_equal(nf_guide_pass_variance(3, sum, sum_sq, 4, ref, 0.01, &v), NF_OK);
    double expect = (3.0 / 1.01 + 0.0 + 0.25 / 0.26) / 3.0;
    /* Three terms of a few flops each in double: within a few ulps. */
    assert_true(fabs(v - expect) <= 1e-14 * expect);
    assert_int_equal(nf_guide_pass_variance(0, NULL, NULL, 1, NULL, 0.01, &v), NF_OK);
    assert_true(v == 0.0);
}

/* In expectation it is the relative variance: 2,000 pixels of 8 passes each, every pass a
 * rare bright value (probability p of value a, else 0), about the true mean. */
static void test_variance_in_expectation(void **state)
{
    (void)state;
    enum { PIXELS = 2000, PASSES = 8 };
    const double p = 0.05, a = 20.0, mean = p * a, eps = 0.01;
    double *sum = calloc(PIXELS, sizeof *sum), *sq = calloc(PIXELS, sizeof *sq);
    double *ref = calloc(PIXELS, sizeof *ref);
    assert_non_null(sum);
    assert_non_null(sq);
    assert_non_null(ref);
    nft_rng r;
    nft_rng_seed(&r, 7, 0);
    for (int i = 0; i < PIXELS; ++i) {
        ref[i] = mean;
        for (int k = 0; k < PASSES; ++k) {
            double x = nft_rng_double(&r) < p ? a : 0.0;
            sum[i] += x;
            sq[i] += x * x;
        }
    }
    double v = 0.0;
    assert_int_equal(nf_guide_pass_variance(PIXELS, sum, sq, PASSES, ref, eps, &v), NF_OK);
    double var = p * a * a - mean * mean, expect = var / (mean * mean + eps);
    /* Each of the 16,000 values contributes (x - mean)^2, whose standard deviation is about
     * a^2 sqrt(p) = 89 against a mean of 19: the estimate's relative standard error is
     * 89 / 19 / sqrt(16,000) = 3.7 %; 15 % is four of them. */
    assert_true(fabs(v / expect - 1.0) < 0.15);
    free(sum);
    free(sq);
    free(ref);
}

/* nf_plain_moment has plain path tracing's second moment as its expectation over guided
 * paths (docs/schedule-theory.md), checked on a path of one scatter in [0, 1] with
 * integrand f(x) = x^2: emission 0.5 seen at the camera, then a direction drawn from the
 * guided density p_g(x) = 2x where plain path tracing draws it uniformly (p_p = 1), Russian
 * roulette survived with probability 0.5 where plain path tracing's rule would have given
 * min(f / p_p, 0.95), and the direction's contribution f / p_g / 0.5. Plain path tracing's
 * value is 0.5 + [survives] f / (p_p q_p), whose second moment is
 *     0.25 + 2 x 0.5 x int f + int f^2 / (p_p q_p) = 0.25 + 1/3 + int x^4 / min(x^2, 0.95). */
static void test_plain_moment_in_expectation(void **state)
{
    (void)state;
    nf_guide_policy pol;
    nf_guide_policy_init(&pol); /* max_survival 0.95 */
    const double a = sqrt(0.95); /* x^2 reaches 0.95 here */
    const double expect = 0.25 + 1.0 / 3.0 + a * a * a / 3.0 + (1.0 - pow(a, 5.0)) / (5.0 * 0.95);
    enum { N = 400000 };
    nft_rng r;
    nft_rng_seed(&r, 31, 0);
    double sum = 0.0, sum_sq = 0.0;
    for (int i = 0; i < N; ++i) {
        nf_plain_moment m;
        nf_plain_moment_start(&m);
        nf_plain_moment_add(&m, 0.5f);
        /* x from p_g = 2x: the inverse of x^2; x > 0 keeps p_g positive. */
        float x = (float)sqrt(fmax(nft_rng_double(&r), 1e-12));
        float f = x * x, p_g = 2.0f * x, q = 0.5f;
        nf_plain_moment_scatter(&m, 1.0f, p_g, 0.7f);
        if (nft_rng_double(&r) < q) {
            nf_plain_moment_roulette(&m, &pol, f / p_g, q);
            nf_plain_moment_add(&m, f / p_g / q);
        }
        sum += m.moment;
        sum_sq += (double)m.moment * m.moment;
    }
    double mean = sum / N, sd = sqrt(fmax(sum_sq / N - mean * mean, 0.0));
    /* Five standard errors of the mean of N independent estimates; float rounding of the
     * accumulator is far below (relative 1e-7 per path). */
    double tol = 5.0 * sd / sqrt((double)N);
    assert_true(fabs(mean - expect) < tol);
    assert_true(tol < 0.01 * expect); /* and the check is tight: under 1 % */
    /* A plain path (R = 1 throughout) gives the square of its value. */
    nf_plain_moment m;
    nf_plain_moment_start(&m);
    nf_plain_moment_add(&m, 0.25f);
    nf_plain_moment_add(&m, 1.5f);
    assert_true(fabs(m.moment - 1.75f * 1.75f) < 1e-6f);
}

/* nf_depth_moment in expectation, on a two-vertex toy: vertex 1 draws x1 from p_g = 2x in both
 * the guided path and the depth-1 policy; at vertex 2 the path survives roulette with 0.5 and
 * draws x2 from p_g again, where the depth-1 policy survives with its own rule (its boost
 * frozen at vertex 1's 1 / (2 x1)) and draws x2 uniformly. The integrand is x^2 at both
 * vertices, emission 0.5 at the camera and 1 after vertex 2. The estimator's mean over
 * guided paths must match the depth-1 policy's second moment, simulated directly. */
static void test_depth_moment_in_expectation(void **state)
{
    (void)state;
    nf_guide_policy pol;
    nf_guide_policy_init(&pol);
    enum { N = 400000 };
    nft_rng r;
    nft_rng_seed(&r, 37, 0);
    nf_depth_moment m;
    double est = 0.0, est_sq = 0.0, sim = 0.0, sim_sq = 0.0;
    for (int i = 0; i < N; ++i) {
        /* The guided path and the estimator. */
        float x1 = (float)sqrt(fmax(nft_rng_double(&r), 1e-12));
        float t1 = x1 * x1 / (2.0f * x1), q = 0.5f;
        nf_depth_moment_start(&m, 1);
        nf_depth_moment_add(&m, 1, 0, 0.5f, 0.5f);
        nf_depth_moment_scatter(&m, 1, 1, 1.0f, 2.0f * x1, 0.7f);
        if (nft_rng_double(&r) < q) {
            nf_depth_moment_roulette(&m, 1, &pol, 2, t1, q);
            float x2 = (float)sqrt(fmax(nft_rng_double(&r), 1e-12));
            nf_depth_moment_scatter(&m, 1, 2, 1.0f, 2.0f * x2, 0.7f);
            float c = t1 * (x2 * x2 / (2.0f * x2)) / q; /* no light sampling: one weight */
            nf_depth_moment_add(&m, 1, 2, c, c);
        }
        est += m.moment;
        est_sq += (double)m.moment * m.moment;
        /* The depth-1 policy itself. */
        double y1 = sqrt(fmax(nft_rng_double(&r), 1e-12)), u1 = y1 / 2.0;
        double qp = nf_guide_roulette_survival(&pol, (float)u1, (float)(1.0 / (2.0 * y1)));
        double v = 0.5;
        if (nft_rng_double(&r) < qp) {
            double y2 = nft_rng_double(&r);
            v += u1 * y2 * y2 / qp;
        }
        sim += v * v;
        sim_sq += v * v * v * v;
    }
    double me = est / N, ms = sim / N;
    double se = sqrt(fmax(est_sq / N - me * me, 0.0) / N);
    double ss = sqrt(fmax(sim_sq / N - ms * ms, 0.0) / N);
    /* Five standard errors of the difference of two independent means; float rounding of the
     * estimator (relative 1e-7 per path) is far below. */
    double tol = 5.0 * sqrt(se * se + ss * ss);
    assert_true(fabs(me - ms) < tol);
    assert_true(tol < 0.02 * ms); /* and the check is tight: under 2 % */

    /* A path guided up to exactly D (no step deeper) gives its squared value. */
    nf_depth_moment_start(&m, 2);
    nf_depth_moment_add(&m, 1, 0, 0.25f, 0.25f);
    nf_depth_moment_scatter(&m, 1, 1, 1.0f, 3.0f, 0.7f);
    nf_depth_moment_roulette(&m, 1, &pol, 2, 0.01f, 0.3f);
    nf_depth_moment_scatter(&m, 1, 2, 1.0f, 0.2f, 0.7f);
    nf_depth_moment_add(&m, 1, 2, 1.5f, 9.0f);
    assert_true(fabs(m.moment - 1.75f * 1.75f) < 1e-6f);
    assert_true(m.ratio == 1.0f);
    /* Each moment of an array takes the path's weight where its policy guides the vertex,
     * plain path tracing's deeper: at vertex 2, depth 0 and 1 take 2, depth 2 takes 1. */
    nf_depth_moment arr[3];
    for (uint32_t d = 0; d < 3; ++d)
        nf_depth_moment_start(&arr[d], d);
    nf_depth_moment_add(arr, 3, 2, 1.0f, 2.0f);
    assert_true(arr[0].moment == 4.0f && arr[1].moment == 4.0f && arr[2].moment == 1.0f);
    nf_depth_moment_add(arr, 0, 2, 5.0f, 5.0f); /* n = 0 and NULL: no-ops */
    nf_depth_moment_add(NULL, 3, 2, 5.0f, 5.0f);
    assert_true(arr[0].moment == 4.0f && arr[2].moment == 1.0f);
    /* D = 0 is nf_plain_moment, to the bit, on any sequence of steps. */
    for (int i = 0; i < 1000; ++i) {
        nf_plain_moment pm;
        nf_plain_moment_start(&pm);
        nf_depth_moment_start(&m, 0);
        for (uint32_t depth = 1; depth <= 6; ++depth) {
            float pb = (float)nft_rng_double(&r), pmix = (float)nft_rng_double(&r) + 0.01f;
            float t = 4.0f * (float)nft_rng_double(&r), q = (float)nft_rng_double(&r) + 0.05f;
            float c = (float)nft_rng_double(&r);
            nf_plain_moment_roulette(&pm, &pol, t, q);
            nf_depth_moment_roulette(&m, 1, &pol, depth, t, q);
            nf_plain_moment_scatter(&pm, pb, pmix, 0.7f);
            nf_depth_moment_scatter(&m, 1, depth, pb, pmix, 0.7f);
            nf_plain_moment_add(&pm, c);
            nf_depth_moment_add(&m, 1, depth, c, c);
        }
        assert_memory_equal(&pm.moment, &m.moment, sizeof m.moment);
        assert_memory_equal(&pm.ratio, &m.ratio, sizeof m.ratio);
    }
}

static void test_variance_refuses(void **state)
{
    (void)state;
    const double one[1] = {1.0}, nan[1] = {NAN}, neg[1] = {-1.0};
    double v = 42.0;
    assert_int_equal(nf_guide_pass_variance(1, NULL, one, 1, one, 0.01, &v),
                     NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "sum is NULL"));
    assert_int_equal(nf_guide_pass_variance(1, one, one, 1, one, 0.01, NULL),
                     NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_guide_pass_variance(1, one, one, 0, one, 0.01, &v),
                     NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_guide_pass_variance(1, one, one, 1, one, 0.0, &v),
                     NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_guide_pass_variance(1, one, one, 1, one, NAN, &v),
                     NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_guide_pass_variance(1, nan, one, 1, one, 0.01, &v),
                     NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "pixel 0"));
    assert_int_equal(nf_guide_pass_variance(1, one, neg, 1, one, 0.01, &v),
                     NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_guide_pass_variance(1, one, one, 1, nan, 0.01, &v),
                     NF_ERROR_INVALID_ARGUMENT);
    assert_true(v == 42.0); /* refused calls leave *out alone */
}

/* Before each kind has two passes: guided, plain, guided, plain, and no ratio. */
static void test_warm_up(void **state)
{
    (void)state;
    nf_guide *g = make_guide(NULL);
    const uint32_t gp[4] = {0, 1, 1, 2}, pp[4] = {0, 0, 1, 1};
    const nf_pass_kind expect[4] = {NF_PASS_GUIDED, NF_PASS_PLAIN, NF_PASS_GUIDED, NF_PASS_PLAIN};
    for (int i = 0; i < 4; ++i) {
        nf_pass_measure m[2] = {measure(gp[i], gp[i] * 0.2, 1.0), measure(pp[i], pp[i] * 0.1, 1.0)};
        nf_pass_choice c;
        assert_int_equal(nf_guide_choose_pass(g, m, &c), NF_OK);
        assert_int_equal(c.kind, expect[i]);
        assert_true(isnan(c.ratio));
        assert_int_equal(c.exploring, 0);
    }
    nf_guide_destroy(g);
}

/* Variance x seconds per pass decides: guided 1.0 x 0.2 s against plain 2.0 x 0.12 s is
 * 0.2 against 0.24 (guided, ratio 5/6); plain 1.5 x 0.12 = 0.18 wins (ratio 10/9). */
static void test_cost_rule(void **state)
{
    (void)state;
    nf_guide *g = make_guide(NULL);
    nf_pass_choice c;
    nf_pass_measure m[2] = {measure(10, 2.0, 1.0), measure(10, 1.2, 2.0)};
    assert_int_equal(nf_guide_choose_pass(g, m, &c), NF_OK);
    assert_int_equal(c.kind, NF_PASS_GUIDED);
    assert_true(fabs(c.ratio - 5.0 / 6.0) < 1e-12);
    m[1].variance = 1.5;
    assert_int_equal(nf_guide_choose_pass(g, m, &c), NF_OK);
    assert_int_equal(c.kind, NF_PASS_PLAIN);
    assert_true(fabs(c.ratio - 10.0 / 9.0) < 1e-12);
    /* A tie, and two black images, go to guiding. */
    m[0] = measure(10, 1.2, 1.5);
    assert_int_equal(nf_guide_choose_pass(g, m, &c), NF_OK);
    assert_int_equal(c.kind, NF_PASS_GUIDED);
    m[0].variance = m[1].variance = 0.0;
    assert_int_equal(nf_guide_choose_pass(g, m, &c), NF_OK);
    assert_int_equal(c.kind, NF_PASS_GUIDED);
    assert_true(c.ratio == 1.0);
    nf_guide_destroy(g);
}

/* Guided passes keep explore_share of the passes while plain measures better: the next pass
 * is guided while they have fewer than 5 % of them, and only then. Plain passes keep a fifth
 * of that share when guiding measures better (every pass measures plain path tracing's
 * variance; only its cost needs plain passes). */
static void test_exploration(void **state)
{
    (void)state;
    nf_guide *g = make_guide(NULL);
    nf_pass_choice c;
    nf_pass_measure m[2] = {measure(5, 1.0, 10.0), measure(100, 20.0, 1.0)};
    assert_int_equal(nf_guide_choose_pass(g, m, &c), NF_OK); /* 5 < 0.05 x 105 */
    assert_int_equal(c.kind, NF_PASS_GUIDED);
    assert_int_equal(c.exploring, 1);
    m[0].passes = 6; /* 6 >= 5.3 */
    m[0].seconds = 1.2;
    assert_int_equal(nf_guide_choose_pass(g, m, &c), NF_OK);
    assert_int_equal(c.kind, NF_PASS_PLAIN);
    assert_int_equal(c.exploring, 0);
    nf_pass_measure ahead[2] = {measure(100, 20.0, 1.0), measure(2, 0.4, 10.0)};
    assert_int_equal(nf_guide_choose_pass(g, ahead, &c), NF_OK); /* 2 >= 0.01 x 102 */
    assert_int_equal(c.kind, NF_PASS_GUIDED);
    assert_int_equal(c.exploring, 0);
    ahead[0].passes = 300; /* 2 < 0.01 x 302 */
    ahead[0].seconds = 60.0;
    assert_int_equal(nf_guide_choose_pass(g, ahead, &c), NF_OK);
    assert_int_equal(c.kind, NF_PASS_PLAIN);
    assert_int_equal(c.exploring, 1);
    nf_guide_destroy(g);

    /* A run of choices against fixed measures: each kind's share settles at its floor when
     * the other one wins. */
    nf_guide_config gc;
    nf_guide_config_init(&gc);
    gc.explore_share = 0.2f;
    g = make_guide(&gc);
    for (int plain_wins = 1; plain_wins >= 0; --plain_wins) {
        /* Per pass: guided 0.2 s, plain 0.1 s; variances guided 3 or 1, plain 1 or 3. */
        double vg = plain_wins ? 3.0 : 1.0, vp = plain_wins ? 1.0 : 3.0;
        nf_pass_measure run[2] = {measure(0, 0.0, vg), measure(0, 0.0, vp)};
        for (int i = 0; i < 1000; ++i) {
            assert_int_equal(nf_guide_choose_pass(g, run, &c), NF_OK);
            run[c.kind].passes++;
            run[c.kind].seconds += c.kind == NF_PASS_GUIDED ? 0.2 : 0.1;
        }
        if (plain_wins) /* 0.1 x 1 against 0.2 x 3: guided keeps 20 % of 1000, to one pass */
            assert_in_range(run[NF_PASS_GUIDED].passes, 200, 201);
        else /* 0.2 x 1 against 0.1 x 3: plain keeps 0.2 / 5 = 4 % of 1000, to one pass */
            assert_in_range(run[NF_PASS_PLAIN].passes, 40, 41);
    }
    nf_guide_destroy(g);
}

static void test_fixed_policy_and_refusals(void **state)
{
    (void)state;
    nf_guide_config gc;
    nf_guide_config_init(&gc);
    assert_int_equal(gc.pass_choice, 1);
    gc.pass_choice = 0;
    nf_guide *g = make_guide(&gc);
    nf_pass_choice c;
    nf_pass_measure m[2] = {measure(10, 10.0, 10.0), measure(10, 1.0, 1.0)};
    assert_int_equal(nf_guide_choose_pass(g, m, &c), NF_OK);
    assert_int_equal(c.kind, NF_PASS_GUIDED);
    m[1].variance = NAN;
    assert_int_equal(nf_guide_choose_pass(g, m, &c), NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "NF_PASS_PLAIN"));
    m[1].variance = 1.0;
    m[0].seconds = -1.0;
    assert_int_equal(nf_guide_choose_pass(g, m, &c), NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_guide_choose_pass(g, NULL, &c), NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_guide_choose_pass(NULL, m, &c), NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_guide_choose_pass(g, m, NULL), NF_ERROR_INVALID_ARGUMENT);
    nf_guide_destroy(g);

    /* The configuration's new fields are range-checked like the others. */
    nf_config cfg = nft_config(NF_PRESET_SMALL, NF_PRIOR_COSINE);
    nf_model *model = nft_model_from(&cfg);
    nf_guide_config_init(&gc);
    gc.pass_choice = 2;
    assert_int_equal(nf_guide_create(model, &gc, &g), NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "pass_choice"));
    nf_guide_config_init(&gc);
    gc.explore_share = 0.6f;
    assert_int_equal(nf_guide_create(model, &gc, &g), NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "explore_share"));
    nf_model_destroy(model);
}

/* Each depth's first two passes in candidate order, then the lowest variance x cost per pass:
 * every depth 1.0 x 0.2 s = 0.2, depth 1 1.4 x 0.1 s = 0.14 (ratio 0.7), depth 2 1.2 x 0.15 s
 * = 0.18. A tie goes to the deeper guiding (the lower candidate). */
static void test_depth_choice(void **state)
{
    (void)state;
    nf_guide *g = make_guide(NULL);
    nf_depth_choice c;
    nf_pass_measure m[NF_GUIDE_DEPTHS] = {measure(0, 0.0, 1.0), measure(0, 0.0, 1.4),
                                          measure(0, 0.0, 1.2)};
    const double per_pass[NF_GUIDE_DEPTHS] = {0.2, 0.1, 0.15};
    const uint32_t warm[6] = {0, 0, 1, 1, 2, 2};
    for (int i = 0; i < 6; ++i) {
        assert_int_equal(nf_guide_choose_depth(g, m, &c), NF_OK);
        assert_int_equal(c.candidate, warm[i]);
        assert_int_equal(c.depth, warm[i]);
        assert_true(isnan(c.ratio));
        m[c.candidate].passes++;
        m[c.candidate].seconds += per_pass[c.candidate];
    }
    assert_int_equal(nf_guide_choose_depth(g, m, &c), NF_OK);
    assert_int_equal(c.candidate, 1);
    assert_int_equal(c.depth, 1);
    assert_true(fabs(c.ratio - 0.7) < 1e-12);
    m[1].variance = 2.0; /* 0.2: ties every depth, which keeps it */
    assert_int_equal(nf_guide_choose_depth(g, m, &c), NF_OK);
    assert_int_equal(c.candidate, 2);
    m[2].variance = 2.0; /* 0.3 */
    assert_int_equal(nf_guide_choose_depth(g, m, &c), NF_OK);
    assert_int_equal(c.candidate, 0);
    assert_int_equal(c.depth, 0);
    assert_true(c.ratio == 1.0);

    /* Refused: *out untouched, the message names the measure. */
    nf_depth_choice before = {7u, 7u, 7.0}, d = before;
    m[2].seconds = INFINITY;
    assert_int_equal(nf_guide_choose_depth(g, m, &d), NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "measured[2]"));
    assert_memory_equal(&d, &before, sizeof d);
    m[2].seconds = 0.3;
    m[0].variance = -1.0;
    assert_int_equal(nf_guide_choose_depth(g, m, &d), NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_guide_choose_depth(g, NULL, &d), NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_guide_choose_depth(NULL, m, &d), NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_guide_choose_depth(g, m, NULL), NF_ERROR_INVALID_ARGUMENT);
    assert_memory_equal(&d, &before, sizeof d);
    nf_guide_destroy(g);

    /* A fixed policy guides every depth, whatever the measures. */
    nf_guide_config gc;
    nf_guide_config_init(&gc);
    gc.pass_choice = 0;
    g = make_guide(&gc);
    nf_pass_measure ahead[NF_GUIDE_DEPTHS] = {measure(10, 10.0, 10.0), measure(10, 1.0, 1.0),
                                              measure(0, 0.0, 0.0)};
    assert_int_equal(nf_guide_choose_depth(g, ahead, &c), NF_OK);
    assert_int_equal(c.candidate, 0);
    assert_int_equal(c.depth, 0);
    assert_true(isnan(c.ratio));
    nf_guide_destroy(g);
}

/* The training-ratio stop rule (schedule.h, nf_guide_report_training_ratio): training stops
 * once the ratio of a training pass's variance x time to a plain pass's has not fallen by 5 %
 * for 3 passes while it stays above 0.8, and not before; a ratio that keeps falling, or one
 * that stalls at or below 0.8, trains on; pass_choice 0 ignores the ratios. */
static void test_training_ratio_stop_rule(void **state)
{
    (void)state;
    nf_guide_config gc;
    nf_guide_config_init(&gc);
    gc.patience = 0; /* the held-out loss's rule out of the way */
    nf_guide *g = make_guide(&gc);
    assert_true(nf_guide_keep_training(g, 0.0, 0.0));
    /* 1.5 is the best; 1.45 and 1.43 are not 5 % below it (1.425): stalled 1, 2 ... */
    const double stalled[] = {1.5, 1.45, 1.43};
    for (size_t i = 0; i < 3; ++i) {
        assert_int_equal(nf_guide_report_training_ratio(g, stalled[i]), NF_OK);
        assert_true(nf_guide_keep_training(g, 0.0, 0.0));
    }
    /* ... the third pass without a 5 % fall stops it */
    assert_int_equal(nf_guide_report_training_ratio(g, 1.426), NF_OK);
    assert_false(nf_guide_keep_training(g, 0.0, 0.0));
    nf_guide_destroy(g);

    /* Falling by 5 % or more each pass trains on, for as long as it falls. */
    g = make_guide(&gc);
    double r = 2.0;
    for (int i = 0; i < 20; ++i, r *= 0.94) {
        assert_int_equal(nf_guide_report_training_ratio(g, r), NF_OK);
        assert_true(nf_guide_keep_training(g, 0.0, 0.0));
    }
    nf_guide_destroy(g);

    /* Stalled at 0.8 or below: guiding pays, training goes on. */
    g = make_guide(&gc);
    for (int i = 0; i < 10; ++i) {
        assert_int_equal(nf_guide_report_training_ratio(g, 0.8), NF_OK);
        assert_true(nf_guide_keep_training(g, 0.0, 0.0));
    }
    /* A ratio of +inf (a pass that bought nothing) counts as stalled, above 0.8. */
    nf_guide_destroy(g);
    g = make_guide(&gc);
    for (int i = 0; i < 3; ++i)
        assert_int_equal(nf_guide_report_training_ratio(g, INFINITY), NF_OK);
    assert_false(nf_guide_keep_training(g, 0.0, 0.0));
    /* Refused: NaN and negative ratios, the state unchanged. */
    assert_int_equal(nf_guide_report_training_ratio(g, NAN), NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_guide_report_training_ratio(g, -1.0), NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_guide_report_training_ratio(NULL, 1.0), NF_ERROR_INVALID_ARGUMENT);
    nf_guide_destroy(g);

    /* pass_choice 0: the ratios do not stop training. */
    gc.pass_choice = 0;
    g = make_guide(&gc);
    for (int i = 0; i < 6; ++i)
        assert_int_equal(nf_guide_report_training_ratio(g, 3.0), NF_OK);
    assert_true(nf_guide_keep_training(g, 0.0, 0.0));
    nf_guide_destroy(g);
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_variance_by_hand),
    cmocka_unit_test(test_variance_in_expectation),
    cmocka_unit_test(test_variance_refuses),
    cmocka_unit_test(test_plain_moment_in_expectation),
    cmocka_unit_test(test_depth_moment_in_expectation),
    cmocka_unit_test(test_warm_up),
    cmocka_unit_test(test_cost_rule),
    cmocka_unit_test(test_exploration),
    cmocka_unit_test(test_fixed_policy_and_refusals),
    cmocka_unit_test(test_depth_choice),
    cmocka_unit_test(test_training_ratio_stop_rule),
)
