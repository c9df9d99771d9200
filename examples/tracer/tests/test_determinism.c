/*
 * test_determinism.c - a given seed gives the same result whatever the number of threads:
 * rendered images and trained models are compared bit for bit between 1 and 3 threads, and
 * a different seed must change them (so the comparison is not vacuous). Also: a saved model
 * loads with its BSDF-prior callbacks and renders identically. A render pass gives the same
 * bits, and a training pass the same records, whether its paths ask the flow one vertex at a
 * time (trace_path) or batched across paths (trace_paths).
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "nf_test_main.h"

#include "model_setup.h"
#include "render.h"
#include "scene.h"
#include "training.h"

#include "test_policy.h"

static void load_scene(scene *s, const char *name)
{
    tr_error err;
    char path[1024];
    snprintf(path, sizeof path, "%s/%s/scene.xml", TRACER_SCENES_DIR, name);
    if (!scene_load(path, s, &err))
        fail_msg("%s", err.msg);
    scene_set_resolution(s, 24, 24);
}

static void load_cornell(scene *s) { load_scene(s, "cornell-box"); }

/* What the BSDF prior's callbacks of the models made here read (bsdf_prior.h); static, so zero
 * is a valid empty lookup. */
static prior_lookup test_lookup;

/* Trains a fresh model for 3 iterations and renders 2 spp with it. */
static void train_and_render(const scene *s, model_prior prior, int threads, uint64_t seed,
                             nf_model **model, image *img)
{
    tr_error err;
    model_settings gs = model_default_settings(prior);
    if (!model_create_for_scene(s, &gs, &test_lookup, model, &err))
        fail_msg("%s", err.msg);
    tracer t = {.s = s, .policy = test_policy(0.5f), .bsdf_prior = prior == MODEL_PRIOR_BSDF};
    training_settings ts = {.iterations = 3, .batch = 200, .eval_spp = 1, .threads = threads,
                            .seed = seed};
    training_report rep;
    if (!train_guide(&t, model, &ts, &rep, &err))
        fail_msg("%s", err.msg);
    t.model = *model;
    assert_true(image_alloc(img, s->width, s->height, &err));
    if (!render_image(&t, 2, seed, 0, threads, img, NULL, NULL, &err))
        fail_msg("%s", err.msg);
}

static void compare_params(const nf_model *a, const nf_model *b, int expect_equal)
{
    size_t n = nf_model_param_count(a);
    float *pa = malloc(n * sizeof *pa), *pb = malloc(n * sizeof *pb);
    assert_non_null(pa);
    assert_non_null(pb);
    assert_int_equal(nf_model_get_params(a, pa), NF_OK);
    assert_int_equal(nf_model_get_params(b, pb), NF_OK);
    if (expect_equal)
        assert_memory_equal(pa, pb, n * sizeof *pa);
    else
        assert_memory_not_equal(pa, pb, n * sizeof *pa);
    free(pa);
    free(pb);
}

static void check_prior(model_prior prior)
{
    scene s;
    load_cornell(&s);
    nf_model *m1, *m3, *m_other;
    image i1, i3, i_other;
    train_and_render(&s, prior, 1, 42, &m1, &i1);
    train_and_render(&s, prior, 3, 42, &m3, &i3);
    train_and_render(&s, prior, 3, 43, &m_other, &i_other);
    size_t bytes = (size_t)s.width * (size_t)s.height * 3u * sizeof(float);
    compare_params(m1, m3, 1);
    assert_memory_equal(i1.data, i3.data, bytes);
    compare_params(m1, m_other, 0);
    assert_memory_not_equal(i1.data, i_other.data, bytes);
    nf_model_destroy(m1);
    nf_model_destroy(m3);
    nf_model_destroy(m_other);
    image_free(&i1);
    image_free(&i3);
    image_free(&i_other);
    scene_free(&s);
    /* The BSDF prior found its shading point in every callback, in rendering and training. */
    assert_int_equal(atomic_load(&test_lookup.failures), 0);
}

/* The same model and image on 1 and 3 threads (another seed differs) under the prior in
 * *state. */
static void test_threads_do_not_change_results(void **state)
{
    check_prior((model_prior)nft_case(state));
}

static void test_saved_model_renders_identically(void **state)
{
    (void)state;
    scene s;
    tr_error err;
    load_cornell(&s);
    nf_model *m, *loaded;
    image a, b;
    train_and_render(&s, MODEL_PRIOR_BSDF, 2, 5, &m, &a);
    char path[1024];
    snprintf(path, sizeof path, "%s/saved.nf", TRACER_TEST_TMP_DIR);
    assert_int_equal(nf_model_save(m, path), NF_OK);
    if (!model_load_file(path, &test_lookup, &loaded, &err))
        fail_msg("%s", err.msg);
    compare_params(m, loaded, 1);
    tracer t = {.s = &s, .model = loaded, .policy = test_policy(0.5f), .bsdf_prior = 1};
    assert_true(image_alloc(&b, s.width, s.height, &err));
    assert_true(render_image(&t, 2, 5, 0, 2, &b, NULL, NULL, &err));
    assert_memory_equal(a.data, b.data, (size_t)s.width * (size_t)s.height * 3u * sizeof(float));
    nf_model_destroy(m);
    nf_model_destroy(loaded);
    image_free(&a);
    image_free(&b);
    scene_free(&s);
}

/* The records of two passes, field by field (their padding is not written). */
static void assert_same_records(const record_buffer *a, const record_buffer *b)
{
    assert_int_equal(a->count, b->count);
    for (size_t i = 0; i < a->count; ++i) {
        const train_record *x = &a->data[i], *y = &b->data[i];
        assert_memory_equal(&x->ctx, &y->ctx, sizeof x->ctx);
        assert_memory_equal(x->dir, y->dir, sizeof x->dir);
        assert_true(x->weight == y->weight);
        assert_true(x->pixel == y->pixel && x->bp.b == y->bp.b);
    }
}

/* A record sink that keeps each chunk's records apart (at most 16 chunks), to compare passes
 * in chunk order. */
typedef struct tile_parts {
    record_buffer tile[16];
    int out_of_memory;
} tile_parts;

static void keep_tile(void *user, size_t chunk, int thread, const record_buffer *records)
{
    (void)thread;
    tile_parts *p = user;
    if (chunk >= 16 || records->out_of_memory || !record_buffer_append(&p->tile[chunk], records))
        p->out_of_memory = 1;
}

/* The pass's records in chunk order; the parts are freed. */
static void join_tiles(tile_parts *p, record_buffer *out)
{
    assert_false(p->out_of_memory);
    for (int i = 0; i < 16; ++i) {
        assert_true(record_buffer_append(out, &p->tile[i]));
        record_buffer_free(&p->tile[i]);
    }
}

/* The first pass of a schedule for a w x h image that fits a pass. */
static nf_pass_plan whole_image_plan(int w, int h)
{
    nf_schedule_config sc;
    nf_schedule_config_init(&sc);
    sc.width = (uint32_t)w;
    sc.height = (uint32_t)h;
    sc.budget = 1.0;
    nf_schedule *sched = NULL;
    nf_pass_plan plan;
    assert_int_equal(nf_schedule_create(NULL, &sc, &sched), NF_OK);
    assert_int_equal(nf_schedule_next(sched, 0.0, NULL, &plan), NF_OK);
    nf_schedule_destroy(sched); /* the plan holds no pointer into it */
    return plan;
}

/* One pass rendered three times: one path at a time with the flow asked at shading points
 * (no_batching), and with the questions of TRACE_BATCH paths batched (trace_paths), with
 * records (a training pass) and without. 37 x 23 pixels leave partial tiles and partial
 * batches. */
static void check_batched_pass_in(const char *scene_name, model_prior prior,
                                  uint32_t light_mis_depth, int light_mis_bsdf)
{
    scene s;
    tr_error err;
    load_scene(&s, scene_name);
    scene_set_resolution(&s, 37, 23);
    nf_model *m;
    image trained, one, batched, recorded, other;
    train_and_render(&s, prior, 2, 7, &m, &trained);
    /* Shading points and batch calls give the same bits on every kernel but the presets'
     * AVX-512 vector path (docs/architecture.md, "Which rule holds where"), which agrees within
     * a bound: the tracer's two ways of asking are compared where the bits must agree. */
    assert_int_equal(nf_model_set_isa(m, NF_ISA_GENERIC), NF_OK);
    tracer t = {.s = &s, .model = m, .policy = test_policy(0.5f),
                .bsdf_prior = prior == MODEL_PRIOR_BSDF, .light_mis_bsdf = light_mis_bsdf};
    t.policy.light_mis_depth = light_mis_depth;
    tracer one_by_one = t;
    one_by_one.no_batching = 1;
    assert_true(image_alloc(&one, s.width, s.height, &err));
    assert_true(image_alloc(&batched, s.width, s.height, &err));
    assert_true(image_alloc(&recorded, s.width, s.height, &err));
    assert_true(image_alloc(&other, s.width, s.height, &err));
    record_buffer records_one = {0}, records_batched = {0};
    tile_parts parts_one = {0}, parts_batched = {0};
    const record_sink sink_one = {keep_tile, &parts_one},
                      sink_batched = {keep_tile, &parts_batched};
    render_memory mem = {0}; /* reused by the passes, as budget.c does */
    path_stats st_one = {0}, st_batched = {0}, st_recorded = {0};
    size_t pixels = (size_t)s.width * (size_t)s.height;
    float *moment_one = calloc(PATH_MOMENTS * pixels, sizeof(float)),
          *moment_batched = calloc(PATH_MOMENTS * pixels, sizeof(float));
    assert_non_null(moment_one);
    assert_non_null(moment_batched);
    /* A schedule's pass over the whole image: path j through pixel j, into the images. */
    nf_pass_plan plan = whole_image_plan(s.width, s.height);
    assert_int_equal(plan.paths, pixels);
    assert_true(render_pass(&one_by_one, 7, 3, &plan, 2, one.data, moment_one, &sink_one, NULL,
                            &st_one, &err));
    assert_true(render_pass(&t, 7, 3, &plan, 2, batched.data, moment_batched, NULL, &mem,
                            &st_batched, &err));
    assert_true(render_pass(&t, 7, 3, &plan, 2, recorded.data, NULL, &sink_batched, &mem,
                            &st_recorded, &err));
    assert_true(render_pass(&t, 7, 4, &plan, 2, other.data, NULL, NULL, &mem, NULL, &err));
    render_memory_free(&mem);
    join_tiles(&parts_one, &records_one);
    join_tiles(&parts_batched, &records_batched);
    size_t bytes = pixels * 3u * sizeof(float);
    assert_memory_equal(one.data, batched.data, bytes);
    /* The paths' estimates of plain path tracing's and the depth candidates' second moments
     * too, and they say something. */
    assert_memory_equal(moment_one, moment_batched, PATH_MOMENTS * pixels * sizeof(float));
    double moments = 0.0;
    for (size_t i = 0; i < PATH_MOMENTS * pixels; ++i)
        moments += moment_one[i];
    assert_true(moments > 0.0);
    free(moment_one);
    free(moment_batched);
    assert_memory_equal(one.data, recorded.data, bytes);
    assert_memory_not_equal(one.data, other.data, bytes); /* the comparison is not vacuous */
    assert_memory_equal(&st_one, &st_batched, sizeof st_one);
    assert_memory_equal(&st_one, &st_recorded, sizeof st_one);
    assert_true(st_batched.guided_vertices > 0);
    assert_int_equal(st_batched.nf_errors, 0);
    assert_true(records_one.count > 0);
    assert_same_records(&records_one, &records_batched);
    record_buffer_free(&records_one);
    record_buffer_free(&records_batched);
    nf_model_destroy(m);
    image_free(&trained);
    image_free(&one);
    image_free(&batched);
    image_free(&recorded);
    image_free(&other);
    scene_free(&s);
}

static void check_batched_pass(model_prior prior, uint32_t light_mis_depth, int light_mis_bsdf)
{
    check_batched_pass_in("cornell-box", prior, light_mis_depth, light_mis_bsdf);
}

static void test_batched_pass_equals_one_path_at_a_time(void **state)
{
    (void)state;
    check_batched_pass(MODEL_PRIOR_COSINE, 0, 0);
    check_batched_pass(MODEL_PRIOR_COSINE, 1, 0); /* deeper light samples ask nothing */
    check_batched_pass(MODEL_PRIOR_COSINE, 0, 1); /* light samples ask nothing */
    check_batched_pass(MODEL_PRIOR_BSDF, 0, 0); /* asked at shading points in both passes */
    /* a dense medium: volume vertices, free flight, null boundaries */
    check_batched_pass_in("cornell-box-smoke", MODEL_PRIOR_COSINE, 0, 0);
    check_batched_pass_in("cornell-box-smoke", MODEL_PRIOR_BSDF, 0, 0);
}

NFT_TEST_MAIN(
    NFT_TEST_CASE("test_threads_do_not_change_results_cosine",
                  test_threads_do_not_change_results, MODEL_PRIOR_COSINE),
    NFT_TEST_CASE("test_threads_do_not_change_results_bsdf_prior",
                  test_threads_do_not_change_results, MODEL_PRIOR_BSDF),
    cmocka_unit_test(test_saved_model_renders_identically),
    cmocka_unit_test(test_batched_pass_equals_one_path_at_a_time),
)
