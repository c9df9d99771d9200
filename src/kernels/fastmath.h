/*
 * fastmath.h - branch-free float approximations of exp, log, sin/cos and atan2 for the hot
 * loops. They inline into the per-ISA kernels, where libm calls would be opaque, and their
 * straight-line code lets the compiler vectorize loops over spline bins.
 *
 * Error bounds, measured by tests/correctness/test_fastmath.c against double-precision libm
 * over the stated domains (and asserted there):
 *   nf_fast_exp(x), x in [-87, 88]        relative error < 3e-7
 *   nf_fast_log(x), x in [1e-30, 1e30]    absolute error < 3e-7 where |log x| <= 1, else
 *                                         relative error < 3e-7
 *   nf_fast_sincos_turns(t)               absolute error < 3e-7 (sin relative < 3e-7 near 0)
 *   nf_fast_atan2(y, x)                   absolute error < 3e-7 rad (relative near 0)
 * The exp, log and atan coefficients are Cephes' single-precision minimax fits (S. Moshier);
 * sin and cos use their Taylor series, short enough on the reduced range.
 */
#ifndef NISFLOW_KERNELS_FASTMATH_H
#define NISFLOW_KERNELS_FASTMATH_H

#include <stdint.h>
#include <string.h>

static inline float nf_bits_to_float(uint32_t u)
{
    float f;
    memcpy(&f, &u, sizeof f);
    return f;
}

static inline uint32_t nf_float_to_bits(float f)
{
    uint32_t u;
    memcpy(&u, &f, sizeof u);
    return u;
}

/* e^x. Range reduction x = n ln2 + r with |r| <= ln2/2, a degree-6 polynomial for e^r, and
 * 2^n assembled in the exponent bits. Inputs are clamped to [-87, 88] (no overflow, no
 * denormals). */
static inline float nf_fast_exp(float x)
{
    x = x < -87.0f ? -87.0f : (x > 88.0f ? 88.0f : x);
    /* round(x / ln2) without floorf (a libm call before SSE4.1): shift to positive, truncate */
    int n = (int)(x * 1.44269504088896341f + 128.5f) - 128;
    float fn = (float)n;
    float r = x - fn * 0.693359375f + fn * 2.12194440e-4f; /* ln2 split in two for accuracy */
    float r2 = r * r;
    float p = 1.9875691500e-4f;
    p = p * r + 1.3981999507e-3f;
    p = p * r + 8.3334519073e-3f;
    p = p * r + 4.1665795894e-2f;
    p = p * r + 1.6666665459e-1f;
    p = p * r + 5.0000001201e-1f;
    p = p * r2 + r + 1.0f;
    return p * nf_bits_to_float((uint32_t)(n + 127) << 23);
}

/* Natural log for normal positive floats: x = m 2^e with m in [sqrt(1/2), sqrt(2)). */
static inline float nf_fast_log(float x)
{
    uint32_t bits = nf_float_to_bits(x);
    int e = (int)((bits >> 23) & 0xffu) - 126;
    float m = nf_bits_to_float((bits & 0x007fffffu) | 0x3f000000u); /* in [0.5, 1) */
    int small = m < 0.70710678118654752f;
    e -= small;
    m = small ? m + m - 1.0f : m - 1.0f;
    float z = m * m;
    float y = 7.0376836292e-2f;
    y = y * m - 1.1514610310e-1f;
    y = y * m + 1.1676998740e-1f;
    y = y * m - 1.2420140846e-1f;
    y = y * m + 1.4249322787e-1f;
    y = y * m - 1.6668057665e-1f;
    y = y * m + 2.0000714765e-1f;
    y = y * m - 2.4999993993e-1f;
    y = y * m + 3.3333331174e-1f;
    y = y * m * z;
    float fe = (float)e;
    y += -2.12194440e-4f * fe;
    y += -0.5f * z;
    return m + y + 0.693359375f * fe;
}

/* sin and cos of 2 pi t for t in [-1, 1] (turns). t is reduced to r in [-1/8, 1/8] turn and
 * the quadrant picks which polynomial, and which sign, each output takes. Working in turns
 * keeps the reduction exact: t - q/4 has no rounding for the t this library passes. */
static inline void nf_fast_sincos_turns(float t, float *s, float *c)
{
    int q = (int)(t * 4.0f + 64.5f) - 64; /* nearest quarter turn */
    /* the reduced turn is exact; scaling it to radians in double keeps it to one rounding */
    float r = (float)((double)(t - (float)q * 0.25f) * 6.28318530717958647692);
    /* Taylor series to r^9 and r^10 on |r| <= pi/4: truncation below 2e-9, so the result is
     * limited by float rounding alone. */
    float r2 = r * r;
    float sp = 2.7557319224e-6f;
    sp = sp * r2 - 1.9841269841e-4f;
    sp = sp * r2 + 8.3333333333e-3f;
    sp = sp * r2 - 1.6666666667e-1f;
    float sin_r = r + r * r2 * sp;
    float cp = -2.7557319224e-7f;
    cp = cp * r2 + 2.4801587302e-5f;
    cp = cp * r2 - 1.3888888889e-3f;
    cp = cp * r2 + 4.1666666667e-2f;
    float cos_r = 1.0f - 0.5f * r2 + r2 * r2 * cp;
    int quad = q & 3;
    float sv = (quad & 1) ? cos_r : sin_r;
    float cv = (quad & 1) ? sin_r : cos_r;
    *s = (quad & 2) ? -sv : sv;
    *c = ((quad + 1) & 2) ? -cv : cv;
}

/* atan2(y, x) in (-pi, pi]; atan2(0, 0) = 0. */
static inline float nf_fast_atan2(float y, float x)
{
    float ax = x < 0.0f ? -x : x, ay = y < 0.0f ? -y : y;
    float hi = ax > ay ? ax : ay, lo = ax > ay ? ay : ax;
    float a = hi > 0.0f ? lo / hi : 0.0f; /* in [0, 1] */
    /* atan(a) = pi/4 + atan((a - 1)/(a + 1)) moves a above tan(pi/8) into the fitted range */
    int big = a > 0.4142135623730950f;
    float base = big ? 0.78539816339744831f : 0.0f;
    a = big ? (a - 1.0f) / (a + 1.0f) : a;
    float z = a * a;
    float p = 8.05374449538e-2f;
    p = p * z - 1.38776856032e-1f;
    p = p * z + 1.99777106478e-1f;
    p = p * z - 3.33329491539e-1f;
    float r = base + (p * z * a + a);
    r = ay > ax ? 1.57079632679489662f - r : r;
    r = x < 0.0f ? 3.14159265358979324f - r : r;
    return y < 0.0f ? -r : r;
}

#endif /* NISFLOW_KERNELS_FASTMATH_H */
