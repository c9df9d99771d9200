/*
 * conditioner_tile.h - the conditioner MLPs (docs/theory.md sections 4-5) for a tile of samples.
 *
 * The input layer runs per sample: its one-blob rows differ from sample to sample, so it
 * gathers weight rows (input-major, NF_CHUNK outputs per vector) as conditioner.h does. Its
 * activations are then transposed into the tile layout, where the remaining layers are dense
 * products whose loops run across the lanes, with one broadcast weight per step.
 */
#ifndef NISFLOW_KERNELS_CONDITIONER_TILE_H
#define NISFLOW_KERNELS_CONDITIONER_TILE_H

#include <string.h>

#include "internal.h"
#include "lanes.h"
#include "tile.h"

/* Room for the hidden activations of a tile: `slots` hidden layers of at most
 * NF_PAD(NF_MAX_HIDDEN_WIDTH) units, [unit][lane]. Sampling and densities keep two slots (each
 * layer reads only the one before it, 16 KiB); the gradient keeps every hidden layer of one
 * conditioner for its reverse pass. */
#define NF_TILE_ACT_ROWS(slots) ((slots)*NF_PAD(NF_MAX_HIDDEN_WIDTH))

/* The first hidden layer of layer `layer`'s conditioner, with `vblob` the one-blob of the
 * pass-through coordinate, into out[unit][lane] (ReLU applied; rows up to the padded width
 * are written, the padding ones zero). One sample at a time through nf_input_layer_context and
 * nf_input_layer_blob, the same
 * arithmetic as the per-sample kernels, then transposed into the tile layout. */
static inline void nf_tile_input_layer(const nf_model *m, uint32_t layer, const nf_tile *tile,
                                       const nf_tile_blob *vblob, float (*out)[NF_TILE])
{
    const nf_linear *lin = &m->packed_linear[layer][0];
    const float *w = m->packed + lin->weight, *bias = m->packed + lin->bias;
    const uint32_t hp = lin->stride;
    const float *wd = w + (size_t)4u * m->cfg.oneblob_bins * hp; /* the SH rows */
    const uint32_t dense = 2u * m->cfg.sh_bands * m->cfg.sh_bands;
    /* sample-major, in blocks of NF_CHUNK units: act[chunk][lane][unit] */
    float act[NF_PAD(NF_MAX_HIDDEN_WIDTH) / NF_CHUNK][NF_TILE][NF_CHUNK];
    float one[NF_PAD(NF_MAX_HIDDEN_WIDTH)];
    for (uint32_t i = 0; i < tile->count; ++i) {
        uint32_t rows[9], vrows[3];
        float vals[9], vvals[3];
        for (uint32_t s = 0; s < 3; ++s) {
            vrows[s] = vblob->row[s][i];
            vvals[s] = vblob->value[s][i];
            for (uint32_t a = 0; a < 3; ++a) {
                rows[3 * a + s] = tile->position[a].row[s][i];
                vals[3 * a + s] = tile->position[a].value[s][i];
            }
        }
        nf_input_layer_context(w, bias, hp, rows, vals, wd, &tile->sh[0][i], NF_TILE, dense, one);
        nf_input_layer_blob(one, w, hp, vrows, vvals, one);
        for (uint32_t c = 0; c < hp; c += NF_CHUNK)
            memcpy(act[c / NF_CHUNK][i], one + c, sizeof act[0][0]);
    }
    for (uint32_t c = 0; c < hp / NF_CHUNK; ++c) {
        for (uint32_t i = tile->count; i < NF_TILE; ++i)
            memcpy(act[c][i], act[c][0], sizeof act[c][i]);
        /* a fixed-size 16 x 16 transpose, which the compiler turns into vector permutes */
        const float(*block)[NF_CHUNK] = (const float(*)[NF_CHUNK])act[c];
        float(*dst)[NF_TILE] = out + c * NF_CHUNK;
        for (uint32_t j = 0; j < NF_CHUNK; ++j)
            for (uint32_t i = 0; i < NF_TILE; ++i)
                dst[j][i] = nf_maxf(block[i][j], 0.0f);
    }
}

/* out[r][lane] = bias[r] + sum_k w[k in_stride + r out_stride] in[k][lane] for r < outputs
 * (bias NULL: no bias); ReLU if relu. The forward passes read the packed weights W[k][r]
 * (out_stride 1); the reverse pass reads the same matrix transposed (in_stride 1). Eight
 * outputs at a time share each input row and give the CPU eight independent multiply-add
 * chains to overlap (each step waits on the previous one's latency); the last outputs % 8 go
 * one at a time. */
static inline void nf_tile_dense_layer(const float *w, size_t in_stride, size_t out_stride,
                                       const float *bias, uint32_t inputs, uint32_t outputs,
                                       const float (*in)[NF_TILE], float (*out)[NF_TILE], int relu)
{
    uint32_t r = 0;
    for (; r + 8 <= outputs; r += 8) {
        /* Named accumulators: an array of them would be kept in memory. */
        nf_lanes a0, a1, a2, a3, a4, a5, a6, a7, x;
        const float *b = bias ? bias + r : NULL;
        nf_lanes_splat(&a0, b ? b[0] : 0.0f);
        nf_lanes_splat(&a1, b ? b[1] : 0.0f);
        nf_lanes_splat(&a2, b ? b[2] : 0.0f);
        nf_lanes_splat(&a3, b ? b[3] : 0.0f);
        nf_lanes_splat(&a4, b ? b[4] : 0.0f);
        nf_lanes_splat(&a5, b ? b[5] : 0.0f);
        nf_lanes_splat(&a6, b ? b[6] : 0.0f);
        nf_lanes_splat(&a7, b ? b[7] : 0.0f);
        for (uint32_t k = 0; k < inputs; ++k) {
            const float *wk = w + (size_t)k * in_stride + (size_t)r * out_stride;
            nf_lanes_load(&x, in[k]);
            nf_lanes_madd(&a0, wk[0], &x);
            nf_lanes_madd(&a1, wk[out_stride], &x);
            nf_lanes_madd(&a2, wk[2 * out_stride], &x);
            nf_lanes_madd(&a3, wk[3 * out_stride], &x);
            nf_lanes_madd(&a4, wk[4 * out_stride], &x);
            nf_lanes_madd(&a5, wk[5 * out_stride], &x);
            nf_lanes_madd(&a6, wk[6 * out_stride], &x);
            nf_lanes_madd(&a7, wk[7 * out_stride], &x);
        }
        nf_lanes_store(out[r], &a0);
        nf_lanes_store(out[r + 1], &a1);
        nf_lanes_store(out[r + 2], &a2);
        nf_lanes_store(out[r + 3], &a3);
        nf_lanes_store(out[r + 4], &a4);
        nf_lanes_store(out[r + 5], &a5);
        nf_lanes_store(out[r + 6], &a6);
        nf_lanes_store(out[r + 7], &a7);
    }
    for (; r < outputs; ++r) {
        nf_lanes a, x;
        nf_lanes_splat(&a, bias ? bias[r] : 0.0f);
        for (uint32_t k = 0; k < inputs; ++k) {
            nf_lanes_load(&x, in[k]);
            nf_lanes_madd(&a, w[(size_t)k * in_stride + (size_t)r * out_stride], &x);
        }
        nf_lanes_store(out[r], &a);
    }
    if (relu)
        for (uint32_t j = 0; j < outputs; ++j)
            for (uint32_t i = 0; i < NF_TILE; ++i)
                out[j][i] = nf_maxf(out[j][i], 0.0f);
}

/* Raw spline parameters raw[r][lane] (r < 3K+1; rows up to a multiple of 8 are written) of
 * coupling layer `layer` for the tile, from the one-blob of the pass-through coordinate.
 * Hidden layer l goes to act + (l % slots) hp rows, hp the padded width: slots = 2 keeps the
 * last two, slots = hidden_layers all of them. Raw values are clamped to +-NF_RAW_LIMIT as in
 * nf_conditioner_forward. */
static inline void nf_tile_conditioner_forward(const nf_model *m, uint32_t layer,
                                               const nf_tile *tile, const nf_tile_blob *vblob,
                                               float (*act)[NF_TILE], uint32_t slots,
                                               float (*raw)[NF_TILE])
{
    const nf_linear *lin = m->packed_linear[layer];
    const float *packed = m->packed;
    const uint32_t depth = m->cfg.hidden_layers, width = m->cfg.hidden_width;
    const uint32_t hp = lin[0].stride;
    nf_tile_input_layer(m, layer, tile, vblob, act);
    for (uint32_t l = 1; l < depth; ++l)
        nf_tile_dense_layer(packed + lin[l].weight, lin[l].stride, 1, packed + lin[l].bias, width,
                            width, (const float(*)[NF_TILE])(act + (l - 1) % slots * hp),
                            act + l % slots * hp, 1);
    /* All eight rows of the last group (the packed columns are zero-padded to NF_CHUNK, so
     * the extra rows are zeros): the raw rows stay on the eight-chain path, as before the
     * one-row tail existed, instead of ending with a row on a chain of its own. */
    nf_tile_dense_layer(packed + lin[depth].weight, lin[depth].stride, 1, packed + lin[depth].bias,
                        width, (m->raw_dim + 7u) / 8u * 8u,
                        (const float(*)[NF_TILE])(act + (depth - 1) % slots * hp), raw, 0);
    for (uint32_t r = 0; r < m->raw_dim; ++r)
        for (uint32_t i = 0; i < NF_TILE; ++i)
            raw[r][i] = nf_clampf(raw[r][i], -NF_RAW_LIMIT, NF_RAW_LIMIT);
}

#endif /* NISFLOW_KERNELS_CONDITIONER_TILE_H */
