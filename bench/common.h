/*
 * common.h - what every part of the benchmark program shares: the operations it times, the
 * options the command line sets, and the names the output gives them.
 *
 * The program is split by job, in the style of zstd's programs/:
 *
 *   harness.c   measurement machinery that knows nothing of libnisflow: clock, CPU load of
 *               other processes, peak memory, CPU name, random numbers, a counting
 *               allocator, a pool of persistent threads.
 *   setup.c     what a preset's cases run on, prepared outside any timing: the model with
 *               randomized parameters, its FLOP counts, the inputs, the ring of prepared
 *               shading points, and the start-up checks of sharding and shading points.
 *   cases.c     one case timed: the timed loops of every op, repetitions and their median,
 *               re-measuring when the machine was busy, the checks of what the calls wrote.
 *   report.c    the results table (plain text and Markdown), the targets, the JSON file.
 *   nf_bench.c  the command line and main.
 */
#ifndef NF_BENCH_COMMON_H
#define NF_BENCH_COMMON_H

#include <stddef.h>

#include <nisflow/nisflow.h>
#include "point_batch.h"
#include "direction_table.h"
#include "shading_point.h"

#define NFB_STREAM 256u /* n = 1 calls per unit of work at batch 1 */

/* The batched ops come first: they have a row per batch size. The shading-point ops after
 * them are per-call latencies (n = 1) with one row each. */
enum {
    OP_SAMPLE = 0,
    OP_PDF = 1,
    OP_TRAIN = 2,
    OP_GUIDE = 3, /* one step of a guide (guide.h): nf_guide_train_batch, 16 groups */
    OP_BATCHED_COUNT = 4,
    OP_PREPARE = 4,
    OP_POINT_SAMPLE = 5,
    OP_POINT_PDF = 6,
    OP_VERTEX = 7,       /* the recipe: nf_point_prepare + nf_point_sample_and_pdf      */
    OP_VERTEX_CALLS = 8, /* the same questions as three calls: prepare, sample, pdf     */
    OP_TABLE_BUILD = 9,  /* nf_table_build from a prepared point (table.h)                */
    OP_TABLE_VERTEX = 10, /* a vertex from a built table: nf_table_sample + nf_table_pdf   */
    OP_TABLE_FIND = 11,   /* nf_table_cache_find of a cell whose table is built           */
    OP_CELL_VERTEX = 12,  /* a vertex from a cache: table-find, then table-vertex's calls */
    OP_COUNT = 13
};
#define OP_MASK_ALL ((1 << OP_COUNT) - 1)
#define OP_MASK_BATCHED ((1 << OP_BATCHED_COUNT) - 1)
#define OP_MASK_POINT (OP_MASK_ALL & ~OP_MASK_BATCHED)

/* The ops' names in --op, the progress lines, the tables and the JSON. */
extern const char *const OP_NAME[OP_COUNT];

/* The presets: 0 small, 1 large. */
extern const char *const PRESET_NAME[2];

static inline int op_is_point(int op)
{
    return op >= OP_BATCHED_COUNT;
}

/* The ops that draw and evaluate from tables (their outputs a table's, zero below a horizon). */
static inline int op_is_table_vertex(int op)
{
    return op == OP_TABLE_VERTEX || op == OP_CELL_VERTEX;
}

/* The ops that find walls' tables in each thread's cache, filled before the timing. */
static inline int op_finds_walls(int op)
{
    return op == OP_TABLE_FIND || op == OP_CELL_VERTEX;
}

/* What the command line asked for (nf_bench.c's parse_args). */
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
    nf_phi_map phi_map;
    const char *phi_map_name;
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

#endif /* NF_BENCH_COMMON_H */
