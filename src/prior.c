/*
 * prior.c - the latent densities of SPEC section 2 on the unit square: sampling, log density
 * and its gradient (which reverse mode needs because z = F^-1(s) depends on the parameters).
 */
#include <math.h>

#include "internal.h"

#define NF_HALF_PI 1.57079632679489661923f
#define NF_TWO_PI_SQUARED 19.7392088021787172f

/* Below 1 by one ulp: u = 1 would map to the far edge of the square. */
static float nf_clamp_unit(float u)
{
    return nf_clampf(u, 0.0f, 0x1.fffffep-1f);
}

/* An orthonormal frame (t, b, n) around a unit normal, branch-free except for the sign
 * (Duff et al. 2017, "Building an Orthonormal Basis, Revisited"). */
static void nf_frame(const float n[3], float t[3], float b[3])
{
    float sign = copysignf(1.0f, n[2]);
    float a = -1.0f / (sign + n[2]);
    float c = n[0] * n[1] * a;
    t[0] = 1.0f + sign * n[0] * n[0] * a;
    t[1] = sign * c;
    t[2] = -sign * n[0];
    b[0] = c;
    b[1] = sign + n[1] * n[1] * a;
    b[2] = -n[1];
}

static void nf_uniform_sphere_square(float u0, float u1, float z[2])
{
    float cos_theta = 1.0f - 2.0f * u0;
    float sin_theta = 2.0f * sqrtf(nf_maxf(u0 * (1.0f - u0), 0.0f));
    z[0] = nf_minf(atan2f(sin_theta, cos_theta) / NF_PI, 1.0f);
    z[1] = u1;
}

static void nf_cosine_direction(const float n[3], float u0, float u1, float w[3])
{
    float t[3], b[3];
    nf_frame(n, t, b);
    float r = sqrtf(u0), phi = NF_TWO_PI * u1;
    float lx = r * cosf(phi), ly = r * sinf(phi), lz = sqrtf(nf_maxf(1.0f - u0, 0.0f));
    for (int a = 0; a < 3; ++a)
        w[a] = lx * t[a] + ly * b[a] + lz * n[a];
}

/* log of the square's Jacobian factor sin(theta), clamped as everywhere in the library, and
 * its derivative in z0 (zero where the clamp is active). */
static float nf_log_sin(float z0, float *dlog)
{
    float s = nf_sin_pi(z0);
    if (s <= NF_SIN_THETA_MIN) {
        if (dlog)
            *dlog = 0.0f;
        return logf(NF_SIN_THETA_MIN);
    }
    if (dlog)
        *dlog = NF_PI * cosf(NF_PI * z0) / s;
    return logf(s);
}

static nf_status nf_custom_pdf(const nf_model *m, const nf_point *pt, const float w[3],
                               float *pdf)
{
    float p = m->cfg.custom_prior.pdf(m->cfg.custom_prior.user, &pt->ctx, w);
    if (!(p >= 0.0f) || !isfinite(p))
        return nf_fail(NF_ERROR_NUMERIC, "custom prior pdf callback returned %g", (double)p);
    *pdf = p;
    return NF_OK;
}

/* log of the eps-mixed custom density on the square at z (no gradient). */
static nf_status nf_custom_log_density(const nf_model *m, const nf_point *pt, const float z[2],
                                       float *log_q)
{
    float w[3], pc = 0.0f;
    nf_square_to_direction(z, w);
    nf_status st = nf_custom_pdf(m, pt, w, &pc);
    if (st != NF_OK)
        return st;
    float eps = m->cfg.prior_epsilon;
    float q_w = (1.0f - eps) * pc + eps * NF_INV_FOUR_PI;
    *log_q = logf(q_w * NF_TWO_PI_SQUARED) + nf_log_sin(z[0], NULL);
    return NF_OK;
}

nf_status nf_prior_log_density(const nf_model *m, const nf_point *pt, const float z[2],
                               float *log_q, float grad[2])
{
    float dsin = 0.0f;
    switch (m->cfg.prior) {
    case NF_PRIOR_UNIFORM_ANGLE:
        *log_q = 0.0f;
        if (grad)
            grad[0] = grad[1] = 0.0f;
        return NF_OK;
    case NF_PRIOR_UNIFORM_DIRECTION:
        *log_q = logf(NF_HALF_PI) + nf_log_sin(z[0], grad ? &dsin : NULL);
        if (grad) {
            grad[0] = dsin;
            grad[1] = 0.0f;
        }
        return NF_OK;
    case NF_PRIOR_COSINE: {
        /* q_s = sin(theta) ((1 - eps) 2 pi max(0, n.w) + eps pi / 2) */
        float eps = m->cfg.prior_epsilon, w[3];
        const float *n = pt->ctx.normal;
        nf_square_to_direction(z, w);
        float c = n[0] * w[0] + n[1] * w[1] + n[2] * w[2];
        float g = (1.0f - eps) * NF_TWO_PI * nf_maxf(c, 0.0f) + eps * NF_HALF_PI;
        *log_q = logf(g) + nf_log_sin(z[0], grad ? &dsin : NULL);
        if (grad) {
            grad[0] = dsin;
            grad[1] = 0.0f;
            if (c > 0.0f) {
                float st = nf_sin_pi(z[0]), ct = cosf(NF_PI * z[0]);
                float cp = cosf(NF_TWO_PI * z[1]), sp = sinf(NF_TWO_PI * z[1]);
                float dc0 = NF_PI * (ct * cp * n[0] + ct * sp * n[1] - st * n[2]);
                float dc1 = NF_TWO_PI * st * (-sp * n[0] + cp * n[1]);
                float k = (1.0f - eps) * NF_TWO_PI / g;
                grad[0] += k * dc0;
                grad[1] += k * dc1;
            }
        }
        return NF_OK;
    }
    case NF_PRIOR_CUSTOM: {
        nf_status st = nf_custom_log_density(m, pt, z, log_q);
        if (st != NF_OK || !grad)
            return st;
        /* The callbacks give no derivative: central differences of the log density, one-sided
         * at the edges of the square. h = 1e-3 balances float rounding (~1e-7 / h) against
         * the truncation error (~h^2) for smooth lobes. */
        const float h = 1e-3f;
        for (int a = 0; a < 2; ++a) {
            float lo[2] = {z[0], z[1]}, hi[2] = {z[0], z[1]};
            lo[a] = nf_maxf(z[a] - h, 0.0f);
            hi[a] = nf_minf(z[a] + h, 1.0f);
            float l_lo, l_hi;
            if ((st = nf_custom_log_density(m, pt, lo, &l_lo)) != NF_OK ||
                (st = nf_custom_log_density(m, pt, hi, &l_hi)) != NF_OK)
                return st;
            grad[a] = (l_hi - l_lo) / (hi[a] - lo[a]);
        }
        return NF_OK;
    }
    }
    return nf_fail(NF_ERROR_INVALID_ARGUMENT, "unknown prior kind");
}

nf_status nf_prior_sample(const nf_model *m, const nf_point *pt, float u0, float u1, float z[2],
                          float *log_q)
{
    u0 = nf_clamp_unit(u0);
    u1 = nf_clamp_unit(u1);
    float eps = m->cfg.prior_epsilon;
    switch (m->cfg.prior) {
    case NF_PRIOR_UNIFORM_ANGLE:
        z[0] = u0;
        z[1] = u1;
        break;
    case NF_PRIOR_UNIFORM_DIRECTION:
        nf_uniform_sphere_square(u0, u1, z);
        break;
    case NF_PRIOR_COSINE:
        /* u0 picks the mixture component and is rescaled, so u -> z stays deterministic. */
        if (u0 < 1.0f - eps) {
            float w[3];
            nf_cosine_direction(pt->ctx.normal, nf_clamp_unit(u0 / (1.0f - eps)), u1, w);
            nf_direction_to_square(w, z);
        } else {
            nf_uniform_sphere_square(nf_clamp_unit((u0 - (1.0f - eps)) / eps), u1, z);
        }
        break;
    case NF_PRIOR_CUSTOM: {
        float w[3], pc = 0.0f;
        if (u0 < 1.0f - eps) {
            pc = m->cfg.custom_prior.sample(m->cfg.custom_prior.user, &pt->ctx,
                                            nf_clamp_unit(u0 / (1.0f - eps)), u1, w);
            if (!(pc > 0.0f) || !isfinite(pc) || !nf_all_finite(w, 3) ||
                !(w[0] * w[0] + w[1] * w[1] + w[2] * w[2] > 0.0f))
                return nf_fail(NF_ERROR_NUMERIC,
                               "custom prior sample callback returned pdf %g or a bad "
                               "direction", (double)pc);
            nf_direction_to_square(w, z);
        } else {
            nf_uniform_sphere_square(nf_clamp_unit((u0 - (1.0f - eps)) / eps), u1, z);
            nf_square_to_direction(z, w);
            nf_status st = nf_custom_pdf(m, pt, w, &pc);
            if (st != NF_OK)
                return st;
        }
        float q_w = (1.0f - eps) * pc + eps * NF_INV_FOUR_PI;
        *log_q = logf(q_w * NF_TWO_PI_SQUARED) + nf_log_sin(z[0], NULL);
        return NF_OK;
    }
    }
    return nf_prior_log_density(m, pt, z, log_q, NULL);
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
    nf_point_prepare(m, ctx, &pt);
    double len = sqrt((double)dir[0] * dir[0] + (double)dir[1] * dir[1] + (double)dir[2] * dir[2]);
    float w[3] = {(float)(dir[0] / len), (float)(dir[1] / len), (float)(dir[2] / len)};
    float eps = m->cfg.prior_epsilon;
    switch (m->cfg.prior) {
    case NF_PRIOR_UNIFORM_DIRECTION:
        return NF_INV_FOUR_PI;
    case NF_PRIOR_UNIFORM_ANGLE:
        return 1.0f / (NF_TWO_PI_SQUARED * nf_maxf(hypotf(w[0], w[1]), NF_SIN_THETA_MIN));
    case NF_PRIOR_COSINE: {
        const float *n = pt.ctx.normal;
        float c = nf_maxf(n[0] * w[0] + n[1] * w[1] + n[2] * w[2], 0.0f);
        return (1.0f - eps) * c / NF_PI + eps * NF_INV_FOUR_PI;
    }
    case NF_PRIOR_CUSTOM: {
        float pc = 0.0f;
        if (nf_custom_pdf(m, &pt, w, &pc) != NF_OK)
            return -1.0f;
        return (1.0f - eps) * pc + eps * NF_INV_FOUR_PI;
    }
    }
    return -1.0f;
}
