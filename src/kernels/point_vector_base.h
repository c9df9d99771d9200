/*
 * point_vector_base.h - what the per-direction path's two register layers share
 * (point_vector_avx512.h, point_vector_avx2.h): the bin that a layer hands the walk, the
 * one-blob slots of a coordinate, and the exp and log polynomials, written once for either
 * vector width. point_vector.h says what the path is for.
 */
#ifndef NISFLOW_KERNELS_POINT_VECTOR_BASE_H
#define NISFLOW_KERNELS_POINT_VECTOR_BASE_H

#if defined(__AVX2__) && defined(__FMA__)

#include <float.h>
#include <immintrin.h>

#include "point.h"

/* Directions walked in step at most: two questions of a vertex. One direction is a chain of
 * dependent operations that leaves the core waiting on latencies; a second, independent chain
 * interleaved with it fills those waits. */
#define NF_PV_PAIR 2u

/* The softmax of the knots needs no shift by the max while every |raw| <= NF_PV_EXP_SAFE (e^60
 * summed 16 times stays finite, e^-60 normal), which trained models never leave; beyond, the
 * max is subtracted. */
#define NF_PV_EXP_SAFE 60.0f

/* One bin of the spline, as nf_spline_bin, with its slope and inverse width. */
typedef struct nf_pv_bin {
    float xk, yk, x1, y1, wk, hk, d0, d1, sk, iw;
} nf_pv_bin;

/* The two polynomials of nf_pv_exp and nf_pv_log for a vector type V, given its operations:
 *
 * 2^f for f in [-1/2, 1/2] by its Taylor series to degree 6 in Estrin's scheme (truncation
 * below 2e-8), three multiply-adds deep instead of nf_fast_exp's seven;
 *
 * log of m 2^e from m - 1 (or 2m - 1 below sqrt(1/2)) and e, nf_fast_log's polynomial in
 * Estrin's scheme, four multiply-adds deep instead of nine.
 *
 * Both register layers evaluate the same operations in the same order, so lanes agree to the
 * bit between them. */
#define NF_PV_POLYNOMIALS(V, SET1, MUL, ADD, FMA)                                                  \
    static NF_ALWAYS_INLINE V nf_pv_exp2_reduced(V f)                                              \
    {                                                                                              \
        V f2 = MUL(f, f), f4 = MUL(f2, f2);                                                        \
        V p01 = FMA(f, SET1(0.693147180559945309f), SET1(1.0f));                                   \
        V p23 = FMA(f, SET1(0.0555041086648215800f), SET1(0.240226506959100712f));                 \
        V p45 = FMA(f, SET1(0.00133335581464284434f), SET1(0.00961812910762847717f));              \
        V p46 = FMA(f2, SET1(0.000154035303933816099f), p45);                                      \
        return FMA(f4, p46, FMA(f2, p23, p01));                                                    \
    }                                                                                              \
    static NF_ALWAYS_INLINE V nf_pv_log_reduced(V m, V e)                                          \
    {                                                                                              \
        V z = MUL(m, m), m4 = MUL(z, z), m8 = MUL(m4, m4);                                         \
        V q0 = FMA(m, SET1(-2.4999993993e-1f), SET1(3.3333331174e-1f));                            \
        V q1 = FMA(m, SET1(-1.6668057665e-1f), SET1(2.0000714765e-1f));                            \
        V q2 = FMA(m, SET1(-1.2420140846e-1f), SET1(1.4249322787e-1f));                            \
        V q3 = FMA(m, SET1(-1.1514610310e-1f), SET1(1.1676998740e-1f));                            \
        V r0 = FMA(z, q1, q0), r1 = FMA(z, q3, q2);                                                \
        V y = FMA(m8, SET1(7.0376836292e-2f), FMA(m4, r1, r0));                                    \
        y = MUL(MUL(y, m), z);                                                                     \
        y = FMA(e, SET1(-2.12194440e-4f), y);                                                      \
        y = FMA(z, SET1(-0.5f), y);                                                                \
        return FMA(e, SET1(0.693359375f), ADD(m, y));                                              \
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

#endif /* __AVX2__ && __FMA__ */
#endif /* NISFLOW_KERNELS_POINT_VECTOR_BASE_H */
