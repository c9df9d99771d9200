/*
 * nisflow/schedule.h - the schedule: what a renderer that renders in passes (each pixel once
 * per pass, say) renders next to make the best image in a time budget.
 *
 * After training, a pass guided by the flow costs more than a plain one and does not always
 * buy that much less variance; guiding deep vertices may not repay its questions either. The
 * schedule decides, pass by pass, from what each kind of pass costs and buys as the renderer
 * measured it, and combines every pass into one image at the end:
 *
 *   1. with a guide that chooses (nf_guide_config.pass_choice), two plain passes: the
 *      yardstick that training measures itself against;
 *   2. training passes, guided at every depth, whose samples the renderer hands to the guide
 *      and trains on after each pass, until nf_guide_keep_training says stop (its share of the
 *      budget, the held-out loss's patience, or the training passes' ratio to a plain pass);
 *   3. render passes, each guided (to a depth, nf_guide_choose_depth) or plain
 *      (nf_guide_choose_pass), until the next pass would overrun the budget;
 *   4. the image: every pass's radiance, training passes included, by inverse variance (one
 *      weight per kind of render pass, one per group of training passes;
 *      docs/integration.md, "The schedule").
 *
 * The loop (docs/integration.md has it with a renderer around it):
 *
 *     nf_schedule_config sc;  nf_schedule_config_init(&sc);
 *     sc.width = w;  sc.height = h;  sc.budget = seconds;
 *     nf_schedule_create(guide, &sc, &s);
 *     for (;;) {
 *         nf_pass_plan plan;  nf_schedule_next(s, elapsed_seconds, NULL, &plan);
 *         if (plan.todo == NF_TODO_STOP) break;
 *         ... render one pass as plan says into rgb[] and moments[], timing it ...
 *         nf_schedule_add_pass(s, &plan, rgb, moments, seconds, cpu_seconds, NULL);
 *         if (plan.todo == NF_TODO_TRAIN) { train (nf_guide_train_pass), publish }
 *     }
 *     nf_schedule_combine(s, NULL, image, &report);
 *
 * What a pass measures. Every pass writes, per pixel, its RGB radiance and the estimates of
 * the second moments that its paths measured for the kinds it did not render
 * (nf_plain_moment, nf_depth_moment): moments[m x pixels + i] for m < NF_GUIDE_DEPTHS is
 * pixel i's sum over its paths of the moment of candidate m's policy, where candidate 0 is
 * plain path tracing (nf_plain_moment) and candidates 1, 2 guide up to nf_guide_depth_of(m).
 * Plain passes may give NULL (each pixel's squared luminance is used). Luminance here is the
 * mean of R, G and B.
 *
 * Processes. With a caller-supplied nf_reduce (guide.h) the schedule spans processes that
 * render disjoint pixels of one image (the other pixels zero): each call below is then
 * collective, every process calls it in the same order with the same plans, and every
 * process gets the same plans (elapsed is the largest over them). A call refused on one
 * process (bad input) must be made to fail on the others, as for the guide.
 *
 * Memory: everything is allocated by nf_schedule_create, from the guide's allocator (malloc
 * without a guide): about width x height x 1.2 KB (32 groups of training passes and five
 * kinds of pass, in doubles); nothing later allocates. Thread-safety: one thread drives a
 * schedule (no two calls on it at once); schedules are independent. nf_schedule_next reads
 * the guide's training state: no training call of the guide may run meanwhile. Stack: a few
 * hundred bytes.
 */
#ifndef NISFLOW_SCHEDULE_H
#define NISFLOW_SCHEDULE_H

#include <stddef.h>
#include <stdint.h>

#include "guide.h"
#include "status.h"
#include "version.h"

NF_EXTERN_C_BEGIN

typedef struct nf_schedule nf_schedule;

/* What a schedule is made of. Zero is never valid: call nf_schedule_config_init, then set the
 * image and the budget. */
typedef struct nf_schedule_config {
    uint32_t magic_; /* set by nf_schedule_config_init                                  */
    uint32_t width;  /* the image, in pixels: [1, 2^16] each, width x height <= 2^26;
                      * no default                                                    */
    uint32_t height;
    double budget;        /* the job's length in the unit of `elapsed` (seconds, say), > 0
                           * and finite; no default                                        */
    uint32_t guide_depth; /* 0: the schedule chooses how deep guided render passes guide
                           * (default); D >= 1: every guided pass, training too, guides up
                           * to depth D (an experiment's fixed depth)                      */
} nf_schedule_config;

/* Fills sc with the defaults (width, height and budget 0: the caller sets them). NULL is
 * ignored. Thread-safe. */
NF_API void nf_schedule_config_init(nf_schedule_config *sc);

/* Creates a schedule for passes of the configured image. guide: the guide whose model guided
 * passes sample and whose training it schedules; it must outlive the schedule. NULL: plain
 * path tracing, every pass plain. Errors: NF_ERROR_INVALID_ARGUMENT (NULL sc or out, a config
 * not from nf_schedule_config_init, a field out of range: the message names it),
 * NF_ERROR_OUT_OF_MEMORY; *out is then NULL. Thread-safe; allocates everything it will use. */
NF_API nf_status nf_schedule_create(nf_guide *guide, const nf_schedule_config *sc,
                                    nf_schedule **out);

/* Frees the schedule. NULL is a no-op. */
NF_API void nf_schedule_destroy(nf_schedule *s);

/* ---- Pass by pass ------------------------------------------------------------------------ */

/* What to render next. */
typedef enum nf_pass_todo {
    NF_TODO_TRAIN = 0,  /* a training pass: guided up to `depth` (0: every depth) by the
                         * guide's published model, its samples added to the guide; after
                         * nf_schedule_add_pass, train (nf_guide_train_pass) and publish    */
    NF_TODO_GUIDED = 1, /* a render pass guided up to `depth` (0: every depth); no samples   */
    NF_TODO_PLAIN = 2,  /* a render pass without the flow (BSDF sampling and next-event
                         * estimation: the renderer's own path tracer)                      */
    NF_TODO_STOP = 3    /* the next pass would overrun the budget: call nf_schedule_combine */
} nf_pass_todo;

/* nf_schedule_next's answer; hand it back unchanged to nf_schedule_add_pass. */
typedef struct nf_pass_plan {
    nf_pass_todo todo;
    uint32_t depth; /* TRAIN and GUIDED: the deepest vertex guided, in segments from the
                     * camera (the first vertex is 1), 0 for every depth                  */
    uint32_t pass;  /* the pass's index from 0: a random stream per pass, say             */
    uint32_t kind_; /* the schedule's own                                                 */
    uint32_t measure_;
} nf_pass_plan;

/* The next pass to render, at `elapsed` (the budget's unit, counted from the job's start).
 * The first pass is always rendered, however short the budget; later, STOP once the next pass
 * (timed as the last pass of its kind, or of any kind) would end after the budget, and STOP
 * ever after. The answer depends only on elapsed, the passes added and the guide's training
 * state: processes that add the same passes get the same plans. Each plan must be added
 * (nf_schedule_add_pass) before the next call: a second call refuses. Errors:
 * NF_ERROR_INVALID_ARGUMENT (NULL, elapsed NaN or negative, a plan not added), a reduce hook's
 * status; the schedule is then unchanged. */
NF_API nf_status nf_schedule_next(nf_schedule *s, double elapsed, const nf_reduce *red,
                                  nf_pass_plan *plan);

/* Adds the pass that `plan` (the latest from nf_schedule_next) asked for: rgb[3 x pixels]
 * (row by row) and moments (as above; NULL only for a plain pass), seconds its wall-clock time
 * (for a training pass, the rendering only, not the steps), cpu_seconds its CPU time summed
 * over the threads that rendered it (the choice weighs kinds by it; the first pass of the job,
 * and passes before training ended, pay for cold caches and do not decide it). Errors:
 * NF_ERROR_INVALID_ARGUMENT (NULL, a plan not the latest or added twice, a value not finite or
 * a moment negative: the message names the first pixel; times negative or not finite), a
 * reduce hook's status; the schedule is then unchanged. */
NF_API nf_status nf_schedule_add_pass(nf_schedule *s, const nf_pass_plan *plan, const float *rgb,
                                      const float *moments, double seconds, double cpu_seconds,
                                      const nf_reduce *red);

/* ---- The image --------------------------------------------------------------------------- */

/* What the schedule did, for a renderer's log. */
typedef struct nf_schedule_report {
    uint32_t train_passes, render_passes;
    double render_seconds; /* wall-clock seconds of the render passes          */
    /* The render passes by kind, [NF_PASS_GUIDED] and [NF_PASS_PLAIN]: */
    uint32_t kind_passes[2];
    double kind_cpu_seconds[2];
    double kind_variance[2]; /* relative variance of one pass (guide.h); a guided
                              * pass's is its depths' weighted by their passes   */
    /* The guided render passes by depth candidate (nf_guide_depth_of); with a fixed
     * guide_depth, all of them in [0]: */
    uint32_t depth_passes[NF_GUIDE_DEPTHS];
    double depth_cpu_seconds[NF_GUIDE_DEPTHS];
    double depth_variance[NF_GUIDE_DEPTHS];
    uint32_t depth;      /* the last choice's depth, 0: every depth          */
    double ratio;        /* the last choice's guided / plain variance x cost
                          * (steady costs); NaN: none made                  */
    double depth_ratio;  /* its depth's over every depth's; NaN: none made   */
    double train_ratio;  /* the last training pass's guided / plain; NaN     */
    uint32_t explored;   /* passes of the kind that measured worse, kept so
                          * that its estimate goes on improving              */
    int stopped_early;   /* training ended before its share of the budget:
                          * the loss or the gain stopped improving           */
    double train_weight; /* the training passes' share of the image, [0, 1]  */
} nf_schedule_report;

/* The image: every pass added, combined by inverse variance, into rgb[3 x pixels] (this
 * process's pixels; the others' are 0, so the processes' images add up to the whole). report
 * (may be NULL) receives what the schedule did. It may be called more than once, and passes
 * added after it. Errors: NF_ERROR_INVALID_ARGUMENT (NULL s or rgb), a reduce hook's status;
 * rgb is then unchanged. */
NF_API nf_status nf_schedule_combine(nf_schedule *s, const nf_reduce *red, float *rgb,
                                     nf_schedule_report *report);

NF_EXTERN_C_END

#endif /* NISFLOW_SCHEDULE_H */
