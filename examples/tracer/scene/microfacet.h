/*
 * microfacet.h - microfacet distributions (GGX and Beckmann, isotropic) and Fresnel terms,
 * in the local shading frame (normal = +z). The formulas and the meaning of alpha are
 * Mitsuba's, so that scene files give the same appearance.
 */
#ifndef TRACER_MICROFACET_H
#define TRACER_MICROFACET_H

#include "vecmath.h"

typedef enum mf_type { MF_BECKMANN = 0, MF_GGX = 1 } mf_type;

/* The normal distribution D(h) per unit solid angle of microfacet normals; zero below the
 * surface. */
static inline float mf_D(mf_type type, float alpha, vec3 h)
{
    float c2 = h.z * h.z;
    if (h.z <= 0.0f)
        return 0.0f;
    float a2 = alpha * alpha, t2 = (1.0f - c2) / c2; /* tan^2 theta */
    if (type == MF_BECKMANN)
        return expf(-t2 / a2) / (PI_F * a2 * c2 * c2);
    float d = 1.0f + t2 / a2;
    return 1.0f / (PI_F * a2 * c2 * c2 * d * d);
}

/* Smith's shadowing-masking term for one direction v seen from the microfacet normal h. */
static inline float mf_G1(mf_type type, float alpha, vec3 v, vec3 h)
{
    if (v3_dot(v, h) * v.z <= 0.0f)
        return 0.0f;
    float t2 = fmaxf(0.0f, 1.0f - v.z * v.z) / (v.z * v.z);
    if (t2 == 0.0f)
        return 1.0f;
    if (type == MF_GGX)
        return 2.0f / (1.0f + sqrtf(1.0f + alpha * alpha * t2));
    /* Beckmann: Walter et al.'s rational approximation, as Mitsuba. */
    float a = 1.0f / (alpha * sqrtf(t2));
    if (a >= 1.6f)
        return 1.0f;
    return (3.535f * a + 2.181f * a * a) / (1.0f + 2.276f * a + 2.577f * a * a);
}

static inline float mf_G(mf_type type, float alpha, vec3 wo, vec3 wi, vec3 h)
{
    return mf_G1(type, alpha, wo, h) * mf_G1(type, alpha, wi, h);
}

/* Samples a microfacet normal with density D(h) cos(theta_h) (per solid angle of h). We
 * sample the whole distribution rather than the visible normals: a little more variance at
 * grazing angles, but short and identical for both distributions. */
static inline vec3 mf_sample_h(mf_type type, float alpha, float u0, float u1)
{
    float t2 = type == MF_BECKMANN ? -alpha * alpha * logf(1.0f - u0)
                                   : alpha * alpha * u0 / (1.0f - u0);
    float c = 1.0f / sqrtf(1.0f + t2), s = sqrtf(fmaxf(0.0f, 1.0f - c * c));
    float phi = 2.0f * PI_F * u1;
    return v3(s * cosf(phi), s * sinf(phi), c);
}

/* The density, per solid angle of wi, of reflecting wo about an h drawn by mf_sample_h.
 * Every h gives a direction (possibly below the surface); this is its density over the
 * whole sphere. */
static inline float mf_reflect_pdf(mf_type type, float alpha, vec3 wo, vec3 wi)
{
    vec3 h = v3_add(wo, wi);
    float len = v3_length(h);
    if (len == 0.0f)
        return 0.0f;
    h = v3_scale(h, 1.0f / len);
    if (h.z < 0.0f) /* the sampler only draws upper normals; -h reflects the same way */
        h = v3_neg(h);
    float d = fabsf(v3_dot(wo, h));
    if (d == 0.0f)
        return 0.0f;
    return mf_D(type, alpha, h) * h.z / (4.0f * d);
}

/* Unpolarized Fresnel reflectance of a dielectric interface. cos_i is the cosine of the
 * incident direction with the normal (negative: from inside); eta = n_inside / n_outside.
 * *cos_t receives the cosine of the refracted direction (opposite sign to cos_i, 0 on total
 * internal reflection) and *eta_ti the ratio n_incident / n_transmitted. */
static inline float fresnel_dielectric(float cos_i, float eta, float *cos_t, float *eta_ti)
{
    float e = cos_i >= 0.0f ? eta : 1.0f / eta; /* n_transmitted / n_incident */
    float inv = 1.0f / e;
    float ci = fabsf(cos_i);
    float s2t = inv * inv * fmaxf(0.0f, 1.0f - ci * ci);
    if (eta_ti)
        *eta_ti = inv;
    if (s2t >= 1.0f) {
        if (cos_t)
            *cos_t = 0.0f;
        return 1.0f;
    }
    float ct = sqrtf(1.0f - s2t);
    float rs = (ci - e * ct) / (ci + e * ct);
    float rp = (e * ci - ct) / (e * ci + ct);
    if (cos_t)
        *cos_t = cos_i >= 0.0f ? -ct : ct;
    return 0.5f * (rs * rs + rp * rp);
}

/* Fresnel reflectance of a conductor with complex index eta + i k (relative to the outside),
 * for one colour channel; cos_i in [0, 1]. */
static inline float fresnel_conductor(float cos_i, float eta, float k)
{
    float c2 = cos_i * cos_i, s2 = 1.0f - c2, s4 = s2 * s2;
    float t1 = eta * eta - k * k - s2;
    float a2b2 = sqrtf(fmaxf(t1 * t1 + 4.0f * k * k * eta * eta, 0.0f));
    float a = sqrtf(fmaxf(0.5f * (a2b2 + t1), 0.0f));
    float t2 = a2b2 + c2, t3 = 2.0f * cos_i * a;
    float rs = (t2 - t3) / (t2 + t3);
    float t4 = a2b2 * c2 + s4, t5 = t3 * s2;
    float rp = rs * (t4 - t5) / (t4 + t5);
    return 0.5f * (rs + rp);
}

/* The hemispherical average of the dielectric Fresnel reflectance (fits by Egan and
 * Hilgeman 1973 for eta < 1 and d'Eon and Irving 2011 otherwise), as in Mitsuba. */
static inline float fresnel_diffuse_reflectance(float eta)
{
    if (eta < 1.0f)
        return -1.4399f * eta * eta + 0.7099f * eta + 0.6681f + 0.0636f / eta;
    float i1 = 1.0f / eta, i2 = i1 * i1, i3 = i2 * i1, i4 = i3 * i1, i5 = i4 * i1;
    return 0.919317f - 3.4793f * i1 + 6.75335f * i2 - 7.80989f * i3 + 4.98554f * i4 -
           1.36881f * i5;
}

#endif /* TRACER_MICROFACET_H */
