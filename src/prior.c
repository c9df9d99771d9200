/*
 * prior.c - the public nf_prior_pdf: the prior's solid-angle density, computed directly in
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

float nf_prior_pdf(const nf_model *m, const nf_context *ctx, const float dir[3])
{
    if (!m || !ctx || !dir) {
        nf_fail(NF_ERROR_INVALID_ARGUMENT, "nf_prior_pdf: NULL argument");
        return -1.0f;
    }
    if (nf_validate_contexts("nf_prior_pdf", 1, ctx) != NF_OK ||
        nf_validate_directions("nf_prior_pdf", "dir", 1, dir) != NF_OK)
        return -1.0f;
    nf_point pt;
    nf_context_features(m, ctx, &pt);
    float w[3];
    nf_normalize3(dir, w);
    float eps = m->cfg.prior_epsilon;
    switch (m->cfg.prior) {
    case NF_PRIOR_UNIFORM_DIRECTION: return NF_INV_FOUR_PI;
    case NF_PRIOR_UNIFORM_ANGLE:
        return nf_prior_clamp(1.0f / (NF_TWO_PI_SQUARED *
                                      nf_maxf(sqrtf(w[0] * w[0] + w[1] * w[1]), NF_SIN_THETA_MIN)));
    case NF_PRIOR_COSINE: {
        nf_prior_point pp;
        nf_point_prior(&pt, &pp);
        if (pp.medium) {
            /* the eps-mixed Henyey-Greenstein phase function around d (docs/theory.md 2.4) */
            const float *d = pp.axis;
            float base = nf_hg_base(d[0] * w[0] + d[1] * w[1] + d[2] * w[2], pp.g);
            float hg = (1.0f - pp.g) * (1.0f + pp.g) / (base * sqrtf(base)) * NF_INV_FOUR_PI;
            return nf_prior_clamp((1.0f - eps) * hg + eps * NF_INV_FOUR_PI);
        }
        const float *n = pt.ctx.normal;
        float c = nf_maxf(n[0] * w[0] + n[1] * w[1] + n[2] * w[2], 0.0f);
        return nf_prior_clamp((1.0f - eps) * c / NF_PI + eps * NF_INV_FOUR_PI);
    }
    case NF_PRIOR_CUSTOM: {
        float pc = 0.0f;
        nf_prior_point pp = {pt.user, pt.prior, {0.0f, 0.0f, 0.0f}, 0u, {0.0f, 0.0f, 0.0f}, 0.0f};
        if (nf_custom_pdf(&pp, w, &pc) != NF_OK)
            return -1.0f;
        return nf_prior_clamp((1.0f - eps) * pc + eps * NF_INV_FOUR_PI);
    }
    }
    return -1.0f;
}
