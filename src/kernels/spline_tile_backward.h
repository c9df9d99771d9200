/*
 * spline_tile_backward.h - reverse mode of the tile splines (spline_tile.h): the gradient of
 * a y + b log(dy/dx) at each lane's point with respect to that lane's raw spline parameters.
 * The per-lane arithmetic is spline.h's (nf_spline_partials_at, and nf_knots_backward's
 * sums in the same order), with the lane's bin index turned into comparisons over the bins so
 * that every loop runs across the lanes.
 */
#ifndef NISFLOW_KERNELS_SPLINE_TILE_BACKWARD_H
#define NISFLOW_KERNELS_SPLINE_TILE_BACKWARD_H

#include "lanes.h"
#include "spline.h"
#include "spline_tile.h"

/* nf_spline_partials per lane. */
typedef struct nf_tile_partials {
    float dy_dxk[NF_TILE], dy_dwk[NF_TILE], dy_dhk[NF_TILE], dy_dd0[NF_TILE], dy_dd1[NF_TILE];
    float dl_dx[NF_TILE], dl_dxk[NF_TILE], dl_dwk[NF_TILE], dl_dhk[NF_TILE];
    float dl_dd0[NF_TILE], dl_dd1[NF_TILE];
} nf_tile_partials;

/* The partials of y and log(dy/dx) at x[lane], in the lane's bin b. */
static inline void nf_tile_partials_at(const nf_tile_bin *b, const float *x, nf_tile_partials *p)
{
    for (uint32_t i = 0; i < NF_TILE; ++i) {
        nf_spline_bin bin = nf_tile_bin_lane(b, i);
        nf_spline_partials q;
        nf_spline_partials_at(&bin, x[i], &q);
        p->dy_dxk[i] = q.dy_dxk;
        p->dy_dwk[i] = q.dy_dwk;
        p->dy_dhk[i] = q.dy_dhk;
        p->dy_dd0[i] = q.dy_dd0;
        p->dy_dd1[i] = q.dy_dd1;
        p->dl_dx[i] = q.dl_dx;
        p->dl_dxk[i] = q.dl_dxk;
        p->dl_dwk[i] = q.dl_dwk;
        p->dl_dhk[i] = q.dl_dhk;
        p->dl_dd0[i] = q.dl_dd0;
        p->dl_dd1[i] = q.dl_dd1;
    }
}

/* nf_knots_backward for every lane: the gradient g_pos on knot k[lane] (as position) and
 * g_width on the width of bin k[lane], back to the softmax inputs raw_grad[0..bins). Bin b's
 * share gw is g_lo + g_hi below k, g_hi at k and 0 above, as in nf_knots_backward (where the
 * sums with 0 are exact). The lanes type keeps dot in a register and the selects branch-free;
 * written as plain loops GCC left them scalar. */
static inline void nf_tile_knots_backward(uint32_t bins, const uint32_t *k,
                                          const float (*soft)[NF_TILE], const float *g_pos,
                                          const float *g_width, float (*raw_grad)[NF_TILE])
{
    const float scale = 1.0f - (float)bins * NF_SPLINE_MIN;
    float below[NF_TILE], at[NF_TILE];
    for (uint32_t i = 0; i < NF_TILE; ++i) {
        float g_hi = k[i] + 1 < bins ? g_width[i] : 0.0f;
        below[i] = (g_pos[i] - g_width[i]) + g_hi;
        at[i] = g_hi;
    }
    nf_lanes lo, hi, dot, gw, t, sb, zero;
    nf_lanes_load(&lo, below);
    nf_lanes_load(&hi, at);
    nf_lanes_splat(&zero, 0.0f);
    nf_lanes_splat(&dot, 0.0f);
    for (uint32_t b = 0; b < bins; ++b) {
        gw = zero;
        nf_lanes_pick(&gw, k, b, &hi);
        nf_lanes_pick_above(&gw, k, b, &lo);
        nf_lanes_load(&t, soft[b]);
        nf_lanes_mul(&t, &gw);
        nf_lanes_add(&dot, &t);
    }
    for (uint32_t b = 0; b < bins; ++b) {
        gw = zero;
        nf_lanes_pick(&gw, k, b, &hi);
        nf_lanes_pick_above(&gw, k, b, &lo);
        nf_lanes_sub(&gw, &dot);
        nf_lanes_splat(&t, scale);
        nf_lanes_load(&sb, soft[b]);
        nf_lanes_mul(&t, &sb);
        nf_lanes_mul(&t, &gw);
        nf_lanes_load(&gw, raw_grad[b]);
        nf_lanes_add(&gw, &t);
        nf_lanes_store(raw_grad[b], &gw);
    }
}

/* Adds to raw_grad[r][lane] (3K+1 rows) the gradient of a[lane] y + b[lane] log(dy/dx) at the
 * lane's point, whose bin and partials are given; as nf_spline_raw_backward. */
static inline void nf_tile_spline_raw_backward(const nf_tile_spline *s, uint32_t bins,
                                               const nf_tile_bin *bin, const nf_tile_partials *p,
                                               const float *a, const float *b,
                                               float (*raw_grad)[NF_TILE])
{
    float g_pos[NF_TILE], g_width[NF_TILE], d0[NF_TILE], d1[NF_TILE];
    for (uint32_t i = 0; i < NF_TILE; ++i) {
        g_pos[i] = a[i] * p->dy_dxk[i] + b[i] * p->dl_dxk[i];
        g_width[i] = a[i] * p->dy_dwk[i] + b[i] * p->dl_dwk[i];
    }
    nf_tile_knots_backward(bins, bin->k, (const float(*)[NF_TILE])s->sw, g_pos, g_width, raw_grad);
    for (uint32_t i = 0; i < NF_TILE; ++i) {
        g_pos[i] = a[i];
        g_width[i] = a[i] * p->dy_dhk[i] + b[i] * p->dl_dhk[i];
    }
    nf_tile_knots_backward(bins, bin->k, (const float(*)[NF_TILE])s->sh, g_pos, g_width,
                           raw_grad + bins);
    for (uint32_t i = 0; i < NF_TILE; ++i) {
        d0[i] = (a[i] * p->dy_dd0[i] + b[i] * p->dl_dd0[i]) * bin->sd0[i];
        d1[i] = (a[i] * p->dy_dd1[i] + b[i] * p->dl_dd1[i]) * bin->sd1[i];
    }
    /* The raw derivatives of knots k and k + 1, selected over the K + 1 rows. */
    uint32_t k1[NF_TILE];
    for (uint32_t i = 0; i < NF_TILE; ++i)
        k1[i] = bin->k[i] + 1;
    nf_lanes l0, l1, d, r;
    nf_lanes_load(&l0, d0);
    nf_lanes_load(&l1, d1);
    for (uint32_t j = 0; j <= bins; ++j) {
        nf_lanes_splat(&d, 0.0f);
        nf_lanes_pick(&d, bin->k, j, &l0);
        nf_lanes_pick(&d, k1, j, &l1);
        nf_lanes_load(&r, raw_grad[2 * bins + j]);
        nf_lanes_add(&r, &d);
        nf_lanes_store(raw_grad[2 * bins + j], &r);
    }
}

#endif /* NISFLOW_KERNELS_SPLINE_TILE_BACKWARD_H */
