/*
 * point_batch.h - shading points and tables in bulk: one direction per prepared point, and a
 * point's table built outright. Internal (not installed): the table cache builds its tables
 * with nf_table_build; wavefront renderers batch over contexts (nf_sample, nf_pdf); the tests
 * and fuzzers check these.
 */
#ifndef NISFLOW_SRC_POINT_BATCH_H
#define NISFLOW_SRC_POINT_BATCH_H

#include <stddef.h>

#include "shading_point.h"
#include "direction_table.h"

/* Batch forms for wavefront renderers: one direction per point. points[i] is prepared (each
 * with its own context); u, dir and pdf as in nf_sample. Every point and input is checked
 * before anything is written; NF_ERROR_NUMERIC from a custom prior may come mid-batch, after
 * earlier entries were written. Thread-safe on a const model; never allocates. */
nf_status nf_point_sample_batch(const nf_model *m, size_t n, const nf_shading_point *points,
                                const float *u, float *dir, float *pdf);

nf_status nf_point_pdf_batch(const nf_model *m, size_t n, const nf_shading_point *points,
                             const float *dir, float *pdf);

/* Builds `table` from the prepared `point`: asks the flow the density of each of the
 * NF_TABLE_CELLS cells' centres (one nf_point_pdf call of that many directions) and keeps
 * the normalized masses. Costs about NF_TABLE_CELLS point densities (docs/performance.md).
 * Errors (nothing written): NF_ERROR_INVALID_ARGUMENT (NULL, an unprepared point, a point of
 * another model), NF_ERROR_STALE (as nf_point_pdf), NF_ERROR_NUMERIC (a custom prior returned
 * an invalid value). Thread-safe on a const model and point; writes only *table. */
nf_status nf_table_build(const nf_model *m, const nf_shading_point *point,
                         nf_direction_table *table);

#endif /* NISFLOW_SRC_POINT_BATCH_H */
