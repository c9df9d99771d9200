/*
 * test_budget.c - the equal-time levers stay unbiased, and the time-budgeted job keeps its
 * budget:
 *   - every lever of the guided vertex (the guide's policy: its mixture probability, boost
 *     cap, roulette and light-MIS depth; guiding depth, smooth conductors left unguided,
 *     MIS-aware training, light samples weighed against the BSDF's density) renders the mixed
 *     scene with the same mean as plain path tracing;
 *   - the boost cap is wired into the integrator: a cap the first vertex already reaches
 *     guides nothing;
 *   - render_with_budget, guided by a library guide, with its training passes and its guided
 *     and plain render passes combined into the image, agrees with plain path tracing too,
 *     ends within its budget and reports consistent counts; so does the fixed policy (every
 *     render pass guided).
 */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include <cmocka.h>

#include "nf_test_main.h"

#include "budget.h"
#include "integrator.h"
#include "model_setup.h"
#include "parallel.h"
#include "progress.h"
#include "render.h"
#include "scene.h"
#include "training.h"

#include "mixed_scene.h"
#include "test_policy.h"

/* Under the sanitizers fewer samples keep the test fast, but not so few that the power check
 * of assert_same_mean fails: at 16 spp a lever had a standard error of 0.0036 (4 se = 5.6% of
 * the mean) with NF_PHI_CIRCULAR's trained model. */
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

/* What the BSDF prior's callbacks of the models made here read (bsdf_prior.h); static, so zero
 * is a valid empty lookup. */
static prior_lookup test_lookup;

/* A model trained for a few iterations with the tracer's policy (t->policy), so that the
 * flow is no longer its prior: the estimator must stay unbiased for any model. t->model is
 * the trained model on return. */
static nf_model *trained_model(tracer *t)
{
    tr_error err;
    nf_model *model = NULL;
    model_settings gs = model_default_settings(MODEL_PRIOR_COSINE);
    gs.seed = 7;
    if (!model_create_for_scene(t->s, &gs, &test_lookup, &model, &err))
        fail_msg("%s", err.msg);
    nf_guide_config gc;
    nf_guide_config_init(&gc);
    gc.policy = t->policy;
    training_settings ts = {.iterations = 4, .batch = 256, .eval_spp = 1, .threads = 2,
                            .seed = 3, .guide = &gc};
    training_report rep;
    if (!train_guide(t, &model, &ts, &rep, &err))
        fail_msg("%s", err.msg);
    assert_true(rep.samples > 0);
    assert_int_equal(rep.refused, 0);
    t->model = model;
    return model;
}

/* test_policy's g, with the levers given (0: off). */
static nf_guide_policy policy(float g, float max_boost, uint32_t light_mis_depth,
                              float min_roughness)
{
    nf_guide_policy p = test_policy(g);
    p.max_boost = max_boost;
    p.light_mis_depth = light_mis_depth;
    p.min_roughness = min_roughness;
    return p;
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
    float g;
    int depth, mis_training;
    float min_roughness;
    int light_mis_bsdf;
    float max_boost;
    int rr_depth; /* 0: the scene's (5, which only the mixed scene's last vertex reaches) */
    uint32_t light_mis_depth;
} lever;

static void test_levers_match_unguided(void **state)
{
    (void)state;
    static const lever levers[] = {
        {"mixture g 0.5, no cap, light MIS everywhere", 0.5f, 0, 0, 0.0f, 0, 0.0f, 0, 0},
        {"the default policy (g 0.7, cap 10, depth 2)", 0.7f, 0, 1, 0.3f, 0, 10.0f, 0, 2},
        {"guiding depth 1", 0.5f, 1, 0, 0.0f, 0, 0.0f, 0, 0},
        {"rough conductor (alpha 0.3) unguided", 0.5f, 0, 0, 0.5f, 0, 0.0f, 0, 0},
        {"MIS-aware training", 0.5f, 0, 1, 0.0f, 0, 0.0f, 0, 0},
        {"light MIS by the BSDF's density", 0.5f, 0, 0, 0.0f, 1, 0.0f, 0, 0},
        /* g = 0.5 raises a BSDF sample at most 2-fold: a cap of 3 lowers the g of a vertex
         * after misses to 1 - boost / 3 or turns it off, so g varies along the paths */
        {"boost capped at 3", 0.5f, 0, 0, 0.0f, 0, 3.0f, 0, 0},
        {"boost capped at 3, MIS-aware, light MIS by p_bsdf", 0.5f, 0, 1, 0.0f, 1, 3.0f, 0, 0},
        /* roulette from the second vertex on, so that most vertices play it */
        {"roulette from depth 2", 0.5f, 0, 0, 0.0f, 0, 0.0f, 2, 0},
        {"roulette from depth 2, boost capped at 3", 0.5f, 0, 1, 0.0f, 0, 3.0f, 2, 0},
        {"roulette from depth 2, the default policy", 0.7f, 0, 1, 0.3f, 0, 10.0f, 2, 2},
        {"light MIS by the mixture's density to depth 1", 0.5f, 0, 0, 0.0f, 0, 0.0f, 0, 1},
        {"light MIS by the mixture's to depth 2, capped", 0.5f, 0, 1, 0.0f, 0, 3.0f, 2, 2},
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
        t.policy = policy(l->g, l->max_boost, l->light_mis_depth, l->min_roughness);
        t.guide_depth = l->depth;
        t.mis_training = l->mis_training;
        t.light_mis_bsdf = l->light_mis_bsdf;
        nf_model *model = trained_model(&t);
        image img;
        render(&t, 4 * SPP, 200 + i, &img);
        assert_same_mean(l->name, &reference, &img);
        image_free(&img);
        nf_model_destroy(model);
    }
    image_free(&reference);
    scene_free(&s);
}

/* A guide for the budget job: the library's defaults, with smaller steps for a tiny film;
 * with the BSDF prior, each sample keeps its material. */
static nf_guide *budget_guide_on(const scene *s, float train_fraction, model_prior prior,
                                 uint32_t pass_choice, prior_lookup *lookup)
{
    tr_error err;
    nf_model *model = NULL;
    model_settings gs = model_default_settings(prior);
    if (!model_create_for_scene(s, &gs, lookup, &model, &err))
        fail_msg("%s", err.msg);
    nf_guide_config gc;
    nf_guide_config_init(&gc);
    gc.train_fraction = train_fraction;
    gc.step_samples = 256;
    gc.steps_per_pass = 4;
    gc.store_capacity = 16384;
    gc.pass_choice = pass_choice;
    if (prior == MODEL_PRIOR_BSDF)
        gc.payload_bytes = sizeof(prior_point);
    nf_guide *g = NULL;
    assert_int_equal(nf_guide_create(model, &gc, &g), NF_OK);
    nf_model_destroy(model); /* the guide holds copies */
    return g;
}

static nf_guide *budget_guide_with(const scene *s, float train_fraction, model_prior prior,
                                   uint32_t pass_choice)
{
    return budget_guide_on(s, train_fraction, prior, pass_choice, &test_lookup);
}

static nf_guide *budget_guide(const scene *s, float train_fraction)
{
    return budget_guide_with(s, train_fraction, MODEL_PRIOR_COSINE, 1);
}

/* With the BSDF prior the guide's training finds every sample's material in its payload:
 * the callbacks never fall back to a cosine lobe. */
static void test_budget_job_bsdf_prior(void **state)
{
    (void)state;
    scene s = load_mixed();
    tr_error err;
    tracer t = {.s = &s, .bsdf_prior = 1};
    nf_guide_policy_init(&t.policy);
    nf_guide *guide = budget_guide_with(&s, 0.5f, MODEL_PRIOR_BSDF, 1);
    unsigned long long misses = atomic_load(&test_lookup.failures);
    budget_settings bs = {0.5, now_seconds(), 2, 4};
    image img;
    budget_report rep;
    if (!render_with_budget(&t, guide, &bs, &img, &rep, &err))
        fail_msg("%s", err.msg);
    assert_true(rep.steps > 0);
    assert_int_equal(atomic_load(&test_lookup.failures), misses);
    image_free(&img);
    nf_guide_destroy(guide);
    /* A guide without room for the materials is refused, not trained on cosine lobes. */
    guide = budget_guide(&s, 0.5f);
    bs.start = now_seconds();
    err.msg[0] = '\0';
    assert_false(render_with_budget(&t, guide, &bs, &img, &rep, &err));
    assert_non_null(strstr(err.msg, "payload"));
    image_free(&img); /* allocated before the check: the caller frees it */
    nf_guide_destroy(guide);
    scene_free(&s);
}

/* One of two BSDF-prior jobs that run at once in test_two_jobs_train_at_once. */
typedef struct concurrent_job {
    const scene *s;
    prior_lookup lookup;
    budget_report rep;
    int ok;
} concurrent_job;

static void run_concurrent_job(void *user, size_t item, int thread)
{
    (void)thread;
    concurrent_job *j = (concurrent_job *)user + item;
    tracer t = {.s = j->s, .bsdf_prior = 1};
    nf_guide_policy_init(&t.policy);
    nf_guide *guide = budget_guide_on(j->s, 0.5f, MODEL_PRIOR_BSDF, 1, &j->lookup);
    budget_settings bs = {0.6, now_seconds(), 1, 7 + item};
    image img;
    tr_error err;
    j->ok = render_with_budget(&t, guide, &bs, &img, &j->rep, &err);
    image_free(&img);
    nf_guide_destroy(guide);
}

/* Two jobs in one process, each with the BSDF prior, train at the same time: each finds its
 * samples' materials through its own lookup, so neither falls back once. A lookup shared by
 * the process would, while the other job's training call had its guide bound. */
static void test_two_jobs_train_at_once(void **state)
{
    (void)state;
    scene s = load_mixed();
    concurrent_job jobs[2];
    for (int k = 0; k < 2; ++k) {
        jobs[k].s = &s;
        prior_lookup_init(&jobs[k].lookup);
    }
    tr_error err;
    assert_true(parallel_for(2, 2, run_concurrent_job, jobs, NULL, &err));
    for (int k = 0; k < 2; ++k) {
        assert_true(jobs[k].ok);
        assert_true(jobs[k].rep.steps > 0);
        assert_int_equal(atomic_load(&jobs[k].lookup.failures), 0);
    }
    scene_free(&s);
}

/* The budget job on the mixed scene, guided by a library guide that chooses its passes
 * (pass_choice 1) or renders every pass guided (0): it keeps plain path tracing's mean, ends
 * within its budget and reports consistent counts. */
static void check_budget_job(uint32_t pass_choice, double seconds, uint64_t seed)
{
    scene s = load_mixed();
    tr_error err;
    tracer plain = {.s = &s};
    image reference;
    render(&plain, 4 * SPP, 300, &reference);

    tracer t = {.s = &s};
    nf_guide_policy_init(&t.policy);
    t.mis_training = 1;
    nf_guide *guide = budget_guide_with(&s, 0.5f, MODEL_PRIOR_COSINE, pass_choice);
    budget_settings bs = {seconds, now_seconds(), 2, seed};
    image img;
    budget_report rep;
    if (!render_with_budget(&t, guide, &bs, &img, &rep, &err))
        fail_msg("%s", err.msg);
    double elapsed = now_seconds() - bs.start;
    printf("  budget job: %u training passes, %u render passes (%u plain), %.3f s, training "
           "weight %.3f\n",
           rep.sched.train_passes, rep.sched.render_passes, rep.sched.kind_passes[NF_PASS_PLAIN],
           elapsed, rep.sched.train_weight);
    assert_true(rep.sched.train_passes >= 1);
    assert_true(rep.sched.render_passes >= 2);
    assert_int_equal(rep.refused, 0);
    assert_int_equal(rep.steps, rep.sched.train_passes * 4);
    assert_int_equal(nf_model_step_count(nf_guide_training_model(guide)), (uint64_t)rep.steps);
    nf_guide_stats gs;
    assert_int_equal(nf_guide_get_stats(guide, &gs), NF_OK);
    assert_int_equal(gs.samples, rep.samples);
    assert_true(rep.sched.train_weight >= 0.0 && rep.sched.train_weight <= 1.0);
    assert_int_equal(rep.sched.kind_passes[NF_PASS_GUIDED] + rep.sched.kind_passes[NF_PASS_PLAIN],
                     rep.sched.render_passes);
    for (int k = 0; k < 2; ++k)
        assert_true(rep.sched.kind_variance[k] >= 0.0 && isfinite(rep.sched.kind_variance[k]));
    if (pass_choice) /* the two plain passes before training come first */
        assert_true(rep.sched.kind_passes[NF_PASS_PLAIN] >= 2);
    else { /* every render pass guided, and no choice made */
        assert_int_equal(rep.sched.kind_passes[NF_PASS_PLAIN], 0);
        assert_true(isnan(rep.sched.ratio));
    }
    assert_null(t.model); /* the job's published model does not outlive it */
    /* The job stops before a pass that would overrun; a pass of this 20 x 20 film takes
     * milliseconds (tens under sanitizers), so 0.25 s is a wide margin for a loaded machine
     * and still catches a job that ignores its budget. */
    assert_true(elapsed < bs.seconds + 0.25);
    assert_same_mean(pass_choice ? "budget job, guided and plain passes combined"
                                 : "budget job, every pass guided",
                     &reference, &img);
    image_free(&img);
    image_free(&reference);
    nf_guide_destroy(guide);
    scene_free(&s);
}

static void test_budget_job(void **state)
{
    (void)state;
    check_budget_job(1, 1.0, 9);
}

static void test_budget_job_guided_passes(void **state)
{
    (void)state;
    check_budget_job(0, 0.5, 5);
}

/* Guided vertices of one render of the mixed scene (8 spp) with the boost cap `max_boost`
 * (0: none) and g 0.5. */
static uint64_t guided_vertices_with_cap(float max_boost)
{
    scene s = load_mixed();
    tracer t = {.s = &s};
    t.policy = policy(0.5f, 0.0f, 0, 0.0f);
    nf_model *model = trained_model(&t);
    t.policy.max_boost = max_boost;
    tr_error err;
    path_stats st = {0};
    image img;
    assert_true(image_alloc(&img, s.width, s.height, &err));
    if (!render_image(&t, 8, 11, 0, 2, &img, &st, NULL, &err))
        fail_msg("%s", err.msg);
    assert_int_equal(st.nf_errors, 0);
    image_free(&img);
    nf_model_destroy(model);
    scene_free(&s);
    return st.guided_vertices;
}

static void test_boost_cap_lowers_guiding(void **state)
{
    (void)state;
    /* Wired into the integrator (the rule itself: the library's tests/correctness/test_guide.c):
     * g = 0.5 lets the first vertex alone raise a path 2-fold, so a cap of 1.02 leaves it
     * g = 0.02 and no vertex is guided. */
    uint64_t none = guided_vertices_with_cap(0.0f);
    uint64_t first = guided_vertices_with_cap(1.02f);
    printf("  guided vertices: no cap %llu, cap 1.02 %llu\n", (unsigned long long)none,
           (unsigned long long)first);
    assert_true(none > 0);
    assert_int_equal(first, 0);
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
    nf_guide_policy_init(&t.policy);
    nf_guide *guide = budget_guide(&s, 0.5f);
    budget_settings bs = {0.2, now_seconds(), 2, 1};
    image img;
    budget_report rep;
    if (!render_with_budget(&t, guide, &bs, &img, &rep, &err))
        fail_msg("%s", err.msg);
    assert_true(rep.sched.train_passes >= 1 && rep.sched.render_passes >= 2);
    assert_int_equal(rep.samples, 0);
    for (size_t i = 0; i < 3u * 8u * 8u; ++i)
        assert_true(img.data[i] == 0.0f); /* NaN compares unequal */
    image_free(&img);
    nf_guide_destroy(guide);
    scene_free(&s);
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_levers_match_unguided),
    cmocka_unit_test(test_boost_cap_lowers_guiding),
    cmocka_unit_test(test_budget_job),
    cmocka_unit_test(test_budget_job_guided_passes),
    cmocka_unit_test(test_budget_job_black_scene),
    cmocka_unit_test(test_budget_job_bsdf_prior),
    cmocka_unit_test(test_two_jobs_train_at_once),
)
