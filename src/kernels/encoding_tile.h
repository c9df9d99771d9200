/*
 * encoding_tile.h - the conditioner's input encodings (docs/theory.md section 5) for a tile of
 * samples: encoding.h's one-blob slots and spherical harmonics with the lanes innermost, so
 * that the loops vectorize across samples and give the same bits per lane.
 */
#ifndef NISFLOW_KERNELS_ENCODING_TILE_H
#define NISFLOW_KERNELS_ENCODING_TILE_H

#include "encoding.h"
#include "internal.h"
#include "lanes.h"

/* The one-blob encoding of one scalar per lane as the three slots of nf_oneblob_slots. */
typedef struct nf_tile_blob {
    uint32_t row[3][NF_TILE]; /* row of the input layer's weights (encoding offset added) */
    float value[3][NF_TILE];
} nf_tile_blob;

/* nf_tile_oneblob with `wrap` (a coordinate on the circle, nf_oneblob_bin): every slot is
 * inside, beyond either end at the other. A loop of its own, so that the interval form's
 * loop stays as simple as it was (a select on a run-time flag there cost 12% of nf_sample). */
static inline void nf_tile_oneblob_wrapped(const float *v, uint32_t bins, uint32_t row_offset,
                                           nf_tile_blob *out)
{
    for (uint32_t c = 0; c < 3; ++c)
        for (uint32_t i = 0; i < NF_TILE; ++i) {
            float vb = nf_clampf(v[i], 0.0f, 1.0f) * (float)bins;
            int j = (int)vb - 1 + (int)c;
            int bin = nf_oneblob_bin(j, bins, 1);
            float hi = (float)(j + 1) - vb, lo = (float)j - vb;
            out->row[c][i] = row_offset + (uint32_t)bin;
            out->value[c][i] = nf_quartic_cdf(hi) - nf_quartic_cdf(lo);
        }
}

/* The one-blob of v[lane] (clamped to [0,1]) with B bins; rows are offset by row_offset;
 * `wrap` as in nf_oneblob_slots. */
static inline void nf_tile_oneblob(const float *v, uint32_t bins, uint32_t row_offset, int wrap,
                                   nf_tile_blob *out)
{
    if (wrap) {
        nf_tile_oneblob_wrapped(v, bins, row_offset, out);
        return;
    }
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
static inline void nf_tile_oneblob_slopes(const float *v, uint32_t bins, int wrap,
                                          float (*slope)[NF_TILE])
{
    for (uint32_t c = 0; c < 3; ++c)
        for (uint32_t i = 0; i < NF_TILE; ++i) {
            float vb = nf_clampf(v[i], 0.0f, 1.0f) * (float)bins;
            int j = (int)vb - 1 + (int)c;
            int inside = wrap | ((j >= 0) & (j < (int)bins));
            float hi = (float)(j + 1) - vb, lo = (float)j - vb;
            float d = (float)bins * (nf_quartic_kernel(lo) - nf_quartic_kernel(hi));
            slope[c][i] = inside ? d : 0.0f;
        }
}

/* Real SH of the unit vectors d[.][i] into out[row][i] (S^2 rows). */
static inline void nf_tile_sh(const float (*d)[NF_TILE], uint32_t bands, float (*out)[NF_TILE])
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

#endif /* NISFLOW_KERNELS_ENCODING_TILE_H */
