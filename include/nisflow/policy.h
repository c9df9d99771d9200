/*
 * nisflow/policy.h - the path policy: what a renderer does at each vertex of a guided path,
 * and what the path measures for the schedule (nisflow/schedule.h).
 *
 * At a guided vertex the renderer mixes the flow with its BSDF: the mixture probability and
 * its boost cap, the Russian roulette rule and which vertices weigh light samples by the flow
 * are the defaults that docs/equal-time.md found best (docs/integration.md, "A guided
 * vertex"). Along the path it keeps estimates of the second moments that plain path tracing
 * and shallower guiding would have had (nf_plain_moment, nf_depth_moment), which let every
 * pass measure the kinds of pass it did not render.
 *
 * nf_path_state holds both for one camera path (the boost and the moments together).
 *
 * Every function here is total and thread-safe: it reads its arguments and writes only what
 * its pointers name. Stack: a few dozen bytes.
 */
#ifndef NISFLOW_POLICY_H
#define NISFLOW_POLICY_H

#include <stddef.h>
#include <stdint.h>

#include "version.h"

NF_EXTERN_C_BEGIN

/* ---- The path policy --------------------------------------------------------------------- */

/* How a renderer mixes the flow with its BSDF at a guided vertex (docs/integration.md, "The
 * recipe"). The defaults are what docs/equal-time.md found best; one place holds them.
 *
 * Volume vertices. At a scattering event in a participating medium (a context with a zero
 * normal, nisflow/model.h) the phase function plays the BSDF's role everywhere in this
 * header: "p_bsdf" is the phase function's density of the direction (per steradian), "BSDF
 * sampling" is phase-function sampling, and f_s |cos| becomes the phase function's value (no
 * cosine in a medium). The same guide, store and model take surface and volume vertices.
 * min_roughness is a surface notion (docs/integration.md, "Volume vertices"). */
typedef struct nf_guide_policy {
    float mixture_prob;       /* probability of sampling the flow at a guided vertex, [0, 1);
                               * default 0.7                                                  */
    float max_boost;          /* cap on the path's boost (nf_guide_mixture_prob), >= 1 or 0 for
                               * none; default 10                                             */
    float max_survival;       /* Russian roulette survives at most with this, (0, 1]; 0.95    */
    uint32_t light_mis_depth; /* vertices up to this many segments deep weigh a light
                               * sample against the mixture's density (which asks the flow);
                               * deeper ones against the BSDF's; 0: every depth asks; default 2 */
    float min_roughness;      /* a renderer's hint: lobes sharper than this roughness (alpha)
                               * are better sampled by the BSDF alone; default 0.3            */
} nf_guide_policy;

/* The defaults above. NULL is ignored. Thread-safe. */
NF_API void nf_guide_policy_init(nf_guide_policy *p);

/* The probability of sampling the flow at the next guided vertex of a path whose boost is
 * `boost`. The boost is the product, over the path's guided vertices so far, of p_bsdf / p_mix
 * (nf_guide_boost): how much the mixture has raised the throughput over BSDF sampling's. A
 * BSDF sample where the flow has no mass weighs 1 / (1 - g) more than under BSDF sampling, and
 * along a path these factors multiply; the cap keeps their product within max_boost by
 * lowering g to 1 - boost / max_boost, and to 0 below 0.05 (a vertex guided that little pays
 * the flow for nothing). It depends only on the path so far: the estimator stays unbiased.
 * A NULL policy gives 0. Thread-safe, total. */
NF_API float nf_guide_mixture_prob(const nf_guide_policy *p, float boost);

/* The boost after a guided vertex: boost x p_bsdf / p_mix for a sampled direction whose BSDF
 * and mixture densities (per steradian) are given; a delta lobe (p_bsdf = p_mix = 0) that the
 * mixture chose with probability 1 - g passes g_used and multiplies 1 / (1 - g_used).
 * Non-finite or non-positive densities leave the boost unchanged. Thread-safe, total. */
NF_API float nf_guide_boost(float boost, float p_bsdf, float p_mix, float g_used);

/* The probability that Russian roulette lets a path go on: the larger of its throughput's
 * largest channel and that channel divided by the path's boost, at most max_survival. The
 * quotient is the throughput BSDF sampling would have given the same path, so a path the flow
 * sent where it expects light survives as often as plain path tracing would let it; the
 * larger of the two keeps the throughput after roulette at or below about 1 when the flow sent
 * it where it expects little. boost = 1 gives plain path tracing's rule. NaN gives 0. A NULL
 * policy, or one whose max_survival is outside (0, 1] (a zeroed one), caps at 0.95.
 * Thread-safe, total. */
NF_API float nf_guide_roulette_survival(const nf_guide_policy *p, float throughput_max,
                                        float boost);

/* Whether a light sample at a vertex `depth` segments into the path is weighed against the
 * mixture's density (1: ask the flow its density) or the BSDF's (0). Both the light sample and
 * the scattered direction that hits the light must use the same answer, so that the MIS
 * weights still sum to one. Thread-safe, total. */
NF_API int nf_guide_light_mis_uses_flow(const nf_guide_policy *p, uint32_t depth);

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
NF_API void nf_plain_moment_start(nf_plain_moment *m);

/* A scattered direction with BSDF and mixture densities p_bsdf and p_mix (per steradian),
 * or a delta lobe chosen with probability 1 - g_used (p_bsdf = p_mix = 0): R takes the step
 * as nf_guide_boost's boost does. */
NF_API void nf_plain_moment_scatter(nf_plain_moment *m, float p_bsdf, float p_mix, float g_used);

/* Russian roulette survived with probability q_used at a path whose throughput's largest
 * channel (before the roulette) is throughput_max: R takes plain roulette's survival, which is
 * nf_guide_roulette_survival(p, throughput_max / R, 1), over q_used. */
NF_API void nf_plain_moment_roulette(nf_plain_moment *m, const nf_guide_policy *p,
                                     float throughput_max, float q_used);

/* A contribution c >= 0 (a luminance, as added to the pixel) of the path; negative or
 * non-finite c is ignored. */
NF_API void nf_plain_moment_add(nf_plain_moment *m, float c);

/* ---- How deep guided passes guide --------------------------------------------------------- */

/* Guiding a vertex costs the flow's questions, and deep vertices, which carry little of a
 * pixel, may not repay them: in a box lit directly, guiding each path's first vertex alone buys
 * more per second than guiding every vertex or none, while light that arrives through several
 * bounces (a room lit through a door's gap) needs guiding at every depth. Guided render passes
 * therefore come in NF_GUIDE_DEPTHS kinds, by the deepest vertex they guide: kind 0 guides
 * every depth, kinds 1 and 2 up to that many segments from the camera (the first vertex is 1);
 * every depth measured on its own passes, a shallower kind on every pass
 * that guides deeper than it (nf_depth_moment, as plain path tracing is measured);
 * nf_guide_choose_depth picks the kind to render, and nf_guide_choose_pass then weighs it
 * against plain passes (docs/integration.md, "The schedule"; docs/schedule-theory.md). Training
 * passes guide every depth. A vertex deeper than a pass's depth is not guided: the mixture
 * probability 0, no question to the flow, light samples weighed against the BSDF's density. */
#define NF_GUIDE_DEPTHS 3u

/* A kind that guides up to depth D, measured on paths guided deeper (as nf_plain_moment
 * measures plain path tracing): its passes alone would miss the rare bright paths that rule
 * its variance (light that only guiding finds, deeper than D), and the choice would pick it by
 * chance. A path guided up to depth A >= D (every depth, training passes included) traces the
 * same vertices as the depth-D policy up to D; beyond, R takes the step from the path's
 * mixture to BSDF sampling, and roulette the depth-D policy's survival (its boost frozen at
 * depth D). A path keeps one nf_depth_moment per policy it measures, in an array that each
 * call below updates at once: start each with its policy's depth D, then call scatter and
 * roulette at every vertex with the vertex's depth (the first vertex is 1) where the path
 * calls nf_guide_boost and nf_guide_roulette_survival, and add every contribution. A path
 * guided up to exactly D gives its squared luminance. D = 0 is nf_plain_moment's plain path
 * tracing, to the bit. Thread-safe, total (the functions only write m[0..n); moments stay
 * >= 0, +inf at worst); NULL m or n = 0 is a no-op. */
typedef struct nf_depth_moment {
    float ratio;    /* R: the depth-D policy's density of the path so far over the path's */
    float sum;      /* the contributions so far, each divided by its R                    */
    float moment;   /* the estimate of the depth-D policy's second moment                 */
    float boost;    /* the depth-D policy's boost: the path's, frozen after depth D       */
    uint32_t depth; /* D                                                                  */
} nf_depth_moment;

/* A path at the camera, measuring the policy that guides up to depth `depth`. */
NF_API void nf_depth_moment_start(nf_depth_moment *m, uint32_t depth);

/* A scattered direction at a vertex `vertex_depth` deep, with the arguments of
 * nf_plain_moment_scatter: for each of the n moments, up to its D the boost takes the step,
 * deeper R does. */
NF_API void nf_depth_moment_scatter(nf_depth_moment *m, size_t n, uint32_t vertex_depth,
                                    float p_bsdf, float p_mix, float g_used);

/* Russian roulette survived with probability q_used at a vertex `vertex_depth` deep, whose
 * throughput's largest channel before the roulette is throughput_max: for each moment deeper
 * than its D, R takes nf_guide_roulette_survival(p, throughput_max / R, boost) over q_used. */
NF_API void nf_depth_moment_roulette(nf_depth_moment *m, size_t n, const nf_guide_policy *p,
                                     uint32_t vertex_depth, float throughput_max, float q_used);

/* A contribution (a luminance, as added to the pixel) that the technique of the vertex
 * `vertex_depth` deep found (0: seen from the camera): c >= 0 with the MIS weight the path gave
 * it, c_plain >= 0 with plain path tracing's (light sampling against the BSDF's density). Each
 * moment takes c where its policy guides that vertex (vertex_depth <= D), c_plain deeper, as
 * nf_plain_moment_add takes its contribution; negative or non-finite values are ignored. */
NF_API void nf_depth_moment_add(nf_depth_moment *m, size_t n, uint32_t vertex_depth, float c,
                                float c_plain);

/* ---- One path's state -------------------------------------------------------------------- */

/* What a camera path carries for guiding: its boost (nf_guide_boost) and the second moments
 * it measures for the schedule (nf_depth_moment): moments[0] plain path tracing's, moments[k]
 * for k >= 1 the kind that guides up to depth k (the moments a pass's paths hand to
 * nf_schedule_add_pass, kind by kind). One struct and five calls replace the boost and the
 * moments' array, with the same bits as the calls they make:
 *
 *     nf_path_state ps;  nf_path_start(&ps);                       at the camera
 *     g = nf_path_mixture_prob(&ps, pol, depth, pass_depth);       at each vertex
 *     q = nf_path_survival(&ps, pol, throughput_max);              roulette's probability
 *     nf_path_survived(&ps, pol, depth, throughput_max, q);        if it went on (depth >= RR)
 *     nf_path_scatter(&ps, depth, p_bsdf, p_mix, g);               the scattered direction
 *     nf_path_add(&ps, depth, c, c_plain);                         every contribution
 *     ps.moments[k].moment                                         for the schedule
 *
 * depth counts segments from the camera (the first vertex is 1; a contribution seen from the
 * camera is depth 0). Every call is total and thread-safe on its own state; NULL is a no-op
 * (the functions that return a value return 0). Stack: a few dozen bytes. */
typedef struct nf_path_state {
    float boost;                              /* the mixture's boost so far, from 1       */
    nf_depth_moment moments[NF_GUIDE_DEPTHS]; /* 0: plain path tracing's; k: up to depth k */
} nf_path_state;

/* A path at the camera: boost 1, moments[k] started for depth k (0: plain path tracing). */
NF_API void nf_path_start(nf_path_state *ps);

/* The mixture probability at the vertex `depth` deep in a pass that guides up to pass_depth
 * (0: every depth; a training pass guides every depth): nf_guide_mixture_prob of the path's
 * boost, 0 deeper than pass_depth. */
NF_API float nf_path_mixture_prob(const nf_path_state *ps, const nf_guide_policy *p, uint32_t depth,
                                  uint32_t pass_depth);

/* Russian roulette's survival probability for the path: nf_guide_roulette_survival of its
 * throughput's largest channel and its boost. */
NF_API float nf_path_survival(const nf_path_state *ps, const nf_guide_policy *p,
                              float throughput_max);

/* The path survived roulette with probability q_used at the vertex `depth` deep:
 * nf_depth_moment_roulette on its moments. */
NF_API void nf_path_survived(nf_path_state *ps, const nf_guide_policy *p, uint32_t depth,
                             float throughput_max, float q_used);

/* A direction scattered at the vertex `depth` deep with BSDF and mixture densities p_bsdf,
 * p_mix (per steradian) and mixture probability g_used (a delta lobe: both densities 0):
 * nf_depth_moment_scatter on the moments, then nf_guide_boost on the boost. */
NF_API void nf_path_scatter(nf_path_state *ps, uint32_t depth, float p_bsdf, float p_mix,
                            float g_used);

/* A contribution that the technique of the vertex `depth` deep found (0: seen from the
 * camera), with the path's MIS weight (c) and plain path tracing's (c_plain):
 * nf_depth_moment_add. */
NF_API void nf_path_add(nf_path_state *ps, uint32_t depth, float c, float c_plain);

/* ---- Names kept until 0.10 (CHANGELOG.md, 0.8.1) ------------------------------------------ */

/* The depth of kind `candidate`: the candidate itself, 0 for candidate >= NF_GUIDE_DEPTHS. */
NF_API NF_DEPRECATED("the candidate itself (kind c guides up to depth c)") uint32_t
    nf_guide_depth_of(uint32_t candidate);

NF_EXTERN_C_END

#endif /* NISFLOW_POLICY_H */
