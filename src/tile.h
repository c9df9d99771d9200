/*
 * tile.h - a tile of up to NF_TILE samples in structure-of-arrays layout, the unit of work of
 * the batch kernels (kernel.c), and its shading-point features (SPEC section 5).
 *
 * Element [q][i] of a tile array is quantity q of sample (lane) i, so every loop over the
 * lanes of a tile is a loop over contiguous floats that the compiler vectorizes across
 * samples, whatever the bin counts and widths of the model. Lanes beyond the tile's sample
 * count repeat sample 0: they compute finite values that are never stored, and no callback
 * is ever made for them.
 */
#ifndef NISFLOW_TILE_H
#define NISFLOW_TILE_H

#include "conditioner.h"
#include "encoding.h"
#include "internal.h"

/* 16 lanes: one AVX-512 register of floats, two AVX2 ones. */
#define NF_TILE 16u
_Static_assert(NF_TILE == 16, "lanes.h holds 16 floats per tile");

/* The one-blob encoding of one scalar per lane as the three slots of nf_oneblob_slots. */
typedef struct nf_tile_blob {
    uint32_t row[3][NF_TILE]; /* row of the input layer's weights (encoding offset added) */
    float value[3][NF_TILE];
} nf_tile_blob;

/* The shading points of a tile: everything the conditioners share across layers. */
typedef struct nf_tile {
    uint32_t count;                     /* real samples, 1..NF_TILE                       */
    const nf_context *user[NF_TILE];    /* the caller's contexts, for custom priors       */
    const nf_prior_callbacks *prior;    /* the model's custom prior callbacks             */
    float normal[3][NF_TILE];           /* unit normals                                   */
    nf_tile_blob position[3];           /* one-blob of each position axis                 */
    float sh[2 * NF_MAX_SH][NF_TILE];   /* SH of the normal (S^2 rows), then of wo        */
} nf_tile;

/* The one-blob of v[lane] (clamped to [0,1]) with B bins; rows are offset by row_offset. */
static inline void nf_tile_oneblob(const float *v, uint32_t bins, uint32_t row_offset,
                                   nf_tile_blob *out)
{
    /* nf_oneblob_slots' arithmetic with the slot loop outermost, so that the lane loops
     * vectorize; the results are the same bits. */
    for (uint32_t c = 0; c < 3; ++c)
        for (uint32_t i = 0; i < NF_TILE; ++i) {
            float vb = nf_clampf(v[i], 0.0f, 1.0f) * (float)bins;
            int j = (int)vb - 1 + (int)c;
            int inside = (j >= 0) & (j < (int)bins);
            float hi = (float)(j + 1) - vb, lo = (float)j - vb;
            float q = nf_quartic_cdf(hi) - nf_quartic_cdf(lo);
            out->row[c][i] = row_offset + (uint32_t)(inside ? j : 0);
            out->value[c][i] = inside ? q : 0.0f;
        }
}

/* d value / d v of the three slots of nf_tile_oneblob (0 for a slot outside the encoding), as
 * nf_oneblob_sparse's dvalue, for the reverse pass. */
static inline void nf_tile_oneblob_slopes(const float *v, uint32_t bins, float (*slope)[NF_TILE])
{
    for (uint32_t c = 0; c < 3; ++c)
        for (uint32_t i = 0; i < NF_TILE; ++i) {
            float vb = nf_clampf(v[i], 0.0f, 1.0f) * (float)bins;
            int j = (int)vb - 1 + (int)c;
            int inside = (j >= 0) & (j < (int)bins);
            float hi = (float)(j + 1) - vb, lo = (float)j - vb;
            float d = (float)bins * (nf_quartic_kernel(lo) - nf_quartic_kernel(hi));
            slope[c][i] = inside ? d : 0.0f;
        }
}

/* Real SH of the unit vectors d[.][i] into out[row][i] (S^2 rows). */
static inline void nf_tile_sh(const float (*d)[NF_TILE], uint32_t bands,
                              float (*out)[NF_TILE])
{
    float v[16][NF_TILE];
    for (uint32_t i = 0; i < NF_TILE; ++i) {
        float lane[16];
        nf_sh4(d[0][i], d[1][i], d[2][i], lane);
        for (uint32_t k = 0; k < 16; ++k)
            v[k][i] = lane[k];
    }
    uint32_t count = bands < 4 ? bands * bands : 16;
    for (uint32_t k = 0; k < count; ++k)
        for (uint32_t i = 0; i < NF_TILE; ++i)
            out[k][i] = v[k][i];
    if (bands > 4) {
        /* Bands 5 and 6 take the general recurrence, one lane at a time; the first 16 values
         * stay nf_sh4's (the recurrence's agree with them to float rounding). */
        for (uint32_t i = 0; i < NF_TILE; ++i) {
            float dir[3] = {d[0][i], d[1][i], d[2][i]}, all[NF_MAX_SH];
            nf_sh_recurrence(dir, bands, all);
            for (uint32_t k = 16; k < bands * bands; ++k)
                out[k][i] = all[k];
        }
    }
}

/* Loads the contexts *ctx[0..count) (count in 1..NF_TILE, inputs validated) into a tile. The
 * pointers are kept for custom prior callbacks, which receive the caller's own context. */
static inline void nf_tile_prepare_from(const nf_model *m, const nf_context *const *ctx,
                                        uint32_t count, nf_tile *tile)
{
    const nf_config *cfg = &m->cfg;
    float position[3][NF_TILE], normal[3][NF_TILE], wo[3][NF_TILE];
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
    }
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
        nf_tile_oneblob(t, cfg->oneblob_bins, (a + 1) * cfg->oneblob_bins, &tile->position[a]);
    }
    uint32_t sh = cfg->sh_bands * cfg->sh_bands;
    if (sh) {
        nf_tile_sh((const float(*)[NF_TILE])tile->normal, cfg->sh_bands, tile->sh);
        nf_tile_sh((const float(*)[NF_TILE])wo, cfg->sh_bands, tile->sh + sh);
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

#endif /* NISFLOW_TILE_H */
