/*
 * harness.h - the measurement machinery of nf_bench that knows nothing of libnisflow: a
 * monotonic clock, snapshots of the CPU time other processes use, the peak memory, the CPU's
 * name, random numbers, an allocator that counts its bytes, and a pool of persistent worker
 * threads released by a spin-then-block barrier.
 *
 * It is kept apart from the benchmark cases (cases.h) so that what is generic about timing
 * code on an idle machine can be read, and trusted, on its own.
 */
#ifndef NF_BENCH_HARNESS_H
#define NF_BENCH_HARNESS_H

#include <pthread.h>
#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>

#define NFB_PI 3.14159265358979f
#define NFB_MAX_THREADS 64 /* the most threads a pool (and --threads) can have */

/* ---- Clock, memory, CPU ------------------------------------------------------------------ */

/* CLOCK_MONOTONIC in seconds. */
double now_s(void);

/* The peak resident set size of this process in KiB; -1 unknown. */
long peak_rss_kib(void);

/* The CPU's model name from /proc/cpuinfo into buf; "unknown" where there is none. */
void read_cpu_model(char *buf, size_t size);

/* CPU time used by other processes: /proc/stat's busy time of all CPUs minus this process's
 * own CPU time. The benchmark assumes an otherwise idle machine; this tells when it was not. */
typedef struct cpu_snapshot {
    int ok;
    double busy_s, own_s, wall_s;
} cpu_snapshot;

void take_cpu_snapshot(cpu_snapshot *s);

/* The average number of CPUs that other processes kept busy between a and b; -1 unknown. */
double foreign_cpu_load(const cpu_snapshot *a, const cpu_snapshot *b);

/* ---- Random numbers (splitmix64) --------------------------------------------------------- */

uint64_t rng_next(uint64_t *state);

/* Uniform in [0, 1). */
float rng_float(uint64_t *state);

/* Uniform on the unit sphere. */
void rng_unit_vector(uint64_t *state, float v[3]);

/* ---- A counting allocator ---------------------------------------------------------------- */

/* For the models (nf_allocator's alloc and free, with the allocator as user): 64-byte
 * aligned blocks with a size header, so that the bytes live now and at the peak are known.
 * Initialise both counters with atomic_init to 0. */
typedef struct counting_allocator {
    atomic_size_t live;
    atomic_size_t peak;
} counting_allocator;

void *counting_alloc(void *user, size_t size);
void counting_free(void *user, void *ptr);

/* ---- A pool of persistent worker threads ------------------------------------------------- */

/* Threads are created once and released per job by a barrier that spins before it blocks,
 * so that neither thread creation nor a wake-up from sleep is inside a timed region. */
typedef struct barrier {
    atomic_uint count;
    atomic_uint generation;
    unsigned parties;
    pthread_mutex_t mutex;
    pthread_cond_t cond;
} barrier;

/* A job: what `thread` (0 .. threads - 1) does with the shared `arg`. */
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

/* The main thread joins as worker 0: the pool starts threads - 1 pthreads. A failed
 * pthread_create ends the program (a partial pool cannot be released). */
int pool_create(pool *pl, int threads);

/* Runs fn(arg, k) on every worker k, the main thread included, and returns when all are
 * done. */
void pool_run(pool *pl, job_fn fn, void *arg);

void pool_destroy(pool *pl);

#endif /* NF_BENCH_HARNESS_H */
