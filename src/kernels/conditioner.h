/*
 * conditioner.h - the per-layer MLPs that predict spline parameters (docs/theory.md sections 4-5)
 * as inline code for the kernels: shading-point features, forward pass and reverse mode.
 *
 * The input vector of layer i is [one-blob(v) | one-blob(position) | SH(normal) | SH(wo)].
 * One-blob parts have at most three non-zeros per scalar, so the input layer gathers those
 * weight rows instead of multiplying a dense vector. The forward pass reads the packed
 * weights (input-major, outputs padded to NF_CHUNK) and accumulates NF_CHUNK outputs at a
 * time in a fixed-size local array, which the compiler keeps in vector registers. Gradients
 * are written in the public (unpadded) parameter layout.
 */
#ifndef NISFLOW_KERNELS_CONDITIONER_H
#define NISFLOW_KERNELS_CONDITIONER_H

#include <math.h>

#include "circle.h"
#include "encoding.h"
#include "internal.h"
#include "lanes.h"

/* t of each position axis: where the position lies in the bounds, to be one-blob encoded (and
 * clamped to [0, 1] there). */
static inline float nf_position_unit(const nf_config *cfg, const nf_context *ctx, uint32_t a)
{
    return (ctx->position[a] - cfg->bounds_min[a]) / (cfg->bounds_max[a] - cfg->bounds_min[a]);
}

/* Every feature of nf_context_features but the position's one-blob slots (pt->rows and
 * pt->values, left unwritten): the unit normal and wo, their SH. */
static inline void nf_context_direction_features(const nf_model *m, const nf_context *ctx,
                                                 nf_point *pt)
{
    const nf_config *cfg = &m->cfg;
    pt->user = ctx;
    pt->prior = &cfg->custom_prior;
    pt->ctx.position[0] = ctx->position[0];
    pt->ctx.position[1] = ctx->position[1];
    pt->ctx.position[2] = ctx->position[2];
    /* A zero normal marks a point in a medium (nisflow/model.h): it stays zero, and phase_g
     * is taken there only, so that a surface's is never read. */
    const int medium = nf_context_in_medium(ctx);
    if (medium) {
        pt->ctx.normal[0] = pt->ctx.normal[1] = pt->ctx.normal[2] = 0.0f;
        pt->ctx.phase_g = ctx->phase_g;
    } else {
        nf_normalize3(ctx->normal, pt->ctx.normal);
        pt->ctx.phase_g = 0.0f;
    }
    nf_normalize3(ctx->wo, pt->ctx.wo);
    pt->row_count = 9;
    uint32_t sh = cfg->sh_bands * cfg->sh_bands;
    if (sh) {
        /* A medium's normal block is all zeros (as tile.h): no unit normal encodes so. */
        if (medium)
            memset(pt->sh, 0, sizeof(float) * sh);
        else
            nf_sh_unit(pt->ctx.normal, cfg->sh_bands, pt->sh);
        nf_sh_unit(pt->ctx.wo, cfg->sh_bands, pt->sh + sh);
    }
}

static inline void nf_context_features(const nf_model *m, const nf_context *ctx, nf_point *pt)
{
    const uint32_t bins = m->cfg.oneblob_bins;
    nf_context_direction_features(m, ctx, pt);
    /* three one-blob slots per axis (zero-valued where outside the encoding) */
    for (uint32_t a = 0; a < 3; ++a)
        nf_oneblob_slots(nf_position_unit(&m->cfg, ctx, a), bins, (a + 1) * bins, 0,
                         pt->rows + 3 * a, pt->values + 3 * a);
}

/* The prior's view of a point's features (prior.h): the unit normal on surfaces; in a medium
 * the propagation direction d = -wo and the phase function's g. */
static inline void nf_point_prior(const nf_point *pt, nf_prior_point *pp)
{
    pp->user = pt->user;
    pp->prior = pt->prior;
    pp->medium = (uint32_t)nf_context_in_medium(&pt->ctx);
    pp->g = pt->ctx.phase_g; /* zero on surfaces (nf_context_features) */
    for (uint32_t a = 0; a < 3; ++a) {
        pp->normal[a] = pt->ctx.normal[a];
        pp->axis[a] = pp->medium ? -pt->ctx.wo[a] : 0.0f;
    }
}

/* The context's share of the first hidden layer of one sample, before its ReLU:
 * ctx[0..hp) = bias + the 9 position one-blob slots (three per axis: rows/vals) +
 * sum_k sh[k * sh_stride] wd[k], k < dense (the SH inputs and their weight rows). hp is the
 * padded width. It depends on the shading context alone, so a shading point computes it once
 * per coupling layer (point.h) and each direction adds only the pass-through
 * coordinate's slots (nf_input_layer_blob). Four accumulators, one per position axis plus the
 * bias, each taking every fourth SH input, keep four multiply-add chains in flight. The tile,
 * per-sample and shading-point kernels all call this, so a sample's sums run in the same
 * order whichever path evaluates it. */
static inline void nf_input_layer_context_sums(const float *restrict w, const float *restrict bias,
                                               uint32_t hp, const uint32_t rows[9],
                                               const float vals[9], const float *restrict wd,
                                               const float *restrict sh, size_t sh_stride,
                                               uint32_t dense, float *restrict ctx)
{
    _Static_assert(NF_CHUNK == 16, "nf_lanes holds one chunk of units");
    for (uint32_t c = 0; c < hp; c += NF_CHUNK) {
        nf_lanes a0, a1, a2, a3, row;
        nf_lanes_load(&a0, bias + c);
        nf_lanes_splat(&a1, 0.0f);
        nf_lanes_splat(&a2, 0.0f);
        nf_lanes_splat(&a3, 0.0f);
        for (uint32_t s = 0; s < 3; ++s) {
            nf_lanes_load(&row, w + (size_t)rows[s] * hp + c);
            nf_lanes_madd(&a1, vals[s], &row);
            nf_lanes_load(&row, w + (size_t)rows[3 + s] * hp + c);
            nf_lanes_madd(&a2, vals[3 + s], &row);
            nf_lanes_load(&row, w + (size_t)rows[6 + s] * hp + c);
            nf_lanes_madd(&a3, vals[6 + s], &row);
        }
        uint32_t k = 0;
        for (; k + 4 <= dense; k += 4) {
            const float *wk = wd + (size_t)k * hp + c;
            nf_lanes_load(&row, wk);
            nf_lanes_madd(&a0, sh[k * sh_stride], &row);
            nf_lanes_load(&row, wk + hp);
            nf_lanes_madd(&a1, sh[(k + 1) * sh_stride], &row);
            nf_lanes_load(&row, wk + 2 * hp);
            nf_lanes_madd(&a2, sh[(k + 2) * sh_stride], &row);
            nf_lanes_load(&row, wk + 3 * hp);
            nf_lanes_madd(&a3, sh[(k + 3) * sh_stride], &row);
        }
        for (; k < dense; ++k) {
            nf_lanes_load(&row, wd + (size_t)k * hp + c);
            nf_lanes_madd(&a0, sh[k * sh_stride], &row);
        }
        nf_lanes_add(&a0, &a1);
        nf_lanes_add(&a2, &a3);
        nf_lanes_add(&a0, &a2);
        nf_lanes_store(ctx + c, &a0);
    }
}

static inline void nf_input_layer_context(const float *restrict w, const float *restrict bias,
                                          uint32_t hp, const uint32_t rows[9], const float vals[9],
                                          const float *restrict wd, const float *restrict sh,
                                          size_t sh_stride, uint32_t dense, float *restrict ctx)
{
    /* The presets' shape (16 units, 4 SH bands: 32 SH inputs) with constant bounds: the
     * compiler unrolls the loops and addresses the rows at fixed offsets, instead of keeping
     * loop counters and row pointers in registers it then spills. Same operations, same
     * order. */
    if (hp == NF_CHUNK && dense == 32)
        nf_input_layer_context_sums(w, bias, NF_CHUNK, rows, vals, wd, sh, sh_stride, 32, ctx);
    else
        nf_input_layer_context_sums(w, bias, hp, rows, vals, wd, sh, sh_stride, dense, ctx);
}

/* The first hidden layer before its ReLU: act = ctx + the pass-through coordinate's three
 * one-blob slots (rows/vals, rows of the input layer's weights w), added last and in slot
 * order. ctx and act may be the same array. */
static inline void nf_input_layer_blob(const float *ctx, const float *restrict w, uint32_t hp,
                                       const uint32_t rows[3], const float vals[3], float *act)
{
    for (uint32_t c = 0; c < hp; c += NF_CHUNK) {
        nf_lanes a, row;
        nf_lanes_load(&a, ctx + c);
        nf_lanes_load(&row, w + (size_t)rows[0] * hp + c);
        nf_lanes_madd(&a, vals[0], &row);
        nf_lanes_load(&row, w + (size_t)rows[1] * hp + c);
        nf_lanes_madd(&a, vals[1], &row);
        nf_lanes_load(&row, w + (size_t)rows[2] * hp + c);
        nf_lanes_madd(&a, vals[2], &row);
        nf_lanes_store(act + c, &a);
    }
}

/* y[0..stride) = bias + sum_k x[k] W[k] for k ascending (stride a multiple of NF_CHUNK): per
 * output the same sequence of FMAs as the tile kernels' dense layers. */
static inline void nf_dense_one(float *restrict y, const float *restrict w, uint32_t stride,
                                const float *restrict bias, const float *restrict x,
                                uint32_t inputs)
{
    for (uint32_t c = 0; c < stride; c += NF_CHUNK) {
        nf_lanes acc, row;
        nf_lanes_load(&acc, bias + c);
        for (uint32_t k = 0; k < inputs; ++k) {
            nf_lanes_load(&row, w + (size_t)k * stride + c);
            nf_lanes_madd(&acc, x[k], &row);
        }
        nf_lanes_store(y + c, &acc);
    }
}

static inline void nf_relu(float *v, uint32_t n)
{
    for (uint32_t j = 0; j < n; ++j)
        v[j] = nf_maxf(v[j], 0.0f);
}

/* sum_j a[j] b[j] over a multiple of NF_CHUNK, in NF_CHUNK independent lanes so that it
 * vectorizes without reassociation flags, and the lanes summed pairwise: four dependent
 * vector adds rather than a chain of sixteen scalar ones, which dominated the reverse pass's
 * per-sample dot products. */
static inline float nf_dot_padded(const float *restrict a, const float *restrict b, uint32_t n)
{
    float lanes[NF_CHUNK] = {0.0f};
    for (uint32_t c = 0; c < n; c += NF_CHUNK)
        for (uint32_t j = 0; j < NF_CHUNK; ++j)
            lanes[j] += a[c + j] * b[c + j];
    for (uint32_t half = NF_CHUNK / 2; half > 0; half /= 2)
        for (uint32_t j = 0; j < half; ++j)
            lanes[j] += lanes[j + half];
    return lanes[0];
}

/* y[0..n) += v * x[0..n) */
static inline void nf_axpy(float *restrict y, const float *restrict x, float v, uint32_t n)
{
    for (uint32_t j = 0; j < n; ++j)
        y[j] += v * x[j];
}

/* Raw spline parameters of coupling layer `layer` from the pass-through coordinate v. `act`
 * receives the hidden activations, hidden_layers rows of NF_PAD(hidden_width) floats, and
 * `raw` NF_PAD(3K+1) floats (the padding is zero). */
static inline void nf_conditioner_forward(const nf_model *m, uint32_t layer, const nf_point *pt,
                                          float v, float *act, float *raw)
{
    const nf_linear *lin = m->packed_linear[layer];
    const float *packed = m->packed;
    const uint32_t bins = m->cfg.oneblob_bins, depth = m->cfg.hidden_layers;
    const uint32_t width = m->cfg.hidden_width, hp = lin[0].stride;

    uint32_t rows[3];
    float vals[3];
    nf_input_layer_context(packed + lin[0].weight, packed + lin[0].bias, hp, pt->rows, pt->values,
                           packed + lin[0].weight + (size_t)4u * bins * hp, pt->sh, 1,
                           2u * m->cfg.sh_bands * m->cfg.sh_bands, act);
    nf_oneblob_slots(v, bins, 0, nf_layer_wraps(m, layer), rows, vals);
    nf_input_layer_blob(act, packed + lin[0].weight, hp, rows, vals, act);
    nf_relu(act, hp);
    for (uint32_t l = 1; l < depth; ++l) {
        float *h = act + (size_t)l * hp;
        nf_dense_one(h, packed + lin[l].weight, hp, packed + lin[l].bias, h - hp, width);
        nf_relu(h, hp);
    }
    nf_dense_one(raw, packed + lin[depth].weight, lin[depth].stride, packed + lin[depth].bias,
                 act + (size_t)(depth - 1) * hp, width);
    /* Extreme but finite weights (nf_model_set_params, a loaded file) can overflow the MLP to Inf
     * or NaN; the clamp (internal.h, NF_RAW_LIMIT) keeps the splines finite whatever the
     * weights. nf_clampf maps NaN to the lower bound. A no-op for ordinary models. */
    for (uint32_t r = 0; r < m->raw_dim; ++r)
        raw[r] = nf_clampf(raw[r], -NF_RAW_LIMIT, NF_RAW_LIMIT);
}

/* Reverse mode: given d loss / d raw (g_raw, NF_PAD(3K+1) floats with zero padding), adds the
 * parameter gradients into grad (public layout) and returns d loss / d v. */
static inline float nf_conditioner_backward(const nf_model *m, uint32_t layer, const nf_point *pt,
                                            float v, const float *act, const float *g_raw,
                                            float *grad)
{
    const nf_linear *pk = m->packed_linear[layer], *pub = m->linear[layer];
    const float *packed = m->packed;
    const uint32_t bins = m->cfg.oneblob_bins, depth = m->cfg.hidden_layers;
    const uint32_t width = m->cfg.hidden_width, hp = pk[0].stride;
    const uint32_t sh = 2u * m->cfg.sh_bands * m->cfg.sh_bands;
    float g_act[NF_MAX_HIDDEN_WIDTH] = {0.0f}, g_pre[NF_MAX_HIDDEN_WIDTH] = {0.0f};

    /* output layer */
    const nf_linear *out = &pk[depth];
    const float *last = act + (size_t)(depth - 1) * hp;
    nf_axpy(grad + pub[depth].bias, g_raw, 1.0f, m->raw_dim);
    for (uint32_t i = 0; i < width; ++i) {
        nf_axpy(grad + pub[depth].weight + (size_t)i * m->raw_dim, g_raw, last[i], m->raw_dim);
        g_act[i] =
            nf_dot_padded(packed + out->weight + (size_t)i * out->stride, g_raw, out->stride);
    }

    /* hidden-to-hidden layers, last to first */
    for (uint32_t l = depth - 1; l >= 1; --l) {
        const float *out_act = act + (size_t)l * hp, *in_act = out_act - hp;
        for (uint32_t j = 0; j < hp; ++j)
            g_pre[j] = out_act[j] > 0.0f ? g_act[j] : 0.0f;
        nf_axpy(grad + pub[l].bias, g_pre, 1.0f, width);
        for (uint32_t i = 0; i < width; ++i) {
            nf_axpy(grad + pub[l].weight + (size_t)i * width, g_pre, in_act[i], width);
            g_act[i] = nf_dot_padded(packed + pk[l].weight + (size_t)i * hp, g_pre, hp);
        }
    }

    /* input layer: only the rows that were gathered receive gradient */
    for (uint32_t j = 0; j < hp; ++j)
        g_pre[j] = act[j] > 0.0f ? g_act[j] : 0.0f;
    nf_axpy(grad + pub[0].bias, g_pre, 1.0f, width);
    float *gw = grad + pub[0].weight;
    const float *w = packed + pk[0].weight;
    nf_blob blob;
    nf_oneblob_sparse(v, bins, nf_layer_wraps(m, layer), &blob);
    float g_v = 0.0f;
    for (uint32_t c = 0; c < blob.count; ++c) {
        nf_axpy(gw + (size_t)blob.bin[c] * width, g_pre, blob.value[c], width);
        g_v += blob.dvalue[c] * nf_dot_padded(w + (size_t)blob.bin[c] * hp, g_pre, hp);
    }
    for (uint32_t r = 0; r < pt->row_count; ++r)
        nf_axpy(gw + (size_t)pt->rows[r] * width, g_pre, pt->values[r], width);
    for (uint32_t k = 0; k < sh; ++k)
        nf_axpy(gw + (size_t)(4u * bins + k) * width, g_pre, pt->sh[k], width);
    return g_v;
}

#endif /* NISFLOW_KERNELS_CONDITIONER_H */
