/*
 * direction_table.h - a shading point's flow tabulated on a fixed grid of directions, and a
 * render thread's tables by cells of the scene. Internal (not installed): renderers reach
 * tables through the vertex object (nisflow/vertex.h), which keeps one cache; the tests,
 * fuzzers and the benchmark call these directly.
 *
 * A guided vertex through a shading point (point.h) walks the flow once per question. A
 * renderer that keys cells of its scene (a grid of positions, the normal's direction) can
 * instead build one table per cell from a point prepared at the cell's centre and answer
 * every vertex in the cell from it: a draw is two searches in cumulative sums and a density
 * one lookup, where the flow costs a walk through its layers. The table is a distribution of
 * its own, not the flow's: sampling and evaluating at a vertex both use the same table, so an
 * estimator that mixes it with the BSDF stays unbiased; what the cell's size and the grid's
 * resolution cost in variance is the renderer's to measure (docs/client.md has our client's
 * figures). nf_table_cache, below, keeps a render thread's tables by cells.
 *
 * The grid. At a surface point (a non-zero normal n) the table covers n's hemisphere in the
 * cosine lobe's coordinates: NF_TABLE_ROWS rows of equal sin^2(theta) and NF_TABLE_COLS
 * columns of equal azimuth about n, so every cell has the same probability under the cosine
 * lobe, and the table holds the flow's density over the lobe's at each cell's centre. Its
 * density is then (cell probability) x NF_TABLE_CELLS x cos(theta) / pi per steradian:
 * continuous in the cell, zero at the horizon and below it (a BSDF's transmission is left to
 * BSDF sampling). At a point in a medium (a zero normal) the table covers the sphere in cells
 * of equal solid angle (rows of equal z, columns of equal azimuth about +z), each holding the
 * flow's density at its centre.
 *
 * Memory: an nf_direction_table is a plain struct (2,176 bytes) that the caller owns; nothing
 * is allocated. Its fields are the library's: read or write none of them. It may be copied.
 *
 * Validity: a table belongs to the model its point was prepared on and to that model's
 * parameters when it was built; after a change of the parameters (a training step,
 * nf_model_set_params) using it returns NF_ERROR_STALE, as a point does.
 * A table whose contents were overwritten gives wrong results but never reads outside itself.
 *
 * Results: the build asks the flow through nf_point_pdf, so a table holds the bits of that
 * call's path (the presets' vector path agrees with nf_pdf within the bound point.h states).
 * Drawing and evaluating are scalar code compiled once: the same bits on every instruction
 * set for the same table.
 *
 * Thread-safety: the table functions take a const model and a const table (the build writes
 * only *table); any number of threads may draw from one table at once. They never allocate.
 * The cache's rules are its own (below).
 * Stack: a build uses at most 8 KiB (its table, a row of directions and the flow's share), a
 * draw or a density 256 bytes; tests/correctness/test_table.c measures both.
 */
#ifndef NISFLOW_SRC_DIRECTION_TABLE_H
#define NISFLOW_SRC_DIRECTION_TABLE_H

#include <stdint.h>

#include "nisflow/model.h"
#include "shading_point.h"
#include "nisflow/status.h"
#include "nisflow/vertex.h"

/* NF_TABLE_ROWS, NF_TABLE_COLS, NF_TABLE_CELLS: nisflow/vertex.h. */

/* A tabulated point. Its layout is private: the names exist only to size it. A draw reads the
 * first 128 bytes and one row of 128, a density one line of the first and one or two of a row:
 * 64-byte alignment of the struct keeps each row on two cache lines (best, not required). */
typedef struct nf_direction_table {
    uint32_t magic_;                           /* marks a built table                   */
    uint32_t medium_;                          /* 1: the sphere; 0: a hemisphere        */
    uint64_t model_id_;                        /* the model it belongs to               */
    uint64_t generation_;                      /* that model's parameters               */
    float frame_[9];                           /* t, b, n                               */
    float row_cdf_[NF_TABLE_ROWS - 1];         /* the rows' cumulative mass, 0 and 1 aside */
    float pad_[2];                             /* the rows start at byte 128            */
    float rows_[NF_TABLE_ROWS][NF_TABLE_COLS]; /* a row's mass, then its columns'
                                                * cumulative shares, 0 and 1 aside       */
} nf_direction_table;

/* Draws a direction from the table: u[0], u[1] in [0, 1) (values outside are clamped; NaN is
 * refused) give dir, a unit vector, and, if pdf is not NULL, *pdf, its density per steradian
 * (as nf_table_pdf of dir, within rounding), clamped to [FLT_MIN, FLT_MAX].
 * Errors (nothing written): NF_ERROR_INVALID_ARGUMENT (NULL, a table never built, a table of
 * another model, NaN in u), NF_ERROR_STALE. Thread-safe; never allocates. */
nf_status nf_table_sample(const nf_model *m, const nf_direction_table *table, const float u[2],
                          float dir[3], float *pdf);

/* The table's density of dir (any finite direction with squared length above 1e-30; the
 * library normalizes it), per steradian: 0 at and below a surface table's horizon, positive
 * above it. Errors as nf_table_sample (a bad direction is NF_ERROR_INVALID_ARGUMENT).
 * Thread-safe; never allocates. */
nf_status nf_table_pdf(const nf_model *m, const nf_direction_table *table, const float dir[3],
                       float *pdf);

/* ---- A render thread's tables, by cells of the scene ----------------------------------------- */

/* A cache of tables keyed by cells of shading contexts. The normal's cell first: each face of
 * the cube around the origin cut into normal_cells x normal_cells squares, an odd number so
 * that the axes are cells' centres (a wall facing +x gets a table about +x exactly). Then,
 * along the two axes other than the face's, a grid of position_cells over the model's bounds
 * (nf_config.bounds_min / bounds_max); along the face's axis, the offset of the plane through
 * the position with the normal cell's normal, rounded to a sixteenth of a grid cell. A cell's
 * table is built on first use from a point prepared at the cell's centre: the grid cell's
 * centre on that plane, so that a surface's table is asked on the surface (on it exactly for a
 * wall at a multiple of the step, such as the bounds' faces), with the normal cell's normal as
 * the normal and as wo (a model that reads wo, sh_bands > 0, is tabulated for that wo alone).
 * Contexts in a medium are refused (NF_ERROR_INVALID_ARGUMENT): the phase function's lobe
 * follows wo, which one table per cell cannot; ask them at a shading point. A model with a
 * custom prior is tabulated with the model's own callbacks at the centre context. A cell's
 * table depends only on the cell and the model, the same for any order of the finds and any
 * number of threads; which cells of a full bucket (below) go without depends on the order.
 *
 * Memory: nf_table_cache_create allocates everything, capacity tables of 2,176 bytes and 16
 * bytes each for their keys, from the config's allocator; nothing is allocated afterwards.
 * Cells hash to buckets of 8 tables; a cell whose bucket is full gets no table (the find says
 * so, and stats.full counts it): ask that vertex at a shading point. Give the cache room for
 * about three times the cells a render visits, and a bucket overflows once in some 250. A
 * table is kept until the model changes: a find with another model, or after the parameters
 * changed, forgets every table first (O(1): a new epoch) and reuses their memory.
 *
 * Cost per thread: caches share nothing, so each render thread's builds the cells that thread
 * visits. T threads hold T x capacity x 2,192 bytes (8.6 MiB each at the default: 550 MiB for
 * 64 threads) and build up to T times one thread's tables, each about NF_TABLE_CELLS point
 * densities; both are bounded by capacity, which the renderer sets from the cells a render visits.
 *
 * Thread-safety: a cache belongs to one thread at a time (one per render thread); its calls
 * never overlap. The models it is asked about may be shared (const). */
typedef struct nf_table_cache nf_table_cache;

typedef struct nf_table_cache_config {
    uint32_t capacity;       /* tables kept, 1..2^24; default 4096 (8.6 MiB)                  */
    uint32_t position_cells; /* grid cells per axis of the model's bounds, 1..1024; default 16 */
    uint32_t normal_cells;   /* cells per side of a face of the normals' cube, odd, 1..15;
                              * default 3 (54 directions)                                     */
    nf_allocator allocator;  /* optional; both NULL: malloc and free                          */
    uint32_t magic_;         /* set by nf_table_cache_config_init                             */
} nf_table_cache_config;

/* The defaults above. NULL is ignored. Thread-safe. */
void nf_table_cache_config_init(nf_table_cache_config *cfg);

/* Creates a cache. Errors: NF_ERROR_INVALID_ARGUMENT (NULL, a config not initialized by
 * nf_table_cache_config_init, a field out of its range; the message names it),
 * NF_ERROR_OUT_OF_MEMORY. *out is NULL on error. Thread-safe. */
nf_status nf_table_cache_create(const nf_table_cache_config *cfg, nf_table_cache **out);

/* Frees the cache and its tables. NULL is a no-op. */
void nf_table_cache_destroy(nf_table_cache *c);

/* The table of ctx's cell for model m (ctx: a finite position and a finite normal of squared
 * length above 1e-30; wo and phase_g are not read).
 * build = 0: *table is the cell's table, or NULL when the cache holds none. build = 1: a
 * missing table is built first (NF_TABLE_CELLS point densities; renderers that time their passes
 * can time this call alone and leave one-time builds out), or *table is NULL when the cell's
 * bucket is full. *table is valid until a find with another model or new parameters, or the
 * cache's destruction. A find that hits starts the loads of its table's cache lines (a
 * prefetch, where the compiler has one), so that nf_table_sample and nf_table_pdf right after
 * wait once for a table that is not in the processor's caches, not twice; a hit whose table is
 * not used pays for those loads. Errors (*table NULL): NF_ERROR_INVALID_ARGUMENT (NULL, a bad
 * context, a medium context), NF_ERROR_STALE or NF_ERROR_NUMERIC from the build. Never
 * allocates. */
nf_status nf_table_cache_find(nf_table_cache *c, const nf_model *m, const nf_context *ctx,
                              int build, const nf_direction_table **table);

/* What a cache has done since its creation: finds, the tables it built, and the finds with
 * build = 1 that found their cell's bucket full. */
typedef struct nf_table_cache_stats {
    uint64_t finds;
    uint64_t builds;
    uint64_t full;
} nf_table_cache_stats;

/* *stats of cache c. Errors: NF_ERROR_INVALID_ARGUMENT (NULL). */
nf_status nf_table_cache_get_stats(const nf_table_cache *c, nf_table_cache_stats *stats);

#endif /* NISFLOW_SRC_DIRECTION_TABLE_H */
