/*
 * render.c - the tracer's one parallel engine (run_job: items on the threads, per-thread
 * counters, reusable per-thread memory, per-item training records joined in item order) and
 * its three kinds of item: an image's tile of spp paths per pixel, a chunk of a schedule's
 * pass (its records handed to a sink), and a chunk of training paths through random film
 * positions.
 */
#include "render.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "parallel.h"

#define TILE 16
#define TRAIN_CHUNK 64

/* The k-th of this rank's tiles: tiles are dealt to the ranks in turn, so that every rank gets
 * tiles from every part of the film (costs differ across it). */
static size_t rank_tile(const tracer *t, size_t k)
{
    return t->ranks > 1 ? (size_t)t->rank + k * (size_t)t->ranks : k;
}

static size_t rank_tile_count(const tracer *t, size_t tiles)
{
    if (t->ranks <= 1)
        return tiles;
    size_t r = (size_t)t->rank, n = (size_t)t->ranks;
    return tiles > r ? (tiles - r + n - 1) / n : 0;
}

/* With several ranks an image holds only this rank's tiles, and the ranks' images are summed:
 * the other tiles must be black, whatever an earlier pass left in them. */
static void clear_for_ranks(const tracer *t, image *img)
{
    if (t->ranks > 1)
        memset(img->data, 0, 3 * (size_t)img->width * (size_t)img->height * sizeof *img->data);
}

/* ---- The engine ----------------------------------------------------------------------------- */

/* One thread's counters. The threads add to theirs at every ray, so no two may share a cache
 * line: with 48-byte counters side by side, each increment missed the cache and took half of
 * vertex_plan_next's time in a guided veach-bidir pass. 128 bytes apart, the counters of two
 * threads are at least 80 bytes apart, wherever the array starts. */
typedef struct thread_stats {
    path_stats s;
    unsigned char apart[128 - sizeof(path_stats)];
} thread_stats;

/* What every job's items share: the tracer, per-thread counters, the memory the threads
 * reuse, and with joined records one buffer per item, joined in item order when the job ends.
 * Jobs embed it first. */
typedef struct job_common {
    const tracer *t;
    thread_stats *stats;  /* one per thread                        */
    render_memory *mem;   /* at least one entry per thread         */
    record_buffer *parts; /* one per item; NULL: no joined records */
} job_common;

/* Gives mem at least n threads' buffers, the new ones empty. */
static int render_memory_reserve(render_memory *mem, int n)
{
    if (mem->threads >= n)
        return 1;
    trace_scratch *sc = realloc(mem->scratch, (size_t)n * sizeof *sc);
    if (sc)
        mem->scratch = sc;
    record_buffer *rb = realloc(mem->records, (size_t)n * sizeof *rb);
    if (rb)
        mem->records = rb;
    if (!sc || !rb)
        return 0;
    size_t more = (size_t)(n - mem->threads);
    memset(sc + mem->threads, 0, more * sizeof *sc);
    memset(rb + mem->threads, 0, more * sizeof *rb);
    mem->threads = n;
    return 1;
}

void render_memory_free(render_memory *mem)
{
    for (int i = 0; i < mem->threads; ++i) {
        trace_scratch_free(&mem->scratch[i]);
        record_buffer_free(&mem->records[i]);
    }
    free(mem->scratch);
    free(mem->records);
    memset(mem, 0, sizeof *mem);
}

/* Runs fn over `items` on `threads` threads with c's buffers (mem's, or for this job only
 * when mem is NULL), then appends the items' records to *records in item order (replacing its
 * contents; `joined`, if given, learns where each item's records start) and adds the threads'
 * counters to *stats. Deterministic whatever the number of threads: items own their records
 * and counters are sums. */
static int run_job(job_common *c, const tracer *t, size_t items, int threads, parallel_fn fn,
                   void *job, render_memory *mem, record_buffer *records,
                   void (*joined)(void *, size_t, size_t), path_stats *stats, const char *label,
                   tr_error *err)
{
    int nthreads = threads > 0 ? threads : 1;
    render_memory own = {0};
    c->t = t;
    c->mem = mem ? mem : &own;
    c->stats = calloc((size_t)nthreads, sizeof *c->stats);
    c->parts = records ? calloc(items ? items : 1, sizeof *c->parts) : NULL;
    int ok = (c->stats && render_memory_reserve(c->mem, nthreads) && (!records || c->parts)) ||
             tr_fail(err, "out of memory");
    if (ok)
        ok = parallel_for(items, threads, fn, job, label, err);
    if (records && c->parts) {
        records->count = 0;
        for (size_t i = 0; i < items; ++i) {
            size_t before = records->count;
            if (c->parts[i].out_of_memory || !record_buffer_append(records, &c->parts[i]))
                ok = ok && tr_fail(err, "out of memory for training records");
            else if (joined)
                joined(job, i, before);
            record_buffer_free(&c->parts[i]);
        }
    }
    for (int i = 0; stats && c->stats && i < nthreads; ++i)
        path_stats_add(stats, &c->stats[i].s);
    free(c->stats);
    free(c->parts);
    render_memory_free(&own);
    return ok;
}

/* The pixels of this rank's k-th tile. */
static void tile_bounds(const tracer *t, size_t k, int *x0, int *y0)
{
    size_t tiles_x = (size_t)((t->s->width + TILE - 1) / TILE), item = rank_tile(t, k);
    *x0 = (int)(item % tiles_x) * TILE;
    *y0 = (int)(item / tiles_x) * TILE;
}

static size_t tile_count(const tracer *t)
{
    size_t tiles_x = (size_t)((t->s->width + TILE - 1) / TILE);
    return rank_tile_count(t, tiles_x * (size_t)((t->s->height + TILE - 1) / TILE));
}

/* ---- An image: spp paths per pixel ------------------------------------------------------------ */

typedef struct image_job {
    job_common c;
    image *img;
    int spp;
    uint64_t seed;
    uint32_t pass;
} image_job;

static void render_tile(void *user, size_t k, int thread)
{
    image_job *job = user;
    const scene *s = job->c.t->s;
    int x0, y0;
    tile_bounds(job->c.t, k, &x0, &y0);
    for (int y = y0; y < y0 + TILE && y < s->height; ++y)
        for (int x = x0; x < x0 + TILE && x < s->width; ++x) {
            uint64_t pixel = (uint64_t)y * (uint64_t)s->width + (uint64_t)x;
            rng r = rng_seed(job->seed, RNG_RENDER, job->pass, pixel);
            rgb sum = rgb_gray(0.0f);
            for (int i = 0; i < job->spp; ++i) {
                float jx = rng_next(&r), jy = rng_next(&r);
                rgb c = trace_path(job->c.t, &r, (float)x + jx, (float)y + jy, NULL,
                                   &job->c.mem->scratch[thread], &job->c.stats[thread].s);
                /* One bad sample (a NaN from a numerical corner case) must not poison the
                 * pixel; such samples are dropped and would show up as darkening. */
                if (rgb_is_finite(c))
                    sum = rgb_add(sum, c);
            }
            float *p = image_pixel(job->img, x, y);
            p[0] = sum.r / (float)job->spp;
            p[1] = sum.g / (float)job->spp;
            p[2] = sum.b / (float)job->spp;
        }
}

int render_image(const tracer *t, int spp, uint64_t seed, uint32_t pass, int threads,
                 image *img, path_stats *stats, const char *progress_label, tr_error *err)
{
    image_job job = {{0}, img, spp, seed, pass};
    clear_for_ranks(t, img);
    return run_job(&job.c, t, tile_count(t), threads, render_tile, &job, NULL, NULL, NULL, stats,
                   progress_label, err);
}

/* ---- A pass: the schedule's paths ---------------------------------------------------------- */

/* One chunk of a pass's paths is one item: as many paths as a tile has pixels. */
#define PASS_CHUNK (TILE * TILE)

/* The paths of one pass (nisflow/schedule.h: path j through pixel nf_pass_pixel), their
 * training records going to the sink chunk by chunk. */
typedef struct pass_job {
    job_common c;
    const record_sink *sink; /* NULL: no records */
    const nf_pass_plan *plan;
    float *rgb;    /* 3 per path                                                        */
    float *moment; /* NULL, or PATH_MOMENTS planes of one float per path: the paths' second
                    * moments (trace_paths) */
    uint64_t seed;
    uint32_t stream; /* the pass's random streams */
} pass_job;

/* Whether this rank renders pixel i: the rank its tile is dealt to (rank_tile). */
static int rank_owns(const tracer *t, uint32_t i)
{
    if (t->ranks <= 1)
        return 1;
    size_t w = (size_t)t->s->width, tiles_x = (w + TILE - 1) / TILE;
    size_t tile = (i / w / TILE) * tiles_x + i % w / TILE;
    return tile % (size_t)t->ranks == (size_t)t->rank;
}

/* Path j's radiance and moments into the pass's arrays. */
static void pass_path_out(pass_job *job, uint32_t j, rgb c, const float *moment)
{
    const int finite = rgb_is_finite(c);
    if (!finite) /* as in render_tile: a NaN must not poison the pixel */
        c = rgb_gray(0.0f);
    float *p = job->rgb + 3 * (size_t)j;
    p[0] = c.r;
    p[1] = c.g;
    p[2] = c.b;
    for (int k = 0; job->moment && k < PATH_MOMENTS; ++k)
        job->moment[(size_t)k * job->plan->paths + j] =
            finite && moment && isfinite(moment[k]) ? moment[k] : 0.0f;
}

/* Traces n gathered paths together and writes them out (their records to out). */
static void pass_paths(pass_job *job, int thread, size_t n, rng *r, const float *px,
                       const float *py, const uint32_t *at, record_buffer *out)
{
    rgb c[TRACE_BATCH];
    float m[PATH_MOMENTS * TRACE_BATCH];
    trace_paths(job->c.t, n, r, px, py, c, m, out, &job->c.mem->scratch[thread],
                &job->c.stats[thread].s);
    for (size_t i = 0; i < n; ++i)
        pass_path_out(job, at[i], c[i], &m[PATH_MOMENTS * i]);
}

/* A guided pass traces its chunk's paths TRACE_BATCH at a time (trace_paths: the flow's
 * questions batched, the same bits and records); an unguided pass traces them one by one. */
static void pass_chunk(void *user, size_t k, int thread)
{
    pass_job *job = user;
    const scene *s = job->c.t->s;
    const nf_pass_plan *plan = job->plan;
    record_buffer *out = job->sink ? &job->c.mem->records[thread] : NULL;
    if (out) { /* the thread's buffer, emptied for this chunk; its memory stays */
        out->count = 0;
        out->out_of_memory = 0;
    }
    /* Unguided paths ask nothing: advancing them together would only cost locality. */
    const int batched = trace_paths_pay(job->c.t);
    rng r[TRACE_BATCH];
    float px[TRACE_BATCH], py[TRACE_BATCH];
    uint32_t at[TRACE_BATCH];
    size_t n = 0;
    const uint32_t end = (uint32_t)((k + 1) * PASS_CHUNK < plan->paths ? (k + 1) * PASS_CHUNK
                                                                        : plan->paths);
    for (uint32_t j = (uint32_t)(k * PASS_CHUNK); j < end; ++j) {
        const uint32_t pixel = nf_pass_pixel(plan, j);
        if (!rank_owns(job->c.t, pixel)) { /* another rank's: zero, for the sum */
            pass_path_out(job, j, rgb_gray(0.0f), NULL);
            continue;
        }
        const int x = (int)(pixel % (uint32_t)s->width), y = (int)(pixel / (uint32_t)s->width);
        /* Path j's own stream: a pixel may have two paths in one pass. */
        rng pr = rng_seed(job->seed, RNG_RENDER, job->stream, j);
        float jx = rng_next(&pr), jy = rng_next(&pr);
        if (!batched) {
            float m[PATH_MOMENTS] = {0.0f};
            rgb c = trace_path_moment(job->c.t, &pr, (float)x + jx, (float)y + jy, out,
                                      &job->c.mem->scratch[thread], &job->c.stats[thread].s, m);
            pass_path_out(job, j, c, m);
            continue;
        }
        r[n] = pr;
        px[n] = (float)x + jx;
        py[n] = (float)y + jy;
        at[n++] = j;
        if (n == TRACE_BATCH) {
            pass_paths(job, thread, n, r, px, py, at, out);
            n = 0;
        }
    }
    if (n)
        pass_paths(job, thread, n, r, px, py, at, out);
    if (out)
        job->sink->fn(job->sink->user, k, thread, out);
}

int render_pass(const tracer *t, uint64_t seed, uint32_t stream, const nf_pass_plan *plan,
                int threads, float *rgb, float *moment, const record_sink *sink,
                render_memory *mem, path_stats *stats, tr_error *err)
{
    pass_job job = {{0}, sink, plan, rgb, moment, seed, stream};
    size_t chunks = (plan->paths + (size_t)PASS_CHUNK - 1) / PASS_CHUNK;
    return run_job(&job.c, t, chunks, threads, pass_chunk, &job, mem, NULL, NULL, stats, NULL,
                   err);
}

/* ---- Training paths through random film positions ---------------------------------------- */

typedef struct train_job {
    job_common c;
    size_t first, paths;
    uint64_t seed;
    uint32_t iteration;
    size_t *path_end; /* NULL, or per path: the batch's record count after it */
} train_job;

static void train_chunk(void *user, size_t item, int thread)
{
    train_job *job = user;
    const scene *s = job->c.t->s;
    record_buffer *out = &job->c.parts[item];
    out->count = 0;
    for (size_t j = item * TRAIN_CHUNK; j < (item + 1) * TRAIN_CHUNK && j < job->paths; ++j) {
        rng r = rng_seed(job->seed, RNG_TRAIN, job->iteration, job->first + j);
        float px = rng_next(&r) * (float)s->width, py = rng_next(&r) * (float)s->height;
        trace_path(job->c.t, &r, px, py, out, &job->c.mem->scratch[thread],
                   &job->c.stats[thread].s);
        if (job->path_end)
            job->path_end[j] = out->count; /* the chunk's count; joined_chunk adds the rest */
    }
}

/* A chunk's records now start at `before` in the batch: its paths' counts follow. */
static void joined_chunk(void *user, size_t item, size_t before)
{
    train_job *job = user;
    for (size_t j = item * TRAIN_CHUNK; job->path_end && j < (item + 1) * TRAIN_CHUNK &&
                                        j < job->paths;
         ++j)
        job->path_end[j] += before;
}

int trace_training_batch(const tracer *t, size_t first, size_t paths, uint64_t seed,
                         uint32_t iteration, int threads, record_buffer *out, size_t *path_end,
                         path_stats *stats, tr_error *err)
{
    train_job job = {{0}, first, paths, seed, iteration, path_end};
    size_t chunks = (paths + TRAIN_CHUNK - 1) / TRAIN_CHUNK;
    return run_job(&job.c, t, chunks, threads, train_chunk, &job, NULL, out, joined_chunk, stats,
                   NULL, err);
}
