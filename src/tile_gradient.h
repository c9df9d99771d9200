/*
 * tile_gradient.h - the loss gradient of SPEC section 6 for a tile of training samples: the
 * inverse flow of nf_tile_pdf, then reverse mode from the prior back through the coupling
 * layers (the tile form of nf_flow_density with a gradient, flow_eval.h).
 *
 * Memory is bounded like the per-sample code's: the forward pass keeps each layer's input
 * point, not its activations, and the reverse pass recomputes one conditioner at a time,
 * except layer 0's, which the forward pass computed last.
 */
#ifndef NISFLOW_TILE_GRADIENT_H
#define NISFLOW_TILE_GRADIENT_H

#include <math.h>

#include "flow_eval.h"
#include "tile_conditioner_backward.h"
#include "tile_flow.h"
#include "tile_spline_backward.h"

/* Everything one training tile needs, about 150 KiB (the activations of up to
 * NF_MAX_HIDDEN_LAYERS hidden layers of NF_MAX_HIDDEN_WIDTH units take 64 KiB): the gradient
 * kernel declares it once per call, on the stack. */
typedef struct nf_tile_gradient_work {
    nf_tile tile;
    nf_tile_blob blob;
    float act[NF_TILE_ACT_ROWS(NF_MAX_HIDDEN_LAYERS)][NF_TILE];
    float raw[NF_MAX_RAW_PADDED][NF_TILE];
    float g_raw[NF_MAX_RAW_PADDED][NF_TILE];
    nf_tile_spline spline;
    nf_tile_bin bin;
    nf_tile_partials partials;
    nf_tile_backward_work backward;
} nf_tile_gradient_work;

/* Conditioner (keeping every hidden layer) and splines of coupling layer `layer` at x. */
static inline void nf_tile_gradient_layer(const nf_model *m, uint32_t layer,
                                          const float (*x)[NF_TILE], nf_tile_gradient_work *w)
{
    uint32_t t = nf_transformed(layer);
    nf_tile_oneblob(x[1 - t], m->cfg.oneblob_bins, 0, &w->blob);
    nf_tile_conditioner_forward(m, layer, &w->tile, &w->blob, w->act, m->cfg.hidden_layers,
                                w->raw);
    nf_tile_spline_build(&w->spline, m->cfg.spline_bins, (const float(*)[NF_TILE])w->raw);
}

/* For the samples (*ctx[i], dir[i], share[i]), i < count (count in 1..NF_TILE, shares > 0,
 * summing to at most 1 over the batch): adds sum_i share_i d(-log p_w)/d(params) into grad
 * (public layout) and subtracts sum_i share_i log p_w from *loss, as nf_kernel_gradient's
 * per-sample loop does. */
static inline nf_status nf_tile_gradient(const nf_model *m, const nf_context *const *ctx,
                                         const float *const *dir, const double *share,
                                         uint32_t count, float *grad, double *loss,
                                         nf_tile_gradient_work *w)
{
    const uint32_t layers = m->cfg.coupling_layers, bins = m->cfg.spline_bins;
    float inputs[NF_MAX_COUPLING_LAYERS][2][NF_TILE]; /* what each inverse layer received */
    float x[2][NF_TILE], s0[NF_TILE], slope[NF_TILE], coef[NF_TILE], q[NF_TILE];
    float g[2][NF_TILE], g_y[NF_TILE], a[NF_TILE], b[NF_TILE], g_v[NF_TILE];
    double inv_det[NF_TILE];
    nf_tile_prepare_from(m, ctx, count, &w->tile);
    for (uint32_t i = 0; i < NF_TILE; ++i) {
        const float *d = dir[i < count ? i : 0];
        float si[2];
        nf_to_square(d, si);
        x[0][i] = s0[i] = si[0];
        x[1][i] = si[1];
        inv_det[i] = 1.0;
        /* The padding lanes repeat sample 0 with coefficient 0: their gradients are zeros. */
        coef[i] = i < count ? (float)-share[i] : 0.0f;
    }
    for (uint32_t layer = layers; layer-- > 0;) {
        uint32_t t = nf_transformed(layer);
        memcpy(inputs[layer], x, sizeof x);
        nf_tile_gradient_layer(m, layer, (const float(*)[NF_TILE])x, w);
        nf_tile_spline_inverse(&w->spline, bins, (const float(*)[NF_TILE])(w->raw + 2 * bins),
                               x[t], slope, &w->bin);
        for (uint32_t i = 0; i < NF_TILE; ++i)
            inv_det[i] /= slope[i];
    }

    /* The prior's density and its log-gradient, lane by lane (custom priors call back). */
    for (uint32_t i = 0; i < NF_TILE; ++i) {
        if (i >= count) {
            g[0][i] = g[1][i] = 0.0f;
            continue;
        }
        nf_point pt;
        float z[2] = {x[0][i], x[1][i]}, gz[2] = {0.0f, 0.0f};
        nf_tile_point(&w->tile, i, &pt);
        nf_status st = nf_prior_density(m, &pt, z, &q[i], gz);
        if (st != NF_OK)
            return st;
        /* log p_w = log p_s - log(2 pi^2 sin theta) */
        double log_p = log((double)q[i] * inv_det[i]);
        double sin_theta = (double)nf_maxf(nf_sin_pi(s0[i]), NF_SIN_THETA_MIN);
        *loss -= share[i] * (log_p - log((double)NF_TWO_PI_SQUARED * sin_theta));
        g[0][i] = gz[0] * coef[i];
        g[1][i] = gz[1] * coef[i];
    }

    /* Reverse mode of J = coef (log q(z) + sum_i log dx/dy of layer i), from layer 0 (the
     * last inverse applied) upwards. */
    for (uint32_t layer = 0; layer < layers; ++layer) {
        uint32_t t = nf_transformed(layer);
        float xi[2][NF_TILE];
        memcpy(xi, inputs[layer], sizeof xi);
        if (layer > 0)
            nf_tile_gradient_layer(m, layer, (const float(*)[NF_TILE])xi, w);
        nf_tile_spline_inverse(&w->spline, bins, (const float(*)[NF_TILE])(w->raw + 2 * bins),
                               xi[t], slope, &w->bin);
        nf_tile_partials_at(&w->bin, xi[t], &w->partials);
        /* x = S^-1(y): dx/dy = 1/S'; the layer's term is -log S'(x). */
        for (uint32_t i = 0; i < NF_TILE; ++i) {
            g_y[i] = (g[t][i] - coef[i] * w->partials.dl_dx[i]) / slope[i];
            a[i] = -g_y[i];
            b[i] = -coef[i];
        }
        for (uint32_t r = 0; r < m->raw_dim; ++r)
            for (uint32_t i = 0; i < NF_TILE; ++i)
                w->g_raw[r][i] = 0.0f;
        nf_tile_spline_raw_backward(&w->spline, bins, &w->bin, &w->partials, a, b, w->g_raw);
        /* A raw parameter held at the clamp does not depend on the weights. */
        for (uint32_t r = 0; r < m->raw_dim; ++r)
            for (uint32_t i = 0; i < NF_TILE; ++i) {
                float v = w->raw[r][i];
                w->g_raw[r][i] = v <= -NF_RAW_LIMIT || v >= NF_RAW_LIMIT ? 0.0f : w->g_raw[r][i];
            }
        nf_tile_conditioner_backward(m, layer, &w->tile, xi[1 - t],
                                     (const float(*)[NF_TILE])w->act,
                                     (const float(*)[NF_TILE])w->g_raw, grad, g_v, &w->backward);
        for (uint32_t i = 0; i < NF_TILE; ++i) {
            g[1 - t][i] += g_v[i];
            g[t][i] = g_y[i];
        }
    }
    return NF_OK;
}

#endif /* NISFLOW_TILE_GRADIENT_H */
