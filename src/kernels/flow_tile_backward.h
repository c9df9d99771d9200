/*
 * flow_tile_backward.h - the loss gradient of docs/theory.md section 6 for a tile of training
 * samples: the inverse flow of nf_tile_pdf, then reverse mode from the prior back through the
 * coupling layers (the tile form of nf_flow_density with a gradient, flow.h).
 *
 * The forward pass records what the reverse pass needs on a tape: every coupling layer's
 * hidden activations and raw spline parameters, and its bins, solutions and slopes. When the
 * model's layers do not all fit (only networks near the configuration limits), the tape holds
 * one layer and the reverse pass recomputes each conditioner from the recorded inputs, as the
 * per-sample code always does.
 */
#ifndef NISFLOW_KERNELS_FLOW_TILE_BACKWARD_H
#define NISFLOW_KERNELS_FLOW_TILE_BACKWARD_H

#include <math.h>

#include "flow.h"
#include "conditioner_tile_backward.h"
#include "flow_tile.h"
#include "spline_tile_backward.h"

/* Rows of the tape: the largest single coupling layer (NF_MAX_HIDDEN_LAYERS hidden layers of
 * NF_MAX_HIDDEN_WIDTH units and NF_MAX_RAW_PADDED raw rows), about 77 KiB. The presets' layers
 * all fit: 2 x 48 rows (small) and 4 x 88 rows (large). */
#define NF_TILE_TAPE_ROWS (NF_TILE_ACT_ROWS(NF_MAX_HIDDEN_LAYERS) + NF_MAX_RAW_PADDED)

/* Everything one training tile needs, about 160 KiB: the gradient kernel declares it once
 * per call, on the stack. */
typedef struct nf_tile_gradient_work {
    nf_tile tile;
    nf_tile_blob blob;
    float tape[NF_TILE_TAPE_ROWS][NF_TILE];
    float g_raw[NF_MAX_RAW_PADDED][NF_TILE];
    nf_tile_spline spline;
    nf_tile_bin bin[NF_MAX_COUPLING_LAYERS];             /* each inverse layer's bins */
    float solved[NF_MAX_COUPLING_LAYERS][NF_TILE];       /* its solutions x[t]        */
    float slope[NF_MAX_COUPLING_LAYERS][NF_TILE];        /* dy/dx there               */
    float rotation_raw[NF_MAX_COUPLING_LAYERS][NF_TILE]; /* circular layers' rotations, raw */
    nf_tile_partials partials;
    nf_tile_backward_work backward;
} nf_tile_gradient_work;

/* Where coupling layer `layer` keeps its activations on the tape (its raw parameters follow
 * them, after hidden_layers * hp rows), and whether every layer has its own place. */
typedef struct nf_tape_layout {
    uint32_t act_rows;   /* hidden_layers * hp                    */
    uint32_t layer_rows; /* act_rows + the raw rows, a multiple of 8 */
    int keep_all;
} nf_tape_layout;

static inline nf_tape_layout nf_tape_plan(const nf_model *m)
{
    nf_tape_layout t;
    t.act_rows = m->cfg.hidden_layers * m->packed_linear[0][0].stride;
    t.layer_rows = t.act_rows + (m->raw_dim + 7u) / 8u * 8u;
    t.keep_all = (size_t)t.layer_rows * m->cfg.coupling_layers <= NF_TILE_TAPE_ROWS;
    return t;
}

static inline float (*nf_tape_act(nf_tile_gradient_work *w, const nf_tape_layout *t,
                                  uint32_t layer))[NF_TILE]
{
    return w->tape + (t->keep_all ? (size_t)layer * t->layer_rows : 0u);
}

/* Conditioner (keeping every hidden layer) and splines of coupling layer `layer` at x, on
 * the layer's place on the tape. */
static inline void nf_tile_gradient_layer(const nf_model *m, uint32_t layer,
                                          const float (*x)[NF_TILE], const nf_tape_layout *t,
                                          nf_tile_gradient_work *w)
{
    uint32_t tr = nf_transformed(layer);
    float(*act)[NF_TILE] = nf_tape_act(w, t, layer);
    nf_tile_oneblob(x[1 - tr], m->cfg.oneblob_bins, 0, nf_layer_wraps(m, layer), &w->blob);
    nf_tile_conditioner_forward(m, layer, &w->tile, &w->blob, act, m->cfg.hidden_layers,
                                act + t->act_rows);
    if (nf_layer_circular(m, layer))
        nf_tile_circular_take_rotation(act + t->act_rows, m->cfg.spline_bins,
                                       w->rotation_raw[layer]);
    nf_tile_spline_build(&w->spline, m->cfg.spline_bins,
                         (const float(*)[NF_TILE])(act + t->act_rows));
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
    float x[2][NF_TILE], s0[NF_TILE], coef[NF_TILE], q[NF_TILE];
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
    const nf_tape_layout tape = nf_tape_plan(m);
    for (uint32_t layer = layers; layer-- > 0;) {
        uint32_t t = nf_transformed(layer);
        memcpy(inputs[layer], x, sizeof x);
        nf_tile_gradient_layer(m, layer, (const float(*)[NF_TILE])x, &tape, w);
        const float(*raw)[NF_TILE] =
            (const float(*)[NF_TILE])(nf_tape_act(w, &tape, layer) + tape.act_rows);
        if (nf_layer_turns(m, layer))
            for (uint32_t i = 0; i < NF_TILE; ++i)
                x[t][i] = nf_wrap_unit(x[t][i] - nf_rotation(w->rotation_raw[layer][i], bins));
        nf_tile_spline_inverse(&w->spline, bins, raw + 2 * bins, x[t], w->slope[layer],
                               &w->bin[layer]);
        for (uint32_t i = 0; i < NF_TILE; ++i) {
            w->solved[layer][i] = x[t][i];
            inv_det[i] /= w->slope[layer][i];
        }
    }

    /* The prior's density and its log-gradient, lane by lane (custom priors call back). */
    for (uint32_t i = 0; i < NF_TILE; ++i) {
        if (i >= count) {
            g[0][i] = g[1][i] = 0.0f;
            continue;
        }
        nf_prior_point pt;
        float z[2] = {x[0][i], x[1][i]}, gz[2] = {0.0f, 0.0f};
        nf_tile_point(&w->tile, i, &pt);
        nf_status st = nf_prior_density(m, &pt, z, &q[i], gz);
        if (st != NF_OK)
            return st;
        /* p_w = p_s / (2 pi^2 sin theta); one log of the ratio, in double, where the
         * per-sample code takes two (their difference is rounding, ~1e-16). */
        double sin_theta = (double)nf_maxf(nf_sin_pi(s0[i]), NF_SIN_THETA_MIN);
        double p_w = (double)q[i] * inv_det[i] / ((double)NF_TWO_PI_SQUARED * sin_theta);
        *loss -= share[i] * log(p_w);
        g[0][i] = gz[0] * coef[i];
        g[1][i] = gz[1] * coef[i];
    }

    /* Reverse mode of J = coef (log q(z) + sum_i log dx/dy of layer i), from layer 0 (the
     * last inverse applied) upwards. */
    for (uint32_t layer = 0; layer < layers; ++layer) {
        uint32_t t = nf_transformed(layer);
        float(*act)[NF_TILE] = nf_tape_act(w, &tape, layer);
        float(*raw)[NF_TILE] = act + tape.act_rows;
        /* Layer 0 was the last one evaluated: its conditioner and splines are in place. */
        if (layer > 0) {
            if (tape.keep_all)
                nf_tile_spline_build(&w->spline, bins, (const float(*)[NF_TILE])raw);
            else
                nf_tile_gradient_layer(m, layer, (const float(*)[NF_TILE])inputs[layer], &tape, w);
        }
        nf_tile_partials_at(&w->bin[layer], w->solved[layer], &w->partials);
        /* x = S^-1(y): dx/dy = 1/S'; the layer's term is -log S'(x). */
        for (uint32_t i = 0; i < NF_TILE; ++i) {
            g_y[i] = (g[t][i] - coef[i] * w->partials.dl_dx[i]) / w->slope[layer][i];
            a[i] = -g_y[i];
            b[i] = -coef[i];
        }
        for (uint32_t r = 0; r < m->raw_dim; ++r)
            for (uint32_t i = 0; i < NF_TILE; ++i)
                w->g_raw[r][i] = 0.0f;
        nf_tile_spline_raw_backward(&w->spline, bins, &w->bin[layer], &w->partials, a, b, w->g_raw);
        /* A raw parameter held at the clamp does not depend on the weights. */
        for (uint32_t r = 0; r < m->raw_dim; ++r)
            for (uint32_t i = 0; i < NF_TILE; ++i) {
                float v = raw[r][i];
                w->g_raw[r][i] = v <= -NF_RAW_LIMIT || v >= NF_RAW_LIMIT ? 0.0f : w->g_raw[r][i];
            }
        if (nf_layer_circular(m, layer))
            nf_tile_circular_backward(w->g_raw, bins, nf_layer_turns(m, layer),
                                      w->rotation_raw[layer], g_y);
        nf_tile_conditioner_backward(m, layer, &w->tile, inputs[layer][1 - t],
                                     (const float(*)[NF_TILE])act,
                                     (const float(*)[NF_TILE])w->g_raw, grad, g_v, &w->backward);
        for (uint32_t i = 0; i < NF_TILE; ++i) {
            g[1 - t][i] += g_v[i];
            g[t][i] = g_y[i];
        }
    }
    return NF_OK;
}

#endif /* NISFLOW_KERNELS_FLOW_TILE_BACKWARD_H */
