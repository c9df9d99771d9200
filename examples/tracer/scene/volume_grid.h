/*
 * volume_grid.h - voxel grids as Mitsuba 3's `gridvolume` reads them from `.vol` files, and
 * their lookup: the values of a heterogeneous medium (docs/scene-format.md, "Participating media").
 *
 * The file (little endian): "VOL", version byte 3, encoding 1 (float32, int32), the cell
 * counts nx, ny, nz (int32 each), the channel count (int32), a bounding box of 6 floats
 * (ignored, as Mitsuba 3 ignores it unless use_grid_bbox is set), then nx ny nz channels
 * floats, x fastest: data[((z ny + y) nx + x) channels + c].
 *
 * The grid fills the unit cube of its own coordinates, which its `to_world` places in the
 * scene. A lookup at u in [0, 1]^3 is drjit's texture lookup: cell centres at (i + 1/2) / n,
 * trilinear between them (or the nearest cell), coordinates clamped to the edge cells.
 */
#ifndef TRACER_VOLUME_GRID_H
#define TRACER_VOLUME_GRID_H

#include <stddef.h>

#include "error.h"
#include "vecmath.h"

/* More cells x channels than this are refused (4 GiB of floats would not fit a 2-core,
 * 24 GiB machine's other needs; smoke scenes need a few million). */
#define VOLUME_GRID_MAX_VALUES (1u << 28)

typedef struct volume_grid {
    int nx, ny, nz;
    int channels;   /* 1 or 3                                                              */
    float *data;    /* owned; nx ny nz channels values, each finite                        */
    float max;      /* the largest value of any cell and channel                           */
    int nearest;    /* filter_type "nearest"; 0: "trilinear" (Mitsuba 3's default)          */
} volume_grid;

/* Reads a .vol file. Every value must be finite and within [lo, hi]; `what` names the
 * values in messages ("density", "albedo"). Returns 0 with a message that names the file and
 * what is wrong (magic, version, encoding, sizes, channels, a short or long file, the first
 * cell out of range with its coordinates and value); *g is then empty. */
int volume_grid_read(const char *path, const char *what, float lo, float hi, volume_grid *g,
                     tr_error *err);

/* The same from bytes in memory (`name` stands for the path in messages): the fuzzer's and
 * the tests' entry point. */
int volume_grid_parse(const unsigned char *bytes, size_t size, const char *name,
                      const char *what, float lo, float hi, volume_grid *g, tr_error *err);

void volume_grid_free(volume_grid *g);

/* The first channel at u (grid coordinates; outside [0, 1]^3 the edge cells' values). */
float volume_grid_eval1(const volume_grid *g, vec3 u);

/* Three channels at u; a one-channel grid gives its value in all three. */
rgb volume_grid_eval_rgb(const volume_grid *g, vec3 u);

#endif /* TRACER_VOLUME_GRID_H */
