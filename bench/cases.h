/*
 * cases.h - the benchmark cases of nf_bench: each op of a preset at each batch size on each
 * thread count, timed into a result (cases.c says what exactly is timed and how).
 */
#ifndef NF_BENCH_CASES_H
#define NF_BENCH_CASES_H

#include <stddef.h>

#include "harness.h"
#include "common.h"
#include "setup.h"

/* The figure of one case. The shading-point ops are stored with batch 1 (n = 1 per call). */
typedef struct result {
    int preset, op, threads;
    size_t batch;
    int measured;      /* 0: not applicable */
    double ns_median;  /* per sample */
    double ns_min, ns_max;
    size_t units_per_rep, samples_per_rep;
    int reps;
    double foreign_cpus; /* other processes' CPU load during the measurement; -1 unknown */
    int disturbed;       /* foreign_cpus > idle CPUs + busy_threshold                      */
    int attempts;
} result;

/* What the cases of one preset share. */
typedef struct case_env {
    const options *o;
    pool *pl; /* NULL when every case runs on 1 thread */
    bench_data *d;
    const nf_model *model;
    int preset;
    const preset_info *info;
    float *const *grad; /* one gradient buffer per thread (train) */
    float *grad_sum;
} case_env;

/* Runs every case of the preset that the options select, in the order of the tables: the
 * batched ops by op, batch size (batches[0 .. batch_count)) and thread count, then the
 * shading-point ops by op and thread count. Appends each result to res[*count], at most
 * capacity in all. Progress lines go to stderr. -1 on any failure (already reported) or
 * when res is full. */
int run_preset_cases(const case_env *e, const size_t *batches, size_t batch_count,
                     result *res, size_t *count, size_t capacity);

#endif /* NF_BENCH_CASES_H */
