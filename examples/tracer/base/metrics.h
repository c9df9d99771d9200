/*
 * metrics.h - image error against a reference, over all pixels and the three channels:
 *
 *   MAPE   = mean |v - w| / (v + 1e-2)          (the paper's Equation 7; v is the reference)
 *   relMSE = mean (v - w)^2 / (v^2 + 1e-2)
 *
 * The epsilon keeps black reference pixels from dominating. A non-finite value in either
 * image makes the result non-finite, on purpose: it must not go unnoticed.
 */
#ifndef TRACER_METRICS_H
#define TRACER_METRICS_H

#include "image.h"

#define METRIC_EPSILON 1e-2
/* The worst pixels that image_relmse_tail's body leaves out, in the tracer's and nf_compare's
 * output. */
#define METRIC_TAIL_PIXELS 10
/* The most worst pixels image_relmse_tail leaves out. */
#define METRIC_TAIL_MAX 64

/* Both images must have the same size. */
double image_mape(const image *reference, const image *img);
double image_relmse(const image *reference, const image *img);

/* How much of relMSE its worst pixels hold. A single path of huge weight (a caustic that
 * next-event estimation cannot reach) can decide a render's relMSE: then two renders compare
 * by where their rarest paths landed, not by their noise. *worst_share receives the share of
 * relMSE in the worst pixel (its three channels), *body the relMSE over the image with the
 * `k` worst pixels' errors left out, k in [1, METRIC_TAIL_MAX] (clamped; the mean is still
 * over every pixel, so that body <= relMSE; k beyond the pixels with an error leaves them all
 * out). 0 and 0 for an exact image; NaN and a non-finite body when relMSE is not finite.
 * One pass over the images; allocates nothing. */
void image_relmse_tail(const image *reference, const image *img, int k, double *worst_share,
                       double *body);

#endif /* TRACER_METRICS_H */
