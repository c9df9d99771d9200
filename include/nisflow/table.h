/*
 * nisflow/table.h - a shading point's flow tabulated on a fixed grid of directions, for
 * renderers that ask about many vertices in one small region of the scene.
 *
 * A guided vertex through a shading point (point.h) walks the flow once per question. A
 * renderer that keys cells of its scene (a grid of positions, the normal's direction) can
 * instead build one table per cell from a point prepared at the cell's centre and answer
 * every vertex in the cell from it: a draw is two searches in cumulative sums and a density
 * one lookup, where the flow costs a walk through its layers. The table is a distribution of
 * its own, not the flow's: sampling and evaluating at a vertex both use the same table, so an
 * estimator that mixes it with the BSDF stays unbiased; what the cell's size and the grid's
 * resolution cost in variance is the renderer's to measure (docs/equal-time.md has our
 * client's figures).
 *
 * The grid. At a surface point (a non-zero normal n) the table covers n's hemisphere in the
 * cosine lobe's coordinates: NF_TABLE_ROWS rows of equal sin^2(theta) and NF_TABLE_COLS
 * columns of equal azimuth about n, so every cell has the same probability under the cosine
 * lobe, and the table holds the flow's density over the lobe's at each cell's centre. Its
 * density is then (cell probability) x NF_TABLE_CELLS x cos(theta) / pi per steradian:
 * continuous in the cell, zero at the horizon and below it (a BSDF's transmission is left to
 * BSDF sampling). At a point in a medium (a zero normal) the table covers the sphere in cells
 * of equal solid angle (rows of equal z, columns of equal azimuth about +z), each holding the
 * flow's density at its centre.
 *
 * Memory: an nf_direction_table is a plain struct (2,304 bytes) that the caller owns; nothing
 * is allocated. Its fields are the library's: read or write none of them. It may be copied.
 *
 * Validity: a table belongs to the model its point was prepared on and to that model's
 * parameters when it was built; after a change of the parameters (a training step,
 * nf_model_set_params, nf_apply_gradient) using it returns NF_ERROR_STALE, as a point does.
 * A table whose contents were overwritten gives wrong results but never reads outside itself.
 *
 * Results: the build asks the flow through nf_point_pdf, so a table holds the bits of that
 * call's path (the presets' vector path agrees with nf_pdf within the bound point.h states).
 * Drawing and evaluating are scalar code compiled once: the same bits on every instruction
 * set for the same table.
 *
 * Thread-safety: every function takes a const model and a const table (the build writes only
 * *table); any number of threads may draw from one table at once. Nothing allocates.
 * Stack: a build uses at most 8 KiB (its table, a row of directions and the flow's share), a
 * draw or a density 256 bytes; tests/correctness/test_table.c measures both.
 */
#ifndef NISFLOW_TABLE_H
#define NISFLOW_TABLE_H

#include <stdint.h>

#include "point.h"
#include "status.h"
#include "version.h"

NF_EXTERN_C_BEGIN

#define NF_TABLE_ROWS 16u                              /* polar rows                  */
#define NF_TABLE_COLS 32u                              /* azimuthal columns           */
#define NF_TABLE_CELLS (NF_TABLE_ROWS * NF_TABLE_COLS) /* 512 directions asked a build */

/* A tabulated point. Its layout is private: the names exist only to size it. */
typedef struct nf_direction_table {
    uint32_t magic_;                                      /* marks a built table            */
    uint32_t medium_;                                     /* 1: the sphere; 0: a hemisphere */
    uint64_t model_id_;                                   /* the model it belongs to        */
    uint64_t generation_;                                 /* that model's parameters        */
    float frame_[9];                                      /* t, b, n                        */
    float row_cdf_[NF_TABLE_ROWS + 1];                    /* the rows' cumulative mass      */
    float row_mass_[NF_TABLE_ROWS];                       /* each row's mass                */
    float col_cdf_[NF_TABLE_ROWS * (NF_TABLE_COLS + 1)];  /* each row's columns, cumulative */
} nf_direction_table;

/* Builds `table` from the prepared `point`: asks the flow the density of each of the
 * NF_TABLE_CELLS cells' centres (one nf_point_pdf call of that many directions) and keeps
 * the normalized masses. Costs about NF_TABLE_CELLS point densities (docs/performance.md).
 * Errors (nothing written): NF_ERROR_INVALID_ARGUMENT (NULL, an unprepared point, a point of
 * another model), NF_ERROR_STALE (as nf_point_pdf), NF_ERROR_NUMERIC (a custom prior returned
 * an invalid value). Thread-safe on a const model and point; writes only *table. */
NF_API nf_status nf_table_build(const nf_model *m, const nf_shading_point *point,
                                nf_direction_table *table);

/* Draws a direction from the table: u[0], u[1] in [0, 1) (values outside are clamped; NaN is
 * refused) give dir, a unit vector, and, if pdf is not NULL, *pdf, its density per steradian
 * (as nf_table_pdf of dir, within rounding), clamped to [FLT_MIN, FLT_MAX].
 * Errors (nothing written): NF_ERROR_INVALID_ARGUMENT (NULL, a table never built, a table of
 * another model, NaN in u), NF_ERROR_STALE. Thread-safe; never allocates. */
NF_API nf_status nf_table_sample(const nf_model *m, const nf_direction_table *table,
                                 const float u[2], float dir[3], float *pdf);

/* The table's density of dir (any finite direction with squared length above 1e-30; the
 * library normalizes it), per steradian: 0 at and below a surface table's horizon, positive
 * above it. Errors as nf_table_sample (a bad direction is NF_ERROR_INVALID_ARGUMENT).
 * Thread-safe; never allocates. */
NF_API nf_status nf_table_pdf(const nf_model *m, const nf_direction_table *table,
                              const float dir[3], float *pdf);

NF_EXTERN_C_END

#endif /* NISFLOW_TABLE_H */
