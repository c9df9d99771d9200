/*
 * path_record.c - the training records of paths (path_record.h): the buffers they go to, and
 * the library's backward walk over a finished path's recorded vertices.
 */
#include "path_record.h"

#include <stdlib.h>
#include <string.h>

void record_buffer_free(record_buffer *b)
{
    free(b->data);
    memset(b, 0, sizeof *b);
}

static train_record *record_push(record_buffer *b)
{
    if (b->count == b->capacity) {
        size_t cap = b->capacity ? 2 * b->capacity : 256;
        train_record *d = realloc(b->data, cap * sizeof *d);
        if (!d) {
            b->out_of_memory = 1;
            return NULL;
        }
        b->data = d;
        b->capacity = cap;
    }
    return &b->data[b->count++];
}

int record_buffer_append(record_buffer *dst, const record_buffer *src)
{
    if (dst->count + src->count > dst->capacity) {
        size_t cap = dst->capacity ? dst->capacity : 256;
        while (cap < dst->count + src->count)
            cap *= 2;
        train_record *d = realloc(dst->data, cap * sizeof *d);
        if (!d) {
            dst->out_of_memory = 1;
            return 0;
        }
        dst->data = d;
        dst->capacity = cap;
    }
    if (src->count)
        memcpy(dst->data + dst->count, src->data, src->count * sizeof *src->data);
    dst->count += src->count;
    return 1;
}

/* Appends the training samples of a recorded path (nf_path_training_samples does the walk:
 * next-event estimates, MIS weights, roulette). Returns 0 if the library refused the path. */
static int record_path(const tracer *t, nf_path_vertex *pv, const vertex_extra *ex, int nv,
                       uint32_t pixel, record_buffer *records)
{
    nf_context ctx[MAX_RECORDED_VERTICES];
    float dir[3 * MAX_RECORDED_VERTICES], weight[MAX_RECORDED_VERTICES];
    size_t from[MAX_RECORDED_VERTICES], n = 0;
    if (!t->mis_training) /* --variant all-emission: L_i counts all the emission found */
        for (int j = 0; j < nv; ++j)
            pv[j].emitted_mis = 1.0f;
    if (nf_path_training_samples((size_t)nv, pv, (size_t)nv, ctx, dir, weight, from, &n) != NF_OK)
        return 0;
    for (size_t i = 0; i < n; ++i) {
        train_record *rec = record_push(records);
        if (!rec)
            return 1; /* out_of_memory is set: the caller reports it */
        const vertex_extra *x = &ex[from[i]];
        rec->ctx = ctx[i];
        memcpy(rec->dir, dir + 3 * i, sizeof rec->dir);
        rec->weight = weight[i];
        rec->bp = x->bp;
        rec->pixel = pixel;
    }
    return 1;
}

void recorder_close(const tracer *t, const path_recorder *pr, uint32_t pixel,
                           record_buffer *records, path_stats *st)
{
    if (pr->nv > 0 && pr->nv <= pr->cap &&
        !record_path(t, pr->pv, pr->ex, pr->nv, pixel, records))
        st->nf_errors++;
}

/* Grows every array to hold n samples (at least one, so that none is NULL). */
static int record_arrays_reserve(record_arrays *a, size_t n)
{
    if (n <= a->capacity && a->capacity)
        return 1;
    size_t cap = a->capacity ? a->capacity : 1024;
    while (cap < n)
        cap *= 2;
    uint64_t *key = realloc(a->key, cap * sizeof *key);
    if (key)
        a->key = key;
    nf_context *ctx = realloc(a->ctx, cap * sizeof *ctx);
    if (ctx)
        a->ctx = ctx;
    float *dir = realloc(a->dir, cap * 3 * sizeof *dir);
    if (dir)
        a->dir = dir;
    float *weight = realloc(a->weight, cap * sizeof *weight);
    if (weight)
        a->weight = weight;
    prior_point *points = realloc(a->points, cap * sizeof *points);
    if (points)
        a->points = points;
    if (!key || !ctx || !dir || !weight || !points)
        return 0;
    a->capacity = cap;
    return 1;
}

int record_arrays_from(record_arrays *a, const record_buffer *b, uint64_t first_key)
{
    if (!record_arrays_reserve(a, b->count))
        return 0;
    for (size_t i = 0; i < b->count; ++i) {
        const train_record *r = &b->data[i];
        a->key[i] = first_key + i;
        a->ctx[i] = r->ctx;
        memcpy(a->dir + 3 * i, r->dir, sizeof r->dir);
        a->weight[i] = r->weight;
        memcpy(a->points[i].position, r->ctx.position, sizeof r->ctx.position);
        a->points[i].bp = r->bp;
    }
    return 1;
}

void record_arrays_free(record_arrays *a)
{
    free(a->key);
    free(a->ctx);
    free(a->dir);
    free(a->weight);
    free(a->points);
    memset(a, 0, sizeof *a);
}
