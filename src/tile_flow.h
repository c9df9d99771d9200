/*
 * tile_flow.h - nf_sample and nf_pdf for a tile of samples: the prior (SPEC section 2) and the
 * coupling flow (section 4) over the tile layout of tile.h, on the conditioners of
 * tile_conditioner.h and the splines of tile_spline.h. The per-lane arithmetic is that of
 * prior_eval.h, sphere.h and flow_eval.h; custom priors call their callbacks lane by lane,
 * for real samples only.
 */
#ifndef NISFLOW_TILE_FLOW_H
#define NISFLOW_TILE_FLOW_H

#include "flow_eval.h"
#include "tile_conditioner.h"
#include "tile_spline.h"

/* Everything one tile needs, about 52 KiB: kernels declare it once per call, on the stack. */
typedef struct nf_tile_work {
    nf_tile tile;
    nf_tile_blob blob;                  /* one-blob of the pass-through coordinate */
    float act[NF_TILE_ACT_ROWS(2)][NF_TILE];
    float raw[NF_MAX_RAW_PADDED][NF_TILE]; /* nf_tile_dense_layer writes 8 rows at a time */
    nf_tile_spline spline;
    nf_tile_bin bin;
} nf_tile_work;

/* The per-sample view of lane i that custom prior callbacks need (the caller's context and
 * the unit normal); the encodings are not filled. */
static inline void nf_tile_point(const nf_tile *tile, uint32_t i, nf_prior_point *pt)
{
    pt->user = tile->user[i];
    pt->prior = tile->prior;
    for (uint32_t a = 0; a < 3; ++a)
        pt->normal[a] = tile->normal[a][i];
}

/* Custom prior, lane by lane: z[.][i] and q[i] from u for the real samples; padding lanes
 * copy lane 0. */
static inline nf_status nf_tile_custom_sample(const nf_model *m, const nf_tile *tile,
                                              const float *u0, const float *u1,
                                              float (*z)[NF_TILE], float *q)
{
    for (uint32_t i = 0; i < NF_TILE; ++i) {
        if (i >= tile->count) {
            z[0][i] = z[0][0];
            z[1][i] = z[1][0];
            q[i] = q[0];
            continue;
        }
        nf_prior_point pt;
        float zi[2];
        nf_tile_point(tile, i, &pt);
        nf_status st = nf_prior_sample(m, &pt, u0[i], u1[i], zi, &q[i]);
        if (st != NF_OK)
            return st;
        z[0][i] = zi[0];
        z[1][i] = zi[1];
    }
    return NF_OK;
}

/* The prior's density q_s(z) on the square for every lane. */
static inline nf_status nf_tile_prior_density(const nf_model *m, const nf_tile *tile,
                                              const float (*z)[NF_TILE], float *q)
{
    const float eps = m->cfg.prior_epsilon;
    switch (m->cfg.prior) {
    case NF_PRIOR_UNIFORM_ANGLE:
        for (uint32_t i = 0; i < NF_TILE; ++i)
            q[i] = 1.0f;
        return NF_OK;
    case NF_PRIOR_UNIFORM_DIRECTION:
        for (uint32_t i = 0; i < NF_TILE; ++i) {
            float zi[2] = {z[0][i], z[1][i]}, w[3];
            q[i] = NF_HALF_PI * nf_maxf(nf_from_square(zi, w), NF_SIN_THETA_MIN);
        }
        return NF_OK;
    case NF_PRIOR_COSINE:
        /* as nf_prior_density: q_s = sin(theta) ((1 - eps) 2 pi max(0, n.w) + eps pi / 2) */
        for (uint32_t i = 0; i < NF_TILE; ++i) {
            float zi[2] = {z[0][i], z[1][i]}, w[3];
            float sin_theta = nf_maxf(nf_from_square(zi, w), NF_SIN_THETA_MIN);
            float c = tile->normal[0][i] * w[0] + tile->normal[1][i] * w[1] +
                      tile->normal[2][i] * w[2];
            q[i] = sin_theta * ((1.0f - eps) * NF_TWO_PI * nf_maxf(c, 0.0f) + eps * NF_HALF_PI);
        }
        return NF_OK;
    case NF_PRIOR_CUSTOM:
        break;
    }
    for (uint32_t i = 0; i < tile->count; ++i) {
        nf_prior_point pt;
        float zi[2] = {z[0][i], z[1][i]};
        nf_tile_point(tile, i, &pt);
        nf_status st = nf_prior_density(m, &pt, zi, &q[i], NULL);
        if (st != NF_OK)
            return st;
    }
    for (uint32_t i = tile->count; i < NF_TILE; ++i)
        q[i] = q[0];
    return NF_OK;
}

/* Latent points z[.][lane] and their densities q[lane] from u, as nf_prior_sample. */
static inline nf_status nf_tile_prior_sample(const nf_model *m, const nf_tile *tile,
                                             const float *u0_in, const float *u1_in,
                                             float (*z)[NF_TILE], float *q)
{
    const float eps = m->cfg.prior_epsilon;
    float u0[NF_TILE], u1[NF_TILE];
    for (uint32_t i = 0; i < NF_TILE; ++i) {
        u0[i] = nf_clamp_unit(u0_in[i]);
        u1[i] = nf_clamp_unit(u1_in[i]);
    }
    switch (m->cfg.prior) {
    case NF_PRIOR_UNIFORM_ANGLE:
        for (uint32_t i = 0; i < NF_TILE; ++i) {
            z[0][i] = u0[i];
            z[1][i] = u1[i];
        }
        break;
    case NF_PRIOR_UNIFORM_DIRECTION:
        for (uint32_t i = 0; i < NF_TILE; ++i) {
            float zi[2];
            nf_uniform_sphere_square(u0[i], u1[i], zi);
            z[0][i] = zi[0];
            z[1][i] = zi[1];
        }
        break;
    case NF_PRIOR_COSINE:
        /* Both mixture components for every lane, then a select: a branch per lane would
         * keep the loop from vectorizing. The component picked is nf_prior_sample's. */
        for (uint32_t i = 0; i < NF_TILE; ++i) {
            float n[3] = {tile->normal[0][i], tile->normal[1][i], tile->normal[2][i]};
            float w[3], zc[2], zu[2];
            nf_cosine_direction(n, nf_clamp_unit(u0[i] / (1.0f - eps)), u1[i], w);
            nf_to_square(w, zc);
            nf_uniform_sphere_square(nf_clamp_unit((u0[i] - (1.0f - eps)) / eps), u1[i], zu);
            int cosine = u0[i] < 1.0f - eps;
            z[0][i] = cosine ? zc[0] : zu[0];
            z[1][i] = cosine ? zc[1] : zu[1];
        }
        break;
    case NF_PRIOR_CUSTOM:
        return nf_tile_custom_sample(m, tile, u0, u1, z, q);
    }
    return nf_tile_prior_density(m, tile, (const float(*)[NF_TILE])z, q);
}

/* One coupling layer's conditioner and splines for the tile, given the current point x. */
static inline void nf_tile_layer_splines(const nf_model *m, uint32_t layer,
                                         const float (*x)[NF_TILE], nf_tile_work *w)
{
    uint32_t t = nf_transformed(layer);
    nf_tile_oneblob(x[1 - t], m->cfg.oneblob_bins, 0, &w->blob);
    nf_tile_conditioner_forward(m, layer, &w->tile, &w->blob, w->act, 2, w->raw);
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
        nf_tile_spline_forward(&w->spline, bins, (const float(*)[NF_TILE])(w->raw + 2 * bins),
                               x[t], slope, &w->bin);
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
        nf_tile_spline_inverse(&w->spline, bins, (const float(*)[NF_TILE])(w->raw + 2 * bins),
                               x[t], slope, &w->bin);
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

#endif /* NISFLOW_TILE_FLOW_H */
