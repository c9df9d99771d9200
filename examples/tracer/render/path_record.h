/*
 * path_record.h - what the tracer records of a path for training: the library's
 * nf_path_vertex per vertex (nisflow/path.h, whose backward walk makes the training samples)
 * with the material beside it, and the buffers of training records that the paths fill.
 * recorder_last and recorder_open run at every vertex and are inline.
 */
#ifndef TRACER_PATH_RECORD_H
#define TRACER_PATH_RECORD_H

#include <string.h>

#include <nisflow/nisflow.h>

#include "integrator.h"
#include "model_setup.h"

#define MAX_RECORDED_VERTICES 256

/* What a recorded vertex keeps beside the library's nf_path_vertex (nisflow/path.h, which
 * does the backward walk): the material, for the BSDF prior. */
typedef struct vertex_extra {
    bsdf_point bp;
} vertex_extra;

/* A path's record while it is traced: its vertices for nf_path_training_samples and what the
 * tracer keeps beside them. A path longer than `cap` vertices is not recorded at all (nv is
 * then cap + 1). */
typedef struct path_recorder {
    nf_path_vertex *pv;
    vertex_extra *ex;
    int nv, cap;
} path_recorder;

/* The last recorded vertex, which receives what the next ray finds; NULL without a record. */
static inline nf_path_vertex *recorder_last(const path_recorder *pr)
{
    return pr && pr->nv > 0 && pr->nv <= pr->cap ? &pr->pv[pr->nv - 1] : NULL;
}

/* Opens the record of a planned vertex (*v, *vx stay NULL without a record). */
static inline void recorder_open(path_recorder *pr, nf_path_vertex **v, vertex_extra **vx)
{
    *v = NULL;
    *vx = NULL;
    if (!pr)
        return;
    if (pr->nv < pr->cap) {
        *v = &pr->pv[pr->nv];
        *vx = &pr->ex[pr->nv++];
        memset(*v, 0, sizeof **v);
    } else {
        pr->nv = pr->cap + 1; /* past the cap: stop recording this path */
    }
}

/* Training: the library walks the finished path backwards (nisflow/path.h) and its samples
 * are appended to `records`; a path the library refuses counts in st->nf_errors. */
void recorder_close(const tracer *t, const path_recorder *pr, uint32_t pixel,
                    record_buffer *records, path_stats *st);

/* Training records as structure of arrays, as the guide (nf_guide_add_samples,
 * nf_guide_train_batch) takes them: each sample keyed by its place among the records (which
 * come in tile and path order, the same for any number of threads), its material as the
 * payload the BSDF prior's callbacks read. Zero-initialize; grows as needed. */
typedef struct record_arrays {
    uint64_t *key;
    nf_context *ctx;
    float *dir, *weight;
    prior_point *points;
    size_t capacity;
} record_arrays;

/* Fills `a` with every record of `b` (index i of the arrays is b->data[i], keyed
 * first_key + i). Returns 0 when out of memory; `a` then keeps what it held. */
int record_arrays_from(record_arrays *a, const record_buffer *b, uint64_t first_key);
void record_arrays_free(record_arrays *a);

#endif /* TRACER_PATH_RECORD_H */
