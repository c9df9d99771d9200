/*
 * budget.h - a whole render in a wall-clock budget: the time-budgeted job behind
 * `nf_tracer --time-budget`, and what docs/equal-time.md measures.
 *
 * The job is a sequence of passes of one path per pixel (render_pass):
 *   0. with the guide's choice of passes (nf_guide_config.pass_choice), two plain passes,
 *      the yardstick that training measures itself against;
 *   1. training passes, guided by the guide's published model: their records go to the
 *      guide, which trains after each pass (nisflow/guide.h: its store, its steps, its
 *      schedule), and their radiance is kept, not thrown away;
 *   2. render passes with the model frozen, each guided or plain as nf_guide_choose_pass
 *      says, a guided one guiding as deep as nf_guide_choose_depth says, until the next pass
 *      would overrun the budget.
 * Every pass also writes its paths' estimates of the second moments of plain path tracing and
 * of guiding less deep than the pass (nf_plain_moment, nf_depth_moment), which measure those
 * kinds. Training stops when the guide says (nf_guide_keep_training: its share of the
 * budget, the held-out loss's patience, or the training passes' ratio to a plain pass). The
 * image is the inverse-variance combination of the training passes (grouped) and the render
 * passes of every kind, one weight per kind (docs/tracer.md, "The time budget"). Without a
 * guide every pass is a plain render pass.
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
    int train_passes, render_passes, steps;
    uint64_t samples;          /* training samples used                                     */
    double train_seconds;      /* tracing and stepping of the training passes               */
    double step_seconds;       /* of which optimizer steps                                  */
    double render_seconds;
    double render_cpu_seconds; /* CPU time of the render passes, all threads                */
    /* The render passes by kind, [NF_PASS_GUIDED] and [NF_PASS_PLAIN] (nisflow/guide.h); a
     * guided pass's variance is its kinds' weighted by their passes:                       */
    int kind_passes[2];
    double kind_cpu_seconds[2];
    double kind_variance[2];   /* relative variance of one pass (nf_guide_pass_variance)    */
    double ratio;              /* the last choice's guided / plain variance x cost; NaN:
                                * none made (no guide, or too few passes)                   */
    /* The guided render passes by the guide's depth candidates (nf_guide_depth_of), summed
     * in kind_*[NF_PASS_GUIDED]; with a fixed depth (depth_fixed), all of them in [0]:       */
    int depth_passes[NF_GUIDE_DEPTHS];
    double depth_cpu_seconds[NF_GUIDE_DEPTHS];
    double depth_variance[NF_GUIDE_DEPTHS];
    int depth;                 /* the depth of the last choice, 0: every depth             */
    int depth_fixed;           /* the user fixed it (integrator.h guide_depth)            */
    double depth_ratio;        /* the last choice's variance x cost over every depth's; NaN:
                                * none made                                                 */
    int explored;              /* guided passes kept while plain ones measured better       */
    double train_ratio;        /* the last training pass's guided / plain variance x cost   */
    double seconds;            /* the whole job                                             */
    double train_weight;       /* the training passes' share of the combined image, [0, 1]  */
    float last_loss;
    int stopped_early;         /* training ended because the loss or the gain stopped
                                * improving                                                 */
    int refused;               /* optimizer steps the library refused                       */
    path_stats stats;
} budget_report;

/* Runs the job into img (allocated here at the scene's resolution; the caller frees it).
 * With guide != NULL its training model is trained in place and t->model is set to its
 * published model for each pass (NULL on return); guide NULL: plain path tracing. With the
 * BSDF prior (t->bsdf_prior) the guide must keep sizeof(guide_point) payload bytes per
 * sample, each sample's material, or the job is refused. */
int render_with_budget(tracer *t, nf_guide *guide, const budget_settings *bs, image *img,
                       budget_report *rep, tr_error *err);

#endif /* TRACER_BUDGET_H */
