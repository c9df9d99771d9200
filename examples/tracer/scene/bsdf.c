/*
 * bsdf.c - evaluation, sampling and densities of the materials in bsdf.h.
 *
 * The rough types sample microfacet normals from D(h) cos(theta_h) and reflect wo about
 * them. Plastics follow Mitsuba's plastic: a Fresnel-weighted choice between the coating
 * and the diffuse base, whose light is attenuated by Fresnel transmission in and out and
 * by internal reflections. roughplastic uses the same base term with the Fresnel factor of
 * the macro-surface (Mitsuba integrates the rough coating's transmittance numerically;
 * this approximation keeps the appearance and stays energy conserving).
 */
#include "bsdf.h"

#include <math.h>

void bsdf_prepare(bsdf *b)
{
    b->fdr_int = 0.0f;
    b->specular_weight = 0.0f;
    if (b->type == BSDF_PLASTIC || b->type == BSDF_ROUGHPLASTIC) {
        b->fdr_int = fresnel_diffuse_reflectance(1.0f / b->ior);
        float d = rgb_mean(b->diffuse->mean), s = rgb_mean(b->specular->mean);
        b->specular_weight = d + s > 0.0f ? s / (d + s) : 0.5f;
    }
}

void bsdf_point_init(bsdf_point *bp, const bsdf *b, float u, float v)
{
    bp->b = b;
    bp->diffuse = b->diffuse ? texture_eval(b->diffuse, u, v) : rgb_gray(0.0f);
    bp->specular = b->specular ? texture_eval(b->specular, u, v) : rgb_gray(0.0f);
    bp->transmission = b->transmission ? texture_eval(b->transmission, u, v) : rgb_gray(0.0f);
}

int bsdf_has_smooth_part(const bsdf *b)
{
    return b->type != BSDF_CONDUCTOR && b->type != BSDF_DIELECTRIC &&
           b->type != BSDF_THINDIELECTRIC && b->type != BSDF_NULL;
}

int bsdf_transmits(const bsdf *b)
{
    return b->type == BSDF_DIELECTRIC || b->type == BSDF_THINDIELECTRIC;
}

/* ---- Pieces shared by several materials ----------------------------------------------- */

/* Probability of choosing the coating of a plastic, from the Fresnel reflectance at wo. */
static float plastic_specular_probability(const bsdf *b, float cos_o)
{
    float f = fresnel_dielectric(cos_o, b->ior, NULL, NULL);
    float ps = f * b->specular_weight, pd = (1.0f - f) * (1.0f - b->specular_weight);
    return ps + pd > 0.0f ? ps / (ps + pd) : 0.0f;
}

/* The diffuse base of a plastic, times cos theta_i. */
static rgb plastic_base(const bsdf_point *bp, float cos_o, float cos_i)
{
    const bsdf *b = bp->b;
    rgb d = bp->diffuse;
    if (b->nonlinear)
        d = rgb_make(d.r / (1.0f - d.r * b->fdr_int), d.g / (1.0f - d.g * b->fdr_int),
                     d.b / (1.0f - d.b * b->fdr_int));
    else
        d = rgb_scale(d, 1.0f / (1.0f - b->fdr_int));
    float fo = fresnel_dielectric(cos_o, b->ior, NULL, NULL);
    float fi = fresnel_dielectric(cos_i, b->ior, NULL, NULL);
    return rgb_scale(d, (1.0f - fo) * (1.0f - fi) / (b->ior * b->ior) * cos_i * INV_PI_F);
}

/* A microfacet coating's F D G / (4 cos_o), i.e. f cos_i, without the colour. For
 * conductors the Fresnel term is per channel, so it is returned as rgb. */
static rgb microfacet_reflection(const bsdf_point *bp, vec3 wo, vec3 wi)
{
    const bsdf *b = bp->b;
    vec3 h = v3_normalize(v3_add(wo, wi));
    float dg = mf_D(b->distribution, b->alpha, h) * mf_G(b->distribution, b->alpha, wo, wi, h) /
               (4.0f * wo.z);
    float c = v3_dot(wo, h);
    rgb f;
    if (b->type == BSDF_ROUGHCONDUCTOR)
        f = rgb_make(fresnel_conductor(c, b->eta.r, b->k.r), fresnel_conductor(c, b->eta.g, b->k.g),
                     fresnel_conductor(c, b->eta.b, b->k.b));
    else
        f = rgb_gray(fresnel_dielectric(c, b->ior, NULL, NULL));
    return rgb_mul(rgb_scale(f, dg), bp->specular);
}

/* ---- The three functions of the interface ------------------------------------------------ */

rgb bsdf_eval(const bsdf_point *bp, vec3 wo, vec3 wi)
{
    const bsdf *b = bp->b;
    rgb zero = rgb_gray(0.0f);
    if (wo.z <= 0.0f || wi.z <= 0.0f) /* every non-delta lobe here is a reflection */
        return zero;
    switch (b->type) {
    case BSDF_DIFFUSE:
        return rgb_scale(bp->diffuse, wi.z * INV_PI_F);
    case BSDF_ROUGHCONDUCTOR:
        return microfacet_reflection(bp, wo, wi);
    case BSDF_PLASTIC:
        return plastic_base(bp, wo.z, wi.z);
    case BSDF_ROUGHPLASTIC:
        return rgb_add(microfacet_reflection(bp, wo, wi), plastic_base(bp, wo.z, wi.z));
    default:
        return zero; /* delta only */
    }
}

float bsdf_pdf(const bsdf_point *bp, vec3 wo, vec3 wi)
{
    const bsdf *b = bp->b;
    if (wo.z <= 0.0f || wi.z <= 0.0f)
        return 0.0f;
    switch (b->type) {
    case BSDF_DIFFUSE:
        return wi.z * INV_PI_F;
    case BSDF_ROUGHCONDUCTOR:
        return mf_reflect_pdf(b->distribution, b->alpha, wo, wi);
    case BSDF_PLASTIC:
        return (1.0f - plastic_specular_probability(b, wo.z)) * wi.z * INV_PI_F;
    case BSDF_ROUGHPLASTIC: {
        float ps = plastic_specular_probability(b, wo.z);
        return ps * mf_reflect_pdf(b->distribution, b->alpha, wo, wi) +
               (1.0f - ps) * wi.z * INV_PI_F;
    }
    default:
        return 0.0f;
    }
}

/* Completes a non-delta sample: density and weight from the full material. */
static int finish_smooth(const bsdf_point *bp, vec3 wo, bsdf_sample *s)
{
    if (s->wi.z <= 0.0f)
        return 0; /* reflected below the surface: the sampler failed */
    s->pdf = bsdf_pdf(bp, wo, s->wi);
    if (!(s->pdf > 0.0f))
        return 0;
    s->weight = rgb_scale(bsdf_eval(bp, wo, s->wi), 1.0f / s->pdf);
    s->delta = 0;
    return rgb_is_finite(s->weight);
}

int bsdf_sample_dir(const bsdf_point *bp, vec3 wo, float u_lobe, float u0, float u1,
                    bsdf_sample *s)
{
    const bsdf *b = bp->b;
    if (bsdf_transmits(b)) {
        /* A delta pair: the mirror direction with probability r, else the transmitted one. */
        float r, cos_t = 0.0f, eta_ti = 1.0f;
        if (b->type == BSDF_DIELECTRIC) {
            r = fresnel_dielectric(wo.z, b->ior, &cos_t, &eta_ti);
        } else {
            /* Mitsuba's thindielectric: the sheet reflects R + T R T + T R^3 T + ... =
             * 2R / (1 + R) of the light, from either side, and lets the rest through
             * unbent. */
            r = fresnel_dielectric(fabsf(wo.z), b->ior, NULL, NULL);
            r = 2.0f * r / (1.0f + r);
        }
        s->delta = 1;
        if (u_lobe < r) {
            s->wi = v3(-wo.x, -wo.y, wo.z);
            s->weight = bp->specular;
            s->pdf = r;
        } else if (b->type == BSDF_DIELECTRIC) {
            s->wi = v3_normalize(v3(-eta_ti * wo.x, -eta_ti * wo.y, cos_t));
            /* Radiance is compressed into a smaller solid angle on the denser side. */
            s->weight = rgb_scale(bp->transmission, eta_ti * eta_ti);
            s->pdf = 1.0f - r;
        } else {
            s->wi = v3_neg(wo);
            s->weight = bp->transmission;
            s->pdf = 1.0f - r;
        }
        return s->pdf > 0.0f;
    }
    if (wo.z <= 0.0f)
        return 0;
    switch (b->type) {
    case BSDF_DIFFUSE:
        s->wi = sample_cosine_hemisphere(u0, u1);
        return finish_smooth(bp, wo, s);
    case BSDF_CONDUCTOR: {
        float c = wo.z;
        s->wi = v3(-wo.x, -wo.y, wo.z);
        s->weight = rgb_mul(bp->specular, rgb_make(fresnel_conductor(c, b->eta.r, b->k.r),
                                                   fresnel_conductor(c, b->eta.g, b->k.g),
                                                   fresnel_conductor(c, b->eta.b, b->k.b)));
        s->pdf = 1.0f;
        s->delta = 1;
        return 1;
    }
    case BSDF_ROUGHCONDUCTOR:
        s->wi = v3_reflect(wo, mf_sample_h(b->distribution, b->alpha, u0, u1));
        return finish_smooth(bp, wo, s);
    case BSDF_PLASTIC: {
        float ps = plastic_specular_probability(b, wo.z);
        if (u_lobe < ps) {
            s->wi = v3(-wo.x, -wo.y, wo.z);
            s->weight = rgb_scale(bp->specular, fresnel_dielectric(wo.z, b->ior, NULL, NULL) / ps);
            s->pdf = ps;
            s->delta = 1;
            return 1;
        }
        s->wi = sample_cosine_hemisphere(u0, u1);
        return finish_smooth(bp, wo, s);
    }
    case BSDF_ROUGHPLASTIC: {
        float ps = plastic_specular_probability(b, wo.z);
        if (u_lobe < ps)
            s->wi = v3_reflect(wo, mf_sample_h(b->distribution, b->alpha, u0, u1));
        else
            s->wi = sample_cosine_hemisphere(u0, u1);
        return finish_smooth(bp, wo, s);
    }
    default:
        return 0;
    }
}

/* ---- The non-delta lobes as a prior for the flow --------------------------------------- */

/* The prior's microfacet lobe: reflect wo about h ~ D cos. When that gives no usable
 * direction (a back-facing microfacet or a reflection below the surface), the same (u0, u1)
 * drive a cosine lobe instead: the prior never fails, and its density stays exact because
 * the fallback's share of a direction can be recomputed by inverting the cosine map. */
static int microfacet_reflection_valid(const bsdf *b, vec3 wo, float u0, float u1, vec3 *wi)
{
    vec3 h = mf_sample_h(b->distribution, b->alpha, u0, u1);
    if (v3_dot(wo, h) <= 0.0f)
        return 0;
    *wi = v3_reflect(wo, h);
    return wi->z > 0.0f;
}

static vec3 prior_microfacet_sample(const bsdf *b, vec3 wo, float u0, float u1)
{
    vec3 wi;
    if (microfacet_reflection_valid(b, wo, u0, u1, &wi))
        return wi;
    return sample_cosine_hemisphere(u0, u1);
}

static float prior_microfacet_pdf(const bsdf *b, vec3 wo, vec3 wi)
{
    if (wi.z <= 0.0f)
        return 0.0f;
    /* Reflections: wo.h > 0 holds for h = normalize(wo + wi), and wi.z > 0 here, so this is
     * exactly the density of the valid microfacet samples. */
    float p = mf_reflect_pdf(b->distribution, b->alpha, wo, wi);
    /* The fallback: the numbers a cosine sample of wi came from, and whether the microfacet
     * sampler rejected them. */
    float u0 = fminf(fmaxf(1.0f - wi.z * wi.z, 0.0f), 0.99999994f);
    float u1 = atan2f(wi.y, wi.x) * (0.5f * INV_PI_F);
    u1 = u1 < 0.0f ? u1 + 1.0f : u1;
    vec3 unused;
    if (!microfacet_reflection_valid(b, wo, u0, fminf(u1, 0.99999994f), &unused))
        p += wi.z * INV_PI_F;
    return p;
}

static float lobe_specular_probability(const bsdf *b, vec3 wo)
{
    if (b->type == BSDF_ROUGHCONDUCTOR)
        return 1.0f;
    if (b->type == BSDF_ROUGHPLASTIC)
        return plastic_specular_probability(b, wo.z);
    return 0.0f; /* diffuse, plastic (its coating is a delta), pure delta materials */
}

static vec3 safe_wo(vec3 wo)
{
    return wo.z < 1e-4f ? v3_normalize(v3(wo.x, wo.y, 1e-4f)) : wo;
}

float bsdf_lobe_pdf(const bsdf_point *bp, vec3 wo, vec3 wi)
{
    wo = safe_wo(wo);
    float ps = lobe_specular_probability(bp->b, wo);
    float p = (1.0f - ps) * fmaxf(wi.z, 0.0f) * INV_PI_F;
    if (ps > 0.0f)
        p += ps * prior_microfacet_pdf(bp->b, wo, wi);
    return p;
}

vec3 bsdf_lobe_sample(const bsdf_point *bp, vec3 wo, float u0, float u1, float *pdf)
{
    const bsdf *b = bp->b;
    wo = safe_wo(wo);
    float ps = lobe_specular_probability(b, wo);
    vec3 wi;
    /* u0 both picks the lobe and, rescaled, drives it: the map stays deterministic. */
    if (u0 < ps) {
        float v = fminf(u0 / ps, 0.99999994f);
        wi = prior_microfacet_sample(b, wo, v, u1);
    } else {
        float v = ps > 0.0f ? fminf((u0 - ps) / (1.0f - ps), 0.99999994f) : u0;
        wi = sample_cosine_hemisphere(v, u1);
    }
    *pdf = bsdf_lobe_pdf(bp, wo, wi);
    if (!(*pdf > 0.0f) || !isfinite(*pdf)) {
        /* Cannot happen for valid parameters (every direction above the surface has a
         * positive cosine part or lies in the microfacet lobe); the guard keeps the promise
         * to libnisflow that the density is positive and finite. */
        wi = v3(0.0f, 0.0f, 1.0f);
        *pdf = fmaxf(bsdf_lobe_pdf(bp, wo, wi), INV_PI_F);
    }
    return wi;
}
