/*
 * bsdf_prior.h - the BSDF prior (--prior bsdf): the material's own non-delta lobe as the
 * flow's prior, through libnisflow's nf_prior_callbacks, and how its callbacks find the
 * material of a context.
 *
 * While rendering, each guided vertex sets the thread's vertex object with callbacks bound to
 * its own material (bsdf_prior_at_point): they need no lookup.
 *
 * While training, the model's callbacks receive an nf_context and one model-wide user
 * pointer, and the prior needs the material at that context. That pointer is the caller's
 * prior_lookup, which guide_train_pass and guide_train_batch (model_setup.h) fill for the
 * call: a guide's store keeps each sample's material as its payload (nf_guide_payload finds
 * it in the guide bound there), and a batch the caller holds is found by the context's index
 * in it. The training calls may run on several threads (sharded gradients); they only read.
 *
 * At a point in a participating medium (a context whose normal is (0, 0, 0)) the prior is
 * the medium's Henyey-Greenstein phase function with the context's phase_g, around the
 * propagation direction -wo: it needs no material.
 *
 * A context outside the bound store step and batch (which no caller here allows to happen)
 * falls back to a cosine lobe, counted by prior_lookup_failures: the callbacks never fail.
 */
#ifndef TRACER_BSDF_PRIOR_H
#define TRACER_BSDF_PRIOR_H

#include <stdatomic.h>
#include <stddef.h>

#include <nisflow/nisflow.h>

#include "bsdf.h"

/* What the BSDF prior needs to know about a shading point: the material with its textures
 * evaluated. The frame is rebuilt from the context's normal. */
typedef struct prior_point {
    float position[3];
    bsdf_point bp;
} prior_point;

/* Where the prior's model-wide callbacks find a training context's material. The models
 * made with one (model_create_for_scene, model_load_file) point to it from their callbacks'
 * user, so it must outlive them and their copies. The callbacks only read it (and count
 * failures); guide_train_pass and guide_train_batch fill and clear it around their call, so
 * a lookup serves one training call at a time. prior_lookup_init it before use. */
typedef struct prior_lookup {
    const nf_guide *guide;            /* whose store step is computed (nf_guide_payload) */
    const nf_context *batch_ctx;      /* a batch the caller holds: points[i] is ctx[i]'s */
    const prior_point *batch_points;
    size_t batch_count;
    atomic_ullong failures;           /* contexts found in neither (a cosine lobe instead) */
} prior_lookup;

/* An empty lookup: nothing bound, no failures. */
void prior_lookup_init(prior_lookup *l);

/* The lookup that m's callbacks read: m's prior is the BSDF prior; else NULL. */
prior_lookup *prior_lookup_of(const nf_model *m);

/* How many times the callbacks of m's lookup found no shading point and fell back to a
 * cosine lobe (0 for other priors). Always 0 in this program; tests check it. */
unsigned long long prior_lookup_failures(const nf_model *m);

/* The model-wide callbacks (for nf_config.custom_prior and nf_model_load), reading `lookup`
 * (may be NULL: every surface context then gets a cosine lobe, uncounted). */
nf_prior_callbacks bsdf_prior_callbacks(prior_lookup *lookup);

/* The same prior bound to one vertex, for nf_vertex_set: its callbacks read `p`
 * (which must outlive the prepared point's use) and no lookup. */
nf_prior_callbacks bsdf_prior_at_point(const prior_point *p);

#endif /* TRACER_BSDF_PRIOR_H */
