/*
 * test_budget.c - the equal-time levers stay unbiased, and the time-budgeted job keeps its
 * budget:
 *   - every lever of the guided vertex (plain mixture, guiding depth, smooth conductors left
 *     unguided, MIS-aware training, a learned guiding probability with cells switched off,
 *     light samples weighed against the BSDF's density, the mixture's boost capped, Russian
 *     roulette by the default rule or on the mixture's throughput alone, from an early depth,
 *     light samples weighed against the mixture's density only up to a depth)
 *     renders the mixed scene with the same mean as plain path tracing;
 *   - the boost cap lowers the guiding probability as integrator.h says, and a cap the first
 *     vertex already reaches guides nothing;
 *   - Russian roulette takes the larger of the throughput and the throughput divided by the
 *     boost, as integrator.h says, and guided paths live longer for it;
 *   - render_with_budget, guided, with its training passes combined into the image, agrees
 *     with plain path tracing too, ends within its budget and reports consistent counts;
 *   - the learned guiding probability moves towards the technique whose density is larger
 *     where the integrand is;
 *   - relative training weights divide each record's weight by its pixel's filtered
 *     estimate, counting only the pixels this rank renders.
 */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include <cmocka.h>

#include "budget.h"
#include "guide.h"
#include "integrator.h"
#include "progress.h"
#include "relative.h"
#include "render.h"
#include "scene.h"
#include "selection.h"
#include "training.h"

#include "mixed_scene.h"

/* Under the sanitizers fewer samples keep the test fast, but not so few that the power check
 * of assert_same_mean fails: at 16 spp the lever "plain mixture, depth 2, MIS-aware" had a
 * standard error of 0.0036 (4 se = 5.6% of the mean) with NF_PHI_CIRCULAR's trained model. */
#ifdef TRACER_SANITIZED
#define SPP 32
#else
#define SPP 64
#endif

static scene load_mixed(void)
{
    scene s;
    tr_error err;
    if (!scene_load_string(MIXED_SCENE_XML, TRACER_TEST_TMP_DIR, &s, &err))
        fail_msg("%s", err.msg);
    return s;
}

static nf_model *trained_model(tracer *t)
{
    tr_error err;
    nf_model *model = NULL;
    guide_settings gs = guide_default_settings(GUIDE_PRIOR_COSINE);
    gs.seed = 7;
    if (!guide_create(t->s, &gs, &model, &err))
        fail_msg("%s", err.msg);
    t->model = model;
    t->guide_prob = 0.5f;
    /* A few steps, so that the flow is no longer its prior: the estimator must stay unbiased
     * for any model. */
    training_settings ts = {4, 256, 0, 1, 2, 3, NULL, NULL};
    training_report rep;
    if (!train_guide(t, model, &ts, &rep, &err))
        fail_msg("%s", err.msg);
    assert_true(rep.samples > 0);
    assert_int_equal(rep.refused, 0);
    return model;
}

static void render(const tracer *t, int spp, uint64_t seed, image *img)
{
    tr_error err;
    path_stats st = {0};
    assert_true(image_alloc(img, t->s->width, t->s->height, &err));
    if (!render_image(t, spp, seed, 0, 2, img, &st, NULL, &err))
        fail_msg("%s", err.msg);
    assert_int_equal(st.nf_errors, 0);
}

/* a and b independent renders of one scene: their pixel-by-pixel difference has mean 0
 * within 4 standard errors (the image's structure cancels). 4: an unbiased pair fails with
 * probability 6e-5, and the standard error is itself estimated; the seeds are fixed, so the
 * outcome is reproducible. The test must also be able to see a 5% bias. */
static void assert_same_mean(const char *label, const image *a, const image *b)
{
    tr_error err;
    image diff;
    assert_true(image_alloc(&diff, a->width, a->height, &err));
    size_t n = (size_t)a->width * (size_t)a->height * 3u;
    double mean_a = 0.0;
    for (size_t i = 0; i < n; ++i) {
        diff.data[i] = b->data[i] - a->data[i];
        mean_a += a->data[i] / (double)n;
    }
    double d, se;
    image_stats(&diff, &d, &se);
    printf("  %-44s difference %.5f +- %.5f (mean %.4f)\n", label, d, se, mean_a);
    if (!(fabs(d) < 4.0 * se))
        fail_msg("%s: the mean differs from plain path tracing by %g +- %g", label, d, se);
    assert_true(0.05 * mean_a > 4.0 * se);
    image_free(&diff);
}

typedef struct lever {
    const char *name;
    int plain, depth, mis_training, selection;
    float min_roughness;
    int light_mis_bsdf;
    float max_boost;
    int rr_depth; /* 0: the scene's (5, which only the mixed scene's last vertex reaches) */
    int throughput_roulette;
    int light_mis_depth;
} lever;

static void test_levers_match_unguided(void **state)
{
    (void)state;
    static const lever levers[] = {
        {"balance mixture (default)", 0, 0, 0, 0, 0.0f, 0, 0.0f, 0, 0, 0},
        {"plain mixture", 1, 0, 0, 0, 0.0f, 0, 0.0f, 0, 0, 0},
        {"guiding depth 1", 0, 1, 0, 0, 0.0f, 0, 0.0f, 0, 0, 0},
        {"rough conductor (alpha 0.3) unguided", 0, 0, 0, 0, 0.5f, 0, 0.0f, 0, 0, 0},
        {"MIS-aware training", 0, 0, 1, 0, 0.0f, 0, 0.0f, 0, 0, 0},
        {"guiding probability per cell, some off", 0, 0, 0, 1, 0.0f, 0, 0.0f, 0, 0, 0},
        {"plain mixture, depth 2, MIS-aware", 1, 2, 1, 0, 0.0f, 0, 0.0f, 0, 0, 0},
        {"light MIS by the BSDF's density", 0, 0, 0, 0, 0.0f, 1, 0.0f, 0, 0, 0},
        {"light MIS by p_bsdf, MIS-aware, cells off", 0, 0, 1, 1, 0.0f, 1, 0.0f, 0, 0, 0},
        /* g = 0.5 raises a BSDF sample at most 2-fold: a cap of 3 lowers the g of a vertex
         * after misses to 1 - boost / 3 or turns it off, so g varies along the paths */
        {"boost capped at 3", 0, 0, 0, 0, 0.0f, 0, 3.0f, 0, 0, 0},
        {"boost capped at 3, MIS-aware, light MIS by p_bsdf", 0, 0, 1, 0, 0.0f, 1, 3.0f, 0, 0, 0},
        /* roulette from the second vertex on, so that most vertices play it */
        {"roulette from depth 2 (the default rule)", 0, 0, 0, 0, 0.0f, 0, 0.0f, 2, 0, 0},
        {"roulette from depth 2 on the mixture's", 0, 0, 0, 0, 0.0f, 0, 0.0f, 2, 1, 0},
        {"roulette from depth 2, boost capped at 3", 0, 0, 1, 0, 0.0f, 0, 3.0f, 2, 0, 0},
        {"light MIS by the mixture's density to depth 1", 0, 0, 0, 0, 0.0f, 0, 0.0f, 0, 0, 1},
        {"light MIS by the mixture's to depth 2, capped", 0, 0, 1, 0, 0.0f, 0, 3.0f, 2, 0, 2},
    };
    scene s = load_mixed();
    const int scene_rr_depth = s.rr_depth;
    tracer plain = {.s = &s};
    image reference;
    render(&plain, 4 * SPP, 100, &reference);
    for (size_t i = 0; i < sizeof levers / sizeof *levers; ++i) {
        const lever *l = &levers[i];
        s.rr_depth = l->rr_depth ? l->rr_depth : scene_rr_depth;
        tracer t = {.s = &s};
        t.throughput_roulette = l->throughput_roulette;
        t.plain_mixture = l->plain;
        t.guide_depth = l->depth;
        t.mis_training = l->mis_training;
        t.guide_min_roughness = l->min_roughness;
        t.light_mis_bsdf = l->light_mis_bsdf;
        t.light_mis_depth = l->light_mis_depth;
        t.guide_max_boost = l->max_boost;
        selection_grid grid;
        if (l->selection) {
            assert_true(selection_init(&grid, s.bounds_min, s.bounds_max, 0.5f));
            rng r = rng_seed(5, RNG_TEST, 0, 0);
            for (size_t c = 0; c < grid.cells; ++c) /* alphas from 0 (off) to 0.8 */
                grid.theta[c] = 8.0f * rng_next(&r) - 4.0f;
            grid.frozen = 1;
        }
        nf_model *model = trained_model(&t);
        if (l->selection)
            t.selection = &grid;
        image img;
        render(&t, 4 * SPP, 200 + i, &img);
        assert_same_mean(l->name, &reference, &img);
        image_free(&img);
        if (l->selection)
            selection_free(&grid);
        nf_model_destroy(model);
    }
    image_free(&reference);
    scene_free(&s);
}

static void check_budget_job(int learn_selection, int relative_training)
{
    scene s = load_mixed();
    tr_error err;
    tracer plain = {.s = &s};
    image reference;
    render(&plain, 4 * SPP, 300, &reference);

    tracer t = {.s = &s};
    nf_model *model = NULL;
    guide_settings gs = guide_default_settings(GUIDE_PRIOR_COSINE);
    if (!guide_create(&s, &gs, &model, &err))
        fail_msg("%s", err.msg);
    t.model = model;
    t.guide_prob = 0.5f;
    budget_settings bs = budget_default_settings();
    bs.seconds = 1.0;
    bs.start = now_seconds();
    bs.train_fraction = 0.5;
    bs.step_samples = 256;
    bs.steps_per_pass = 4;
    bs.threads = 2;
    bs.seed = 9;
    bs.learn_selection = learn_selection;
    bs.relative_training = relative_training;
    image img;
    budget_report rep;
    if (!render_with_budget(&t, model, &bs, &img, &rep, &err))
        fail_msg("%s", err.msg);
    double elapsed = now_seconds() - bs.start;
    printf("  budget job: %d training passes, %d render passes, %.3f s, training weight %.3f\n",
           rep.train_passes, rep.render_passes, elapsed, rep.train_weight);
    assert_true(rep.train_passes >= 1);
    assert_true(rep.render_passes >= 2);
    assert_int_equal(rep.refused, 0);
    assert_int_equal(rep.steps, rep.train_passes * bs.steps_per_pass);
    assert_int_equal(nf_model_step_count(model), (uint64_t)rep.steps);
    assert_true(rep.train_weight >= 0.0 && rep.train_weight <= 1.0);
    assert_null(t.selection); /* the job's grid does not outlive it */
    /* The job stops before a pass that would overrun; a pass of this 20 x 20 film takes
     * milliseconds (tens under sanitizers), so 0.25 s is a wide margin for a loaded machine
     * and still catches a job that ignores its budget. */
    assert_true(elapsed < bs.seconds + 0.25);
    assert_same_mean(relative_training ? "budget job, relative training weights"
                     : learn_selection ? "budget job, learned guiding probability"
                                       : "budget job, training passes combined",
                     &reference, &img);
    image_free(&img);
    image_free(&reference);
    nf_model_destroy(model);
    scene_free(&s);
}

static void test_budget_job(void **state)
{
    (void)state;
    check_budget_job(0, 0);
}

static void test_budget_job_learned_selection(void **state)
{
    (void)state;
    check_budget_job(1, 0);
}

static void test_budget_job_relative_training(void **state)
{
    (void)state;
    check_budget_job(0, 1);
}

/* What one guided render of the mixed scene (8 spp, seed `seed`) counted, with the boost cap
 * `max_boost` (0: none), roulette from `rr_depth` (0: the scene's) and the roulette rule
 * `throughput_roulette` (tracer). */
typedef struct guided_render {
    float max_boost;
    int rr_depth, throughput_roulette;
    uint64_t seed;
} guided_render;

static path_stats guided_render_stats(guided_render g)
{
    scene s = load_mixed();
    if (g.rr_depth)
        s.rr_depth = g.rr_depth;
    tracer t = {.s = &s};
    nf_model *model = trained_model(&t);
    t.guide_max_boost = g.max_boost;
    t.throughput_roulette = g.throughput_roulette;
    tr_error err;
    path_stats st = {0};
    image img;
    assert_true(image_alloc(&img, s.width, s.height, &err));
    if (!render_image(&t, 8, g.seed, 0, 2, &img, &st, NULL, &err))
        fail_msg("%s", err.msg);
    assert_int_equal(st.nf_errors, 0);
    image_free(&img);
    nf_model_destroy(model);
    scene_free(&s);
    return st;
}

/* Guided vertices of one render with the cap `max_boost` (0: none). */
static uint64_t guided_vertices_with_cap(float max_boost)
{
    guided_render g = {.max_boost = max_boost, .seed = 11};
    return guided_render_stats(g).guided_vertices;
}

static void test_boost_cap_lowers_guiding(void **state)
{
    (void)state;
    /* boost / (1 - g) <= cap: g kept where it fits, lowered to 1 - boost / cap where not,
     * 0 once that is below 0.05. The expected values are exact in float up to rounding of
     * 1 - boost / cap, hence the 1e-6. */
    assert_true(guide_capped_prob(0.7f, 1.0f, 10.0f) == 0.7f); /* 3.3 <= 10          */
    assert_true(guide_capped_prob(0.7f, 3.0f, 10.0f) == 0.7f); /* 3 / 0.3 = 10       */
    assert_true(fabsf(guide_capped_prob(0.7f, 5.0f, 10.0f) - 0.5f) < 1e-6f);
    assert_true(fabsf(guide_capped_prob(0.7f, 0.5f, 1.0f) - 0.5f) < 1e-6f);
    assert_true(guide_capped_prob(0.7f, 9.6f, 10.0f) == 0.0f); /* 0.04 < 0.05        */
    assert_true(guide_capped_prob(0.7f, 12.0f, 10.0f) == 0.0f);
    assert_true(guide_capped_prob(0.2f, 0.1f, 1.0f) == 0.2f); /* a well-drawn path  */

    /* Wired into the integrator: g = 0.5 lets the first vertex alone raise a path 2-fold,
     * so a cap of 1.02 leaves it g = 0.02 and no vertex is guided. */
    uint64_t none = guided_vertices_with_cap(0.0f);
    uint64_t first = guided_vertices_with_cap(1.02f);
    printf("  guided vertices: no cap %llu, cap 1.02 %llu\n", (unsigned long long)none,
           (unsigned long long)first);
    assert_true(none > 0);
    assert_int_equal(first, 0);
}

/* Rays traced by one guided render with roulette from the second vertex, by the default rule
 * (roulette_survival) or on the mixture's throughput alone. */
static uint64_t rays_with_roulette(int throughput_roulette)
{
    guided_render g = {.rr_depth = 2, .throughput_roulette = throughput_roulette, .seed = 12};
    return guided_render_stats(g).rays;
}

static void test_roulette_sees_the_bsdf_throughput(void **state)
{
    (void)state;
    /* q = min(max(c, c / boost), 0.95) with c the largest channel; exact in float. */
    rgb thr = {0.25f, 0.125f, 0.0625f};
    assert_true(roulette_survival(thr, 1.0f) == 0.25f);  /* unguided: plain roulette      */
    assert_true(roulette_survival(thr, 0.5f) == 0.5f);   /* drawn towards the light       */
    assert_true(roulette_survival(thr, 4.0f) == 0.25f);  /* drawn where the flow has none:
                                                          * never below plain roulette's  */
    assert_true(roulette_survival(thr, 0.25f) == 0.95f); /* never certain survival        */

    /* Wired into the integrator: q is never below the throughput's own, and it is above it
     * wherever the boost is below 1, as after a direction the flow prefers (p_mix > p_bsdf;
     * mixture sampling draws such directions with weight: the mean of p_mix / p_bsdf under
     * p_mix is the integral of p_mix^2 / p_bsdf >= 1, Cauchy-Schwarz). So guided paths live
     * longer and trace more rays than under roulette on the mixture's throughput; equal
     * counts would mean the boost is not used. */
    uint64_t rule = rays_with_roulette(0), mixture = rays_with_roulette(1);
    printf("  rays: roulette by the default rule %llu, on the mixture's throughput %llu\n",
           (unsigned long long)rule, (unsigned long long)mixture);
    assert_true(rule > mixture);
}

/* A scene without light: no training sample, zero variance everywhere; the combination must
 * fall back to pass counts, not divide by zero (which gave NaN pixels). */
static void test_budget_job_black_scene(void **state)
{
    (void)state;
    static const char xml[] =
        "<scene version=\"3.0.0\">\n"
        "<sensor type=\"perspective\"><float name=\"fov\" value=\"55\"/>"
        "<film type=\"hdrfilm\"><integer name=\"width\" value=\"8\"/>"
        "<integer name=\"height\" value=\"8\"/></film></sensor>\n"
        "<shape type=\"rectangle\"><transform name=\"to_world\"><translate z=\"-1\"/></transform>"
        "<bsdf type=\"diffuse\"/></shape>\n"
        "</scene>\n";
    scene s;
    tr_error err;
    if (!scene_load_string(xml, TRACER_TEST_TMP_DIR, &s, &err))
        fail_msg("%s", err.msg);
    tracer t = {.s = &s};
    nf_model *model = NULL;
    guide_settings gs = guide_default_settings(GUIDE_PRIOR_COSINE);
    if (!guide_create(&s, &gs, &model, &err))
        fail_msg("%s", err.msg);
    t.model = model;
    t.guide_prob = 0.5f;
    budget_settings bs = budget_default_settings();
    bs.seconds = 0.2;
    bs.start = now_seconds();
    bs.threads = 2;
    image img;
    budget_report rep;
    if (!render_with_budget(&t, model, &bs, &img, &rep, &err))
        fail_msg("%s", err.msg);
    assert_true(rep.train_passes >= 1 && rep.render_passes >= 2);
    assert_int_equal(rep.samples, 0);
    for (size_t i = 0; i < 3u * 8u * 8u; ++i)
        assert_true(img.data[i] == 0.0f); /* NaN compares unequal */
    image_free(&img);
    nf_model_destroy(model);
    scene_free(&s);
}

/* Samples where the flow's density is the larger one (and the integrand is not zero) raise
 * alpha; where the BSDF's is, they lower it. */
static void test_selection_learns_direction(void **state)
{
    (void)state;
    selection_grid g;
    vec3 lo = v3(0.0f, 0.0f, 0.0f), hi = v3(1.0f, 1.0f, 1.0f);
    assert_true(selection_init(&g, lo, hi, 0.5f));
    size_t a = selection_cell(&g, v3(0.1f, 0.1f, 0.1f), v3(0.0f, 0.0f, 1.0f));
    size_t b = selection_cell(&g, v3(0.9f, 0.9f, 0.9f), v3(0.0f, 0.0f, 1.0f));
    assert_int_not_equal(a, b);
    assert_int_not_equal(a, selection_cell(&g, v3(0.1f, 0.1f, 0.1f), v3(0.0f, 0.0f, -1.0f)));
    selection_sample smp[2] = {{a, 1.0f, 4.0f, 0.5f, 0.5f}, {b, 1.0f, 0.5f, 4.0f, 0.5f}};
    double work[2 * 8 * 8 * 8 * 6];
    assert_true(2 * g.cells <= sizeof work / sizeof *work);
    for (int i = 0; i < 20; ++i)
        selection_step(&g, smp, 2, work);
    printf("  alpha: flow-favoured cell %.3f, BSDF-favoured cell %.3f\n",
           (double)selection_prob(&g, a), (double)selection_prob(&g, b));
    assert_true(selection_prob(&g, a) > 0.7f);
    assert_true(selection_prob(&g, b) < 0.3f);
    /* Untouched cells keep their start. */
    size_t c = selection_cell(&g, v3(0.5f, 0.1f, 0.9f), v3(1.0f, 0.0f, 0.0f));
    assert_true(fabsf(selection_prob(&g, c) - 0.5f) < 1e-6f);
    g.frozen = 1; /* rendering: a cell below off_below is off */
    assert_true(selection_prob(&g, b) == 0.0f || selection_prob(&g, b) >= g.off_below);
    selection_free(&g);
}

/* The cost test: a cell where the mixture cuts the second moment by less than 1 + cost is
 * switched off when learning ends; one where it cuts it by more stays on. */
static void test_selection_cost_switches_off(void **state)
{
    (void)state;
    selection_grid g;
    assert_true(selection_init(&g, v3(0.0f, 0.0f, 0.0f), v3(1.0f, 1.0f, 1.0f), 0.5f));
    g.cost = 1.0f;
    size_t helps = selection_cell(&g, v3(0.1f, 0.1f, 0.1f), v3(0.0f, 1.0f, 0.0f));
    size_t useless = selection_cell(&g, v3(0.9f, 0.1f, 0.1f), v3(0.0f, 1.0f, 0.0f));
    size_t rare = selection_cell(&g, v3(0.1f, 0.9f, 0.1f), v3(0.0f, 1.0f, 0.0f));
    selection_sample smp[41];
    for (int i = 0; i < 20; ++i) {
        /* p_mix / p_bsdf = 2.5 / 1 (the mixture finds what the BSDF misses): moment x 2.5 */
        selection_sample a = {helps, 1.0f, 4.0f, 1.0f, 0.5f};
        /* p_mix / p_bsdf = 1.5 / 2: the mixture's moment is the larger, 1 + cost fails */
        selection_sample b = {useless, 1.0f, 1.0f, 2.0f, 0.5f};
        smp[2 * i] = a;
        smp[2 * i + 1] = b;
    }
    selection_sample c = {rare, 1.0f, 1.0f, 2.0f, 0.5f}; /* too few samples to judge */
    smp[40] = c;
    selection_observe(&g, smp, 41);
    selection_freeze(&g);
    assert_true(selection_prob(&g, helps) > 0.0f);
    assert_true(selection_prob(&g, useless) == 0.0f);
    assert_true(selection_prob(&g, rare) > 0.0f);
    g.frozen = 0;
    g.cost = 2.0f; /* 2.5 > 1 + 2 is false: with a dearer flow the helpful cell goes off too */
    selection_freeze(&g);
    assert_true(selection_prob(&g, helps) == 0.0f);
    selection_free(&g);
}

/* A film of w x h pixels for relative_weights, which reads only the size. */
static scene film_only(int w, int h)
{
    scene s;
    memset(&s, 0, sizeof s);
    s.width = w;
    s.height = h;
    return s;
}

/* 1 / sqrt(I^2 + METRIC_EPSILON), the scale relative.h promises for a filtered value I. */
static float expected_scale(double i)
{
    return (float)(1.0 / sqrt(i * i + 1e-2));
}

/* Fills the pass: luminance left of column `split`, right from it (grey pixels). */
static void fill_halves(image *img, int split, float left, float right)
{
    for (int y = 0; y < img->height; ++y)
        for (int x = 0; x < img->width; ++x) {
            float *p = image_pixel(img, x, y);
            p[0] = p[1] = p[2] = x < split ? left : right;
        }
}

/* Far from the edge between two halves the box filter sees one value: the scale is exact
 * there (up to float rounding, 1e-6 relative); a second pass averages with the first; a
 * record takes its own pixel's scale. */
static void test_relative_weights_scale_by_pixel(void **state)
{
    (void)state;
    tr_error err;
    scene s = film_only(40, 12);
    tracer t = {.s = &s};
    relative_weights rw;
    assert_true(relative_init(&rw, &t));
    assert_true(rw.scale[0] == 1.0f); /* nothing known yet */
    image pass;
    assert_true(image_alloc(&pass, 40, 12, &err));
    fill_halves(&pass, 20, 10.0f, 0.1f);
    relative_add_pass(&rw, &pass);
    size_t left = 5 * 40 + 2, right = 5 * 40 + 35, edge = 5 * 40 + 20;
    assert_float_equal(rw.scale[left], expected_scale(10.0), 1e-6 * expected_scale(10.0));
    assert_float_equal(rw.scale[right], expected_scale(0.1), 1e-6 * expected_scale(0.1));
    /* At the edge the window holds 3 columns of 10 and 4 of 0.1. */
    double mixed = (3.0 * 10.0 + 4.0 * 0.1) / 7.0;
    assert_float_equal(rw.scale[edge], expected_scale(mixed), 1e-5 * expected_scale(mixed));

    fill_halves(&pass, 20, 30.0f, 0.1f); /* the mean of 10 and 30 on the left */
    pass.data[3 * right] = NAN;          /* counts as black */
    relative_add_pass(&rw, &pass);
    assert_float_equal(rw.scale[left], expected_scale(20.0), 1e-6 * expected_scale(20.0));
    double with_black = 0.1 - 0.1 / (2.0 * 49.0); /* one of 98 samples in the window is 0 */
    assert_float_equal(rw.scale[right], expected_scale(with_black),
                       1e-5 * expected_scale(with_black));

    record_buffer rec = {0};
    train_record r[3];
    memset(r, 0, sizeof r);
    r[0].pixel = (uint32_t)left;
    r[1].pixel = (uint32_t)right;
    r[2].pixel = 40u * 12u; /* outside the film: left as it is */
    for (int i = 0; i < 3; ++i)
        r[i].weight = 2.0f;
    rec.data = r;
    rec.count = rec.capacity = 3;
    relative_apply(&rw, &rec);
    assert_true(r[0].weight == 2.0f * rw.scale[left]);
    assert_true(r[1].weight == 2.0f * rw.scale[right]);
    assert_true(r[2].weight == 2.0f);
    image_free(&pass);
    relative_free(&rw);
}

/* With two ranks, the other rank's tiles (black in this rank's passes; here 1e6, so that a
 * leak would show) stay out of the filter. Tiles are 16 pixels (render.c). */
static void test_relative_weights_own_tiles_only(void **state)
{
    (void)state;
    tr_error err;
    scene s = film_only(32, 16);
    tracer t = {.s = &s, .rank = 0, .ranks = 2};
    assert_true(render_pixel_mine(&t, 15, 8));
    assert_false(render_pixel_mine(&t, 16, 8));
    relative_weights rw;
    assert_true(relative_init(&rw, &t));
    image pass;
    assert_true(image_alloc(&pass, 32, 16, &err));
    fill_halves(&pass, 16, 0.5f, 1e6f);
    relative_add_pass(&rw, &pass);
    assert_float_equal(rw.scale[8 * 32 + 15], expected_scale(0.5), 1e-6 * expected_scale(0.5));
    image_free(&pass);
    relative_free(&rw);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_selection_learns_direction),
        cmocka_unit_test(test_selection_cost_switches_off),
        cmocka_unit_test(test_levers_match_unguided),
        cmocka_unit_test(test_roulette_sees_the_bsdf_throughput),
        cmocka_unit_test(test_boost_cap_lowers_guiding),
        cmocka_unit_test(test_budget_job),
        cmocka_unit_test(test_budget_job_learned_selection),
        cmocka_unit_test(test_budget_job_relative_training),
        cmocka_unit_test(test_relative_weights_scale_by_pixel),
        cmocka_unit_test(test_relative_weights_own_tiles_only),
        cmocka_unit_test(test_budget_job_black_scene),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
