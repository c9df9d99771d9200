/*
 * point_vector_avx2.h - the per-direction path's coupling layer in AVX2 registers: the
 * conditioner, the knots and their derivatives, a bin's search and its values. A direction's
 * 16 hidden units take two 8-lane registers, its K = 8 or 16 knots one or two; the 3K + 1 raw
 * parameters fall on register boundaries (widths, heights and derivatives each start at a
 * multiple of 8), so no window straddles two registers. A bin's values are read from small
 * arrays the layer stores, where AVX-512 permutes registers: AVX2 has no two-register permute.
 * point_vector.h says what the path is for and walks the layers these build.
 */
#ifndef NISFLOW_KERNELS_POINT_VECTOR_AVX2_H
#define NISFLOW_KERNELS_POINT_VECTOR_AVX2_H

#if defined(__AVX2__) && defined(__FMA__) && !defined(__AVX512F__)

#include "point_vector_base.h"

/* Floats per register, and the most registers a shape's raw parameters take (3K + 1 <= 49). */
#define NF_PV_LANES 8u
#define NF_PV_RAW_REGS 7u

/* One coupling layer's spline for one direction: the knots in registers for the bin search,
 * and what a bin reads in arrays. Index i of xs / ys is knot i (x_0 = y_0 = 0); of d the
 * derivative d_i; of s and iw bin i's slope h_i / w_i and 1 / w_i. */
typedef struct nf_pv_spline {
    __m256 x[2], y[2]; /* knots x_1 .. x_K, y_1 .. y_K: 8 to a register (x_K = y_K = 1) */
    float xs[NF_PV_LANES * 2 + 1], ys[NF_PV_LANES * 2 + 1];
    float d[NF_PV_LANES * 3], s[NF_PV_LANES * 2], iw[NF_PV_LANES * 2];
    float rotation; /* a turning layer's raw rotation (circle.h) */
} nf_pv_spline;

NF_PV_POLYNOMIALS(__m256, _mm256_set1_ps, _mm256_mul_ps, _mm256_add_ps, _mm256_fmadd_ps)

/* e^x for x in [-87, 88] as 2^n 2^f (point_vector_avx512.h's nf_pv_exp, the same bits): 2^n
 * enters the exponent field, which stays normal over that range. */
static NF_ALWAYS_INLINE __m256 nf_pv_exp(__m256 x)
{
    __m256 t = _mm256_mul_ps(x, _mm256_set1_ps(1.44269504088896341f));
    __m256 n = _mm256_round_ps(t, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
    __m256 p = nf_pv_exp2_reduced(_mm256_sub_ps(t, n)); /* t - n is exact */
    __m256i e = _mm256_slli_epi32(_mm256_cvtps_epi32(n), 23);
    return _mm256_castsi256_ps(_mm256_add_epi32(_mm256_castps_si256(p), e));
}

/* log x for normal positive x, as nf_fast_log: the exponent and the mantissa in [1/2, 1) from
 * the bits (point_vector_avx512.h's getexp and getmant). */
static NF_ALWAYS_INLINE __m256 nf_pv_log(__m256 x)
{
    __m256i bits = _mm256_castps_si256(x);
    __m256 e =
        _mm256_cvtepi32_ps(_mm256_sub_epi32(_mm256_srli_epi32(bits, 23), _mm256_set1_epi32(126)));
    __m256 m = _mm256_castsi256_ps(_mm256_or_si256(
        _mm256_and_si256(bits, _mm256_set1_epi32(0x007fffff)), _mm256_set1_epi32(0x3f000000)));
    __m256 small = _mm256_cmp_ps(m, _mm256_set1_ps(0.70710678118654752f), _CMP_LT_OQ);
    e = _mm256_sub_ps(e, _mm256_and_ps(small, _mm256_set1_ps(1.0f)));
    __m256 m1 = _mm256_sub_ps(m, _mm256_set1_ps(1.0f));
    return nf_pv_log_reduced(_mm256_add_ps(m1, _mm256_and_ps(small, m)), e);
}

/* Lane 7 of v. */
static NF_ALWAYS_INLINE float nf_pv_last(__m256 v)
{
    __m128 hi = _mm256_extractf128_ps(v, 1);
    return _mm_cvtss_f32(_mm_permute_ps(hi, _MM_SHUFFLE(3, 3, 3, 3)));
}

/* out[c] = bias + sum_k h[k] W[k] for `regs` registers of outputs, on four partial sums per
 * register (inputs k = j mod 4) added as point_vector_avx512.h adds them, so that both round
 * alike. One output register at a time: its four sums and a broadcast input fit in registers,
 * where all outputs at once (16 sums for K = 8, 28 for K = 16) spill to the stack on AVX2's
 * 16 registers. The inputs are broadcast from memory (a load each), not permuted out of h. */
static NF_ALWAYS_INLINE void nf_pv_dense(const float *w, const float *bias, uint32_t stride,
                                         uint32_t regs, uint32_t inputs, const __m256 h[2],
                                         __m256 *out)
{
    _Alignas(32) float hs[2 * NF_PV_LANES];
    _mm256_store_ps(hs, h[0]);
    _mm256_store_ps(hs + NF_PV_LANES, h[1]);
    for (uint32_t c = 0; c < regs; ++c) {
        const float *wc = w + (size_t)c * NF_PV_LANES;
        __m256 acc[4];
        acc[0] = _mm256_loadu_ps(bias + (size_t)c * NF_PV_LANES);
        acc[1] = acc[2] = acc[3] = _mm256_setzero_ps();
        for (uint32_t k = 0; k < inputs; ++k)
            acc[k & 3u] = _mm256_fmadd_ps(_mm256_broadcast_ss(hs + k),
                                          _mm256_loadu_ps(wc + (size_t)k * stride), acc[k & 3u]);
        out[c] = _mm256_add_ps(_mm256_add_ps(acc[0], acc[1]), _mm256_add_ps(acc[2], acc[3]));
    }
}

/* a with its lanes below s (1, 2 or 4) taken from b. */
static NF_ALWAYS_INLINE __m256 nf_pv_blend_low(__m256 a, __m256 b, uint32_t s)
{
    switch (s) {
    case 1: return _mm256_blend_ps(a, b, 0x01);
    case 2: return _mm256_blend_ps(a, b, 0x03);
    default: return _mm256_blend_ps(a, b, 0x0f);
    }
}

/* One step of the prefix scan over the K lanes of e (one or two registers): every lane plus
 * the lane s below it, zero below lane s, as point_vector_avx512.h's step on one 16-lane
 * register adds it, so that the knots are the same bits. */
static NF_ALWAYS_INLINE void nf_pv_scan_step(__m256 *e, uint32_t regs, uint32_t s)
{
    const __m256i rotate = _mm256_and_si256(
        _mm256_sub_epi32(_mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7), _mm256_set1_epi32((int)s)),
        _mm256_set1_epi32(7));
    const __m256 low = _mm256_permutevar8x32_ps(e[0], rotate);
    if (regs > 1u)
        e[1] = _mm256_add_ps(e[1], nf_pv_blend_low(_mm256_permutevar8x32_ps(e[1], rotate), low, s));
    e[0] = _mm256_add_ps(e[0], nf_pv_blend_low(low, _mm256_setzero_ps(), s));
}

/* Inclusive prefix sums of the K lanes of e: steps of 1, 2 and 4 lanes, then of 8 from the
 * first register into the second (adding zero leaves the first's sums as they are). */
static NF_ALWAYS_INLINE void nf_pv_prefix(__m256 *e, uint32_t regs)
{
    nf_pv_scan_step(e, regs, 1);
    nf_pv_scan_step(e, regs, 2);
    nf_pv_scan_step(e, regs, 4);
    if (regs > 1u)
        e[1] = _mm256_add_ps(e[1], e[0]);
}

/* v shifted up one lane, `first` (the last lane of the register before, or 0) into lane 0. */
static NF_ALWAYS_INLINE __m256 nf_pv_shift_one(__m256 v, float first)
{
    __m256 up = _mm256_permutevar8x32_ps(v, _mm256_setr_epi32(0, 0, 1, 2, 3, 4, 5, 6));
    return _mm256_blend_ps(up, _mm256_set1_ps(first), 0x01);
}

/* The knots t_1 .. t_K = m (i + 1) + (1 - K m) sum_{j <= i} softmax_j of the K raw values in
 * r[0 .. K/8) (the widths or the heights), t_K pinned to 1 (as nf_spline_knots_from_exps): the
 * exps, then a prefix scan (beyond NF_PV_EXP_SAFE, the max subtracted first). */
static NF_ALWAYS_INLINE void nf_pv_knots(const __m256 *raw, uint32_t bins, __m256 *knots)
{
    const uint32_t regs = bins / NF_PV_LANES;
    const __m256 abs_mask = _mm256_castsi256_ps(_mm256_set1_epi32(0x7fffffff));
    __m256 r[2] = {raw[0], regs > 1u ? raw[1] : raw[0]};
    __m256 big = _mm256_max_ps(_mm256_and_ps(r[0], abs_mask), _mm256_and_ps(r[1], abs_mask));
    if (__builtin_expect(
            _mm256_movemask_ps(_mm256_cmp_ps(big, _mm256_set1_ps(NF_PV_EXP_SAFE), _CMP_GT_OQ)),
            0)) {
        __m256 t = _mm256_max_ps(r[0], r[1]);
        t = _mm256_max_ps(t, _mm256_permute2f128_ps(t, t, 0x01));
        t = _mm256_max_ps(t, _mm256_permute_ps(t, _MM_SHUFFLE(1, 0, 3, 2)));
        t = _mm256_max_ps(t, _mm256_permute_ps(t, _MM_SHUFFLE(2, 3, 0, 1)));
        for (uint32_t i = 0; i < 2; ++i)
            r[i] = _mm256_max_ps(_mm256_sub_ps(r[i], t), _mm256_set1_ps(-87.0f));
    }
    __m256 e[2];
    for (uint32_t i = 0; i < regs; ++i)
        e[i] = nf_pv_exp(r[i]);
    nf_pv_prefix(e, regs);
    const float scale = 1.0f - (float)bins * NF_SPLINE_MIN;
    const __m256 inv = _mm256_set1_ps(scale / nf_pv_last(e[regs - 1u]));
    for (uint32_t i = 0; i < regs; ++i) {
        __m256 steps = _mm256_mul_ps(_mm256_add_ps(_mm256_setr_ps(1, 2, 3, 4, 5, 6, 7, 8),
                                                   _mm256_set1_ps((float)(i * NF_PV_LANES))),
                                     _mm256_set1_ps(NF_SPLINE_MIN));
        knots[i] = _mm256_fmadd_ps(e[i], inv, steps);
    }
    knots[regs - 1u] = _mm256_blend_ps(knots[regs - 1u], _mm256_set1_ps(1.0f), 0x80);
}

/* m + softplus(raw + c) in every lane (nf_spline_derivatives's values). */
static NF_ALWAYS_INLINE __m256 nf_pv_derivatives(__m256 raw)
{
    __m256 a = _mm256_add_ps(raw, _mm256_set1_ps(NF_SPLINE_DERIVATIVE_SHIFT));
    __m256 abs_a = _mm256_and_ps(a, _mm256_castsi256_ps(_mm256_set1_epi32(0x7fffffff)));
    __m256 e =
        nf_pv_exp(_mm256_max_ps(_mm256_sub_ps(_mm256_setzero_ps(), abs_a), _mm256_set1_ps(-87.0f)));
    __m256 sp = _mm256_add_ps(_mm256_max_ps(a, _mm256_setzero_ps()),
                              nf_pv_log(_mm256_add_ps(_mm256_set1_ps(1.0f), e)));
    return _mm256_add_ps(sp, _mm256_set1_ps(NF_SPLINE_MIN));
}

/* A knot set's registers stored as knots 0 .. K, knot 0 = 0. */
static NF_ALWAYS_INLINE void nf_pv_store_knots(const __m256 *knots, uint32_t regs, float *to)
{
    to[0] = 0.0f;
    for (uint32_t i = 0; i < regs; ++i)
        _mm256_storeu_ps(to + 1 + i * NF_PV_LANES, knots[i]);
}

/* Coupling layer `layer`'s spline for the pass-through coordinate v: the conditioner from the
 * point's context sums, the clamp of nf_conditioner_forward (NaN to the lower bound), knots
 * and knot derivatives (a circular layer's d_K is d_0, circle.h). */
static NF_ALWAYS_INLINE void nf_pv_layer(const nf_model *m, nf_point_shape sh,
                                         const nf_shading_point *p, uint32_t layer, float v,
                                         nf_pv_spline *s)
{
    const float *packed = m->packed;
    const nf_linear *lin = m->packed_linear[layer];
    uint32_t rows[3];
    __m128 vals = nf_pv_oneblob(v, sh.blob_bins, nf_shape_wraps(sh, layer), rows);
    const __m256 slot[3] = {_mm256_broadcastss_ps(vals),
                            _mm256_broadcastss_ps(_mm_movehdup_ps(vals)),
                            _mm256_broadcastss_ps(_mm_movehl_ps(vals, vals))};
    const float *w0 = packed + lin[0].weight, *sums = p->cache_ + (size_t)layer * NF_CHUNK;
    __m256 h[2];
    for (uint32_t i = 0; i < 2; ++i) {
        h[i] = _mm256_loadu_ps(sums + i * NF_PV_LANES);
        for (uint32_t k = 0; k < 3; ++k)
            h[i] = _mm256_fmadd_ps(
                slot[k], _mm256_loadu_ps(w0 + (size_t)rows[k] * NF_CHUNK + i * NF_PV_LANES), h[i]);
        h[i] = _mm256_max_ps(h[i], _mm256_setzero_ps());
    }
    for (uint32_t l = 1; l < sh.depth; ++l) {
        __m256 next[2];
        nf_pv_dense(packed + lin[l].weight, packed + lin[l].bias, NF_CHUNK, 2, sh.width, h, next);
        h[0] = _mm256_max_ps(next[0], _mm256_setzero_ps());
        h[1] = _mm256_max_ps(next[1], _mm256_setzero_ps());
    }
    const uint32_t bins = sh.bins, regs = bins / NF_PV_LANES;
    const uint32_t raw_regs = (sh.raw + NF_PV_LANES - 1u) / NF_PV_LANES;
    __m256 raw[NF_PV_RAW_REGS];
    nf_pv_dense(packed + lin[sh.depth].weight, packed + lin[sh.depth].bias, sh.raw_stride, raw_regs,
                sh.width, h, raw);
    for (uint32_t c = 0; c < raw_regs; ++c) /* max(NaN, lo) is lo */
        raw[c] = _mm256_min_ps(_mm256_max_ps(raw[c], _mm256_set1_ps(-NF_RAW_LIMIT)),
                               _mm256_set1_ps(NF_RAW_LIMIT));
    nf_pv_knots(raw, bins, s->x);
    nf_pv_knots(raw + regs, bins, s->y);
    /* the derivatives d_0 .. d_K start at raw 2K; d_K (or a turning layer's rotation) is lane
     * 0 of the register after them, whose softplus a turning layer skips: its d_K is d_0 */
    const int circular = nf_shape_circular(sh, layer);
    for (uint32_t c = 0; c < regs + (circular ? 0u : 1u); ++c)
        _mm256_storeu_ps(s->d + c * NF_PV_LANES, nf_pv_derivatives(raw[2u * regs + c]));
    s->rotation = 0.0f;
    if (circular) {
        s->rotation = _mm256_cvtss_f32(raw[3u * regs]);
        s->d[bins] = s->d[0];
    }
    nf_pv_store_knots(s->x, regs, s->xs);
    nf_pv_store_knots(s->y, regs, s->ys);
    /* the bins' slopes and inverse widths, here in vectors, in parallel with the bin search,
     * instead of two divisions after it */
    float x_prev = 0.0f, y_prev = 0.0f;
    for (uint32_t i = 0; i < regs; ++i) {
        __m256 w = _mm256_sub_ps(s->x[i], nf_pv_shift_one(s->x[i], x_prev));
        __m256 hgt = _mm256_sub_ps(s->y[i], nf_pv_shift_one(s->y[i], y_prev));
        __m256 r = _mm256_div_ps(_mm256_set1_ps(1.0f), w);
        _mm256_storeu_ps(s->iw + i * NF_PV_LANES, r);
        _mm256_storeu_ps(s->s + i * NF_PV_LANES, _mm256_mul_ps(hgt, r));
        x_prev = nf_pv_last(s->x[i]);
        y_prev = nf_pv_last(s->y[i]);
    }
}

/* The bin of v among knots t_1 .. t_K: the count of interior knots <= v (nf_spline_find). */
static NF_ALWAYS_INLINE uint32_t nf_pv_find(const __m256 knots[2], uint32_t bins, float v)
{
    const __m256 vv = _mm256_set1_ps(v);
    unsigned le = (unsigned)_mm256_movemask_ps(_mm256_cmp_ps(knots[0], vv, _CMP_LE_OQ));
    if (bins > NF_PV_LANES)
        le |= (unsigned)_mm256_movemask_ps(_mm256_cmp_ps(knots[1], vv, _CMP_LE_OQ)) << 8;
    return (uint32_t)__builtin_popcount(le & ((1u << (bins - 1u)) - 1u));
}

static NF_ALWAYS_INLINE void nf_pv_bin_at(const nf_pv_spline *s, uint32_t k, nf_pv_bin *b)
{
    b->xk = s->xs[k];
    b->yk = s->ys[k];
    b->x1 = s->xs[k + 1u];
    b->y1 = s->ys[k + 1u];
    b->wk = b->x1 - b->xk;
    b->hk = b->y1 - b->yk;
    b->sk = s->s[k];
    b->iw = s->iw[k];
    b->d0 = s->d[k];
    b->d1 = s->d[k + 1u];
}

#endif /* __AVX2__ && __FMA__ && !__AVX512F__ */
#endif /* NISFLOW_KERNELS_POINT_VECTOR_AVX2_H */
