/*
 * sphere.h - the map between unit directions and the unit square (docs/theory.md section 1) as
 * inline code on the fast trigonometry of fastmath.h. sphere.c wraps it for the public API, so the
 * library has exactly one definition of the parameterization.
 */
#ifndef NISFLOW_KERNELS_SPHERE_H
#define NISFLOW_KERNELS_SPHERE_H

#include <math.h>

#include "fastmath.h"
#include "internal.h"

/* sin(pi x) for x in [0,1]. In turns the argument is x/2, and the reduction subtracts a
 * quarter or half turn exactly, so relative precision holds near both poles. */
static inline float nf_sin_pi(float x)
{
    float s, c;
    nf_fast_sincos_turns(0.5f * nf_clampf(x, 0.0f, 1.0f), &s, &c);
    return nf_maxf(s, 0.0f);
}

/* dir_in scaled by an exact power of two so that its largest component lies in [1, 2), into
 * dir. Directions may have any positive length. Squaring a component above ~2^64 overflows
 * and one below ~2^-63 underflows, which made theta wrong (e.g. (1e20, 1e20, 1e20) gave
 * theta = pi/2). The angles are scale-invariant, every power-of-two multiple of a vector maps
 * to the same bits, and for vectors of ordinary length the exact scaling leaves the results
 * bit-identical to the unscaled computation. */
static NF_ALWAYS_INLINE void nf_square_scaled(const float dir_in[3], float dir[3])
{
    float big = nf_maxf(nf_maxf(fabsf(dir_in[0]), fabsf(dir_in[1])), fabsf(dir_in[2]));
    /* Branch-free, so that the kernels' loops over samples vectorize. The zero vector (and
     * Inf/NaN) keeps its components: scale and pre are then 1. First into [2^-85, 2^64)
     * (denormals become normal), then by 2^-e with big in [2^e, 2^(e+1)), e in [-85, 63]:
     * both factors are normal floats. */
    int usable = big > 0.0f && big <= 0x1.fffffep127f;
    float pre = big >= 0x1p64f ? 0x1p-64f : 1.0f;
    pre = big < 0x1p-64f ? 0x1p64f : pre;
    int e = (int)((nf_float_to_bits(big * pre) >> 23) & 0xffu) - 127;
    float scale = nf_bits_to_float((uint32_t)(127 - e) << 23);
    pre = usable ? pre : 1.0f;
    scale = usable ? scale : 1.0f;
    for (int a = 0; a < 3; ++a)
        dir[a] = dir_in[a] * pre * scale;
}

static NF_ALWAYS_INLINE void nf_to_square(const float dir_in[3], float s[2])
{
    float dir[3];
    nf_square_scaled(dir_in, dir);
    float theta = nf_fast_atan2(sqrtf(dir[0] * dir[0] + dir[1] * dir[1]), dir[2]);
    float phi = nf_fast_atan2(dir[1], dir[0]);
    phi = phi < 0.0f ? phi + NF_TWO_PI : phi;
    s[0] = nf_clampf(theta * (1.0f / NF_PI), 0.0f, 1.0f);
    /* phi just below 2 pi can round up to 2 pi; keep s1 below 1 so the seam stays on the side
     * it was approached from. */
    s[1] = nf_clampf(phi * (1.0f / NF_TWO_PI), 0.0f, 0x1.fffffep-1f);
}

/* The unit direction of s; also returns sin(theta), which callers need for the Jacobian. */
static inline float nf_from_square(const float s[2], float dir[3])
{
    float sin_theta, cos_theta, sin_phi, cos_phi;
    nf_fast_sincos_turns(0.5f * s[0], &sin_theta, &cos_theta);
    nf_fast_sincos_turns(s[1], &sin_phi, &cos_phi);
    sin_theta = nf_maxf(sin_theta, 0.0f);
    dir[0] = sin_theta * cos_phi;
    dir[1] = sin_theta * sin_phi;
    dir[2] = cos_theta;
    return sin_theta;
}

#endif /* NISFLOW_KERNELS_SPHERE_H */
