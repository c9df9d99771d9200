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
    for (uint32_t a = 0; a < 3; ++a)
        pt->normal[a] = tile->normal[a][i];
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
        for (uint32_t i = 0; i < NF_TILE; ++i) {
            float zi[2] = {z[0][i], z[1][i]}, w[3];
            float sin_theta = nf_maxf(nf_from_square(zi, w), NF_SIN_THETA_MIN);
            float c =
                tile->normal[0][i] * w[0] + tile->normal[1][i] * w[1] + tile->normal[2][i] * w[2];
            q[i] = sin_theta * ((1.0f - eps) * NF_TWO_PI * nf_maxf(c, 0.0f) + eps * NF_HALF_PI);
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
