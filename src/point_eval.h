/*
 * point_eval.h - the shading-point kernels behind nisflow/point.h, as inline code that
 * kernel.c compiles once per instruction set: prepare a point, then draw and evaluate single
 * directions at it.
 *
 * Prepare stores, per coupling layer, the context's share of the first hidden layer
 * (nf_input_layer_context: bias, position one-blobs, SH of normal and wo). Each direction then
 * adds the three one-blob slots of its pass-through coordinate (nf_input_layer_blob) and runs
 * the rest of the conditioner, the spline and the maps of sphere.h: the same functions, in the
 * same order, as the per-sample and tile paths, so the results are the same bits.
 */
#ifndef NISFLOW_POINT_EVAL_H
#define NISFLOW_POINT_EVAL_H

#include "conditioner.h"
#include "flow_eval.h"
#include "internal.h"
#include "prior_eval.h"
#include "spline_eval.h"

/* What one direction needs beyond the point: two rows of hidden activations (ping-pong), the
 * raw spline parameters and the spline's knots, about 2.9 KiB at the configuration limits. */
typedef struct nf_point_scratch {
    float act[2][NF_PAD(NF_MAX_HIDDEN_WIDTH)];
    float raw[NF_MAX_RAW_PADDED];
    nf_spline spline;
} nf_point_scratch;

/* The context's first-layer sums of coupling layer `layer` from the encodings `feat`. */
static inline void nf_point_layer_sums(const nf_model *m, const nf_point *feat, uint32_t layer,
                                       float *into)
{
    const nf_linear *lin = &m->packed_linear[layer][0];
    const uint32_t hp = lin->stride;
    const float *w = m->packed + lin->weight;
    nf_input_layer_context(w, m->packed + lin->bias, hp, feat->rows, feat->values,
                           w + (size_t)4u * m->cfg.oneblob_bins * hp, feat->sh, 1,
                           2u * m->cfg.sh_bands * m->cfg.sh_bands, into);
}

/* The same sums from the point's cache, or computed into `into` from `feat` when the model
 * is too large for the cache. */
static inline const float *nf_point_context_sums(const nf_model *m, const nf_shading_point *p,
                                                 const nf_point *feat, uint32_t layer,
                                                 float *into)
{
    if (p->cached_)
        return p->cache_ + (size_t)layer * m->packed_linear[layer][0].stride;
    nf_point_layer_sums(m, feat, layer, into);
    return into;
}

/* Raw spline parameters of coupling layer `layer` into sc->raw, from the pass-through
 * coordinate v: nf_conditioner_forward with the context's share read from the point. */
static inline void nf_point_conditioner(const nf_model *m, const nf_shading_point *p,
                                        const nf_point *feat, uint32_t layer, float v,
                                        nf_point_scratch *sc)
{
    const nf_linear *lin = m->packed_linear[layer];
    const float *packed = m->packed;
    const uint32_t depth = m->cfg.hidden_layers, width = m->cfg.hidden_width;
    const uint32_t hp = lin[0].stride;
    const float *ctx = nf_point_context_sums(m, p, feat, layer, sc->act[0]);
    uint32_t rows[3];
    float vals[3];
    nf_oneblob_slots(v, m->cfg.oneblob_bins, 0, rows, vals);
    nf_input_layer_blob(ctx, packed + lin[0].weight, hp, rows, vals, sc->act[0]);
    nf_relu(sc->act[0], hp);
    const float *h = sc->act[0];
    for (uint32_t l = 1; l < depth; ++l) {
        float *o = sc->act[l & 1u];
        nf_dense_one(o, packed + lin[l].weight, hp, packed + lin[l].bias, h, width);
        nf_relu(o, hp);
        h = o;
    }
    nf_dense_one(sc->raw, packed + lin[depth].weight, lin[depth].stride,
                 packed + lin[depth].bias, h, width);
    for (uint32_t r = 0; r < m->raw_dim; ++r)
        sc->raw[r] = nf_clampf(sc->raw[r], -NF_RAW_LIMIT, NF_RAW_LIMIT);
}

/* The prior's view of the point (nf_prior_sample and nf_prior_density read the unit normal,
 * the context handed to callbacks and the callbacks). */
static inline void nf_point_prior_view(const nf_shading_point *p, const nf_context *user,
                                       nf_point *view)
{
    view->user = user;
    view->prior = &p->prior_;
    for (uint32_t a = 0; a < 3; ++a)
        view->ctx.normal[a] = p->frame_[a];
}

/* Writes the point for a validated context; prior NULL keeps the model's callbacks. */
static inline void nf_point_prepare_at(const nf_model *m, const nf_context *ctx,
                                       const nf_prior_callbacks *prior, nf_shading_point *p)
{
    nf_point feat;
    nf_context_features(m, ctx, &feat);
    const uint32_t layers = m->cfg.coupling_layers, hp = m->packed_linear[0][0].stride;
    p->context_ = *ctx;
    p->magic_ = NF_POINT_MAGIC;
    p->model_id_ = m->id;
    p->generation_ = m->generation;
    p->prior_ = prior ? *prior : m->cfg.custom_prior;
    for (uint32_t a = 0; a < 3; ++a)
        p->frame_[a] = feat.ctx.normal[a];
    p->cached_ = (size_t)layers * hp <= NF_SHADING_POINT_CACHE_FLOATS;
    for (uint32_t r = 0; r < sizeof p->reserved_ / sizeof p->reserved_[0]; ++r)
        p->reserved_[r] = 0;
    p->check_ = nf_point_hash(p);
    if (!p->cached_)
        return;
    for (uint32_t i = 0; i < layers; ++i)
        nf_point_layer_sums(m, &feat, i, p->cache_ + (size_t)i * hp);
}

/* One direction drawn at the point (nf_sample_one's arithmetic). `user` is the context that
 * custom prior callbacks receive. */
static inline nf_status nf_point_sample_one(const nf_model *m, const nf_shading_point *p,
                                            const nf_point *feat, const nf_context *user,
                                            const float u[2], float dir[3], float *pdf,
                                            nf_point_scratch *sc)
{
    nf_point view;
    nf_point_prior_view(p, user, &view);
    float x[2], q;
    nf_status st = nf_prior_sample(m, &view, u[0], u[1], x, &q);
    if (st != NF_OK)
        return st;
    double det = 1.0;
    for (uint32_t i = 0; i < m->cfg.coupling_layers; ++i) {
        uint32_t t = nf_transformed(i);
        nf_point_conditioner(m, p, feat, i, x[1 - t], sc);
        nf_spline_build(&sc->spline, m->cfg.spline_bins, sc->raw);
        nf_spline_bin bin;
        nf_spline_bin_at(&sc->spline, nf_spline_find(sc->spline.x, m->cfg.spline_bins, x[t]),
                         &bin);
        float slope;
        x[t] = nf_spline_bin_eval(&bin, x[t], &slope);
        det *= slope;
    }
    /* One ulp below 1, as nf_sample: phi = 2 pi would map back across the seam. */
    x[1] = nf_minf(x[1], 0x1.fffffep-1f);
    nf_from_square(x, dir);
    if (pdf)
        *pdf = nf_solid_angle_pdf((double)q / det, x[0]);
    return NF_OK;
}

/* The solid-angle density of one direction at the point (nf_pdf_one's arithmetic). */
static inline nf_status nf_point_pdf_one(const nf_model *m, const nf_shading_point *p,
                                         const nf_point *feat, const nf_context *user,
                                         const float dir[3], float *pdf, nf_point_scratch *sc)
{
    float s[2], x[2];
    nf_to_square(dir, s);
    x[0] = s[0];
    x[1] = s[1];
    double inv_det = 1.0;
    for (uint32_t i = m->cfg.coupling_layers; i-- > 0;) {
        uint32_t t = nf_transformed(i);
        nf_point_conditioner(m, p, feat, i, x[1 - t], sc);
        nf_spline_build(&sc->spline, m->cfg.spline_bins, sc->raw);
        nf_spline_bin bin;
        nf_spline_bin_at(&sc->spline, nf_spline_find(sc->spline.y, m->cfg.spline_bins, x[t]),
                         &bin);
        float solved = nf_spline_bin_solve(&bin, x[t]), slope;
        nf_spline_bin_eval(&bin, solved, &slope);
        x[t] = solved;
        inv_det /= slope;
    }
    nf_point view;
    nf_point_prior_view(p, user, &view);
    float q;
    nf_status st = nf_prior_density(m, &view, x, &q, NULL);
    if (st != NF_OK)
        return st;
    *pdf = nf_solid_angle_pdf((double)q * inv_det, s[0]);
    return NF_OK;
}

#endif /* NISFLOW_POINT_EVAL_H */
