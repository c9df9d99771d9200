/*
 * bsdf.h - the materials of the scene format: diffuse, conductor, roughconductor,
 * dielectric, thindielectric, roughdielectric, plastic and roughplastic, each optionally
 * two-sided, optionally masked (an opacity texture, applied when rays are traced) and
 * optionally bump-mapped (a height texture, applied to the shading normal).
 *
 * All directions are local to the shading frame (normal = +z) and point away from the
 * surface: wo towards the previous path vertex (the camera side), wi towards the light.
 *
 * Conventions (Mitsuba's):
 *   bsdf_eval returns f(wo, wi) |cos theta_i|, the "cosine-weighted BSDF", of the
 *     non-delta part only (a delta lobe is never hit by a direction chosen elsewhere);
 *   bsdf_pdf returns the solid-angle density with which bsdf_sample produces wi through a
 *     non-delta lobe, lobe-selection probability included, and 0 where the sampler never
 *     succeeds (for example below the surface of a reflector);
 *   bsdf_sample may fail (returns 0): the path then ends, and the failure probability is
 *     exactly the mass missing from bsdf_pdf, which keeps every estimator unbiased.
 * One-sided materials are black when seen from below (wo.z <= 0), as in Mitsuba; the
 * caller flips the frame of two-sided materials so that wo.z > 0. Dielectrics have two
 * sides: wo.z < 0 is inside (the side the normal points away from). Transmission carries
 * radiance: its values are scaled by (n_wo / n_wi)^2, Mitsuba's radiance mode.
 */
#ifndef TRACER_BSDF_H
#define TRACER_BSDF_H

#include "microfacet.h"
#include "texture.h"
#include "vecmath.h"

typedef enum bsdf_type {
    BSDF_DIFFUSE,
    BSDF_CONDUCTOR,      /* smooth: a delta reflection                         */
    BSDF_ROUGHCONDUCTOR,
    BSDF_DIELECTRIC,     /* smooth: delta reflection and refraction            */
    BSDF_THINDIELECTRIC, /* a thin sheet: delta reflection, and transmission straight
                          * through, with the sheet's internal reflections summed  */
    BSDF_ROUGHDIELECTRIC, /* microfacet reflection and refraction (Walter et al. 2007) */
    BSDF_PLASTIC,        /* delta coating over a diffuse base                  */
    BSDF_ROUGHPLASTIC,   /* microfacet coating over a diffuse base             */
    BSDF_NULL            /* no surface: the boundary of a medium. The integrator passes
                          * rays through it and never asks it anything below */
} bsdf_type;

typedef struct bsdf {
    bsdf_type type;
    int twosided;
    const texture *diffuse;      /* diffuse: reflectance; plastics: diffuse_reflectance */
    const texture *specular;     /* specular_reflectance (conductors, dielectric, plastics) */
    const texture *transmission; /* dielectrics: specular_transmittance                 */
    rgb eta, k;                  /* conductors: complex index relative to the outside   */
    float ior;                   /* dielectrics, plastics: int_ior / ext_ior            */
    mf_type distribution;        /* rough types                                         */
    float alpha;                 /* rough types: roughness (Mitsuba's alpha)            */
    int nonlinear;               /* plastics                                            */
    float fdr_int;               /* plastics: diffuse Fresnel reflectance inside        */
    float specular_weight;       /* plastics: s / (s + d) with the textures' means      */
    const texture *opacity;      /* mask: the chance that a ray meets the surface (its
                                  * texture_eval_opacity); elsewhere a ray passes through
                                  * as if nothing were there (scene.c's alpha test). NULL:
                                  * opaque. Everything below sees only the opaque part  */
    const texture *bump;         /* bumpmap: a height field whose gradient tilts the shading
                                  * normal (scene_surface); NULL: none. Everything below
                                  * sees the tilted frame                               */
    float bump_scale;            /* bumpmap: the gradient's multiplier (Mitsuba's scale) */
} bsdf;

/* Fills the derived fields (fdr_int, specular_weight) once the parameters are set. */
void bsdf_prepare(bsdf *b);

/* A material at one surface point: its textures evaluated at the hit's (u, v). */
typedef struct bsdf_point {
    const bsdf *b;
    rgb diffuse, specular, transmission;
} bsdf_point;

void bsdf_point_init(bsdf_point *bp, const bsdf *b, float u, float v);

/* Whether the material has a non-delta part (what light sampling and guiding can use). */
int bsdf_has_smooth_part(const bsdf *b);
/* Whether light may pass through (then wi may lie below the surface). */
int bsdf_transmits(const bsdf *b);

typedef struct bsdf_sample {
    vec3 wi;
    rgb weight; /* f |cos| / pdf (for delta lobes: the lobe's value / its probability)     */
    float pdf;  /* non-delta: bsdf_pdf(wo, wi); delta: the probability of choosing the lobe */
    int delta;
} bsdf_sample;

rgb bsdf_eval(const bsdf_point *bp, vec3 wo, vec3 wi);
float bsdf_pdf(const bsdf_point *bp, vec3 wo, vec3 wi);
/* u_lobe picks a lobe, (u0, u1) the direction inside it; all in [0, 1). */
int bsdf_sample_dir(const bsdf_point *bp, vec3 wo, float u_lobe, float u0, float u1,
                    bsdf_sample *s);

/* The material's non-delta lobes as a proper density over the whole sphere that never
 * fails to produce a direction: the prior of the flow for --prior bsdf (see bsdf_prior.c).
 * Where the microfacet lobe yields no direction (a back-facing microfacet, a reflection
 * below the surface), the same random numbers drive a cosine lobe, and the density includes
 * that fallback exactly. Pure delta materials and the rough dielectric get a cosine lobe. wo.z should be > 0 (it is
 * clamped to a grazing angle otherwise). */
vec3 bsdf_lobe_sample(const bsdf_point *bp, vec3 wo, float u0, float u1, float *pdf);
float bsdf_lobe_pdf(const bsdf_point *bp, vec3 wo, vec3 wi);

#endif /* TRACER_BSDF_H */
