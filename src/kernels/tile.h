/*
 * tile.h - a tile of up to NF_TILE samples in structure-of-arrays layout, the unit of work of
 * the batch kernels (kernel.c), and its shading-point features (docs/theory.md section 5,
 * encoded by encoding_tile.h).
 *
 * Element [q][i] of a tile array is quantity q of sample (lane) i, so every loop over the
 * lanes of a tile is a loop over contiguous floats that the compiler vectorizes across
 * samples, whatever the bin counts and widths of the model. Lanes beyond the tile's sample
 * count repeat sample 0: they compute finite values that are never stored, and no callback
 * is ever made for them.
 */
#ifndef NISFLOW_KERNELS_TILE_H
#define NISFLOW_KERNELS_TILE_H

#include "conditioner.h"
#include "encoding_tile.h"
#include "internal.h"

/* The shading points of a tile: everything the conditioners share across layers. */
typedef struct nf_tile {
    uint32_t count;                   /* real samples, 1..NF_TILE                       */
    const nf_context *user[NF_TILE];  /* the caller's contexts, for custom priors       */
    const nf_prior_callbacks *prior;  /* the model's custom prior callbacks             */
    float normal[3][NF_TILE];         /* unit normals; zero at points in a medium       */
    uint32_t media;                   /* lanes at points in a medium (0: arrays below unset) */
    uint32_t medium[NF_TILE];         /* 1 where the lane's point is in a medium        */
    float axis[3][NF_TILE];           /* in a medium: d = -wo / |wo|; else zero         */
    float phase_g[NF_TILE];           /* in a medium: the context's phase_g; else zero  */
    nf_tile_blob position[3];         /* one-blob of each position axis                 */
    float sh[2 * NF_MAX_SH][NF_TILE]; /* SH of the normal (S^2 rows), then of wo        */
} nf_tile;

/* Loads the contexts *ctx[0..count) (count in 1..NF_TILE, inputs validated) into a tile. The
 * pointers are kept for custom prior callbacks, which receive the caller's own context. */
static inline void nf_tile_prepare_from(const nf_model *m, const nf_context *const *ctx,
                                        uint32_t count, nf_tile *tile)
{
    const nf_config *cfg = &m->cfg;
    float position[3][NF_TILE], normal[3][NF_TILE], wo[3][NF_TILE];
    uint32_t media = 0;
    tile->count = count;
    tile->prior = &cfg->custom_prior;
    for (uint32_t i = 0; i < NF_TILE; ++i) {
        const nf_context *c = ctx[i < count ? i : 0];
        tile->user[i] = c;
        for (uint32_t a = 0; a < 3; ++a) {
            position[a][i] = c->position[a];
            normal[a][i] = c->normal[a];
            wo[a][i] = c->wo[a];
        }
        tile->medium[i] = (uint32_t)nf_context_in_medium(c);
        media += tile->medium[i];
    }
    tile->media = media;
    for (uint32_t i = 0; i < NF_TILE; ++i) {
        float n[3] = {normal[0][i], normal[1][i], normal[2][i]};
        float w[3] = {wo[0][i], wo[1][i], wo[2][i]};
        nf_normalize3(n, n);
        nf_normalize3(w, w);
        for (uint32_t a = 0; a < 3; ++a) {
            tile->normal[a][i] = n[a];
            wo[a][i] = w[a];
        }
    }
    for (uint32_t a = 0; a < 3; ++a) {
        float t[NF_TILE];
        float lo = cfg->bounds_min[a], extent = cfg->bounds_max[a] - cfg->bounds_min[a];
        for (uint32_t i = 0; i < NF_TILE; ++i)
            t[i] = (position[a][i] - lo) / extent;
        nf_tile_oneblob(t, cfg->oneblob_bins, (a + 1) * cfg->oneblob_bins, 0, &tile->position[a]);
    }
    if (media) {
        /* Points in a medium: the normal (0/0 above) becomes zero, the phase prior gets its
         * axis and g; surface lanes take g = 0 by a select, never their phase_g. */
        for (uint32_t i = 0; i < NF_TILE; ++i) {
            const nf_context *c = tile->user[i];
            uint32_t in = tile->medium[i];
            for (uint32_t a = 0; a < 3; ++a) {
                tile->normal[a][i] = in ? 0.0f : tile->normal[a][i];
                tile->axis[a][i] = in ? -wo[a][i] : 0.0f;
            }
            tile->phase_g[i] = in ? c->phase_g : 0.0f;
        }
    }
    uint32_t sh = cfg->sh_bands * cfg->sh_bands;
    if (sh) {
        nf_tile_sh((const float(*)[NF_TILE])tile->normal, cfg->sh_bands, tile->sh);
        nf_tile_sh((const float(*)[NF_TILE])wo, cfg->sh_bands, tile->sh + sh);
        /* A medium's normal block is all zeros, a value no unit normal's SH takes (its band 0
         * is a non-zero constant): the network can tell media from surfaces. */
        for (uint32_t k = 0; media && k < sh; ++k)
            for (uint32_t i = 0; i < NF_TILE; ++i)
                tile->sh[k][i] = tile->medium[i] ? 0.0f : tile->sh[k][i];
    }
}

/* Loads contexts ctx[0..count) (count in 1..NF_TILE, inputs validated) into a tile. */
static inline void nf_tile_prepare(const nf_model *m, const nf_context *ctx, uint32_t count,
                                   nf_tile *tile)
{
    const nf_context *each[NF_TILE];
    for (uint32_t i = 0; i < count; ++i)
        each[i] = &ctx[i];
    nf_tile_prepare_from(m, each, count, tile);
}

#endif /* NISFLOW_KERNELS_TILE_H */
