/*
 * integrator.h - unidirectional path tracing with next-event estimation, multiple
 * importance sampling (power heuristic) and Russian roulette, guided at non-specular
 * vertices by a one-sample mixture of BSDF sampling and the normalizing flow.
 *
 * One call traces one camera path. Optionally it records the training samples of the
 * path's guided vertices (see trace_path).
 */
#ifndef TRACER_INTEGRATOR_H
#define TRACER_INTEGRATOR_H

#include <stddef.h>
#include <stdint.h>

#include <nisflow/nisflow.h>

#include "bsdf.h"
#include "rng.h"
#include "scene.h"

typedef struct tracer {
    const scene *s;
    const nf_model *model; /* NULL: no guiding (pure BSDF sampling + NEE)                  */
    nf_guide_policy policy; /* how guided vertices mix the flow with the BSDF, when roulette
                            * lets a path go on, which vertices weigh light samples by the
                            * flow (nisflow/guide.h; nf_guide_policy_init's defaults)      */
    int bsdf_prior;        /* the model uses the BSDF prior: publish shading points        */
    int mis_training;      /* train on the MIS-weighted emission the scattered ray finds
                            * (what the scattering estimator needs; the default) instead of
                            * all of it                                                    */
    /* Ablation switches (options.h, --variant), all 0 by default: */
    int guide_depth;       /* guide only vertices up to this many segments deep; 0: all    */
    int light_mis_bsdf;    /* MIS between light sampling and scattering by the BSDF's density
                            * at every depth: a light sample never asks the flow           */
    int no_batching;       /* budget passes trace one path at a time (trace_paths_pay)      */
    int rank, ranks;       /* render_image renders this rank's share of the film's tiles;
                            * ranks 0 or 1: all of them (ranks.h)                          */
} tracer;

/* A training sample (docs/theory.md section 6): at a guided vertex, the context, the sampled
 * direction and weight = mean over RGB of f_s L_i |cos| / p_mix, with L_i the radiance the rest of
 * the path brought back along the direction. The material is kept for the BSDF prior. */
typedef struct train_record {
    nf_context ctx;
    float dir[3];
    float weight;
    bsdf_point bp;
    uint32_t pixel; /* the film pixel the path went through, y * width + x */
} train_record;

typedef struct record_buffer {
    train_record *data;
    size_t count, capacity;
    int out_of_memory;
} record_buffer;

void record_buffer_free(record_buffer *b);
/* Appends src to dst (in order). Returns 0 when out of memory. */
int record_buffer_append(record_buffer *dst, const record_buffer *src);

/* Counters for throughput figures; each thread keeps its own and they are summed. Every field
 * is a uint64_t counter: the MPI ranks sum them as an array (nf_tracer.c, budget.c). */
/* The second moments a path estimates (path_state.guide.moments). */
#define PATH_MOMENTS ((int)NF_GUIDE_DEPTHS)

typedef struct path_stats {
    uint64_t paths, rays, guided_vertices, nf_errors;
    uint64_t camera_backfaces; /* camera rays that hit the black back of a one-sided material */
    uint64_t invalid_rays;     /* rays Embree cannot take (scene_ray_valid); each ended its
                                * path or its light sample without reaching Embree. Always 0
                                * for a scene the loader accepted; tests check it. */
} path_stats;
_Static_assert(sizeof(path_stats) == 6 * sizeof(uint64_t), "path_stats: uint64_t counters only");

void path_stats_add(path_stats *a, const path_stats *b);

/* A path between two vertices: what it has gathered and the ray it follows next. */
typedef struct path_state {
    rgb L, throughput;
    ray ry;
    float prev_pdf;    /* density of the last scattered direction (0: delta or camera)    */
    float prev_p_bsdf; /* its BSDF density, which plain path tracing's MIS weighs with     */
    int depth;         /* segments traced so far                                          */
    int guided;        /* the tracer has a model: the path may be guided                  */
    int medium;        /* the medium the ray ry travels in (scene.media); -1: vacuum      */
    nf_path_state guide; /* the library's per-path state (nisflow/policy.h), started on every
                          * path: the mixture's boost, which the boost cap and roulette read,
                          * and the second moments the schedule reads ([0] plain path
                          * tracing's, [k] the kind that guides up to depth k)              */
} path_state;

/* What a render thread keeps from path to path: the memory trace_paths reuses for its paths'
 * records, and the thread's vertex object, through which its vertices are asked at a shading
 * point (nisflow/vertex.h; made on first use). One per thread, zero-initialized ({0}),
 * released with trace_scratch_free. */
typedef struct trace_scratch {
    void *mem;
    size_t bytes;
    nf_vertex *flow;
} trace_scratch;

void trace_scratch_free(trace_scratch *scratch);

/* Traces the path through film position (px, py) and returns its radiance estimate.
 * With records != NULL, appends a record for every guided vertex whose weight is positive
 * (zero-weight samples carry no information for the loss). */
rgb trace_path(const tracer *t, rng *r, float px, float py, record_buffer *records,
               trace_scratch *scratch, path_stats *stats);

/* trace_path, and with moment != NULL moment[0..PATH_MOMENTS) receive the path's estimates
 * of the second moments of the pixel's luminance under the policies of
 * path_state.guide.moments: plain path tracing's, then the guide's depth candidates' (an
 * unguided path: its squared luminance). The schedule reads only those of kinds that guide
 * less deep than the pass. */
rgb trace_path_moment(const tracer *t, rng *r, float px, float py, record_buffer *records,
                      trace_scratch *scratch, path_stats *stats, float *moment);

/* How many paths trace_paths takes at once: a whole 16 x 16 tile of pixels, so that even
 * the later rounds, when most paths have ended, and scenes where guided vertices are rare
 * still fill several of the library's 16-lane tiles (it cost 5-7% less CPU per render pass in
 * Veach Ajar than 64 paths). */
#define TRACE_BATCH 256

/* Traces the paths through film positions (px[i], py[i]), i < n <= TRACE_BATCH, with path i
 * drawing from r[i], and writes their radiance estimates to out[i]: the same bits as n calls
 * of trace_path, records included (appended in path order), but the paths advance together:
 * each round takes every path to its next vertex that asks the flow something (a guided
 * vertex: its light sample's density, a flow sample or its BSDF direction's density), and the
 * round's questions go to the library as one nf_sample and one nf_pdf call. Batches run the
 * library's 16-lane kernels, several times faster per direction than a shading point
 * (docs/performance.md). Models with a custom prior are asked at shading points. With
 * records != NULL the paths' vertices are kept in *scratch (about 170 bytes per vertex, up to
 * the scene's max_depth vertices per path); when it cannot grow, the paths are traced one at
 * a time (the same bits). With moment != NULL, moment[PATH_MOMENTS i + k] receives path i's
 * estimates of second moments (trace_path_moment). Uses about 185 KiB of stack (360 bytes of
 * plan per path). */
void trace_paths(const tracer *t, size_t n, rng *r, const float *px, const float *py, rgb *out,
                 float *moment, record_buffer *records, trace_scratch *scratch,
                 path_stats *stats);

/* Whether trace_paths batches anything for t: a guided model without a custom prior, and
 * t->no_batching not set. Otherwise trace_paths traces the paths one after the other. */
int trace_paths_pay(const tracer *t);

#endif /* TRACER_INTEGRATOR_H */
