/*
 * nisflow/policy.h - the path policy: what a renderer does at each vertex of a guided path,
 * and what the path measures for the schedule (nisflow/schedule.h).
 *
 * At a guided vertex the renderer mixes the flow with its BSDF: the mixture probability and
 * its boost cap, the Russian roulette rule and which vertices weigh light samples by the flow
 * are the defaults that docs/equal-time.md found best (docs/integration.md, "A guided
 * vertex"). Along the path it keeps estimates of the second moments that plain path tracing
 * and shallower guiding would have had, which let every pass measure the kinds of pass it did
 * not render (docs/schedule-theory.md).
 *
 * nf_path_state holds both for one camera path (the boost and the moments together); six
 * calls keep it.
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
    float max_boost;          /* cap on the path's boost (nf_path_mixture_prob), >= 1 or 0 for
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

/* Whether a light sample at a vertex `depth` segments into the path is weighed against the
 * mixture's density (1: ask the flow its density) or the BSDF's (0). Both the light sample and
 * the scattered direction that hits the light must use the same answer, so that the MIS
 * weights still sum to one. Thread-safe, total. */
NF_API int nf_guide_light_mis_uses_flow(const nf_guide_policy *p, uint32_t depth);

/* ---- How deep guided passes guide --------------------------------------------------------- */

/* Guiding a vertex costs the flow's questions, and deep vertices, which carry little of a
 * pixel, may not repay them: in a box lit directly, guiding each path's first vertex alone buys
 * more per second than guiding every vertex or none, while light that arrives through several
 * bounces (a room lit through a door's gap) needs guiding at every depth. Guided render passes
 * therefore come in NF_GUIDE_DEPTHS kinds, by the deepest vertex they guide: kind 0 guides
 * every depth, kinds 1 and 2 up to that many segments from the camera (the first vertex is 1);
 * every depth measured on its own passes, a shallower kind on every pass
 * that guides deeper than it (nf_depth_moment, as plain path tracing is measured); the
 * schedule picks the kind to render and weighs it against plain passes (docs/integration.md,
 * "The schedule"; docs/schedule-theory.md). Training
 * passes guide every depth. A vertex deeper than a pass's depth is not guided: the mixture
 * probability 0, no question to the flow, light samples weighed against the BSDF's density. */
#define NF_GUIDE_DEPTHS 3u

/* The two zeros of depths, named. A pass's depth (nf_pass_plan.depth, nf_path_mixture_prob's
 * pass_depth) of NF_EVERY_DEPTH guides every vertex; the moment of index NF_MOMENT_PLAIN
 * (nf_path_state.moments[NF_MOMENT_PLAIN], the schedule's moments[NF_MOMENT_PLAIN x paths + j])
 * is plain path tracing's, which guides no vertex. Moments 1 and 2 are the kinds that guide
 * up to depths 1 and 2. */
#define NF_EVERY_DEPTH 0u
#define NF_MOMENT_PLAIN 0u

/* The second moment of the policy that guides up to depth D (D = 0: plain path tracing),
 * measured on a path guided at least as deep. A kind's own passes would miss the rare bright
 * paths that rule its variance (light that only guiding finds, deeper than D), and the choice
 * would pick it by chance; the guided paths find them often, and each says how much it would
 * weigh under the depth-D policy. With R the ratio of that policy's density of the path so
 * far to the path's own (BSDF over mixture densities beyond D, and the policy's roulette
 * survival over the path's), a contribution c_k (a luminance) is worth c_k / R_k to it, and
 *     sum over k of c_k^2 / R_k + 2 sum over j < k of c_j c_k / R_j
 * has its second moment as expectation (importance weighting; docs/schedule-theory.md). A
 * path guided up to exactly D gives its squared luminance. nf_path_state keeps one per kind;
 * the fields are read-only to the renderer (moment, >= 0, +inf at worst). */
typedef struct nf_depth_moment {
    float ratio;    /* R: the depth-D policy's density of the path so far over the path's */
    float sum;      /* the contributions so far, each divided by its R                    */
    float moment;   /* the estimate of the depth-D policy's second moment                 */
    float boost;    /* the depth-D policy's boost: the path's, frozen after depth D       */
    uint32_t depth; /* D                                                                  */
} nf_depth_moment;

/* ---- One path's state -------------------------------------------------------------------- */

/* What a camera path carries for guiding: its boost, the product over its guided vertices of
 * p_bsdf / p_mix (how much the mixture has raised the throughput over BSDF sampling's; a delta
 * lobe chosen with probability 1 - g multiplies 1 / (1 - g)), and the second moments it
 * measures for the schedule (nf_depth_moment): moments[0] plain path tracing's, moments[k]
 * for k >= 1 the kind that guides up to depth k (the moments a pass's paths hand to
 * nf_schedule_add_pass, kind by kind). The calls, in a path's order:
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
    nf_depth_moment moments[NF_GUIDE_DEPTHS]; /* NF_MOMENT_PLAIN: plain path tracing's;
                                               * k >= 1: the kind guiding up to depth k   */
} nf_path_state;

/* A path at the camera: boost 1, moments[k] started for depth k (0: plain path tracing). */
NF_API void nf_path_start(nf_path_state *ps);

/* The probability of sampling the flow at the vertex `depth` deep in a pass that guides up to
 * pass_depth (NF_EVERY_DEPTH: every depth; a training pass guides every depth): the policy's
 * mixture_prob, lowered to 1 - boost / max_boost so that the path's boost stays within its
 * cap, 0 below 0.05 (a vertex guided that little pays the flow for nothing) and 0 deeper than
 * pass_depth. It depends only on the path so far: the estimator stays unbiased. */
NF_API float nf_path_mixture_prob(const nf_path_state *ps, const nf_guide_policy *p, uint32_t depth,
                                  uint32_t pass_depth);

/* Russian roulette's survival probability for the path: the larger of its throughput's
 * largest channel and that channel divided by its boost, at most max_survival (0.95 for a
 * policy whose max_survival is outside (0, 1]); NaN gives 0. The quotient is the throughput
 * BSDF sampling would have given the same path, so a path the flow sent where it expects
 * light survives as often as plain path tracing would let it; the larger of the two keeps the
 * throughput after roulette at or below about 1 where the flow expected little. This rule
 * replaces the renderer's own roulette on guided paths; boost 1 gives plain path tracing's. */
NF_API float nf_path_survival(const nf_path_state *ps, const nf_guide_policy *p,
                              float throughput_max);

/* The path survived roulette with probability q_used at the vertex `depth` deep, its
 * throughput's largest channel before the roulette throughput_max: each moment deeper than
 * its D takes its policy's survival over q_used into R. */
NF_API void nf_path_survived(nf_path_state *ps, const nf_guide_policy *p, uint32_t depth,
                             float throughput_max, float q_used);

/* A direction scattered at the vertex `depth` deep with BSDF and mixture densities p_bsdf,
 * p_mix (per steradian) and mixture probability g_used (a delta lobe: both densities 0):
 * the moments whose D is below `depth` take p_bsdf / p_mix into R, the others and the path
 * take it into their boost. Non-finite or non-positive densities change nothing. */
NF_API void nf_path_scatter(nf_path_state *ps, uint32_t depth, float p_bsdf, float p_mix,
                            float g_used);

/* A contribution (a luminance, as added to the pixel: the mean of R, G and B) that the
 * technique of the vertex `depth` deep found (0: seen from the camera), c >= 0 with the MIS
 * weight the path gave it, c_plain >= 0 with plain path tracing's (light sampling against the
 * BSDF's density): each moment takes c where its policy guides that vertex (depth <= D),
 * c_plain deeper. Negative or non-finite values are ignored. */
NF_API void nf_path_add(nf_path_state *ps, uint32_t depth, float c, float c_plain);

NF_EXTERN_C_END

#endif /* NISFLOW_POLICY_H */
