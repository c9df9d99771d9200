/*
 * spline_tile.h - the rational-quadratic splines of docs/theory.md section 3 for a tile of samples:
 * one spline per lane, every loop across the lanes. The per-lane arithmetic is spline.h's own
 * inline functions, so a tile computes exactly what the per-sample code computes; only the knot
 * search and the bin's quantities are gathered differently (by comparison and select over the bins
 * instead of indexing, which would not vectorize).
 */
#ifndef NISFLOW_KERNELS_SPLINE_TILE_H
#define NISFLOW_KERNELS_SPLINE_TILE_H

#include "lanes.h"
#include "spline.h"
#include "tile.h"

/* The knots of a tile's splines, [knot][lane], and their softmaxes (kept for gradients). */
typedef struct nf_tile_spline {
    float x[NF_MAX_SPLINE_BINS + 1][NF_TILE];
    float y[NF_MAX_SPLINE_BINS + 1][NF_TILE];
    float sw[NF_MAX_SPLINE_BINS][NF_TILE];
    float sh[NF_MAX_SPLINE_BINS][NF_TILE];
} nf_tile_spline;

/* The bin each lane's point falls in, with nf_spline_bin's quantities per lane. */
typedef struct nf_tile_bin {
    uint32_t k[NF_TILE];
    float xk[NF_TILE], wk[NF_TILE], yk[NF_TILE], hk[NF_TILE];
    float x1[NF_TILE], y1[NF_TILE];
    float d0[NF_TILE], d1[NF_TILE], sd0[NF_TILE], sd1[NF_TILE];
} nf_tile_bin;

/* nf_spline_knots for every lane, in the same order of operations. */
static inline void nf_tile_knots(uint32_t bins, const float (*raw)[NF_TILE],
                                 float (*knots)[NF_TILE], float (*soft)[NF_TILE])
{
    const float scale = 1.0f - (float)bins * NF_SPLINE_MIN;
    nf_lanes top, sum, inv, acc, x, step, min;
    nf_lanes_load(&top, raw[0]);
    for (uint32_t b = 1; b < bins; ++b) {
        nf_lanes_load(&x, raw[b]);
        nf_lanes_max(&top, &x);
    }
    float t[NF_TILE];
    nf_lanes_store(t, &top);
    nf_lanes_splat(&sum, 0.0f);
    for (uint32_t b = 0; b < bins; ++b) {
        for (uint32_t i = 0; i < NF_TILE; ++i)
            soft[b][i] = nf_fast_exp(raw[b][i] - t[i]);
        nf_lanes_load(&x, soft[b]);
        nf_lanes_add(&sum, &x);
    }
    nf_lanes_splat(&inv, 1.0f);
    nf_lanes_div(&inv, &sum);
    nf_lanes_splat(&acc, 0.0f);
    nf_lanes_store(knots[0], &acc);
    for (uint32_t b = 0; b < bins; ++b) {
        nf_lanes_load(&x, soft[b]);
        nf_lanes_mul(&x, &inv);
        nf_lanes_store(soft[b], &x);
        /* NF_SPLINE_MIN + scale * soft rounded twice, as nf_spline_knots: not a madd */
        nf_lanes_splat(&step, scale);
        nf_lanes_mul(&step, &x);
        nf_lanes_splat(&min, NF_SPLINE_MIN);
        nf_lanes_add(&step, &min);
        nf_lanes_add(&acc, &step);
        nf_lanes_store(knots[b + 1], &acc);
    }
    for (uint32_t i = 0; i < NF_TILE; ++i)
        knots[bins][i] = 1.0f; /* exactly 1, as in nf_spline_knots */
}

/* Knots of the tile's splines from raw[r][lane] (3K+1 rows). */
static inline void nf_tile_spline_build(nf_tile_spline *s, uint32_t bins,
                                        const float (*raw)[NF_TILE])
{
    nf_tile_knots(bins, raw, s->x, s->sw);
    nf_tile_knots(bins, raw + bins, s->y, s->sh);
}

/* The bin of v[lane] among `key` (s->x to evaluate, s->y to invert), as nf_spline_find and
 * nf_spline_bin_at; raw_d are the K+1 raw derivative rows. */
static inline void nf_tile_bin_select(const nf_tile_spline *s, uint32_t bins,
                                      const float (*raw_d)[NF_TILE], const float (*key)[NF_TILE],
                                      const float *v, nf_tile_bin *b)
{
    nf_lanes vl, kl;
    nf_lanes_load(&vl, v);
    for (uint32_t i = 0; i < NF_TILE; ++i)
        b->k[i] = 0;
    for (uint32_t j = 1; j < bins; ++j) {
        nf_lanes_load(&kl, key[j]);
        nf_lanes_count_ge(b->k, &vl, &kl);
    }
    /* The bin's knots and raw derivatives by compare-and-select over the bins: gathers
     * would need AVX2 and GCC does not emit them for generic tuning. Two passes of three
     * selections: six at once, with the index and the candidate, need more than AVX2's 16
     * registers (two per lanes value), and spill (docs/performance.md has the measurement). */
    nf_lanes xk, x1, yk, y1, r0, r1, t;
    nf_lanes_load(&xk, s->x[0]);
    nf_lanes_load(&x1, s->x[1]);
    nf_lanes_load(&yk, s->y[0]);
    for (uint32_t j = 1; j < bins; ++j) {
        nf_lanes_load(&t, s->x[j]);
        nf_lanes_pick(&xk, b->k, j, &t);
        nf_lanes_load(&t, s->x[j + 1]);
        nf_lanes_pick(&x1, b->k, j, &t);
        nf_lanes_load(&t, s->y[j]);
        nf_lanes_pick(&yk, b->k, j, &t);
    }
    nf_lanes_load(&y1, s->y[1]);
    nf_lanes_load(&r0, raw_d[0]);
    nf_lanes_load(&r1, raw_d[1]);
    for (uint32_t j = 1; j < bins; ++j) {
        nf_lanes_load(&t, s->y[j + 1]);
        nf_lanes_pick(&y1, b->k, j, &t);
        nf_lanes_load(&t, raw_d[j]);
        nf_lanes_pick(&r0, b->k, j, &t);
        nf_lanes_load(&t, raw_d[j + 1]);
        nf_lanes_pick(&r1, b->k, j, &t);
    }
    float rd0[NF_TILE], rd1[NF_TILE];
    nf_lanes_store(b->xk, &xk);
    nf_lanes_store(b->x1, &x1);
    nf_lanes_store(b->yk, &yk);
    nf_lanes_store(b->y1, &y1);
    nf_lanes_store(rd0, &r0);
    nf_lanes_store(rd1, &r1);
    /* c = log(exp(1 - m) - 1), as in nf_spline_bin_at */
    const float shift = 0.53974242f;
    for (uint32_t i = 0; i < NF_TILE; ++i) {
        float sp0, sp1;
        b->wk[i] = b->x1[i] - b->xk[i];
        b->hk[i] = b->y1[i] - b->yk[i];
        nf_softplus(rd0[i] + shift, &sp0, &b->sd0[i]);
        nf_softplus(rd1[i] + shift, &sp1, &b->sd1[i]);
        b->d0[i] = NF_SPLINE_MIN + sp0;
        b->d1[i] = NF_SPLINE_MIN + sp1;
    }
}

/* Lane i of a tile bin as the per-sample struct, for spline.h's arithmetic. */
static inline nf_spline_bin nf_tile_bin_lane(const nf_tile_bin *b, uint32_t i)
{
    nf_spline_bin bin;
    bin.k = b->k[i];
    bin.xk = b->xk[i];
    bin.wk = b->wk[i];
    bin.yk = b->yk[i];
    bin.hk = b->hk[i];
    bin.d0 = b->d0[i];
    bin.d1 = b->d1[i];
    bin.x1 = b->x1[i];
    bin.y1 = b->y1[i];
    bin.sd0 = b->sd0[i];
    bin.sd1 = b->sd1[i];
    return bin;
}

/* v[lane] <- S(v[lane]); slope[lane] = S'. */
static inline void nf_tile_spline_forward(const nf_tile_spline *s, uint32_t bins,
                                          const float (*raw_d)[NF_TILE], float *v, float *slope,
                                          nf_tile_bin *b)
{
    nf_tile_bin_select(s, bins, raw_d, (const float(*)[NF_TILE])s->x, v, b);
    for (uint32_t i = 0; i < NF_TILE; ++i) {
        nf_spline_bin bin = nf_tile_bin_lane(b, i);
        v[i] = nf_spline_bin_eval(&bin, v[i], &slope[i]);
    }
}

/* v[lane] <- S^-1(v[lane]); slope[lane] = S' at the solution. */
static inline void nf_tile_spline_inverse(const nf_tile_spline *s, uint32_t bins,
                                          const float (*raw_d)[NF_TILE], float *v, float *slope,
                                          nf_tile_bin *b)
{
    nf_tile_bin_select(s, bins, raw_d, (const float(*)[NF_TILE])s->y, v, b);
    for (uint32_t i = 0; i < NF_TILE; ++i) {
        nf_spline_bin bin = nf_tile_bin_lane(b, i);
        float x = nf_spline_bin_solve(&bin, v[i]);
        nf_spline_bin_eval(&bin, x, &slope[i]);
        v[i] = x;
    }
}

#endif /* NISFLOW_KERNELS_SPLINE_TILE_H */
