/*
 * schedule_atoms.h - what the schedule (nisflow/schedule.h) decides with: the variance of a
 * kind of pass from per-pixel sums, the reference without lone peaks, the training passes'
 * ratio to a plain pass, and the choices of the next pass's kind and depth
 * (docs/schedule-theory.md). Internal (not installed): the schedule object calls them; the
 * tests and fuzz_guide check them one by one.
 */
#ifndef NISFLOW_SRC_SCHEDULE_ATOMS_H
#define NISFLOW_SRC_SCHEDULE_ATOMS_H

#include <stddef.h>
#include <stdint.h>

#include "nisflow/guide.h"
#include "nisflow/policy.h"
#include "nisflow/schedule.h"

/* The variance of one pass of a kind, relative, from per-pixel sums. For each of n pixels (or
 * any unit of the image): S = sum[i] and Q = sum_sq[i], the sums of its value (a luminance,
 * say) and of its square over the kind's k = `passes` passes, and r = reference[i], the best
 * estimate of the pixel's value (every pass of both kinds and of training, averaged). *out is
 * the mean over i of
 *     (Q - 2 r S + k r^2) / k / (r^2 + epsilon),
 * the passes' mean squared distance to the reference, relative as relMSE is. The distance is
 * to the reference, not to the kind's own mean: a kind whose rare paths carry the light shows
 * zeros where the other kind has seen light, and its own mean would call those pixels
 * noiseless. *out is 0 for n = 0. Errors: NF_ERROR_INVALID_ARGUMENT (NULL arrays with n > 0,
 * NULL out, passes 0, epsilon not finite and > 0, a value not finite, sum_sq[i] < 0: the
 * message names the first), NF_ERROR_NUMERIC (finite values whose squares overflow); *out is
 * then unchanged. Thread-safe, allocates nothing. */
nf_status nf_guide_pass_variance(size_t n, const double *sum, const double *sum_sq, uint32_t passes,
                                 const double *reference, double epsilon, double *out);

/* The reference without lone peaks, against which the guided kinds of nf_guide_choose_depth
 * are measured. A rare bright path lands in one pixel and sits in that pixel's mean over the
 * passes too, so against that mean its pixel's relative variance stays near the pass count
 * however bright the path was: the depths would be ranked as if the path were not there
 * (docs/theory.md, "Rare bright paths in the depth choice"). Here each pixel brighter than
 * every one of its neighbours (8; fewer at the border) takes the brightest neighbour's value:
 *     out[i] = min(reference[i], the largest of pixel i's neighbours),
 * for a width x height image of one value per pixel (a luminance, say), row by row; an image
 * of one pixel is copied. Compare guided against plain passes with the reference itself:
 * plain passes draw the same rare paths. Errors: NF_ERROR_INVALID_ARGUMENT (NULL arrays with
 * width x height > 0, width x height overflowing size_t, reference and out overlapping, a value
 * not finite: the message names the first); out is then unchanged. Thread-safe, allocates
 * nothing, O(width x height). */
nf_status nf_guide_lower_peaks(size_t width, size_t height, const double *reference, double *out);

/* Tells the schedule what a training pass measured: `ratio` is its variance x cost over a
 * plain pass's (as nf_pass_choice.ratio, with the training pass's own variance about the
 * reference and its tracing time, steps not counted; plain passes measured as for
 * nf_guide_choose_pass, two rendered before training). Once the ratio has not fallen by 5 %
 * for 3 training passes while it stays above 0.8, nf_guide_keep_training says stop: a model
 * that buys little over plain path tracing and has stopped improving does not repay its
 * steps. Not calling it leaves the schedule as it was; pass_choice 0 ignores it.
 * Errors: NF_ERROR_INVALID_ARGUMENT (NULL g, ratio NaN or negative; +inf is allowed).
 * Not thread-safe with the training calls. */
nf_status nf_guide_report_training_ratio(nf_guide *g, double ratio);

/* What the renderer measured on the render passes of one kind so far (after training). */
typedef struct nf_pass_measure {
    uint32_t passes; /* passes of this kind                                              */
    double seconds;  /* their cost, >= 0, in one unit for both kinds (CPU seconds, say)   */
    double variance; /* the variance of one pass of this kind, >= 0: relative to the
                      * image, as nf_guide_pass_variance estimates it                     */
} nf_pass_measure;

/* nf_guide_choose_pass's answer. */
typedef struct nf_pass_choice {
    nf_pass_kind kind; /* render this kind next                                          */
    int exploring;     /* 1: a pass of the kind that measured worse, kept by its share     */
    double ratio;      /* a guided pass's variance x cost over a plain pass's (below 1:
                        * guiding pays); NaN until each kind has 2 passes                 */
} nf_pass_choice;

/* Which kind of render pass to render next, from measured[NF_PASS_GUIDED] and
 * measured[NF_PASS_PLAIN]: first two passes of each kind, guided first, alternating; then the
 * kind with the lower variance x cost per pass (ties: guided), except that the other kind
 * keeps a share of all render passes, so that its measure stays current: guided passes
 * explore_share when plain ones measure better (a model that measured worse early can still
 * show better), plain passes a fifth of it when guided ones do (every pass measures plain path
 * tracing's variance, nf_plain_moment, which measured[NF_PASS_PLAIN] must hold; only its cost
 * needs plain passes). With pass_choice 0, always guided.
 * The answer depends only on the arguments and the configuration: processes that pass the same
 * measures choose alike. Errors: NF_ERROR_INVALID_ARGUMENT (NULL, a measure negative or not
 * finite). Thread-safe. */
nf_status nf_guide_choose_pass(const nf_guide *g, const nf_pass_measure measured[2],
                               nf_pass_choice *out);

/* nf_guide_choose_depth's answer. */
typedef struct nf_depth_choice {
    uint32_t candidate; /* render guided passes of this kind next, < NF_GUIDE_DEPTHS         */
    uint32_t depth;     /* the candidate: how deep its passes guide (0: every depth)       */
    double ratio;       /* its variance x cost per pass over every depth's (below 1: the
                         * shallower passes pay); NaN while a kind has fewer than 2 passes  */
} nf_depth_choice;

/* Which kind of guided pass to render next, from the measures of the guided render passes of
 * each kind (measured[c] for candidate c, as nf_pass_measure of NF_PASS_GUIDED, each variance
 * against the reference without lone peaks, nf_guide_lower_peaks): first two passes of each
 * kind, in candidate order; then the kind with the lowest variance x cost per pass (ties: the
 * lower candidate, so every depth first). The chosen kind, its variance measured against the
 * reference itself, is the NF_PASS_GUIDED measure to give nf_guide_choose_pass. With
 * pass_choice 0, always candidate 0 (every depth). Depends only on the arguments and the
 * configuration, as nf_guide_choose_pass.
 * Errors: NF_ERROR_INVALID_ARGUMENT (NULL, a measure negative or not finite); *out is then
 * unchanged. Thread-safe. */
nf_status nf_guide_choose_depth(const nf_guide *g, const nf_pass_measure measured[NF_GUIDE_DEPTHS],
                                nf_depth_choice *out);

#endif /* NISFLOW_SRC_SCHEDULE_ATOMS_H */
