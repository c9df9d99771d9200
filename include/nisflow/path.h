/*
 * nisflow/path.h - training samples from a traced path: the renderer records what happened
 * at each vertex, the library walks the path backwards and returns the (context, direction,
 * weight) samples that nf_train_step takes.
 *
 * A training sample at vertex j is (ctx_j, w_j, f_j) with
 *
 *     f_j = mean over R, G, B of  f_s(wo_j, w_j) |cos| L_i(w_j) / p_mix(w_j)
 *
 * (docs/theory.md section 6), where L_i(w_j) is the radiance the rest of the path brought back
 * along w_j. It is known only when the path is finished, so the renderer records per vertex
 * the quantities below (all RGB radiance or throughput, in the renderer's own radiance unit)
 * and calls nf_path_training_samples once per path. With S the radiance scattered from vertex
 * j + 1 towards vertex j (its emission excluded), the walk is
 *
 *     S = 0
 *     for j = last .. 0:
 *         L_i(w_j) = emitted_mis_j * emitted_j + S
 *         if learn_j:  f_j = mean(f_over_p_j * L_i(w_j))    (a sample if 0 < f_j <= FLT_MAX)
 *         S = direct_j + beta_j * L_i(w_j)
 *
 * Written forwards, L_i(w_j) = H_j E_j + sum over k > j of (prod_{j<m<k} beta_m) (D_k +
 * beta_k H_k E_k), with D = direct, E = emitted, H = emitted_mis: the radiance along w_j as
 * the pixel estimate counts it, whatever the later vertices did (next-event estimation, MIS,
 * delta bounces, Russian roulette).
 *
 * Emission: record it unweighted (emitted) with the MIS weight the pixel estimate gives it
 * (emitted_mis); the walk weighs it, at vertex j's own sample as upstream. The flow then
 * learns what scattering has to find: emission that next-event estimation already samples
 * carries its share of light sampling's weight, not all of it (on veach-ajar, the rule that
 * left it unweighted at its own vertex measured 1.5x the relMSE at equal time:
 * docs/equal-time.md, the ablation's all-emission row). A renderer that wants the flow to
 * learn all the emission found sets emitted_mis = 1.
 *
 * Russian roulette: beta_j carries 1/q_j of the vertex's own roulette, f_over_p_j does not.
 * The roulette at vertex j is decided before w_j is drawn (with a probability q_j that
 * depends on the path so far, not on w_j), so:
 *   - the 1/q_k of every later vertex k > j stays in S: it is part of the unbiased estimate
 *     of L_i(w_j) (dropping it would bias L_i low by the survival probabilities);
 *   - the vertex's own 1/q_j stays out of f_j, as the throughput of the path before vertex j
 *     does. It is a constant of the context, the same for every direction the vertex could
 *     have drawn, so it scales the target f_s L_i |cos| at that context and not its shape;
 *     the loss's minimizer at each context is the same with or without it. Leaving it out
 *     spares the batch weights as large as 1/q (for q near 0 a single sample would dominate
 *     the batch), and each context counts as often as the renderer really visits it.
 *     docs/theory.md section 6, "Russian roulette", has the argument.
 * A renderer without Russian roulette sets beta = f_over_p.
 *
 * Dropped samples: a learned vertex gives no sample when its weight is 0 (the path found no
 * light along w_j, or f_over_p is black: such a sample contributes nothing to the loss) or
 * above FLT_MAX (the float it would be is Inf). The walk runs in double precision, and a
 * zero factor (a black channel, beta = 0 at the end of a path) counts as an exact zero even
 * where the radiance behind it overflowed, so no weight is ever NaN.
 *
 * Every sample the call returns is accepted by nf_train_step: its context and direction pass
 * the same checks, and its weight is finite and > 0.
 */
#ifndef NISFLOW_PATH_H
#define NISFLOW_PATH_H

#include <stddef.h>

#include "model.h"
#include "status.h"
#include "version.h"

NF_EXTERN_C_BEGIN

/* The most vertices one path may have: longer "paths" are refused as a caller's bug. */
#define NF_PATH_MAX_VERTICES 65536u

/* One vertex of a path: where the path scattered (or ended), as the renderer's estimator saw
 * it. The caller owns the storage (a stack array with a capacity is enough); zero it first
 * (memset or = {0}): a zeroed vertex contributes nothing and learns nothing.
 *
 * Radiance fields (read on every vertex; finite and >= 0, else the call is refused):
 *   (At a vertex in a participating medium, a context with a zero normal, read the phase
 *   function for f_s |cos| and its density for the BSDF's: docs/integration.md, "Volume
 *   vertices".)
 *   direct       RGB radiance: the MIS-weighted next-event estimate at this vertex, the
 *                light reflected towards wo, f_s |cos| L_e w_light / p_light summed over the
 *                vertex's light samples, *without* the path throughput before the vertex.
 *                0 where the renderer does no next-event estimation (delta vertices).
 *   beta         RGB: the factor the path throughput was multiplied by at this vertex,
 *                f_s |cos| / p of the sampled direction times 1/q of this vertex's Russian
 *                roulette (f / p of the lobe for a delta bounce). 0 where the path ended at
 *                this vertex (absorbed, roulette, maximum depth).
 *   emitted      RGB radiance found by the ray scattered from this vertex: the emission of
 *                the surface it hit (towards this vertex), or the environment's if it
 *                escaped; unweighted (no MIS weight, no throughput). 0 if none.
 *   emitted_mis  the MIS weight in [0, 1] the renderer gave `emitted` in its pixel estimate
 *                (1 after a delta bounce or without light sampling); the walk applies it.
 *
 * Sample fields (read only where learn != 0: a vertex that learns nothing, such as a
 * specular one, may leave them zero):
 *   learn        non-zero: this vertex gives a training sample (a non-delta direction the
 *                mixture of flow and BSDF drew). 0: it gives none (delta bounce, no guiding,
 *                the path ended here), yet its radiance fields above still carry the light
 *                it passes back to the vertices before it.
 *   ctx          the vertex's context, as passed to nf_vertex_set / nf_sample: finite,
 *                normal and wo of squared length > 1e-30, or a normal exactly (0, 0, 0) at
 *                a vertex in a medium, whose phase_g is then within +-NF_PHASE_G_MAX.
 *   dir          the sampled direction w_j, finite with squared length > 1e-30 (any length).
 *   f_over_p     RGB, finite and >= 0: f_s(wo, w_j) |cos| / p_mix(w_j), the density the
 *                direction was really drawn with, *without* the roulette's 1/q.
 */
typedef struct nf_path_vertex {
    nf_context ctx;
    float dir[3];
    float f_over_p[3];
    float beta[3];
    float direct[3];
    float emitted[3];
    float emitted_mis;
    int learn;
} nf_path_vertex;

/* Walks the path vertices[0 .. vertex_count - 1] (vertex 0 the camera's first hit) backwards
 * and writes its training samples, in vertex order, into the caller's arrays:
 * ctx_out[i], dir_out[3i .. 3i+2] (the vertex's dir as given), weight_out[i] (finite, > 0),
 * and, if vertex_out is not NULL, vertex_out[i] = the index of the vertex it came from (to
 * attach the renderer's own data, a material for a custom prior for example). *count_out
 * receives the number of samples, at most the number of learned vertices, so a capacity of
 * vertex_count always suffices.
 *
 * Statuses:
 *   NF_OK                      *count_out samples written (0 is fine: no learned vertex, or
 *                              no light found).
 *   NF_ERROR_CAPACITY          the path gives more than `capacity` samples: *count_out
 *                              receives how many, and nothing else is written; grow the
 *                              arrays and call again (the result does not change).
 *   NF_ERROR_INVALID_ARGUMENT  a NULL count_out, vertices (with vertex_count > 0) or output
 *                              array (with capacity > 0; with capacity 0 they may be NULL, to
 *                              ask for the count alone); vertex_count above
 *                              NF_PATH_MAX_VERTICES; a field outside its range above (NaN, Inf,
 *                              negative, emitted_mis above 1, a bad context or direction of a
 *                              learned vertex). Nothing is written, *count_out included, and
 *                              nf_last_error_message() names the vertex and the field, e.g.
 *                              "nf_path_training_samples: vertices[3].beta[1] = nan is not
 *                              finite".
 * vertex_count = 0 gives NF_OK and no samples. Outputs must not overlap the vertices.
 *
 * A pure function of its arguments: thread-safe, never allocates, needs no model. Stack: 176
 * bytes at most (GCC 12 -O2, -fstack-usage), plus the C library's vsnprintf when a refused
 * call formats its message. Its cost is a few dozen floating-point operations per vertex. */
NF_API nf_status nf_path_training_samples(size_t vertex_count, const nf_path_vertex *vertices,
                                          size_t capacity, nf_context *ctx_out, float *dir_out,
                                          float *weight_out, size_t *vertex_out, size_t *count_out);

NF_EXTERN_C_END

#endif /* NISFLOW_PATH_H */
