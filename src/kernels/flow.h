/*
 * flow.h - the coupling flow F = G_{L-1} o ... o G_0 (docs/theory.md section 4) as inline code for
 * the kernels. Layer i transforms s1 conditioned on s0 when i is even, s0 conditioned on s1
 * when i is odd. All scratch is on the stack: no allocation, no shared state.
 */
#ifndef NISFLOW_KERNELS_FLOW_H
#define NISFLOW_KERNELS_FLOW_H

#include <float.h>
#include <math.h>

#include "circle.h"
#include "conditioner.h"
#include "internal.h"
#include "prior.h"
#include "spline.h"

/* Per-sample scratch, kept in one struct so the kernels declare it once. */
typedef struct nf_scratch {
    float act[NF_MAX_HIDDEN_LAYERS * NF_PAD(NF_MAX_HIDDEN_WIDTH)];
    float raw[NF_MAX_RAW_PADDED];
    float g_raw[NF_MAX_RAW_PADDED];
    nf_spline spline;
    float rotation_raw; /* a circular layer's rotation, raw (circle.h) */
} nf_scratch;

/* Forward map z -> s; returns |det J_F(z)| (a product of slopes, in double so that deep flows
 * cannot overflow it). A turning layer is y = wrap(S(x) + rotation) (circle.h). */
static inline double nf_flow_forward(const nf_model *m, const nf_point *pt, const float z[2],
                                     float s[2], nf_scratch *sc)
{
    float x[2] = {z[0], z[1]};
    double det = 1.0;
    for (uint32_t i = 0; i < m->cfg.coupling_layers; ++i) {
        uint32_t t = nf_transformed(i);
        nf_conditioner_forward(m, i, pt, x[1 - t], sc->act, sc->raw);
        if (nf_layer_circular(m, i))
            sc->rotation_raw = nf_circular_take_rotation(sc->raw, m->cfg.spline_bins);
        nf_spline_build(&sc->spline, m->cfg.spline_bins, sc->raw);
        nf_spline_bin bin;
        nf_spline_bin_at(&sc->spline, nf_spline_find(sc->spline.x, m->cfg.spline_bins, x[t]), &bin);
        float slope;
        x[t] = nf_spline_bin_eval(&bin, x[t], &slope);
        if (nf_layer_turns(m, i))
            x[t] = nf_wrap_unit(x[t] + nf_rotation(sc->rotation_raw, m->cfg.spline_bins));
        det *= slope;
    }
    s[0] = x[0];
    s[1] = x[1];
    return det;
}

/* One inverse layer: x[t] <- S^-1(x[t]) (S^-1(wrap(x[t] - rotation)) for a turning layer);
 * returns dy/dx at the solution and leaves the bin in *bin (and the spline, activations and
 * rotation in sc) for reverse mode. */
static inline float nf_layer_inverse(const nf_model *m, const nf_point *pt, uint32_t i, float x[2],
                                     nf_scratch *sc, nf_spline_bin *bin)
{
    uint32_t t = nf_transformed(i);
    const int turns = nf_layer_turns(m, i);
    nf_conditioner_forward(m, i, pt, x[1 - t], sc->act, sc->raw);
    if (nf_layer_circular(m, i))
        sc->rotation_raw = nf_circular_take_rotation(sc->raw, m->cfg.spline_bins);
    if (turns)
        x[t] = nf_wrap_unit(x[t] - nf_rotation(sc->rotation_raw, m->cfg.spline_bins));
    nf_spline_build(&sc->spline, m->cfg.spline_bins, sc->raw);
    nf_spline_bin_at(&sc->spline, nf_spline_find(sc->spline.y, m->cfg.spline_bins, x[t]), bin);
    float solved = nf_spline_bin_solve(bin, x[t]), slope;
    nf_spline_bin_eval(bin, solved, &slope);
    x[t] = solved;
    return slope;
}

/* The flow's density on the square at s. With grad != NULL, also adds
 * coef * d(log p_s)/d(params) into grad (public layout) and returns log p_s in *log_p. */
static inline nf_status nf_flow_density(const nf_model *m, const nf_point *pt, const float s[2],
                                        float coef, float *grad, double *p_s, double *log_p,
                                        nf_scratch *sc)
{
    const uint32_t layers = m->cfg.coupling_layers;
    float inputs[NF_MAX_COUPLING_LAYERS][2]; /* what each inverse layer received */
    nf_spline_bin bin;
    float x[2] = {s[0], s[1]};
    double inv_det = 1.0;
    for (uint32_t i = layers; i-- > 0;) {
        inputs[i][0] = x[0];
        inputs[i][1] = x[1];
        inv_det /= nf_layer_inverse(m, pt, i, x, sc, &bin);
    }
    float q, g[2] = {0.0f, 0.0f};
    nf_prior_point pp;
    nf_point_prior(pt, &pp);
    nf_status st = nf_prior_density(m, &pp, x, &q, grad ? g : NULL);
    if (st != NF_OK)
        return st;
    *p_s = (double)q * inv_det;
    if (!grad)
        return NF_OK;
    *log_p = log(*p_s);

    /* Reverse mode of J = coef * (log q(z) + sum_i log dx/dy of layer i), from layer 0 (the
     * last inverse applied) upwards. The conditioner activations are recomputed per layer
     * rather than stored, which bounds the stack to one layer's worth. */
    g[0] *= coef;
    g[1] *= coef;
    for (uint32_t i = 0; i < layers; ++i) {
        uint32_t t = nf_transformed(i);
        float xi[2] = {inputs[i][0], inputs[i][1]};
        float slope = nf_layer_inverse(m, pt, i, xi, sc, &bin);
        nf_spline_partials p;
        nf_spline_partials_at(&bin, xi[t], &p);
        /* x = S^-1(y): dx/dy = 1/S'; the layer's term is -log S'(x). */
        float g_y = (g[t] - coef * p.dl_dx) / slope;
        for (uint32_t r = 0; r < NF_MAX_RAW_PADDED; ++r)
            sc->g_raw[r] = 0.0f;
        nf_spline_raw_backward(&sc->spline, &bin, &p, -g_y, -coef, sc->g_raw);
        /* A raw parameter held at the clamp of nf_conditioner_forward does not depend on the
         * weights: its gradient is zero. */
        for (uint32_t r = 0; r < m->raw_dim; ++r)
            if (sc->raw[r] <= -NF_RAW_LIMIT || sc->raw[r] >= NF_RAW_LIMIT)
                sc->g_raw[r] = 0.0f;
        if (nf_layer_circular(m, i))
            nf_circular_backward(sc->g_raw, m->cfg.spline_bins, nf_layer_turns(m, i),
                                 sc->rotation_raw, g_y);
        g[1 - t] += nf_conditioner_backward(m, i, pt, xi[1 - t], sc->act, sc->g_raw, grad);
        g[t] = g_y;
    }
    return NF_OK;
}

/* Density on the square -> solid-angle density at s (docs/theory.md section 1). Extreme parameters
 * can make a density (correctly) exceed the float range; it is clamped to [FLT_MIN, FLT_MAX] so
 * that both the density and its reciprocal are finite and positive (a renderer divides by
 * it). Ordinary densities are untouched; NaN, which cannot arise, would pass through. */
static inline float nf_solid_angle_pdf_at(double p_s, float sin_theta)
{
    double p = p_s / (double)(NF_TWO_PI_SQUARED * nf_maxf(sin_theta, NF_SIN_THETA_MIN));
    p = p > (double)FLT_MAX ? (double)FLT_MAX : p;
    return (float)(p < (double)FLT_MIN ? (double)FLT_MIN : p);
}

/* The same with sin(theta) from s0 = theta / pi. */
static inline float nf_solid_angle_pdf(double p_s, float s0)
{
    return nf_solid_angle_pdf_at(p_s, nf_sin_pi(s0));
}

#endif /* NISFLOW_KERNELS_FLOW_H */
