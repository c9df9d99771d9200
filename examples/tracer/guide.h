/*
 * guide.h - the tracer's use of libnisflow: creating the model for a scene and a prior,
 * the BSDF prior (--prior bsdf) and the table that lets its callbacks find the material of
 * a shading context.
 *
 * While rendering, the BSDF prior needs no table: each guided vertex prepares an
 * nf_shading_point with callbacks bound to its own material (guide_point_callbacks).
 *
 * While training, the model's nf_prior_callbacks receive an nf_context and one model-wide
 * user pointer, and the BSDF prior needs the material at that context. That pointer is the
 * caller's guide_lookup, which guide_train_pass and guide_train_batch fill for the call: a
 * guide's store keeps each sample's material as its payload (nf_guide_payload finds it in the
 * guide bound there), and a batch the caller holds is found by the context's index in it. The
 * training calls may run on several threads (sharded gradients); they only read.
 *
 * At a point in a participating medium (a context whose normal is (0, 0, 0)) the BSDF prior
 * is the medium's Henyey-Greenstein phase function with the context's phase_g, around the
 * propagation direction -wo: it needs no material.
 *
 * A context outside the bound store step and batch (which no caller here allows to happen)
 * falls back to a cosine lobe, counted by guide_lookup_failures: the callbacks never fail.
 */
#ifndef TRACER_GUIDE_H
#define TRACER_GUIDE_H

#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>

#include <nisflow/nisflow.h>

#include "bsdf.h"
#include "error.h"
#include "scene.h"

typedef enum guide_prior {
    GUIDE_PRIOR_UNIFORM_DIRECTION,
    GUIDE_PRIOR_UNIFORM_ANGLE,
    GUIDE_PRIOR_COSINE,
    GUIDE_PRIOR_BSDF
} guide_prior;

/* What the BSDF prior needs to know about a shading point: the material with its textures
 * evaluated. The frame is rebuilt from the context's normal. */
typedef struct guide_point {
    float position[3];
    bsdf_point bp;
} guide_point;

/* Where the BSDF prior's model-wide callbacks find a training context's material. The
 * models made with one (guide_create, guide_load) point to it from their callbacks' user, so
 * it must outlive them and their copies. The callbacks only read it (and count failures);
 * guide_train_pass and guide_train_batch fill and clear it around their call, so a lookup
 * serves one training call at a time. guide_lookup_init it before use. */
typedef struct guide_lookup {
    const nf_guide *guide;            /* whose store step is computed (nf_guide_payload) */
    const nf_context *batch_ctx;      /* a batch the caller holds: points[i] is ctx[i]'s */
    const guide_point *batch_points;
    size_t batch_count;
    atomic_ullong failures;           /* contexts found in neither (a cosine lobe instead) */
} guide_lookup;

/* An empty lookup: nothing bound, no failures. */
void guide_lookup_init(guide_lookup *l);

/* The model-wide callbacks of the BSDF prior (for nf_config.custom_prior and nf_model_load),
 * reading `lookup` (may be NULL: every surface context then gets a cosine lobe, uncounted). */
nf_prior_callbacks guide_bsdf_callbacks(guide_lookup *lookup);

/* The same callbacks bound to one shading point, for nf_point_prepare: they read `p` (which
 * must outlive the prepared point's use) and need no table. */
nf_prior_callbacks guide_point_callbacks(const guide_point *p);

/* What a new model is made of. */
typedef struct guide_settings {
    guide_prior prior;
    int large;              /* NF_PRESET_LARGE instead of NF_PRESET_SMALL                     */
    int phi_interval;       /* NF_PHI_INTERVAL instead of the library's NF_PHI_CIRCULAR       */
    float learning_rate;
    float prior_epsilon;    /* the cosine/bsdf priors' uniform mixture weight; < 0: default   */
    int sh_bands;           /* nf_config.sh_bands, the context's normal and wo encoding;
                             * < 0: the preset's (4)                                       */
    uint64_t seed;
} guide_settings;

/* The defaults for `prior` (the command line's too): small model, rate 5e-3, the library's
 * prior_epsilon, 0 SH bands (the position alone: docs/equal-time.md), seed 1. */
guide_settings guide_default_settings(guide_prior prior);

/* Creates a model for the scene: positions are normalized by the scene's bounds (padded a
 * little). With the BSDF prior its callbacks read `lookup` (see guide_lookup). */
int guide_create(const scene *s, const guide_settings *settings, guide_lookup *lookup,
                 nf_model **out, tr_error *err);

/* Whether a model's position bounds are the ones guide_create gives this scene (within 1% of
 * its extent). Returns 1 if so; else 0 with a message for the user in msg. */
int guide_bounds_match(const scene *s, const nf_model *m, char *msg, size_t size);

/* Loads a model saved with --save-model; the BSDF prior's callbacks are supplied, reading
 * `lookup`. */
int guide_load(const char *path, guide_lookup *lookup, nf_model **out, tr_error *err);

const char *guide_prior_name(guide_prior p);

/* What the library's training calls need from the tracer: its threads (parallel.h) as an
 * nf_parallel, and with several ranks the ranks' reductions (ranks.h) as an nf_reduce. */
typedef struct guide_hooks {
    nf_parallel parallel;
    const nf_reduce *reduce; /* NULL with one rank */
    nf_reduce reduce_storage;
    int threads;
} guide_hooks;

/* Fills the hooks for `threads` threads. */
void guide_hooks_init(guide_hooks *h, int threads);

/* nf_guide_train_pass and nf_guide_train_batch with the hooks, and, when the guide's model has
 * the BSDF prior, its guide_lookup filled for the call (points[i] the shading point of ctx[i],
 * i < n). Not thread-safe for one lookup; the statuses are the library's. */
nf_status guide_train_pass(nf_guide *g, const guide_hooks *h, nf_guide_pass_report *report);
nf_status guide_train_batch(nf_guide *g, const guide_hooks *h, size_t n, const nf_context *ctx,
                            const guide_point *points, const float *dir, const float *weight,
                            const size_t *group_end, size_t groups, float *loss);

/* Replaces *model (destroyed) by a copy of the guide's training model, optimizer state
 * included: what --save-model saves and the final render uses. Returns 0 with a message when
 * the copy fails; *model is then unchanged. */
int guide_take_trained(nf_guide *g, nf_model **model, tr_error *err);

/* Collective (ranks.h): whether every rank's model has rank 0's parameters and step count,
 * bit for bit. Returns 1 if so; else 0 with a message naming the ranks that differ, as seen
 * after training iteration `iteration` (0: before training). */
int guide_models_agree(const nf_model *m, int iteration, tr_error *err);

/* How many times the BSDF prior's callbacks of m's lookup found no shading point and fell
 * back to a cosine lobe (0 for other priors). Always 0 in this program; tests check it. */
unsigned long long guide_lookup_failures(const nf_model *m);

#endif /* TRACER_GUIDE_H */
