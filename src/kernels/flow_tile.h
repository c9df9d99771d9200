/*
 * flow_tile.h - nf_sample and nf_pdf for a tile of samples: the coupling flow (docs/theory.md
 * section 4) over the tile layout of tile.h, from the priors of prior_tile.h, on the
 * conditioners of conditioner_tile.h and the splines of spline_tile.h. The per-lane
 * arithmetic is that of prior.h, sphere.h and flow.h.
 */
#ifndef NISFLOW_KERNELS_FLOW_TILE_H
#define NISFLOW_KERNELS_FLOW_TILE_H

#include "conditioner_tile.h"
#include "flow.h"
#include "prior_tile.h"
#include "spline_tile.h"

/* Everything one tile needs, about 52 KiB: kernels declare it once per call, on the stack. */
typedef struct nf_tile_work {
    nf_tile tile;
    nf_tile_blob blob; /* one-blob of the pass-through coordinate */
    float act[NF_TILE_ACT_ROWS(2)][NF_TILE];
    float raw[NF_MAX_RAW_PADDED][NF_TILE]; /* nf_tile_dense_layer writes 8 rows at a time */
    nf_tile_spline spline;
    nf_tile_bin bin;
    float rotation_raw[NF_TILE]; /* a circular layer's rotations, raw (circle.h) */
} nf_tile_work;

/* One coupling layer's conditioner and splines for the tile, given the current point x. */
static inline void nf_tile_layer_splines(const nf_model *m, uint32_t layer,
                                         const float (*x)[NF_TILE], nf_tile_work *w)
{
    uint32_t t = nf_transformed(layer);
    nf_tile_oneblob(x[1 - t], m->cfg.oneblob_bins, 0, nf_layer_wraps(m, layer), &w->blob);
    nf_tile_conditioner_forward(m, layer, &w->tile, &w->blob, w->act, 2, w->raw);
    if (nf_layer_circular(m, layer))
        nf_tile_circular_take_rotation(w->raw, m->cfg.spline_bins, w->rotation_raw);
    nf_tile_spline_build(&w->spline, m->cfg.spline_bins, (const float(*)[NF_TILE])w->raw);
}

/* nf_sample for ctx[0..count), u[2 count], count in 1..NF_TILE. */
static inline nf_status nf_tile_sample(const nf_model *m, const nf_context *ctx, const float *u,
                                       uint32_t count, float *dir, float *pdf, nf_tile_work *w)
{
    const uint32_t bins = m->cfg.spline_bins;
    float x[2][NF_TILE], u0[NF_TILE], u1[NF_TILE], q[NF_TILE], slope[NF_TILE];
    double det[NF_TILE];
    nf_tile_prepare(m, ctx, count, &w->tile);
    for (uint32_t i = 0; i < NF_TILE; ++i) {
        uint32_t j = i < count ? i : 0;
        u0[i] = u[2 * j];
        u1[i] = u[2 * j + 1];
        det[i] = 1.0;
    }
    nf_status st = nf_tile_prior_sample(m, &w->tile, u0, u1, x, q);
    if (st != NF_OK)
        return st;
    for (uint32_t layer = 0; layer < m->cfg.coupling_layers; ++layer) {
        uint32_t t = nf_transformed(layer);
        nf_tile_layer_splines(m, layer, (const float(*)[NF_TILE])x, w);
        nf_tile_spline_forward(&w->spline, bins, (const float(*)[NF_TILE])(w->raw + 2 * bins), x[t],
                               slope, &w->bin);
        if (nf_layer_turns(m, layer))
            for (uint32_t i = 0; i < NF_TILE; ++i)
                x[t][i] = nf_wrap_unit(x[t][i] + nf_rotation(w->rotation_raw[i], bins));
        for (uint32_t i = 0; i < NF_TILE; ++i)
            det[i] *= slope[i];
    }
    float out[3][NF_TILE], p[NF_TILE];
    for (uint32_t i = 0; i < NF_TILE; ++i) {
        /* s1 one ulp below 1 at most, as in nf_sample_one (kernel.c):
         * nf_pdf maps phi = 2 pi back to the other side of the seam. */
        float s[2] = {x[0][i], nf_minf(x[1][i], 0x1.fffffep-1f)}, d[3];
        nf_from_square(s, d);
        for (uint32_t a = 0; a < 3; ++a)
            out[a][i] = d[a];
        p[i] = nf_solid_angle_pdf((double)q[i] / det[i], s[0]);
    }
    for (uint32_t i = 0; i < count; ++i)
        for (uint32_t a = 0; a < 3; ++a)
            dir[3 * i + a] = out[a][i];
    if (pdf)
        for (uint32_t i = 0; i < count; ++i)
            pdf[i] = p[i];
    return NF_OK;
}

/* nf_pdf for ctx[0..count), dir[3 count], count in 1..NF_TILE. */
static inline nf_status nf_tile_pdf(const nf_model *m, const nf_context *ctx, const float *dir,
                                    uint32_t count, float *pdf, nf_tile_work *w)
{
    const uint32_t bins = m->cfg.spline_bins;
    float s[2][NF_TILE], x[2][NF_TILE], q[NF_TILE], slope[NF_TILE], p[NF_TILE];
    double inv_det[NF_TILE];
    float d[3][NF_TILE];
    nf_tile_prepare(m, ctx, count, &w->tile);
    for (uint32_t i = 0; i < NF_TILE; ++i)
        for (uint32_t a = 0; a < 3; ++a)
            d[a][i] = dir[3 * (i < count ? i : 0) + a];
    for (uint32_t i = 0; i < NF_TILE; ++i) {
        float di[3] = {d[0][i], d[1][i], d[2][i]}, si[2];
        nf_to_square(di, si);
        s[0][i] = x[0][i] = si[0];
        s[1][i] = x[1][i] = si[1];
        inv_det[i] = 1.0;
    }
    for (uint32_t layer = m->cfg.coupling_layers; layer-- > 0;) {
        uint32_t t = nf_transformed(layer);
        nf_tile_layer_splines(m, layer, (const float(*)[NF_TILE])x, w);
        if (nf_layer_turns(m, layer))
            for (uint32_t i = 0; i < NF_TILE; ++i)
                x[t][i] = nf_wrap_unit(x[t][i] - nf_rotation(w->rotation_raw[i], bins));
        nf_tile_spline_inverse(&w->spline, bins, (const float(*)[NF_TILE])(w->raw + 2 * bins), x[t],
                               slope, &w->bin);
        for (uint32_t i = 0; i < NF_TILE; ++i)
            inv_det[i] /= slope[i];
    }
    nf_status st = nf_tile_prior_density(m, &w->tile, (const float(*)[NF_TILE])x, q);
    if (st != NF_OK)
        return st;
    for (uint32_t i = 0; i < NF_TILE; ++i)
        p[i] = nf_solid_angle_pdf((double)q[i] * inv_det[i], s[0][i]);
    for (uint32_t i = 0; i < count; ++i)
        pdf[i] = p[i];
    return NF_OK;
}

#endif /* NISFLOW_KERNELS_FLOW_TILE_H */
