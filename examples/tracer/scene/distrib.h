/*
 * distrib.h - discrete distributions for picking lights (one entry per emissive triangle
 * plus the environment) and envmap pixels (a row, then a column in it).
 */
#ifndef TRACER_DISTRIB_H
#define TRACER_DISTRIB_H

#include <stddef.h>

typedef struct distrib1d {
    size_t n;
    double *cdf; /* n + 1 entries, cdf[0] = 0, cdf[n] = 1 */
    double total;
} distrib1d;

/* Builds the distribution proportional to weights (>= 0, finite). Returns 0 when out of
 * memory or when all weights are zero (nothing can be sampled). */
int distrib1d_init(distrib1d *d, const double *weights, size_t n);
void distrib1d_free(distrib1d *d);
/* Picks an index for u in [0,1) and rescales u to [0,1) within the chosen entry (so the
 * same number can drive a second choice). */
size_t distrib1d_sample(const distrib1d *d, float u, float *u_rescaled);
static inline double distrib1d_pmf(const distrib1d *d, size_t i)
{
    return d->cdf[i + 1] - d->cdf[i];
}

/* A piecewise-constant density over [0,1]^2 on a w x h grid: rows by their sums, then a
 * column within the row. */
typedef struct distrib2d {
    size_t w, h;
    distrib1d rows;
    distrib1d *cols; /* h distributions (a row with zero weight gets a uniform one) */
} distrib2d;

int distrib2d_init(distrib2d *d, const double *weights, size_t w, size_t h);
void distrib2d_free(distrib2d *d);
/* A point in [0,1)^2 and its density with respect to area on the unit square. */
void distrib2d_sample(const distrib2d *d, float u0, float u1, float *x, float *y, float *pdf);
float distrib2d_pdf(const distrib2d *d, float x, float y);

#endif /* TRACER_DISTRIB_H */
