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
 *     wrong; a thread that still holds an older generation does not hold publication up).
 *
 * The path policy at each vertex (the mixture, the roulette, the moments a path measures) is
 * nisflow/policy.h, included here; the choice of passes and the time-budgeted schedule around
 * the guide are nisflow/schedule.h.
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
 * stages, step_samples x 64 bytes for a step, groups x (4 x nf_model_param_count + 200) bytes for
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
#include "policy.h"
#include "status.h"
#include "version.h"

NF_EXTERN_C_BEGIN

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
                              * can add; [1, 2^26]; default 131072. Size it to a training
                              * pass's samples: at most one per guided vertex, so paths a
                              * pass (nf_schedule_config.pass_paths) x the guided vertices
                              * a path records; nf_guide_stats.dropped says if it did not  */
    size_t payload_bytes;    /* caller bytes kept with each sample (a material for a BSDF
                              * prior, say), [0, 4096]; default 0                          */
    uint32_t step_samples;   /* samples per step on this process, [1, 2^20]; default 2048  */
    uint32_t steps_per_pass; /* steps after each training pass, [1, 4096]; default 64. Best
                              * when steps x step_samples is 2-4x the samples a pass adds
                              * (docs/equal-time.md, "How large a training pass")         */
    uint32_t groups;         /* gradient groups per step (the most threads that help),
                              * [1, 256]; default 16. The groups are fixed by the step's
                              * samples alone, so the bits do not depend on the threads   */
    uint32_t patience;       /* training passes without a 1 % better held-out loss before
                              * the schedule stops training; 0 never; default 6         */
    float clamp_quantile;    /* training weights clamped at a running quantile of each
                              * pass's weights, (0, 1), or 0 for none; default 0: a
                              * clamp hides the rare bright paths the flow must learn
                              * (docs/equal-time.md)                                     */
    float train_fraction;    /* share of a time budget to train, [0, 1]; default 0.15     */
    float learning_rate;     /* AdamW rate set on the model; default 5e-3                  */
    uint64_t seed;           /* the draws from the store; default 1                        */
    uint32_t pass_choice;    /* 1: the schedule picks guided or plain render passes and how
                              * deep they guide, from what each costs and buys (default);
                              * 0: every render pass guided at every depth (a fixed
                              * policy)                                                    */
    float explore_share;     /* the least share of render passes that stay guided when
                              * plain ones measure better, so that guiding's estimate goes
                              * on improving, [0, 0.5]; default 0.05. Plain passes keep a
                              * fifth of it when guided ones measure better               */
    nf_guide_policy policy;  /* nf_guide_policy_init's                                     */
} nf_guide_config;

/* Fills `gc` with the defaults above. NULL is ignored. Thread-safe. */
NF_API void nf_guide_config_init(nf_guide_config *gc);

/* Fills cfg with the model configuration the guide's defaults were measured with
 * (docs/equal-time.md): nf_config_init's NF_PRESET_SMALL (the cosine prior), positions
 * encoded inside [bounds_min, bounds_max] (world units: the scene's bounds), and the context
 * encoded by its position alone (sh_bands 0). NULL bounds (either) keep the preset's; the
 * bounds are checked by nf_model_create. NULL cfg is ignored. Thread-safe, total. */
NF_API void nf_guide_model_config_init(nf_config *cfg, const float bounds_min[3],
                                       const float bounds_max[3]);

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
 * threads interleaved their calls, as long as nothing is dropped (below: which samples drop
 * depends on that order); give distinct keys (a pixel and vertex index, say).
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
    int keep_training;    /* whether training still pays after this pass: 0 once the
                           * budget's train_fraction is spent, the held-out loss has lost
                           * its patience or training buys too little over plain passes */
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

/* Copies the training model (parameters and optimizer state) into the
 * published model that is not the newest and that no thread holds, and makes it the newest:
 * acquire hands it out from now on. There are three, so publication needs one of the two
 * copies older than the newest free: threads that hold the newest and one older generation
 * never hold it up. A holder sees its model unchanged until it releases it. NF_ERROR_BUSY,
 * the newest staying as it was, when threads still hold both older copies (release one
 * first), or when a training call runs meanwhile. Safe while other threads add samples, acquire and
 * sample acquired models. */
NF_API nf_status nf_guide_publish(nf_guide *g);

/* The model that training changes, for saving (nf_model_save), inspection or nf_model_set_params.
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

NF_EXTERN_C_END

#endif /* NISFLOW_GUIDE_H */
