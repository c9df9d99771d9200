/*
 * nf_bench.c - the libnisflow benchmark: nanoseconds per sample of nf_sample, nf_pdf and
 * training, for the small and large presets, batch sizes 1, 64, 4096 and 65536, with 1 and 2
 * threads; the model's FLOPs per sample, the achieved GFLOP/s and the peak memory.
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
 *   vertex        one guided vertex, the headline figure: nf_point_prepare on a new context,
 *                 nf_point_sample of one direction and nf_point_pdf of another (a uniform
 *                 random unit direction, standing for the BSDF's or a light sample's), all
 *                 timed.
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
 * The model has randomized parameters (nf_get_params + uniform noise + nf_set_params) so
 * every spline is a real, non-identity spline; the cosine prior is the default.
 *
 * Validity: every call's status is checked inside the timed loop (the first failure ends the
 * case and the program, with the call and its message), and after each case, outside the
 * timed region, every density and direction the case wrote is checked (finite, positive,
 * unit length), so a broken call is reported rather than timed. At start-up the shading-point
 * results are compared with nf_sample / nf_pdf, which they must equal bit for bit.
 */
#define _POSIX_C_SOURCE 200809L
#define _DEFAULT_SOURCE 1

#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <time.h>
#include <unistd.h>

#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>
#define NFB_PAUSE() _mm_pause()
#else
#define NFB_PAUSE() ((void)0)
#endif

#include <nisflow/nisflow.h>

#define NFB_MAX_THREADS 64
#define NFB_STREAM 256u         /* n = 1 calls per unit of work at batch 1              */
#define NFB_POOL 65536u         /* distinct inputs (a multiple of every batch size)     */
#define NFB_PARAM_NOISE 0.1f    /* half-width of the uniform noise added to parameters  */
#define NFB_SPIN 20000          /* pause iterations before a barrier waiter blocks      */
#define NFB_MAX_RESULTS 256

static const float PI = 3.14159265358979f;

/* The batched ops come first: they have a row per batch size. The shading-point ops after
 * them are per-call latencies (n = 1) with one row each. */
enum {
    OP_SAMPLE = 0,
    OP_PDF = 1,
    OP_TRAIN = 2,
    OP_BATCHED_COUNT = 3,
    OP_PREPARE = 3,
    OP_POINT_SAMPLE = 4,
    OP_POINT_PDF = 5,
    OP_VERTEX = 6,
    OP_COUNT = 7
};
static const char *const OP_NAME[OP_COUNT] = {"sample",       "pdf",       "train", "prepare",
                                              "point-sample", "point-pdf", "vertex"};
#define OP_MASK_ALL ((1 << OP_COUNT) - 1)
#define OP_MASK_BATCHED ((1 << OP_BATCHED_COUNT) - 1)
#define OP_MASK_POINT (OP_MASK_ALL & ~OP_MASK_BATCHED)

static int op_is_point(int op)
{
    return op >= OP_BATCHED_COUNT;
}

/* ---- Random numbers (splitmix64) ------------------------------------------------------------ */

static uint64_t rng_next(uint64_t *state)
{
    uint64_t z = (*state += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

/* Uniform in [0, 1). */
static float rng_float(uint64_t *state)
{
    return (float)(rng_next(state) >> 40) * 0x1p-24f;
}

static void rng_unit_vector(uint64_t *state, float v[3])
{
    float z = 2.0f * rng_float(state) - 1.0f;
    float phi = 2.0f * PI * rng_float(state);
    float r = sqrtf(fmaxf(0.0f, 1.0f - z * z));
    v[0] = r * cosf(phi);
    v[1] = r * sinf(phi);
    v[2] = z;
}

/* ---- Clock, memory ---------------------------------------------------------------------- */

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static long peak_rss_kib(void)
{
    struct rusage ru;
    if (getrusage(RUSAGE_SELF, &ru) != 0)
        return -1;
    return (long)ru.ru_maxrss; /* KiB on Linux */
}

/* CPU time used by other processes: /proc/stat's busy time of all CPUs minus this process's
 * own CPU time. The benchmark assumes an otherwise idle machine; this tells when it was not. */
typedef struct cpu_snapshot {
    int ok;
    double busy_s, own_s, wall_s;
} cpu_snapshot;

static void cpu_snap(cpu_snapshot *s)
{
    memset(s, 0, sizeof *s);
    s->wall_s = now_s();
    struct rusage ru;
    if (getrusage(RUSAGE_SELF, &ru) == 0)
        s->own_s = (double)ru.ru_utime.tv_sec + 1e-6 * (double)ru.ru_utime.tv_usec +
                   (double)ru.ru_stime.tv_sec + 1e-6 * (double)ru.ru_stime.tv_usec;
    FILE *f = fopen("/proc/stat", "r");
    if (!f)
        return;
    unsigned long long v[8];
    long tick = sysconf(_SC_CLK_TCK);
    if (fscanf(f, "cpu %llu %llu %llu %llu %llu %llu %llu %llu", &v[0], &v[1], &v[2], &v[3],
               &v[4], &v[5], &v[6], &v[7]) == 8 &&
        tick > 0) {
        /* user nice system idle iowait irq softirq steal: all but idle and iowait */
        s->busy_s = (double)(v[0] + v[1] + v[2] + v[5] + v[6] + v[7]) / (double)tick;
        s->ok = 1;
    }
    fclose(f);
}

/* The average number of CPUs that other processes kept busy between a and b; -1 unknown. */
static double foreign_load(const cpu_snapshot *a, const cpu_snapshot *b)
{
    if (!a->ok || !b->ok || b->wall_s <= a->wall_s)
        return -1.0;
    double other = (b->busy_s - a->busy_s) - (b->own_s - a->own_s);
    return other > 0.0 ? other / (b->wall_s - a->wall_s) : 0.0;
}

/* A counting allocator for the models: 64-byte aligned blocks with a size header. */
typedef struct counting_allocator {
    atomic_size_t live;
    atomic_size_t peak;
} counting_allocator;

#define NFB_HEADER 64u

static void *counting_alloc(void *user, size_t size)
{
    counting_allocator *ca = (counting_allocator *)user;
    size_t total = (size + NFB_HEADER + 63u) & ~(size_t)63u;
    unsigned char *block = (unsigned char *)aligned_alloc(64, total);
    if (!block)
        return NULL;
    memcpy(block, &size, sizeof size);
    size_t live = atomic_fetch_add(&ca->live, size) + size;
    size_t peak = atomic_load(&ca->peak);
    while (live > peak && !atomic_compare_exchange_weak(&ca->peak, &peak, live)) {
    }
    return block + NFB_HEADER;
}

static void counting_free(void *user, void *ptr)
{
    counting_allocator *ca = (counting_allocator *)user;
    unsigned char *block = (unsigned char *)ptr - NFB_HEADER;
    size_t size;
    memcpy(&size, block, sizeof size);
    atomic_fetch_sub(&ca->live, size);
    free(block);
}

/* ---- A custom prior for --prior custom: a cosine lobe through the callbacks ------------ */

static float custom_sample(void *user, const nf_context *ctx, float u0, float u1, float dir[3])
{
    (void)user;
    float n[3] = {ctx->normal[0], ctx->normal[1], ctx->normal[2]};
    float len = sqrtf(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    n[0] /= len;
    n[1] /= len;
    n[2] /= len;
    /* Duff et al. 2017 orthonormal basis. */
    float sign = copysignf(1.0f, n[2]);
    float a = -1.0f / (sign + n[2]);
    float b = n[0] * n[1] * a;
    float t[3] = {1.0f + sign * n[0] * n[0] * a, sign * b, -sign * n[0]};
    float s[3] = {b, sign + n[1] * n[1] * a, -n[1]};
    float r = sqrtf(u0), phi = 2.0f * PI * u1;
    float z = sqrtf(fmaxf(1.0f - u0, 1e-6f));
    float x = r * cosf(phi), y = r * sinf(phi);
    for (int i = 0; i < 3; ++i)
        dir[i] = x * t[i] + y * s[i] + z * n[i];
    return z / PI;
}

static float custom_pdf(void *user, const nf_context *ctx, const float dir[3])
{
    (void)user;
    const float *n = ctx->normal;
    float nn = sqrtf(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    float dd = sqrtf(dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]);
    float c = (n[0] * dir[0] + n[1] * dir[1] + n[2] * dir[2]) / (nn * dd);
    return c > 0.0f ? c / PI : 0.0f;
}

/* ---- A spin-then-block barrier and a pool of persistent worker threads ------------------ */

typedef struct barrier {
    atomic_uint count;
    atomic_uint generation;
    unsigned parties;
    pthread_mutex_t mutex;
    pthread_cond_t cond;
} barrier;

static int barrier_init(barrier *b, unsigned parties)
{
    atomic_init(&b->count, 0u);
    atomic_init(&b->generation, 0u);
    b->parties = parties;
    if (pthread_mutex_init(&b->mutex, NULL) != 0)
        return -1;
    if (pthread_cond_init(&b->cond, NULL) != 0) {
        pthread_mutex_destroy(&b->mutex);
        return -1;
    }
    return 0;
}

static void barrier_destroy(barrier *b)
{
    pthread_cond_destroy(&b->cond);
    pthread_mutex_destroy(&b->mutex);
}

static void barrier_wait(barrier *b)
{
    unsigned gen = atomic_load_explicit(&b->generation, memory_order_acquire);
    if (atomic_fetch_add_explicit(&b->count, 1u, memory_order_acq_rel) + 1u == b->parties) {
        atomic_store_explicit(&b->count, 0u, memory_order_relaxed);
        pthread_mutex_lock(&b->mutex);
        atomic_fetch_add_explicit(&b->generation, 1u, memory_order_release);
        pthread_cond_broadcast(&b->cond);
        pthread_mutex_unlock(&b->mutex);
        return;
    }
    for (int spin = 0; spin < NFB_SPIN; ++spin) {
        if (atomic_load_explicit(&b->generation, memory_order_acquire) != gen)
            return;
        NFB_PAUSE();
    }
    pthread_mutex_lock(&b->mutex);
    while (atomic_load_explicit(&b->generation, memory_order_acquire) == gen)
        pthread_cond_wait(&b->cond, &b->mutex);
    pthread_mutex_unlock(&b->mutex);
}

typedef void (*job_fn)(void *arg, int thread);

typedef struct pool pool;

typedef struct pool_worker {
    pool *owner;
    int index;
} pool_worker;

struct pool {
    int threads; /* including the main thread, worker 0 */
    int started; /* pthreads actually running */
    pthread_t tid[NFB_MAX_THREADS];
    pool_worker worker[NFB_MAX_THREADS];
    barrier start, done;
    job_fn fn;
    void *arg;
    int quit;
};

static void *pool_main(void *p)
{
    pool_worker *w = (pool_worker *)p;
    pool *pl = w->owner;
    for (;;) {
        barrier_wait(&pl->start);
        if (pl->quit)
            break;
        pl->fn(pl->arg, w->index);
        barrier_wait(&pl->done);
    }
    return NULL;
}

/* The main thread joins as worker 0: the pool starts threads - 1 pthreads. */
static int pool_create(pool *pl, int threads)
{
    memset(pl, 0, sizeof *pl);
    pl->threads = threads;
    if (barrier_init(&pl->start, (unsigned)threads) != 0)
        return -1;
    if (barrier_init(&pl->done, (unsigned)threads) != 0) {
        barrier_destroy(&pl->start);
        return -1;
    }
    for (int i = 1; i < threads; ++i) {
        pl->worker[i].owner = pl;
        pl->worker[i].index = i;
        if (pthread_create(&pl->tid[i], NULL, pool_main, &pl->worker[i]) != 0) {
            /* Cannot release a partial pool with a full-size barrier: report and abort. */
            fprintf(stderr, "nf_bench: pthread_create failed\n");
            exit(EXIT_FAILURE);
        }
        pl->started++;
    }
    return 0;
}

static void pool_run(pool *pl, job_fn fn, void *arg)
{
    pl->fn = fn;
    pl->arg = arg;
    barrier_wait(&pl->start);
    fn(arg, 0);
    barrier_wait(&pl->done);
}

static void pool_destroy(pool *pl)
{
    if (pl->threads <= 1)
        return;
    pl->quit = 1;
    barrier_wait(&pl->start);
    for (int i = 1; i <= pl->started; ++i)
        pthread_join(pl->tid[i], NULL);
    barrier_destroy(&pl->start);
    barrier_destroy(&pl->done);
}

/* ---- Inputs ------------------------------------------------------------------------------ */

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
} bench_data;

static void data_free(bench_data *d)
{
    free(d->ctx);
    free(d->u);
    free(d->dir);
    free(d->light_dir);
    free(d->weight);
    free(d->out_dir);
    free(d->out_pdf);
    free(d->out_pdf2);
    free(d->points);
    memset(d, 0, sizeof *d);
}

static size_t data_bytes(const bench_data *d)
{
    return d->n * (sizeof(nf_context) + 14 * sizeof(float)) +
           NFB_POINT_RING * sizeof(nf_shading_point);
}

static int data_alloc(bench_data *d, size_t n, const nf_config *cfg)
{
    memset(d, 0, sizeof *d);
    d->n = n;
    d->ctx = (nf_context *)malloc(n * sizeof *d->ctx);
    d->u = (float *)malloc(2 * n * sizeof(float));
    d->dir = (float *)malloc(3 * n * sizeof(float));
    d->light_dir = (float *)malloc(3 * n * sizeof(float));
    d->weight = (float *)malloc(n * sizeof(float));
    d->out_dir = (float *)malloc(3 * n * sizeof(float));
    d->out_pdf = (float *)malloc(n * sizeof(float));
    d->out_pdf2 = (float *)malloc(n * sizeof(float));
    /* 64-byte aligned, as point.h advises; aligned_alloc needs a multiple of 64 bytes. */
    d->points = (nf_shading_point *)aligned_alloc(
        64, (NFB_POINT_RING * sizeof *d->points + 63u) / 64u * 64u);
    if (!d->ctx || !d->u || !d->dir || !d->light_dir || !d->weight || !d->out_dir ||
        !d->out_pdf || !d->out_pdf2 || !d->points) {
        data_free(d);
        return -1;
    }
    uint64_t rng = 0x5EEDF00Du;
    for (size_t i = 0; i < n; ++i) {
        nf_context *c = &d->ctx[i];
        for (int a = 0; a < 3; ++a) {
            float lo = cfg->bounds_min[a], hi = cfg->bounds_max[a];
            c->position[a] = lo + (hi - lo) * rng_float(&rng);
        }
        rng_unit_vector(&rng, c->normal);
        rng_unit_vector(&rng, c->wo);
        float cosine = c->normal[0] * c->wo[0] + c->normal[1] * c->wo[1] +
                       c->normal[2] * c->wo[2];
        if (cosine < 0.0f) /* wo on the normal's side, as at a real shading point */
            for (int a = 0; a < 3; ++a)
                c->wo[a] = -c->wo[a];
        d->u[2 * i] = rng_float(&rng);
        d->u[2 * i + 1] = rng_float(&rng);
        d->weight[i] = 0.05f + 2.0f * rng_float(&rng);
    }
    /* A stream of its own, so that the inputs above (and the figures of the batched ops) are
     * those of earlier versions of this program. */
    uint64_t rng_light = 0x11647D1Bu;
    for (size_t i = 0; i < n; ++i)
        rng_unit_vector(&rng_light, d->light_dir + 3 * i);
    return 0;
}

/* ---- Benchmark cases --------------------------------------------------------------------- */

typedef struct thread_result {
    nf_status status;
    const char *fn;
    char message[256];
    double weight_sum;
    char pad[64]; /* keep neighbours on separate cache lines */
} thread_result;

typedef struct bench_case {
    int op;
    size_t batch;
    int threads;
    const nf_model *model; /* sample, pdf */
    nf_model *train_model; /* train (a clone) */
    const bench_data *d;
    size_t cursor; /* index of the next unit of work */
    /* the current pool job */
    size_t first_unit, units, train_base;
    float *grad[NFB_MAX_THREADS];
    float *grad_sum;
    size_t param_count;
    thread_result res[NFB_MAX_THREADS];
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
    const char *dir_fn = op == OP_SAMPLE                            ? "nf_sample"
                         : op == OP_POINT_SAMPLE || op == OP_VERTEX ? "nf_point_sample"
                                                                     : NULL;
    const char *pdf_fn = op == OP_PDF ? "nf_pdf" : dir_fn;
    const char *pdf2_fn = op == OP_POINT_PDF || op == OP_VERTEX ? "nf_point_pdf" : NULL;
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
        } else if (pdf2_fn && !valid_density(d->out_pdf2[i])) {
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

/* Runs `units` units of work and returns their wall time in *seconds. */
static int run_units(bench_case *c, pool *pl, size_t units, double *seconds)
{
    const bench_data *d = c->d;
    double t0 = now_s();
    if (c->op != OP_TRAIN) {
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

/* ---- Measurement -------------------------------------------------------------------------- */

typedef struct options {
    int quick;
    int presets[2];
    int preset_count;
    int threads[2];
    int thread_count;
    int reps;
    double min_rep_s;
    nf_prior_kind prior;
    const char *prior_name;
    const char *json_path;
    const char *label;
    const char *markdown_path;
    int retries;
    double busy_threshold;
    long nproc;
    int op_mask;
    size_t batch; /* 0: every batch size; else only this one */
    nf_isa isa;   /* kernels to ask for (NF_ISA_AUTO: the library's choice) */
} options;

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

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

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

/* ---- The model ------------------------------------------------------------------------ */

typedef struct preset_info {
    const char *name;
    size_t params;
    size_t model_bytes;
    double flops_sparse;     /* forward FLOPs per sample, one-blob sparsity exploited */
    double flops_dense;      /* forward FLOPs per sample, dense input layer           */
    double flops_context;    /* the share of flops_sparse that nf_point_prepare does  */
    double shard_check;      /* check_sharding's relative difference                  */
    size_t point_checked;    /* check_points: inputs compared                         */
    size_t point_mismatches; /* check_points: inputs whose results differ             */
    const char *isa;         /* the kernel variant the model runs (nf_model_isa_name) */
    nf_config cfg;
} preset_info;

static const char *const PRESET_NAME[2] = {"small", "large"};

/* Multiply-adds of the conditioner MLPs, times 2. Per coupling layer: input layer
 * in * H (in = 3 + 9 one-blob non-zeros + 2 S^2 SH values exploiting sparsity, or the dense
 * 4 B + 2 S^2), hidden layers H^2 each, output layer H (3K + 1). Biases, activations,
 * encodings and splines are not counted. *context is the share of *sparse that depends on
 * the context alone (the input rows of the position's one-blobs and the SH values), which
 * nf_point_prepare does once per point; the rest is done per direction. */
static void model_flops(const nf_config *cfg, double *sparse, double *dense, double *context)
{
    double h = cfg->hidden_width, s2 = (double)cfg->sh_bands * cfg->sh_bands;
    double blob_nz = cfg->oneblob_bins < 3 ? cfg->oneblob_bins : 3;
    double in_sparse = 4.0 * blob_nz + 2.0 * s2;
    double in_dense = 4.0 * cfg->oneblob_bins + 2.0 * s2;
    double rest = (cfg->hidden_layers - 1.0) * h * h + h * (3.0 * cfg->spline_bins + 1.0);
    *sparse = 2.0 * cfg->coupling_layers * (in_sparse * h + rest);
    *dense = 2.0 * cfg->coupling_layers * (in_dense * h + rest);
    *context = 2.0 * cfg->coupling_layers * (3.0 * blob_nz + 2.0 * s2) * h;
}

static int report_status(nf_status st, const char *fn)
{
    if (st == NF_OK)
        return 0;
    fprintf(stderr, "nf_bench: %s failed: %s: %s\n", fn, nf_status_string(st),
            nf_last_error_message());
    return -1;
}

/* A model of the preset with randomized parameters. */
static int make_model(int preset, const options *o, counting_allocator *ca, preset_info *info,
                      nf_model **out)
{
    *out = NULL;
    nf_config cfg;
    nf_config_init(&cfg, preset == 0 ? NF_PRESET_SMALL : NF_PRESET_LARGE);
    cfg.prior = o->prior;
    cfg.isa = o->isa;
    if (o->prior == NF_PRIOR_CUSTOM) {
        cfg.custom_prior.sample = custom_sample;
        cfg.custom_prior.pdf = custom_pdf;
        cfg.custom_prior.user = NULL;
    }
    cfg.allocator.alloc = counting_alloc;
    cfg.allocator.free = counting_free;
    cfg.allocator.user = ca;
    size_t before = atomic_load(&ca->live);
    nf_model *m = NULL;
    if (report_status(nf_model_create(&cfg, &m), "nf_model_create") != 0)
        return -1;
    size_t p = nf_param_count(m);
    float *params = (float *)malloc(p * sizeof(float));
    if (!params) {
        fprintf(stderr, "nf_bench: out of memory\n");
        nf_model_destroy(m);
        return -1;
    }
    uint64_t rng = 0xC0FFEEu + (uint64_t)preset;
    int bad = report_status(nf_get_params(m, params), "nf_get_params");
    if (!bad) {
        for (size_t i = 0; i < p; ++i)
            params[i] += NFB_PARAM_NOISE * (2.0f * rng_float(&rng) - 1.0f);
        bad = report_status(nf_set_params(m, params), "nf_set_params");
    }
    free(params);
    if (bad) {
        nf_model_destroy(m);
        return -1;
    }
    info->name = PRESET_NAME[preset];
    info->params = p;
    info->model_bytes = atomic_load(&ca->live) - before;
    info->isa = nf_model_isa_name(m);
    info->cfg = cfg;
    model_flops(&cfg, &info->flops_sparse, &info->flops_dense, &info->flops_context);
    *out = m;
    return 0;
}

/* Checks the sharding recipe the 2-thread training uses: the gradient of a batch equals the
 * weight-sum-weighted mean of the gradients of its two halves. *rel receives
 * max |g - g_combined| / max |g|. */
static int check_sharding(const nf_model *m, const bench_data *d, size_t n, size_t p,
                          double *rel)
{
    float *g = (float *)malloc(3 * p * sizeof(float));
    if (!g) {
        fprintf(stderr, "nf_bench: out of memory\n");
        return -1;
    }
    float *g1 = g + p, *g2 = g + 2 * p;
    size_t h = n / 2;
    double f1 = 0.0, f2 = 0.0;
    for (size_t i = 0; i < h; ++i)
        f1 += d->weight[i];
    for (size_t i = h; i < n; ++i)
        f2 += d->weight[i];
    int bad = report_status(nf_loss_gradient(m, n, d->ctx, d->dir, d->weight, NULL, g),
                            "nf_loss_gradient") ||
              report_status(nf_loss_gradient(m, h, d->ctx, d->dir, d->weight, NULL, g1),
                            "nf_loss_gradient") ||
              report_status(nf_loss_gradient(m, n - h, d->ctx + h, d->dir + 3 * h,
                                             d->weight + h, NULL, g2),
                            "nf_loss_gradient");
    if (!bad) {
        double num = 0.0, den = 0.0;
        for (size_t i = 0; i < p; ++i) {
            double c = (f1 * g1[i] + f2 * g2[i]) / (f1 + f2);
            num = fmax(num, fabs(c - g[i]));
            den = fmax(den, fabs((double)g[i]));
        }
        *rel = den > 0.0 ? num / den : num;
    }
    free(g);
    return bad ? -1 : 0;
}

/* Checks the shading-point functions against the batched ones they must equal bit for bit
 * (point.h): for the first n inputs, nf_point_sample(u) against d->dir and d->out_pdf (which
 * the caller has just filled with nf_sample) and nf_point_pdf(light_dir) against nf_pdf.
 * A failed call is an error; *mismatches counts inputs whose results differ in any bit. */
static int check_points(const nf_model *m, bench_data *d, size_t n, size_t *mismatches)
{
    *mismatches = 0;
    if (report_status(nf_pdf(m, n, d->ctx, d->light_dir, d->out_pdf2), "nf_pdf") != 0)
        return -1;
    _Alignas(64) nf_shading_point sp;
    for (size_t i = 0; i < n; ++i) {
        float dir[3], pdf, pdf2;
        if (report_status(nf_point_prepare(m, d->ctx + i, NULL, &sp), "nf_point_prepare") ||
            report_status(nf_point_sample(m, &sp, 1, d->u + 2 * i, dir, &pdf),
                          "nf_point_sample") ||
            report_status(nf_point_pdf(m, &sp, 1, d->light_dir + 3 * i, &pdf2),
                          "nf_point_pdf"))
            return -1;
        if (memcmp(dir, d->dir + 3 * i, sizeof dir) != 0 ||
            memcmp(&pdf, d->out_pdf + i, sizeof pdf) != 0 ||
            memcmp(&pdf2, d->out_pdf2 + i, sizeof pdf2) != 0)
            ++*mismatches;
    }
    return 0;
}

/* Prepares the ring of points that point-sample and point-pdf use, outside any timing. */
static int prepare_ring(const nf_model *m, bench_data *d)
{
    for (size_t i = 0; i < NFB_POINT_RING; ++i)
        if (report_status(nf_point_prepare(m, d->ctx + i, NULL, &d->points[i]),
                          "nf_point_prepare") != 0)
            return -1;
    return 0;
}

/* ---- Output -------------------------------------------------------------------------- */

static void cpu_model(char *buf, size_t size)
{
    snprintf(buf, size, "unknown");
    FILE *f = fopen("/proc/cpuinfo", "r");
    if (!f)
        return;
    char line[512];
    while (fgets(line, sizeof line, f)) {
        if (strncmp(line, "model name", 10) == 0) {
            const char *v = strchr(line, ':');
            if (v) {
                v++;
                while (*v == ' ' || *v == '\t')
                    v++;
                snprintf(buf, size, "%s", v);
                size_t len = strlen(buf);
                while (len && (buf[len - 1] == '\n' || buf[len - 1] == '\r'))
                    buf[--len] = '\0';
            }
            break;
        }
    }
    fclose(f);
}

static void json_string(FILE *f, const char *s)
{
    fputc('"', f);
    for (; *s; ++s) {
        unsigned char ch = (unsigned char)*s;
        if (ch == '"' || ch == '\\')
            fprintf(f, "\\%c", ch);
        else if (ch < 0x20)
            fprintf(f, "\\u%04x", ch);
        else
            fputc(ch, f);
    }
    fputc('"', f);
}

/* FLOPs per sample (per call for the shading-point ops; per vertex for vertex). */
static double flops_of(const preset_info *pi, int op)
{
    double direction = pi->flops_sparse - pi->flops_context;
    switch (op) {
    case OP_TRAIN:
        return 3.0 * pi->flops_sparse;
    case OP_PREPARE:
        return pi->flops_context;
    case OP_POINT_SAMPLE:
    case OP_POINT_PDF:
        return direction;
    case OP_VERTEX:
        return pi->flops_context + 2.0 * direction;
    default:
        return pi->flops_sparse;
    }
}

static const result *find(const result *res, size_t count, int preset, int op, int threads,
                          size_t batch)
{
    for (size_t i = 0; i < count; ++i)
        if (res[i].preset == preset && res[i].op == op && res[i].threads == threads &&
            res[i].batch == batch && res[i].measured)
            return &res[i];
    return NULL;
}

typedef struct target {
    int preset;
    const char *what;
    double value, limit;
    int higher_is_better;
    int available;
} target;

#define NFB_MAX_TARGETS 32

/* The targets of docs/performance.md. Batched ops: small preset, batch 4096 (and the n = 1
 * streams against it). Shading points: per-call latencies of the small preset on 1 thread,
 * the vertex of the large preset, and the vertex's 2-thread scaling (small preset, as the
 * other scaling targets). */
static size_t eval_targets(const result *res, size_t count, target *t)
{
    size_t k = 0;
    static const char *const abs_name[OP_BATCHED_COUNT] = {
        "sample, 1 thread, batch 4096 (ns/sample)", "pdf, 1 thread, batch 4096 (ns/sample)",
        "train, 1 thread, batch 4096 (ns/sample)"};
    static const double abs_limit[OP_BATCHED_COUNT] = {150.0, 150.0, 600.0};
    static const char *const n1_name[OP_BATCHED_COUNT] = {
        "sample, n=1 / batch 4096 (1 thread)", "pdf, n=1 / batch 4096 (1 thread)",
        "train, n=1 / batch 4096 (1 thread)"};
    static const char *const sc_name[OP_BATCHED_COUNT] = {
        "sample, 2 threads / 1 thread, batch 4096", "pdf, 2 threads / 1 thread, batch 4096",
        "train, 2 threads / 1 thread, batch 4096"};
    static const double sc_limit[OP_BATCHED_COUNT] = {1.8, 1.8, 1.6};
    for (int op = 0; op < OP_BATCHED_COUNT; ++op) {
        const result *b = find(res, count, 0, op, 1, 4096);
        t[k++] = (target){0, abs_name[op], b ? b->ns_median : 0.0, abs_limit[op], 0, b != NULL};
    }
    for (int op = 0; op < OP_BATCHED_COUNT; ++op) {
        const result *b = find(res, count, 0, op, 1, 4096);
        const result *s = find(res, count, 0, op, 1, 1);
        t[k++] = (target){0, n1_name[op], b && s ? s->ns_median / b->ns_median : 0.0, 2.0, 0,
                          b && s};
    }
    for (int op = 0; op < OP_BATCHED_COUNT; ++op) {
        const result *b = find(res, count, 0, op, 1, 4096);
        const result *s = find(res, count, 0, op, 2, 4096);
        t[k++] = (target){0, sc_name[op], b && s ? b->ns_median / s->ns_median : 0.0,
                          sc_limit[op], 1, b && s};
    }
    /* The shading-point ops are stored with batch 1 (n = 1 per call). */
    static const struct {
        int preset, op;
        const char *what;
        double limit;
    } point_abs[] = {
        {0, OP_PREPARE, "prepare, 1 thread (ns/call)", 100.0},
        {0, OP_POINT_SAMPLE, "point-sample, 1 thread (ns/call)", 70.0},
        {0, OP_POINT_PDF, "point-pdf, 1 thread (ns/call)", 60.0},
        {0, OP_VERTEX, "vertex, 1 thread (ns/vertex)", 220.0},
        {1, OP_VERTEX, "vertex, 1 thread (ns/vertex)", 600.0},
    };
    for (size_t i = 0; i < sizeof point_abs / sizeof point_abs[0]; ++i) {
        const result *r = find(res, count, point_abs[i].preset, point_abs[i].op, 1, 1);
        t[k++] = (target){point_abs[i].preset, point_abs[i].what, r ? r->ns_median : 0.0,
                          point_abs[i].limit, 0, r != NULL};
    }
    const result *v1 = find(res, count, 0, OP_VERTEX, 1, 1);
    const result *v2 = find(res, count, 0, OP_VERTEX, 2, 1);
    t[k++] = (target){0, "vertex, 2 threads / 1 thread",
                      v1 && v2 ? v1->ns_median / v2->ns_median : 0.0, 1.8, 1, v1 && v2};
    return k;
}

static int target_met(const target *t)
{
    return t->higher_is_better ? t->value >= t->limit : t->value <= t->limit;
}

/* The thread columns of a table's header: ns (per `unit`) and GFLOP/s per thread count,
 * then the 2T/1T scaling, and the Markdown separator row after `lead` ("|---|..." of the
 * leading columns). */
static void print_thread_header(FILE *f, int md, const options *o, const char *unit,
                                int has_scaling, const char *lead)
{
    for (int ti = 0; ti < o->thread_count; ++ti) {
        char h1[32], h2[32];
        snprintf(h1, sizeof h1, "%s %dT", unit, o->threads[ti]);
        snprintf(h2, sizeof h2, "GFLOP/s %dT", o->threads[ti]);
        if (md)
            fprintf(f, " | %s | %s", h1, h2);
        else
            fprintf(f, " | %11s %10s", h1, h2);
    }
    if (has_scaling)
        fprintf(f, md ? " | %s" : " | %5s", "2T/1T");
    fprintf(f, md ? " |\n" : "\n");
    if (md) {
        fprintf(f, "%s", lead);
        for (int ti = 0; ti < o->thread_count; ++ti)
            fprintf(f, "--:|--:|");
        fprintf(f, has_scaling ? "--:|\n" : "\n");
    }
}

/* The thread columns of one row (preset, op, batch), ending the line; *marked is set when a
 * figure is flagged as disturbed. */
static void print_thread_cells(FILE *f, int md, const options *o, const preset_info *info,
                               const result *res, size_t count, int preset, int op,
                               size_t batch, int has_scaling, int *marked)
{
    const result *r1 = NULL, *r2 = NULL;
    for (int ti = 0; ti < o->thread_count; ++ti) {
        const result *r = find(res, count, preset, op, o->threads[ti], batch);
        if (ti == 0)
            r1 = r;
        else
            r2 = r;
        if (r) {
            int busy = r->disturbed;
            double gf = flops_of(&info[preset], op) / r->ns_median;
            if (md)
                fprintf(f, " | %.1f%s | %.2f", r->ns_median, busy ? "\\*" : "", gf);
            else
                fprintf(f, " | %10.1f%c %10.2f", r->ns_median, busy ? '*' : ' ', gf);
            *marked |= busy;
        } else {
            fprintf(f, md ? " | n/a | n/a" : " | %11s %10s", "n/a", "n/a");
        }
    }
    if (has_scaling) {
        if (r1 && r2)
            fprintf(f, md ? " | %.2fx" : " | %4.2fx", r1->ns_median / r2->ns_median);
        else
            fprintf(f, md ? " | n/a" : " | %5s", "n/a");
    }
    fprintf(f, md ? " |\n" : "\n");
}

/* The results: plain text (md = 0) or Markdown (md = 1) for docs/performance.md. Two
 * tables: the batched ops, a row per batch size; then the shading-point ops, per-call
 * latencies with no batch size, a row per op. Each is printed when --op selected any of its
 * ops. */
static void print_table(FILE *f, int md, const options *o, const preset_info *info,
                        const size_t *batches, size_t batch_count, const result *res,
                        size_t count)
{
    int has_scaling = o->thread_count == 2 && o->threads[0] == 1;
    int marked = 0;
    if (o->op_mask & OP_MASK_BATCHED) {
        if (md)
            fprintf(f, "| preset | op | batch");
        else
            fprintf(f, "%-6s %-6s %6s", "preset", "op", "batch");
        print_thread_header(f, md, o, "ns/smp", has_scaling, "|---|---|--:|");
        for (int pi = 0; pi < o->preset_count; ++pi) {
            int preset = o->presets[pi];
            for (int op = 0; op < OP_BATCHED_COUNT; ++op) {
                if (!(o->op_mask & (1 << op)))
                    continue;
                for (size_t bi = 0; bi < batch_count; ++bi) {
                    if (md)
                        fprintf(f, "| %s | %s | %zu", PRESET_NAME[preset], OP_NAME[op],
                                batches[bi]);
                    else
                        fprintf(f, "%-6s %-6s %6zu", PRESET_NAME[preset], OP_NAME[op],
                                batches[bi]);
                    print_thread_cells(f, md, o, info, res, count, preset, op, batches[bi],
                                       has_scaling, &marked);
                }
            }
        }
    }
    if (o->op_mask & OP_MASK_POINT) {
        if (o->op_mask & OP_MASK_BATCHED)
            fprintf(f, "\n");
        if (md)
            fprintf(f, "Shading points (`nf_point_*`, one call with n = 1 each, ns per call; "
                       "`vertex` = `nf_point_prepare` + `nf_point_sample` + `nf_point_pdf` of "
                       "another direction, ns per vertex):\n\n| preset | op");
        else
            fprintf(f, "shading points (n = 1 per call, ns per call; vertex = prepare + "
                       "point-sample + point-pdf of another direction, ns per vertex):\n"
                       "%-6s %-12s",
                    "preset", "op");
        print_thread_header(f, md, o, "ns/call", has_scaling, "|---|---|");
        for (int pi = 0; pi < o->preset_count; ++pi) {
            int preset = o->presets[pi];
            for (int op = OP_BATCHED_COUNT; op < OP_COUNT; ++op) {
                if (!(o->op_mask & (1 << op)))
                    continue;
                if (md)
                    fprintf(f, "| %s | %s", PRESET_NAME[preset], OP_NAME[op]);
                else
                    fprintf(f, "%-6s %-12s", PRESET_NAME[preset], OP_NAME[op]);
                print_thread_cells(f, md, o, info, res, count, preset, op, 1, has_scaling,
                                   &marked);
            }
        }
    }
    if (marked)
        fprintf(f,
                "%s disturbed: other processes used more than the idle CPUs + %.1f during this "
                "measurement (the quietest of up to %d attempts); an upper bound\n",
                md ? "\n\\*" : "*", o->busy_threshold, o->retries + 1);
}

static int write_json(const options *o, const char *cpu, long nproc, const preset_info *info,
                      const result *res, size_t count, const target *t, size_t tcount,
                      long rss_kib, double wall_s, double other_load)
{
    FILE *f = fopen(o->json_path, "w");
    if (!f) {
        fprintf(stderr, "nf_bench: cannot write %s\n", o->json_path);
        return -1;
    }
    fprintf(f, "{\n  \"library_version\": ");
    json_string(f, nf_version_string());
    fprintf(f, ",\n  \"label\": ");
    json_string(f, o->label ? o->label : "");
    fprintf(f, ",\n  \"cpu\": ");
    json_string(f, cpu);
    fprintf(f, ",\n  \"online_cpus\": %ld,\n  \"prior\": ", nproc);
    json_string(f, o->prior_name);
    fprintf(f,
            ",\n  \"quick\": %s,\n  \"reps\": %d,\n  \"min_rep_ms\": %.1f,\n"
            "  \"batch1_stream_calls\": %u,\n"
            "  \"flop_count\": \"2 * multiply-adds of the conditioner MLPs, input layer with "
            "one-blob sparsity exploited; training = 3 x forward; prepare = the context's "
            "share of the input layers, point-sample and point-pdf = the rest, vertex = "
            "prepare + 2 directions\",\n"
            "  \"point_ops\": \"prepare, point-sample, point-pdf and vertex are calls with "
            "n = 1 (batch 1); ns_per_sample is per call, for vertex per guided vertex "
            "(nf_point_prepare + nf_point_sample + nf_point_pdf)\",\n"
            "  \"presets\": [",
            o->quick ? "true" : "false", o->reps, o->min_rep_s * 1e3, NFB_STREAM);
    for (int pi = 0; pi < o->preset_count; ++pi) {
        const preset_info *p = &info[o->presets[pi]];
        fprintf(f,
                "%s\n    {\"name\": \"%s\", \"coupling_layers\": %u, \"spline_bins\": %u, "
                "\"hidden_layers\": %u, \"hidden_width\": %u, \"params\": %zu, "
                "\"model_bytes\": %zu, \"forward_flops_sparse\": %.0f, "
                "\"forward_flops_dense\": %.0f, \"train_flops\": %.0f, "
                "\"prepare_flops\": %.0f, \"point_direction_flops\": %.0f, "
                "\"sharded_gradient_rel_diff\": %.2e, \"point_check_inputs\": %zu, "
                "\"point_check_mismatches\": %zu, \"kernels\": \"%s\"}",
                pi ? "," : "", p->name, p->cfg.coupling_layers, p->cfg.spline_bins,
                p->cfg.hidden_layers, p->cfg.hidden_width, p->params, p->model_bytes,
                p->flops_sparse, p->flops_dense, 3.0 * p->flops_sparse,
                flops_of(p, OP_PREPARE), flops_of(p, OP_POINT_SAMPLE), p->shard_check,
                p->point_checked, p->point_mismatches, p->isa);
    }
    fprintf(f, "\n  ],\n  \"results\": [");
    int first = 1;
    for (size_t i = 0; i < count; ++i) {
        const result *r = &res[i];
        fprintf(f, "%s\n    {\"preset\": \"%s\", \"op\": \"%s\", \"threads\": %d, \"batch\": %zu",
                first ? "" : ",", PRESET_NAME[r->preset], OP_NAME[r->op], r->threads,
                r->batch);
        first = 0;
        if (!r->measured) {
            fprintf(f, ", \"ns_per_sample\": null, \"note\": \"not applicable\"}");
            continue;
        }
        double fl = flops_of(&info[r->preset], r->op);
        fprintf(f,
                ", \"ns_per_sample\": %.3f, \"ns_min\": %.3f, \"ns_max\": %.3f, "
                "\"samples_per_second\": %.1f, \"gflops\": %.3f, \"reps\": %d, "
                "\"samples_per_rep\": %zu, \"other_load_cpus\": %.3f, \"disturbed\": %s, "
                "\"attempts\": %d}",
                r->ns_median, r->ns_min, r->ns_max, 1e9 / r->ns_median, fl / r->ns_median,
                r->reps, r->samples_per_rep, r->foreign_cpus, r->disturbed ? "true" : "false",
                r->attempts);
    }
    fprintf(f, "\n  ],\n  \"targets\": [");
    first = 1;
    for (size_t i = 0; i < tcount; ++i) {
        if (!t[i].available)
            continue;
        fprintf(f, "%s\n    {\"preset\": \"%s\", \"what\": ", first ? "" : ",",
                PRESET_NAME[t[i].preset]);
        first = 0;
        json_string(f, t[i].what);
        fprintf(f, ", \"value\": %.3f, \"limit\": \"%s %.2f\", \"met\": %s}", t[i].value,
                t[i].higher_is_better ? ">=" : "<=", t[i].limit,
                target_met(&t[i]) ? "true" : "false");
    }
    fprintf(f,
            "\n  ],\n  \"peak_rss_kib\": %ld,\n  \"wall_seconds\": %.1f,\n"
            "  \"other_load_cpus\": %.3f\n}\n",
            rss_kib, wall_s, other_load);
    if (fclose(f) != 0) {
        fprintf(stderr, "nf_bench: error writing %s\n", o->json_path);
        return -1;
    }
    return 0;
}

/* ---- Command line ------------------------------------------------------------------------ */

static void usage(FILE *f)
{
    fprintf(f,
            "usage: nf_bench [options]\n"
            "  --preset small|large|all   presets to measure (default all)\n"
            "  --threads 1|2|all|N        thread counts (default all = 1 and 2)\n"
            "  --op LIST                  operations to measure, comma-separated (default\n"
            "                             all): sample, pdf, train; the shading-point ops\n"
            "                             prepare, point-sample, point-pdf, vertex; point\n"
            "                             (those four); all\n"
            "  --reps N                   timed repetitions, median reported (default 7)\n"
            "  --min-rep-ms X             minimum length of one repetition (default 50)\n"
            "  --prior NAME               cosine (default), uniform-direction,\n"
            "                             uniform-angle, or custom (a cosine lobe given as\n"
            "                             callbacks)\n"
            "  --json FILE                write the results as JSON (default bench.json)\n"
            "  --markdown FILE            also write the table as Markdown\n"
            "  --label TEXT               a free-form label stored in the JSON and printed\n"
            "  --retries N                re-measure a case up to N times when other\n"
            "                             processes disturbed it (default 2)\n"
            "  --batch 1|64|4096|65536    measure only this batch size of sample, pdf and\n"
            "                             train (for profiling; the shading-point ops have\n"
            "                             none: select them or not with --op)\n"
            "  --isa auto|generic|avx2|avx512\n"
            "                             kernels to use (default auto, the library's choice)\n"
            "  --quick                    smoke run: batches 1, 64, 4096; 3 reps of >= 5 ms\n"
            "  --help                     this text\n"
            "Batch sizes 1, 64, 4096, 65536. Batch 1 is streams of calls with n = 1, in units\n"
            "of %u calls. The shading-point ops are such streams too, timed per call:\n"
            "prepare (nf_point_prepare on a new context), point-sample and point-pdf (one\n"
            "direction at a prepared point), vertex (prepare + point-sample + point-pdf of\n"
            "another direction, per vertex).\n",
            NFB_STREAM);
}

static int parse_int(const char *s, int lo, int hi, int *out)
{
    char *end;
    long v = strtol(s, &end, 10);
    if (end == s || *end != '\0' || v < lo || v > hi)
        return -1;
    *out = (int)v;
    return 0;
}

/* --op: a comma-separated list of op names, "point" (the four shading-point ops) or "all". */
static int parse_ops(const char *list, int *mask)
{
    int m = 0;
    const char *s = list;
    for (;;) {
        size_t len = strcspn(s, ",");
        int found = 0;
        if (len == 3 && strncmp(s, "all", len) == 0) {
            m |= OP_MASK_ALL;
            found = 1;
        } else if (len == 5 && strncmp(s, "point", len) == 0) {
            m |= OP_MASK_POINT;
            found = 1;
        }
        for (int op = 0; op < OP_COUNT && !found; ++op) {
            if (strlen(OP_NAME[op]) == len && strncmp(s, OP_NAME[op], len) == 0) {
                m |= 1 << op;
                found = 1;
            }
        }
        if (!found)
            return -1; /* also an empty name: "", "a,,b", "a," */
        if (s[len] == '\0')
            break;
        s += len + 1;
    }
    *mask = m;
    return 0;
}

static int parse_args(int argc, char **argv, options *o)
{
    memset(o, 0, sizeof *o);
    o->presets[0] = 0;
    o->presets[1] = 1;
    o->preset_count = 2;
    o->threads[0] = 1;
    o->threads[1] = 2;
    o->thread_count = 2;
    o->reps = -1;
    o->min_rep_s = -1.0;
    o->prior = NF_PRIOR_COSINE;
    o->prior_name = "cosine";
    o->json_path = "bench.json";
    o->retries = 2;
    o->busy_threshold = 0.2;
    o->op_mask = OP_MASK_ALL;
    for (int i = 1; i < argc; ++i) {
        const char *a = argv[i];
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) {
            usage(stdout);
            exit(EXIT_SUCCESS);
        } else if (strcmp(a, "--quick") == 0) {
            o->quick = 1;
            continue;
        }
        if (!v) {
            fprintf(stderr, "nf_bench: unknown option or missing value: %s\n", a);
            return -1;
        }
        ++i;
        if (strcmp(a, "--preset") == 0) {
            if (strcmp(v, "small") == 0) {
                o->presets[0] = 0;
                o->preset_count = 1;
            } else if (strcmp(v, "large") == 0) {
                o->presets[0] = 1;
                o->preset_count = 1;
            } else if (strcmp(v, "all") == 0) {
                o->preset_count = 2;
            } else {
                fprintf(stderr, "nf_bench: --preset takes small, large or all\n");
                return -1;
            }
        } else if (strcmp(a, "--threads") == 0) {
            int n;
            if (strcmp(v, "all") == 0) {
                o->threads[0] = 1;
                o->threads[1] = 2;
                o->thread_count = 2;
            } else if (parse_int(v, 1, NFB_MAX_THREADS, &n) == 0) {
                o->threads[0] = n;
                o->thread_count = 1;
            } else {
                fprintf(stderr, "nf_bench: --threads takes 1, 2, all or N in [1, %d]\n",
                        NFB_MAX_THREADS);
                return -1;
            }
        } else if (strcmp(a, "--reps") == 0) {
            if (parse_int(v, 1, 64, &o->reps) != 0) {
                fprintf(stderr, "nf_bench: --reps takes an integer in [1, 64]\n");
                return -1;
            }
        } else if (strcmp(a, "--min-rep-ms") == 0) {
            char *end;
            double ms = strtod(v, &end);
            if (end == v || *end != '\0' || !(ms > 0.0) || ms > 60000.0) {
                fprintf(stderr, "nf_bench: --min-rep-ms takes a number in (0, 60000]\n");
                return -1;
            }
            o->min_rep_s = ms * 1e-3;
        } else if (strcmp(a, "--prior") == 0) {
            if (strcmp(v, "cosine") == 0)
                o->prior = NF_PRIOR_COSINE;
            else if (strcmp(v, "uniform-direction") == 0)
                o->prior = NF_PRIOR_UNIFORM_DIRECTION;
            else if (strcmp(v, "uniform-angle") == 0)
                o->prior = NF_PRIOR_UNIFORM_ANGLE;
            else if (strcmp(v, "custom") == 0)
                o->prior = NF_PRIOR_CUSTOM;
            else {
                fprintf(stderr, "nf_bench: unknown prior %s\n", v);
                return -1;
            }
            o->prior_name = v;
        } else if (strcmp(a, "--op") == 0) {
            if (parse_ops(v, &o->op_mask) != 0) {
                fprintf(stderr, "nf_bench: --op takes a comma-separated list of sample, pdf, "
                                "train, prepare, point-sample, point-pdf, vertex, point, all\n");
                return -1;
            }
        } else if (strcmp(a, "--isa") == 0) {
            if (strcmp(v, "auto") == 0)
                o->isa = NF_ISA_AUTO;
            else if (strcmp(v, "generic") == 0)
                o->isa = NF_ISA_GENERIC;
            else if (strcmp(v, "avx2") == 0)
                o->isa = NF_ISA_AVX2;
            else if (strcmp(v, "avx512") == 0)
                o->isa = NF_ISA_AVX512;
            else {
                fprintf(stderr, "nf_bench: --isa takes auto, generic, avx2 or avx512\n");
                return -1;
            }
        } else if (strcmp(a, "--batch") == 0) {
            int n;
            if (parse_int(v, 1, 65536, &n) != 0 || (n != 1 && n != 64 && n != 4096 && n != 65536)) {
                fprintf(stderr, "nf_bench: --batch takes 1, 64, 4096 or 65536\n");
                return -1;
            }
            o->batch = (size_t)n;
        } else if (strcmp(a, "--retries") == 0) {
            if (parse_int(v, 0, 10, &o->retries) != 0) {
                fprintf(stderr, "nf_bench: --retries takes an integer in [0, 10]\n");
                return -1;
            }
        } else if (strcmp(a, "--json") == 0) {
            o->json_path = v;
        } else if (strcmp(a, "--markdown") == 0) {
            o->markdown_path = v;
        } else if (strcmp(a, "--label") == 0) {
            o->label = v;
        } else {
            fprintf(stderr, "nf_bench: unknown option %s\n", a);
            return -1;
        }
    }
    if (o->reps < 0)
        o->reps = o->quick ? 3 : 7;
    if (o->min_rep_s < 0.0)
        o->min_rep_s = o->quick ? 5e-3 : 50e-3;
    return 0;
}

/* ---- One case -------------------------------------------------------------------------- */

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
    clear_outputs(e->d);
    /* Re-measure when other processes were busy; keep the quietest. */
    result best = *r;
    int bad = 0, have = 0, attempt = 0;
    for (; attempt <= o->retries; ++attempt) {
        result cur = *r;
        cpu_snapshot before, after;
        cpu_snap(&before);
        bad = measure(&c, threads > 1 ? e->pl : NULL, o, &cur);
        cpu_snap(&after);
        if (bad)
            break;
        cur.foreign_cpus = foreign_load(&before, &after);
        double idle = (double)(o->nproc > threads ? o->nproc - threads : 0);
        cur.disturbed = cur.foreign_cpus > idle + o->busy_threshold;
        if (!have || cur.foreign_cpus < best.foreign_cpus)
            best = cur;
        have = 1;
        if (!cur.disturbed)
            break;
    }
    nf_model_destroy(train_model);
    if (bad || check_outputs(&c, name) != 0)
        return -1;
    best.attempts = attempt <= o->retries ? attempt + 1 : attempt;
    *r = best;
    /* What one "sample" of the figure is: a call of n = 1, or a vertex of three calls. */
    const char *unit = op == OP_VERTEX ? "vertex" : op_is_point(op) ? "call" : "sample";
    const char *units = op == OP_VERTEX ? "vertices" : op_is_point(op) ? "calls" : "samples";
    fprintf(stderr,
            "%s: %9.1f ns/%s (min %.1f, max %.1f; %d reps x %zu %s; other load %.2f CPUs; "
            "attempts %d)%s\n",
            label, r->ns_median, unit, r->ns_min, r->ns_max, r->reps, r->samples_per_rep,
            units, r->foreign_cpus, r->attempts, r->disturbed ? " disturbed" : "");
    return 0;
}

/* ---- main ----------------------------------------------------------------------------- */

int main(int argc, char **argv)
{
    options o;
    if (parse_args(argc, argv, &o) != 0) {
        usage(stderr);
        return EXIT_FAILURE;
    }
    double t_start = now_s();
    cpu_snapshot run_start;
    cpu_snap(&run_start);
    size_t all_batches[] = {1, 64, 4096, 65536};
    size_t batch_count = o.quick ? 3 : 4;
    if (o.batch) {
        all_batches[0] = o.batch;
        batch_count = 1;
    }
    int max_threads = 1;
    for (int i = 0; i < o.thread_count; ++i)
        if (o.threads[i] > max_threads)
            max_threads = o.threads[i];

    char cpu[256];
    cpu_model(cpu, sizeof cpu);
    long nproc = sysconf(_SC_NPROCESSORS_ONLN);
    o.nproc = nproc > 0 ? nproc : 1;
    printf("libnisflow %s benchmark%s%s\n", nf_version_string(), o.label ? ": " : "",
           o.label ? o.label : "");
    printf("cpu: %s, %ld online CPUs; prior %s; median of %d reps, each >= %.0f ms%s\n", cpu,
           nproc, o.prior_name, o.reps, o.min_rep_s * 1e3, o.quick ? " (quick)" : "");
    fflush(stdout);

    int rc = EXIT_FAILURE;
    counting_allocator ca;
    atomic_init(&ca.live, 0);
    atomic_init(&ca.peak, 0);
    preset_info info[2];
    memset(info, 0, sizeof info);
    result *res = (result *)calloc(NFB_MAX_RESULTS, sizeof *res);
    size_t res_count = 0;
    bench_data data;
    memset(&data, 0, sizeof data);
    nf_model *model = NULL;
    float *grad[NFB_MAX_THREADS] = {NULL};
    float *grad_sum = NULL;
    pool pl;
    memset(&pl, 0, sizeof pl);
    int pool_ok = 0;
    target targets[NFB_MAX_TARGETS];
    size_t target_count = 0;

    if (!res) {
        fprintf(stderr, "nf_bench: out of memory\n");
        goto done;
    }
    {
        nf_config cfg;
        nf_config_init(&cfg, NF_PRESET_SMALL); /* bounds are the same for both presets */
        size_t n = o.quick ? 4096u : NFB_POOL;
        if (data_alloc(&data, n, &cfg) != 0) {
            fprintf(stderr, "nf_bench: out of memory for %zu inputs\n", n);
            goto done;
        }
    }
    if (max_threads > 1) {
        if (pool_create(&pl, max_threads) != 0) {
            fprintf(stderr, "nf_bench: cannot create the thread pool\n");
            goto done;
        }
        pool_ok = 1;
    }

    for (int pi = 0; pi < o.preset_count; ++pi) {
        int preset = o.presets[pi];
        preset_info *inf = &info[preset];
        if (make_model(preset, &o, &ca, inf, &model) != 0)
            goto done;
        printf("\npreset %s: %u coupling layers, %u bins, %u x %u hidden; %zu params, model "
               "%.1f KiB; %s kernels;\n  forward FLOP/sample %.0f (one-blob sparse input) / "
               "%.0f (dense); training counted as 3x forward = %.0f\n",
               inf->name, inf->cfg.coupling_layers, inf->cfg.spline_bins,
               inf->cfg.hidden_layers, inf->cfg.hidden_width, inf->params,
               inf->model_bytes / 1024.0, inf->isa, inf->flops_sparse, inf->flops_dense,
               3.0 * inf->flops_sparse);
        fflush(stdout);
        /* Directions for pdf and training: the model's own samples. */
        if (report_status(nf_sample(model, data.n, data.ctx, data.u, data.dir, data.out_pdf),
                          "nf_sample") != 0)
            goto done;
        size_t p = inf->params;
        double shard_rel = 0.0;
        if (check_sharding(model, &data, 4096, p, &shard_rel) != 0)
            goto done;
        printf("  sharded gradient check (2 halves of 4096 samples vs the whole batch): max "
               "relative difference %.1e%s\n",
               shard_rel, shard_rel > 1e-4 ? "  WARNING: larger than 1e-4" : "");
        inf->shard_check = shard_rel;
        if (o.op_mask & OP_MASK_POINT) {
            /* data.dir and data.out_pdf still hold the nf_sample results of above. */
            inf->point_checked = data.n < 4096 ? data.n : 4096;
            if (check_points(model, &data, inf->point_checked, &inf->point_mismatches) != 0)
                goto done;
            if (inf->point_mismatches)
                printf("  shading-point check: WARNING: nf_point_sample / nf_point_pdf differ "
                       "from nf_sample / nf_pdf on %zu of %zu inputs\n",
                       inf->point_mismatches, inf->point_checked);
            else
                printf("  shading-point check (nf_point_sample / nf_point_pdf vs nf_sample / "
                       "nf_pdf, %zu inputs): bit-identical\n",
                       inf->point_checked);
        }
        fflush(stdout);
        for (int k = 0; k < max_threads; ++k) {
            free(grad[k]);
            grad[k] = (float *)aligned_alloc(64, ((p * sizeof(float) + 63u) / 64u) * 64u);
        }
        free(grad_sum);
        grad_sum = (float *)aligned_alloc(64, ((p * sizeof(float) + 63u) / 64u) * 64u);
        int grads_ok = grad_sum != NULL;
        for (int k = 0; k < max_threads; ++k)
            grads_ok &= grad[k] != NULL;
        if (!grads_ok) {
            fprintf(stderr, "nf_bench: out of memory for gradients\n");
            goto done;
        }

        case_env env = {&o, max_threads > 1 ? &pl : NULL, &data, model, preset, inf, grad,
                        grad_sum};
        for (int op = 0; op < OP_BATCHED_COUNT; ++op) {
            if (!(o.op_mask & (1 << op)))
                continue;
            for (size_t bi = 0; bi < batch_count; ++bi) {
                for (int ti = 0; ti < o.thread_count; ++ti) {
                    if (res_count == NFB_MAX_RESULTS)
                        goto done;
                    if (run_case(&env, op, all_batches[bi], o.threads[ti], &res[res_count++]))
                        goto done;
                }
            }
        }
        if (o.op_mask & OP_MASK_POINT) {
            /* The model is not changed by the cases (training uses a clone), so the ring
             * stays valid for all of them. */
            if (prepare_ring(model, &data) != 0)
                goto done;
            /* Per-call ops: batch 1 (n = 1) in the results. */
            for (int op = OP_BATCHED_COUNT; op < OP_COUNT; ++op) {
                if (!(o.op_mask & (1 << op)))
                    continue;
                for (int ti = 0; ti < o.thread_count; ++ti) {
                    if (res_count == NFB_MAX_RESULTS)
                        goto done;
                    if (run_case(&env, op, 1, o.threads[ti], &res[res_count++]))
                        goto done;
                }
            }
        }
        nf_model_destroy(model);
        model = NULL;
    }

    {
        long rss = peak_rss_kib();
        double wall = now_s() - t_start;
        cpu_snapshot run_end;
        cpu_snap(&run_end);
        double other = foreign_load(&run_start, &run_end);
        printf("\n");
        print_table(stdout, 0, &o, info, all_batches, batch_count, res, res_count);
        if (o.markdown_path) {
            FILE *md = fopen(o.markdown_path, "w");
            if (!md) {
                fprintf(stderr, "nf_bench: cannot write %s\n", o.markdown_path);
                goto done;
            }
            print_table(md, 1, &o, info, all_batches, batch_count, res, res_count);
            if (fclose(md) != 0) {
                fprintf(stderr, "nf_bench: error writing %s\n", o.markdown_path);
                goto done;
            }
        }
        target_count = eval_targets(res, res_count, targets);
        int any = 0;
        for (size_t i = 0; i < target_count; ++i)
            any |= targets[i].available;
        if (any) {
            printf("\ntargets (docs/performance.md):\n");
            for (size_t i = 0; i < target_count; ++i) {
                const target *t = &targets[i];
                if (!t->available)
                    continue;
                printf("  %-5s %-44s %9.2f  %s %6.2f  %s\n", PRESET_NAME[t->preset], t->what,
                       t->value, t->higher_is_better ? ">=" : "<=", t->limit,
                       target_met(t) ? "met" : "MISSED");
            }
        }
        printf("\npeak RSS %.1f MiB (bench inputs %.1f MiB, models at most %.1f KiB live); "
               "wall time %.1f s\n",
               rss / 1024.0,
               (double)data_bytes(&data) / (1024.0 * 1024.0),
               atomic_load(&ca.peak) / 1024.0, wall);
        if (other >= 0.0)
            printf("other processes kept %.2f of %ld CPUs busy on average during the run%s\n",
                   other, nproc, other >= o.busy_threshold ? " (the machine was not idle)" : "");
        if (write_json(&o, cpu, nproc, info, res, res_count, targets, target_count, rss,
                       wall, other) != 0)
            goto done;
        printf("results written to %s\n", o.json_path);
    }
    rc = EXIT_SUCCESS;

done:
    nf_model_destroy(model);
    if (pool_ok)
        pool_destroy(&pl);
    for (int k = 0; k < NFB_MAX_THREADS; ++k)
        free(grad[k]);
    free(grad_sum);
    data_free(&data);
    free(res);
    if (rc == EXIT_SUCCESS && atomic_load(&ca.live) != 0) {
        fprintf(stderr, "nf_bench: %zu bytes of model memory not freed\n",
                (size_t)atomic_load(&ca.live));
        rc = EXIT_FAILURE;
    }
    return rc;
}
