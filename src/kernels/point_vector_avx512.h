/*
 * point_vector_avx512.h - the per-direction path's coupling layer in AVX-512 registers: the
 * conditioner, the knots and their derivatives, a bin's search and its values, with the hidden
 * units, the knots and the bins of one direction each in one 16-lane register (K <= 16).
 * point_vector.h says what the path is for and walks the layers these build. kernel.c runs
 * it for the large preset; the small one's points go to the AVX2 kernels' layer.
 */
#ifndef NISFLOW_KERNELS_POINT_VECTOR_AVX512_H
#define NISFLOW_KERNELS_POINT_VECTOR_AVX512_H

#if defined(__AVX512F__)

#include "point_vector_base.h"

/* The most raw-parameter chunks a shape of this path has: 3K + 1 <= 49 floats. */
#define NF_PV_CHUNKS 4u

/* One coupling layer's spline for one direction, in registers. */
typedef struct nf_pv_spline {
    __m512 x, y;    /* knots x_1 .. x_K and y_1 .. y_K in lanes 0 .. K-1 (lane K-1 exactly 1) */
    __m512 d[2];    /* knot derivatives d_0 .. d_15, then d_16 (K = 16) in lane 0          */
    __m512 s, iw;   /* per bin k: s_k = h_k / w_k and 1 / w_k                                */
    float rotation; /* a turning layer's raw rotation (circle.h)                          */
} nf_pv_spline;
NF_PV_POLYNOMIALS(__m512, _mm512_set1_ps, _mm512_mul_ps, _mm512_add_ps, _mm512_fmadd_ps)

/* e^x for x in [-87, 88] (callers clamp where they need to) as 2^n 2^f, n = round(x log2 e),
 * f in [-1/2, 1/2]. The rounding of x log2 e bounds its relative error, measured against
 * double exp on 4 million points: 4.0e-6 over [-87, 88], 1.1e-6 for |x| <= 16, 2.4e-7 for
 * |x| <= 1 (nf_fast_exp: 3e-7). Splitting the product as Cody and Waite split ln 2 brought it
 * to 2.9e-7 and cost the large preset's pdf 5 %; the densities' bound in test_point did not
 * move. */
static NF_ALWAYS_INLINE __m512 nf_pv_exp(__m512 x)
{
    __m512 t = _mm512_mul_ps(x, _mm512_set1_ps(1.44269504088896341f));
    __m512 f = _mm512_reduce_ps(t, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC); /* t - n */
    return _mm512_scalef_ps(nf_pv_exp2_reduced(f), _mm512_sub_ps(t, f));
}

/* log x for normal positive x, as nf_fast_log, with the exponent and mantissa from getexp /
 * getmant. */
static NF_ALWAYS_INLINE __m512 nf_pv_log(__m512 x)
{
    __m512 m = _mm512_getmant_ps(x, _MM_MANT_NORM_p5_1, _MM_MANT_SIGN_src); /* [0.5, 1) */
    __m512 e = _mm512_add_ps(_mm512_getexp_ps(x), _mm512_set1_ps(1.0f));
    __mmask16 small = _mm512_cmp_ps_mask(m, _mm512_set1_ps(0.70710678118654752f), _CMP_LT_OQ);
    e = _mm512_mask_sub_ps(e, small, e, _mm512_set1_ps(1.0f));
    __m512 m1 = _mm512_sub_ps(m, _mm512_set1_ps(1.0f));
    return nf_pv_log_reduced(_mm512_mask_add_ps(m1, small, m1, m), e);
}

/* Lane k of v in every lane. */
static NF_ALWAYS_INLINE __m512 nf_pv_splat(__m512 v, uint32_t k)
{
    return _mm512_permutexvar_ps(_mm512_set1_epi32((int)k), v);
}

static NF_ALWAYS_INLINE float nf_pv_lane(__m512 v, uint32_t k)
{
    return _mm512_cvtss_f32(nf_pv_splat(v, k));
}

/* out[c] = bias + sum_k h[k] W[k] for `chunks` chunks of outputs, on four partial sums per
 * chunk (inputs k = j mod 4), so that the chain is 4 multiply-adds deep instead of 16. */
static NF_ALWAYS_INLINE void nf_pv_dense(const float *w, const float *bias, uint32_t stride,
                                         uint32_t chunks, uint32_t inputs, __m512 h, __m512 *out)
{
    __m512 hk[NF_CHUNK];
    for (uint32_t k = 0; k < inputs; ++k)
        hk[k] = nf_pv_splat(h, k);
    for (uint32_t c = 0; c < chunks; ++c) {
        __m512 acc[4] = {_mm512_loadu_ps(bias + (size_t)c * NF_CHUNK), _mm512_setzero_ps(),
                         _mm512_setzero_ps(), _mm512_setzero_ps()};
        for (uint32_t k = 0; k < inputs; ++k)
            acc[k & 3u] = _mm512_fmadd_ps(
                hk[k], _mm512_loadu_ps(w + (size_t)k * stride + (size_t)c * NF_CHUNK), acc[k & 3u]);
        out[c] = _mm512_add_ps(_mm512_add_ps(acc[0], acc[1]), _mm512_add_ps(acc[2], acc[3]));
    }
}

/* Floats offset .. offset + 15 of the raw parameters held in `chunks` registers (zero past
 * them). */
static NF_ALWAYS_INLINE __m512 nf_pv_window(const __m512 *raw, uint32_t chunks, uint32_t offset)
{
    const uint32_t c = offset / NF_CHUNK, s = offset % NF_CHUNK;
    __m512 lo = c < chunks ? raw[c] : _mm512_setzero_ps();
    if (s == 0)
        return lo;
    __m512 hi = c + 1u < chunks ? raw[c + 1u] : _mm512_setzero_ps();
    __m512i idx =
        _mm512_add_epi32(_mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15),
                         _mm512_set1_epi32((int)s));
    return _mm512_permutex2var_ps(lo, idx, hi);
}

/* v shifted up by s lanes, zeros below. */
static NF_ALWAYS_INLINE __m512 nf_pv_shift_up(__m512 v, int s)
{
    __m512i z = _mm512_setzero_si512(), x = _mm512_castps_si512(v);
    switch (s) {
    case 1: return _mm512_castsi512_ps(_mm512_alignr_epi32(x, z, 15));
    case 2: return _mm512_castsi512_ps(_mm512_alignr_epi32(x, z, 14));
    case 4: return _mm512_castsi512_ps(_mm512_alignr_epi32(x, z, 12));
    default: return _mm512_castsi512_ps(_mm512_alignr_epi32(x, z, 8));
    }
}

/* The knots t_1 .. t_K = m (i + 1) + (1 - K m) sum_{j <= i} softmax_j of the K raw values in
 * lanes 0 .. K-1 of r (the widths or the heights), t_K pinned to 1 (as
 * nf_spline_knots_from_exps), lanes K and above 1: the exps, then a prefix scan (beyond
 * NF_PV_EXP_SAFE, the max subtracted first). */
static NF_ALWAYS_INLINE __m512 nf_pv_knots(__m512 r, uint32_t bins)
{
    const __mmask16 valid = (__mmask16)((1u << bins) - 1u);
    __m512 abs_r = _mm512_castsi512_ps(
        _mm512_and_si512(_mm512_castps_si512(r), _mm512_set1_epi32(0x7fffffff)));
    if (__builtin_expect(
            _mm512_mask_cmp_ps_mask(valid, abs_r, _mm512_set1_ps(NF_PV_EXP_SAFE), _CMP_GT_OQ) != 0,
            0)) {
        __m512 t = _mm512_mask_mov_ps(_mm512_set1_ps(-FLT_MAX), valid, r);
        t = _mm512_max_ps(t, _mm512_shuffle_f32x4(t, t, _MM_SHUFFLE(1, 0, 3, 2)));
        t = _mm512_max_ps(t, _mm512_shuffle_f32x4(t, t, _MM_SHUFFLE(2, 3, 0, 1)));
        t = _mm512_max_ps(t, _mm512_permute_ps(t, _MM_SHUFFLE(1, 0, 3, 2)));
        t = _mm512_max_ps(t, _mm512_permute_ps(t, _MM_SHUFFLE(2, 3, 0, 1)));
        r = _mm512_max_ps(_mm512_sub_ps(r, t), _mm512_set1_ps(-87.0f));
    }
    __m512 e = _mm512_maskz_mov_ps(valid, nf_pv_exp(r));
    e = _mm512_add_ps(e, nf_pv_shift_up(e, 1));
    e = _mm512_add_ps(e, nf_pv_shift_up(e, 2));
    e = _mm512_add_ps(e, nf_pv_shift_up(e, 4));
    if (bins > 8u)
        e = _mm512_add_ps(e, nf_pv_shift_up(e, 8));
    const float scale = 1.0f - (float)bins * NF_SPLINE_MIN;
    __m512 inv = _mm512_set1_ps(scale / nf_pv_lane(e, bins - 1u));
    __m512 steps =
        _mm512_mul_ps(_mm512_setr_ps(1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16),
                      _mm512_set1_ps(NF_SPLINE_MIN));
    __m512 knots = _mm512_fmadd_ps(e, inv, steps);
    return _mm512_mask_mov_ps(_mm512_set1_ps(1.0f), (__mmask16)(valid >> 1), knots);
}

/* m + softplus(raw + c) in every lane (nf_spline_derivatives's values). */
static NF_ALWAYS_INLINE __m512 nf_pv_derivatives(__m512 raw)
{
    __m512 a = _mm512_add_ps(raw, _mm512_set1_ps(NF_SPLINE_DERIVATIVE_SHIFT));
    __m512 abs_a = _mm512_castsi512_ps(
        _mm512_and_si512(_mm512_castps_si512(a), _mm512_set1_epi32(0x7fffffff)));
    __m512 e =
        nf_pv_exp(_mm512_max_ps(_mm512_sub_ps(_mm512_setzero_ps(), abs_a), _mm512_set1_ps(-87.0f)));
    __m512 sp = _mm512_add_ps(_mm512_max_ps(a, _mm512_setzero_ps()),
                              nf_pv_log(_mm512_add_ps(_mm512_set1_ps(1.0f), e)));
    return _mm512_add_ps(sp, _mm512_set1_ps(NF_SPLINE_MIN));
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
    __m512 vals =
        _mm512_castps128_ps512(nf_pv_oneblob(v, sh.blob_bins, nf_shape_wraps(sh, layer), rows));
    const float *w0 = packed + lin[0].weight;
    __m512 h = _mm512_loadu_ps(p->cache_ + (size_t)layer * NF_CHUNK);
    for (uint32_t k = 0; k < 3; ++k)
        h = _mm512_fmadd_ps(nf_pv_splat(vals, k), _mm512_loadu_ps(w0 + (size_t)rows[k] * NF_CHUNK),
                            h);
    h = _mm512_max_ps(h, _mm512_setzero_ps());
    __m512 raw[NF_PV_CHUNKS];
    for (uint32_t l = 1; l < sh.depth; ++l) {
        nf_pv_dense(packed + lin[l].weight, packed + lin[l].bias, NF_CHUNK, 1, sh.width, h, raw);
        h = _mm512_max_ps(raw[0], _mm512_setzero_ps());
    }
    const uint32_t chunks = sh.raw_stride / NF_CHUNK, bins = sh.bins;
    nf_pv_dense(packed + lin[sh.depth].weight, packed + lin[sh.depth].bias, sh.raw_stride, chunks,
                sh.width, h, raw);
    for (uint32_t c = 0; c < chunks; ++c) /* max(NaN, lo) is lo */
        raw[c] = _mm512_min_ps(_mm512_max_ps(raw[c], _mm512_set1_ps(-NF_RAW_LIMIT)),
                               _mm512_set1_ps(NF_RAW_LIMIT));
    s->x = nf_pv_knots(nf_pv_window(raw, chunks, 0), bins);
    s->y = nf_pv_knots(nf_pv_window(raw, chunks, bins), bins);
    __m512 d0 = nf_pv_window(raw, chunks, 2u * bins), d1 = _mm512_setzero_ps();
    if (bins == 16u)
        d1 = nf_pv_window(raw, chunks, 3u * bins);
    s->rotation = 0.0f;
    if (nf_shape_circular(sh, layer)) {
        s->rotation = _mm512_cvtss_f32(nf_pv_window(raw, chunks, 3u * bins));
        if (bins < 16u)
            d0 = _mm512_mask_mov_ps(d0, (__mmask16)(1u << bins), nf_pv_splat(d0, 0));
        else
            d1 = _mm512_mask_mov_ps(d1, 1, d0);
    }
    /* the bins' slopes and inverse widths, here in one vector each, in parallel with the bin
     * search, instead of two divisions after it (lanes K and above are never read) */
    __m512 w = _mm512_sub_ps(s->x, nf_pv_shift_up(s->x, 1));
    __m512 hgt = _mm512_sub_ps(s->y, nf_pv_shift_up(s->y, 1));
    __m512 r = _mm512_div_ps(_mm512_set1_ps(1.0f), w);
    s->iw = r;
    s->s = _mm512_mul_ps(hgt, r);
    s->d[0] = nf_pv_derivatives(d0);
    s->d[1] = bins == 16u ? nf_pv_derivatives(d1) : s->d[0];
}

/* The bin of v among knots t_1 .. t_K: the count of interior knots <= v (nf_spline_find). */
static NF_ALWAYS_INLINE uint32_t nf_pv_find(__m512 knots, uint32_t bins, float v)
{
    __mmask16 le = _mm512_cmp_ps_mask(knots, _mm512_set1_ps(v), _CMP_LE_OQ);
    return (uint32_t)__builtin_popcount((unsigned)le & ((1u << (bins - 1u)) - 1u));
}

static NF_ALWAYS_INLINE void nf_pv_bin_at(const nf_pv_spline *s, uint32_t k, nf_pv_bin *b)
{
    b->xk = k ? nf_pv_lane(s->x, k - 1u) : 0.0f;
    b->yk = k ? nf_pv_lane(s->y, k - 1u) : 0.0f;
    b->x1 = nf_pv_lane(s->x, k);
    b->y1 = nf_pv_lane(s->y, k);
    b->wk = b->x1 - b->xk;
    b->hk = b->y1 - b->yk;
    b->sk = nf_pv_lane(s->s, k);
    b->iw = nf_pv_lane(s->iw, k);
    __m512i idx = _mm512_setr_epi32((int)k, (int)k + 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0);
    __m512 d = _mm512_permutex2var_ps(s->d[0], idx, s->d[1]);
    b->d0 = _mm512_cvtss_f32(d);
    b->d1 = nf_pv_lane(d, 1);
}

#endif /* __AVX512F__ */
#endif /* NISFLOW_KERNELS_POINT_VECTOR_AVX512_H */
