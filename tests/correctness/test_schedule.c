/*
 * test_schedule.c - the schedule (nisflow/schedule.h) fed synthetic passes with a clock the
 * test sets: the order of its plans (plain yardstick, training, warm-up of every kind, the
 * choice, the stop rule), which kind wins when one buys more per second, that cold passes do
 * not decide the choice, the combined image against the truth, the exact sum over processes,
 * and its refusals.
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

enum { W = 16, H = 8, PIXELS = W * H };

static nf_guide *make_guide(void)
{
    nf_config cfg = nft_config(NF_PRESET_SMALL, NF_PRIOR_COSINE);
    nf_model *m = nft_model_from(&cfg);
    nf_guide_config gc = nft_guide_config(64, 16, 1);
    nf_guide *g = NULL;
    assert_int_equal(nf_guide_create(m, &gc, &g), NF_OK);
    nf_model_destroy(m);
    return g;
}

static nf_schedule *make_schedule(nf_guide *g, double budget)
{
    nf_schedule_config sc;
    nf_schedule_config_init(&sc);
    sc.width = W;
    sc.height = H;
    sc.budget = budget;
    nf_schedule *s = NULL;
    assert_int_equal(nf_schedule_create(g, &sc, &s), NF_OK);
    return s;
}

/* The synthetic scene: every pixel's value is 1. A "noisy" kind sees 4 with probability 1/4,
 * else 0 (variance 3); a "clean" kind sees 1 +- 0.1 (variance 0.01). Every pass reports
 * plain path tracing's second moment as 4 (what the noisy kind has), shallower depths' as 2. */
typedef struct pass_buffers {
    float rgb[3 * PIXELS];
    float moments[NF_GUIDE_DEPTHS * PIXELS];
} pass_buffers;

static void render(pass_buffers *b, nft_rng *r, int noisy, double plain_moment)
{
    for (int i = 0; i < PIXELS; ++i) {
        float v = noisy ? (nft_rng_float(r) < 0.25f ? 4.0f : 0.0f)
                        : 0.9f + 0.2f * nft_rng_float(r);
        b->rgb[3 * i] = b->rgb[3 * i + 1] = b->rgb[3 * i + 2] = v;
        b->moments[i] = (float)plain_moment;
        for (int m = 1; m < (int)NF_GUIDE_DEPTHS; ++m)
            b->moments[m * PIXELS + i] = 2.0f;
    }
}

/* Runs a schedule to its stop, each pass taking one second on the clock; guided passes cost
 * guided_cpu CPU seconds, plain ones plain_cpu (the first pass of each kind `cold` more), and
 * every guided pass reports plain path tracing's second moment as plain_moment (plain passes
 * give none: their squares count). counts[todo] receives how many of each plan came. Returns
 * the passes rendered. */
typedef struct run_spec {
    int guided_noisy, plain_noisy;
    double guided_cpu, plain_cpu, cold, plain_moment;
} run_spec;

static int run(nf_schedule *s, const run_spec *spec, int counts[4], nf_pass_plan *plans,
               int max_plans)
{
    pass_buffers *b = malloc(sizeof *b);
    assert_non_null(b);
    nft_rng r;
    nft_rng_seed(&r, 7, 1);
    memset(counts, 0, 4 * sizeof *counts);
    int n = 0, seen[3] = {0};
    for (;;) {
        nf_pass_plan plan;
        assert_int_equal(nf_schedule_next(s, (double)n, NULL, &plan), NF_OK);
        counts[plan.todo]++;
        if (plan.todo == NF_TODO_STOP)
            break;
        assert_true(n < max_plans);
        plans[n] = plan;
        assert_int_equal((int)plan.pass, n);
        int plain = plan.todo == NF_TODO_PLAIN;
        int noisy = plain ? spec->plain_noisy : spec->guided_noisy;
        render(b, &r, noisy, spec->plain_moment);
        double cpu = plain ? spec->plain_cpu : spec->guided_cpu;
        if (!seen[plan.todo]++)
            cpu += spec->cold;
        assert_int_equal(nf_schedule_add_pass(s, &plan, b->rgb, plain ? NULL : b->moments, 1.0,
                                              cpu, NULL),
                         NF_OK);
        ++n;
    }
    free(b);
    return n;
}

/* Without a guide: plain passes until the next would overrun, then STOP for good; the image
 * of passes that all see 2 is 2. */
static void test_plain_until_the_budget(void **state)
{
    (void)state;
    nf_schedule *s = make_schedule(NULL, 10.5);
    float rgb[3 * PIXELS];
    for (int i = 0; i < 3 * PIXELS; ++i)
        rgb[i] = 2.0f;
    int passes = 0;
    nf_pass_plan plan;
    for (;; ++passes) {
        assert_int_equal(nf_schedule_next(s, (double)passes, NULL, &plan), NF_OK);
        if (plan.todo == NF_TODO_STOP)
            break;
        assert_int_equal(plan.todo, NF_TODO_PLAIN);
        assert_int_equal(nf_schedule_add_pass(s, &plan, rgb, NULL, 1.0, 1.0, NULL), NF_OK);
    }
    /* Passes of 1 s from 0: the 10th ends at 10 <= 10.5, an 11th would end at 11. */
    assert_int_equal(passes, 10);
    assert_int_equal(nf_schedule_next(s, 0.0, NULL, &plan), NF_OK);
    assert_int_equal(plan.todo, NF_TODO_STOP);
    float out[3 * PIXELS];
    nf_schedule_report rep;
    assert_int_equal(nf_schedule_combine(s, NULL, out, &rep), NF_OK);
    for (int i = 0; i < 3 * PIXELS; ++i)
        assert_true(out[i] == 2.0f); /* a mean of equal values, in double, rounds back */
    assert_int_equal(rep.render_passes, 10);
    assert_int_equal(rep.kind_passes[NF_PASS_PLAIN], 10);
    assert_int_equal(rep.train_passes, 0);
    nf_schedule_destroy(s);
}

/* A budget shorter than one pass still renders one. */
static void test_one_pass_at_least(void **state)
{
    (void)state;
    nf_schedule *s = make_schedule(NULL, 1e-3);
    float rgb[3 * PIXELS] = {0.0f};
    nf_pass_plan plan;
    assert_int_equal(nf_schedule_next(s, 5.0, NULL, &plan), NF_OK);
    assert_int_equal(plan.todo, NF_TODO_PLAIN);
    assert_int_equal(nf_schedule_add_pass(s, &plan, rgb, NULL, 5.0, 5.0, NULL), NF_OK);
    assert_int_equal(nf_schedule_next(s, 5.0, NULL, &plan), NF_OK);
    assert_int_equal(plan.todo, NF_TODO_STOP);
    nf_schedule_destroy(s);
}

/* With a guide: two plain passes, training until its share of the budget (15 % of 100 s),
 * then every kind warms up and the kind that buys more per second wins. */
static void test_order_and_choice(void **state)
{
    (void)state;
    nf_guide *g = make_guide();
    nf_schedule *s = make_schedule(g, 100.0);
    static nf_pass_plan plans[128];
    int counts[4];
    const run_spec spec = {0, 1, 1.0, 0.5, 0.0, 4.0}; /* guided clean, plain noisy */
    int n = run(s, &spec, counts, plans, 128);
    assert_int_equal(n, 100);
    assert_int_equal(plans[0].todo, NF_TODO_PLAIN);
    assert_int_equal(plans[1].todo, NF_TODO_PLAIN);
    /* Elapsed 2 .. 15 < 0.15f x 100 (15.0000006: train_fraction is a float). */
    for (int i = 2; i < 16; ++i)
        assert_int_equal(plans[i].todo, NF_TODO_TRAIN);
    /* Two plain passes after training, whose cost is the steady one; then the depth warm-up:
     * two guided passes of each candidate, in order. */
    assert_int_equal(plans[16].todo, NF_TODO_PLAIN);
    assert_int_equal(plans[17].todo, NF_TODO_PLAIN);
    for (uint32_t c = 0; c < NF_GUIDE_DEPTHS; ++c) {
        assert_int_equal(plans[18 + 2 * c].todo, NF_TODO_GUIDED);
        assert_int_equal(plans[18 + 2 * c].depth, c);
        assert_int_equal(plans[19 + 2 * c].depth, c);
    }
    nf_schedule_report rep;
    float *out = malloc(3 * PIXELS * sizeof *out);
    assert_int_equal(nf_schedule_combine(s, NULL, out, &rep), NF_OK);
    assert_int_equal(rep.train_passes, 14);
    assert_true(rep.ratio < 1.0);        /* guided: 0.01 x 1 against plain's 3 x 0.5 */
    assert_int_equal(rep.depth, 0);      /* every depth: the shallower ones have variance 1 */
    /* Guided wins; plain passes: 2 before training, 2 after, and their share (1 % of the
     * render passes) no more. */
    assert_true(rep.kind_passes[NF_PASS_GUIDED] >= 75);
    assert_int_equal(rep.kind_passes[NF_PASS_PLAIN], 4);
    /* The image: the clean passes dominate, so every pixel is within their spread of 1 (a
     * clean pass is within 0.1 of 1; noisy passes weigh 1 / 300 of a clean one each). */
    for (int i = 0; i < 3 * PIXELS; ++i)
        assert_true(fabsf(out[i] - 1.0f) < 0.1f);
    assert_true(rep.train_weight > 0.0 && rep.train_weight < 1.0);
    free(out);
    nf_schedule_destroy(s);
    nf_guide_destroy(g);
}

/* When plain passes buy more per second, plain wins, and guided passes keep explore_share. */
static void test_plain_wins(void **state)
{
    (void)state;
    nf_guide *g = make_guide();
    nf_schedule *s = make_schedule(g, 200.0);
    /* Guided noisy, plain clean: the guided paths report plain path tracing's second moment
     * as 1, the clean kind's. */
    const run_spec spec = {1, 0, 1.0, 1.0, 0.0, 1.0};
    static nf_pass_plan plans[256];
    int counts[4];
    run(s, &spec, counts, plans, 256);
    nf_schedule_report rep;
    float *out = malloc(3 * PIXELS * sizeof *out);
    assert_int_equal(nf_schedule_combine(s, NULL, out, &rep), NF_OK);
    assert_true(rep.ratio > 1.0);
    assert_true(rep.kind_passes[NF_PASS_PLAIN] > rep.kind_passes[NF_PASS_GUIDED]);
    /* Exploration: guided passes stay at 5 % of the render passes (the warm-up's 6 count). */
    assert_true(rep.kind_passes[NF_PASS_GUIDED] >= 6);
    assert_true(rep.explored > 0);
    free(out);
    nf_schedule_destroy(s);
    nf_guide_destroy(g);
}

/* Cold passes do not decide: plain passes cost 1.5 CPU s before training and 0.9 after (the
 * cold ones were the only plain passes the choice had seen), guided ones 1.0. Both kinds
 * have about the same variance (every guided pixel alternates 0.9 and 1.1, and the guided
 * paths measure plain path tracing's moment as 1.01: 0.01 about 1 each; the plain passes' own
 * squares, 1, lower it as they come), so steady costs make plain the better kind (1.0 / 0.9)
 * where the mean of all four plain passes would keep guiding (1.0 / 1.2). */
static void test_steady_costs_decide(void **state)
{
    (void)state;
    nf_guide *g = make_guide();
    nf_schedule *s = make_schedule(g, 200.0);
    pass_buffers *b = malloc(sizeof *b);
    int trained = 0;
    for (int n = 0;; ++n) {
        nf_pass_plan plan;
        assert_int_equal(nf_schedule_next(s, (double)n, NULL, &plan), NF_OK);
        if (plan.todo == NF_TODO_STOP)
            break;
        int plain = plan.todo == NF_TODO_PLAIN;
        trained |= plan.todo == NF_TODO_TRAIN;
        for (int i = 0; i < PIXELS; ++i) {
            float v = plain ? 1.0f : ((i + n) % 2 ? 1.1f : 0.9f);
            b->rgb[3 * i] = b->rgb[3 * i + 1] = b->rgb[3 * i + 2] = v;
            b->moments[i] = plain ? 1.0f : 1.01f;
            for (int m = 1; m < (int)NF_GUIDE_DEPTHS; ++m)
                b->moments[m * PIXELS + i] = 2.0f;
        }
        double cpu = plain ? (trained ? 0.9 : 1.5) : 1.0;
        assert_int_equal(nf_schedule_add_pass(s, &plan, b->rgb, b->moments, 1.0, cpu, NULL),
                         NF_OK);
    }
    nf_schedule_report rep;
    float *out = malloc(3 * PIXELS * sizeof *out);
    assert_int_equal(nf_schedule_combine(s, NULL, out, &rep), NF_OK);
    assert_true(rep.ratio > 1.0);
    assert_true(rep.kind_passes[NF_PASS_PLAIN] > rep.kind_passes[NF_PASS_GUIDED]);
    free(out);
    free(b);
    nf_schedule_destroy(s);
    nf_guide_destroy(g);
}

/* Identity hooks (one process through the reduce): the same plans, and the same image to
 * the fixed point's 2^-50 of the largest value. */
static nf_status max_identity(void *user, double *v, size_t n)
{
    (void)user;
    (void)v;
    (void)n;
    return NF_OK;
}

static nf_status sum_identity(void *user, int64_t *v, size_t n)
{
    (void)v;
    (void)n;
    ++*(int *)user;
    return NF_OK;
}

static void test_reduce_of_one_process(void **state)
{
    (void)state;
    int sums = 0;
    nf_reduce red = {max_identity, sum_identity, &sums};
    nf_guide *g = make_guide();
    nf_schedule *a = make_schedule(g, 60.0), *b = make_schedule(g, 60.0);
    pass_buffers *buf = malloc(sizeof *buf);
    nft_rng r;
    nft_rng_seed(&r, 5, 1);
    for (int n = 0;; ++n) {
        nf_pass_plan pa, pb;
        assert_int_equal(nf_schedule_next(a, (double)n, NULL, &pa), NF_OK);
        assert_int_equal(nf_schedule_next(b, (double)n, &red, &pb), NF_OK);
        assert_memory_equal(&pa, &pb, sizeof pa);
        if (pa.todo == NF_TODO_STOP)
            break;
        render(buf, &r, pa.todo == NF_TODO_PLAIN, 4.0);
        assert_int_equal(nf_schedule_add_pass(a, &pa, buf->rgb, buf->moments, 1.0, 0.7, NULL),
                         NF_OK);
        assert_int_equal(nf_schedule_add_pass(b, &pb, buf->rgb, buf->moments, 1.0, 0.7, &red),
                         NF_OK);
    }
    float *ia = malloc(2 * 3 * PIXELS * sizeof *ia), *ib = ia + 3 * PIXELS;
    assert_int_equal(nf_schedule_combine(a, NULL, ia, NULL), NF_OK);
    assert_int_equal(nf_schedule_combine(b, &red, ib, NULL), NF_OK);
    assert_true(sums > 0);
    for (int i = 0; i < 3 * PIXELS; ++i) /* weights to 2^-50, rounded to float */
        assert_true(fabsf(ia[i] - ib[i]) <= 1e-6f * fabsf(ia[i]));
    free(ia);
    free(buf);
    nf_schedule_destroy(a);
    nf_schedule_destroy(b);
    nf_guide_destroy(g);
}

/* Refusals name what is wrong and change nothing. */
static void test_refusals(void **state)
{
    (void)state;
    nf_schedule_config sc;
    nf_schedule *s = NULL;
    assert_int_equal(nf_schedule_create(NULL, NULL, &s), NF_ERROR_INVALID_ARGUMENT);
    memset(&sc, 0, sizeof sc);
    sc.width = sc.height = 4;
    sc.budget = 1.0;
    assert_int_equal(nf_schedule_create(NULL, &sc, &s), NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "nf_schedule_config_init"));
    nf_schedule_config_init(&sc);
    sc.width = 0;
    sc.height = 4;
    sc.budget = 1.0;
    assert_int_equal(nf_schedule_create(NULL, &sc, &s), NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "0 x 4"));
    sc.width = 4;
    sc.budget = NAN;
    assert_int_equal(nf_schedule_create(NULL, &sc, &s), NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "budget"));
    assert_null(s);

    nf_guide *g = make_guide();
    s = make_schedule(g, 10.0);
    float rgb[3 * PIXELS] = {0.0f}, moments[NF_GUIDE_DEPTHS * PIXELS] = {0.0f};
    nf_pass_plan plan, again;
    assert_int_equal(nf_schedule_next(s, NAN, NULL, &plan), NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_schedule_next(s, 0.0, NULL, &plan), NF_OK);
    assert_int_equal(nf_schedule_next(s, 0.0, NULL, &again), NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "not added"));
    assert_int_equal(nf_schedule_add_pass(s, &plan, rgb, moments, -1.0, 1.0, NULL),
                     NF_ERROR_INVALID_ARGUMENT);
    nf_pass_plan forged = plan;
    forged.pass = 3;
    assert_int_equal(nf_schedule_add_pass(s, &forged, rgb, moments, 1.0, 1.0, NULL),
                     NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_schedule_add_pass(s, &plan, rgb, moments, 1.0, 1.0, NULL), NF_OK);
    assert_int_equal(nf_schedule_add_pass(s, &plan, rgb, moments, 1.0, 1.0, NULL),
                     NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "added already"));
    /* The refusals changed nothing: the next plan is pass 1, the second plain pass. */
    assert_int_equal(nf_schedule_next(s, 1.0, NULL, &plan), NF_OK);
    assert_int_equal(plan.pass, 1);
    assert_int_equal(plan.todo, NF_TODO_PLAIN);
    assert_int_equal(nf_schedule_combine(s, NULL, NULL, NULL), NF_ERROR_INVALID_ARGUMENT);
    nf_schedule_destroy(s);
    nf_schedule_destroy(NULL);
    nf_guide_destroy(g);
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_plain_until_the_budget),
    cmocka_unit_test(test_one_pass_at_least),
    cmocka_unit_test(test_order_and_choice),
    cmocka_unit_test(test_plain_wins),
    cmocka_unit_test(test_steady_costs_decide),
    cmocka_unit_test(test_reduce_of_one_process),
    cmocka_unit_test(test_refusals),
)
