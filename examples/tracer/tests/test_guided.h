/*
 * test_guided.h - the tracer the tests render with: plain, or guided by a fresh model that a
 * few training iterations moved off its prior (an estimator must stay unbiased for any model,
 * not only for a flow that is still its prior), with test_policy(0.5); and one image rendered
 * with it. Each helper fails the calling test on an error. Include it after cmocka.h.
 */
#ifndef TRACER_TEST_GUIDED_H
#define TRACER_TEST_GUIDED_H

#include <nisflow/nisflow.h>

#include "image.h"
#include "integrator.h"
#include "model_setup.h"
#include "render.h"
#include "scene.h"
#include "test_policy.h"
#include "training.h"

/* What the BSDF prior's callbacks of the models made here read (bsdf_prior.h); static, so zero
 * is a valid empty lookup. */
static prior_lookup test_lookup;

/* A tracer of `s`: plain when `guided` is 0; otherwise guided by a model with `prior` (model
 * seed 7) trained `iterations` iterations of 256 paths on 2 threads (seed 3), none refused,
 * through the paper's protocol (render/training.c). The caller destroys its model with
 * nf_model_destroy((nf_model *)t.model). */
static inline tracer test_tracer(const scene *s, int guided, model_prior prior, int iterations)
{
    tracer t = {.s = s};
    if (!guided)
        return t;
    tr_error err;
    nf_model *model = NULL;
    model_settings gs = model_default_settings(prior);
    gs.seed = 7;
    if (!model_create_for_scene(s, &gs, &test_lookup, &model, &err))
        fail_msg("%s", err.msg);
    t.policy = test_policy(0.5f);
    t.bsdf_prior = prior == MODEL_PRIOR_BSDF;
    if (iterations > 0) {
        training_settings ts = {.iterations = iterations, .batch = 256, .eval_spp = 1,
                                .threads = 2, .seed = 3};
        training_report rep;
        if (!train_guide(&t, &model, &ts, &rep, &err))
            fail_msg("%s", err.msg);
        assert_true(rep.samples > 0);
        assert_int_equal(rep.refused, 0);
        assert_int_equal(nf_model_step_count(model), (uint64_t)iterations);
    }
    t.model = model;
    return t;
}

/* One image of the scene's size at `spp` samples per pixel (seed `seed`, pass 0, 2 threads)
 * into *img, which the caller frees; its statistics in *st (may be NULL). No libnisflow error
 * may cut a path short. */
static inline void test_render(const tracer *t, int spp, uint64_t seed, image *img,
                               path_stats *st)
{
    tr_error err;
    path_stats own = {0};
    if (!image_alloc(img, t->s->width, t->s->height, &err))
        fail_msg("%s", err.msg);
    if (!render_image(t, spp, seed, 0, 2, img, &own, NULL, &err))
        fail_msg("%s", err.msg);
    assert_int_equal(own.nf_errors, 0);
    if (st)
        *st = own;
}

#endif /* TRACER_TEST_GUIDED_H */
