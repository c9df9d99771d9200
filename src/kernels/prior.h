/*
 * prior.h - the latent densities of docs/theory.md section 2 on the unit square as inline code for
 * the kernels: sampling, density, and the gradient of its log (which reverse mode needs
 * because z = F^-1(s) depends on the parameters).
 */
#ifndef NISFLOW_KERNELS_PRIOR_H
#define NISFLOW_KERNELS_PRIOR_H

#include <math.h>

#include "fastmath.h"
#include "internal.h"
#include "sphere.h"

/* Below 1 by one ulp: u = 1 would map to the far edge of the square. */
static inline float nf_clamp_unit(float u) { return nf_clampf(u, 0.0f, 0x1.fffffep-1f); }

/* An orthonormal frame (t, b, n) around a unit normal, branch-free except for the sign
 * (Duff et al. 2017, "Building an Orthonormal Basis, Revisited"). */
static inline void nf_frame(const float n[3], float t[3], float b[3])
{
    float sign = n[2] >= 0.0f ? 1.0f : -1.0f;
    float a = -1.0f / (sign + n[2]);
    float c = n[0] * n[1] * a;
    t[0] = 1.0f + sign * n[0] * n[0] * a;
    t[1] = sign * c;
    t[2] = -sign * n[0];
    b[0] = c;
    b[1] = sign + n[1] * n[1] * a;
    b[2] = -n[1];
}

static inline void nf_uniform_sphere_square(float u0, float u1, float z[2])
{
    float cos_theta = 1.0f - 2.0f * u0;
    float sin_theta = 2.0f * sqrtf(nf_maxf(u0 * (1.0f - u0), 0.0f));
    z[0] = nf_minf(nf_fast_atan2(sin_theta, cos_theta) * (1.0f / NF_PI), 1.0f);
    z[1] = u1;
}

/* The cosine lobe's direction around n for u0 and the azimuth's sine and cosine; returns
 * cos theta = n.w. */
static NF_ALWAYS_INLINE float nf_cosine_direction_at(const float n[3], float u0, float sin_phi,
                                                     float cos_phi, float w[3])
{
    float t[3], b[3];
    nf_frame(n, t, b);
    float r = sqrtf(u0);
    float lx = r * cos_phi, ly = r * sin_phi, lz = sqrtf(nf_maxf(1.0f - u0, 0.0f));
    for (int a = 0; a < 3; ++a)
        w[a] = lx * t[a] + ly * b[a] + lz * n[a];
    return lz;
}

static inline void nf_cosine_direction(const float n[3], float u0, float u1, float w[3])
{
    float sin_phi, cos_phi;
    nf_fast_sincos_turns(u1, &sin_phi, &cos_phi);
    nf_cosine_direction_at(n, u0, sin_phi, cos_phi, w);
}

/* A direction drawn from the Henyey-Greenstein phase function with asymmetry g (|g| < 1)
 * around the unit axis d (docs/theory.md section 2, "Media"): u0 = 0 gives -d, u0 = 1 gives d, u1
 * the azimuth. The inversion's usual form (1 + g^2 - s^2) / (2 g) cancels as g -> 0; here 1 - cos
 * and 1 + cos come as products with no cancellation, so cos theta near either pole and
 * sin theta keep their relative precision and g = 0 is the uniform sphere exactly. Branch-free
 * and the same arithmetic wherever it is called, so points and batches agree to the bit. */
static inline void nf_hg_direction(const float d[3], float g, float u0, float u1, float w[3])
{
    float t = 1.0f - g + 2.0f * g * u0; /* in [1 - |g|, 1 + |g|] */
    float inv_t2 = 1.0f / (t * t);
    float lo = (1.0f - g) * (1.0f - g), hi = (1.0f + g) * (1.0f + g);
    float one_minus = 2.0f * lo * (1.0f - u0) * (1.0f + g * u0) * inv_t2;
    float one_plus = 2.0f * hi * u0 * (1.0f - g + g * u0) * inv_t2;
    float cos_theta = one_minus < one_plus ? 1.0f - one_minus : one_plus - 1.0f;
    float sin_theta = sqrtf(nf_maxf(one_minus * one_plus, 0.0f));
    float t_axis[3], b_axis[3], sin_phi, cos_phi;
    nf_frame(d, t_axis, b_axis);
    nf_fast_sincos_turns(u1, &sin_phi, &cos_phi);
    float lx = sin_theta * cos_phi, ly = sin_theta * sin_phi;
    for (int a = 0; a < 3; ++a)
        w[a] = lx * t_axis[a] + ly * b_axis[a] + cos_theta * d[a];
}

/* The cosine prior's solid-angle density times 2 pi^2 (the square's Jacobian without
 * sin theta) at n.w = c: (1 - eps) 2 pi max(0, c) + eps pi / 2. */
static inline float nf_cosine_lobe(float c, float eps)
{
    return (1.0f - eps) * NF_TWO_PI * nf_maxf(c, 0.0f) + eps * NF_HALF_PI;
}

/* 1 + g^2 - 2 g c, the Henyey-Greenstein denominator's base, as (1 - |g|)^2 + 2 |g| (1 - c')
 * with c' = c sign(g): 1 - c' is exact near the peak (c' -> 1), where the plain form loses
 * the low bits of (1 - |g|)^2. */
static inline float nf_hg_base(float c, float g)
{
    float a = fabsf(g), s = g < 0.0f ? -c : c;
    return (1.0f - a) * (1.0f - a) + 2.0f * a * (1.0f - s);
}

/* The eps-mixed Henyey-Greenstein density times 2 pi^2 at d.w = c:
 * 2 pi^2 ((1 - eps) (1 - g^2) / (4 pi base^(3/2)) + eps / (4 pi))
 *   = pi / 2 ((1 - eps) (1 - g^2) / base^(3/2) + eps). */
static inline float nf_hg_lobe(float c, float g, float eps)
{
    float base = nf_hg_base(c, g);
    return NF_HALF_PI * ((1.0f - eps) * (1.0f - g) * (1.0f + g) / (base * sqrtf(base)) + eps);
}

/* The solid-angle density of the custom prior's callbacks at w, checked. */
static inline nf_status nf_custom_pdf(const nf_prior_point *pt, const float w[3], float *pdf)
{
    float p = pt->prior->pdf(pt->prior->user, pt->user, w);
    *pdf = 0.0f;
    if (!(p >= 0.0f) || !isfinite(p))
        return nf_fail(NF_ERROR_NUMERIC, "custom prior pdf callback returned %g", (double)p);
    *pdf = p;
    return NF_OK;
}

/* The eps-mixed custom density on the square at z (no gradient). */
static inline nf_status nf_custom_density(const nf_model *m, const nf_prior_point *pt,
                                          const float z[2], float *q)
{
    float w[3], pc;
    float sin_theta = nf_from_square(z, w);
    nf_status st = nf_custom_pdf(pt, w, &pc);
    float eps = m->cfg.prior_epsilon;
    *q = ((1.0f - eps) * pc + eps * NF_INV_FOUR_PI) * NF_TWO_PI_SQUARED *
         nf_maxf(sin_theta, NF_SIN_THETA_MIN);
    return st;
}

/* The prior's density on the square at z, q_s(z) > 0, and (if grad != NULL) the gradient of
 * log q_s in z. For custom priors NF_ERROR_NUMERIC if a callback returns a bad value. */
static inline nf_status nf_prior_density(const nf_model *m, const nf_prior_point *pt,
                                         const float z[2], float *q, float grad[2])
{
    if (m->cfg.prior == NF_PRIOR_UNIFORM_ANGLE) {
        *q = 1.0f;
        if (grad)
            grad[0] = grad[1] = 0.0f;
        return NF_OK;
    }
    if (m->cfg.prior == NF_PRIOR_CUSTOM) {
        nf_status st = nf_custom_density(m, pt, z, q);
        if (st != NF_OK || !grad)
            return st;
        /* The callbacks give no derivative: central differences of the log density,
         * one-sided at the edges of the square. h = 1e-3 balances float rounding (~1e-7 / h)
         * against the truncation error (~h^2) for smooth lobes. */
        const float h = 1e-3f;
        for (int a = 0; a < 2; ++a) {
            float lo[2] = {z[0], z[1]}, hi[2] = {z[0], z[1]}, q_lo, q_hi;
            lo[a] = nf_maxf(z[a] - h, 0.0f);
            hi[a] = nf_minf(z[a] + h, 1.0f);
            if ((st = nf_custom_density(m, pt, lo, &q_lo)) != NF_OK ||
                (st = nf_custom_density(m, pt, hi, &q_hi)) != NF_OK)
                return st;
            grad[a] = (float)(log((double)q_hi / (double)q_lo) / (double)(hi[a] - lo[a]));
        }
        return NF_OK;
    }
    /* Uniform direction and cosine share the Jacobian factor sin(theta), clamped as
     * everywhere in the library; its log-derivative is zero where the clamp is active. */
    float w[3];
    float sin_raw = nf_from_square(z, w);
    float sin_theta = nf_maxf(sin_raw, NF_SIN_THETA_MIN);
    float dlog_sin = sin_raw > NF_SIN_THETA_MIN ? NF_PI * w[2] / sin_raw : 0.0f;
    if (m->cfg.prior == NF_PRIOR_UNIFORM_DIRECTION) {
        *q = NF_HALF_PI * sin_theta;
        if (grad) {
            grad[0] = dlog_sin;
            grad[1] = 0.0f;
        }
        return NF_OK;
    }
    /* cosine: q_s = sin(theta) ((1 - eps) 2 pi max(0, n.w) + eps pi / 2) on surfaces; in a
     * medium the eps-mixed Henyey-Greenstein lobe around d (nf_hg_lobe). */
    const float eps = m->cfg.prior_epsilon, *n = pt->medium ? pt->axis : pt->normal;
    float c = n[0] * w[0] + n[1] * w[1] + n[2] * w[2];
    float g = pt->medium ? nf_hg_lobe(c, pt->g, eps) : nf_cosine_lobe(c, eps);
    *q = sin_theta * g;
    if (grad) {
        grad[0] = dlog_sin;
        grad[1] = 0.0f;
        /* d log(lobe) / dc: the cosine's is (1 - eps) 2 pi / lobe where c > 0; the phase
         * function's (1 - eps) pi/2 (1 - g^2) 3 g base^(-5/2) / lobe. */
        float k = 0.0f;
        if (pt->medium) {
            float hg = pt->g, base = nf_hg_base(c, hg);
            k = NF_HALF_PI * (1.0f - eps) * (1.0f - hg) * (1.0f + hg) * 3.0f * hg /
                (base * base * sqrtf(base) * g);
        } else if (c > 0.0f) {
            k = (1.0f - eps) * NF_TWO_PI / g;
        }
        if (k != 0.0f) {
            /* dw/dz0 = pi (cos t cos p, cos t sin p, -sin t), dw/dz1 = 2 pi (-w_y, w_x, 0) */
            float cos_phi = sin_raw > 0.0f ? w[0] / sin_raw : 1.0f;
            float sin_phi = sin_raw > 0.0f ? w[1] / sin_raw : 0.0f;
            float dc0 = NF_PI * (w[2] * cos_phi * n[0] + w[2] * sin_phi * n[1] - sin_raw * n[2]);
            float dc1 = NF_TWO_PI * (-w[1] * n[0] + w[0] * n[1]);
            grad[0] += k * dc0;
            grad[1] += k * dc1;
        }
    }
    return NF_OK;
}

/* Draws a latent point z on the square and returns its density q_s(z) in *q. */
static inline nf_status nf_prior_sample(const nf_model *m, const nf_prior_point *pt, float u0,
                                        float u1, float z[2], float *q)
{
    u0 = nf_clamp_unit(u0);
    u1 = nf_clamp_unit(u1);
    const float eps = m->cfg.prior_epsilon;
    switch (m->cfg.prior) {
    case NF_PRIOR_UNIFORM_ANGLE:
        z[0] = u0;
        z[1] = u1;
        break;
    case NF_PRIOR_UNIFORM_DIRECTION: nf_uniform_sphere_square(u0, u1, z); break;
    case NF_PRIOR_COSINE:
        /* u0 picks the mixture component and is rescaled, so u -> z stays deterministic. */
        if (u0 < 1.0f - eps) {
            float w[3], uc = nf_clamp_unit(u0 / (1.0f - eps));
            if (pt->medium)
                nf_hg_direction(pt->axis, pt->g, uc, u1, w);
            else
                nf_cosine_direction(pt->normal, uc, u1, w);
            nf_to_square(w, z);
        } else {
            nf_uniform_sphere_square(nf_clamp_unit((u0 - (1.0f - eps)) / eps), u1, z);
        }
        break;
    case NF_PRIOR_CUSTOM: {
        float w[3], pc = 0.0f;
        if (u0 < 1.0f - eps) {
            pc = pt->prior->sample(pt->prior->user, pt->user, nf_clamp_unit(u0 / (1.0f - eps)), u1,
                                   w);
            if (!(pc > 0.0f) || !isfinite(pc) || !nf_all_finite(w, 3) ||
                !(w[0] * w[0] + w[1] * w[1] + w[2] * w[2] > 0.0f))
                return nf_fail(NF_ERROR_NUMERIC,
                               "custom prior sample callback returned pdf %g or a bad "
                               "direction",
                               (double)pc);
            nf_to_square(w, z);
        } else {
            nf_uniform_sphere_square(nf_clamp_unit((u0 - (1.0f - eps)) / eps), u1, z);
            nf_from_square(z, w);
            nf_status st = nf_custom_pdf(pt, w, &pc);
            if (st != NF_OK)
                return st;
        }
        float sin_theta = nf_maxf(nf_sin_pi(z[0]), NF_SIN_THETA_MIN);
        *q = ((1.0f - eps) * pc + eps * NF_INV_FOUR_PI) * NF_TWO_PI_SQUARED * sin_theta;
        return NF_OK;
    }
    }
    return nf_prior_density(m, pt, z, q, NULL);
}

#endif /* NISFLOW_KERNELS_PRIOR_H */
