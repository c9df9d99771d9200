/*
 * peaks.c - lone peaks lowered to their brightest neighbour (peaks.h).
 */
#include "peaks.h"

#include <math.h>

/* The values are luminances the tracer has kept finite: a plain comparison, which compiles to
 * one instruction where fmax's NaN rules do not. */
static double larger(double a, double b)
{
    return a > b ? a : b;
}

/* The largest of row[x - 1], row[x], row[x + 1] that lie in the row. */
static double row_max3(const double *row, size_t x, size_t width)
{
    double m = row[x];
    if (x > 0)
        m = larger(m, row[x - 1]);
    if (x + 1 < width)
        m = larger(m, row[x + 1]);
    return m;
}

void image_lower_peaks(const double *in, size_t width, size_t height, double *out)
{
    if (width * height == 1) {
        out[0] = in[0];
        return;
    }
    /* A pixel's neighbours: the three above, the three below, and its left and right. */
    for (size_t y = 0; y < height; ++y) {
        const double *row = in + y * width;
        const double *above = y > 0 ? row - width : NULL;
        const double *below = y + 1 < height ? row + width : NULL;
        for (size_t x = 0; x < width; ++x) {
            double peak = -INFINITY;
            if (above)
                peak = larger(peak, row_max3(above, x, width));
            if (below)
                peak = larger(peak, row_max3(below, x, width));
            if (x > 0)
                peak = larger(peak, row[x - 1]);
            if (x + 1 < width)
                peak = larger(peak, row[x + 1]);
            out[y * width + x] = row[x] < peak ? row[x] : peak;
        }
    }
}
