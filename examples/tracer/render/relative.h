/*
 * relative.h - relative training weights (`nf_tracer --relative-training`): each training
 * sample's weight divided by an estimate of its pixel's value, sqrt(I^2 + METRIC_EPSILON),
 * so that the flow spends its capacity where the relative error is, not only where the
 * image is bright.
 *
 * Why: the flow's loss weighs a sample by the radiance it carries, so a bright pixel's paths
 * decide what is learned around them. relMSE weighs pixel p's variance by
 * c_p = 1 / (I_p^2 + eps); the guide q that minimizes sum_p c_p * integral f_p^2 / q draws
 * in proportion to sqrt(sum_p c_p f_p^2), which is f_p sqrt(c_p) where one pixel's paths
 * dominate a location (docs/tracer.md, "The time budget"). I_p is estimated from the
 * training passes rendered so far, box-filtered over (2 RELATIVE_RADIUS + 1)^2 pixels,
 * because a pass has one path per pixel. The estimator stays unbiased: only the distribution
 * the flow learns moves, and the BSDF part of the mixture keeps the density positive.
 */
#ifndef TRACER_RELATIVE_H
#define TRACER_RELATIVE_H

#include "image.h"
#include "integrator.h"

/* Half the side of the box filter, in pixels. */
#define RELATIVE_RADIUS 3

typedef struct relative_weights {
    int width, height, passes;
    double *sum;         /* per pixel: luminance summed over the passes added             */
    float *scale;        /* per pixel: 1 / sqrt(I^2 + eps) of the filtered mean            */
    unsigned char *mine; /* per pixel: rendered by this rank (others are left out)       */
    double *row;         /* work: the horizontal pass of the filter, value and count      */
} relative_weights;

/* Allocates the estimate for t's film; pixels other ranks render (render_pixel_mine) do not
 * enter the filter. Every scale is 1 until a pass is added. Returns 0 when out of memory. */
int relative_init(relative_weights *rw, const tracer *t);
void relative_free(relative_weights *rw);

/* Adds a pass (one path per pixel, the film's size) to the estimate and recomputes the
 * scales. Non-finite pixels count as black. */
void relative_add_pass(relative_weights *rw, const image *pass);

/* Multiplies each record's weight by its pixel's scale. */
void relative_apply(const relative_weights *rw, record_buffer *records);

#endif /* TRACER_RELATIVE_H */
