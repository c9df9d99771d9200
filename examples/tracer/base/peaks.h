/*
 * peaks.h - a per-pixel reference without lone peaks, for measuring how much a kind of render
 * pass spreads about the image (render/budget.c).
 *
 * A rare bright path lands in one pixel and sits in that pixel's mean over the passes too, so
 * measured against that mean its pixel's relative variance stays near the number of passes,
 * however bright the path. relMSE against a converged reference sees it in full. A pixel
 * brighter than every one of its neighbours (up to 8; fewer at the border) is therefore taken
 * at the brightest neighbour's value; every other pixel keeps its own.
 */
#ifndef TRACER_PEAKS_H
#define TRACER_PEAKS_H

#include <stddef.h>

/* out[i] = min(in[i], the largest of pixel i's neighbours) for a width x height image of one
 * value per pixel, row by row, of finite values. in and out must not overlap. An image of one
 * pixel keeps it. */
void image_lower_peaks(const double *in, size_t width, size_t height, double *out);

#endif
