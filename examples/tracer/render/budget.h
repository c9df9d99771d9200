/*
 * budget.h - a whole render in a wall-clock budget: the time-budgeted job behind
 * `nf_tracer --time-budget`, and what docs/equal-time.md measures.
 *
 * The library's schedule (nisflow/schedule.h) says what to render next: plain passes first,
 * training passes whose records go to the guide (which trains after each), then render
 * passes guided (to a depth) or plain, until the budget ends; it combines them into the
 * image. This file is the tracer's loop around it: it renders the passes (render_pass), whose
 * render threads hand each chunk's training samples to the guide as soon as it is traced, trains
 * and publishes, and keeps the ranks in step.
 * Without a guide every pass is a plain render pass.
 */
#ifndef TRACER_BUDGET_H
#define TRACER_BUDGET_H

#include <stdint.h>

#include <nisflow/nisflow.h>

#include "error.h"
#include "image.h"
#include "integrator.h"

typedef struct budget_settings {
    double seconds; /* the whole job, counted from `start` (seconds, > 0)          */
    double start;   /* now_seconds() when the budget began                        */
    int threads;
    uint64_t seed;
} budget_settings;

typedef struct budget_report {
    nf_schedule_report sched;  /* the passes, their kinds and the image's weights          */
    int steps;
    uint64_t samples;          /* training samples used                                     */
    double train_seconds;      /* tracing and stepping of the training passes               */
    double step_seconds;       /* of which optimizer steps                                  */
    double seconds;            /* the whole job                                             */
    int depth_fixed;           /* the user fixed the guided depth (integrator.h guide_depth) */
    float last_loss;
    int refused;               /* optimizer steps the library refused                       */
    path_stats stats;
} budget_report;

/* Runs the job into img (allocated here at the scene's resolution; the caller frees it).
 * With guide != NULL its training model is trained in place and t->model is set to its
 * published model for each pass (NULL on return); guide NULL: plain path tracing. With the
 * BSDF prior (t->bsdf_prior) the guide must keep sizeof(prior_point) payload bytes per
 * sample, each sample's material, or the job is refused. */
int render_with_budget(tracer *t, nf_guide *guide, const budget_settings *bs, image *img,
                       budget_report *rep, tr_error *err);

#endif /* TRACER_BUDGET_H */
