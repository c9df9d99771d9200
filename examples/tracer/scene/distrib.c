/*
 * distrib.c - cumulative tables (in double precision, so that millions of small entries
 * still sum exactly enough) and binary search.
 */
#include "distrib.h"

#include <math.h>
#include <stdlib.h>

int distrib1d_init(distrib1d *d, const double *weights, size_t n)
{
    d->n = n;
    d->total = 0.0;
    d->cdf = malloc((n + 1) * sizeof *d->cdf);
    if (!d->cdf)
        return 0;
    d->cdf[0] = 0.0;
    for (size_t i = 0; i < n; ++i) {
        d->total += weights[i];
        d->cdf[i + 1] = d->total;
    }
    if (!(d->total > 0.0) || !isfinite(d->total)) {
        free(d->cdf);
        d->cdf = NULL;
        return 0;
    }
    for (size_t i = 1; i <= n; ++i)
        d->cdf[i] /= d->total;
    d->cdf[n] = 1.0;
    return 1;
}

void distrib1d_free(distrib1d *d)
{
    free(d->cdf);
    d->cdf = NULL;
    d->n = 0;
}

size_t distrib1d_sample(const distrib1d *d, float u, float *u_rescaled)
{
    /* The first i with cdf[i + 1] > u; entries of zero probability are never returned. */
    size_t lo = 0, hi = d->n - 1;
    while (lo < hi) {
        size_t mid = lo + (hi - lo) / 2;
        if (d->cdf[mid + 1] > (double)u)
            hi = mid;
        else
            lo = mid + 1;
    }
    if (u_rescaled) {
        double p = d->cdf[lo + 1] - d->cdf[lo];
        double r = p > 0.0 ? ((double)u - d->cdf[lo]) / p : 0.0;
        *u_rescaled = (float)fmin(fmax(r, 0.0), 0.99999994);
    }
    return lo;
}

int distrib2d_init(distrib2d *d, const double *weights, size_t w, size_t h)
{
    d->w = w;
    d->h = h;
    d->cols = calloc(h, sizeof *d->cols);
    double *row_sums = malloc(h * sizeof *row_sums);
    double *uniform = malloc(w * sizeof *uniform);
    int ok = d->cols && row_sums && uniform;
    for (size_t x = 0; ok && x < w; ++x)
        uniform[x] = 1.0;
    for (size_t y = 0; ok && y < h; ++y) {
        const double *row = weights + y * w;
        row_sums[y] = 0.0;
        for (size_t x = 0; x < w; ++x)
            row_sums[y] += row[x];
        ok = distrib1d_init(&d->cols[y], row_sums[y] > 0.0 ? row : uniform, w);
    }
    ok = ok && distrib1d_init(&d->rows, row_sums, h);
    free(row_sums);
    free(uniform);
    if (!ok)
        distrib2d_free(d);
    return ok;
}

void distrib2d_free(distrib2d *d)
{
    if (d->cols)
        for (size_t y = 0; y < d->h; ++y)
            distrib1d_free(&d->cols[y]);
    free(d->cols);
    d->cols = NULL;
    distrib1d_free(&d->rows);
}

void distrib2d_sample(const distrib2d *d, float u0, float u1, float *x, float *y, float *pdf)
{
    float r0, r1;
    size_t row = distrib1d_sample(&d->rows, u1, &r1);
    size_t col = distrib1d_sample(&d->cols[row], u0, &r0);
    *x = ((float)col + r0) / (float)d->w;
    *y = ((float)row + r1) / (float)d->h;
    *pdf = (float)(distrib1d_pmf(&d->rows, row) * distrib1d_pmf(&d->cols[row], col) *
                   (double)d->w * (double)d->h);
}

float distrib2d_pdf(const distrib2d *d, float x, float y)
{
    size_t col = (size_t)fminf(fmaxf(x * (float)d->w, 0.0f), (float)d->w - 1.0f);
    size_t row = (size_t)fminf(fmaxf(y * (float)d->h, 0.0f), (float)d->h - 1.0f);
    return (float)(distrib1d_pmf(&d->rows, row) * distrib1d_pmf(&d->cols[row], col) *
                   (double)d->w * (double)d->h);
}
