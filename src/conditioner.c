/*
 * conditioner.c - the per-layer MLPs that predict spline parameters (SPEC sections 4-5):
 * shading-point features, forward pass and hand-written reverse mode.
 *
 * The input vector of layer i is [one-blob(v) | one-blob(position) | SH(normal) | SH(wo)].
 * The one-blob parts have at most three non-zeros per scalar, so the input layer gathers
 * those weight rows instead of multiplying a dense vector; weights are stored input-major so
 * each gathered row is contiguous.
 */
#include <math.h>
#include <string.h>

#include "internal.h"

static void nf_normalize(const float v[3], float out[3])
{
    double len = sqrt((double)v[0] * v[0] + (double)v[1] * v[1] + (double)v[2] * v[2]);
    for (int a = 0; a < 3; ++a)
        out[a] = (float)(v[a] / len);
}

void nf_point_prepare(const nf_model *m, const nf_context *ctx, nf_point *pt)
{
    const nf_config *cfg = &m->cfg;
    pt->ctx = *ctx;
    nf_normalize(ctx->normal, pt->ctx.normal);
    nf_normalize(ctx->wo, pt->ctx.wo);
    for (int a = 0; a < 3; ++a) {
        float t = (ctx->position[a] - cfg->bounds_min[a]) /
                  (cfg->bounds_max[a] - cfg->bounds_min[a]);
        nf_oneblob_sparse(nf_clampf(t, 0.0f, 1.0f), cfg->oneblob_bins, &pt->position[a]);
    }
    uint32_t sh = cfg->sh_bands * cfg->sh_bands;
    if (sh) {
        nf_sh_unit(pt->ctx.normal, cfg->sh_bands, pt->sh);
        nf_sh_unit(pt->ctx.wo, cfg->sh_bands, pt->sh + sh);
    }
}

/* h += value * W[row] over one gathered row of width `width`. */
static void nf_add_row(float *h, const float *w_row, float value, uint32_t width)
{
    for (uint32_t j = 0; j < width; ++j)
        h[j] += value * w_row[j];
}

void nf_conditioner_forward(const nf_model *m, uint32_t layer, const nf_point *pt, float v,
                            float *act, float *raw)
{
    const uint32_t width = m->cfg.hidden_width, bins = m->cfg.oneblob_bins;
    const uint32_t sh = 2u * m->cfg.sh_bands * m->cfg.sh_bands;
    const float *params = m->params;

    nf_linear lin = nf_model_linear(m, layer, 0);
    const float *w = params + lin.weight;
    float *h = act;
    memcpy(h, params + lin.bias, width * sizeof(float));
    nf_blob blob;
    nf_oneblob_sparse(v, bins, &blob);
    for (uint32_t c = 0; c < blob.count; ++c)
        nf_add_row(h, w + (size_t)blob.bin[c] * width, blob.value[c], width);
    for (uint32_t a = 0; a < 3; ++a) {
        const nf_blob *pb = &pt->position[a];
        for (uint32_t c = 0; c < pb->count; ++c)
            nf_add_row(h, w + (size_t)((a + 1) * bins + pb->bin[c]) * width, pb->value[c],
                       width);
    }
    for (uint32_t k = 0; k < sh; ++k)
        nf_add_row(h, w + (size_t)(4u * bins + k) * width, pt->sh[k], width);
    for (uint32_t j = 0; j < width; ++j)
        h[j] = nf_maxf(h[j], 0.0f);

    for (uint32_t l = 1; l < m->cfg.hidden_layers; ++l) {
        lin = nf_model_linear(m, layer, l);
        const float *prev = act + (size_t)(l - 1) * width;
        h = act + (size_t)l * width;
        memcpy(h, params + lin.bias, width * sizeof(float));
        for (uint32_t i = 0; i < width; ++i)
            nf_add_row(h, params + lin.weight + (size_t)i * width, prev[i], width);
        for (uint32_t j = 0; j < width; ++j)
            h[j] = nf_maxf(h[j], 0.0f);
    }

    lin = nf_model_linear(m, layer, m->cfg.hidden_layers);
    const float *last = act + (size_t)(m->cfg.hidden_layers - 1) * width;
    memcpy(raw, params + lin.bias, lin.out * sizeof(float));
    for (uint32_t i = 0; i < width; ++i)
        nf_add_row(raw, params + lin.weight + (size_t)i * lin.out, last[i], lin.out);
}

/* g_in[i] = sum_j W[i][j] g_out[j] for input-major W. */
static float nf_row_dot(const float *w_row, const float *g, uint32_t width)
{
    float s = 0.0f;
    for (uint32_t j = 0; j < width; ++j)
        s += w_row[j] * g[j];
    return s;
}

float nf_conditioner_backward(const nf_model *m, uint32_t layer, const nf_point *pt, float v,
                              const float *act, const float *g_raw, float *grad)
{
    const uint32_t width = m->cfg.hidden_width, bins = m->cfg.oneblob_bins;
    const uint32_t sh = 2u * m->cfg.sh_bands * m->cfg.sh_bands, depth = m->cfg.hidden_layers;
    const float *params = m->params;
    float g_act[NF_MAX_HIDDEN_WIDTH], g_pre[NF_MAX_HIDDEN_WIDTH];

    /* output layer */
    nf_linear lin = nf_model_linear(m, layer, depth);
    const float *last = act + (size_t)(depth - 1) * width;
    nf_add_row(grad + lin.bias, g_raw, 1.0f, lin.out);
    for (uint32_t i = 0; i < width; ++i) {
        nf_add_row(grad + lin.weight + (size_t)i * lin.out, g_raw, last[i], lin.out);
        g_act[i] = nf_row_dot(params + lin.weight + (size_t)i * lin.out, g_raw, lin.out);
    }

    /* hidden-to-hidden layers, last to first */
    for (uint32_t l = depth - 1; l >= 1; --l) {
        const float *out_act = act + (size_t)l * width, *in_act = out_act - width;
        for (uint32_t j = 0; j < width; ++j)
            g_pre[j] = out_act[j] > 0.0f ? g_act[j] : 0.0f;
        lin = nf_model_linear(m, layer, l);
        nf_add_row(grad + lin.bias, g_pre, 1.0f, width);
        for (uint32_t i = 0; i < width; ++i) {
            nf_add_row(grad + lin.weight + (size_t)i * width, g_pre, in_act[i], width);
            g_act[i] = nf_row_dot(params + lin.weight + (size_t)i * width, g_pre, width);
        }
    }

    /* input layer: only the rows that were gathered receive gradient */
    for (uint32_t j = 0; j < width; ++j)
        g_pre[j] = act[j] > 0.0f ? g_act[j] : 0.0f;
    lin = nf_model_linear(m, layer, 0);
    nf_add_row(grad + lin.bias, g_pre, 1.0f, width);
    float *gw = grad + lin.weight;
    const float *w = params + lin.weight;
    nf_blob blob;
    nf_oneblob_sparse(v, bins, &blob);
    float g_v = 0.0f;
    for (uint32_t c = 0; c < blob.count; ++c) {
        size_t row = (size_t)blob.bin[c] * width;
        nf_add_row(gw + row, g_pre, blob.value[c], width);
        g_v += blob.dvalue[c] * nf_row_dot(w + row, g_pre, width);
    }
    for (uint32_t a = 0; a < 3; ++a) {
        const nf_blob *pb = &pt->position[a];
        for (uint32_t c = 0; c < pb->count; ++c)
            nf_add_row(gw + (size_t)((a + 1) * bins + pb->bin[c]) * width, g_pre,
                       pb->value[c], width);
    }
    for (uint32_t k = 0; k < sh; ++k)
        nf_add_row(gw + (size_t)(4u * bins + k) * width, g_pre, pt->sh[k], width);
    return g_v;
}
