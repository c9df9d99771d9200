/*
 * lanes.h - one value per lane of a tile (NF_TILE = 16 floats) as a single variable, for the
 * accumulators of the tile kernels.
 *
 * Why: a loop `for k: for i: acc[i] += w[k] * x[k][i]` vectorizes over i, but GCC and Clang
 * then keep the array acc in memory between iterations of k, which puts a store-to-load round
 * trip on every step of the dependency chain (docs/performance.md, "Measurements behind the
 * kernels", has what moving the knots and the bin selection into this type saved). With GNU C
 * vector types the accumulator is one variable that lives in registers (one zmm, two ymm or
 * four xmm). Other compilers get a plain struct and
 * loops with the same results.
 */
#ifndef NISFLOW_KERNELS_LANES_H
#define NISFLOW_KERNELS_LANES_H

#include <string.h>

#include <stdint.h>

#if defined(__GNUC__) || defined(__clang__)
#if defined(__AVX512F__) || defined(__FMA__)
#include <immintrin.h>
#endif
#endif

/* A tile (tile.h) is one nf_lanes of samples: 16 lanes, one AVX-512 register of floats, two
 * AVX2 ones. */
#define NF_TILE 16u

#if defined(__GNUC__) || defined(__clang__)
#define NF_LANES_VECTOR 1
typedef float nf_lanes __attribute__((vector_size(64)));
typedef int32_t nf_lanes_i32 __attribute__((vector_size(64))); /* comparison masks */
#else
typedef struct nf_lanes {
    float v[16];
} nf_lanes;
#endif

#if defined(NF_LANES_VECTOR) && defined(__AVX2__) && !defined(__AVX512F__)
/* With AVX2, GCC 12 lowers comparisons and selects on 64-byte vectors to a scalar cmov per
 * lane (seen in perf profiles of nf_pdf; docs/performance.md). The selecting
 * operations below therefore work on two 32-byte halves, which map onto AVX2 registers one
 * to one. */
#define NF_LANES_HALVES 1
typedef float nf_half __attribute__((vector_size(32)));
typedef int32_t nf_half_i32 __attribute__((vector_size(32)));
#endif

/* Values travel by pointer: a vector passed by value changes the calling convention between
 * instruction sets (GCC's -Wpsabi), and these functions always inline anyway. */
static inline void nf_lanes_load(nf_lanes *r, const float *p) { memcpy(r, p, sizeof *r); }

static inline void nf_lanes_store(float *p, const nf_lanes *v) { memcpy(p, v, sizeof *v); }

static inline void nf_lanes_splat(nf_lanes *r, float s)
{
#if defined(NF_LANES_VECTOR)
    *r = s - (nf_lanes){0.0f}; /* s - 0 is s exactly, -0 included */
#else
    for (int i = 0; i < 16; ++i)
        r->v[i] = s;
#endif
}

/* acc += s * x, with one rounding (a fused multiply-add) in the kernels built for an
 * instruction set that has FMA, with two elsewhere. Within one build of the kernels every
 * caller rounds alike, which is what keeps the per-sample and tiled paths bit-identical; the
 * generic kernels differ from the fused ones by one rounding per step (test_kernels bounds
 * the difference at 1e-4). Fused, a conditioner's multiply-add chains are half as long and
 * issue half the instructions. */
static inline void nf_lanes_madd(nf_lanes *acc, float s, const nf_lanes *x)
{
#if defined(NF_LANES_VECTOR) && defined(__AVX512F__)
    __m512 a, v;
    memcpy(&a, acc, sizeof a);
    memcpy(&v, x, sizeof v);
    a = _mm512_fmadd_ps(_mm512_set1_ps(s), v, a);
    memcpy(acc, &a, sizeof a);
#elif defined(NF_LANES_VECTOR) && defined(__FMA__)
    __m256 a0, a1, v0, v1, sv = _mm256_set1_ps(s);
    memcpy(&a0, acc, sizeof a0);
    memcpy(&a1, (const char *)acc + sizeof a0, sizeof a1);
    memcpy(&v0, x, sizeof v0);
    memcpy(&v1, (const char *)x + sizeof v0, sizeof v1);
    a0 = _mm256_fmadd_ps(sv, v0, a0);
    a1 = _mm256_fmadd_ps(sv, v1, a1);
    memcpy(acc, &a0, sizeof a0);
    memcpy((char *)acc + sizeof a0, &a1, sizeof a1);
#elif defined(NF_LANES_VECTOR)
    *acc += s * *x;
#else
    for (int i = 0; i < 16; ++i)
        acc->v[i] += s * x->v[i];
#endif
}

/* acc += x */
static inline void nf_lanes_add(nf_lanes *acc, const nf_lanes *x)
{
#if defined(NF_LANES_VECTOR)
    *acc += *x;
#else
    for (int i = 0; i < 16; ++i)
        acc->v[i] += x->v[i];
#endif
}

/* acc /= x */
static inline void nf_lanes_div(nf_lanes *acc, const nf_lanes *x)
{
#if defined(NF_LANES_VECTOR)
    *acc /= *x;
#else
    for (int i = 0; i < 16; ++i)
        acc->v[i] /= x->v[i];
#endif
}

/* acc -= x */
static inline void nf_lanes_sub(nf_lanes *acc, const nf_lanes *x)
{
#if defined(NF_LANES_VECTOR)
    *acc -= *x;
#else
    for (int i = 0; i < 16; ++i)
        acc->v[i] -= x->v[i];
#endif
}

/* acc *= x */
static inline void nf_lanes_mul(nf_lanes *acc, const nf_lanes *x)
{
#if defined(NF_LANES_VECTOR)
    *acc *= *x;
#else
    for (int i = 0; i < 16; ++i)
        acc->v[i] *= x->v[i];
#endif
}

/* acc = acc > x ? acc : x per lane, as nf_maxf(acc, x) */
static inline void nf_lanes_max(nf_lanes *acc, const nf_lanes *x)
{
#if defined(NF_LANES_HALVES)
    for (int h = 0; h < 2; ++h) {
        nf_half a, b;
        nf_half_i32 keep, ia, ib;
        memcpy(&a, (const char *)acc + h * sizeof a, sizeof a);
        memcpy(&b, (const char *)x + h * sizeof b, sizeof b);
        keep = a > b;
        memcpy(&ia, &a, sizeof ia);
        memcpy(&ib, &b, sizeof ib);
        ia = (ia & keep) | (ib & ~keep);
        memcpy((char *)acc + h * sizeof ia, &ia, sizeof ia);
    }
#elif defined(NF_LANES_VECTOR)
    nf_lanes_i32 keep = *acc > *x, a, b;
    memcpy(&a, acc, sizeof a);
    memcpy(&b, x, sizeof b);
    a = (a & keep) | (b & ~keep);
    memcpy(acc, &a, sizeof a);
#else
    for (int i = 0; i < 16; ++i)
        acc->v[i] = acc->v[i] > x->v[i] ? acc->v[i] : x->v[i];
#endif
}

/* count[i] += (v[i] >= key[i]) for 16 lanes */
static inline void nf_lanes_count_ge(uint32_t *count, const nf_lanes *v, const nf_lanes *key)
{
#if defined(NF_LANES_HALVES)
    for (int h = 0; h < 2; ++h) {
        nf_half a, b;
        nf_half_i32 c;
        memcpy(&a, (const char *)v + h * sizeof a, sizeof a);
        memcpy(&b, (const char *)key + h * sizeof b, sizeof b);
        memcpy(&c, count + 8 * h, sizeof c);
        c -= (a >= b);
        memcpy(count + 8 * h, &c, sizeof c);
    }
#elif defined(NF_LANES_VECTOR)
    nf_lanes_i32 c;
    memcpy(&c, count, sizeof c);
    c -= (*v >= *key); /* a true comparison is -1 */
    memcpy(count, &c, sizeof c);
#else
    for (int i = 0; i < 16; ++i)
        count[i] += v->v[i] >= key->v[i];
#endif
}

#if defined(NF_LANES_HALVES)
/* acc[i] = hit[i] ? x[i] : acc[i] for the eight lanes of half h, hit a comparison mask */
static inline void nf_half_blend(nf_lanes *acc, int h, const nf_half_i32 *hit, const nf_lanes *x)
{
    nf_half_i32 a, b;
    memcpy(&a, (const char *)acc + h * sizeof a, sizeof a);
    memcpy(&b, (const char *)x + h * sizeof b, sizeof b);
    a = (a & ~*hit) | (b & *hit);
    memcpy((char *)acc + h * sizeof a, &a, sizeof a);
}
#endif

#if defined(NF_LANES_VECTOR)
/* acc[i] = hit[i] ? x[i] : acc[i], hit a comparison mask (all ones or zero per lane) */
static inline void nf_lanes_blend(nf_lanes *acc, const nf_lanes_i32 *hit, const nf_lanes *x)
{
    nf_lanes_i32 a, b;
    memcpy(&a, acc, sizeof a);
    memcpy(&b, x, sizeof b);
    a = (a & ~*hit) | (b & *hit);
    memcpy(acc, &a, sizeof a);
}
#endif

/* acc[i] = index[i] == j ? x[i] : acc[i] for 16 lanes */
static inline void nf_lanes_pick(nf_lanes *acc, const uint32_t *index, uint32_t j,
                                 const nf_lanes *x)
{
#if defined(NF_LANES_HALVES)
    for (int h = 0; h < 2; ++h) {
        nf_half_i32 idx, hit;
        memcpy(&idx, index + 8 * h, sizeof idx);
        hit = idx == (nf_half_i32){0} + (int32_t)j;
        nf_half_blend(acc, h, &hit, x);
    }
#elif defined(NF_LANES_VECTOR)
    nf_lanes_i32 idx, hit;
    memcpy(&idx, index, sizeof idx);
    hit = idx == (nf_lanes_i32){0} + (int32_t)j;
    nf_lanes_blend(acc, &hit, x);
#else
    for (int i = 0; i < 16; ++i)
        acc->v[i] = index[i] == j ? x->v[i] : acc->v[i];
#endif
}

/* acc[i] = index[i] > j ? x[i] : acc[i] for 16 lanes */
static inline void nf_lanes_pick_above(nf_lanes *acc, const uint32_t *index, uint32_t j,
                                       const nf_lanes *x)
{
#if defined(NF_LANES_HALVES)
    for (int h = 0; h < 2; ++h) {
        nf_half_i32 idx, hit;
        memcpy(&idx, index + 8 * h, sizeof idx);
        hit = idx > (nf_half_i32){0} + (int32_t)j;
        nf_half_blend(acc, h, &hit, x);
    }
#elif defined(NF_LANES_VECTOR)
    nf_lanes_i32 idx, hit;
    memcpy(&idx, index, sizeof idx);
    /* indices are small (bins), so the signed comparison is the unsigned one */
    hit = idx > (nf_lanes_i32){0} + (int32_t)j;
    nf_lanes_blend(acc, &hit, x);
#else
    for (int i = 0; i < 16; ++i)
        acc->v[i] = index[i] > j ? x->v[i] : acc->v[i];
#endif
}

/* g[i] = a[i] > 0 ? g[i] : 0 for 16 lanes: a gradient through a ReLU whose outputs were a */
static inline void nf_lanes_relu_backward(nf_lanes *g, const nf_lanes *a)
{
#if defined(NF_LANES_HALVES)
    for (int h = 0; h < 2; ++h) {
        nf_half act;
        nf_half_i32 bits;
        memcpy(&act, (const char *)a + h * sizeof act, sizeof act);
        memcpy(&bits, (const char *)g + h * sizeof bits, sizeof bits);
        bits &= act > (nf_half){0.0f};
        memcpy((char *)g + h * sizeof bits, &bits, sizeof bits);
    }
#elif defined(NF_LANES_VECTOR)
    nf_lanes_i32 keep = *a > (nf_lanes){0.0f}, bits;
    memcpy(&bits, g, sizeof bits);
    bits &= keep;
    memcpy(g, &bits, sizeof bits);
#else
    for (int i = 0; i < 16; ++i)
        g->v[i] = a->v[i] > 0.0f ? g->v[i] : 0.0f;
#endif
}

#endif /* NISFLOW_KERNELS_LANES_H */
