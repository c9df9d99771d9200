/*
 * flow.c - the coupling flow F = G_{L-1} o ... o G_0 (SPEC section 4) and the public
 * nf_sample / nf_pdf. Layer i transforms s1 conditioned on s0 when i is even, s0 conditioned
 * on s1 when i is odd. All scratch lives on the stack: no allocation, no shared state.
 */
#include <math.h>

#include "internal.h"

#define NF_TWO_PI_SQUARED 19.7392088021787172f

/* The coordinate that layer i transforms; the other one passes through. */
static uint32_t nf_transformed(uint32_t layer)
{
    return (layer & 1u) ? 0u : 1u;
}

float nf_flow_forward(const nf_model *m, const nf_point *pt, const float z[2], float s[2])
{
    float act[NF_MAX_ACTIVATIONS], raw[NF_MAX_RAW];
    nf_spline sp;
    float x[2] = {z[0], z[1]}, log_det = 0.0f;
    for (uint32_t i = 0; i < m->cfg.coupling_layers; ++i) {
        uint32_t t = nf_transformed(i);
        nf_conditioner_forward(m, i, pt, x[1 - t], act, raw);
        nf_spline_build(&sp, m->cfg.spline_bins, raw);
        float y, log_d;
        nf_spline_eval(&sp, nf_spline_bin_of_x(&sp, x[t]), x[t], &y, &log_d);
        x[t] = y;
        log_det += log_d;
    }
    s[0] = x[0];
    s[1] = x[1];
    return log_det;
}

/* One inverse layer: x[t] <- S^-1(x[t]); returns log(dy/dx) at the solution. */
static float nf_layer_inverse(const nf_model *m, const nf_point *pt, uint32_t i, float x[2],
                              float *act, float *raw, nf_spline *sp, uint32_t *bin)
{
    uint32_t t = nf_transformed(i);
    nf_conditioner_forward(m, i, pt, x[1 - t], act, raw);
    nf_spline_build(sp, m->cfg.spline_bins, raw);
    uint32_t k = nf_spline_bin_of_y(sp, x[t]);
    float solved = nf_spline_solve(sp, k, x[t]), y_again, log_d;
    nf_spline_eval(sp, k, solved, &y_again, &log_d);
    x[t] = solved;
    *bin = k;
    return log_d;
}

float nf_flow_inverse(const nf_model *m, const nf_point *pt, const float s[2], float z[2])
{
    float act[NF_MAX_ACTIVATIONS], raw[NF_MAX_RAW];
    nf_spline sp;
    uint32_t k;
    float x[2] = {s[0], s[1]}, log_det = 0.0f;
    for (uint32_t i = m->cfg.coupling_layers; i-- > 0;)
        log_det -= nf_layer_inverse(m, pt, i, x, act, raw, &sp, &k);
    z[0] = x[0];
    z[1] = x[1];
    return log_det;
}

nf_status nf_flow_log_density(const nf_model *m, const nf_point *pt, const float s[2],
                              float coef, float *grad, float *log_p)
{
    const uint32_t layers = m->cfg.coupling_layers;
    float act[NF_MAX_ACTIVATIONS], raw[NF_MAX_RAW], g_raw[NF_MAX_RAW];
    float inputs[NF_MAX_COUPLING_LAYERS][2]; /* what each inverse layer received */
    nf_spline sp;
    uint32_t k;
    float x[2] = {s[0], s[1]}, log_det = 0.0f;
    for (uint32_t i = layers; i-- > 0;) {
        inputs[i][0] = x[0];
        inputs[i][1] = x[1];
        log_det -= nf_layer_inverse(m, pt, i, x, act, raw, &sp, &k);
    }
    float log_q, g[2] = {0.0f, 0.0f};
    nf_status st = nf_prior_log_density(m, pt, x, &log_q, grad ? g : NULL);
    if (st != NF_OK)
        return st;
    *log_p = log_q + log_det;
    if (!grad)
        return NF_OK;

    /* Reverse mode of J = coef * (log q(z) + sum_i log dx/dy of layer i), from layer 0 (the
     * last inverse applied) upwards. The conditioner activations are recomputed per layer
     * rather than stored, which bounds the stack to one layer's worth. */
    g[0] *= coef;
    g[1] *= coef;
    for (uint32_t i = 0; i < layers; ++i) {
        uint32_t t = nf_transformed(i);
        float xi[2] = {inputs[i][0], inputs[i][1]};
        float log_d = nf_layer_inverse(m, pt, i, xi, act, raw, &sp, &k);
        nf_spline_partials p;
        nf_spline_partials_at(&sp, k, xi[t], &p);
        /* x = S^-1(y): dx/dy = 1/S'; the layer's term is -log S'(x). */
        float g_y = (g[t] - coef * p.dl_dx) * expf(-log_d);
        for (uint32_t r = 0; r < m->raw_dim; ++r)
            g_raw[r] = 0.0f;
        nf_spline_raw_backward(&sp, k, &p, -g_y, -coef, g_raw);
        float g_v = nf_conditioner_backward(m, i, pt, xi[1 - t], act, g_raw, grad);
        g[1 - t] += g_v;
        g[t] = g_y;
    }
    return NF_OK;
}

/* Density on the square -> solid-angle density at s (SPEC section 1). */
static float nf_solid_angle_pdf(float log_p, float s0)
{
    return expf(log_p) / (NF_TWO_PI_SQUARED * nf_maxf(nf_sin_pi(s0), NF_SIN_THETA_MIN));
}

nf_status nf_sample(const nf_model *m, size_t n, const nf_context *ctx, const float *u,
                    float *dir, float *pdf)
{
    static const char fn[] = "nf_sample";
    if (n == 0)
        return NF_OK;
    if (!m || !ctx || !u || !dir)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: NULL model, ctx, u or dir", fn);
    nf_status st;
    if ((st = nf_validate_batch_size(fn, n)) != NF_OK ||
        (st = nf_validate_contexts(fn, n, ctx)) != NF_OK)
        return st;
    if (!nf_all_finite(u, 2 * n))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: u contains NaN or Inf", fn);
    for (size_t i = 0; i < n; ++i) {
        nf_point pt;
        nf_point_prepare(m, &ctx[i], &pt);
        float z[2], s[2], log_q;
        if ((st = nf_prior_sample(m, &pt, u[2 * i], u[2 * i + 1], z, &log_q)) != NF_OK)
            return st;
        float log_det = nf_flow_forward(m, &pt, z, s);
        nf_square_to_direction(s, dir + 3 * i);
        if (pdf)
            pdf[i] = nf_solid_angle_pdf(log_q - log_det, s[0]);
    }
    return NF_OK;
}

nf_status nf_pdf(const nf_model *m, size_t n, const nf_context *ctx, const float *dir,
                 float *pdf)
{
    static const char fn[] = "nf_pdf";
    if (n == 0)
        return NF_OK;
    if (!m || !ctx || !dir || !pdf)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: NULL model, ctx, dir or pdf", fn);
    nf_status st;
    if ((st = nf_validate_batch_size(fn, n)) != NF_OK ||
        (st = nf_validate_contexts(fn, n, ctx)) != NF_OK ||
        (st = nf_validate_directions(fn, "dir", n, dir)) != NF_OK)
        return st;
    for (size_t i = 0; i < n; ++i) {
        nf_point pt;
        nf_point_prepare(m, &ctx[i], &pt);
        float s[2], log_p;
        nf_direction_to_square(dir + 3 * i, s);
        if ((st = nf_flow_log_density(m, &pt, s, 0.0f, NULL, &log_p)) != NF_OK)
            return st;
        pdf[i] = nf_solid_angle_pdf(log_p, s[0]);
    }
    return NF_OK;
}
