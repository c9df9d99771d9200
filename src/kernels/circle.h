/*
 * circle.h - phi on the circle (NF_PHI_CIRCULAR, docs/theory.md section 4): which coupling
 * layers are circular, how their raw parameters are read, their rotation, and the wrap of a
 * coordinate onto [0, 1). Everything that moves mass across phi = 0 is here; the splines,
 * encodings and flows call it.
 */
#ifndef NISFLOW_KERNELS_CIRCLE_H
#define NISFLOW_KERNELS_CIRCLE_H

#include <math.h>

#include "internal.h"
#include "lanes.h"

/* The coordinate that layer i transforms (1: s1 = phi / 2 pi, 0: s0 = theta / pi); the other
 * one passes through. */
static inline uint32_t nf_transformed(uint32_t layer) { return (layer & 1u) ? 0u : 1u; }

/* Layer i maps phi on the circle: its spline's end slopes are equal. */
static inline int nf_layer_circular(const nf_model *m, uint32_t layer)
{
    return m->cfg.phi_map == NF_PHI_CIRCULAR && nf_transformed(layer) == 1u;
}

/* Layer i also turns phi after its spline (in the sampling direction): the last phi layer
 * only, the one that writes the direction's phi. Every circular spline keeps phi = 0 in place;
 * the turn after the last one decides where that point lands, so a lobe built in the middle
 * of the splines' domain can sit across phi = 0. (A turn before a spline instead only
 * relabels a prior that is uniform in phi, and measured no better than no turn.) One turn is
 * enough, and each turn adds a rounding of phi (half an ulp of 1) between a spline and the
 * direction, which moves where nf_pdf reads the splines' slopes: with this one, the samples
 * of sharp random flows whose density differs from nf_pdf's by >= 1e-4 are 3.1% against
 * NF_PHI_INTERVAL's 2.5% (tests/correctness/test_sampling.c). Earlier circular layers leave
 * their rotation output unused (its gradient is zero). */
static inline int nf_layer_turns(const nf_model *m, uint32_t layer)
{
    return m->cfg.phi_map == NF_PHI_CIRCULAR && layer == ((m->cfg.coupling_layers - 1u) & ~1u);
}

/* Layer i's conditioner sees phi (its pass-through coordinate) on the circle: the one-blob
 * wraps around (encoding.h). */
static inline int nf_layer_wraps(const nf_model *m, uint32_t layer)
{
    return m->cfg.phi_map == NF_PHI_CIRCULAR && nf_transformed(layer) == 0u;
}

/* The point of [0, 1) that v (in [-1, 2)) is on the circle. A result that rounds up to 1 is
 * 0, the same point, so that a coordinate never leaves [0, 1). floorf is exact, so every
 * instruction set computes the same bits. */
static inline float nf_wrap_unit(float v)
{
    float f = v - floorf(v);
    return f < 1.0f ? f : 0.0f;
}

/* A circular layer's 3K + 1 raw parameters are K widths, K heights, the slopes d_0 .. d_{K-1}
 * and, in the place of d_K (which equals d_0 on the circle), the rotation. This moves the
 * rotation's raw value out (returned) and d_0's raw value into d_K's place, so that the
 * spline code reads K + 1 slopes as for any layer, and gives reverse mode the gradient of both
 * of d_0's places to add (nf_circular_backward). */
static inline float nf_circular_take_rotation(float *raw, uint32_t bins)
{
    float r = raw[3u * bins];
    raw[3u * bins] = raw[2u * bins];
    return r;
}

/* The rotation, a fraction of the circle, from its raw value: raw / K modulo 1, whose
 * derivative is 1 / K (the jumps at whole turns are no jumps on the circle). A unit of raw
 * turns the spline by one bin's width at the identity, as a unit of a raw width moves the
 * knots by about that much: at the raw value's full rate (a turn per unit) random and
 * early-training weights spin phi with theta so fast that the next layer's features are
 * crossed within ~1e-4 of theta (tests/correctness/test_flow.c measured it). */
static inline float nf_rotation(float raw, uint32_t bins)
{
    return nf_wrap_unit(raw / (float)bins);
}

/* A turning layer is y = wrap(S(x) + rotation) and its inverse x = S^-1(wrap(y - rotation)).
 * Reverse mode of the inverse: g_raw holds the spline's raw gradients with d_K's in d_K's
 * place; g_u is d loss / d u, u = y - rotation, the spline's output side. Folds d_K's gradient
 * into d_0's and writes the rotation's (-g_u / K, as u = y - raw / K), zero when the layer
 * does not turn or the raw value was held at the conditioner's clamp. */
static inline void nf_circular_backward(float *g_raw, uint32_t bins, int turns, float rotation_raw,
                                        float g_u)
{
    g_raw[2u * bins] += g_raw[3u * bins];
    int clamped = rotation_raw <= -NF_RAW_LIMIT || rotation_raw >= NF_RAW_LIMIT;
    g_raw[3u * bins] = clamped || !turns ? 0.0f : -g_u / (float)bins;
}

/* nf_circular_take_rotation for a tile: raw[row][lane], rotation raw values per lane. */
static inline void nf_tile_circular_take_rotation(float (*raw)[NF_TILE], uint32_t bins,
                                                  float *rotation_raw)
{
    for (uint32_t i = 0; i < NF_TILE; ++i) {
        rotation_raw[i] = raw[3u * bins][i];
        raw[3u * bins][i] = raw[2u * bins][i];
    }
}

/* nf_circular_backward for a tile. */
static inline void nf_tile_circular_backward(float (*g_raw)[NF_TILE], uint32_t bins, int turns,
                                             const float *rotation_raw, const float *g_u)
{
    for (uint32_t i = 0; i < NF_TILE; ++i) {
        g_raw[2u * bins][i] += g_raw[3u * bins][i];
        int clamped = rotation_raw[i] <= -NF_RAW_LIMIT || rotation_raw[i] >= NF_RAW_LIMIT;
        g_raw[3u * bins][i] = clamped || !turns ? 0.0f : -g_u[i] / (float)bins;
    }
}

#endif /* NISFLOW_KERNELS_CIRCLE_H */
