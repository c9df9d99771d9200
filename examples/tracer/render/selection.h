/*
 * selection.h - a learned guiding probability: the weight alpha of the flow in the one-sample
 * mixture alpha p_flow + (1 - alpha) p_bsdf, per cell of a grid over the scene (position and
 * the normal's dominant axis), learned from the training samples with the flow's own loss.
 *
 * Why: guiding helps where the BSDF samples the integrand badly (diffuse surfaces lit through
 * a gap) and hurts where it samples it well (a glossy lobe, a surface lit directly, which
 * next-event estimation already handles), and every guided vertex costs the flow's work.
 * Where the learned alpha falls below `off_below` the vertex is not guided at all: no
 * shading point is prepared and the flow is never evaluated there.
 *
 * The loss is the mixture's cross-entropy with the integrand (docs/theory.md section 6), and
 * its gradient with respect to alpha, estimated from samples x_i drawn from the mixture with
 * weights w_i = f L |cos| / p_mix, is
 *     dL/dalpha = - sum_i w_i (p_flow(x_i) - p_bsdf(x_i)) / p_mix(x_i) / sum_i w_i.
 * alpha = sigmoid(theta) per cell; Adam on theta.
 */
#ifndef TRACER_SELECTION_H
#define TRACER_SELECTION_H

#include <stddef.h>

#include "vecmath.h"

#define SELECTION_RES 8 /* cells per axis: a few samples per cell and pass at 320 x 180 */

typedef struct selection_grid {
    vec3 lo, scale;      /* cell = (p - lo) * scale, per axis                            */
    float *theta, *m, *v; /* logits and Adam's moments, one per cell                      */
    size_t cells;
    int steps;
    float lr;            /* Adam's step on the logits                                    */
    float min_prob, max_prob; /* alpha's range while learning                             */
    float off_below;     /* rendering: alpha below this is 0 (the vertex is not guided)  */
    int frozen;          /* 1: rendering (off_below applies)                             */
    /* The cost test (selection_freeze): per cell, decayed sums of the second moments of the
     * scattering estimate f L |cos| / p under the mixture and under BSDF sampling alone. */
    double *moment_mix, *moment_bsdf, *count;
    float cost;          /* a guided vertex's extra cost, relative: guiding must cut the
                          * second moment by 1 + cost to stay on                          */
} selection_grid;

/* A grid over [lo, hi] starting at alpha = initial. Returns 0 when out of memory. */
int selection_init(selection_grid *g, vec3 lo, vec3 hi, float initial);
void selection_free(selection_grid *g);

/* The cell of a shading point (position, shading normal). */
size_t selection_cell(const selection_grid *g, vec3 p, vec3 n);

/* alpha at a cell: in [min_prob, max_prob], or 0 when frozen and below off_below. */
float selection_prob(const selection_grid *g, size_t cell);

/* What a training sample tells the grid. */
typedef struct selection_sample {
    size_t cell;
    float weight;        /* f L |cos| / p_mix (the flow's training weight)                */
    float p_flow, p_bsdf, alpha;
} selection_sample;

/* One Adam step on the cells the samples touch; each cell's gradient is normalized by its
 * own weight sum. `work` holds 2 * cells doubles. */
void selection_step(selection_grid *g, const selection_sample *s, size_t n, double *work);

/* Folds one pass's samples into the second moments of the cost test (older passes decay by
 * half: the flow they saw has changed). Both are estimated from the mixture's samples,
 * E_mix[w^2] and E_bsdf[(F / p_bsdf)^2] = E_mix[w^2 p_mix / p_bsdf]. */
void selection_observe(selection_grid *g, const selection_sample *s, size_t n);

/* Ends learning: a cell whose mixture does not cut the second moment by 1 + cost (with at
 * least 16 samples seen) is switched off; then alpha below off_below is 0 (frozen). The
 * second moment stands for the variance: their difference, the squared mean, is the same for
 * both techniques and small where the variance matters. */
void selection_freeze(selection_grid *g);

/* The share of visited cells where guiding is off (for the report). */
double selection_off_share(const selection_grid *g);

#endif /* TRACER_SELECTION_H */
