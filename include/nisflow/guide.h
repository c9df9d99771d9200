/*
 * nisflow/guide.h - the guide: what a renderer needs around the flow to win at equal time.
 *
 * A model (model.h) samples and evaluates directions; a guide trains one while a renderer
 * renders with it. It holds:
 *
 *   - a store of training samples that the render threads fill without a lock, at any time,
 *     also while a training pass runs (bounded: the newest samples are kept, as a replay
 *     buffer);
 *   - the training schedule that docs/equal-time.md measured: after each training pass, one
 *     step on the pass's new samples (its loss, before the step, is a held-out loss), then
 *     steps on samples drawn from the store (weights optionally clamped at a running
 *     quantile); training stops when the held-out loss stops improving (patience) or at a
 *     share of the budget;
 *   - training steps sharded over the renderer's own threads through a parallel-for that the
 *     caller supplies (the library starts no threads), summed exactly in fixed point, so that
 *     the model has the same bits for any number of threads; with a caller-supplied allreduce
 *     (MPI or any other) the same exact sum spans processes (docs/distributed.md);
 *   - three published copies of the model that render threads sample while the next step
 *     trains a private one (training and sampling at the same time is safe, never silently
 *     wrong; a thread that still holds an older generation does not hold publication up);
 *   - the path policy the study measured: the mixture probability and its boost cap, the
 *     Russian roulette rule, which vertices weigh light samples by the flow;
 *   - the choice, after training, between guided and plain passes, and of how deep guided
 *     passes guide, from what each kind costs and buys as the renderer measured it (plain
 *     path tracing and shallower guiding measured on guided paths too, nf_plain_moment and
 *     nf_depth_moment), and a training schedule that stops when it buys little.
 *
 * The recipe (docs/integration.md has it with a renderer around it):
 *
 *     nf_guide_config gc;  nf_guide_config_init(&gc);
 *     nf_guide_create(model, &gc, &guide);                  once; the model is copied
 *     while (rendering) {
 *         const nf_model *m;  nf_guide_acquire(guide, &m);  per pass (any thread)
 *         ... render; at guided vertices sample m; nf_guide_add_samples(guide, ...) ...
 *         nf_guide_release(guide, m);
 *         if (training) {                                    after the pass, threads joined
 *             nf_guide_train_pass(guide, &parallel, NULL, &report);
 *             nf_guide_publish(guide);
 *         }
 *     }
 *
 * or with training beside rendering: a trainer thread loops over nf_guide_train_pass (with
 * nf_guide_helpers' parallel-for) and nf_guide_publish while the render threads go on adding
 * samples, which are never refused, and call nf_guide_help between their tiles.
 *
 * Memory: everything is allocated by nf_guide_create, from the model's allocator: about
 * store_capacity x (3 x (64 + payload_bytes) + 12) bytes for the store and its two intake
 * stages, step_samples x 64 bytes for a step, groups x (4 x nf_param_count + 200) bytes for
 * the gradients, and four copies of the model; nothing later allocates. Stack: the training
 * calls need NF_TRAINING_STACK_BYTES (train.h) on every thread that runs their tasks, the
 * calling thread included when it runs them itself; the other calls hold no buffers on the
 * stack.
 * Every function returns a status with a message (status.h) or is documented as total.
 */
#ifndef NISFLOW_GUIDE_H
#define NISFLOW_GUIDE_H

#include <stddef.h>
#include <stdint.h>

#include "model.h"
#include "status.h"
#include "version.h"

NF_EXTERN_C_BEGIN

/* ---- The path policy --------------------------------------------------------------------- */

/* How a renderer mixes the flow with its BSDF at a guided vertex (docs/integration.md, "The
 * recipe"). The defaults are what docs/equal-time.md found best; one place holds them.
 *
 * Volume vertices. At a scattering event in a participating medium (a context with a zero
 * normal, nisflow/model.h) the phase function plays the BSDF's role everywhere in this
 * header: "p_bsdf" is the phase function's density of the direction (per steradian), "BSDF
 * sampling" is phase-function sampling, and f_s |cos| becomes the phase function's value (no
 * cosine in a medium). The same guide, store and model take surface and volume vertices.
 * min_roughness is a surface notion (docs/integration.md, "Volume vertices"). */
typedef struct nf_guide_policy {
    float mixture_prob;       /* probability of sampling the flow at a guided vertex, [0, 1);
                               * default 0.7                                                  */
    float max_boost;          /* cap on the path's boost (nf_guide_mixture_prob), >= 1 or 0 for
                               * none; default 10                                             */
    float max_survival;       /* Russian roulette survives at most with this, (0, 1]; 0.95    */
    uint32_t light_mis_depth; /* vertices up to this many segments deep weigh a light
                               * sample against the mixture's density (which asks the flow);
                               * deeper ones against the BSDF's; 0: every depth asks; default 2 */
    float min_roughness;      /* a renderer's hint: lobes sharper than this roughness (alpha)
                               * are better sampled by the BSDF alone; default 0.3            */
} nf_guide_policy;

/* The defaults above. NULL is ignored. Thread-safe. */
NF_API void nf_guide_policy_init(nf_guide_policy *p);

/* The probability of sampling the flow at the next guided vertex of a path whose boost is
 * `boost`. The boost is the product, over the path's guided vertices so far, of p_bsdf / p_mix
 * (nf_guide_boost): how much the mixture has raised the throughput over BSDF sampling's. A
 * BSDF sample where the flow has no mass weighs 1 / (1 - g) more than under BSDF sampling, and
 * along a path these factors multiply; the cap keeps their product within max_boost by
 * lowering g to 1 - boost / max_boost, and to 0 below 0.05 (a vertex guided that little pays
 * the flow for nothing). It depends only on the path so far: the estimator stays unbiased.
 * A NULL policy gives 0. Thread-safe, total. */
NF_API float nf_guide_mixture_prob(const nf_guide_policy *p, float boost);

/* The boost after a guided vertex: boost x p_bsdf / p_mix for a sampled direction whose BSDF
 * and mixture densities (per steradian) are given; a delta lobe (p_bsdf = p_mix = 0) that the
 * mixture chose with probability 1 - g passes g_used and multiplies 1 / (1 - g_used).
 * Non-finite or non-positive densities leave the boost unchanged. Thread-safe, total. */
NF_API float nf_guide_boost(float boost, float p_bsdf, float p_mix, float g_used);

/* The probability that Russian roulette lets a path go on: the larger of its throughput's
 * largest channel and that channel divided by the path's boost, at most max_survival. The
 * quotient is the throughput BSDF sampling would have given the same path, so a path the flow
 * sent where it expects light survives as often as plain path tracing would let it; the
 * larger of the two keeps the throughput after roulette at or below about 1 when the flow sent
 * it where it expects little. boost = 1 gives plain path tracing's rule. NaN gives 0. A NULL
 * policy, or one whose max_survival is outside (0, 1] (a zeroed one), caps at 0.95.
 * Thread-safe, total. */
NF_API float nf_guide_roulette_survival(const nf_guide_policy *p, float throughput_max,
                                        float boost);

/* Whether a light sample at a vertex `depth` segments into the path is weighed against the
 * mixture's density (1: ask the flow its density) or the BSDF's (0). Both the light sample and
 * the scattered direction that hits the light must use the same answer, so that the MIS
 * weights still sum to one. Thread-safe, total. */
NF_API int nf_guide_light_mis_uses_flow(const nf_guide_policy *p, uint32_t depth);

/* ---- Hooks the renderer supplies --------------------------------------------------------- */

/* A task of a parallel-for: task(task_data, index) for one index. */
typedef void (*nf_task_fn)(void *task_data, size_t index);

/* The renderer's parallel-for: run(user, count, task, task_data) calls task(task_data, i) for
 * every i in [0, count), on any of the renderer's threads and in any order, and returns when
 * all have returned. Each thread that runs a task needs NF_TRAINING_STACK_BYTES (train.h) of
 * stack. A NULL nf_parallel (or run) runs the tasks on the calling thread. The results are the
 * same bits whichever threads ran which tasks. */
typedef struct nf_parallel {
    void (*run)(void *user, size_t count, nf_task_fn task, void *task_data);
    void *user;
} nf_parallel;

/* The renderer's allreduce over processes (MPI_Allreduce, for example), for one model trained
 * by several processes: each function replaces values[0..n) by the element-wise maximum, or
 * the exact integer sum, over all processes, and returns NF_OK (any other status aborts the
 * step on this process, which then leaves the model unchanged; the renderer must make the
 * other processes fail too). Every process calls the training functions with the same
 * configuration and the same number of times: they are collective. A NULL nf_reduce is one
 * process. */
typedef struct nf_reduce {
    nf_status (*max_f64)(void *user, double *values, size_t n);
    nf_status (*sum_i64)(void *user, int64_t *values, size_t n);
    void *user;
} nf_reduce;

/* ---- The guide ---------------------------------------------------------------------------- */

typedef struct nf_guide nf_guide;

/* What a guide is made of. Zero is never a valid configuration: call nf_guide_config_init. */
typedef struct nf_guide_config {
    uint32_t magic_;         /* set by nf_guide_config_init                                */
    size_t store_capacity;   /* training samples kept, newest first, and the most one pass
                              * can add; [1, 2^26]; default 131072                        */
    size_t payload_bytes;    /* caller bytes kept with each sample (a material for a BSDF
                              * prior, say), [0, 4096]; default 0                          */
    uint32_t step_samples;   /* samples per step on this process, [1, 2^20]; default 2048  */
    uint32_t steps_per_pass; /* steps after each training pass, [1, 4096]; default 64      */
    uint32_t groups;         /* gradient groups per step (the most threads that help),
                              * [1, 256]; default 16. The groups are fixed by the step's
                              * samples alone, so the bits do not depend on the threads   */
    uint32_t patience;       /* training passes without a 1 % better held-out loss before
                              * nf_guide_keep_training says stop; 0 never; default 6      */
    float clamp_quantile;    /* training weights clamped at a running quantile of each
                              * pass's weights, (0, 1), or 0 for none; default 0: a
                              * clamp hides the rare bright paths the flow must learn
                              * (docs/equal-time.md)                                     */
    float train_fraction;    /* share of a time budget to train, [0, 1]; default 0.15     */
    float learning_rate;     /* AdamW rate set on the model; default 5e-3                  */
    uint64_t seed;           /* the draws from the store; default 1                        */
    uint32_t pass_choice;    /* 1: nf_guide_choose_pass picks guided or plain render passes
                              * and nf_guide_choose_depth how deep they guide, from what
                              * each costs and buys (default); 0: every render pass guided
                              * at every depth (a fixed policy)                            */
    float explore_share;     /* the least share of render passes that stay guided when
                              * plain ones measure better, so that guiding's estimate goes
                              * on improving, [0, 0.5]; default 0.05. Plain passes keep a
                              * fifth of it when guided ones measure better               */
    nf_guide_policy policy;  /* nf_guide_policy_init's                                     */
} nf_guide_config;

/* Fills `gc` with the defaults above. NULL is ignored. Thread-safe. */
NF_API void nf_guide_config_init(nf_guide_config *gc);

/* Creates a guide around copies of `model` (the caller keeps and frees `model`; it may be
 * destroyed at once); the guide's memory comes from the model's allocator. gc NULL: the
 * defaults. The copies' learning rate becomes gc->learning_rate. A model with a custom prior keeps
 * its callbacks: during training they receive contexts of the guide's step (nf_guide_payload finds
 * each one's payload). Errors: NF_ERROR_INVALID_ARGUMENT (NULL model or out, a field out of range,
 * a config not from nf_guide_config_init: the message names the field), NF_ERROR_OUT_OF_MEMORY;
 * *out is then NULL. Thread-safe; allocates everything the guide will use. */
NF_API nf_status nf_guide_create(const nf_model *model, const nf_guide_config *gc, nf_guide **out);

/* Frees the guide. NULL is a no-op. No other call may use the guide meanwhile or after, and
 * no model it handed out may be used after. */
NF_API void nf_guide_destroy(nf_guide *g);

/* The configuration the guide was created with, or NULL for NULL. Thread-safe. */
NF_API const nf_guide_config *nf_guide_get_config(const nf_guide *g);

/* ---- Rendering with the guide ------------------------------------------------------------- */

/* Hands out the newest published model for sampling, and holds it until nf_guide_release:
 * *out stays valid and unchanged while held (no step or publish writes it), so that a pass
 * samples one consistent model. Call it once per pass and thread, not per vertex (two atomic
 * operations). Errors: NF_ERROR_INVALID_ARGUMENT for NULL arguments. Thread-safe with every
 * call but nf_guide_destroy. */
NF_API nf_status nf_guide_acquire(nf_guide *g, const nf_model **out);

/* Ends a hold of nf_guide_acquire. A model this guide did not hand out, or one released more
 * often than acquired, is refused with NF_ERROR_INVALID_ARGUMENT. Thread-safe as acquire. */
NF_API nf_status nf_guide_release(nf_guide *g, const nf_model *m);

/* Adds n training samples (train.h: context, unit-length-or-not direction, weight f >= 0 as
 * in nf_train_step). key[i] orders the samples: the store sorts a pass's samples by key (and
 * equal keys by their bytes) before training, so that training is the same bits however the
 * threads interleaved their calls; give distinct keys (a pixel and vertex index, say).
 * key NULL: keys 0 (the bytes decide). payload: n x payload_bytes bytes, or NULL (zeros).
 * Samples with weight 0 are skipped (they carry nothing for the loss). Validated as
 * nf_train_step; a refused call adds nothing. n = 0 is a no-op whatever the pointers.
 *
 * When samples are trained on: the samples added before a training pass starts are that
 * pass's new samples; those added while it runs wait for the next pass (the intake has two
 * stages: a pass drains one while adds fill the other). Each stage holds store_capacity
 * samples: the rest are dropped at once and counted (nf_guide_stats.dropped), never refused.
 * Thread-safe with every call but nf_guide_destroy, the training calls included; lock-free.
 * Never NF_ERROR_BUSY. */
NF_API nf_status nf_guide_add_samples(nf_guide *g, size_t n, const uint64_t *key,
                                      const nf_context *ctx, const float *dir, const float *weight,
                                      const void *payload);

/* ---- Training ----------------------------------------------------------------------------- */

/* What one nf_guide_train_pass did. */
typedef struct nf_guide_pass_report {
    uint64_t new_samples; /* this process's samples of the pass                          */
    uint32_t steps;       /* steps taken                                                  */
    uint32_t refused;     /* steps the model refused (NF_ERROR_NUMERIC); it is unchanged  */
    float held_out_loss;  /* the loss of the pass's new samples before the first step;
                           * NaN when no process had new samples                         */
    float clamp;          /* the running clamp of the weights after this pass (0: none)  */
    int keep_training;    /* nf_guide_keep_training after this pass                      */
} nf_guide_pass_report;

/* Trains after a training pass: the pass's samples join the store (sorted by key; the oldest
 * leave), the running clamp takes in the pass's weights, then steps_per_pass steps of
 * step_samples samples: the first on the pass's new samples (a held-out loss), the rest drawn
 * uniformly from the store, each sharded into `groups` gradient groups run through `par` and
 * summed exactly (through `red` across processes). The held-out loss, averaged over about
 * three passes, feeds the patience. The training model changes; the published ones do not
 * (nf_guide_publish). rep may be NULL.
 * Collective over `red`'s processes. Errors: NF_ERROR_BUSY when another training call or
 * nf_guide_publish runs meanwhile (on two threads they must take turns; the overlap is
 * detected, not silently wrong), NF_ERROR_INVALID_ARGUMENT, a reduce hook's status; the model
 * is then as before the failing step. Safe while other threads add samples (they go to the
 * next pass), acquire and sample acquired models. Uses NF_TRAINING_STACK_BYTES of each task's
 * stack. */
NF_API nf_status nf_guide_train_pass(nf_guide *g, const nf_parallel *par, const nf_reduce *red,
                                     nf_guide_pass_report *rep);

/* One sharded step on samples the caller holds (no store, no clamp): n samples of ctx / dir /
 * weight as nf_train_step, cut into groups: group k is [group_end[k-1], group_end[k])
 * (group_end[-1] = 0) for k < ngroups <= the configured groups, or, with group_end NULL, the
 * configured number of equal groups. A caller who fixes the groups by its batch (paths per
 * group, say) gets the same bits on any number of processes. *loss (may be NULL) receives the
 * batch's loss, NaN when no step was taken. A batch whose weights are all zero on every
 * process takes no step and returns NF_OK. Errors and collectivity as nf_guide_train_pass. */
NF_API nf_status nf_guide_train_batch(nf_guide *g, size_t n, const nf_context *ctx,
                                      const float *dir, const float *weight,
                                      const size_t *group_end, size_t ngroups,
                                      const nf_parallel *par, const nf_reduce *red, float *loss);

/* A parallel-for for renderers without a task system: the guide's own, run by helpers.
 * A training call given it (nf_guide_train_pass(g, &par, ...)) runs its step's tasks on the
 * calling thread and lets any thread that calls nf_guide_help meanwhile take some; the calling
 * thread runs whatever nobody took, so training never waits for a helper and the library
 * starts no thread. The bits are the same however many threads helped. NULL g gives a NULL
 * run (the calling thread alone). Thread-safe, total. */
NF_API nf_parallel nf_guide_helpers(nf_guide *g);

/* Helps the training call in progress, if it runs with nf_guide_helpers and has tasks left:
 * runs some of them on this thread and returns how many (0 at once when there is nothing to
 * do: two atomic loads). Call it from render threads between tiles, or from idle threads in
 * a loop; each task needs NF_TRAINING_STACK_BYTES (train.h) of this thread's stack and lasts
 * one gradient group (a fraction of a millisecond for the small preset's 2048-sample step in
 * 16 groups). NULL is a no-op. Thread-safe with every call but nf_guide_destroy; lock-free. */
NF_API size_t nf_guide_help(nf_guide *g);

/* Whether training still pays: 0 once `elapsed` reaches train_fraction of `budget` (both in
 * the caller's unit, seconds say; budget <= 0: no budget), the held-out loss has not
 * improved by 1 % for `patience` passes, or the reported training ratios say it buys too
 * little (nf_guide_report_training_ratio). Every process gets the same answer for the same
 * arguments. Thread-safe on a guide no training call changes meanwhile. */
NF_API int nf_guide_keep_training(const nf_guide *g, double elapsed, double budget);

/* ---- Guided or plain passes --------------------------------------------------------------- */

/* After training, a pass guided by the flow costs more than a plain one (BSDF sampling and
 * next-event estimation alone: the renderer's path tracer with no flow), and it does not
 * always buy that much less variance: where next-event estimation already finds the light (a
 * box lit directly), plain passes give more per second. A renderer that renders in passes
 * (each pixel once, say) measures both kinds on the passes it renders anyway, asks
 * nf_guide_choose_pass which kind to render next, and combines the passes of both kinds by
 * inverse variance (docs/integration.md, "Guided or plain passes"). The choice stays unbiased:
 * every pass is an unbiased estimate, whichever kind it is. */

typedef enum nf_pass_kind { NF_PASS_GUIDED = 0, NF_PASS_PLAIN = 1 } nf_pass_kind;

/* What the renderer measured on the render passes of one kind so far (after training). */
typedef struct nf_pass_measure {
    uint32_t passes; /* passes of this kind                                              */
    double seconds;  /* their cost, >= 0, in one unit for both kinds (CPU seconds, say)   */
    double variance; /* the variance of one pass of this kind, >= 0: relative to the
                      * image, as nf_guide_pass_variance estimates it                     */
} nf_pass_measure;

/* nf_guide_choose_pass's answer. */
typedef struct nf_pass_choice {
    nf_pass_kind kind; /* render this kind next                                          */
    int exploring;     /* 1: a pass of the kind that measured worse, kept by its share     */
    double ratio;      /* a guided pass's variance x cost over a plain pass's (below 1:
                        * guiding pays); NaN until each kind has 2 passes                 */
} nf_pass_choice;

/* The variance of one pass of a kind, relative, from per-pixel sums. For each of n pixels (or
 * any unit of the image): S = sum[i] and Q = sum_sq[i], the sums of its value (a luminance,
 * say) and of its square over the kind's k = `passes` passes, and r = reference[i], the best
 * estimate of the pixel's value (every pass of both kinds and of training, averaged). *out is
 * the mean over i of
 *     (Q - 2 r S + k r^2) / k / (r^2 + epsilon),
 * the passes' mean squared distance to the reference, relative as relMSE is. The distance is
 * to the reference, not to the kind's own mean: a kind whose rare paths carry the light shows
 * zeros where the other kind has seen light, and its own mean would call those pixels
 * noiseless. *out is 0 for n = 0. Errors: NF_ERROR_INVALID_ARGUMENT (NULL arrays with n > 0,
 * NULL out, passes 0, epsilon not finite and > 0, a value not finite, sum_sq[i] < 0: the
 * message names the first), NF_ERROR_NUMERIC (finite values whose squares overflow); *out is
 * then unchanged. Thread-safe, allocates nothing. */
NF_API nf_status nf_guide_pass_variance(size_t n, const double *sum, const double *sum_sq,
                                        uint32_t passes, const double *reference, double epsilon,
                                        double *out);

/* The reference without lone peaks, against which the guided kinds of nf_guide_choose_depth
 * are measured. A rare bright path lands in one pixel and sits in that pixel's mean over the
 * passes too, so against that mean its pixel's relative variance stays near the pass count
 * however bright the path was: the depths would be ranked as if the path were not there
 * (docs/theory.md, "Rare bright paths in the depth choice"). Here each pixel brighter than
 * every one of its neighbours (8; fewer at the border) takes the brightest neighbour's value:
 *     out[i] = min(reference[i], the largest of pixel i's neighbours),
 * for a width x height image of one value per pixel (a luminance, say), row by row; an image
 * of one pixel is copied. Compare guided against plain passes with the reference itself:
 * plain passes draw the same rare paths. Errors: NF_ERROR_INVALID_ARGUMENT (NULL arrays with
 * width x height > 0, width x height overflowing size_t, reference and out overlapping, a value
 * not finite: the message names the first); out is then unchanged. Thread-safe, allocates
 * nothing, O(width x height). */
NF_API nf_status nf_guide_lower_peaks(size_t width, size_t height, const double *reference,
                                      double *out);

/* Plain path tracing's second moment, measured on guided paths. A plain pass's variance
 * is ruled by rare bright paths that its first passes miss (a light reached through a gap),
 * so its own passes underestimate it; the guided paths find those paths often, and each one
 * says how much it would weigh in plain path tracing. With R the ratio of plain path tracing's
 * density of the path so far to the guided one's (BSDF over mixture densities, and plain
 * roulette's survival over the guided one's), a contribution c_k (a luminance) that a guided
 * path adds at its k-th contribution is worth c_k / R_k to plain path tracing, and
 *     sum over k of c_k^2 / R_k + 2 sum over j < k of c_j c_k / R_j
 * has plain path tracing's second moment as its expectation over guided paths (importance
 * weighting; docs/theory.md, "Guided or plain passes"). Start a path with
 * nf_plain_moment_start, follow its scatters and roulette, add its contributions; a plain
 * path (R = 1) gives the square of its luminance. Add each contribution with the MIS weight
 * plain path tracing would give it (light sampling against the BSDF's density), not the
 * guided path's. Thread-safe, total (the functions only write *m; moment stays >= 0, +inf at
 * worst); NULL m is a no-op. */
typedef struct nf_plain_moment {
    float ratio;  /* R: plain path tracing's density of the path so far over the guided one's */
    float sum;    /* the contributions so far, each divided by its R                          */
    float moment; /* the estimate of plain path tracing's second moment                        */
} nf_plain_moment;

/* A path at the camera: R = 1, nothing added. */
NF_API void nf_plain_moment_start(nf_plain_moment *m);

/* A scattered direction with BSDF and mixture densities p_bsdf and p_mix (per steradian),
 * or a delta lobe chosen with probability 1 - g_used (p_bsdf = p_mix = 0): R takes the step
 * as nf_guide_boost's boost does. */
NF_API void nf_plain_moment_scatter(nf_plain_moment *m, float p_bsdf, float p_mix, float g_used);

/* Russian roulette survived with probability q_used at a path whose throughput's largest
 * channel (before the roulette) is throughput_max: R takes plain roulette's survival, which is
 * nf_guide_roulette_survival(p, throughput_max / R, 1), over q_used. */
NF_API void nf_plain_moment_roulette(nf_plain_moment *m, const nf_guide_policy *p,
                                     float throughput_max, float q_used);

/* A contribution c >= 0 (a luminance, as added to the pixel) of the path; negative or
 * non-finite c is ignored. */
NF_API void nf_plain_moment_add(nf_plain_moment *m, float c);

/* Tells the schedule what a training pass measured: `ratio` is its variance x cost over a
 * plain pass's (as nf_pass_choice.ratio, with the training pass's own variance about the
 * reference and its tracing time, steps not counted; plain passes measured as for
 * nf_guide_choose_pass, two rendered before training). Once the ratio has not fallen by 5 %
 * for 3 training passes while it stays above 0.8, nf_guide_keep_training says stop: a model
 * that buys little over plain path tracing and has stopped improving does not repay its
 * steps. Not calling it leaves the schedule as it was; pass_choice 0 ignores it.
 * Errors: NF_ERROR_INVALID_ARGUMENT (NULL g, ratio NaN or negative; +inf is allowed).
 * Not thread-safe with the training calls. */
NF_API nf_status nf_guide_report_training_ratio(nf_guide *g, double ratio);

/* Which kind of render pass to render next, from measured[NF_PASS_GUIDED] and
 * measured[NF_PASS_PLAIN]: first two passes of each kind, guided first, alternating; then the
 * kind with the lower variance x cost per pass (ties: guided), except that the other kind
 * keeps a share of all render passes, so that its measure stays current: guided passes
 * explore_share when plain ones measure better (a model that measured worse early can still
 * show better), plain passes a fifth of it when guided ones do (every pass measures plain path
 * tracing's variance, nf_plain_moment, which measured[NF_PASS_PLAIN] must hold; only its cost
 * needs plain passes). With pass_choice 0, always guided.
 * The answer depends only on the arguments and the configuration: processes that pass the same
 * measures choose alike. Errors: NF_ERROR_INVALID_ARGUMENT (NULL, a measure negative or not
 * finite). Thread-safe. */
NF_API nf_status nf_guide_choose_pass(const nf_guide *g, const nf_pass_measure measured[2],
                                      nf_pass_choice *out);

/* ---- How deep guided passes guide --------------------------------------------------------- */

/* Guiding a vertex costs the flow's questions, and deep vertices, which carry little of a
 * pixel, may not repay them: in a box lit directly, guiding each path's first vertex alone buys
 * more per second than guiding every vertex or none, while light that arrives through several
 * bounces (a room lit through a door's gap) needs guiding at every depth. Guided render passes
 * therefore come in NF_GUIDE_DEPTHS kinds, by the deepest vertex they guide
 * (nf_guide_depth_of): every depth measured on its own passes, a shallower kind on every pass
 * that guides deeper than it (nf_depth_moment, as plain path tracing is measured);
 * nf_guide_choose_depth picks the kind to render, and nf_guide_choose_pass then weighs it
 * against plain passes (docs/integration.md, "Guided or plain passes"). Training passes guide
 * every depth. A vertex deeper than a pass's depth is not guided: the mixture probability 0,
 * no question to the flow, light samples weighed against the BSDF's density. */
#define NF_GUIDE_DEPTHS 3u

/* The deepest vertex that guided passes of kind `candidate` guide, in segments from the
 * camera (the first vertex is 1), or 0 for every depth: candidates 0, 1, 2 are every depth,
 * 1 and 2. 0 for candidate >= NF_GUIDE_DEPTHS. Thread-safe, total. */
NF_API uint32_t nf_guide_depth_of(uint32_t candidate);

/* A kind that guides up to depth D, measured on paths guided deeper (as nf_plain_moment
 * measures plain path tracing): its passes alone would miss the rare bright paths that rule
 * its variance (light that only guiding finds, deeper than D), and the choice would pick it by
 * chance. A path guided up to depth A >= D (every depth, training passes included) traces the
 * same vertices as the depth-D policy up to D; beyond, R takes the step from the path's
 * mixture to BSDF sampling, and roulette the depth-D policy's survival (its boost frozen at
 * depth D). A path keeps one nf_depth_moment per policy it measures, in an array that each
 * call below updates at once: start each with its policy's depth D, then call scatter and
 * roulette at every vertex with the vertex's depth (the first vertex is 1) where the path
 * calls nf_guide_boost and nf_guide_roulette_survival, and add every contribution. A path
 * guided up to exactly D gives its squared luminance. D = 0 is nf_plain_moment's plain path
 * tracing, to the bit. Thread-safe, total (the functions only write m[0..n); moments stay
 * >= 0, +inf at worst); NULL m or n = 0 is a no-op. */
typedef struct nf_depth_moment {
    float ratio;    /* R: the depth-D policy's density of the path so far over the path's */
    float sum;      /* the contributions so far, each divided by its R                    */
    float moment;   /* the estimate of the depth-D policy's second moment                 */
    float boost;    /* the depth-D policy's boost: the path's, frozen after depth D       */
    uint32_t depth; /* D                                                                  */
} nf_depth_moment;

/* A path at the camera, measuring the policy that guides up to depth `depth`. */
NF_API void nf_depth_moment_start(nf_depth_moment *m, uint32_t depth);

/* A scattered direction at a vertex `vertex_depth` deep, with the arguments of
 * nf_plain_moment_scatter: for each of the n moments, up to its D the boost takes the step,
 * deeper R does. */
NF_API void nf_depth_moment_scatter(nf_depth_moment *m, size_t n, uint32_t vertex_depth,
                                    float p_bsdf, float p_mix, float g_used);

/* Russian roulette survived with probability q_used at a vertex `vertex_depth` deep, whose
 * throughput's largest channel before the roulette is throughput_max: for each moment deeper
 * than its D, R takes nf_guide_roulette_survival(p, throughput_max / R, boost) over q_used. */
NF_API void nf_depth_moment_roulette(nf_depth_moment *m, size_t n, const nf_guide_policy *p,
                                     uint32_t vertex_depth, float throughput_max, float q_used);

/* A contribution (a luminance, as added to the pixel) that the technique of the vertex
 * `vertex_depth` deep found (0: seen from the camera): c >= 0 with the MIS weight the path gave
 * it, c_plain >= 0 with plain path tracing's (light sampling against the BSDF's density). Each
 * moment takes c where its policy guides that vertex (vertex_depth <= D), c_plain deeper, as
 * nf_plain_moment_add takes its contribution; negative or non-finite values are ignored. */
NF_API void nf_depth_moment_add(nf_depth_moment *m, size_t n, uint32_t vertex_depth, float c,
                                float c_plain);

/* nf_guide_choose_depth's answer. */
typedef struct nf_depth_choice {
    uint32_t candidate; /* render guided passes of this kind next, < NF_GUIDE_DEPTHS         */
    uint32_t depth;     /* nf_guide_depth_of(candidate)                                    */
    double ratio;       /* its variance x cost per pass over every depth's (below 1: the
                         * shallower passes pay); NaN while a kind has fewer than 2 passes  */
} nf_depth_choice;

/* Which kind of guided pass to render next, from the measures of the guided render passes of
 * each kind (measured[c] for candidate c, as nf_pass_measure of NF_PASS_GUIDED, each variance
 * against the reference without lone peaks, nf_guide_lower_peaks): first two passes of each
 * kind, in candidate order; then the kind with the lowest variance x cost per pass (ties: the
 * lower candidate, so every depth first). The chosen kind, its variance measured against the
 * reference itself, is the NF_PASS_GUIDED measure to give nf_guide_choose_pass. With
 * pass_choice 0, always candidate 0 (every depth). Depends only on the arguments and the
 * configuration, as nf_guide_choose_pass.
 * Errors: NF_ERROR_INVALID_ARGUMENT (NULL, a measure negative or not finite); *out is then
 * unchanged. Thread-safe. */
NF_API nf_status nf_guide_choose_depth(const nf_guide *g,
                                       const nf_pass_measure measured[NF_GUIDE_DEPTHS],
                                       nf_depth_choice *out);

/* Copies the training model (parameters and optimizer state, nf_model_copy) into the
 * published model that is not the newest and that no thread holds, and makes it the newest:
 * acquire hands it out from now on. There are three, so publication needs one of the two
 * copies older than the newest free: threads that hold the newest and one older generation
 * never hold it up. A holder sees its model unchanged until it releases it. NF_ERROR_BUSY,
 * the newest staying as it was, when threads still hold both older copies (release one
 * first), or when a training call runs meanwhile. Safe while other threads add samples, acquire and
 * sample acquired models. */
NF_API nf_status nf_guide_publish(nf_guide *g);

/* The model that training changes, for saving (nf_model_save), inspection or nf_set_params.
 * Never sample it while a training call may run. NULL for NULL. */
NF_API nf_model *nf_guide_training_model(nf_guide *g);

/* The payload of a sample of the step that is being computed, for a custom prior's callbacks:
 * ctx must be a context pointer the callbacks received during a training call of this guide.
 * NULL for any other pointer. Thread-safe during the training call's tasks. */
NF_API const void *nf_guide_payload(const nf_guide *g, const nf_context *ctx);

/* Counters since creation. */
typedef struct nf_guide_stats {
    uint64_t samples; /* added and kept                                              */
    uint64_t dropped; /* added beyond store_capacity in one pass                     */
    uint64_t stored;  /* in the store now                                            */
    uint64_t steps, refused;
    uint32_t passes;       /* nf_guide_train_pass calls                                   */
    uint32_t stale_passes; /* passes since the held-out loss last improved by 1 %         */
    float last_loss;       /* the latest held-out loss (NaN: none yet)                    */
    float clamp;           /* the running clamp (0: none yet)                             */
} nf_guide_stats;

/* Fills *out. NF_ERROR_INVALID_ARGUMENT for NULL. Thread-safe on a guide no training call
 * changes meanwhile. */
NF_API nf_status nf_guide_get_stats(const nf_guide *g, nf_guide_stats *out);

/* The samples added since the last training pass began, which the next pass will train on
 * (at most store_capacity; the rest are dropped), adds still running included: a trainer on
 * its own thread can wait for enough of them before it trains. 0 for NULL. Thread-safe with
 * every call but nf_guide_destroy; lock-free. */
NF_API size_t nf_guide_pending(const nf_guide *g);

NF_EXTERN_C_END

#endif /* NISFLOW_GUIDE_H */
