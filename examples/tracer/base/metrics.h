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

/* Both images must have the same size. */
double image_mape(const image *reference, const image *img);
double image_relmse(const image *reference, const image *img);

#endif /* TRACER_METRICS_H */
