/*
 * relative.c - relative training weights (see relative.h).
 */
#include "relative.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "metrics.h"
#include "render.h"

int relative_init(relative_weights *rw, const tracer *t)
{
    int w = t->s->width, h = t->s->height;
    size_t n = (size_t)w * (size_t)h;
    memset(rw, 0, sizeof *rw);
    rw->width = w;
    rw->height = h;
    rw->sum = calloc(n, sizeof *rw->sum);
    rw->scale = malloc(n * sizeof *rw->scale);
    rw->mine = malloc(n);
    rw->row = malloc(2 * n * sizeof *rw->row);
    if (!rw->sum || !rw->scale || !rw->mine || !rw->row) {
        relative_free(rw);
        return 0;
    }
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            rw->scale[(size_t)y * (size_t)w + (size_t)x] = 1.0f;
            rw->mine[(size_t)y * (size_t)w + (size_t)x] = (unsigned char)render_pixel_mine(t, x, y);
        }
    return 1;
}

void relative_free(relative_weights *rw)
{
    free(rw->sum);
    free(rw->scale);
    free(rw->mine);
    free(rw->row);
    memset(rw, 0, sizeof *rw);
}

void relative_add_pass(relative_weights *rw, const image *pass)
{
    const int w = rw->width, h = rw->height, r = RELATIVE_RADIUS;
    for (size_t i = 0; i < (size_t)w * (size_t)h; ++i) {
        const float *p = pass->data + 3 * i;
        double l = ((double)p[0] + p[1] + p[2]) / 3.0;
        rw->sum[i] += isfinite(l) ? l : 0.0;
    }
    rw->passes++;
    /* Box filter, horizontal then vertical, over this rank's pixels only: rw->row holds
     * each pixel's horizontal sum of values and of counted pixels. */
    double *rv = rw->row, *rc = rw->row + (size_t)w * (size_t)h;
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            double v = 0.0, c = 0.0;
            for (int k = x - r; k <= x + r; ++k) {
                size_t j = (size_t)y * (size_t)w + (size_t)k;
                if (k >= 0 && k < w && rw->mine[j]) {
                    v += rw->sum[j];
                    c += 1.0;
                }
            }
            rv[(size_t)y * (size_t)w + (size_t)x] = v;
            rc[(size_t)y * (size_t)w + (size_t)x] = c;
        }
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            double v = 0.0, c = 0.0;
            for (int k = y - r; k <= y + r; ++k)
                if (k >= 0 && k < h) {
                    v += rv[(size_t)k * (size_t)w + (size_t)x];
                    c += rc[(size_t)k * (size_t)w + (size_t)x];
                }
            double mean = c > 0.0 ? v / (c * rw->passes) : 0.0;
            rw->scale[(size_t)y * (size_t)w + (size_t)x] =
                (float)(1.0 / sqrt(mean * mean + METRIC_EPSILON));
        }
}

void relative_apply(const relative_weights *rw, record_buffer *records)
{
    const size_t n = (size_t)rw->width * (size_t)rw->height;
    for (size_t i = 0; i < records->count; ++i) {
        train_record *x = &records->data[i];
        if (x->pixel < n)
            x->weight *= rw->scale[x->pixel];
    }
}
