/*
 * rng.h - the tracer's random numbers: PCG32 (O'Neill 2014), seeded per pixel, per pass and
 * per training path from the user's --seed.
 *
 * Why per-pixel streams instead of one generator per thread: the image must not depend on
 * which thread rendered which tile, so every random number a pixel uses is a function of
 * (seed, purpose, pass, pixel) only. That makes renders bit-identical for any --threads.
 */
#ifndef TRACER_RNG_H
#define TRACER_RNG_H

#include <stdint.h>

typedef struct rng {
    uint64_t state;
    uint64_t inc;
} rng;

static inline uint32_t rng_next_u32(rng *r)
{
    uint64_t old = r->state;
    r->state = old * 6364136223846793005ULL + r->inc;
    uint32_t xorshifted = (uint32_t)(((old >> 18u) ^ old) >> 27u);
    uint32_t rot = (uint32_t)(old >> 59u);
    return (xorshifted >> rot) | (xorshifted << ((32u - rot) & 31u));
}

/* A uniform float in [0, 1): 24 random mantissa bits, so 1.0f is never returned. */
static inline float rng_next(rng *r)
{
    return (float)(rng_next_u32(r) >> 8) * (1.0f / 16777216.0f);
}

/* SplitMix64's finalizer: a bijective hash that decorrelates nearby integers. */
static inline uint64_t rng_mix64(uint64_t z)
{
    z += 0x9e3779b97f4a7c15ULL;
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    return z ^ (z >> 31);
}

/* Purposes keep the streams of different phases apart even for equal indices. */
enum rng_purpose {
    RNG_RENDER = 1,   /* a = pass, b = pixel or path index   */
    RNG_TRAIN = 2,    /* a = iteration, b = path index       */
    RNG_TEST = 3      /* unit tests                          */
};

/* A generator for (seed, purpose, a, b): the state comes from hashing all four, the stream
 * (PCG's increment) from the pixel or path index, so neighbouring pixels are independent. */
static inline rng rng_seed(uint64_t seed, uint32_t purpose, uint64_t a, uint64_t b)
{
    rng r;
    uint64_t h = rng_mix64(seed ^ rng_mix64(((uint64_t)purpose << 56) ^ rng_mix64(a) ^
                                            (b * 0x2545f4914f6cdd1dULL)));
    r.state = 0u;
    r.inc = (rng_mix64(h ^ b) << 1u) | 1u;
    rng_next_u32(&r);
    r.state += h;
    rng_next_u32(&r);
    return r;
}

#endif /* TRACER_RNG_H */
