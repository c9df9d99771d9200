/*
 * medium.h - participating media: their coefficients, the Henyey-Greenstein phase function,
 * transmittance and free-flight sampling (docs/scene-format.md, "Participating media").
 *
 * Homogeneous media track over RGB: one channel drawn in proportion to the path's
 * throughput, the distance density the balance over the three channels' densities.
 * Heterogeneous media (a grey extinction from a voxel grid) track against a majorant: delta
 * tracking for free flight, ratio tracking for transmittance; both are unbiased.
 */
#ifndef TRACER_MEDIUM_H
#define TRACER_MEDIUM_H

#include "rng.h"
#include "vecmath.h"
#include "volume_grid.h"

/* A grid placed in the world: world points map to the grid's [0, 1]^3 by to_local. */
typedef struct placed_grid {
    volume_grid grid;
    float to_local[3][4]; /* affine, row-major: u = to_local * (p, 1)                       */
} placed_grid;

/* At most this many tentative collisions on one segment of a heterogeneous medium; a path
 * that needs more ends there (transmittance 0): 1e6 majorant free paths would transmit
 * exp(-1e6) through a medium as dense as its majorant. Only absurd scales reach it. */
#define MEDIUM_MAX_COLLISIONS 1000000

typedef struct medium {
    rgb sigma_t; /* homogeneous: extinction per unit length (the XML's scale applied), each
                  * >= 0 finite; heterogeneous: unused                                      */
    rgb albedo;  /* single-scattering albedo sigma_s / sigma_t, each in [0, 1]; where
                  * albedo_grid is set, unused                                              */
    float g;     /* Henyey-Greenstein asymmetry, in (-1, 1)                                */
    /* Heterogeneous media (both NULL for homogeneous ones); owned, medium_free frees them.
     * The extinction is scale x the density grid's first channel, zero outside its cube. */
    placed_grid *density;
    placed_grid *albedo_grid; /* NULL: the constant albedo                                 */
    float scale;
    float majorant;           /* scale x the density's maximum: per unit length            */
} medium;

void medium_free(medium *m);

/* The Henyey-Greenstein phase function (per steradian) for the cosine between the
 * propagation direction before and after scattering: (1 - g^2) / (4 pi (1 + g^2 - 2 g
 * cos)^(3/2)). It is its own sampling density. */
float phase_hg(float g, float cos_theta);

/* A direction drawn from phase_hg around the propagation direction d (unit); *pdf its
 * density (phase_hg of the result). */
vec3 phase_hg_sample(float g, vec3 d, float u0, float u1, float *pdf);

/* exp(-sigma_t t) per channel; t may be INFINITY (a zero coefficient then gives 1). */
rgb medium_transmittance(const medium *m, float t);

/* Free flight along a segment of length tmax (INFINITY: none ends it): a distance drawn from
 * the exponential density of one channel, chosen by u_channel with probability proportional
 * to the path's throughput beta in that channel (uniform when beta is zero). Returns 1 with
 * *t < tmax when the path scatters in the medium, its weight sigma_s Tr(t) / p(t) in *weight;
 * returns 0 when it passes the whole segment, weight Tr(tmax) / P(pass). p and P are the
 * channel-probability-weighted sums of the channels' densities (the balance heuristic over
 * channels, the "hero" scheme of spectral MIS), which keeps the product throughput x weight
 * bounded; in a grey medium the weights are exactly albedo (scatter) and 1 (pass). */
int medium_sample_distance(const medium *m, rgb beta, float tmax, float u_channel, float u,
                           float *t, rgb *weight);

/* Free flight from o along the unit direction d over a segment of length tmax (INFINITY:
 * unbounded), in either kind of medium, with the same results as medium_sample_distance. A
 * homogeneous medium draws exactly two numbers from r (the channel, then the distance), so
 * its images do not change with heterogeneous media's arrival; a heterogeneous one draws two
 * per tentative collision (delta tracking: scatter weight the albedo there, pass weight 1). */
int medium_sample_flight(const medium *m, rgb beta, vec3 o, vec3 d, float tmax, rng *r,
                         float *t, rgb *weight);

/* The transmittance of the segment from o along the unit direction d, of length len (may be
 * INFINITY): exp(-sigma_t len) in a homogeneous medium, drawing nothing from r; in a
 * heterogeneous one an unbiased estimate by ratio tracking, one number per tentative
 * collision. */
rgb medium_segment_transmittance(const medium *m, vec3 o, vec3 d, float len, rng *r);

#endif /* TRACER_MEDIUM_H */
