/*
 * peaks.c - lone peaks lowered to their brightest neighbour (peaks.h).
 */
#include "peaks.h"

#include <math.h>

void image_lower_peaks(const double *in, size_t width, size_t height, double *out)
{
    for (size_t y = 0; y < height; ++y)
        for (size_t x = 0; x < width; ++x) {
            double peak = -INFINITY;
            for (size_t yy = y ? y - 1 : 0; yy <= y + 1 && yy < height; ++yy)
                for (size_t xx = x ? x - 1 : 0; xx <= x + 1 && xx < width; ++xx)
                    if (yy != y || xx != x)
                        peak = fmax(peak, in[yy * width + xx]);
            double v = in[y * width + x];
            out[y * width + x] = width * height > 1 ? fmin(v, peak) : v;
        }
}
