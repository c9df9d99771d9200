/*
 * point_vector.h - the shading-point API's per-direction path in the AVX-512 kernels, designed
 * for one direction: its vectors run across hidden units, bins and knots, not across samples.
 *
 * The tile and the same-bits point path (point.h) sum in sample order: a 16-unit output layer
 * is a chain of 16 dependent multiply-adds, the knots are two running sums of K steps, and
 * softplus and the bin search run bin by bin. One direction leaves most of a core idle on
 * those chains. Here the output layer keeps four partial sums, the knots come from a prefix
 * scan of the exps in one register, the knot derivatives from one vector softplus, the bin
 * search from one comparison mask, and each bin's slope and inverse width from one vector
 * before the search; the inverse's root is solved in float. The results are not the tile's
 * bits: they differ by rounding, within the bound that tests/correctness/test_point.c states
 * and checks against nf_sample / nf_pdf (docs/architecture.md, "Which rule holds where"). The
 * walks' ends take the sphere maps' angles in one vector (fastmath.h's polynomials, four lanes
 * at a time) and, for the cosine prior on surfaces, the draw's prior density from the drawn
 * direction; other priors and media end as point.h's walks do.
 *
 * It serves the two presets (hidden layers of one register, K <= 16 spline bins, the context
 * sums cached in the point): kernel.c compiles it for their shapes, as constants.
 */
#ifndef NISFLOW_KERNELS_POINT_VECTOR_H
#define NISFLOW_KERNELS_POINT_VECTOR_H

#if defined(__AVX512F__)

#include <float.h>
#include <immintrin.h>

#include "point.h"

/* The most raw-parameter chunks a shape of this path has: 3K + 1 <= 49 floats. */
#define NF_PV_CHUNKS 4u

/* Directions walked in step at most: two questions of a vertex. One direction is a chain of
 * dependent operations that leaves the core waiting on latencies; a second, independent chain
 * interleaved with it fills those waits. */
#define NF_PV_PAIR 2u

/* One coupling layer's spline for one direction, in registers. */
typedef struct nf_pv_spline {
    __m512 x, y;    /* knots x_1 .. x_K and y_1 .. y_K in lanes 0 .. K-1 (lane K-1 exactly 1) */
    __m512 d[2];    /* knot derivatives d_0 .. d_15, then d_16 (K = 16) in lane 0          */
    __m512 s, iw;   /* per bin k: s_k = h_k / w_k and 1 / w_k                                */
    float rotation; /* a turning layer's raw rotation (circle.h)                          */
} nf_pv_spline;

/* e^x for x in [-87, 88] (callers clamp where they need to) as 2^n 2^f, n = round(x log2 e),
 * f in [-1/2, 1/2], 2^f by its Taylor series to degree 6 in Estrin's scheme (truncation below
 * 2e-8): three multiply-adds deep instead of nf_fast_exp's seven. The rounding of x log2 e
 * bounds its relative error, measured against double exp on 4 million points: 4.0e-6 over
 * [-87, 88], 1.1e-6 for |x| <= 16, 2.4e-7 for |x| <= 1 (nf_fast_exp: 3e-7). Splitting the
 * product as Cody and Waite split ln 2 brought it to 2.9e-7 and cost the large preset's
 * pdf 5 %; the densities' bound in test_point did not move. */
static NF_ALWAYS_INLINE __m512 nf_pv_exp(__m512 x)
{
    __m512 t = _mm512_mul_ps(x, _mm512_set1_ps(1.44269504088896341f));
    __m512 f = _mm512_reduce_ps(t, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC); /* t - n */
    __m512 n = _mm512_sub_ps(t, f);
    __m512 f2 = _mm512_mul_ps(f, f);
    __m512 f4 = _mm512_mul_ps(f2, f2);
    __m512 p01 = _mm512_fmadd_ps(f, _mm512_set1_ps(0.693147180559945309f), _mm512_set1_ps(1.0f));
    __m512 p23 = _mm512_fmadd_ps(f, _mm512_set1_ps(0.0555041086648215800f),
                                 _mm512_set1_ps(0.240226506959100712f));
    __m512 p45 = _mm512_fmadd_ps(f, _mm512_set1_ps(0.00133335581464284434f),
                                 _mm512_set1_ps(0.00961812910762847717f));
    __m512 p46 = _mm512_fmadd_ps(f2, _mm512_set1_ps(0.000154035303933816099f), p45);
    __m512 p = _mm512_fmadd_ps(f4, p46, _mm512_fmadd_ps(f2, p23, p01));
    return _mm512_scalef_ps(p, n);
}

/* log x for normal positive x, as nf_fast_log (the same polynomial, evaluated in Estrin's
 * scheme), with the exponent and mantissa from getexp / getmant. */
static NF_ALWAYS_INLINE __m512 nf_pv_log(__m512 x)
{
    __m512 m = _mm512_getmant_ps(x, _MM_MANT_NORM_p5_1, _MM_MANT_SIGN_src); /* [0.5, 1) */
    __m512 e = _mm512_add_ps(_mm512_getexp_ps(x), _mm512_set1_ps(1.0f));
    __mmask16 small = _mm512_cmp_ps_mask(m, _mm512_set1_ps(0.70710678118654752f), _CMP_LT_OQ);
    e = _mm512_mask_sub_ps(e, small, e, _mm512_set1_ps(1.0f));
    __m512 m1 = _mm512_sub_ps(m, _mm512_set1_ps(1.0f));
    m = _mm512_mask_add_ps(m1, small, m1, m);
    /* the polynomial in Estrin's scheme: four multiply-adds deep instead of nine */
    __m512 z = _mm512_mul_ps(m, m);
    __m512 m4 = _mm512_mul_ps(z, z);
    __m512 m8 = _mm512_mul_ps(m4, m4);
    __m512 q0 =
        _mm512_fmadd_ps(m, _mm512_set1_ps(-2.4999993993e-1f), _mm512_set1_ps(3.3333331174e-1f));
    __m512 q1 =
        _mm512_fmadd_ps(m, _mm512_set1_ps(-1.6668057665e-1f), _mm512_set1_ps(2.0000714765e-1f));
    __m512 q2 =
        _mm512_fmadd_ps(m, _mm512_set1_ps(-1.2420140846e-1f), _mm512_set1_ps(1.4249322787e-1f));
    __m512 q3 =
        _mm512_fmadd_ps(m, _mm512_set1_ps(-1.1514610310e-1f), _mm512_set1_ps(1.1676998740e-1f));
    __m512 r0 = _mm512_fmadd_ps(z, q1, q0);
    __m512 r1 = _mm512_fmadd_ps(z, q3, q2);
    __m512 y = _mm512_fmadd_ps(m8, _mm512_set1_ps(7.0376836292e-2f), _mm512_fmadd_ps(m4, r1, r0));
    y = _mm512_mul_ps(_mm512_mul_ps(y, m), z);
    y = _mm512_fmadd_ps(e, _mm512_set1_ps(-2.12194440e-4f), y);
    y = _mm512_fmadd_ps(z, _mm512_set1_ps(-0.5f), y);
    return _mm512_fmadd_ps(e, _mm512_set1_ps(0.693359375f), _mm512_add_ps(m, y));
}

/* Sines (lanes 0-3) and cosines (lanes 4-7) of four angles t given in turns, |t| <= 1:
 * nf_fast_sincos_turns's exact reduction to the nearest quarter turn and its Taylor series, to
 * r^11 and r^10 on |r| <= pi/4, for four angles in one polynomial whose coefficients differ
 * between the halves. The reduced angle is scaled to radians in float, not double, and the
 * polynomial fuses its multiply-adds: within a few ulps of the scalar function. */
static NF_ALWAYS_INLINE __m256 nf_pv_sincos_turns(__m128 t)
{
    __m128 q = _mm_round_ps(_mm_mul_ps(t, _mm_set1_ps(4.0f)),
                            _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
    __m128 r4 = _mm_mul_ps(_mm_fnmadd_ps(q, _mm_set1_ps(0.25f), t), _mm_set1_ps(NF_TWO_PI));
    __m256 r = _mm256_set_m128(r4, r4);
    __m256 r2 = _mm256_mul_ps(r, r);
#define NF_PV_HALVES(s, c) _mm256_setr_ps(s, s, s, s, c, c, c, c)
    __m256 p = NF_PV_HALVES(-2.5052108385e-8f, -2.7557319224e-7f);
    p = _mm256_fmadd_ps(p, r2, NF_PV_HALVES(2.7557319224e-6f, 2.4801587302e-5f));
    p = _mm256_fmadd_ps(p, r2, NF_PV_HALVES(-1.9841269841e-4f, -1.3888888889e-3f));
    p = _mm256_fmadd_ps(p, r2, NF_PV_HALVES(8.3333333333e-3f, 4.1666666667e-2f));
    p = _mm256_fmadd_ps(p, r2, NF_PV_HALVES(-1.6666666667e-1f, -0.5f));
#undef NF_PV_HALVES
    /* sin r = r (1 + r^2 p), cos r = 1 + r^2 p */
    __m256 base = _mm256_blend_ps(r, _mm256_set1_ps(1.0f), 0xf0);
    __m256 f = _mm256_fmadd_ps(_mm256_mul_ps(base, r2), p, base);
    /* quadrant: odd ones swap sine and cosine; the sine is negated in quadrants 2 and 3, the
     * cosine in 1 and 2 */
    __m128i quad = _mm_and_si128(_mm_cvtps_epi32(q), _mm_set1_epi32(3));
    __m256i qq = _mm256_set_m128i(_mm_add_epi32(quad, _mm_set1_epi32(1)), quad);
    __m256i odd = _mm256_set_m128i(quad, quad);
    odd = _mm256_slli_epi32(odd, 31);
    f = _mm256_blendv_ps(f, _mm256_permute2f128_ps(f, f, 0x01), _mm256_castsi256_ps(odd));
    __m256i sign = _mm256_slli_epi32(_mm256_and_si256(qq, _mm256_set1_epi32(2)), 30);
    return _mm256_xor_ps(f, _mm256_castsi256_ps(sign));
}

/* atan2(y, x) in (-pi, pi] of four pairs, atan2(0, 0) = 0: nf_fast_atan2's reduction and
 * polynomial, with its two divisions (lo / hi, then (a - 1) / (a + 1) above tan(pi/8)) as
 * one, (lo - hi) / (lo + hi) there. */
static NF_ALWAYS_INLINE __m128 nf_pv_atan2(__m128 y, __m128 x)
{
    const __m128 sign = _mm_set1_ps(-0.0f);
    __m128 ax = _mm_andnot_ps(sign, x), ay = _mm_andnot_ps(sign, y);
    __m128 hi = _mm_max_ps(ax, ay), lo = _mm_min_ps(ax, ay);
    __m128 big = _mm_cmpgt_ps(lo, _mm_mul_ps(hi, _mm_set1_ps(0.4142135623730950f)));
    __m128 num = _mm_blendv_ps(lo, _mm_sub_ps(lo, hi), big);
    __m128 den = _mm_blendv_ps(hi, _mm_add_ps(lo, hi), big);
    __m128 a = _mm_and_ps(_mm_div_ps(num, den), _mm_cmpgt_ps(hi, _mm_setzero_ps())); /* 0 / 0 */
    __m128 z = _mm_mul_ps(a, a);
    __m128 p = _mm_fmadd_ps(_mm_set1_ps(8.05374449538e-2f), z, _mm_set1_ps(-1.38776856032e-1f));
    p = _mm_fmadd_ps(p, z, _mm_set1_ps(1.99777106478e-1f));
    p = _mm_fmadd_ps(p, z, _mm_set1_ps(-3.33329491539e-1f));
    __m128 r = _mm_fmadd_ps(_mm_mul_ps(p, z), a, a);
    r = _mm_add_ps(r, _mm_and_ps(big, _mm_set1_ps(0.78539816339744831f)));
    r = _mm_blendv_ps(r, _mm_sub_ps(_mm_set1_ps(1.57079632679489662f), r), _mm_cmpgt_ps(ay, ax));
    r = _mm_blendv_ps(r, _mm_sub_ps(_mm_set1_ps(3.14159265358979324f), r),
                      _mm_cmplt_ps(x, _mm_setzero_ps()));
    return _mm_xor_ps(r, _mm_and_ps(sign, _mm_cmplt_ps(y, _mm_setzero_ps())));
}

/* nf_to_square's point of a direction of any positive length, both angles in one vector. The
 * angles are invariant under exact scaling, so a direction whose largest component lies in
 * [2^-60, 2^60] (every one a renderer asks about) skips nf_square_scaled's power of two. */
static NF_ALWAYS_INLINE void nf_pv_to_square(const float dir_in[3], float s[2])
{
    float d[3] = {dir_in[0], dir_in[1], dir_in[2]};
    const float big = nf_maxf(nf_maxf(fabsf(d[0]), fabsf(d[1])), fabsf(d[2]));
    if (__builtin_expect(!(big >= 0x1p-60f && big <= 0x1p60f), 0))
        nf_square_scaled(dir_in, d);
    float rho = sqrtf(d[0] * d[0] + d[1] * d[1]);
    __m128 a = nf_pv_atan2(_mm_setr_ps(rho, d[1], 0.0f, 0.0f), _mm_setr_ps(d[2], d[0], 1.0f, 1.0f));
    float theta = _mm_cvtss_f32(a), phi = _mm_cvtss_f32(_mm_movehdup_ps(a));
    phi = phi < 0.0f ? phi + NF_TWO_PI : phi;
    s[0] = nf_clampf(theta * (1.0f / NF_PI), 0.0f, 1.0f);
    s[1] = nf_clampf(phi * (1.0f / NF_TWO_PI), 0.0f, 0x1.fffffep-1f);
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
 * nf_spline_knots_from_exps), lanes K and above 1: the exps, then a prefix scan. The softmax
 * needs no shift by the max while every |raw| <= NF_PV_EXP_SAFE (e^60 summed 16 times stays
 * finite, e^-60 normal), which trained models never leave; beyond, the max is subtracted. */
#define NF_PV_EXP_SAFE 60.0f
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

/* The three one-blob slots of v (nf_oneblob_slots, offset 0): rows into row, values in lanes
 * 0 .. 2 of the result, the two inner Q of the quartic kernel computed in one vector (its
 * polynomial 1/2 + u (15/16 - 5/8 u^2 + 3/16 u^4) in Horner form in u^2). */
static NF_ALWAYS_INLINE __m128 nf_pv_oneblob(float v, uint32_t bins, int wrap, uint32_t row[3])
{
    const float vb = nf_clampf(v, 0.0f, 1.0f) * (float)bins;
    const int first = (int)vb - 1; /* vb >= 0, so truncation is floor */
    /* With f = vb - floor(vb) in [0, 1), the four Q are at -1 - f, -f, 1 - f and 2 - f: the
     * outer two clamp to the kernel's ends, Q = 0 and 1, so only u = -f and 1 - f, inside
     * [-1, 1], need the polynomial, and no clamp */
    __m128 vbv = _mm_set1_ps(vb);
    __m128 f = _mm_sub_ps(vbv, _mm_round_ps(vbv, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC));
    __m128 u = _mm_sub_ps(_mm_setr_ps(0.0f, 1.0f, 0.0f, 0.0f), f);
    __m128 u2 = _mm_mul_ps(u, u);
    __m128 p = _mm_fmadd_ps(u2, _mm_set1_ps(0.1875f), _mm_set1_ps(-0.625f));
    p = _mm_fmadd_ps(u2, p, _mm_set1_ps(0.9375f));
    /* At u = -1 and 1 this form is 0 and 1 exactly (p = 1/2 without rounding) */
    __m128 q = _mm_fmadd_ps(u, p, _mm_set1_ps(0.5f)); /* Q(-f), Q(1 - f) in lanes 0, 1 */
    /* the slots Q(-f) - 0, Q(1 - f) - Q(-f), 1 - Q(1 - f) */
    __m128 upper = _mm_blend_ps(q, _mm_set1_ps(1.0f), 0xc);
    __m128 lower = _mm_castsi128_ps(_mm_slli_si128(_mm_castps_si128(q), 4));
    __m128 value = _mm_sub_ps(upper, lower);
    int keep[4] = {0, 0, 0, 0};
    for (int c = 0; c < 3; ++c) {
        int j = first + c;
        int inside = wrap | ((j >= 0) & (j < (int)bins));
        int bin = wrap ? nf_oneblob_bin(j, bins, 1) : j;
        row[c] = (uint32_t)(inside ? bin : 0);
        keep[c] = -inside;
    }
    __m128i mask = _mm_setr_epi32(keep[0], keep[1], keep[2], keep[3]);
    return _mm_and_ps(value, _mm_castsi128_ps(mask));
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
        _mm512_castps128_ps512(nf_pv_oneblob(v, sh.blob_bins, nf_layer_wraps(m, layer), rows));
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
    if (nf_layer_circular(m, layer)) {
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

/* One bin of the spline, as nf_spline_bin, with its slope and inverse width. */
typedef struct nf_pv_bin {
    float xk, yk, x1, y1, wk, hk, d0, d1, sk, iw;
} nf_pv_bin;

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

/* y and dy/dx at x in the bin: nf_spline_bin_eval's formula, with the bin's slope and inverse
 * width given (a multiply where it divides) and its multiply-adds fused. */
static NF_ALWAYS_INLINE float nf_pv_bin_eval(const nf_pv_bin *b, float x, float *dydx)
{
    float xi = nf_clampf((x - b->xk) * b->iw, 0.0f, 1.0f);
    float sk = b->sk, om = 1.0f - xi, e = xi * om, xi2 = xi * xi;
    /* fused, and y from one division instead of a reciprocal and a product: the chain from x
     * to y is the layer's last stretch before the next layer can start */
    float den = __builtin_fmaf(b->d1 + b->d0 - 2.0f * sk, e, sk);
    float num = __builtin_fmaf(b->d0, e, sk * xi2);
    float p = __builtin_fmaf(b->d1, xi2, __builtin_fmaf(2.0f * sk, e, b->d0 * (om * om)));
    float slope = sk / den;
    *dydx = slope * slope * p;
    float y = __builtin_fmaf(b->hk, num / den, b->yk);
    return xi >= 1.0f ? b->y1 : nf_clampf(y, 0.0f, 1.0f);
}

/* x in the bin with forward(x) = y: nf_spline_bin_solve's root 2c / (-b - sqrt(disc)), which
 * has no cancellation, in float, its multiply-adds fused. Without its double coefficients the root
 * may lose monotonicity in y by rounding where s_k and d_k nearly cancel; a density only needs it
 * close, which the bound of the tests covers. */
static NF_ALWAYS_INLINE float nf_pv_bin_solve(const nf_pv_bin *b, float y)
{
    float hk = b->hk, d0 = b->d0, sk = b->sk;
    float t = y - b->yk, sum = b->d1 + d0 - 2.0f * sk;
    float qa = __builtin_fmaf(t, sum, hk * (sk - d0));
    float qb = __builtin_fmaf(-t, sum, hk * d0);
    float qc = -sk * t;
    float disc = __builtin_fmaf(qb, qb, qa * (-4.0f * qc));
    float denom = -qb - sqrtf(disc > 0.0f ? disc : 0.0f);
    float xi = denom != 0.0f ? 2.0f * qc / denom : 0.0f;
    /* one clamp, into the bin, where nf_spline_bin_solve clamps xi and then x: a root outside
     * [0, 1] (rounding) lands on the bin's end either way */
    return y >= b->y1 ? b->x1 : nf_minf(nf_maxf(b->xk + xi * b->wk, b->xk), b->x1);
}

/* Step j's map with the layer's spline in s (nf_point_walk_map's, on the vector knots). Both
 * directions multiply w->det by the slope: an inverse walk's det is the forward |det J|, which
 * nf_pv_walk_density divides by once. */
static NF_ALWAYS_INLINE void nf_pv_map(const nf_model *m, nf_point_shape sh, int inverse,
                                       uint32_t j, nf_point_walk *w, const nf_pv_spline *s)
{
    uint32_t i = nf_point_walk_layer(sh, inverse, j), t = nf_transformed(i);
    const int turns = nf_layer_turns(m, i);
    nf_pv_bin bin;
    float slope;
    if (!inverse) {
        nf_pv_bin_at(s, nf_pv_find(s->x, sh.bins, w->x[t]), &bin);
        w->x[t] = nf_pv_bin_eval(&bin, w->x[t], &slope);
        if (turns)
            w->x[t] = nf_wrap_unit(w->x[t] + nf_rotation(s->rotation, sh.bins));
        w->det *= slope;
    } else {
        if (turns)
            w->x[t] = nf_wrap_unit(w->x[t] - nf_rotation(s->rotation, sh.bins));
        nf_pv_bin_at(s, nf_pv_find(s->y, sh.bins, w->x[t]), &bin);
        float solved = nf_pv_bin_solve(&bin, w->x[t]);
        nf_pv_bin_eval(&bin, solved, &slope);
        w->x[t] = solved;
        w->det *= slope; /* the forward |det J| here: one division at the end, not per layer */
    }
}

/* `count` (1 or 2) walks at the point, each coupling layer of them in step. */
static NF_ALWAYS_INLINE void nf_pv_walks(const nf_model *m, nf_point_shape sh,
                                         const nf_shading_point *p, uint32_t count,
                                         const int *inverse, nf_point_walk *w)
{
    for (uint32_t j = 0; j < sh.layers; ++j) {
        nf_pv_spline s[NF_PV_PAIR];
        for (uint32_t d = 0; d < count; ++d) {
            uint32_t layer = nf_point_walk_layer(sh, inverse[d], j);
            nf_pv_layer(m, sh, p, layer, w[d].x[1u - nf_transformed(layer)], &s[d]);
        }
        for (uint32_t d = 0; d < count; ++d)
            nf_pv_map(m, sh, inverse[d], j, &w[d], &s[d]);
    }
}

/* The walks' ends, as point.h's (nf_point_walk_sample, _pdf, _sampled, _density) with the
 * trigonometry of each end in one vector: the sphere maps' two angles together, and at a
 * density's end sin(theta) of the direction asked about beside them. For the cosine prior on
 * surfaces, a draw's prior density comes from the drawn direction itself, where point.h maps
 * the square's point back to a direction first. Other priors, the cosine's uniform share and
 * media take point.h's ends (a density's start aside): with the phase function's draw and
 * density on these ends, the lobe at g = 0.99 turned the vector maps' last-bit differences into
 * 0.26-0.35 % of a draw's density against nf_sample's (tried), beyond the bound. */
static NF_ALWAYS_INLINE nf_status nf_pv_walk_sample(const nf_model *m, const nf_shading_point *p,
                                                    const float u[2], nf_point_walk *w)
{
    const float eps = m->cfg.prior_epsilon, u0 = nf_clamp_unit(u[0]);
    if (m->cfg.prior != NF_PRIOR_COSINE || nf_context_in_medium(&p->context_) || !(u0 < 1.0f - eps))
        return nf_point_walk_sample(m, p, &p->context_, u, w);
    /* nf_cosine_direction around the point's unit normal, its azimuth's sincos in a vector */
    float d[3];
    __m256 sc = nf_pv_sincos_turns(_mm_set1_ps(nf_clamp_unit(u[1])));
    const float lz =
        nf_cosine_direction_at(p->frame_, nf_clamp_unit(u0 / (1.0f - eps)), _mm256_cvtss_f32(sc),
                               _mm_cvtss_f32(_mm256_extractf128_ps(sc, 1)), d);
    nf_pv_to_square(d, w->x);
    /* q_s = sin(theta) lobe(n.w), with n.w = lz and |d| = 1 up to rounding */
    const float sin_theta = nf_maxf(sqrtf(d[0] * d[0] + d[1] * d[1]), NF_SIN_THETA_MIN);
    w->p = p;
    w->user = &p->context_;
    w->q = sin_theta * nf_cosine_lobe(lz, eps);
    w->det = 1.0;
    return NF_OK;
}

static NF_ALWAYS_INLINE void nf_pv_walk_pdf(const nf_shading_point *p, const float dir[3],
                                            nf_point_walk *w)
{
    nf_pv_to_square(dir, w->x);
    w->p = p;
    w->user = &p->context_;
    w->s0 = w->x[0];
    w->det = 1.0;
}

static NF_ALWAYS_INLINE void nf_pv_walk_sampled(nf_point_walk *w, float dir[3], float *pdf)
{
    w->x[1] = nf_minf(w->x[1], 0x1.fffffep-1f); /* as nf_point_walk_sampled */
    float v[8];
    _mm256_storeu_ps(v, nf_pv_sincos_turns(_mm_setr_ps(0.5f * w->x[0], w->x[1], 0.0f, 0.0f)));
    const float sin_theta = nf_maxf(v[0], 0.0f);
    dir[0] = sin_theta * v[5];
    dir[1] = sin_theta * v[1];
    dir[2] = v[4];
    if (pdf)
        *pdf = nf_solid_angle_pdf_at((double)w->q / w->det, sin_theta);
}

static NF_ALWAYS_INLINE nf_status nf_pv_walk_density(const nf_model *m, const nf_point_walk *w,
                                                     float *pdf)
{
    const nf_prior_kind kind = m->cfg.prior;
    if ((kind != NF_PRIOR_COSINE && kind != NF_PRIOR_UNIFORM_DIRECTION) ||
        nf_context_in_medium(&w->p->context_)) {
        nf_point_walk inverted = *w; /* point.h's walks keep 1 / |det J| */
        inverted.det = 1.0 / w->det;
        return nf_point_walk_density(m, &inverted, pdf);
    }
    /* sin and cos of theta and phi at the latent point, and sin(theta) of the direction */
    float v[8];
    _mm256_storeu_ps(v,
                     nf_pv_sincos_turns(_mm_setr_ps(0.5f * w->x[0], w->x[1], 0.5f * w->s0, 0.0f)));
    const float sin_raw = nf_maxf(v[0], 0.0f);
    const float sin_theta = nf_maxf(sin_raw, NF_SIN_THETA_MIN);
    float q = NF_HALF_PI * sin_theta;
    if (kind == NF_PRIOR_COSINE) {
        const float *n = w->p->frame_;
        const float c = n[0] * (sin_raw * v[5]) + n[1] * (sin_raw * v[1]) + n[2] * v[4];
        q = sin_theta * nf_cosine_lobe(c, m->cfg.prior_epsilon);
    }
    *pdf = nf_solid_angle_pdf_at((double)q / w->det, nf_maxf(v[2], 0.0f));
    return NF_OK;
}

static inline nf_status nf_pv_sample_one(const nf_model *m, nf_point_shape sh,
                                         const nf_shading_point *p, const float u[2], float dir[3],
                                         float *pdf)
{
    static const int forward[1] = {0};
    nf_point_walk w;
    nf_status st = nf_pv_walk_sample(m, p, u, &w);
    if (st != NF_OK)
        return st;
    nf_pv_walks(m, sh, p, 1, forward, &w);
    nf_pv_walk_sampled(&w, dir, pdf);
    return NF_OK;
}

static inline nf_status nf_pv_pdf_one(const nf_model *m, nf_point_shape sh,
                                      const nf_shading_point *p, const float dir[3], float *pdf)
{
    static const int inverse[1] = {1};
    nf_point_walk w;
    nf_pv_walk_pdf(p, dir, &w);
    nf_pv_walks(m, sh, p, 1, inverse, &w);
    return nf_pv_walk_density(m, &w, pdf);
}

static inline nf_status nf_pv_pdf_pair(const nf_model *m, nf_point_shape sh,
                                       const nf_shading_point *p, const float dir[6], float pdf[2])
{
    static const int inverse[2] = {1, 1};
    nf_point_walk w[2];
    nf_pv_walk_pdf(p, dir, &w[0]);
    nf_pv_walk_pdf(p, dir + 3, &w[1]);
    nf_pv_walks(m, sh, p, 2, inverse, w);
    nf_status st = nf_pv_walk_density(m, &w[0], &pdf[0]);
    return st != NF_OK ? st : nf_pv_walk_density(m, &w[1], &pdf[1]);
}

/* A draw and another direction's density; a custom prior's failure writes nothing. */
static inline nf_status nf_pv_sample_and_pdf(const nf_model *m, nf_point_shape sh,
                                             const nf_shading_point *p, const float u[2],
                                             float dir[3], float *pdf, const float eval_dir[3],
                                             float *eval_pdf)
{
    static const int inverse[2] = {0, 1};
    nf_point_walk w[2];
    nf_status st = nf_pv_walk_sample(m, p, u, &w[0]);
    if (st != NF_OK)
        return st;
    nf_pv_walk_pdf(p, eval_dir, &w[1]);
    nf_pv_walks(m, sh, p, 2, inverse, w);
    float q;
    if ((st = nf_pv_walk_density(m, &w[1], &q)) != NF_OK)
        return st;
    nf_pv_walk_sampled(&w[0], dir, pdf);
    *eval_pdf = q;
    return NF_OK;
}

#endif /* __AVX512F__ */
#endif /* NISFLOW_KERNELS_POINT_VECTOR_H */
