/*
 * point.h - the shading-point kernels behind nisflow/point.h, as inline code that
 * kernel.c compiles once per instruction set: prepare a point, then draw and evaluate single
 * directions at it.
 *
 * Prepare stores, per coupling layer, the context's share of the first hidden layer
 * (nf_input_layer_context: bias, position one-blobs, SH of normal and wo). Each direction then
 * adds the three one-blob slots of its pass-through coordinate (nf_input_layer_blob) and runs
 * the rest of the conditioner, the spline and the maps of sphere.h: the same operations, in the
 * same order, as the per-sample and tile paths, so the results are the same bits. Where the
 * operations are laid out for one direction (a preset's hidden units kept in a register, the
 * knots' steps vectorized across bins ahead of their running sums), each is the tile's
 * operation on the same values, never a reassociated or fused one. This is the path of small
 * nf_sample / nf_pdf calls everywhere, and of the shading-point API except for the presets on
 * the AVX2 and AVX-512 kernels, which take point_vector.h (its own arithmetic, within a stated
 * bound; docs/architecture.md, "Which rule holds where").
 */
#ifndef NISFLOW_KERNELS_POINT_H
#define NISFLOW_KERNELS_POINT_H

#include "conditioner.h"
#include "flow.h"
#include "internal.h"
#include "prior.h"
#include "spline.h"

/* The architecture's sizes. The presets' shapes are passed as constants to flattened copies
 * of the per-direction functions (kernel.c), so that every loop over bins and units has a
 * constant trip count the compiler unrolls; other configurations read them from the model.
 * Same operations in the same order either way. */
typedef struct nf_point_shape {
    uint32_t layers;     /* coupling layers                          */
    uint32_t bins;       /* spline bins K                            */
    uint32_t blob_bins;  /* one-blob bins B                          */
    uint32_t depth;      /* hidden layers                            */
    uint32_t width;      /* hidden units                             */
    uint32_t hp;         /* hidden units padded to NF_CHUNK          */
    uint32_t raw;        /* 3K + 1                                   */
    uint32_t raw_stride; /* 3K + 1 padded to NF_CHUNK                */
    uint32_t lanes;      /* 1: a preset's shape, whose conditioner may keep its hidden units
                            in registers (nf_point_conditioner); 0: any shape, whose calls
                            keep the smaller stack frame of the path through memory */
    uint32_t circular;   /* the model's phi map is NF_PHI_CIRCULAR: read once per call, not
                            per layer, where the compiler must assume a vector store may have
                            changed the configuration (not part of the shape's identity) */
} nf_point_shape;

static inline nf_point_shape nf_point_shape_of(const nf_model *m)
{
    nf_point_shape s = {m->cfg.coupling_layers,
                        m->cfg.spline_bins,
                        m->cfg.oneblob_bins,
                        m->cfg.hidden_layers,
                        m->cfg.hidden_width,
                        NF_PAD(m->cfg.hidden_width),
                        m->raw_dim,
                        NF_PAD(m->raw_dim),
                        0u,
                        m->cfg.phi_map == NF_PHI_CIRCULAR};
    return s;
}

/* The circle's flags of layer `layer` (circle.h's nf_layer_circular, nf_layer_turns,
 * nf_layer_wraps) from the shape. */
static inline int nf_shape_circular(nf_point_shape sh, uint32_t layer)
{
    return sh.circular && nf_transformed(layer) == 1u;
}

static inline int nf_shape_turns(nf_point_shape sh, uint32_t layer)
{
    return sh.circular && layer == ((sh.layers - 1u) & ~1u);
}

static inline int nf_shape_wraps(nf_point_shape sh, uint32_t layer)
{
    return sh.circular && nf_transformed(layer) == 0u;
}

/* The knot derivatives a direction computes: all K + 1 of them, in whole vectors of NF_CHUNK
 * where the raw parameters' padding holds them (the presets: 16 and 32), so that no scalar
 * remainder of the vectorized softplus is left; the values past K + 1 are never read. */
static inline uint32_t nf_point_derivative_count(uint32_t bins, uint32_t raw_stride)
{
    return 2u * bins + NF_PAD(bins + 1u) <= raw_stride ? NF_PAD(bins + 1u) : bins + 1u;
}

/* What one direction needs beyond the point, as views into one array of floats that the
 * caller sizes for the shape (NF_POINT_WORK_FLOATS): the raw spline parameters, the knot
 * derivatives, and either the hidden activations (two rows, ping-pong) or, once the
 * conditioner is done with them, the spline's exps and knots. The presets need 98 and 194
 * floats, the configuration limits 626 (2.5 KiB). */
typedef struct nf_point_scratch {
    float *raw;    /* raw_stride                                            */
    float *d, *sd; /* NF_PAD(bins + 1) each: knot derivatives, their slopes */
    float *act[2]; /* hp each                                               */
    float *e;      /* 2 bins: exps (over act)                               */
    float *x, *y;  /* bins + 1 each: the knots (over act)                   */
} nf_point_scratch;

#define NF_POINT_MAX2(a, b) ((a) > (b) ? (a) : (b))
#define NF_POINT_WORK_FLOATS(raw_stride, bins, hp)                                                 \
    ((raw_stride) + 2u * NF_PAD((bins) + 1u) + NF_POINT_MAX2(2u * (hp), 4u * (bins) + 2u))

static inline void nf_point_scratch_in(float *work, nf_point_shape sh, nf_point_scratch *sc)
{
    sc->raw = work;
    sc->d = work + sh.raw_stride;
    sc->sd = sc->d + NF_PAD(sh.bins + 1u);
    float *shared = sc->sd + NF_PAD(sh.bins + 1u);
    sc->act[0] = shared;
    sc->act[1] = shared + sh.hp;
    sc->e = shared;
    sc->x = shared + 2 * sh.bins;
    sc->y = sc->x + sh.bins + 1;
}

/* The knots of both halves of each spline (widths into x, heights into y) from the 2K exps in
 * e, which it overwrites: nf_spline_knots_from_exps's operations on each half, in its order,
 * without keeping the softmax (only reverse mode reads it). The steps m + (1 - K m) softmax_i,
 * independent of one another, come first, in one loop over the 2K values (a vector or two for the
 * presets); only the running sums are sequential, as two independent chains. */
static NF_ALWAYS_INLINE void nf_point_knots(uint32_t bins, const nf_point_scratch *sc)
{
    float sum_w = 0.0f, sum_h = 0.0f;
    for (uint32_t i = 0; i < bins; ++i) {
        sum_w += sc->e[i];
        sum_h += sc->e[bins + i];
    }
    const float scale = 1.0f - (float)bins * NF_SPLINE_MIN;
    const float inv_w = 1.0f / sum_w, inv_h = 1.0f / sum_h;
    float *e = sc->e, *step = e; /* in place: the exps are not read again */
    for (uint32_t i = 0; i < 2 * bins; ++i)
        step[i] = NF_SPLINE_MIN + scale * (e[i] * (i < bins ? inv_w : inv_h));
    sc->x[0] = sc->y[0] = 0.0f;
    float acc_w = 0.0f, acc_h = 0.0f;
    for (uint32_t i = 0; i < bins; ++i) {
        acc_w += sc->e[i];
        acc_h += sc->e[bins + i];
        sc->x[i + 1] = acc_w;
        sc->y[i + 1] = acc_h;
    }
    sc->x[bins] = sc->y[bins] = 1.0f; /* exactly 1, as nf_spline_knots_from_exps pins it */
}

/* The spline of the raw parameters in sc->raw: knots and every knot derivative
 * (nf_spline_build's and nf_spline_bin_at's values). A circular spline's d_K is d_0
 * (circle.h); its rotation stays in raw[3K]. */
static NF_ALWAYS_INLINE void nf_point_spline(uint32_t bins, uint32_t raw_stride, int circular,
                                             const nf_point_scratch *sc)
{
    nf_spline_exps(bins, sc->raw, sc->e);
    nf_point_knots(bins, sc);
    nf_spline_derivatives(nf_point_derivative_count(bins, raw_stride) - 1u, sc->raw + 2 * bins,
                          sc->d, sc->sd);
    if (circular) {
        sc->d[bins] = sc->d[0];
        sc->sd[bins] = sc->sd[0];
    }
}

static inline void nf_point_bin(const nf_point_scratch *sc, uint32_t k, nf_spline_bin *bin)
{
    nf_spline_bin_with(sc->x, sc->y, k, sc->d[k], sc->sd[k], sc->d[k + 1], sc->sd[k + 1], bin);
}

/* The context's first-layer sums of coupling layer `layer` from its encodings: rows and
 * values of the 9 position one-blob slots and the 2 S^2 SH values. */
static inline void nf_point_layer_sums(const nf_model *m, const uint32_t rows[9],
                                       const float values[9], const float *sh, uint32_t layer,
                                       float *into)
{
    const nf_linear *lin = &m->packed_linear[layer][0];
    const uint32_t hp = lin->stride;
    const float *w = m->packed + lin->weight;
    nf_input_layer_context(w, m->packed + lin->bias, hp, rows, values,
                           w + (size_t)4u * m->cfg.oneblob_bins * hp, sh, 1,
                           2u * m->cfg.sh_bands * m->cfg.sh_bands, into);
}

/* A point too large for its cache keeps the encodings there instead: the 9 slots' rows (as
 * floats, exact below 2^24), their values, then the SH. 18 + 72 floats at most. */
#define NF_POINT_ROWS 0u
#define NF_POINT_VALUES 9u
#define NF_POINT_SH 18u
_Static_assert(NF_POINT_SH + 2u * NF_MAX_SH <= NF_SHADING_POINT_CACHE_FLOATS,
               "the encodings fit the point's cache");

/* The same sums from the point's cache, or computed into `into` from the encodings it keeps
 * when the model is too large to cache them. */
static inline const float *nf_point_context_sums(const nf_model *m, const nf_shading_point *p,
                                                 uint32_t layer, float *into)
{
    if (p->cached_)
        return p->cache_ + (size_t)layer * m->packed_linear[layer][0].stride;
    /* The hash covers the header, not the cache: a point whose cache was overwritten must
     * still not read outside the weights. Position rows lie in [B, 4B) (nf_context_features);
     * anything else, NaN included, becomes row B, so such a point gives wrong but finite
     * results, as point.h promises. */
    const uint32_t blob = m->cfg.oneblob_bins;
    uint32_t rows[9];
    for (uint32_t r = 0; r < 9; ++r) {
        float f = p->cache_[NF_POINT_ROWS + r];
        rows[r] = f >= (float)blob && f < (float)(4u * blob) ? (uint32_t)f : blob;
    }
    nf_point_layer_sums(m, rows, p->cache_ + NF_POINT_VALUES, p->cache_ + NF_POINT_SH, layer, into);
    return into;
}

/* Lane k of a chunk held in a register. */
static inline float nf_point_lane(const nf_lanes *v, uint32_t k)
{
#if defined(NF_LANES_VECTOR)
    return (*v)[k];
#else
    return v->v[k];
#endif
}

/* The most raw parameters (padded) the register path of nf_point_conditioner holds: the large
 * preset's 64. Wider outputs take the path through memory, so that the array of chunks costs
 * the stack of every call only 256 bytes per direction. */
#define NF_POINT_LANES_RAW 64u

/* y[0..stride) = bias + sum_k x[k] W[k] (nf_dense_one: the same multiply-adds in the same
 * order), for inputs that are one chunk of hidden units in a register, each broadcast from its
 * lane. Stored to memory instead and read back one float at a time, as nf_dense_one reads
 * them, the units waited on the store: a 16-lane store followed by single-float loads from it
 * cost the per-direction conditioner about a third of its time (AMD Zen 4). */
static NF_ALWAYS_INLINE void nf_point_dense_lanes(nf_lanes *y, const float *w, uint32_t stride,
                                                  const float *bias, const nf_lanes *x,
                                                  uint32_t inputs)
{
    for (uint32_t c = 0; c < stride; c += NF_CHUNK) {
        nf_lanes acc, row;
        nf_lanes_load(&acc, bias + c);
        for (uint32_t k = 0; k < inputs; ++k) {
            nf_lanes_load(&row, w + (size_t)k * stride + c);
            nf_lanes_madd(&acc, nf_point_lane(x, k), &row);
        }
        y[c / NF_CHUNK] = acc;
    }
}

/* The raw parameters' clamp (nf_conditioner_forward's nf_clampf, NaN to the lower bound) on a
 * chunk in a register, stored to out. The upper bound is nf_minf(t, hi) = -nf_maxf(-t, -hi)
 * (t is not NaN after the lower bound; negation by * -1 is exact, zeros' signs included). */
static inline void nf_point_clamp_store(float *out, const nf_lanes *v)
{
    nf_lanes r = *v, bound, flip;
    nf_lanes_splat(&bound, -NF_RAW_LIMIT);
    nf_lanes_splat(&flip, -1.0f);
    nf_lanes_max(&r, &bound); /* nf_maxf(v, -limit) */
    nf_lanes_mul(&r, &flip);
    nf_lanes_max(&r, &bound); /* -nf_minf(t, limit) */
    nf_lanes_mul(&r, &flip);
    nf_lanes_store(out, &r);
}

/* Raw spline parameters of coupling layer `layer` into sc->raw, from the pass-through
 * coordinate v: nf_conditioner_forward with the context's share read from the point. The
 * padding of raw is clamped too (finite values the spline never reads): whole vectors, no
 * remainder. Hidden layers of one chunk (both presets) stay in registers from the context sums
 * to the output layer (nf_point_dense_lanes); wider ones go through sc->act. */
static NF_ALWAYS_INLINE void nf_point_conditioner(const nf_model *m, nf_point_shape sh,
                                                  const nf_shading_point *p, uint32_t layer,
                                                  float v, const nf_point_scratch *sc)
{
    const float *packed = m->packed;
    const uint32_t hp = sh.hp;
    const nf_linear *lin = m->packed_linear[layer];
    const float *ctx = nf_point_context_sums(m, p, layer, sc->act[0]);
    uint32_t rows[3];
    float vals[3];
    nf_oneblob_slots(v, sh.blob_bins, 0, nf_shape_wraps(sh, layer), rows, vals);
    if (sh.lanes && hp == NF_CHUNK && sh.raw_stride <= NF_POINT_LANES_RAW) {
        /* nf_input_layer_blob, nf_relu and nf_dense_one on registers: same operations */
        nf_lanes h, row, zero, out[NF_POINT_LANES_RAW / NF_CHUNK];
        nf_lanes_splat(&zero, 0.0f);
        const float *w0 = packed + lin[0].weight;
        nf_lanes_load(&h, ctx);
        for (uint32_t s = 0; s < 3; ++s) {
            nf_lanes_load(&row, w0 + (size_t)rows[s] * hp);
            nf_lanes_madd(&h, vals[s], &row);
        }
        nf_lanes_max(&h, &zero);
        for (uint32_t l = 1; l < sh.depth; ++l) {
            nf_point_dense_lanes(out, packed + lin[l].weight, hp, packed + lin[l].bias, &h,
                                 sh.width);
            h = out[0];
            nf_lanes_max(&h, &zero);
        }
        nf_point_dense_lanes(out, packed + lin[sh.depth].weight, sh.raw_stride,
                             packed + lin[sh.depth].bias, &h, sh.width);
        for (uint32_t c = 0; c < sh.raw_stride / NF_CHUNK; ++c)
            nf_point_clamp_store(sc->raw + (size_t)c * NF_CHUNK, &out[c]);
        return;
    }
    nf_input_layer_blob(ctx, packed + lin[0].weight, hp, rows, vals, sc->act[0]);
    nf_relu(sc->act[0], hp);
    const float *h = sc->act[0];
    for (uint32_t l = 1; l < sh.depth; ++l) {
        float *o = sc->act[l & 1u];
        nf_dense_one(o, packed + lin[l].weight, hp, packed + lin[l].bias, h, sh.width);
        nf_relu(o, hp);
        h = o;
    }
    nf_dense_one(sc->raw, packed + lin[sh.depth].weight, sh.raw_stride, packed + lin[sh.depth].bias,
                 h, sh.width);
    for (uint32_t r = 0; r < sh.raw_stride; ++r)
        sc->raw[r] = nf_clampf(sc->raw[r], -NF_RAW_LIMIT, NF_RAW_LIMIT);
}

/* The prior's view of the point (nf_prior_sample and nf_prior_density read the unit normal,
 * the context handed to callbacks and the callbacks; in a medium the axis d = -wo / |wo| and
 * g, from the point's own copy of the context, with tile.h's arithmetic so that points and
 * batches agree to the bit). */
static inline void nf_point_prior_view(const nf_shading_point *p, const nf_context *user,
                                       nf_prior_point *view)
{
    view->user = user;
    view->prior = &p->prior_;
    view->medium = (uint32_t)nf_context_in_medium(&p->context_);
    view->g = 0.0f;
    for (uint32_t a = 0; a < 3; ++a) {
        view->normal[a] = p->frame_[a];
        view->axis[a] = 0.0f;
    }
    if (view->medium) {
        float wo[3];
        nf_normalize3(p->context_.wo, wo);
        view->g = p->context_.phase_g;
        for (uint32_t a = 0; a < 3; ++a)
            view->axis[a] = -wo[a];
    }
}

/* Writes the point for a validated context from its features; prior NULL keeps the model's
 * callbacks. */
static NF_ALWAYS_INLINE void nf_point_prepare_from(const nf_model *m, const nf_context *ctx,
                                                   const nf_prior_callbacks *prior,
                                                   const nf_point *feat, nf_shading_point *p)
{
    const uint32_t layers = m->cfg.coupling_layers, hp = m->packed_linear[0][0].stride;
    p->context_ = *ctx;
    p->magic_ = NF_POINT_MAGIC;
    p->model_id_ = m->id;
    p->generation_ = nf_generation_read(m); /* before any weight is read */
    p->prior_ = prior ? *prior : m->cfg.custom_prior;
    for (uint32_t a = 0; a < 3; ++a)
        p->frame_[a] = feat->ctx.normal[a];
    p->cached_ = (size_t)layers * hp <= NF_SHADING_POINT_CACHE_FLOATS;
    p->zero_ = 0;
    for (uint32_t r = 0; r < sizeof p->reserved_ / sizeof p->reserved_[0]; ++r)
        p->reserved_[r] = 0;
    p->check_ = 0; /* nf_point_prepare (point.c) seals public points; stack points need none */
    if (p->cached_) {
        for (uint32_t i = 0; i < layers; ++i)
            nf_point_layer_sums(m, feat->rows, feat->values, feat->sh, i,
                                p->cache_ + (size_t)i * hp);
        return;
    }
    for (uint32_t r = 0; r < 9; ++r) {
        p->cache_[NF_POINT_ROWS + r] = (float)feat->rows[r];
        p->cache_[NF_POINT_VALUES + r] = feat->values[r];
    }
    for (uint32_t k = 0; k < 2u * m->cfg.sh_bands * m->cfg.sh_bands; ++k)
        p->cache_[NF_POINT_SH + k] = feat->sh[k];
}

/* The point of the same-bits path (the tile's arithmetic throughout). */
static inline void nf_point_prepare_at(const nf_model *m, const nf_context *ctx,
                                       const nf_prior_callbacks *prior, nf_shading_point *p)
{
    nf_point feat;
    nf_context_features(m, ctx, &feat);
    nf_point_prepare_from(m, ctx, prior, &feat, p);
}

/* A walk through the flow for one direction: forward from a latent point (sampling) or
 * inverse from a direction's point on the square (density), a coupling layer per step. */
typedef struct nf_point_walk {
    const nf_shading_point *p;
    const nf_context *user; /* the context custom prior callbacks receive */
    float x[2];             /* the point being mapped                     */
    float s0;               /* inverse: theta / pi of the direction       */
    float q;                /* forward: the prior's density at the start  */
    double det;             /* forward: |det J|; inverse: 1 / |det J|     */
} nf_point_walk;

/* Starts a forward walk at the prior's sample for u. */
static inline nf_status nf_point_walk_sample(const nf_model *m, const nf_shading_point *p,
                                             const nf_context *user, const float u[2],
                                             nf_point_walk *w)
{
    nf_prior_point view;
    nf_point_prior_view(p, user, &view);
    w->p = p;
    w->user = user;
    w->x[0] = w->x[1] = 0.0f; /* set by nf_prior_sample; GCC cannot see it */
    w->q = 1.0f;
    w->det = 1.0;
    return nf_prior_sample(m, &view, u[0], u[1], w->x, &w->q);
}

/* Starts an inverse walk at dir's point on the square. */
static inline void nf_point_walk_pdf(const nf_shading_point *p, const nf_context *user,
                                     const float dir[3], nf_point_walk *w)
{
    float s[2];
    nf_to_square(dir, s);
    w->p = p;
    w->user = user;
    w->x[0] = s[0];
    w->x[1] = s[1];
    w->s0 = s[0];
    w->det = 1.0;
}

/* The coupling layer that step j of a walk applies. */
static inline uint32_t nf_point_walk_layer(nf_point_shape sh, int inverse, uint32_t j)
{
    return inverse ? sh.layers - 1u - j : j;
}

/* Step j's map, once its conditioner and spline are in sc: the spline applied (forward) or
 * inverted (inverse), with a turning layer's rotation after it (forward) or before it
 * (inverse), as flow.h. */
static inline void nf_point_walk_map(nf_point_shape sh, int inverse, uint32_t j, nf_point_walk *w,
                                     const nf_point_scratch *sc)
{
    uint32_t i = nf_point_walk_layer(sh, inverse, j), t = nf_transformed(i);
    const int turns = nf_shape_turns(sh, i);
    nf_spline_bin bin;
    float slope;
    if (!inverse) {
        nf_point_bin(sc, nf_spline_find(sc->x, sh.bins, w->x[t]), &bin);
        w->x[t] = nf_spline_bin_eval(&bin, w->x[t], &slope);
        if (turns)
            w->x[t] = nf_wrap_unit(w->x[t] + nf_rotation(sc->raw[3u * sh.bins], sh.bins));
        w->det *= slope;
    } else {
        if (turns)
            w->x[t] = nf_wrap_unit(w->x[t] - nf_rotation(sc->raw[3u * sh.bins], sh.bins));
        nf_point_bin(sc, nf_spline_find(sc->y, sh.bins, w->x[t]), &bin);
        float solved = nf_spline_bin_solve(&bin, w->x[t]);
        nf_spline_bin_eval(&bin, solved, &slope);
        w->x[t] = solved;
        w->det /= slope;
    }
}

/* A walk at the point through every coupling layer, forward (inverse = 0) or inverse: each
 * step's conditioner and spline, then its map. */
static NF_ALWAYS_INLINE void nf_point_walk_layers(const nf_model *m, nf_point_shape sh,
                                                  const nf_shading_point *p, int inverse,
                                                  nf_point_walk *w, const nf_point_scratch *sc)
{
    for (uint32_t j = 0; j < sh.layers; ++j) {
        const uint32_t layer = nf_point_walk_layer(sh, inverse, j);
        nf_point_conditioner(m, sh, p, layer, w->x[1u - nf_transformed(layer)], sc);
        nf_point_spline(sh.bins, sh.raw_stride, nf_shape_circular(sh, layer), sc);
        nf_point_walk_map(sh, inverse, j, w, sc);
    }
}

/* Ends a forward walk: the direction and its density. */
static inline void nf_point_walk_sampled(nf_point_walk *w, float dir[3], float *pdf)
{
    /* One ulp below 1, as nf_sample: phi = 2 pi would map back across the seam. */
    w->x[1] = nf_minf(w->x[1], 0x1.fffffep-1f);
    /* the map's sin(theta) is nf_sin_pi(x[0])'s bits (x[0] lies in [0, 1]): one sincos, not two */
    float sin_theta = nf_from_square(w->x, dir);
    if (pdf)
        *pdf = nf_solid_angle_pdf_at((double)w->q / w->det, sin_theta);
}

/* Ends an inverse walk: the prior's density at the latent point, then the direction's. */
static inline nf_status nf_point_walk_density(const nf_model *m, const nf_point_walk *w, float *pdf)
{
    nf_prior_point view;
    nf_point_prior_view(w->p, w->user, &view);
    float q;
    nf_status st = nf_prior_density(m, &view, w->x, &q, NULL);
    if (st != NF_OK)
        return st;
    *pdf = nf_solid_angle_pdf((double)q * w->det, w->s0);
    return NF_OK;
}

/* One direction drawn at the point (nf_sample_one's arithmetic). */
static inline nf_status nf_point_sample_one(const nf_model *m, nf_point_shape sh,
                                            const nf_shading_point *p, const nf_context *user,
                                            const float u[2], float dir[3], float *pdf,
                                            const nf_point_scratch *sc)
{
    nf_point_walk w;
    nf_status st = nf_point_walk_sample(m, p, user, u, &w);
    if (st != NF_OK)
        return st;
    nf_point_walk_layers(m, sh, p, 0, &w, sc);
    nf_point_walk_sampled(&w, dir, pdf);
    return NF_OK;
}

/* The solid-angle density of one direction at the point (nf_pdf_one's arithmetic). */
static inline nf_status nf_point_pdf_one(const nf_model *m, nf_point_shape sh,
                                         const nf_shading_point *p, const nf_context *user,
                                         const float dir[3], float *pdf, const nf_point_scratch *sc)
{
    nf_point_walk w;
    nf_point_walk_pdf(p, user, dir, &w);
    nf_point_walk_layers(m, sh, p, 1, &w, sc);
    return nf_point_walk_density(m, &w, pdf);
}

/* The presets' shapes (nisflow/model.h: NF_PRESET_SMALL, NF_PRESET_LARGE). */
#define NF_POINT_SHAPE_SMALL                                                                       \
    {                                                                                              \
        2u, 8u, 32u, 1u, 16u, 16u, 25u, 32u, 1u, 0u /* circular: set per call */                   \
    }
#define NF_POINT_SHAPE_LARGE                                                                       \
    {                                                                                              \
        4u, 16u, 32u, 2u, 16u, 16u, 49u, 64u, 1u, 0u                                               \
    }

static inline int nf_point_shape_equal(nf_point_shape a, nf_point_shape b)
{
    return a.layers == b.layers && a.bins == b.bins && a.blob_bins == b.blob_bins &&
           a.depth == b.depth && a.width == b.width && a.hp == b.hp && a.raw == b.raw &&
           a.raw_stride == b.raw_stride;
}

#endif /* NISFLOW_KERNELS_POINT_H */
