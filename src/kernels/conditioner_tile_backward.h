/*
 * conditioner_tile_backward.h - reverse mode of the tile conditioners (conditioner_tile.h):
 * from d loss / d raw for every lane, the gradients of one coupling layer's MLP parameters
 * (added into the public layout) and d loss / d v, v the lane's pass-through coordinate.
 *
 * Gradients with respect to activations stay in the tile layout ([unit][lane]) and are dense
 * products with the transposed weights (nf_tile_dense_layer). Weight gradients are sums over
 * the lanes of outer products; they run on a lane-major copy of the output gradient
 * (gt[lane][unit]), 16 outputs per vector, so that one broadcast activation multiplies a whole
 * row. The one-blob rows of the input layer differ per sample and are added lane by lane.
 */
#ifndef NISFLOW_KERNELS_CONDITIONER_TILE_BACKWARD_H
#define NISFLOW_KERNELS_CONDITIONER_TILE_BACKWARD_H

#include "conditioner.h"
#include "lanes.h"
#include "conditioner_tile.h"

/* Columns of a lane-major gradient: the widest of an output layer and a hidden layer. */
#define NF_TILE_GT_COLUMNS                                                                         \
    (NF_MAX_RAW_PADDED > NF_PAD(NF_MAX_HIDDEN_WIDTH) ? NF_MAX_RAW_PADDED                           \
                                                     : NF_PAD(NF_MAX_HIDDEN_WIDTH))

/* Scratch of the reverse pass, about 30 KiB. */
typedef struct nf_tile_backward_work {
    float g_act[NF_PAD(NF_MAX_HIDDEN_WIDTH)][NF_TILE]; /* d loss / d activation            */
    float g_pre[NF_PAD(NF_MAX_HIDDEN_WIDTH)][NF_TILE]; /* the same before the ReLU        */
    float gt[NF_TILE][NF_TILE_GT_COLUMNS];             /* lane-major copy of a gradient   */
} nf_tile_backward_work;

/* A row of ones: its "outer product" with a gradient is the bias gradient, the sum over the
 * lanes. */
static const float nf_tile_ones[1][NF_TILE] = {{1.0f, 1.0f, 1.0f, 1.0f, 1.0f, 1.0f, 1.0f, 1.0f,
                                                1.0f, 1.0f, 1.0f, 1.0f, 1.0f, 1.0f, 1.0f, 1.0f}};

/* gt[lane][r] = g[r][lane] for r < rows, and 0 up to the next multiple of NF_CHUNK. */
static inline void nf_tile_to_lane_major(const float (*g)[NF_TILE], uint32_t rows,
                                         float (*gt)[NF_TILE_GT_COLUMNS])
{
    for (uint32_t r = 0; r < rows; ++r)
        for (uint32_t i = 0; i < NF_TILE; ++i)
            gt[i][r] = g[r][i];
    for (uint32_t r = rows; r < NF_PAD(rows); ++r)
        for (uint32_t i = 0; i < NF_TILE; ++i)
            gt[i][r] = 0.0f;
}

/* dst[i dst_stride + j] += sum over lanes of a[i][lane] gt[lane][j], for i < rows and j < cols
 * (cols <= the padded columns of gt): a weight gradient summed over the tile's samples. Eight
 * rows at a time share each load of gt and keep eight multiply-add chains in flight. */
static inline void nf_tile_outer_add(const float (*a)[NF_TILE], uint32_t rows,
                                     const float (*gt)[NF_TILE_GT_COLUMNS], uint32_t cols,
                                     float *dst, size_t dst_stride)
{
    for (uint32_t c = 0; c < cols; c += NF_CHUNK) {
        const uint32_t n = cols - c < NF_CHUNK ? cols - c : NF_CHUNK;
        float sum[8][NF_CHUNK];
        uint32_t i = 0;
        for (; i + 8 <= rows; i += 8) {
            nf_lanes s0, s1, s2, s3, s4, s5, s6, s7, x;
            nf_lanes_splat(&s0, 0.0f);
            nf_lanes_splat(&s1, 0.0f);
            nf_lanes_splat(&s2, 0.0f);
            nf_lanes_splat(&s3, 0.0f);
            nf_lanes_splat(&s4, 0.0f);
            nf_lanes_splat(&s5, 0.0f);
            nf_lanes_splat(&s6, 0.0f);
            nf_lanes_splat(&s7, 0.0f);
            for (uint32_t l = 0; l < NF_TILE; ++l) {
                nf_lanes_load(&x, gt[l] + c);
                nf_lanes_madd(&s0, a[i][l], &x);
                nf_lanes_madd(&s1, a[i + 1][l], &x);
                nf_lanes_madd(&s2, a[i + 2][l], &x);
                nf_lanes_madd(&s3, a[i + 3][l], &x);
                nf_lanes_madd(&s4, a[i + 4][l], &x);
                nf_lanes_madd(&s5, a[i + 5][l], &x);
                nf_lanes_madd(&s6, a[i + 6][l], &x);
                nf_lanes_madd(&s7, a[i + 7][l], &x);
            }
            nf_lanes_store(sum[0], &s0);
            nf_lanes_store(sum[1], &s1);
            nf_lanes_store(sum[2], &s2);
            nf_lanes_store(sum[3], &s3);
            nf_lanes_store(sum[4], &s4);
            nf_lanes_store(sum[5], &s5);
            nf_lanes_store(sum[6], &s6);
            nf_lanes_store(sum[7], &s7);
            for (uint32_t q = 0; q < 8; ++q)
                for (uint32_t j = 0; j < n; ++j)
                    dst[(size_t)(i + q) * dst_stride + c + j] += sum[q][j];
        }
        for (; i < rows; ++i) {
            nf_lanes s, x;
            nf_lanes_splat(&s, 0.0f);
            for (uint32_t l = 0; l < NF_TILE; ++l) {
                nf_lanes_load(&x, gt[l] + c);
                nf_lanes_madd(&s, a[i][l], &x);
            }
            nf_lanes_store(sum[0], &s);
            for (uint32_t j = 0; j < n; ++j)
                dst[(size_t)i * dst_stride + c + j] += sum[0][j];
        }
    }
}

/* g_pre[j][lane] = act[j][lane] > 0 ? g_act[j][lane] : 0 for j < rows: through a ReLU whose
 * outputs were act. In the lanes type: GCC 12 left the plain loop scalar with a branch per
 * value, and at -O3 -mavx2 even computed it wrongly once written inline (26 of 256 values). */
static inline void nf_tile_relu_backward(const float (*act)[NF_TILE], const float (*g_act)[NF_TILE],
                                         uint32_t rows, float (*g_pre)[NF_TILE])
{
    for (uint32_t j = 0; j < rows; ++j) {
        nf_lanes g, a;
        nf_lanes_load(&g, g_act[j]);
        nf_lanes_load(&a, act[j]);
        nf_lanes_relu_backward(&g, &a);
        nf_lanes_store(g_pre[j], &g);
    }
}

/* One linear layer's parameter gradients from the lane-major gradient of its outputs (gt,
 * `outs` columns) and its inputs x[k][lane] (k < ins), into the public layout at `pub`. */
static inline void nf_tile_linear_backward(const nf_linear *pub, const float (*x)[NF_TILE],
                                           uint32_t ins, const float (*gt)[NF_TILE_GT_COLUMNS],
                                           uint32_t outs, float *grad)
{
    nf_tile_outer_add(nf_tile_ones, 1, gt, outs, grad + pub->bias, 0);
    nf_tile_outer_add(x, ins, gt, outs, grad + pub->weight, outs);
}

/* Reverse mode of nf_tile_conditioner_forward for coupling layer `layer`: act holds every
 * hidden layer (slots = hidden_layers), g_raw[r][lane] = d loss / d raw (rows < 3K+1), v the
 * pass-through coordinate per lane. Adds the parameter gradients of the tile's first `count`
 * lanes into grad (public layout; the other lanes must have zero g_raw) and writes
 * d loss / d v per lane into g_v. */
static inline void nf_tile_conditioner_backward(const nf_model *m, uint32_t layer,
                                                const nf_tile *tile, const float *v,
                                                const float (*act)[NF_TILE],
                                                const float (*g_raw)[NF_TILE], float *grad,
                                                float *g_v, nf_tile_backward_work *w)
{
    const nf_linear *pk = m->packed_linear[layer], *pub = m->linear[layer];
    const float *packed = m->packed;
    const uint32_t bins = m->cfg.oneblob_bins, depth = m->cfg.hidden_layers;
    const uint32_t width = m->cfg.hidden_width, hp = pk[0].stride, raw = m->raw_dim;
    const uint32_t dense = 2u * m->cfg.sh_bands * m->cfg.sh_bands;

    /* output layer: raw = W h + b */
    nf_tile_to_lane_major(g_raw, raw, w->gt);
    nf_tile_linear_backward(&pub[depth], act + (size_t)(depth - 1) * hp, width,
                            (const float(*)[NF_TILE_GT_COLUMNS])w->gt, raw, grad);
    nf_tile_dense_layer(packed + pk[depth].weight, 1, pk[depth].stride, NULL, raw, width, g_raw,
                        w->g_act, 0);

    /* hidden layers, last to first: h_l = relu(W h_{l-1} + b) */
    for (uint32_t l = depth; l-- > 0;) {
        const float(*out_act)[NF_TILE] = act + (size_t)l * hp;
        nf_tile_relu_backward(out_act, (const float(*)[NF_TILE])w->g_act, width, w->g_pre);
        nf_tile_to_lane_major((const float(*)[NF_TILE])w->g_pre, width, w->gt);
        if (l == 0)
            break;
        nf_tile_linear_backward(&pub[l], act + (size_t)(l - 1) * hp, width,
                                (const float(*)[NF_TILE_GT_COLUMNS])w->gt, width, grad);
        nf_tile_dense_layer(packed + pk[l].weight, 1, hp, NULL, width, width,
                            (const float(*)[NF_TILE])w->g_pre, w->g_act, 0);
    }

    /* input layer: the bias, the SH rows as a dense product, then the one-blob rows, which
     * differ per sample: only those were gathered, and only those receive gradient. */
    const float(*gt)[NF_TILE_GT_COLUMNS] = (const float(*)[NF_TILE_GT_COLUMNS])w->gt;
    float *gw = grad + pub[0].weight;
    nf_tile_outer_add(tile->sh, dense, gt, width, gw + (size_t)4u * bins * width, width);
    nf_tile_outer_add(nf_tile_ones, 1, gt, width, grad + pub[0].bias, 0);
    nf_tile_blob vblob;
    float slope[3][NF_TILE];
    const int wrap = nf_layer_wraps(m, layer);
    nf_tile_oneblob(v, bins, 0, wrap, &vblob);
    nf_tile_oneblob_slopes(v, bins, wrap, slope);
    const float *w0 = packed + pk[0].weight;
    float row[NF_PAD(NF_MAX_HIDDEN_WIDTH)];
    for (uint32_t i = 0; i < tile->count; ++i) {
        /* d/dv of the three slots' input sum_s value_s(v) W0[row_s] is sum_s slope_s W0[row_s]:
         * one row, then one dot product with the gradient, not three. */
        for (uint32_t j = 0; j < hp; ++j)
            row[j] = 0.0f;
        for (uint32_t s = 0; s < 3; ++s) {
            nf_axpy(gw + (size_t)vblob.row[s][i] * width, gt[i], vblob.value[s][i], width);
            nf_axpy(row, w0 + (size_t)vblob.row[s][i] * hp, slope[s][i], hp);
        }
        float gv = nf_dot_padded(row, gt[i], hp);
        for (uint32_t a = 0; a < 3; ++a)
            for (uint32_t s = 0; s < 3; ++s)
                nf_axpy(gw + (size_t)tile->position[a].row[s][i] * width, gt[i],
                        tile->position[a].value[s][i], width);
        g_v[i] = gv;
    }
    for (uint32_t i = tile->count; i < NF_TILE; ++i)
        g_v[i] = 0.0f;
}

#endif /* NISFLOW_KERNELS_CONDITIONER_TILE_BACKWARD_H */
