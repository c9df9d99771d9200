/*
 * tile_conditioner.h - the conditioner MLPs (SPEC sections 4-5) for a tile of samples.
 *
 * The input layer runs per sample: its one-blob rows differ from sample to sample, so it
 * gathers weight rows (input-major, NF_CHUNK outputs per vector) as conditioner.h does. Its
 * activations are then transposed into the tile layout, where the remaining layers are dense
 * products whose loops run across the lanes, with one broadcast weight per step.
 */
#ifndef NISFLOW_TILE_CONDITIONER_H
#define NISFLOW_TILE_CONDITIONER_H

#include "internal.h"
#include "lanes.h"
#include "tile.h"

/* Hidden activations of one conditioner for a tile, [unit][lane] after the ReLU; hidden
 * layer l lives in act[l % 2], since each layer reads only the one before it. 16 KiB. */
typedef struct nf_tile_act {
    float act[2][NF_MAX_HIDDEN_WIDTH][NF_TILE];
} nf_tile_act;

/* The first hidden layer of layer `layer`'s conditioner, with `vblob` the one-blob of the
 * pass-through coordinate, into out[unit][lane] (ReLU applied). One sample at a time, NF_CHUNK
 * units per vector; four accumulators (summed at the end) keep four FMA chains in flight. */
static inline void nf_tile_input_layer(const nf_model *m, uint32_t layer, const nf_tile *tile,
                                       const nf_tile_blob *vblob, float (*out)[NF_TILE])
{
    _Static_assert(NF_CHUNK == 16, "nf_lanes holds one chunk of units");
    const nf_linear *lin = &m->packed_linear[layer][0];
    const float *w = m->packed + lin->weight, *bias = m->packed + lin->bias;
    const uint32_t hp = lin->stride, width = m->cfg.hidden_width;
    const float *wd = w + (size_t)4u * m->cfg.oneblob_bins * hp; /* the SH rows */
    const uint32_t dense = 2u * m->cfg.sh_bands * m->cfg.sh_bands;
    for (uint32_t i = 0; i < tile->count; ++i) {
        float act[NF_PAD(NF_MAX_HIDDEN_WIDTH)];
        for (uint32_t c = 0; c < hp; c += NF_CHUNK) {
            nf_lanes a0, a1, a2, a3, row;
            nf_lanes_load(&a0, bias + c);
            nf_lanes_splat(&a1, 0.0f);
            nf_lanes_splat(&a2, 0.0f);
            nf_lanes_splat(&a3, 0.0f);
            /* one-blob slots: three for v, three per position axis */
            for (uint32_t s = 0; s < 3; ++s) {
                nf_lanes_load(&row, w + (size_t)vblob->row[s][i] * hp + c);
                nf_lanes_madd(&a0, vblob->value[s][i], &row);
                nf_lanes_load(&row, w + (size_t)tile->position[0].row[s][i] * hp + c);
                nf_lanes_madd(&a1, tile->position[0].value[s][i], &row);
                nf_lanes_load(&row, w + (size_t)tile->position[1].row[s][i] * hp + c);
                nf_lanes_madd(&a2, tile->position[1].value[s][i], &row);
                nf_lanes_load(&row, w + (size_t)tile->position[2].row[s][i] * hp + c);
                nf_lanes_madd(&a3, tile->position[2].value[s][i], &row);
            }
            uint32_t k = 0;
            for (; k + 4 <= dense; k += 4) {
                const float *wk = wd + (size_t)k * hp + c;
                nf_lanes_load(&row, wk);
                nf_lanes_madd(&a0, tile->sh[k][i], &row);
                nf_lanes_load(&row, wk + hp);
                nf_lanes_madd(&a1, tile->sh[k + 1][i], &row);
                nf_lanes_load(&row, wk + 2 * hp);
                nf_lanes_madd(&a2, tile->sh[k + 2][i], &row);
                nf_lanes_load(&row, wk + 3 * hp);
                nf_lanes_madd(&a3, tile->sh[k + 3][i], &row);
            }
            for (; k < dense; ++k) {
                nf_lanes_load(&row, wd + (size_t)k * hp + c);
                nf_lanes_madd(&a0, tile->sh[k][i], &row);
            }
            nf_lanes_add(&a0, &a1);
            nf_lanes_add(&a2, &a3);
            nf_lanes_add(&a0, &a2);
            nf_lanes_store(act + c, &a0);
        }
        for (uint32_t j = 0; j < width; ++j)
            out[j][i] = nf_maxf(act[j], 0.0f);
    }
    for (uint32_t j = 0; j < width; ++j)
        for (uint32_t i = tile->count; i < NF_TILE; ++i)
            out[j][i] = out[j][0];
}

/* out[r][lane] = bias[r] + sum_k w[k][r] in[k][lane] for r < outputs; ReLU if relu. Four
 * outputs at a time share each input row and give the FMA unit four independent chains; out
 * needs room for outputs rounded up to 4 rows (w and bias are padded to NF_CHUNK columns). */
static inline void nf_tile_dense_layer(const float *w, uint32_t stride, const float *bias,
                                       uint32_t inputs, uint32_t outputs,
                                       const float (*in)[NF_TILE], float (*out)[NF_TILE],
                                       int relu)
{
    for (uint32_t r = 0; r < outputs; r += 4) {
        /* Named accumulators: an array of them would be kept in memory. */
        nf_lanes a0, a1, a2, a3, x;
        nf_lanes_splat(&a0, bias[r]);
        nf_lanes_splat(&a1, bias[r + 1]);
        nf_lanes_splat(&a2, bias[r + 2]);
        nf_lanes_splat(&a3, bias[r + 3]);
        for (uint32_t k = 0; k < inputs; ++k) {
            const float *wk = w + (size_t)k * stride + r;
            nf_lanes_load(&x, in[k]);
            nf_lanes_madd(&a0, wk[0], &x);
            nf_lanes_madd(&a1, wk[1], &x);
            nf_lanes_madd(&a2, wk[2], &x);
            nf_lanes_madd(&a3, wk[3], &x);
        }
        nf_lanes_store(out[r], &a0);
        nf_lanes_store(out[r + 1], &a1);
        nf_lanes_store(out[r + 2], &a2);
        nf_lanes_store(out[r + 3], &a3);
    }
    if (relu)
        for (uint32_t r = 0; r < outputs; ++r)
            for (uint32_t i = 0; i < NF_TILE; ++i)
                out[r][i] = nf_maxf(out[r][i], 0.0f);
}

/* Raw spline parameters raw[r][lane] (r < 3K+1) of coupling layer `layer` for the tile, from
 * the one-blob of the pass-through coordinate; the hidden activations go to `act`. Raw values
 * are clamped to +-NF_RAW_LIMIT as in nf_conditioner_forward. */
static inline void nf_tile_conditioner_forward(const nf_model *m, uint32_t layer,
                                               const nf_tile *tile, const nf_tile_blob *vblob,
                                               nf_tile_act *act, float (*raw)[NF_TILE])
{
    const nf_linear *lin = m->packed_linear[layer];
    const float *packed = m->packed;
    const uint32_t depth = m->cfg.hidden_layers, width = m->cfg.hidden_width;
    nf_tile_input_layer(m, layer, tile, vblob, act->act[0]);
    for (uint32_t l = 1; l < depth; ++l)
        nf_tile_dense_layer(packed + lin[l].weight, lin[l].stride, packed + lin[l].bias, width,
                            width, (const float(*)[NF_TILE])act->act[(l - 1) % 2],
                            act->act[l % 2], 1);
    nf_tile_dense_layer(packed + lin[depth].weight, lin[depth].stride,
                        packed + lin[depth].bias, width, m->raw_dim,
                        (const float(*)[NF_TILE])act->act[(depth - 1) % 2], raw, 0);
    for (uint32_t r = 0; r < m->raw_dim; ++r)
        for (uint32_t i = 0; i < NF_TILE; ++i)
            raw[r][i] = nf_clampf(raw[r][i], -NF_RAW_LIMIT, NF_RAW_LIMIT);
}

#endif /* NISFLOW_TILE_CONDITIONER_H */
