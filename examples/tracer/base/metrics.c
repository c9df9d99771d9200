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
    /* The k largest errors so far, largest first: one pass, and ties take one slot each. */
    double top[METRIC_TAIL_MAX] = {0.0}, total = 0.0, taken = 0.0;
    int kept = k < 1 ? 1 : k > METRIC_TAIL_MAX ? METRIC_TAIL_MAX : k;
    for (size_t p = 0; p < pixels; ++p) {
        double e = pixel_relmse(reference, img, p);
        total += e;
        if (!(e > top[kept - 1]))
            continue;
        int i = kept - 1;
        for (; i > 0 && top[i - 1] < e; --i)
            top[i] = top[i - 1];
        top[i] = e;
    }
    if (!isfinite(total)) { /* as relMSE: a non-finite pixel must not go unnoticed */
        *worst_share = NAN;
        *body = total;
        return;
    }
    for (int i = 0; i < kept; ++i)
        taken += top[i];
    *worst_share = total > 0.0 ? top[0] / total : 0.0;
    *body = pixels ? fmax(total - taken, 0.0) / (double)(3 * pixels) : 0.0;
}
