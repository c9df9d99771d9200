/*
 * prior_tile.h - the priors (docs/theory.md section 2) for a tile of samples: latent points
 * and their densities on the unit square with prior.h's arithmetic per lane. Custom priors
 * call their callbacks lane by lane, for real samples only.
 */
#ifndef NISFLOW_KERNELS_PRIOR_TILE_H
#define NISFLOW_KERNELS_PRIOR_TILE_H

#include "internal.h"
#include "prior.h"
#include "sphere.h"
#include "tile.h"

/* The per-sample view of lane i that custom prior callbacks need (the caller's context and
 * the unit normal); the encodings are not filled. */
static inline void nf_tile_point(const nf_tile *tile, uint32_t i, nf_prior_point *pt)
{
    pt->user = tile->user[i];
    pt->prior = tile->prior;
    pt->medium = tile->media ? tile->medium[i] : 0u;
    pt->g = pt->medium ? tile->phase_g[i] : 0.0f;
    for (uint32_t a = 0; a < 3; ++a) {
        pt->normal[a] = tile->normal[a][i];
        pt->axis[a] = pt->medium ? tile->axis[a][i] : 0.0f;
    }
}

/* Custom prior, lane by lane: z[.][i] and q[i] from u for the real samples; padding lanes
 * copy lane 0. */
static inline nf_status nf_tile_custom_sample(const nf_model *m, const nf_tile *tile,
                                              const float *u0, const float *u1, float (*z)[NF_TILE],
                                              float *q)
{
    for (uint32_t i = 0; i < NF_TILE; ++i) {
        if (i >= tile->count) {
            z[0][i] = z[0][0];
            z[1][i] = z[1][0];
            q[i] = q[0];
            continue;
        }
        nf_prior_point pt;
        float zi[2];
        nf_tile_point(tile, i, &pt);
        nf_status st = nf_prior_sample(m, &pt, u0[i], u1[i], zi, &q[i]);
        if (st != NF_OK)
            return st;
        z[0][i] = zi[0];
        z[1][i] = zi[1];
    }
    return NF_OK;
}

/* The cosine prior's density for a tile with lanes in a medium: both lobes for every lane
 * and a select (the surface lanes' bits are the loop's below, the medium lanes' those of
 * nf_prior_density). A loop of its own, so that surface-only tiles pay nothing for media. */
static inline void nf_tile_medium_density(const nf_tile *tile, float eps, const float (*z)[NF_TILE],
                                          float *q)
{
    for (uint32_t i = 0; i < NF_TILE; ++i) {
        float zi[2] = {z[0][i], z[1][i]}, w[3];
        float sin_theta = nf_maxf(nf_from_square(zi, w), NF_SIN_THETA_MIN);
        float cn =
            tile->normal[0][i] * w[0] + tile->normal[1][i] * w[1] + tile->normal[2][i] * w[2];
        float cd = tile->axis[0][i] * w[0] + tile->axis[1][i] * w[1] + tile->axis[2][i] * w[2];
        float lobe =
            tile->medium[i] ? nf_hg_lobe(cd, tile->phase_g[i], eps) : nf_cosine_lobe(cn, eps);
        q[i] = sin_theta * lobe;
    }
}

/* The cosine prior's latent points for a tile with lanes in a medium: the cosine, phase and
 * uniform components for every lane, then selects, as nf_tile_prior_sample. */
static inline void nf_tile_medium_sample(const nf_tile *tile, float eps, const float *u0,
                                         const float *u1, float (*z)[NF_TILE])
{
    for (uint32_t i = 0; i < NF_TILE; ++i) {
        float n[3] = {tile->normal[0][i], tile->normal[1][i], tile->normal[2][i]};
        float d[3] = {tile->axis[0][i], tile->axis[1][i], tile->axis[2][i]};
        float uc = nf_clamp_unit(u0[i] / (1.0f - eps));
        float wc[3], wh[3], w[3], zl[2], zu[2];
        nf_cosine_direction(n, uc, u1[i], wc);
        nf_hg_direction(d, tile->phase_g[i], uc, u1[i], wh);
        for (int a = 0; a < 3; ++a)
            w[a] = tile->medium[i] ? wh[a] : wc[a];
        nf_to_square(w, zl);
        nf_uniform_sphere_square(nf_clamp_unit((u0[i] - (1.0f - eps)) / eps), u1[i], zu);
        int lobe = u0[i] < 1.0f - eps;
        z[0][i] = lobe ? zl[0] : zu[0];
        z[1][i] = lobe ? zl[1] : zu[1];
    }
}

/* The prior's density q_s(z) on the square for every lane. */
static inline nf_status nf_tile_prior_density(const nf_model *m, const nf_tile *tile,
                                              const float (*z)[NF_TILE], float *q)
{
    const float eps = m->cfg.prior_epsilon;
    switch (m->cfg.prior) {
    case NF_PRIOR_UNIFORM_ANGLE:
        for (uint32_t i = 0; i < NF_TILE; ++i)
            q[i] = 1.0f;
        return NF_OK;
    case NF_PRIOR_UNIFORM_DIRECTION:
        for (uint32_t i = 0; i < NF_TILE; ++i) {
            float zi[2] = {z[0][i], z[1][i]}, w[3];
            q[i] = NF_HALF_PI * nf_maxf(nf_from_square(zi, w), NF_SIN_THETA_MIN);
        }
        return NF_OK;
    case NF_PRIOR_COSINE:
        /* as nf_prior_density: q_s = sin(theta) ((1 - eps) 2 pi max(0, n.w) + eps pi / 2) */
        if (tile->media) {
            nf_tile_medium_density(tile, eps, z, q);
            return NF_OK;
        }
        for (uint32_t i = 0; i < NF_TILE; ++i) {
            float zi[2] = {z[0][i], z[1][i]}, w[3];
            float sin_theta = nf_maxf(nf_from_square(zi, w), NF_SIN_THETA_MIN);
            float c =
                tile->normal[0][i] * w[0] + tile->normal[1][i] * w[1] + tile->normal[2][i] * w[2];
            q[i] = sin_theta * nf_cosine_lobe(c, eps);
        }
        return NF_OK;
    case NF_PRIOR_CUSTOM: break;
    }
    for (uint32_t i = 0; i < tile->count; ++i) {
        nf_prior_point pt;
        float zi[2] = {z[0][i], z[1][i]};
        nf_tile_point(tile, i, &pt);
        nf_status st = nf_prior_density(m, &pt, zi, &q[i], NULL);
        if (st != NF_OK)
            return st;
    }
    for (uint32_t i = tile->count; i < NF_TILE; ++i)
        q[i] = q[0];
    return NF_OK;
}

/* Latent points z[.][lane] and their densities q[lane] from u, as nf_prior_sample. */
static inline nf_status nf_tile_prior_sample(const nf_model *m, const nf_tile *tile,
                                             const float *u0_in, const float *u1_in,
                                             float (*z)[NF_TILE], float *q)
{
    const float eps = m->cfg.prior_epsilon;
    float u0[NF_TILE], u1[NF_TILE];
    for (uint32_t i = 0; i < NF_TILE; ++i) {
        u0[i] = nf_clamp_unit(u0_in[i]);
        u1[i] = nf_clamp_unit(u1_in[i]);
    }
    switch (m->cfg.prior) {
    case NF_PRIOR_UNIFORM_ANGLE:
        for (uint32_t i = 0; i < NF_TILE; ++i) {
            z[0][i] = u0[i];
            z[1][i] = u1[i];
        }
        break;
    case NF_PRIOR_UNIFORM_DIRECTION:
        for (uint32_t i = 0; i < NF_TILE; ++i) {
            float zi[2];
            nf_uniform_sphere_square(u0[i], u1[i], zi);
            z[0][i] = zi[0];
            z[1][i] = zi[1];
        }
        break;
    case NF_PRIOR_COSINE:
        if (tile->media) {
            nf_tile_medium_sample(tile, eps, u0, u1, z);
            break;
        }
        /* Both mixture components for every lane, then a select: a branch per lane would
         * keep the loop from vectorizing. The component picked is nf_prior_sample's. */
        for (uint32_t i = 0; i < NF_TILE; ++i) {
            float n[3] = {tile->normal[0][i], tile->normal[1][i], tile->normal[2][i]};
            float w[3], zc[2], zu[2];
            nf_cosine_direction(n, nf_clamp_unit(u0[i] / (1.0f - eps)), u1[i], w);
            nf_to_square(w, zc);
            nf_uniform_sphere_square(nf_clamp_unit((u0[i] - (1.0f - eps)) / eps), u1[i], zu);
            int cosine = u0[i] < 1.0f - eps;
            z[0][i] = cosine ? zc[0] : zu[0];
            z[1][i] = cosine ? zc[1] : zu[1];
        }
        break;
    case NF_PRIOR_CUSTOM: return nf_tile_custom_sample(m, tile, u0, u1, z, q);
    }
    return nf_tile_prior_density(m, tile, (const float(*)[NF_TILE])z, q);
}

#endif /* NISFLOW_KERNELS_PRIOR_TILE_H */
