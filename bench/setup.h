/*
 * setup.h - what a preset's cases run on, all of it prepared outside any timing: the model
 * (the preset with randomized parameters) and its FLOP counts, the pool of inputs, the ring
 * of prepared shading points, and the start-up checks that the sharded gradient and the
 * shading-point functions agree with the batched calls.
 */
#ifndef NF_BENCH_SETUP_H
#define NF_BENCH_SETUP_H

#include <stddef.h>

#include "harness.h"
#include "common.h"
#include "direction_table.h"
#include "shading_point.h"

/* ---- The inputs -------------------------------------------------------------------------- */

/* The ring of prepared points that point-sample and point-pdf cycle through: one unit's
 * worth, so that call i of a unit uses points[i] and the threads' slices of a unit use
 * disjoint points. A renderer samples the point it has just prepared, hot in L1; 256 points
 * (288 KiB) stay in L2, so the figure carries at most a few L2 hits (the point's header and
 * cached sums, 4 to 6 lines) more than a renderer pays, while a pool-sized array (72 MiB)
 * would time memory instead. The u and directions still change with every call. */
#define NFB_POINT_RING NFB_STREAM

typedef struct bench_data {
    size_t n;
    nf_context *ctx;
    float *u;         /* 2 n */
    float *dir;       /* 3 n, nf_sample's directions for the current preset */
    float *light_dir; /* 3 n, uniform unit directions: the "other" direction of point-pdf and
                         vertex, independent of the flow as a light sample's would be */
    float *weight;    /* n, positive */
    float *out_dir;   /* 3 n, written by sample, point-sample and vertex */
    float *out_pdf;   /* n, the densities of those samples and of pdf */
    float *out_pdf2;  /* n, the densities of light_dir (point-pdf, vertex) */
    nf_shading_point *points; /* NFB_POINT_RING, 64-byte aligned, prepared per preset */
    nf_direction_table *tables; /* NFB_POINT_RING, built from points per preset        */
    nf_context *walls; /* n contexts on the faces of cfg's bounds, facing in: table-find's */
} bench_data;

/* n random inputs inside cfg's bounds (the same for every run); dir and the points are
 * left for the preset to fill. -1 out of memory. */
int bench_data_alloc(bench_data *d, size_t n, const nf_config *cfg);
void bench_data_free(bench_data *d);

/* The bytes the inputs take, for the memory summary. */
size_t bench_data_bytes(const bench_data *d);

/* Prepares the ring of points that point-sample and point-pdf use. */
int prepare_ring(const nf_model *m, bench_data *d);

/* ---- The model --------------------------------------------------------------------------- */

typedef struct preset_info {
    const char *name;
    size_t params;
    size_t model_bytes;
    double flops_sparse;     /* forward FLOPs per sample, one-blob sparsity exploited */
    double flops_dense;      /* forward FLOPs per sample, dense input layer           */
    double flops_context;    /* the share of flops_sparse that nf_point_prepare does  */
    double shard_check;      /* check_sharding's relative difference                  */
    size_t point_checked;    /* check_points: inputs compared                         */
    size_t point_mismatches; /* check_points: inputs whose results differ in a bit    */
    double point_worst;      /* check_points: the largest relative density difference */
    const char *isa;         /* the kernel variant the model runs (nf_model_isa_name) */
    nf_config cfg;
} preset_info;

/* A model of the preset (0 small, 1 large) with randomized parameters, its memory counted by
 * ca; fills *info but for the checks' fields. -1 on failure, already reported. */
int make_model(int preset, const options *o, counting_allocator *ca, preset_info *info,
               nf_model **out);

/* FLOPs per sample (per call for the shading-point ops; per vertex for vertex). */
double flops_per_sample(const preset_info *pi, int op);

/* 0 when st is NF_OK; else prints which call failed and why, and returns -1. */
int report_status(nf_status st, const char *fn);

/* ---- Start-up checks --------------------------------------------------------------------- */

/* Checks the sharding recipe the 2-thread training uses: the gradient of a batch equals the
 * weight-sum-weighted mean of the gradients of its two halves. *rel receives
 * max |g - g_combined| / max |g|. */
int check_sharding(const nf_model *m, const bench_data *d, size_t n, size_t p, double *rel);

/* Checks the shading-point functions against the batched ones they must equal bit for bit
 * (point.h): for the first n inputs, nf_point_sample(u) against d->dir and d->out_pdf (which
 * the caller has just filled with nf_sample) and nf_point_pdf(light_dir) against nf_pdf.
 * A failed call is an error; *mismatches counts inputs whose results differ in any bit. */
int check_points(const nf_model *m, bench_data *d, size_t n, size_t *mismatches, double *worst);

#endif /* NF_BENCH_SETUP_H */
