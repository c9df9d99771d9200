/*
 * nisflow/vertex.h - the flow's answers at a path's vertices, one vertex object per render
 * thread: a direction drawn from the flow, and the flow's density of other directions (the
 * BSDF's, a light sample's), for a renderer that traces one path at a time.
 *
 * A vertex object answers each vertex one of two ways (nf_vertex_get_stats counts which):
 *   - at a shading point of the vertex's context: the flow itself, walked once per question
 *     after the context's share of the work is done once, or
 *   - from the table of the vertex's cell: the flow tabulated once per cell of the scene on a
 *     grid of directions, after which a draw is two searches in cumulative sums and a density
 *     one lookup, a fraction of the flow's cost (docs/performance.md, "Tables"). A table is a
 *     distribution of its own, not the flow's: a vertex draws and evaluates from the same
 *     table, so an estimator that mixes it with the BSDF stays unbiased. Cells: the normal's
 *     direction (each face of a cube cut into normal_cells x normal_cells squares), a grid of
 *     position_cells per axis of the model's bounds across the normal, and the plane's offset
 *     along it. Vertices in a medium (a zero normal) and vertices with their own prior
 *     callbacks are always asked at a point.
 * Tables pay once a model stays long enough for their cells to be asked many times: in render
 * passes after training, not in training passes, whose model changes after each pass (every
 * table is forgotten when the model or its parameters change). The renderer says which per
 * call (NF_VERTEX_TABLE or NF_VERTEX_POINT).
 *
 * The recipe (docs/integration.md, "A guided vertex"):
 *
 *     nf_vertex *v;  nf_vertex_create(NULL, &v);                  once per render thread
 *     nf_vertex_set(v, m, &ctx, NULL, NF_VERTEX_TABLE);           at each guided vertex
 *     nf_vertex_sample(v, u, dir, &pdf, 1, light_dir, &p_light);  the flow's direction, and
 *   or, where the BSDF drew the direction:                         the light sample's density
 *     nf_vertex_pdf(v, 2, bsdf_and_light_dirs, p);                 both densities
 *     nf_vertex_build(v);                                          between chunks of paths
 *
 * A cell's table is never built inside nf_vertex_set: a vertex whose cell has none is asked at
 * a point, and its cell is noted; nf_vertex_build builds the noted cells' tables, so that a
 * renderer can run the builds between chunks of paths and time them apart from tracing (a
 * build is a one-time cost of the model, about NF_TABLE_CELLS densities at a point).
 *
 * Memory: nf_vertex_create allocates everything, from the config's allocator: about 4 KiB,
 * plus capacity x 2,192 bytes of tables when tables is 1 (8.6 MiB at the default). Nothing
 * is allocated afterwards.
 *
 * Thread-safety: a vertex object belongs to one thread at a time (one per render thread);
 * its calls never overlap. The models it is asked about may be shared (const): acquire them
 * for the pass from a guide (guide.h). Stack: at most 8 KiB a call (a build), 5 KiB otherwise.
 */
#ifndef NISFLOW_VERTEX_H
#define NISFLOW_VERTEX_H

#include <stddef.h>
#include <stdint.h>

#include "model.h"
#include "status.h"
#include "version.h"

NF_EXTERN_C_BEGIN

/* The directions a table covers: NF_TABLE_ROWS rows of equal sin^2(theta) about the normal and
 * NF_TABLE_COLS columns of equal azimuth, each with the same probability under the cosine
 * lobe; a table's density is zero below the surface (transmission is left to the BSDF). */
#define NF_TABLE_ROWS 16u
#define NF_TABLE_COLS 32u
#define NF_TABLE_CELLS (NF_TABLE_ROWS * NF_TABLE_COLS)

typedef struct nf_vertex nf_vertex;

typedef struct nf_vertex_config {
    uint32_t tables;         /* 1: keep tables of cells (default); 0: every vertex at a point,
                              * no memory for tables                                          */
    uint32_t capacity;       /* tables kept, 1..2^24; default 4096 (8.6 MiB). Cells hash to
                              * buckets of 8; a cell whose bucket is full keeps being asked at
                              * a point (stats.full). Room for about three times the cells a
                              * render visits keeps that to about one cell in 250            */
    uint32_t position_cells; /* grid cells per axis of the model's bounds, 1..1024; default 16 */
    uint32_t normal_cells;   /* cells per side of a face of the normals' cube, odd, 1..15;
                              * default 3 (54 directions)                                     */
    nf_allocator allocator;  /* optional; both NULL: malloc and free                          */
    uint32_t magic_;         /* set by nf_vertex_config_init                                  */
} nf_vertex_config;

/* The defaults above. NULL is ignored. Thread-safe. */
NF_API void nf_vertex_config_init(nf_vertex_config *cfg);

/* Creates a vertex object; cfg NULL: the defaults. Errors: NF_ERROR_INVALID_ARGUMENT (NULL
 * out, a config not initialized by nf_vertex_config_init, a field out of its range; the
 * message names it), NF_ERROR_OUT_OF_MEMORY. *out is NULL on error. Thread-safe. */
NF_API nf_status nf_vertex_create(const nf_vertex_config *cfg, nf_vertex **out);

/* Frees the object and its tables. NULL is a no-op. */
NF_API void nf_vertex_destroy(nf_vertex *v);

/* How nf_vertex_set answers a vertex. */
typedef enum nf_vertex_route {
    NF_VERTEX_POINT = 0, /* at a shading point of the context                              */
    NF_VERTEX_TABLE = 1  /* from its cell's table where it has one, else at a point (and the
                          * cell is noted for nf_vertex_build)                             */
} nf_vertex_route;

/* Moves the object to a vertex: model m (const; acquired for the pass), context ctx (as
 * nf_sample takes it: finite position, normal zero in a medium or of squared length above
 * 1e-30, wo likewise; a vertex answered from its cell's table reads position and normal
 * only), `prior` NULL or callbacks that replace a custom prior's for this vertex (per-vertex
 * data such as its BSDF in prior->user; they receive a pointer to the object's copy of ctx
 * and run on this thread; a non-NULL prior on a model with another prior kind is refused).
 * The questions that follow are answered for this vertex until the next set.
 * Errors (the object then answers nothing until a set succeeds):
 * NF_ERROR_INVALID_ARGUMENT (NULL, a bad context or prior, a route not of nf_vertex_route),
 * NF_ERROR_STALE (m changed during the call). Never allocates, never builds a table. */
NF_API nf_status nf_vertex_set(nf_vertex *v, const nf_model *m, const nf_context *ctx,
                               const nf_prior_callbacks *prior, nf_vertex_route route);

/* Draws a direction at the vertex: u[0], u[1] in [0,1) (clamped) give dir, a unit vector, and
 * (pdf not NULL) *pdf, its density per steradian in [FLT_MIN, FLT_MAX]; and the densities of
 * n more directions (usually the light sample's, n = 1) into pdfs[0..n), as nf_vertex_pdf.
 * At a point the draw and one more density run interleaved, cheaper than two calls on the
 * AVX2 and AVX-512 kernels; their bits are nf_sample's and nf_pdf's for the context (within
 * the bound docs/architecture.md states for the presets' vector path). Errors:
 * NF_ERROR_INVALID_ARGUMENT (NULL, no vertex set, NaN in u, a bad direction), NF_ERROR_STALE
 * (the model's parameters changed since the set) write nothing; NF_ERROR_NUMERIC (a custom
 * prior returned an invalid value) may come after dir was written. */
NF_API nf_status nf_vertex_sample(nf_vertex *v, const float u[2], float dir[3], float *pdf,
                                  size_t n, const float *dirs, float *pdfs);

/* The densities per steradian of n directions at the vertex, pdfs[i] for dirs[3i..3i+2]
 * (finite, squared length above 1e-30; normalized by the library). Two at a point cost less
 * than two calls of one. Errors as nf_vertex_sample. */
NF_API nf_status nf_vertex_pdf(nf_vertex *v, size_t n, const float *dirs, float *pdfs);

/* Builds the tables of the cells noted since the last call (up to 64 are noted; a cell whose
 * bucket is full is skipped), for the model of the last set. Returns NF_OK with nothing to
 * do. Errors: NF_ERROR_INVALID_ARGUMENT (NULL), NF_ERROR_STALE (the model changed since the
 * set: nothing built), NF_ERROR_NUMERIC (a custom prior returned an invalid value; the other
 * cells are still built). Never allocates. */
NF_API nf_status nf_vertex_build(nf_vertex *v);

/* What an object has done since its creation. */
typedef struct nf_vertex_stats {
    uint64_t points; /* vertices answered at a shading point                           */
    uint64_t tables; /* vertices answered from their cell's table                      */
    uint64_t builds; /* tables built                                                   */
    uint64_t full;   /* cells noted whose bucket was full when their table was to be built */
} nf_vertex_stats;

/* *out of object v. Errors: NF_ERROR_INVALID_ARGUMENT (NULL). */
NF_API nf_status nf_vertex_get_stats(const nf_vertex *v, nf_vertex_stats *out);

NF_EXTERN_C_END

#endif /* NISFLOW_VERTEX_H */
