/*
 * prior.c - the public nf_model_prior_pdf: the prior's solid-angle density, computed directly in
 * solid-angle terms (the kernels work on the square; see prior.h).
 */
#include <float.h>
#include <math.h>

#include "kernels/conditioner.h"
#include "kernels/prior.h"

/* The clamp of nf_pdf (model.h): with prior_epsilon >= NF_PRIOR_EPSILON_MIN it never binds
 * for the built-in priors, but it keeps the two functions' contracts the same. */
static float nf_prior_clamp(float pdf)
{
    return pdf < FLT_MIN ? FLT_MIN : (pdf > FLT_MAX ? FLT_MAX : pdf);
}

/* The prior's density at a validated context and direction into *out, or a status. */
static nf_status nf_prior_density_at(const nf_model *m, const nf_context *ctx, const float dir[3],
                                     float *out)
{
    nf_point pt;
    nf_context_features(m, ctx, &pt);
    float w[3];
    nf_normalize3(dir, w);
    float eps = m->cfg.prior_epsilon;
    switch (m->cfg.prior) {
    case NF_PRIOR_UNIFORM_DIRECTION: *out = NF_INV_FOUR_PI; return NF_OK;
    case NF_PRIOR_UNIFORM_ANGLE:
        *out = nf_prior_clamp(1.0f / (NF_TWO_PI_SQUARED *
                                      nf_maxf(sqrtf(w[0] * w[0] + w[1] * w[1]), NF_SIN_THETA_MIN)));
        return NF_OK;
    case NF_PRIOR_COSINE: {
        nf_prior_point pp;
        nf_point_prior(&pt, &pp);
        if (pp.medium) {
            /* the eps-mixed Henyey-Greenstein phase function around d (docs/theory.md section 2,
             * "Media") */
            const float *d = pp.axis;
            float base = nf_hg_base(d[0] * w[0] + d[1] * w[1] + d[2] * w[2], pp.g);
            float hg = (1.0f - pp.g) * (1.0f + pp.g) / (base * sqrtf(base)) * NF_INV_FOUR_PI;
            *out = nf_prior_clamp((1.0f - eps) * hg + eps * NF_INV_FOUR_PI);
            return NF_OK;
        }
        const float *n = pt.ctx.normal;
        float c = nf_maxf(n[0] * w[0] + n[1] * w[1] + n[2] * w[2], 0.0f);
        *out = nf_prior_clamp((1.0f - eps) * c / NF_PI + eps * NF_INV_FOUR_PI);
        return NF_OK;
    }
    case NF_PRIOR_CUSTOM: {
        float pc = 0.0f;
        nf_prior_point pp = {pt.user, pt.prior, {0.0f, 0.0f, 0.0f}, 0u, {0.0f, 0.0f, 0.0f}, 0.0f};
        nf_status st = nf_custom_pdf(&pp, w, &pc);
        if (st != NF_OK)
            return st;
        *out = nf_prior_clamp((1.0f - eps) * pc + eps * NF_INV_FOUR_PI);
        return NF_OK;
    }
    }
    return nf_fail(NF_ERROR_INVALID_ARGUMENT, "nf_model_prior_pdf: unknown prior %u",
                   (unsigned)m->cfg.prior);
}

nf_status nf_model_prior_pdf(const nf_model *m, const nf_context *ctx, const float dir[3],
                             float *pdf)
{
    static const char fn[] = "nf_model_prior_pdf";
    nf_status st = nf_check_pointers(fn, "m", m, "ctx", ctx, "dir", dir, "pdf", pdf);
    if (st != NF_OK || (st = nf_validate_contexts(fn, 1, ctx)) != NF_OK ||
        (st = nf_validate_directions(fn, "dir", 1, dir)) != NF_OK)
        return st;
    float q;
    if ((st = nf_prior_density_at(m, ctx, dir, &q)) != NF_OK)
        return st;
    *pdf = q;
    return NF_OK;
}
