/*
 * bsdf_prior.c - the BSDF prior's callbacks and the lookup of a training context's material
 * (see bsdf_prior.h for the design).
 */
#include "bsdf_prior.h"

#include <stdint.h>

#include "medium.h"
#include "vecmath.h"

void prior_lookup_init(prior_lookup *l)
{
    l->guide = NULL;
    l->batch_ctx = NULL;
    l->batch_points = NULL;
    l->batch_count = 0;
    atomic_init(&l->failures, 0);
}

/* The lookup of a model with the BSDF prior (its callbacks' user), else NULL. */
prior_lookup *prior_lookup_of(const nf_model *m)
{
    nf_config cfg;
    if (!m || nf_model_get_config(m, &cfg) != NF_OK || cfg.prior != NF_PRIOR_CUSTOM ||
        cfg.custom_prior.sample != bsdf_prior_callbacks(NULL).sample)
        return NULL;
    return cfg.custom_prior.user;
}

static const prior_point *find_point(prior_lookup *l, const nf_context *ctx)
{
    const prior_point *stored = l ? nf_guide_payload(l->guide, ctx) : NULL;
    if (stored)
        return stored;
    /* Compare addresses as integers: relational operators between pointers into different
     * objects are undefined. */
    uintptr_t p = (uintptr_t)ctx, base = l ? (uintptr_t)l->batch_ctx : 0;
    if (base && p >= base && (p - base) % sizeof *ctx == 0 &&
        (p - base) / sizeof *ctx < l->batch_count)
        return &l->batch_points[(p - base) / sizeof *ctx];
    if (l)
        atomic_fetch_add(&l->failures, 1);
    return NULL;
}

unsigned long long prior_lookup_failures(const nf_model *m)
{
    prior_lookup *l = prior_lookup_of(m);
    return l ? atomic_load(&l->failures) : 0;
}

/* ---- The BSDF prior ------------------------------------------------------------------------ */

/* A context in a medium (normal exactly zero, nisflow/model.h): the BSDF prior is then the
 * medium's phase function, Henyey-Greenstein with the context's g around the propagation
 * direction -wo, as the library's cosine prior is there. */
static int in_medium(const nf_context *ctx)
{
    return ctx->normal[0] == 0.0f && ctx->normal[1] == 0.0f && ctx->normal[2] == 0.0f;
}

static vec3 propagation(const nf_context *ctx)
{
    return v3_normalize(v3(-ctx->wo[0], -ctx->wo[1], -ctx->wo[2]));
}

/* The BSDF prior at ctx with p's material (NULL: none known, a cosine lobe). */
static float prior_sample(const prior_point *p, const nf_context *ctx, float u0, float u1,
                          float dir[3])
{
    if (in_medium(ctx)) {
        float pdf;
        vec3 w = phase_hg_sample(ctx->phase_g, propagation(ctx), u0, u1, &pdf);
        dir[0] = w.x;
        dir[1] = w.y;
        dir[2] = w.z;
        return pdf;
    }
    vec3 n = v3(ctx->normal[0], ctx->normal[1], ctx->normal[2]);
    frame f = frame_from_normal(n);
    vec3 wo = frame_to_local(&f, v3(ctx->wo[0], ctx->wo[1], ctx->wo[2]));
    vec3 wi;
    float pdf;
    if (p) {
        wi = bsdf_lobe_sample(&p->bp, wo, u0, u1, &pdf);
    } else { /* no material known: a cosine lobe keeps the callbacks total */
        wi = sample_cosine_hemisphere(u0, u1);
        pdf = pdf_cosine_hemisphere(wi);
    }
    vec3 w = frame_to_world(&f, wi);
    dir[0] = w.x;
    dir[1] = w.y;
    dir[2] = w.z;
    return pdf;
}

static float prior_pdf(const prior_point *p, const nf_context *ctx, const float dir[3])
{
    if (in_medium(ctx))
        return phase_hg(ctx->phase_g,
                        v3_dot(propagation(ctx), v3_normalize(v3(dir[0], dir[1], dir[2]))));
    vec3 n = v3(ctx->normal[0], ctx->normal[1], ctx->normal[2]);
    frame f = frame_from_normal(n);
    vec3 wo = frame_to_local(&f, v3(ctx->wo[0], ctx->wo[1], ctx->wo[2]));
    vec3 wi = v3_normalize(frame_to_local(&f, v3(dir[0], dir[1], dir[2])));
    return p ? bsdf_lobe_pdf(&p->bp, wo, wi) : pdf_cosine_hemisphere(wi);
}

/* The two kinds of callbacks: bound to one shading point (user, from bsdf_prior_at_point),
 * or model-wide (user a prior_lookup, for training). */
static float point_prior_sample(void *user, const nf_context *ctx, float u0, float u1,
                                float dir[3])
{
    return prior_sample(user, ctx, u0, u1, dir);
}

static float point_prior_pdf(void *user, const nf_context *ctx, const float dir[3])
{
    return prior_pdf(user, ctx, dir);
}

static float bsdf_prior_sample(void *user, const nf_context *ctx, float u0, float u1,
                               float dir[3])
{
    return prior_sample(in_medium(ctx) ? NULL : find_point(user, ctx), ctx, u0, u1, dir);
}

static float bsdf_prior_pdf(void *user, const nf_context *ctx, const float dir[3])
{
    return prior_pdf(in_medium(ctx) ? NULL : find_point(user, ctx), ctx, dir);
}

nf_prior_callbacks bsdf_prior_callbacks(prior_lookup *l)
{
    nf_prior_callbacks cb;
    cb.sample = bsdf_prior_sample;
    cb.pdf = bsdf_prior_pdf;
    cb.user = l;
    return cb;
}

nf_prior_callbacks bsdf_prior_at_point(const prior_point *p)
{
    nf_prior_callbacks cb;
    cb.sample = point_prior_sample;
    cb.pdf = point_prior_pdf;
    cb.user = (void *)(uintptr_t)p; /* read only: the callbacks take it back as const */
    return cb;
}

