/*
 * conditioner.h - the per-layer MLPs that predict spline parameters (SPEC sections 4-5) as
 * inline code for the kernels: shading-point features, forward pass and reverse mode.
 *
 * The input vector of layer i is [one-blob(v) | one-blob(position) | SH(normal) | SH(wo)].
 * One-blob parts have at most three non-zeros per scalar, so the input layer gathers those
 * weight rows instead of multiplying a dense vector. The forward pass reads the packed
 * weights (input-major, outputs padded to NF_CHUNK) and accumulates NF_CHUNK outputs at a
 * time in a fixed-size local array, which the compiler keeps in vector registers. Gradients
 * are written in the public (unpadded) parameter layout.
 */
#ifndef NISFLOW_CONDITIONER_H
#define NISFLOW_CONDITIONER_H

#include <math.h>

#include "encoding.h"
#include "internal.h"

/* v / |v| with one rounding per component. Double cannot overflow or underflow on the
 * squares of finite floats, and inputs are validated non-zero upstream. */
static inline void nf_normalize3(const float v[3], float out[3])
{
    double x = v[0], y = v[1], z = v[2];
    double inv = 1.0 / sqrt(x * x + y * y + z * z);
    out[0] = (float)(x * inv);
    out[1] = (float)(y * inv);
    out[2] = (float)(z * inv);
}

static inline void nf_point_prepare(const nf_model *m, const nf_context *ctx, nf_point *pt)
{
    const nf_config *cfg = &m->cfg;
    const uint32_t bins = cfg->oneblob_bins;
    pt->user = ctx;
    pt->ctx.position[0] = ctx->position[0];
    pt->ctx.position[1] = ctx->position[1];
    pt->ctx.position[2] = ctx->position[2];
    nf_normalize3(ctx->normal, pt->ctx.normal);
    nf_normalize3(ctx->wo, pt->ctx.wo);
    pt->row_count = 0;
    for (uint32_t a = 0; a < 3; ++a) {
        float t = (ctx->position[a] - cfg->bounds_min[a]) /
                  (cfg->bounds_max[a] - cfg->bounds_min[a]);
        nf_blob blob;
        nf_oneblob_sparse(t, bins, &blob);
        for (uint32_t c = 0; c < blob.count; ++c) {
            pt->rows[pt->row_count] = (a + 1) * bins + blob.bin[c];
            pt->values[pt->row_count++] = blob.value[c];
        }
    }
    uint32_t sh = cfg->sh_bands * cfg->sh_bands;
    if (sh) {
        nf_sh_unit(pt->ctx.normal, cfg->sh_bands, pt->sh);
        nf_sh_unit(pt->ctx.wo, cfg->sh_bands, pt->sh + sh);
    }
}

/* y[0..stride) = bias + sum_r vals[r] W[rows[r]] + sum_k dense[k] W[dense_first + k]. */
static inline void nf_affine(float *restrict y, const float *restrict w, uint32_t stride,
                             const float *restrict bias, const uint32_t *restrict rows,
                             const float *restrict vals, uint32_t count, uint32_t dense_first,
                             const float *restrict dense, uint32_t dense_count)
{
    for (uint32_t c = 0; c < stride; c += NF_CHUNK) {
        float acc[NF_CHUNK];
        for (uint32_t j = 0; j < NF_CHUNK; ++j)
            acc[j] = bias[c + j];
        for (uint32_t r = 0; r < count; ++r) {
            const float *wr = w + (size_t)rows[r] * stride + c;
            float v = vals[r];
            for (uint32_t j = 0; j < NF_CHUNK; ++j)
                acc[j] += v * wr[j];
        }
        /* Four rows per iteration: the loop control otherwise costs as much as the FMAs. */
        uint32_t r = 0;
        for (; r + 4 <= dense_count; r += 4) {
            const float *w0 = w + (size_t)(dense_first + r) * stride + c;
            const float *w1 = w0 + stride, *w2 = w1 + stride, *w3 = w2 + stride;
            float v0 = dense[r], v1 = dense[r + 1], v2 = dense[r + 2], v3 = dense[r + 3];
            for (uint32_t j = 0; j < NF_CHUNK; ++j)
                acc[j] += v0 * w0[j] + v1 * w1[j] + v2 * w2[j] + v3 * w3[j];
        }
        for (; r < dense_count; ++r) {
            const float *wr = w + (size_t)(dense_first + r) * stride + c;
            float v = dense[r];
            for (uint32_t j = 0; j < NF_CHUNK; ++j)
                acc[j] += v * wr[j];
        }
        for (uint32_t j = 0; j < NF_CHUNK; ++j)
            y[c + j] = acc[j];
    }
}

static inline void nf_relu(float *v, uint32_t n)
{
    for (uint32_t j = 0; j < n; ++j)
        v[j] = nf_maxf(v[j], 0.0f);
}

/* sum_j a[j] b[j] over a multiple of NF_CHUNK, in NF_CHUNK independent lanes so that it
 * vectorizes without reassociation flags. */
static inline float nf_dot_padded(const float *restrict a, const float *restrict b, uint32_t n)
{
    float lanes[NF_CHUNK] = {0.0f};
    for (uint32_t c = 0; c < n; c += NF_CHUNK)
        for (uint32_t j = 0; j < NF_CHUNK; ++j)
            lanes[j] += a[c + j] * b[c + j];
    float s = 0.0f;
    for (uint32_t j = 0; j < NF_CHUNK; ++j)
        s += lanes[j];
    return s;
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

    uint32_t rows[12];
    float vals[12];
    nf_blob blob;
    nf_oneblob_sparse(v, bins, &blob);
    uint32_t count = 0;
    for (uint32_t c = 0; c < blob.count; ++c) {
        rows[count] = blob.bin[c];
        vals[count++] = blob.value[c];
    }
    for (uint32_t r = 0; r < pt->row_count; ++r) {
        rows[count] = pt->rows[r];
        vals[count++] = pt->values[r];
    }
    nf_affine(act, packed + lin[0].weight, hp, packed + lin[0].bias, rows, vals, count,
              4u * bins, pt->sh, 2u * m->cfg.sh_bands * m->cfg.sh_bands);
    nf_relu(act, hp);
    for (uint32_t l = 1; l < depth; ++l) {
        float *h = act + (size_t)l * hp;
        nf_affine(h, packed + lin[l].weight, hp, packed + lin[l].bias, NULL, NULL, 0, 0,
                  h - hp, width);
        nf_relu(h, hp);
    }
    nf_affine(raw, packed + lin[depth].weight, lin[depth].stride, packed + lin[depth].bias,
              NULL, NULL, 0, 0, act + (size_t)(depth - 1) * hp, width);
    /* Extreme but finite weights (nf_set_params, a loaded file) can overflow the MLP to Inf
     * or NaN; the clamp (internal.h, NF_RAW_LIMIT) keeps the splines finite whatever the
     * weights. nf_clampf maps NaN to the lower bound. A no-op for ordinary models. */
    for (uint32_t r = 0; r < m->raw_dim; ++r)
        raw[r] = nf_clampf(raw[r], -NF_RAW_LIMIT, NF_RAW_LIMIT);
}

/* Reverse mode: given d loss / d raw (g_raw, NF_PAD(3K+1) floats with zero padding), adds the
 * parameter gradients into grad (public layout) and returns d loss / d v. */
static inline float nf_conditioner_backward(const nf_model *m, uint32_t layer,
                                            const nf_point *pt, float v, const float *act,
                                            const float *g_raw, float *grad)
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
        g_act[i] = nf_dot_padded(packed + out->weight + (size_t)i * out->stride, g_raw,
                                 out->stride);
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
    nf_oneblob_sparse(v, bins, &blob);
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

#endif /* NISFLOW_CONDITIONER_H */
