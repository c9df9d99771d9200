/*
 * budget.h - a whole render in a wall-clock budget: the time-budgeted job behind
 * `nf_tracer --time-budget`, and what docs/equal-time.md measures.
 *
 * The job is a sequence of passes of one path per pixel (render_pass):
 *   1. training passes, guided by the current model: their records train the model (and the
 *      guiding probabilities, selection.h), and their radiance is kept, not thrown away;
 *   2. render passes with the model frozen, until the next pass would overrun the budget.
 * Training stops at `train_fraction` of the budget, or earlier when the loss, measured on
 * each pass's fresh samples before the model has seen them and averaged over about three
 * passes, has not improved by 1 % for `patience` passes. The image is
 * the inverse-variance combination of the training passes (grouped) and the render passes
 * (docs/equal-time.md, "How the budget is spent"). Without a model every pass is a render pass.
 */
#ifndef TRACER_BUDGET_H
#define TRACER_BUDGET_H

#include <stdint.h>

#include <nisflow/nisflow.h>

#include "error.h"
#include "image.h"
#include "integrator.h"

typedef struct budget_settings {
    double seconds;          /* the whole job, counted from `start` (seconds, > 0)          */
    double start;            /* now_seconds() when the budget began                        */
    double train_fraction;   /* at most this share of the budget trains, [0, 1)            */
    int step_samples;        /* training samples per optimizer step                         */
    int steps_per_pass;      /* optimizer steps after each training pass                   */
    int patience;            /* passes without a 1 % better loss before training stops; 0:
                              * never stop early                                           */
    int combine;             /* 1: inverse-variance combination; 0: training passes dropped */
    float clamp_quantile;    /* training weights clamped at this running quantile, 0: none  */
    int learn_selection;     /* learn the guiding probability per cell (selection.h)        */
    int relative_training;   /* training weights divided by their pixel's estimated value
                              * (relative.h)                                               */
    float selection_cost;    /* the cost test's relative cost of a guided vertex; < 0: the
                              * grid's default                                             */
    int threads;
    uint64_t seed;
} budget_settings;

budget_settings budget_default_settings(void);

typedef struct budget_report {
    int train_passes, render_passes, steps;
    uint64_t samples;          /* training samples used                                     */
    double train_seconds;      /* tracing and stepping of the training passes               */
    double step_seconds;       /* of which optimizer steps (and selection updates)          */
    double render_seconds;
    double render_cpu_seconds; /* CPU time of the render passes, all threads                */
    double pass_variance;      /* relative variance of one render pass (luminance; the
                                * estimate from the passes' spread, so heavy tails are
                                * underestimated), 0 with fewer than 2 passes               */
    double seconds;            /* the whole job                                             */
    double train_weight;       /* the training passes' share of the combined image, [0, 1]  */
    float last_loss;
    int stopped_early;         /* training ended because the loss stopped improving         */
    int refused;               /* optimizer steps the library refused                       */
    double selection_off;      /* share of the visited cells where guiding is off           */
    path_stats stats;
} budget_report;

/* Runs the job into img (allocated here at the scene's resolution; the caller frees it).
 * With model != NULL, t->model must be it; the model is trained in place. */
int render_with_budget(tracer *t, nf_model *model, const budget_settings *bs, image *img,
                       budget_report *rep, tr_error *err);

#endif /* TRACER_BUDGET_H */
