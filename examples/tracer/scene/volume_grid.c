/*
 * volume_grid.c - .vol files and their trilinear lookup (see volume_grid.h).
 */
#include "volume_grid.h"

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define VOL_HEADER_BYTES 48

/* Little endian whatever the host's order. */
static uint32_t read_u32(const unsigned char *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

static float read_f32(const unsigned char *p)
{
    uint32_t u = read_u32(p);
    float f;
    memcpy(&f, &u, sizeof f);
    return f;
}

static int32_t read_i32(const unsigned char *p)
{
    uint32_t u = read_u32(p);
    int32_t i;
    memcpy(&i, &u, sizeof i);
    return i;
}

void volume_grid_free(volume_grid *g)
{
    free(g->data);
    memset(g, 0, sizeof *g);
}

int volume_grid_parse(const unsigned char *b, size_t size, const char *name, const char *what,
                      float lo, float hi, volume_grid *g, tr_error *err)
{
    memset(g, 0, sizeof *g);
    if (size < VOL_HEADER_BYTES)
        return tr_fail(err, "%s: not a volume grid: %zu bytes, shorter than the 48-byte header",
                       name, size);
    if (memcmp(b, "VOL", 3))
        return tr_fail(err, "%s: not a volume grid (it does not start with 'VOL')", name);
    if (b[3] != 3)
        return tr_fail(err, "%s: volume grid version %d is not supported (3)", name, b[3]);
    int32_t encoding = read_i32(b + 4), n[3] = {read_i32(b + 8), read_i32(b + 12),
                                                 read_i32(b + 16)};
    int32_t channels = read_i32(b + 20);
    if (encoding != 1)
        return tr_fail(err, "%s: volume grid encoding %ld is not supported (1, float32)", name,
                       (long)encoding);
    if (n[0] < 1 || n[1] < 1 || n[2] < 1)
        return tr_fail(err, "%s: the grid's size %ld x %ld x %ld is not positive", name,
                       (long)n[0], (long)n[1], (long)n[2]);
    if (channels != 1 && channels != 3)
        return tr_fail(err, "%s: a grid of %ld channels is not supported (1 or 3)", name,
                       (long)channels);
    /* In steps, each below 2^64: the whole product of four sizes can wrap (2^25 x 2^25 x 2^24
     * is 2^74, which wrapped to 0 and passed for an empty file's worth of values). */
    uint64_t count = (uint64_t)n[0] * (uint64_t)n[1]; /* < 2^62 */
    if (count <= VOLUME_GRID_MAX_VALUES)
        count *= (uint64_t)n[2]; /* < 2^59 */
    if (count <= VOLUME_GRID_MAX_VALUES)
        count *= (uint64_t)channels;
    if (count > VOLUME_GRID_MAX_VALUES)
        return tr_fail(err, "%s: the grid's %ld x %ld x %ld x %ld values are more than the %u "
                       "it may hold", name, (long)n[0], (long)n[1], (long)n[2],
                       (long)channels, VOLUME_GRID_MAX_VALUES);
    uint64_t want = VOL_HEADER_BYTES + 4 * count;
    if ((uint64_t)size != want)
        return tr_fail(err, "%s: a %ld x %ld x %ld grid of %ld channel(s) takes %llu bytes; the "
                       "file has %zu (%s)", name, (long)n[0], (long)n[1], (long)n[2],
                       (long)channels, (unsigned long long)want, size,
                       (uint64_t)size < want ? "truncated" : "trailing bytes");
    float *data = malloc((size_t)count * sizeof *data);
    if (!data)
        return tr_fail(err, "%s: out of memory for %llu values", name,
                       (unsigned long long)count);
    float max = -INFINITY;
    for (uint64_t i = 0; i < count; ++i) {
        float v = read_f32(b + VOL_HEADER_BYTES + 4 * i);
        if (!(v >= lo && v <= hi)) { /* NaN fails both */
            uint64_t cell = i / (uint64_t)channels;
            long x = (long)(cell % (uint64_t)n[0]), y = (long)(cell / (uint64_t)n[0] % (uint64_t)n[1]),
                 z = (long)(cell / ((uint64_t)n[0] * (uint64_t)n[1]));
            free(data);
            return tr_fail(err, "%s: the %s of cell (%ld, %ld, %ld), channel %d, is %g: it must "
                           "be finite and lie in [%g, %g]", name, what, x, y, z,
                           (int)(i % (uint64_t)channels), (double)v, (double)lo, (double)hi);
        }
        data[i] = v;
        max = fmaxf(max, v);
    }
    g->nx = n[0];
    g->ny = n[1];
    g->nz = n[2];
    g->channels = channels;
    g->data = data;
    g->max = max;
    return 1;
}

int volume_grid_read(const char *path, const char *what, float lo, float hi, volume_grid *g,
                     tr_error *err)
{
    memset(g, 0, sizeof *g);
    FILE *f = fopen(path, "rb");
    if (!f)
        return tr_fail(err, "%s: cannot open the volume grid", path);
    unsigned char *bytes = NULL;
    size_t size = 0, cap = 0;
    const size_t limit = VOL_HEADER_BYTES + 4 * (size_t)VOLUME_GRID_MAX_VALUES + 1;
    int ok = 1;
    for (;;) {
        if (size == cap) {
            size_t grown = cap ? 2 * cap : 1 << 16;
            if (grown > limit)
                grown = limit;
            if (grown == cap) { /* larger than any grid we take: parse says so */
                break;
            }
            unsigned char *p = realloc(bytes, grown);
            if (!p) {
                ok = tr_fail(err, "%s: out of memory reading the volume grid", path);
                break;
            }
            bytes = p;
            cap = grown;
        }
        size_t got = fread(bytes + size, 1, cap - size, f);
        size += got;
        if (got == 0) {
            if (ferror(f))
                ok = tr_fail(err, "%s: cannot read the volume grid", path);
            break;
        }
    }
    fclose(f);
    if (ok)
        ok = volume_grid_parse(bytes, size, path, what, lo, hi, g, err);
    free(bytes);
    return ok;
}

/* Texel coordinate of u along an axis of n cells: cell centres at (i + 1/2) / n. */
static void axis_weights(float u, int n, int nearest, int *i0, int *i1, float *w1)
{
    if (nearest) {
        float x = floorf(u * (float)n);
        int i = !(x >= 0.0f) ? 0 : x >= (float)n ? n - 1 : (int)x; /* NaN: the first cell */
        *i0 = *i1 = i;
        *w1 = 0.0f;
        return;
    }
    float x = u * (float)n - 0.5f;
    if (!(x > 0.0f)) { /* also NaN: the first cell */
        *i0 = *i1 = 0;
        *w1 = 0.0f;
        return;
    }
    if (x >= (float)(n - 1)) {
        *i0 = *i1 = n - 1;
        *w1 = 0.0f;
        return;
    }
    float f = floorf(x);
    *i0 = (int)f;
    *i1 = *i0 + 1;
    *w1 = x - f;
}

/* The trilinear (or nearest) value of channels [0, nc) at u into out. */
static void lookup(const volume_grid *g, vec3 u, int nc, float *out)
{
    int x0, x1, y0, y1, z0, z1;
    float wx, wy, wz;
    axis_weights(u.x, g->nx, g->nearest, &x0, &x1, &wx);
    axis_weights(u.y, g->ny, g->nearest, &y0, &y1, &wy);
    axis_weights(u.z, g->nz, g->nearest, &z0, &z1, &wz);
    const size_t c = (size_t)g->channels, nx = (size_t)g->nx, nxy = nx * (size_t)g->ny;
    const float *d = g->data;
    for (int k = 0; k < nc; ++k) {
#define AT(x, y, z) d[((size_t)(z) * nxy + (size_t)(y) * nx + (size_t)(x)) * c + (size_t)k]
        float c00 = AT(x0, y0, z0) + wx * (AT(x1, y0, z0) - AT(x0, y0, z0));
        float c10 = AT(x0, y1, z0) + wx * (AT(x1, y1, z0) - AT(x0, y1, z0));
        float c01 = AT(x0, y0, z1) + wx * (AT(x1, y0, z1) - AT(x0, y0, z1));
        float c11 = AT(x0, y1, z1) + wx * (AT(x1, y1, z1) - AT(x0, y1, z1));
#undef AT
        float c0 = c00 + wy * (c10 - c00), c1 = c01 + wy * (c11 - c01);
        out[k] = c0 + wz * (c1 - c0);
    }
}

float volume_grid_eval1(const volume_grid *g, vec3 u)
{
    float v;
    lookup(g, u, 1, &v);
    return v;
}

rgb volume_grid_eval_rgb(const volume_grid *g, vec3 u)
{
    float v[3];
    lookup(g, u, g->channels, v);
    return g->channels == 1 ? rgb_gray(v[0]) : rgb_make(v[0], v[1], v[2]);
}
