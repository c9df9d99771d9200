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
 *      and trains on after each pass, until training stops paying (its share of the budget,
 *      the held-out loss's patience, or the training passes' ratio to a plain pass);
 *   3. render passes, each guided (to a depth) or plain, as each measured in variance x
 *      time, until the next pass would overrun the budget;
 *   4. the image: every pass's radiance, training passes included, by inverse variance
 *      (docs/integration.md, "The schedule").
 *
 * A pass is a fixed number of paths, whatever the image: the whole image, one path per pixel,
 * up to nf_schedule_config.pass_paths pixels (131,072 by default); a larger image is rendered in
 * interleaved subsets of pixels, one subset a pass, so that training and the choice of passes
 * go at the same cadence at 1080p as at 320 x 180. A pass's paths are numbered from 0 to
 * plan.paths - 1 and path j goes through pixel nf_pass_pixel(&plan, j); the arrays handed to
 * nf_schedule_add_pass are in that order.
 *
 * The loop (docs/integration.md has it with a renderer around it):
 *
 *     nf_schedule_config sc;  nf_schedule_config_init(&sc);
 *     sc.width = w;  sc.height = h;  sc.budget = seconds;
 *     nf_schedule_create(guide, &sc, &s);
 *     for (;;) {
 *         nf_pass_plan plan;  nf_schedule_next(s, elapsed_seconds, NULL, &plan);
 *         if (plan.todo == NF_TODO_STOP) break;
 *         for each j < plan.paths: trace a path through pixel nf_pass_pixel(&plan, j)
 *             into rgb[3 j ..] and moments[m x plan.paths + j], timing the pass
 *         nf_schedule_add_pass(s, &plan, rgb, moments, seconds, cpu_seconds, NULL);
 *         if (plan.todo == NF_TODO_TRAIN) { train (nf_guide_train_pass), publish }
 *     }
 *     nf_schedule_combine(s, NULL, image, &report);
 *
 * What a pass measures. Every path writes its RGB radiance and the estimates of the second
 * moments that it measured for the kinds it did not render (nf_path_state.moments):
 * moments[m x plan.paths + j] for m < NF_GUIDE_DEPTHS is path j's moment of candidate m's
 * policy, where candidate 0 is plain path tracing and candidates 1, 2 guide up to depth m. Plain
 * passes may give NULL (each path's squared luminance is used). Luminance here is the mean of R, G
 * and B. A path whose radiance is not finite, or whose moment is not finite or negative, is left
 * out and counted (nf_schedule_report.dropped): one bad path never stops the job. So is a radiance
 * so large that the image's float sums would overflow (possible beyond 10^32).
 *
 * What measuring costs. The schedule measures the kinds of pass on a fixed grid of pixels that
 * every pass renders: the whole image when it fits a pass; for a larger image, at most
 * pass_paths / 16 pixels spread over it, whose paths measure and do not enter the image (1/16
 * of each pass's paths, the price of a measure that does not grow with the image).
 *
 * Processes. With a caller-supplied nf_reduce (guide.h) the schedule spans processes that
 * render disjoint pixels of one image (each pixel always the same process's; the entries of a
 * pass whose pixel another process renders are 0): each call below is then
 * collective, every process calls it in the same order with the same plans, and every
 * process gets the same plans (elapsed is the largest over them). A call refused on one
 * process (bad input) must be made to fail on the others, as for the guide.
 *
 * Memory: everything the schedule object uses is allocated by nf_schedule_create, from the
 * guide's allocator (malloc without a guide): 48 bytes a pixel (three weighted sums of RGB
 * and their weights, in floats: training, guided and plain passes; a pixel's value rounds by
 * about 2^-24 per pass added) and 240 bytes a measured pixel (every pixel up to pass_paths,
 * at most pass_paths / 16 beyond): 100 MB at 1920 x 1080, 398 MB at 3840 x 2160; nothing
 * later allocates. Thread-safety: one thread drives a schedule (no two calls on it at
 * once); schedules are independent. nf_schedule_next and nf_schedule_add_pass read and
 * change the guide's training state (whether training still pays): no training call of the
 * guide may run during them; render threads may sample and add
 * samples meanwhile. Stack: a few hundred bytes.
 */
#ifndef NISFLOW_SCHEDULE_H
#define NISFLOW_SCHEDULE_H

#include <stddef.h>
#include <stdint.h>

#include "guide.h"
#include "status.h"
#include "version.h"

NF_EXTERN_C_BEGIN

/* After training, a pass guided by the flow costs more than a plain one (BSDF sampling and
 * next-event estimation alone: the renderer's path tracer with no flow), and it does not
 * always buy that much less variance: where next-event estimation already finds the light (a
 * box lit directly), plain passes give more per second. The schedule measures both kinds on
 * the passes rendered anyway, chooses the next, and combines the passes of both kinds by
 * inverse variance (docs/schedule-theory.md). The choice stays unbiased: every pass is an
 * unbiased estimate, whichever kind it is. */
typedef enum nf_pass_kind { NF_PASS_GUIDED = 0, NF_PASS_PLAIN = 1 } nf_pass_kind;

/* ---- The schedule ------------------------------------------------------------------------ */

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
    uint32_t pass_paths;  /* the paths of a pass, >= 1024: an image of up to this many
                           * pixels is rendered whole by each pass, a larger one in
                           * subsets (default 131,072; more for many render threads, so
                           * that each has enough paths between the passes' joins)          */
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
    NF_TODO_TRAIN = 0,  /* a training pass: guided up to `depth` (NF_EVERY_DEPTH) by the
                         * guide's published model, its samples added to the guide; after
                         * nf_schedule_add_pass, train (nf_guide_train_pass) and publish    */
    NF_TODO_GUIDED = 1, /* a render pass guided up to `depth` (NF_EVERY_DEPTH: all); no samples */
    NF_TODO_PLAIN = 2,  /* a render pass without the flow (BSDF sampling and next-event
                         * estimation: the renderer's own path tracer)                      */
    NF_TODO_STOP = 3    /* the next pass would overrun the budget: call nf_schedule_combine */
} nf_pass_todo;

/* nf_schedule_next's answer; hand it back unchanged to nf_schedule_add_pass. */
typedef struct nf_pass_plan {
    nf_pass_todo todo;
    uint32_t depth; /* TRAIN and GUIDED: the deepest vertex guided, in segments from the
                     * camera (the first vertex is 1); NF_EVERY_DEPTH (0): every depth   */
    uint32_t pass;  /* the pass's index from 0: a random stream per pass, say             */
    uint32_t paths; /* the pass's paths, one through each of its pixels (nf_pass_pixel);
                     * at most pass_paths + pass_paths / 16 + 1                          */
    /* The schedule's own: */
    uint32_t kind_, measure_;
    uint32_t width_, grid_, grid_width_, measured_, first_, stride_;
} nf_pass_plan;

/* The pixel that path j of the pass goes through, j < plan->paths: its index in the image,
 * row by row (x = index % width, y = index / width). A pixel may have two paths in one pass
 * (one that measures, one for the image). Returns 0 for j out of range or a NULL plan.
 * Thread-safe, allocates nothing, O(1). */
NF_API uint32_t nf_pass_pixel(const nf_pass_plan *plan, uint32_t j);

/* The next pass to render, at `elapsed` (the budget's unit, counted from the job's start).
 * The first pass is always rendered, however short the budget; later, STOP once the next pass
 * (timed as the last pass of its kind, or of any kind) would end after the budget, and STOP
 * ever after; an image rendered in subsets is not stopped before every pixel has a path.
 * The answer depends only on elapsed, the passes added and the guide's training state:
 * processes that add the same passes get the same plans. Each plan must be added
 * (nf_schedule_add_pass) before the next call: a second call refuses. Errors:
 * NF_ERROR_INVALID_ARGUMENT (NULL, elapsed NaN or negative, a plan not added), a reduce hook's
 * status; the schedule is then unchanged. */
NF_API nf_status nf_schedule_next(nf_schedule *s, double elapsed, const nf_reduce *red,
                                  nf_pass_plan *plan);

/* Adds the pass that `plan` (the latest from nf_schedule_next) asked for: rgb[3 x plan.paths]
 * and moments[NF_GUIDE_DEPTHS x plan.paths] in path order (as above; NULL only for a plain
 * pass), seconds its wall-clock time (for a training pass, the rendering only, not the
 * steps), cpu_seconds its tracing's CPU time summed over the threads that rendered it, not
 * their help with training steps nor table builds: time each thread's tracing alone where
 * they help (the choice weighs kinds by it; the first pass of the job, and passes before
 * training ended, pay for cold caches and do not decide it). A path with a value not finite
 * or a moment negative is left out and counted, not refused. Errors:
 * NF_ERROR_INVALID_ARGUMENT (NULL, a plan not the latest or added twice, times negative or
 * not finite): the schedule is then unchanged and the plan still waits; a reduce hook's
 * status: the pass's times did not reach the other processes (the pass is not added), or its
 * measures did not (the pass is added, the measures are the previous ones): make every
 * process fail. */
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
    /* The guided render passes by depth candidate; with a fixed
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
    uint64_t dropped;    /* paths left out: a value not finite, or a moment
                          * negative (this process's)                        */
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
