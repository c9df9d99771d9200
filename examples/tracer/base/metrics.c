/*
 * metrics.c - MAPE and relMSE, summed in double precision.
 */
#include "metrics.h"

#include <math.h>

double image_mape(const image *reference, const image *img)
{
    size_t n = (size_t)img->width * (size_t)img->height * 3u;
    double sum = 0.0;
    for (size_t i = 0; i < n; ++i) {
        double v = reference->data[i], w = img->data[i];
        sum += fabs(v - w) / (v + METRIC_EPSILON);
    }
    return n ? sum / (double)n : 0.0;
}

double image_relmse(const image *reference, const image *img)
{
    size_t n = (size_t)img->width * (size_t)img->height * 3u;
    double sum = 0.0;
    for (size_t i = 0; i < n; ++i) {
        double v = reference->data[i], w = img->data[i];
        sum += (v - w) * (v - w) / (v * v + METRIC_EPSILON);
    }
    return n ? sum / (double)n : 0.0;
}

/* One pixel's relMSE summed over its channels. */
static double pixel_relmse(const image *reference, const image *img, size_t p)
{
    double sum = 0.0;
    for (size_t c = 3 * p; c < 3 * p + 3; ++c) {
        double v = reference->data[c], w = img->data[c];
        sum += (v - w) * (v - w) / (v * v + METRIC_EPSILON);
    }
    return sum;
}

void image_relmse_tail(const image *reference, const image *img, int k, double *worst_share,
                       double *body)
{
    size_t pixels = (size_t)img->width * (size_t)img->height;
    double total = 0.0, taken = 0.0, worst = 0.0, below = INFINITY;
    for (size_t p = 0; p < pixels; ++p)
        total += pixel_relmse(reference, img, p);
    if (!isfinite(total)) { /* as relMSE: a non-finite pixel must not go unnoticed */
        *worst_share = NAN;
        *body = total;
        return;
    }
    /* The k largest errors, each found by a scan for the largest one below the last; pixels
     * with equal errors are counted together, never more than k. */
    for (int taken_n = 0; taken_n < k;) {
        double top = -1.0;
        for (size_t p = 0; p < pixels; ++p) {
            double e = pixel_relmse(reference, img, p);
            if (e < below && e > top)
                top = e;
        }
        if (!(top > 0.0))
            break;
        size_t ties = 0;
        for (size_t p = 0; p < pixels; ++p)
            ties += pixel_relmse(reference, img, p) == top;
        if (taken_n == 0)
            worst = top;
        size_t use = ties < (size_t)(k - taken_n) ? ties : (size_t)(k - taken_n);
        taken += top * (double)use;
        taken_n += (int)use;
        below = top;
    }
    *worst_share = total > 0.0 ? worst / total : 0.0;
    *body = pixels ? fmax(total - taken, 0.0) / (double)(3 * pixels) : 0.0;
}
