/*
 * policy_atoms.h - the steps that nf_path_state's calls (nisflow/policy.h) are made of: the
 * mixture probability under the boost cap, the boost, Russian roulette's survival, and the
 * second-moment estimates of plain path tracing and of shallower guiding. Internal (not
 * installed): a renderer keeps one nf_path_state per path; the tests and fuzz_guide check
 * these one by one (docs/schedule-theory.md derives the moments).
 */
#ifndef NISFLOW_SRC_POLICY_ATOMS_H
#define NISFLOW_SRC_POLICY_ATOMS_H

#include <stddef.h>
#include <stdint.h>

#include "nisflow/policy.h"

/* The probability of sampling the flow at the next guided vertex of a path whose boost is
 * `boost`. The boost is the product, over the path's guided vertices so far, of p_bsdf / p_mix
 * (nf_guide_boost): how much the mixture has raised the throughput over BSDF sampling's. A
 * BSDF sample where the flow has no mass weighs 1 / (1 - g) more than under BSDF sampling, and
 * along a path these factors multiply; the cap keeps their product within max_boost by
 * lowering g to 1 - boost / max_boost, and to 0 below 0.05 (a vertex guided that little pays
 * the flow for nothing). It depends only on the path so far: the estimator stays unbiased.
 * A NULL policy gives 0. Thread-safe, total. */
float nf_guide_mixture_prob(const nf_guide_policy *p, float boost);

/* The boost after a guided vertex: boost x p_bsdf / p_mix for a sampled direction whose BSDF
 * and mixture densities (per steradian) are given; a delta lobe (p_bsdf = p_mix = 0) that the
 * mixture chose with probability 1 - g passes g_used and multiplies 1 / (1 - g_used).
 * Non-finite or non-positive densities leave the boost unchanged. Thread-safe, total. */
float nf_guide_boost(float boost, float p_bsdf, float p_mix, float g_used);

/* The probability that Russian roulette lets a path go on: the larger of its throughput's
 * largest channel and that channel divided by the path's boost, at most max_survival. The
 * quotient is the throughput BSDF sampling would have given the same path, so a path the flow
 * sent where it expects light survives as often as plain path tracing would let it; the
 * larger of the two keeps the throughput after roulette at or below about 1 when the flow sent
 * it where it expects little. boost = 1 gives plain path tracing's rule. NaN gives 0. A NULL
 * policy, or one whose max_survival is outside (0, 1] (a zeroed one), caps at 0.95.
 * Thread-safe, total. */
float nf_guide_roulette_survival(const nf_guide_policy *p, float throughput_max, float boost);

/* Plain path tracing's second moment, measured on guided paths. A plain pass's variance
 * is ruled by rare bright paths that its first passes miss (a light reached through a gap),
 * so its own passes underestimate it; the guided paths find those paths often, and each one
 * says how much it would weigh in plain path tracing. With R the ratio of plain path tracing's
 * density of the path so far to the guided one's (BSDF over mixture densities, and plain
 * roulette's survival over the guided one's), a contribution c_k (a luminance) that a guided
 * path adds at its k-th contribution is worth c_k / R_k to plain path tracing, and
 *     sum over k of c_k^2 / R_k + 2 sum over j < k of c_j c_k / R_j
 * has plain path tracing's second moment as its expectation over guided paths (importance
 * weighting; docs/schedule-theory.md). Start a path with
 * nf_plain_moment_start, follow its scatters and roulette, add its contributions; a plain
 * path (R = 1) gives the square of its luminance. Add each contribution with the MIS weight
 * plain path tracing would give it (light sampling against the BSDF's density), not the
 * guided path's. Thread-safe, total (the functions only write *m; moment stays >= 0, +inf at
 * worst); NULL m is a no-op. */
typedef struct nf_plain_moment {
    float ratio;  /* R: plain path tracing's density of the path so far over the guided one's */
    float sum;    /* the contributions so far, each divided by its R                          */
    float moment; /* the estimate of plain path tracing's second moment                        */
} nf_plain_moment;

/* A path at the camera: R = 1, nothing added. */
void nf_plain_moment_start(nf_plain_moment *m);

/* A scattered direction with BSDF and mixture densities p_bsdf and p_mix (per steradian),
 * or a delta lobe chosen with probability 1 - g_used (p_bsdf = p_mix = 0): R takes the step
 * as nf_guide_boost's boost does. */
void nf_plain_moment_scatter(nf_plain_moment *m, float p_bsdf, float p_mix, float g_used);

/* Russian roulette survived with probability q_used at a path whose throughput's largest
 * channel (before the roulette) is throughput_max: R takes plain roulette's survival, which is
 * nf_guide_roulette_survival(p, throughput_max / R, 1), over q_used. */
void nf_plain_moment_roulette(nf_plain_moment *m, const nf_guide_policy *p, float throughput_max,
                              float q_used);

/* A contribution c >= 0 (a luminance, as added to the pixel) of the path; negative or
 * non-finite c is ignored. */
void nf_plain_moment_add(nf_plain_moment *m, float c);

/* A path at the camera, measuring the policy that guides up to depth `depth`. */
void nf_depth_moment_start(nf_depth_moment *m, uint32_t depth);

/* A scattered direction at a vertex `vertex_depth` deep, with the arguments of
 * nf_plain_moment_scatter: for each of the n moments, up to its D the boost takes the step,
 * deeper R does. */
void nf_depth_moment_scatter(nf_depth_moment *m, size_t n, uint32_t vertex_depth, float p_bsdf,
                             float p_mix, float g_used);

/* Russian roulette survived with probability q_used at a vertex `vertex_depth` deep, whose
 * throughput's largest channel before the roulette is throughput_max: for each moment deeper
 * than its D, R takes nf_guide_roulette_survival(p, throughput_max / R, boost) over q_used. */
void nf_depth_moment_roulette(nf_depth_moment *m, size_t n, const nf_guide_policy *p,
                              uint32_t vertex_depth, float throughput_max, float q_used);

/* A contribution (a luminance, as added to the pixel) that the technique of the vertex
 * `vertex_depth` deep found (0: seen from the camera): c >= 0 with the MIS weight the path gave
 * it, c_plain >= 0 with plain path tracing's (light sampling against the BSDF's density). Each
 * moment takes c where its policy guides that vertex (vertex_depth <= D), c_plain deeper, as
 * nf_plain_moment_add takes its contribution; negative or non-finite values are ignored. */
void nf_depth_moment_add(nf_depth_moment *m, size_t n, uint32_t vertex_depth, float c,
                         float c_plain);

#endif /* NISFLOW_SRC_POLICY_ATOMS_H */
