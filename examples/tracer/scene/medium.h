/*
 * medium.h - homogeneous participating media: their coefficients, the Henyey-Greenstein
 * phase function, transmittance and free-flight distance sampling over RGB (one channel
 * drawn in proportion to the path's throughput, the distance density the balance over the
 * three channels' densities: docs/tracer.md, "Participating media").
 */
#ifndef TRACER_MEDIUM_H
#define TRACER_MEDIUM_H

#include "vecmath.h"

typedef struct medium {
    rgb sigma_t; /* extinction per unit length (the XML's scale applied), each >= 0 finite */
    rgb albedo;  /* single-scattering albedo sigma_s / sigma_t, each in [0, 1]              */
    float g;     /* Henyey-Greenstein asymmetry, in (-1, 1)                                */
} medium;

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

#endif /* TRACER_MEDIUM_H */
