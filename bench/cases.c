/*
 * cases.c - one case of nf_bench timed: an op at a batch size on a number of threads.
 *
 * What is timed (docs/performance.md has the details):
 *
 *   sample    nf_sample on a batch of n contexts and uniform pairs.
 *   pdf       nf_pdf on a batch of n contexts and directions (directions drawn by nf_sample).
 *   train     one optimisation step per batch. 1 thread: nf_train_step. T threads: the
 *             sharded-gradient API. Thread k calls nf_loss_gradient on its contiguous 1/T of
 *             the batch (const model, its own gradient buffer g_k) and sums its weights F_k;
 *             then the main thread forms g = sum F_k g_k / sum F_k and calls
 *             nf_apply_gradient. Everything (gradients, weight sums, the combination, the
 *             AdamW step and the synchronisation) is inside the timed region.
 *   guide     one step of a guide (nisflow/guide.h) per batch: nf_guide_train_batch with the
 *             guide's 16 gradient groups, run on T threads through the pool as the
 *             caller's parallel-for, summed exactly and applied (the same bits on any T).
 *             Batches below 16 samples are n/a.
 *   batch 1   streams of consecutive calls with n = 1, each on a different input (units of
 *             256 calls, as many units per repetition as its minimum time needs), reported
 *             per call. With T threads each thread makes its own stream of n = 1 calls over
 *             its 1/T of each unit's inputs. Training with n = 1 is one nf_train_step per
 *             sample; on several threads it is not defined (one sample cannot be sharded) and
 *             is reported as n/a.
 *
 * The shading-point API (nisflow/point.h) is timed per call, n = 1, in the same streams of
 * 256 calls as batch 1 (so it has no batch sizes; a table of its own):
 *
 *   prepare       nf_point_prepare on a new context every call, into a point on the calling
 *                 thread's stack (where a renderer keeps it).
 *   point-sample  nf_point_sample(n = 1) on an already prepared point: a ring of 256 points
 *                 (one unit's worth, prepared outside the timed region) with a new u every
 *                 call.
 *   point-pdf     nf_point_pdf(n = 1) likewise, of a uniform random unit direction.
 *   vertex        one guided vertex, the headline figure, as docs/integration.md's recipe
 *                 does it: nf_point_prepare on a new context, then nf_point_sample_and_pdf:
 *                 a direction drawn and the density of another (a uniform random unit
 *                 direction, standing for a light sample's), all timed.
 *   vertex-calls  the same vertex as three calls: nf_point_prepare, nf_point_sample of one
 *                 direction and nf_point_pdf of the other.
 *   table-build   nf_table_build (nisflow/table.h) from the ring's points, into a table on
 *                 the calling thread's stack.
 *   table-vertex  a guided vertex from tables built outside the timed region (a ring of 256,
 *                 one per ring point, 544 KiB: a renderer's cells are more and colder):
 *                 nf_table_sample with a new u and nf_table_pdf of another direction.
 *   table-find    nf_table_cache_find (build = 0) of a context on the faces of the model's
 *                 bounds, inward normals (a box's walls: 1,536 cells of the default grid),
 *                 from each thread's cache in which every wall's table was built before the
 *                 timing; a find without a table ends the case.
 *   cell-vertex   a guided vertex as a renderer with a cache pays it: table-find's find, then
 *                 table-vertex's two calls on the table it found. The tables are the walls'
 *                 (3.3 MiB a thread), not a ring that stays in the caches.
 *
 * With T threads, each thread processes its own contiguous 1/T of every batch and the figure
 * is throughput: wall time divided by the total samples. The main thread is worker 0; T - 1
 * persistent pthreads are created once and released per repetition (per step for training)
 * by a spin-then-block barrier, so thread creation is never timed.
 *
 * Timing: CLOCK_MONOTONIC; a warm-up of >= half a repetition, then the median of --reps
 * repetitions, each made of enough calls to last >= --min-rep-ms. Consecutive calls walk
 * through a pool of 65536 different inputs, so nothing is served from a repeated batch.
 * The benchmark assumes an otherwise idle machine. It measures the CPU time that other
 * processes used during each case (from /proc/stat); a case during which they needed more
 * than the CPUs the benchmark left free is re-measured (--retries) and, if it stays
 * disturbed, flagged with '*'.
 *
 * Validity: every call's status is checked inside the timed loop (the first failure ends the
 * case and the program, with the call and its message), and after each case, outside the
 * timed region, every density and direction the case wrote is checked (finite, positive,
 * unit length), so a broken call is reported rather than timed.
 */
#include "cases.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "gradient.h"
#include "point_batch.h"
#include "direction_table.h"
#include "shading_point.h"

/* ---- The timed work ---------------------------------------------------------------------- */

/* What one thread reports of its share of a job. The error message is copied at once: the
 * library keeps it per thread, and the main thread prints it. */
typedef struct thread_result {
    nf_status status;
    const char *fn;
    char message[256];
    double weight_sum;
    char pad[64]; /* keep neighbours on separate cache lines */
} thread_result;

/* A case in progress: what it times, where in the input pool it is, and the current job of
 * the thread pool. */
typedef struct bench_case {
    int op;
    size_t batch;
    int threads;
    const nf_model *model; /* sample, pdf */
    nf_model *train_model; /* train (a clone) */
    nf_guide *guide;       /* guide (of a clone) */
    pool *pl;              /* guide: the pool its parallel-for runs on (NULL: 1 thread) */
    const bench_data *d;
    size_t cursor; /* index of the next unit of work */
    /* the current pool job */
    size_t first_unit, units, train_base;
    float *grad[NFB_MAX_THREADS];
    float *grad_sum;
    size_t param_count;
    thread_result res[NFB_MAX_THREADS];
    nf_table_cache *caches[NFB_MAX_THREADS]; /* table-find, cell-vertex: each thread's, its
                                              * walls built */
} bench_case;

/* Samples in one unit of work: a batch, or a stream of NFB_STREAM calls with n = 1. */
static size_t unit_samples(const bench_case *c)
{
    return c->batch == 1 ? NFB_STREAM : c->batch;
}

/* First input index of unit j: consecutive units walk through the input pool. */
static size_t unit_base(const bench_case *c, size_t j)
{
    size_t m = unit_samples(c);
    size_t base = (j * m) % c->d->n;
    return base + m <= c->d->n ? base : 0;
}

static void record_failure(thread_result *r, nf_status st, const char *fn)
{
    r->status = st;
    r->fn = fn;
    snprintf(r->message, sizeof r->message, "%s", nf_last_error_message());
}

/* A vertex from table t: a draw with input i's u and the density of its light direction; the
 * failing function in *fn. */
static nf_status table_vertex(const nf_model *m, const nf_direction_table *t, const bench_data *d,
                              size_t i, const char **fn)
{
    nf_status st = nf_table_sample(m, t, d->u + 2 * i, d->out_dir + 3 * i, d->out_pdf + i);
    if (st != NF_OK) {
        *fn = "nf_table_sample";
        return st;
    }
    if ((st = nf_table_pdf(m, t, d->light_dir + 3 * i, d->out_pdf2 + i)) != NF_OK)
        *fn = "nf_table_pdf";
    return st;
}

/* The shading-point ops on inputs [lo, hi): hi - lo calls (of each function) with n = 1.
 * Like the batch-1 loops, the first failure ends the range and is recorded, so that
 * run_units reports it instead of timing it. */
static void point_range(bench_case *c, thread_result *r, size_t lo, size_t hi)
{
    const bench_data *d = c->d;
    const nf_model *m = c->model;
    /* prepare and vertex prepare into this thread's stack, as a renderer does: the point is
     * hot when vertex samples it, and the threads never share its cache lines. */
    _Alignas(64) nf_shading_point sp;
    _Alignas(64) nf_direction_table table;
    nf_status st = NF_OK;
    const char *fn = NULL;
    switch (c->op) {
    case OP_PREPARE:
        fn = "nf_point_prepare";
        for (size_t i = lo; i < hi && st == NF_OK; ++i)
            st = nf_point_prepare(m, d->ctx + i, NULL, &sp);
        break;
    case OP_POINT_SAMPLE:
        /* Input i of a unit uses ring point i (units start at multiples of NFB_STREAM). */
        fn = "nf_point_sample";
        for (size_t i = lo; i < hi && st == NF_OK; ++i)
            st = nf_point_sample(m, &d->points[i % NFB_POINT_RING], 1, d->u + 2 * i,
                                 d->out_dir + 3 * i, d->out_pdf + i);
        break;
    case OP_POINT_PDF:
        fn = "nf_point_pdf";
        for (size_t i = lo; i < hi && st == NF_OK; ++i)
            st = nf_point_pdf(m, &d->points[i % NFB_POINT_RING], 1, d->light_dir + 3 * i,
                              d->out_pdf2 + i);
        break;
    case OP_VERTEX:
        /* fn is set only on a failure, to keep the timed loop to the two calls. */
        for (size_t i = lo; i < hi; ++i) {
            if ((st = nf_point_prepare(m, d->ctx + i, NULL, &sp)) != NF_OK) {
                fn = "nf_point_prepare";
                break;
            }
            if ((st = nf_point_sample_and_pdf(m, &sp, d->u + 2 * i, d->out_dir + 3 * i,
                                              d->out_pdf + i, d->light_dir + 3 * i,
                                              d->out_pdf2 + i)) != NF_OK) {
                fn = "nf_point_sample_and_pdf";
                break;
            }
        }
        break;
    case OP_VERTEX_CALLS:
        /* fn is set only on a failure, to keep the timed loop to the three calls. */
        for (size_t i = lo; i < hi; ++i) {
            if ((st = nf_point_prepare(m, d->ctx + i, NULL, &sp)) != NF_OK) {
                fn = "nf_point_prepare";
                break;
            }
            if ((st = nf_point_sample(m, &sp, 1, d->u + 2 * i, d->out_dir + 3 * i,
                                      d->out_pdf + i)) != NF_OK) {
                fn = "nf_point_sample";
                break;
            }
            if ((st = nf_point_pdf(m, &sp, 1, d->light_dir + 3 * i, d->out_pdf2 + i)) !=
                NF_OK) {
                fn = "nf_point_pdf";
                break;
            }
        }
        break;
    case OP_TABLE_BUILD:
        fn = "nf_table_build";
        for (size_t i = lo; i < hi && st == NF_OK; ++i)
            st = nf_table_build(m, &d->points[i % NFB_POINT_RING], &table);
        break;
    case OP_TABLE_FIND:
    case OP_CELL_VERTEX: {
        nf_table_cache *cache = c->caches[r - c->res]; /* the calling thread's */
        for (size_t i = lo; i < hi; ++i) {
            const nf_direction_table *t = NULL;
            if ((st = nf_table_cache_find(cache, m, d->walls + i, 0, &t)) != NF_OK || !t) {
                fn = "nf_table_cache_find";
                if (st == NF_OK) { /* every wall's table was built before the timing */
                    fprintf(stderr, "nf_bench: %s: a wall's cell had no table\n", OP_NAME[c->op]);
                    st = NF_ERROR_INVALID_ARGUMENT;
                }
                break;
            }
            if (c->op == OP_CELL_VERTEX && (st = table_vertex(m, t, d, i, &fn)) != NF_OK)
                break;
        }
        break;
    }
    case OP_TABLE_VERTEX:
        for (size_t i = lo; i < hi; ++i)
            if ((st = table_vertex(m, &d->tables[i % NFB_POINT_RING], d, i, &fn)) != NF_OK)
                break;
        break;
    default:
        break;
    }
    if (st != NF_OK)
        record_failure(r, st, fn);
}

/* nf_sample / nf_pdf on inputs [lo, hi): one call, or hi - lo calls with n = 1; the
 * shading-point ops through point_range. */
static void eval_range(bench_case *c, thread_result *r, size_t lo, size_t hi)
{
    const bench_data *d = c->d;
    nf_status st = NF_OK;
    if (op_is_point(c->op)) {
        point_range(c, r, lo, hi);
    } else if (c->op == OP_SAMPLE) {
        if (c->batch == 1) {
            for (size_t i = lo; i < hi && st == NF_OK; ++i)
                st = nf_sample(c->model, 1, d->ctx + i, d->u + 2 * i, d->out_dir + 3 * i,
                               d->out_pdf + i);
        } else {
            st = nf_sample(c->model, hi - lo, d->ctx + lo, d->u + 2 * lo, d->out_dir + 3 * lo,
                           d->out_pdf + lo);
        }
        if (st != NF_OK)
            record_failure(r, st, "nf_sample");
    } else {
        if (c->batch == 1) {
            for (size_t i = lo; i < hi && st == NF_OK; ++i)
                st = nf_pdf(c->model, 1, d->ctx + i, d->dir + 3 * i, d->out_pdf + i);
        } else {
            st = nf_pdf(c->model, hi - lo, d->ctx + lo, d->dir + 3 * lo, d->out_pdf + lo);
        }
        if (st != NF_OK)
            record_failure(r, st, "nf_pdf");
    }
}

/* Job: thread k evaluates its contiguous 1/T of each of the units [first_unit, +units). */
static void job_eval(void *arg, int k)
{
    bench_case *c = (bench_case *)arg;
    thread_result *r = &c->res[k];
    size_t m = unit_samples(c), t = (size_t)c->threads;
    size_t lo = m * (size_t)k / t, hi = m * ((size_t)k + 1) / t;
    for (size_t j = 0; j < c->units && r->status == NF_OK; ++j) {
        size_t base = unit_base(c, c->first_unit + j);
        eval_range(c, r, base + lo, base + hi);
    }
}

/* Job: thread k's shard of the training batch at train_base: its gradient and weight sum. */
static void job_gradient(void *arg, int k)
{
    bench_case *c = (bench_case *)arg;
    thread_result *r = &c->res[k];
    const bench_data *d = c->d;
    size_t t = (size_t)c->threads;
    size_t lo = c->train_base + c->batch * (size_t)k / t;
    size_t hi = c->train_base + c->batch * ((size_t)k + 1) / t;
    double sum = 0.0;
    for (size_t i = lo; i < hi; ++i)
        sum += d->weight[i];
    r->weight_sum = sum;
    nf_status st = nf_loss_gradient(c->train_model, hi - lo, d->ctx + lo, d->dir + 3 * lo,
                                    d->weight + lo, NULL, c->grad[k]);
    if (st != NF_OK)
        record_failure(r, st, "nf_loss_gradient");
}

/* Prints the failure of every thread that had one: -1 if any did. */
static int check_results(bench_case *c)
{
    int bad = 0;
    for (int k = 0; k < c->threads; ++k) {
        thread_result *r = &c->res[k];
        if (r->status != NF_OK) {
            fprintf(stderr, "nf_bench: %s failed on thread %d: %s: %s\n", r->fn, k,
                    nf_status_string(r->status), r->message);
            bad = 1;
        }
    }
    return bad ? -1 : 0;
}

static void reset_results(bench_case *c)
{
    for (int k = 0; k < c->threads; ++k)
        c->res[k].status = NF_OK;
}

/* One sharded training step on the batch at `base` (threads > 1). */
static int sharded_step(bench_case *c, pool *pl, size_t base)
{
    c->train_base = base;
    reset_results(c);
    pool_run(pl, job_gradient, c);
    if (check_results(c) != 0)
        return -1;
    double total = 0.0;
    for (int k = 0; k < c->threads; ++k)
        total += c->res[k].weight_sum;
    float a[NFB_MAX_THREADS];
    for (int k = 0; k < c->threads; ++k)
        a[k] = (float)(c->res[k].weight_sum / total);
    size_t p = c->param_count;
    float *g = c->grad_sum;
    for (size_t i = 0; i < p; ++i)
        g[i] = a[0] * c->grad[0][i];
    for (int k = 1; k < c->threads; ++k) {
        const float *gk = c->grad[k];
        float ak = a[k];
        for (size_t i = 0; i < p; ++i)
            g[i] += ak * gk[i];
    }
    nf_status st = nf_apply_gradient(c->train_model, g);
    if (st != NF_OK) {
        fprintf(stderr, "nf_bench: nf_apply_gradient failed: %s: %s\n", nf_status_string(st),
                nf_last_error_message());
        return -1;
    }
    return 0;
}

/* The guide's parallel-for on the bench's pool: thread k runs tasks k, k + T, ... */
typedef struct guide_tasks {
    bench_case *c;
    size_t count;
    nf_task_fn task;
    void *data;
} guide_tasks;

static void job_guide_tasks(void *arg, int k)
{
    guide_tasks *g = (guide_tasks *)arg;
    for (size_t i = (size_t)k; i < g->count; i += (size_t)g->c->threads)
        g->task(g->data, i);
}

static void guide_parallel_for(void *user, size_t count, nf_task_fn task, void *data)
{
    bench_case *c = (bench_case *)user;
    guide_tasks g = {c, count, task, data};
    pool_run(c->pl, job_guide_tasks, &g);
}

static int guide_step(bench_case *c, size_t base)
{
    const bench_data *d = c->d;
    nf_parallel par = {guide_parallel_for, c};
    nf_status st = nf_guide_train_batch(c->guide, c->batch, d->ctx + base, d->dir + 3 * base,
                                        d->weight + base, NULL, 0, c->pl ? &par : NULL, NULL,
                                        NULL);
    if (st != NF_OK) {
        fprintf(stderr, "nf_bench: nf_guide_train_batch failed: %s: %s\n", nf_status_string(st),
                nf_last_error_message());
        return -1;
    }
    return 0;
}

/* Runs `units` units of work and returns their wall time in *seconds. */
static int run_units(bench_case *c, pool *pl, size_t units, double *seconds)
{
    const bench_data *d = c->d;
    double t0 = now_s();
    if (c->op == OP_GUIDE) {
        c->pl = c->threads > 1 ? pl : NULL;
        for (size_t j = 0; j < units; ++j)
            if (guide_step(c, unit_base(c, c->cursor + j)) != 0)
                return -1;
    } else if (c->op != OP_TRAIN) {
        c->first_unit = c->cursor;
        c->units = units;
        reset_results(c);
        if (c->threads == 1)
            job_eval(c, 0);
        else
            pool_run(pl, job_eval, c);
        if (check_results(c) != 0)
            return -1;
    } else {
        for (size_t j = 0; j < units; ++j) {
            size_t base = unit_base(c, c->cursor + j);
            if (c->threads > 1) {
                if (sharded_step(c, pl, base) != 0)
                    return -1;
                continue;
            }
            size_t calls = c->batch == 1 ? NFB_STREAM : 1, n = c->batch == 1 ? 1 : c->batch;
            for (size_t i = 0; i < calls; ++i) {
                size_t at = base + i * n;
                nf_status st = nf_train_step(c->train_model, n, d->ctx + at, d->dir + 3 * at,
                                             d->weight + at, NULL);
                if (st != NF_OK) {
                    fprintf(stderr, "nf_bench: nf_train_step failed: %s: %s\n",
                            nf_status_string(st), nf_last_error_message());
                    return -1;
                }
            }
        }
    }
    *seconds = now_s() - t0;
    c->cursor += units;
    return 0;
}

/* ---- Measurement ------------------------------------------------------------------------- */

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* One attempt at case c into *r: a warm-up, then o->reps repetitions of the same number of
 * units of work, and their median (robust to the odd interrupted repetition). */
static int measure(bench_case *c, pool *pl, const options *o, result *r)
{
    /* Warm-up: doubling chunks until half a repetition's time has passed; it also gives the
     * time of one unit of work. */
    double warm_s = 0.5 * o->min_rep_s, total = 0.0, per_unit = 0.0;
    for (size_t k = 1;; k *= 2) {
        double t;
        if (run_units(c, pl, k, &t) != 0)
            return -1;
        total += t;
        per_unit = t / (double)k;
        if (total >= warm_s)
            break;
    }
    size_t units = 1;
    if (per_unit > 0.0 && per_unit < o->min_rep_s)
        units = (size_t)ceil(o->min_rep_s / per_unit);
    double ns[64];
    int reps = o->reps;
    size_t samples = units * unit_samples(c);
    for (int i = 0; i < reps; ++i) {
        double t;
        if (run_units(c, pl, units, &t) != 0)
            return -1;
        ns[i] = t * 1e9 / (double)samples;
    }
    qsort(ns, (size_t)reps, sizeof ns[0], cmp_double);
    r->ns_median = reps % 2 ? ns[reps / 2] : 0.5 * (ns[reps / 2 - 1] + ns[reps / 2]);
    r->ns_min = ns[0];
    r->ns_max = ns[reps - 1];
    r->units_per_rep = units;
    r->samples_per_rep = samples;
    r->reps = reps;
    r->measured = 1;
    return 0;
}

/* ---- Checks of what the timed calls wrote ------------------------------------------------ */

/* Statuses are checked in the timed loops; these check, outside them, the outputs of calls
 * that returned NF_OK: a NaN, a non-positive density, a direction that is not a unit vector
 * or an output never written is a failure too, not a figure. Before a case every output is
 * set to a value no call writes (a NaN direction, a density of -1). */
static void clear_outputs(bench_data *d)
{
    for (size_t i = 0; i < 3 * d->n; ++i)
        d->out_dir[i] = NAN;
    for (size_t i = 0; i < d->n; ++i)
        d->out_pdf[i] = d->out_pdf2[i] = -1.0f;
}

static int valid_density(float p)
{
    return isfinite(p) && p > 0.0f;
}

static int valid_direction(const float *v)
{
    float len2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
    return isfinite(len2) && fabsf(len2 - 1.0f) <= 1e-3f; /* false for NaN */
}

/* The outputs of case c, which started from clear_outputs. Its units so far walked the
 * inputs from the pool's start, so every input in [0, covered) must hold a valid output. */
static int check_outputs(const bench_case *c, const char *preset)
{
    const bench_data *d = c->d;
    int op = c->op;
    /* Which outputs the op writes, and the function that writes them. */
    const char *dir_fn = op == OP_SAMPLE                                  ? "nf_sample"
                         : op == OP_POINT_SAMPLE || op == OP_VERTEX_CALLS ? "nf_point_sample"
                         : op == OP_VERTEX       ? "nf_point_sample_and_pdf"
                         : op_is_table_vertex(op) ? "nf_table_sample"
                                                  : NULL;
    const char *pdf_fn = op == OP_PDF ? "nf_pdf" : dir_fn;
    const char *pdf2_fn = op == OP_POINT_PDF || op == OP_VERTEX_CALLS ? "nf_point_pdf"
                          : op == OP_VERTEX                           ? "nf_point_sample_and_pdf"
                          : op_is_table_vertex(op)                    ? "nf_table_pdf"
                                                                      : NULL;
    size_t covered = c->cursor * unit_samples(c);
    if (covered > d->n)
        covered = d->n;
    for (size_t i = 0; i < covered; ++i) {
        const float *v = d->out_dir + 3 * i;
        const char *fn = NULL, *what = NULL;
        if (dir_fn && !valid_direction(v)) {
            fn = dir_fn;
            what = "direction";
        } else if (pdf_fn && !valid_density(d->out_pdf[i])) {
            fn = pdf_fn;
            what = "density";
        } else if (pdf2_fn && !valid_density(d->out_pdf2[i]) &&
                   /* a surface table's density is 0 below the horizon */
                   !(op_is_table_vertex(op) && d->out_pdf2[i] == 0.0f)) {
            fn = pdf2_fn;
            what = "density";
        }
        if (fn) {
            fprintf(stderr,
                    "nf_bench: %s %s %dT: %s returned NF_OK but input %zu's %s is invalid or "
                    "was not written (direction %g %g %g, densities %g %g)\n",
                    preset, OP_NAME[op], c->threads, fn, i, what, (double)v[0], (double)v[1],
                    (double)v[2], (double)d->out_pdf[i], (double)d->out_pdf2[i]);
            return -1;
        }
    }
    return 0;
}

/* ---- One case, and a preset's cases ------------------------------------------------------ */

/* table-find's and cell-vertex's caches, one a thread, every wall's cell built (8,192 tables of
 * room for the 1,536 cells, so that no bucket of 8 fills), outside the timing. -1 on failure,
 * reported. */
static int fill_caches(bench_case *c)
{
    nf_table_cache_config cfg;
    nf_table_cache_config_init(&cfg);
    cfg.capacity = 8192;
    for (int k = 0; k < c->threads; ++k) {
        if (report_status(nf_table_cache_create(&cfg, &c->caches[k]), "nf_table_cache_create") !=
            0)
            return -1;
        for (size_t i = 0; i < c->d->n; ++i) {
            const nf_direction_table *t = NULL;
            if (report_status(nf_table_cache_find(c->caches[k], c->model, c->d->walls + i, 1, &t),
                              "nf_table_cache_find") != 0)
                return -1;
            if (!t) {
                fprintf(stderr, "nf_bench: a bucket of the walls' cache filled\n");
                return -1;
            }
        }
    }
    return 0;
}

static void destroy_caches(bench_case *c)
{
    for (int k = 0; k < NFB_MAX_THREADS; ++k) {
        nf_table_cache_destroy(c->caches[k]);
        c->caches[k] = NULL;
    }
}

/* Measures one case into *r: re-measured while other processes disturb it (the quietest
 * attempt is kept), then its outputs checked. -1 on any failure, already reported. */
static int run_case(const case_env *e, int op, size_t batch, int threads, result *r)
{
    const options *o = e->o;
    const char *name = e->info->name;
    /* The label of the progress lines: batched ops name their batch size. */
    char label[64];
    if (op_is_point(op))
        snprintf(label, sizeof label, "%-6s %-12s %dT", name, OP_NAME[op], threads);
    else
        snprintf(label, sizeof label, "%-6s %-6s batch %6zu %dT", name, OP_NAME[op], batch,
                 threads);
    memset(r, 0, sizeof *r);
    r->preset = e->preset;
    r->op = op;
    r->threads = threads;
    r->batch = batch;
    if (op == OP_TRAIN && threads > 1 && batch < (size_t)threads) {
        fprintf(stderr, "%s: n/a (a batch of %zu cannot be sharded)\n", label, batch);
        return 0;
    }
    if (op == OP_GUIDE && batch < 16) {
        fprintf(stderr, "%s: n/a (a guide step takes 16 groups)\n", label);
        return 0;
    }
    bench_case c;
    memset(&c, 0, sizeof c);
    c.op = op;
    c.batch = batch;
    c.threads = threads;
    c.model = e->model;
    c.d = e->d;
    c.param_count = e->info->params;
    c.grad_sum = e->grad_sum;
    for (int k = 0; k < threads; ++k)
        c.grad[k] = e->grad[k];
    nf_model *train_model = NULL;
    if (op == OP_TRAIN) {
        /* Train a clone, so that every case sees the same model. */
        if (report_status(nf_model_clone(e->model, &train_model), "nf_model_clone") != 0)
            return -1;
        c.train_model = train_model;
    }
    nf_guide *guide = NULL;
    if (op == OP_GUIDE) { /* the guide trains copies: every case sees the same model */
        nf_guide_config gc;
        nf_guide_config_init(&gc);
        gc.store_capacity = 1; /* the steps take the bench's batches, not the store */
        nf_config cfg;
        nf_model_get_config(e->model, &cfg);
        gc.learning_rate = cfg.learning_rate;
        if (report_status(nf_guide_create(e->model, &gc, &guide), "nf_guide_create") != 0)
            return -1;
        c.guide = guide;
    }
    if (op_finds_walls(op) && fill_caches(&c) != 0) {
        destroy_caches(&c);
        return -1;
    }
    clear_outputs(e->d);
    /* Re-measure when other processes were busy; keep the quietest. */
    result best = *r;
    int bad = 0, have = 0, attempt = 0;
    for (; attempt <= o->retries; ++attempt) {
        result cur = *r;
        cpu_snapshot before, after;
        take_cpu_snapshot(&before);
        bad = measure(&c, threads > 1 ? e->pl : NULL, o, &cur);
        take_cpu_snapshot(&after);
        if (bad)
            break;
        cur.foreign_cpus = foreign_cpu_load(&before, &after);
        double idle = (double)(o->nproc > threads ? o->nproc - threads : 0);
        cur.disturbed = cur.foreign_cpus > idle + o->busy_threshold;
        if (!have || cur.foreign_cpus < best.foreign_cpus)
            best = cur;
        have = 1;
        if (!cur.disturbed)
            break;
    }
    nf_model_destroy(train_model);
    nf_guide_destroy(guide);
    destroy_caches(&c);
    if (bad || check_outputs(&c, name) != 0)
        return -1;
    best.attempts = attempt <= o->retries ? attempt + 1 : attempt;
    *r = best;
    /* What one "sample" of the figure is: a call of n = 1, or a vertex of three calls. */
    const int vertex = op == OP_VERTEX || op == OP_VERTEX_CALLS || op_is_table_vertex(op);
    const char *unit = vertex ? "vertex" : op_is_point(op) ? "call" : "sample";
    const char *units = vertex ? "vertices" : op_is_point(op) ? "calls" : "samples";
    fprintf(stderr,
            "%s: %9.1f ns/%s (min %.1f, max %.1f; %d reps x %zu %s; other load %.2f CPUs; "
            "attempts %d)%s\n",
            label, r->ns_median, unit, r->ns_min, r->ns_max, r->reps, r->samples_per_rep,
            units, r->foreign_cpus, r->attempts, r->disturbed ? " disturbed" : "");
    return 0;
}

/* Case (op, batch) on each thread count selected, its results appended to res. */
static int run_on_each_thread_count(const case_env *e, int op, size_t batch, result *res,
                                    size_t *count, size_t capacity)
{
    for (int ti = 0; ti < e->o->thread_count; ++ti) {
        if (*count == capacity)
            return -1;
        if (run_case(e, op, batch, e->o->threads[ti], &res[(*count)++]))
            return -1;
    }
    return 0;
}

int run_preset_cases(const case_env *e, const size_t *batches, size_t batch_count,
                     result *res, size_t *count, size_t capacity)
{
    int mask = e->o->op_mask;
    for (int op = 0; op < OP_BATCHED_COUNT; ++op) {
        if (!(mask & (1 << op)))
            continue;
        for (size_t bi = 0; bi < batch_count; ++bi)
            if (run_on_each_thread_count(e, op, batches[bi], res, count, capacity) != 0)
                return -1;
    }
    if (mask & OP_MASK_POINT) {
        if (prepare_ring(e->model, e->d) != 0)
            return -1;
        /* Per-call ops: batch 1 (n = 1) in the results. */
        for (int op = OP_BATCHED_COUNT; op < OP_COUNT; ++op)
            if ((mask & (1 << op)) &&
                run_on_each_thread_count(e, op, 1, res, count, capacity) != 0)
                return -1;
    }
    return 0;
}
