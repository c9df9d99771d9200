/*
 * harness.c - the measurement machinery of nf_bench that knows nothing of libnisflow (see
 * harness.h): clock, CPU-load snapshots, peak memory, CPU name, random numbers, the counting
 * allocator, and the thread pool with its barrier.
 */
#include "harness.h"

#include <math.h>
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

#define NFB_SPIN 20000 /* pause iterations before a barrier waiter blocks */

/* ---- Clock, memory, CPU ------------------------------------------------------------------ */

double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

long peak_rss_kib(void)
{
    struct rusage ru;
    if (getrusage(RUSAGE_SELF, &ru) != 0)
        return -1;
    return (long)ru.ru_maxrss; /* KiB on Linux */
}

/* /proc/stat's first line counts every CPU's time by kind since boot, in clock ticks. */
void take_cpu_snapshot(cpu_snapshot *s)
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

/* Other processes' CPU time is the machine's busy time less this process's own, over the wall
 * time between the snapshots. */
double foreign_cpu_load(const cpu_snapshot *a, const cpu_snapshot *b)
{
    if (!a->ok || !b->ok || b->wall_s <= a->wall_s)
        return -1.0;
    double other = (b->busy_s - a->busy_s) - (b->own_s - a->own_s);
    return other > 0.0 ? other / (b->wall_s - a->wall_s) : 0.0;
}

void read_cpu_model(char *buf, size_t size)
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

/* ---- Random numbers (splitmix64) --------------------------------------------------------- */

uint64_t rng_next(uint64_t *state)
{
    uint64_t z = (*state += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

/* The top 24 bits: every float in [0, 1) that is a multiple of 2^-24, equally likely. */
float rng_float(uint64_t *state)
{
    return (float)(rng_next(state) >> 40) * 0x1p-24f;
}

/* z uniform in [-1, 1] and an azimuth uniform in [0, 2 pi): uniform on the sphere, since
 * every slice of a sphere between two heights has the area of its cylinder (Archimedes). */
void rng_unit_vector(uint64_t *state, float v[3])
{
    float z = 2.0f * rng_float(state) - 1.0f;
    float phi = 2.0f * NFB_PI * rng_float(state);
    float r = sqrtf(fmaxf(0.0f, 1.0f - z * z));
    v[0] = r * cosf(phi);
    v[1] = r * sinf(phi);
    v[2] = z;
}

/* ---- A counting allocator ---------------------------------------------------------------- */

/* The size header takes a whole cache line, so that the block handed out is as 64-byte
 * aligned (cache-line aligned) as the allocation itself. */
#define NFB_HEADER 64u

void *counting_alloc(void *user, size_t size)
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

void counting_free(void *user, void *ptr)
{
    counting_allocator *ca = (counting_allocator *)user;
    unsigned char *block = (unsigned char *)ptr - NFB_HEADER;
    size_t size;
    memcpy(&size, block, sizeof size);
    atomic_fetch_sub(&ca->live, size);
    free(block);
}

/* ---- A spin-then-block barrier and a pool of persistent worker threads ------------------- */

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

/* The last to arrive opens the barrier by moving to the next generation. The others spin
 * first, since at a benchmark's step the wait is short and a wake-up from sleep would be
 * timed; they block only when the wait turns out long (a worker while the main thread is
 * between cases). */
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

/* A worker's life: wait for a job, run its share, report done; until the pool quits. */
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

int pool_create(pool *pl, int threads)
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

void pool_run(pool *pl, job_fn fn, void *arg)
{
    pl->fn = fn;
    pl->arg = arg;
    barrier_wait(&pl->start);
    fn(arg, 0);
    barrier_wait(&pl->done);
}

void pool_destroy(pool *pl)
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
