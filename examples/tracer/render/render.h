/*
 * render.h - the parallel jobs of the tracer: rendering an image (tiles of pixels), a pass of
 * the library's schedule (its paths, chunk by chunk) and tracing a batch of training paths.
 * All are deterministic for a given seed whatever the number of threads: every pixel and
 * every path has its own random stream, and training records are gathered per chunk of paths
 * and concatenated in chunk order (a batch) or handed over chunk by chunk with the chunk's
 * index (a pass).
 */
#ifndef TRACER_RENDER_H
#define TRACER_RENDER_H

#include <stddef.h>
#include <stdint.h>

#include "error.h"
#include "image.h"
#include "integrator.h"

/* Renders spp paths per pixel (uniformly jittered in the pixel: a box filter) into img,
 * which must be allocated at the scene's resolution, and stores the mean. `pass` selects
 * independent random streams (evaluation renders and the final render use different ones).
 * With t->ranks > 1 it renders only this rank's tiles (every ranks-th, from t->rank) and
 * leaves the others black, for ranks_sum_floats_to_root to assemble. */
int render_image(const tracer *t, int spp, uint64_t seed, uint32_t pass, int threads,
                 image *img, path_stats *stats, const char *progress_label, tr_error *err);

/* Memory that render_pass reuses from pass to pass, so that a pass neither allocates nor
 * touches fresh pages: per thread, trace_paths' scratch and the records of the tile it traces.
 * Zero-initialize ({0}); it grows to the threads of the passes; render_memory_free releases
 * it. One pass at a time may use it. */
typedef struct render_memory {
    trace_scratch *scratch;
    record_buffer *records;
    int threads;
} render_memory;

void render_memory_free(render_memory *mem);

/* Where a training pass's records go: fn(user, chunk, thread, records) runs on the render
 * thread that traced the chunk (PASS_CHUNK consecutive paths of the pass), once it is done,
 * with its records in path order (records->out_of_memory set when some could not be kept).
 * `chunk` is the same for any number of threads and on every rank, so that keys made from it
 * order the samples as one thread would. fn may run on several threads at once, each with its
 * own `thread` in [0, threads); failures are its own to keep and report. */
typedef struct record_sink {
    void (*fn)(void *user, size_t chunk, int thread, const record_buffer *records);
    void *user;
} record_sink;

/* Renders the paths of the schedule's pass `plan` (nisflow/schedule.h): path j through pixel
 * nf_pass_pixel(plan, j), with random stream j of `stream`, into rgb[3 j ..] and, with
 * moment != NULL (PATH_MOMENTS planes of plan->paths floats), its estimates of second moments
 * into moment[k plan->paths + j] (trace_path_moment). With t->ranks > 1 only the paths through
 * this rank's tiles (as render_image deals them); the others are 0. With sink != NULL, the
 * paths record training samples, which go to the sink chunk by chunk while the pass runs.
 * mem: the memory to reuse, or NULL (allocated for this pass). The passes of a time-budgeted
 * render (budget.h) are these. */
int render_pass(const tracer *t, uint64_t seed, uint32_t stream, const nf_pass_plan *plan,
                int threads, float *rgb, float *moment, const record_sink *sink,
                render_memory *mem, path_stats *stats, tr_error *err);

/* Traces the training paths first .. first + paths - 1 of iteration `iteration`, each through
 * a uniformly random film position (path j's random stream depends on j alone, so a rank that
 * traces part of a batch gets the records one process would get for those paths), and
 * replaces the contents of `out` with their records in path order. With path_end != NULL
 * (`paths` entries), path_end[i] receives the number of records of paths first .. first + i. */
int trace_training_batch(const tracer *t, size_t first, size_t paths, uint64_t seed,
                         uint32_t iteration, int threads, record_buffer *out, size_t *path_end,
                         path_stats *stats, tr_error *err);

#endif /* TRACER_RENDER_H */
