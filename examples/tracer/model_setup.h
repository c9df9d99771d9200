/*
 * model_setup.h - the tracer's models: made for a scene and a prior or loaded, checked
 * across ranks, and trained through the guide with the tracer's threads and ranks.
 */
#ifndef TRACER_MODEL_SETUP_H
#define TRACER_MODEL_SETUP_H

#include <stddef.h>
#include <stdint.h>

#include <nisflow/nisflow.h>

#include "bsdf_prior.h"
#include "error.h"
#include "scene.h"

typedef enum model_prior {
    MODEL_PRIOR_UNIFORM_DIRECTION,
    MODEL_PRIOR_UNIFORM_ANGLE,
    MODEL_PRIOR_COSINE,
    MODEL_PRIOR_BSDF
} model_prior;

const char *model_prior_name(model_prior p);

/* What a new model is made of. */
typedef struct model_settings {
    model_prior prior;
    int large;              /* NF_PRESET_LARGE instead of NF_PRESET_SMALL                     */
    int phi_interval;       /* NF_PHI_INTERVAL instead of the library's NF_PHI_CIRCULAR       */
    float learning_rate;
    float prior_epsilon;    /* the cosine/bsdf priors' uniform mixture weight; < 0: default   */
    int sh_bands;           /* nf_config.sh_bands, the context's normal and wo encoding;
                             * < 0: the preset's (4)                                       */
    uint64_t seed;
} model_settings;

/* The defaults for `prior` (the command line's too): small model, rate 5e-3, the library's
 * prior_epsilon, 0 SH bands (the position alone: docs/equal-time.md), seed 1. */
model_settings model_default_settings(model_prior prior);

/* Creates a model for the scene: positions are normalized by the scene's bounds (padded a
 * little). With the BSDF prior its callbacks read `lookup` (bsdf_prior.h). */
int model_create_for_scene(const scene *s, const model_settings *settings, prior_lookup *lookup,
                           nf_model **out, tr_error *err);

/* Whether a model's position bounds are the ones model_create_for_scene gives this scene
 * (within 1% of its extent). Returns 1 if so; else 0 with a message for the user in msg. */
int model_bounds_match(const scene *s, const nf_model *m, char *msg, size_t size);

/* Loads a model saved with --save-model; the BSDF prior's callbacks are supplied, reading
 * `lookup`. */
int model_load_file(const char *path, prior_lookup *lookup, nf_model **out, tr_error *err);

/* Collective (ranks.h): whether every rank's model has rank 0's parameters and step count,
 * bit for bit. Returns 1 if so; else 0 with a message naming the ranks that differ, as seen
 * after training iteration `iteration` (0: before training). */
int models_agree_across_ranks(const nf_model *m, int iteration, tr_error *err);

/* What the library's training calls need from the tracer: its threads (parallel.h) as an
 * nf_parallel, and with several ranks the ranks' reductions (ranks.h) as an nf_reduce. */
typedef struct training_hooks {
    nf_parallel parallel;
    const nf_reduce *reduce; /* NULL with one rank */
    nf_reduce reduce_storage;
    int threads;
} training_hooks;

/* Fills the hooks for `threads` threads. */
void training_hooks_init(training_hooks *h, int threads);

/* nf_guide_train_pass and nf_guide_train_batch with the hooks, and, when the guide's model has
 * the BSDF prior, its prior_lookup filled for the call (points[i] the shading point of ctx[i],
 * i < n). Not thread-safe for one lookup; the statuses are the library's. */
nf_status guide_train_pass(nf_guide *g, const training_hooks *h, nf_guide_pass_report *report);
nf_status guide_train_batch(nf_guide *g, const training_hooks *h, size_t n, const nf_context *ctx,
                            const prior_point *points, const float *dir, const float *weight,
                            const size_t *group_end, size_t groups, float *loss);

/* Replaces *model (destroyed) by a copy of the guide's training model, optimizer state
 * included: what --save-model saves and the final render uses. Returns 0 with a message when
 * the copy fails; *model is then unchanged. */
int model_take_trained(nf_guide *g, nf_model **model, tr_error *err);

#endif /* TRACER_MODEL_SETUP_H */
