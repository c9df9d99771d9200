/*
 * pcg32.h - the small deterministic random-number generator of the example programs (PCG32,
 * O'Neill 2014), so that their output is the same on every machine. Header-only.
 */
#ifndef NF_EXAMPLES_PCG32_H
#define NF_EXAMPLES_PCG32_H

#include <stdint.h>

typedef struct pcg32 {
    uint64_t state;
    uint64_t inc;
} pcg32;

static inline uint32_t pcg32_next(pcg32 *rng)
{
    uint64_t old = rng->state;
    rng->state = old * 6364136223846793005ULL + rng->inc;
    uint32_t xorshifted = (uint32_t)(((old >> 18u) ^ old) >> 27u);
    uint32_t rot = (uint32_t)(old >> 59u);
    return (xorshifted >> rot) | (xorshifted << ((32u - rot) & 31u));
}

static inline pcg32 pcg32_seed(uint64_t seed, uint64_t stream)
{
    pcg32 rng = {0u, (stream << 1u) | 1u};
    pcg32_next(&rng);
    rng.state += seed;
    pcg32_next(&rng);
    return rng;
}

/* A uniform float in [0, 1). */
static inline float pcg32_float(pcg32 *rng)
{
    return (float)(pcg32_next(rng) >> 8) * (1.0f / 16777216.0f);
}

#endif /* NF_EXAMPLES_PCG32_H */
