/*
 * bsdf.c - evaluation, sampling and densities of the materials in bsdf.h.
 *
 * The rough types sample microfacet normals from D(h) cos(theta_h) and reflect wo about
 * them; the rough dielectric reflects or refracts (Walter et al. 2007, with Mitsuba's
 * choice by the Fresnel term at the microfacet). Plastics follow Mitsuba's plastic: a
 * Fresnel-weighted choice between the coating and the diffuse base, whose light is
 * attenuated by Fresnel transmission in and out and by internal reflections. roughplastic uses the same base term with the Fresnel factor of
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
    return b->type == BSDF_DIELECTRIC || b->type == BSDF_THINDIELECTRIC ||
           b->type == BSDF_ROUGHDIELECTRIC;
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

/* ---- The rough dielectric: microfacets that reflect and refract ------------------------ */

/* The microfacet normal that turns wo into wi and what the pair needs: for a reflection
 * (wo and wi on one side) the half vector, for a refraction the generalized one,
 * normalize(wo + eta wi) with eta = n_wi / n_wo; flipped to the upper side. Returns 0 when no
 * microfacet does it (wi on the wrong side of m, grazing directions). */
typedef struct rough_pair {
    vec3 m;
    int reflect;
    float eta;   /* n on wi's side over n on wo's side */
    float F;     /* Fresnel reflectance at wo . m */
    float D;     /* the distribution at m */
    float denom; /* refraction: wo . m + eta wi . m */
} rough_pair;

static int rough_pair_of(const bsdf *b, vec3 wo, vec3 wi, rough_pair *rp)
{
    if (wo.z == 0.0f || wi.z == 0.0f)
        return 0;
    rp->reflect = wo.z * wi.z > 0.0f;
    rp->eta = rp->reflect ? 1.0f : (wo.z > 0.0f ? b->ior : 1.0f / b->ior);
    vec3 m = v3_add(wo, v3_scale(wi, rp->eta));
    float len = v3_length(m);
    if (!(len > 0.0f))
        return 0;
    m = v3_scale(m, (m.z < 0.0f ? -1.0f : 1.0f) / len);
    float cwo = v3_dot(wo, m), cwi = v3_dot(wi, m);
    /* Each direction on its own side of the microfacet as of the surface (the refraction's
     * two on opposite sides of m). */
    if (cwo * wo.z <= 0.0f || cwi * wi.z <= 0.0f)
        return 0;
    rp->m = m;
    rp->F = fresnel_dielectric(cwo, b->ior, NULL, NULL);
    rp->D = mf_D(b->distribution, b->alpha, m);
    rp->denom = cwo + rp->eta * cwi;
    return rp->D > 0.0f && (rp->reflect || rp->denom != 0.0f);
}

/* f |cos theta_i|: F D G / (4 |cos_o|) reflected, (1 - F) D G |wo.m wi.m| / (|cos_o| denom^2)
 * refracted (radiance: the (n_wo / n_wi)^2 of the solid angle's compression included). */
static rgb rough_dielectric_eval(const bsdf_point *bp, vec3 wo, vec3 wi)
{
    const bsdf *b = bp->b;
    rough_pair rp;
    if (!rough_pair_of(b, wo, wi, &rp))
        return rgb_gray(0.0f);
    float G = mf_G(b->distribution, b->alpha, wo, wi, rp.m);
    if (rp.reflect)
        return rgb_scale(bp->specular, rp.F * rp.D * G / (4.0f * fabsf(wo.z)));
    float v = (1.0f - rp.F) * rp.D * G *
              fabsf(v3_dot(wo, rp.m) * v3_dot(wi, rp.m) / (wo.z * rp.denom * rp.denom));
    return rgb_scale(bp->transmission, v);
}

/* The density of rough_dielectric_sample: m ~ D cos, then reflection with probability F. */
static float rough_dielectric_pdf(const bsdf *b, vec3 wo, vec3 wi)
{
    rough_pair rp;
    if (!rough_pair_of(b, wo, wi, &rp))
        return 0.0f;
    float pm = rp.D * rp.m.z;
    if (rp.reflect)
        return pm * rp.F / (4.0f * fabsf(v3_dot(wo, rp.m)));
    return pm * (1.0f - rp.F) * rp.eta * rp.eta * fabsf(v3_dot(wi, rp.m)) /
           (rp.denom * rp.denom);
}

/* wi from a microfacet normal m ~ D cos: reflected about it with probability F(wo . m),
 * refracted through it otherwise. Returns 0 for a microfacet facing away from wo and when
 * the direction ends on the wrong side of the surface (the mass bsdf_pdf leaves out). */
static int rough_dielectric_sample(const bsdf *b, vec3 wo, float u_lobe, float u0, float u1,
                                   vec3 *wi)
{
    vec3 m = mf_sample_h(b->distribution, b->alpha, u0, u1);
    float c = v3_dot(wo, m), cos_t, eta_ti;
    /* A microfacet that faces away from wo: its Fresnel term would take wo for a ray from
     * the other side. */
    if (c * wo.z <= 0.0f)
        return 0;
    float F = fresnel_dielectric(c, b->ior, &cos_t, &eta_ti);
    if (u_lobe < F) {
        *wi = v3_sub(v3_scale(m, 2.0f * c), wo);
        return wi->z * wo.z > 0.0f;
    }
    *wi = v3_normalize(v3_add(v3_scale(wo, -eta_ti), v3_scale(m, eta_ti * c + cos_t)));
    return wi->z * wo.z < 0.0f;
}

/* ---- The three functions of the interface ------------------------------------------------ */

rgb bsdf_eval(const bsdf_point *bp, vec3 wo, vec3 wi)
{
    const bsdf *b = bp->b;
    rgb zero = rgb_gray(0.0f);
    if (b->type == BSDF_ROUGHDIELECTRIC)
        return rough_dielectric_eval(bp, wo, wi);
    if (wo.z <= 0.0f || wi.z <= 0.0f) /* every other non-delta lobe is a reflection */
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
    if (b->type == BSDF_ROUGHDIELECTRIC)
        return rough_dielectric_pdf(b, wo, wi);
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
    if (s->wi.z <= 0.0f && bp->b->type != BSDF_ROUGHDIELECTRIC)
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
    if (b->type == BSDF_ROUGHDIELECTRIC)
        return rough_dielectric_sample(b, wo, u_lobe, u0, u1, &s->wi) &&
               finish_smooth(bp, wo, s);
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
    return 0.0f; /* diffuse, plastic (its coating is a delta), pure delta materials, the
                  * rough dielectric (the prior's lobe is a reflection) */
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
