/*
 * render.c - tiles, chunks and per-thread statistics around trace_path.
 */
#include "render.h"

#include <stdlib.h>
#include <string.h>

#include "parallel.h"

#define TILE 16
#define TRAIN_CHUNK 64

typedef struct image_job {
    const tracer *t;
    image *img;
    int spp, tiles_x;
    uint64_t seed;
    uint32_t pass;
    path_stats *stats; /* one per thread */
} image_job;

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

int render_pixel_mine(const tracer *t, int x, int y)
{
    if (t->ranks <= 1)
        return 1;
    size_t tiles_x = (size_t)((t->s->width + TILE - 1) / TILE);
    size_t item = (size_t)(y / TILE) * tiles_x + (size_t)(x / TILE);
    return item % (size_t)t->ranks == (size_t)t->rank; /* rank_tile's dealing, inverted */
}

/* With several ranks an image holds only this rank's tiles, and the ranks' images are summed:
 * the other tiles must be black, whatever an earlier pass left in them. */
static void clear_for_ranks(const tracer *t, image *img)
{
    if (t->ranks > 1)
        memset(img->data, 0, 3 * (size_t)img->width * (size_t)img->height * sizeof *img->data);
}

static void render_tile(void *user, size_t k, int thread)
{
    image_job *job = user;
    const scene *s = job->t->s;
    size_t item = rank_tile(job->t, k);
    int x0 = (int)(item % (size_t)job->tiles_x) * TILE, y0 = (int)(item / (size_t)job->tiles_x) * TILE;
    for (int y = y0; y < y0 + TILE && y < s->height; ++y)
        for (int x = x0; x < x0 + TILE && x < s->width; ++x) {
            uint64_t pixel = (uint64_t)y * (uint64_t)s->width + (uint64_t)x;
            rng r = rng_seed(job->seed, RNG_RENDER, job->pass, pixel);
            rgb sum = rgb_gray(0.0f);
            for (int i = 0; i < job->spp; ++i) {
                float jx = rng_next(&r), jy = rng_next(&r);
                rgb c = trace_path(job->t, &r, (float)x + jx, (float)y + jy, NULL,
                                   &job->stats[thread]);
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
    image_job job;
    job.t = t;
    job.img = img;
    job.spp = spp;
    job.seed = seed;
    job.pass = pass;
    job.tiles_x = (t->s->width + TILE - 1) / TILE;
    int tiles_y = (t->s->height + TILE - 1) / TILE;
    job.stats = calloc((size_t)(threads > 0 ? threads : 1), sizeof *job.stats);
    if (!job.stats)
        return tr_fail(err, "out of memory");
    clear_for_ranks(t, img);
    size_t tiles = rank_tile_count(t, (size_t)job.tiles_x * (size_t)tiles_y);
    int ok = parallel_for(tiles, threads, render_tile, &job, progress_label, err);
    for (int i = 0; stats && i < (threads > 0 ? threads : 1); ++i)
        path_stats_add(stats, &job.stats[i]);
    free(job.stats);
    return ok;
}

/* One sample per pixel whose training records are kept per tile, then concatenated in tile
 * order: the same records whatever the number of threads. */
typedef struct pass_job {
    const tracer *t;
    image *img;
    int tiles_x;
    uint64_t seed;
    uint32_t pass;
    record_buffer *tiles; /* one per tile; NULL: no records */
    path_stats *stats;
    trace_scratch *scratch; /* one per thread: trace_paths' records */
} pass_job;

/* One pixel's sample of a pass, written into the pass image. */
static void pass_pixel(image *img, int x, int y, rgb c)
{
    if (!rgb_is_finite(c)) /* as in render_tile: a NaN must not poison the pixel */
        c = rgb_gray(0.0f);
    float *p = image_pixel(img, x, y);
    p[0] = c.r;
    p[1] = c.g;
    p[2] = c.b;
}

/* Traces n gathered paths together and writes their pixels (and their records to out). */
static void pass_paths(pass_job *job, int thread, size_t n, rng *r, const float *px,
                       const float *py, int (*at)[2], record_buffer *out)
{
    rgb c[TRACE_BATCH];
    trace_paths(job->t, n, r, px, py, c, out, &job->scratch[thread], &job->stats[thread]);
    for (size_t i = 0; i < n; ++i)
        pass_pixel(job->img, at[i][0], at[i][1], c[i]);
}

/* A guided pass traces its tile's paths TRACE_BATCH at a time (trace_paths: the flow's
 * questions batched, the same bits and records); an unguided pass traces them one by one. */
static void pass_tile(void *user, size_t k, int thread)
{
    pass_job *job = user;
    const scene *s = job->t->s;
    record_buffer *out = job->tiles ? &job->tiles[k] : NULL;
    size_t item = rank_tile(job->t, k);
    int x0 = (int)(item % (size_t)job->tiles_x) * TILE, y0 = (int)(item / (size_t)job->tiles_x) * TILE;
    /* Unguided paths ask nothing: advancing them together would only cost locality. */
    const int batched = trace_paths_pay(job->t);
    rng r[TRACE_BATCH];
    float px[TRACE_BATCH], py[TRACE_BATCH];
    int at[TRACE_BATCH][2];
    size_t n = 0;
    for (int y = y0; y < y0 + TILE && y < s->height; ++y)
        for (int x = x0; x < x0 + TILE && x < s->width; ++x) {
            uint64_t pixel = (uint64_t)y * (uint64_t)s->width + (uint64_t)x;
            rng pr = rng_seed(job->seed, RNG_RENDER, job->pass, pixel);
            float jx = rng_next(&pr), jy = rng_next(&pr);
            if (!batched) {
                pass_pixel(job->img, x, y,
                           trace_path(job->t, &pr, (float)x + jx, (float)y + jy, out,
                                      &job->stats[thread]));
                continue;
            }
            r[n] = pr;
            px[n] = (float)x + jx;
            py[n] = (float)y + jy;
            at[n][0] = x;
            at[n++][1] = y;
            if (n == TRACE_BATCH) {
                pass_paths(job, thread, n, r, px, py, at, out);
                n = 0;
            }
        }
    if (n)
        pass_paths(job, thread, n, r, px, py, at, out);
}

int render_pass(const tracer *t, uint64_t seed, uint32_t pass, int threads, image *img,
                record_buffer *records, path_stats *stats, tr_error *err)
{
    pass_job job;
    job.t = t;
    job.img = img;
    job.seed = seed;
    job.pass = pass;
    job.tiles_x = (t->s->width + TILE - 1) / TILE;
    size_t ntiles = rank_tile_count(t, (size_t)job.tiles_x *
                                           (size_t)((t->s->height + TILE - 1) / TILE));
    int nthreads = threads > 0 ? threads : 1;
    job.tiles = records ? calloc(ntiles, sizeof *job.tiles) : NULL;
    job.stats = calloc((size_t)nthreads, sizeof *job.stats);
    job.scratch = calloc((size_t)nthreads, sizeof *job.scratch);
    if ((records && !job.tiles) || !job.stats || !job.scratch) {
        free(job.tiles);
        free(job.stats);
        free(job.scratch);
        return tr_fail(err, "out of memory");
    }
    clear_for_ranks(t, img);
    int ok = parallel_for(ntiles, threads, pass_tile, &job, NULL, err);
    if (records) {
        records->count = 0;
        for (size_t i = 0; i < ntiles; ++i) {
            if (job.tiles[i].out_of_memory || !record_buffer_append(records, &job.tiles[i]))
                ok = ok && tr_fail(err, "out of memory for training records");
            record_buffer_free(&job.tiles[i]);
        }
    }
    for (int i = 0; stats && i < nthreads; ++i)
        path_stats_add(stats, &job.stats[i]);
    for (int i = 0; i < nthreads; ++i)
        trace_scratch_free(&job.scratch[i]);
    free(job.tiles);
    free(job.stats);
    free(job.scratch);
    return ok;
}

typedef struct train_job {
    const tracer *t;
    size_t first, paths;
    uint64_t seed;
    uint32_t iteration;
    record_buffer *chunks;
    size_t *path_end; /* NULL, or per path: its chunk's record count after it */
    path_stats *stats;
} train_job;

static void train_chunk(void *user, size_t item, int thread)
{
    train_job *job = user;
    const scene *s = job->t->s;
    record_buffer *out = &job->chunks[item];
    out->count = 0;
    for (size_t j = item * TRAIN_CHUNK; j < (item + 1) * TRAIN_CHUNK && j < job->paths; ++j) {
        rng r = rng_seed(job->seed, RNG_TRAIN, job->iteration, job->first + j);
        float px = rng_next(&r) * (float)s->width, py = rng_next(&r) * (float)s->height;
        trace_path(job->t, &r, px, py, out, &job->stats[thread]);
        if (job->path_end)
            job->path_end[j] = out->count;
    }
}

int trace_training_batch(const tracer *t, size_t first, size_t paths, uint64_t seed,
                         uint32_t iteration, int threads, record_buffer *out, size_t *path_end,
                         path_stats *stats, tr_error *err)
{
    train_job job;
    size_t nchunks = (paths + TRAIN_CHUNK - 1) / TRAIN_CHUNK;
    job.t = t;
    job.first = first;
    job.paths = paths;
    job.path_end = path_end;
    job.seed = seed;
    job.iteration = iteration;
    job.chunks = calloc(nchunks ? nchunks : 1, sizeof *job.chunks);
    job.stats = calloc((size_t)(threads > 0 ? threads : 1), sizeof *job.stats);
    if (!job.chunks || !job.stats) {
        free(job.chunks);
        free(job.stats);
        return tr_fail(err, "out of memory");
    }
    int ok = parallel_for(nchunks, threads, train_chunk, &job, NULL, err);
    out->count = 0;
    for (size_t c = 0; c < nchunks; ++c) {
        size_t before = out->count;
        if (job.chunks[c].out_of_memory || !record_buffer_append(out, &job.chunks[c]))
            ok = ok && tr_fail(err, "out of memory for training records");
        for (size_t j = c * TRAIN_CHUNK; path_end && j < (c + 1) * TRAIN_CHUNK && j < paths; ++j)
            path_end[j] += before; /* from the chunk's count to the batch's */
        record_buffer_free(&job.chunks[c]);
    }
    for (int i = 0; stats && i < (threads > 0 ? threads : 1); ++i)
        path_stats_add(stats, &job.stats[i]);
    free(job.chunks);
    free(job.stats);
    return ok;
}
