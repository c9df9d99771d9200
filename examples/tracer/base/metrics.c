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
