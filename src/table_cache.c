/*
 * table_cache.c - a render thread's tables by cells of shading contexts (nisflow/table.h): the
 * cell's key from the context, a free slot in its hash's bucket of eight, the table built on
 * first use from a point prepared at the cell's centre.
 */
#include "internal.h"
#include "direction_table.h"
#include "point_batch.h"

#define NF_TABLE_CACHE_MAGIC 0x4e465443u /* "NFTC" */
#define NF_TABLE_CACHE_WAYS 8u
#define NF_TABLE_CACHE_MAX_CAPACITY (1u << 24)
#define NF_TABLE_CACHE_MAX_POSITION 1024u
#define NF_TABLE_CACHE_MAX_NORMAL 15u

typedef struct nf_table_slot {
    uint64_t key;   /* the cell's key */
    uint32_t epoch; /* the cache's epoch when it was built: another epoch is an empty slot */
    uint32_t table; /* its table: tables[table] */
} nf_table_slot;

struct nf_table_cache {
    nf_allocator alloc;
    uint32_t capacity, position_cells, normal_cells;
    uint32_t bucket_mask, ways; /* a power of two of buckets (a mask, no division), their slots */
    float lo[3], inv_extent[3]; /* the model's bounds, for the grid                          */
    double inv_step[3];         /* planes' steps per unit along each axis                    */
    float normal_at[NF_TABLE_CACHE_MAX_NORMAL]; /* a normal cell's centre component          */
    uint64_t model_id, generation;              /* the parameters whose tables the slots hold */
    uint32_t epoch; /* starts at 1: a zeroed slot is empty (slots are cleared when it wraps) */
    uint32_t used;  /* tables built in this epoch: tables[0 .. used) */
    nf_table_cache_stats stats;
    nf_table_slot *slots;
    nf_direction_table *tables;
};

void nf_table_cache_config_init(nf_table_cache_config *cfg)
{
    if (!cfg)
        return;
    memset(cfg, 0, sizeof *cfg);
    cfg->capacity = 4096;
    cfg->position_cells = 16;
    cfg->normal_cells = 3;
    cfg->magic_ = NF_TABLE_CACHE_MAGIC;
}

nf_status nf_table_cache_create(const nf_table_cache_config *cfg, nf_table_cache **out)
{
    static const char fn[] = "nf_table_cache_create";
    nf_status st;
    if ((st = nf_check_pointers(fn, "cfg", cfg, "out", out, NULL, NULL, NULL, NULL)) != NF_OK)
        return st;
    *out = NULL;
    if (cfg->magic_ != NF_TABLE_CACHE_MAGIC)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                       "%s: cfg was not initialized by nf_table_cache_config_init", fn);
    if (cfg->capacity < 1 || cfg->capacity > NF_TABLE_CACHE_MAX_CAPACITY)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                       "%s: cfg->capacity = %u is out of range: it must "
                       "be 1..%u",
                       fn, cfg->capacity, NF_TABLE_CACHE_MAX_CAPACITY);
    if (cfg->position_cells < 1 || cfg->position_cells > NF_TABLE_CACHE_MAX_POSITION)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                       "%s: cfg->position_cells = %u is out of range: "
                       "it must be 1..%u",
                       fn, cfg->position_cells, NF_TABLE_CACHE_MAX_POSITION);
    if (cfg->normal_cells % 2u == 0u || cfg->normal_cells > NF_TABLE_CACHE_MAX_NORMAL)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                       "%s: cfg->normal_cells = %u is out of range: it "
                       "must be odd, 1..%u",
                       fn, cfg->normal_cells, NF_TABLE_CACHE_MAX_NORMAL);
    if ((cfg->allocator.alloc == NULL) != (cfg->allocator.free == NULL))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                       "%s: cfg->allocator needs both alloc and free, or neither", fn);
    nf_allocator alloc = cfg->allocator.alloc ? cfg->allocator : nf_default_allocator();
    /* 63 bytes more, so that the tables start on a cache line (table.h: a row on two) */
    const size_t bytes =
        sizeof(nf_table_cache) + 63u +
        (size_t)cfg->capacity * (sizeof(nf_table_slot) + sizeof(nf_direction_table));
    unsigned char *block = (unsigned char *)alloc.alloc(alloc.user, bytes);
    if (!block)
        return nf_fail(NF_ERROR_OUT_OF_MEMORY, "%s: could not allocate %zu bytes for %u tables", fn,
                       bytes, cfg->capacity);
    nf_table_cache *c = (nf_table_cache *)block;
    memset(c, 0, sizeof *c);
    c->alloc = alloc;
    c->capacity = cfg->capacity;
    c->position_cells = cfg->position_cells;
    c->normal_cells = cfg->normal_cells;
    c->epoch = 1;
    for (uint32_t i = 0; i < c->normal_cells; ++i)
        c->normal_at[i] = ((float)(2u * i + 1u) - (float)c->normal_cells) / (float)c->normal_cells;
    uint32_t buckets = 1;
    while (buckets * 2u <= cfg->capacity / NF_TABLE_CACHE_WAYS)
        buckets *= 2u;
    c->bucket_mask = buckets - 1u;
    c->ways = cfg->capacity / buckets;
    c->slots = (nf_table_slot *)(block + sizeof *c);
    uintptr_t tables = (uintptr_t)(c->slots + c->capacity);
    c->tables = (nf_direction_table *)((tables + 63u) & ~(uintptr_t)63u);
    memset(c->slots, 0, (size_t)c->capacity * sizeof *c->slots);
    *out = c;
    return NF_OK;
}

void nf_table_cache_destroy(nf_table_cache *c)
{
    if (c)
        c->alloc.free(c->alloc.user, c);
}

/* A cell: what its key is made of, and so its centre. */
typedef struct nf_table_cell_of {
    int axis;        /* the normal's face: its largest component's axis...      */
    float sign;      /* ...and that component's sign                             */
    uint32_t nrm[2]; /* its square on the face, along axes axis + 1 and axis + 2 */
    uint32_t pos[2]; /* the grid cells along those axes                          */
    int64_t plane;   /* the plane's offset in steps                              */
} nf_table_cell_of;

/* ctx's cell and its key. The normal's cell first: the face of the cube its largest component
 * points to, and the square on that face. Along the other two axes the position's grid cells;
 * along the face's axis not the grid but the offset of the cell normal's plane through the
 * position, to the nearest multiple of a sixteenth of a grid cell, so that the centre lies on
 * the surface (a wall's table is asked on the wall, not a half cell in front of it, where the
 * flow was never trained; a wall at a multiple, the bounds' faces among them, exactly) and
 * parallel surfaces in one grid cell get their own. Only arithmetic: no division (the model's
 * scales are the cache's since the epoch began). */
static uint64_t nf_table_cache_cell(const nf_table_cache *c, const nf_context *ctx,
                                    nf_table_cell_of *cell)
{
    const uint32_t r = c->position_cells, b = c->normal_cells;
    const float *n = ctx->normal;
    int axis = fabsf(n[0]) >= fabsf(n[1]) ? 0 : 1;
    axis = fabsf(n[2]) > fabsf(n[axis]) ? 2 : axis;
    const float inv_big = 1.0f / fabsf(n[axis]);
    cell->axis = axis;
    cell->sign = n[axis] > 0.0f ? 1.0f : -1.0f;
    uint64_t key = (uint64_t)(2 * axis + (cell->sign > 0.0f));
    double plane = (double)ctx->position[axis] * cell->sign;
    for (int k = 0; k < 2; ++k) {
        const int a = (axis + 1 + k) % 3;
        cell->nrm[k] = nf_table_cell(0.5f * (n[a] * inv_big + 1.0f), b);
        cell->pos[k] = nf_table_cell((ctx->position[a] - c->lo[a]) * c->inv_extent[a], r);
        key = (key * b + cell->nrm[k]) * r + cell->pos[k];
        plane += (double)ctx->position[a] * c->normal_at[cell->nrm[k]];
    }
    /* within +-2^20 steps of the origin: offsets beyond share the end steps */
    double t = plane * c->inv_step[axis] + 0.5;
    t = t < -1048576.0 ? -1048576.0 : t > 1048575.0 ? 1048575.0 : t;
    int64_t q = (int64_t)t; /* floor, without libm's call in code built for any x86-64 */
    q -= (double)q > t;
    cell->plane = q;
    return key * 2097152u + (uint64_t)(q + 1048576);
}

/* The context at a cell's centre: the grid cells' centres, on the plane's step, with the
 * normal cell's normal as the normal and as wo. (i + 0.5) / b * 2 - 1 is exactly 0 for the
 * middle normal cell of an odd b. */
static void nf_table_cache_centre(const nf_table_cache *c, const nf_table_cell_of *cell,
                                  nf_context *centre)
{
    memset(centre, 0, sizeof *centre);
    const int axis = cell->axis;
    double off = (double)cell->plane / c->inv_step[axis];
    centre->normal[axis] = cell->sign;
    for (int k = 0; k < 2; ++k) {
        const int a = (axis + 1 + k) % 3;
        centre->normal[a] = c->normal_at[cell->nrm[k]];
        centre->position[a] =
            c->lo[a] + ((float)cell->pos[k] + 0.5f) / (float)c->position_cells / c->inv_extent[a];
        off -= (double)centre->position[a] * centre->normal[a];
    }
    centre->position[axis] = (float)(off * cell->sign);
    for (int a = 0; a < 3; ++a)
        centre->wo[a] = centre->normal[a];
}

/* Asks for every cache line of t at once. A draw or a density reads the header, then a row
 * that the header decides: two misses one after the other where the tables are cold (a
 * render's cells are megabytes), where loads started together cost about one. */
static void nf_table_prefetch(const nf_direction_table *t)
{
#if defined(__GNUC__) || defined(__clang__)
    const char *p = (const char *)t;
    for (size_t off = 0; off < sizeof *t; off += 64u)
        __builtin_prefetch(p + off, 0, 3);
#else
    (void)t;
#endif
}

/* ctx's position finite, its normal finite and not zero: all the cache reads of it. */
static nf_status nf_table_cache_context(const char *fn, const nf_context *ctx)
{
    if (!nf_floats_finite(ctx->position, 3) || !nf_floats_finite(ctx->normal, 3))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: ctx's position or normal is not finite", fn);
    const float *n = ctx->normal;
    if (nf_context_in_medium(ctx))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                       "%s: ctx is in a medium (a zero normal): its phase function follows wo, "
                       "which one table per cell cannot; ask it at a shading point",
                       fn);
    if (!((double)n[0] * n[0] + (double)n[1] * n[1] + (double)n[2] * n[2] > 1e-30))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                       "%s: ctx's normal is too short (squared length at most 1e-30)", fn);
    return NF_OK;
}

nf_status nf_table_cache_find(nf_table_cache *c, const nf_model *m, const nf_context *ctx,
                              int build, const nf_direction_table **table)
{
    static const char fn[] = "nf_table_cache_find";
    nf_status st;
    if ((st = nf_check_pointers(fn, "c", c, "m", m, "ctx", ctx, "table", table)) != NF_OK)
        return st;
    *table = NULL;
    if ((st = nf_table_cache_context(fn, ctx)) != NF_OK)
        return st;
    /* Another model, or new parameters: every table is forgotten at once. */
    if (m->id != c->model_id || nf_generation_moved(m, c->generation)) {
        c->model_id = m->id;
        c->generation = nf_generation_read(m);
        if (++c->epoch == 0u) { /* after 2^32 - 1 models: clear, so no old slot matches */
            memset(c->slots, 0, (size_t)c->capacity * sizeof *c->slots);
            c->epoch = 1;
        }
        c->used = 0;
        for (int a = 0; a < 3; ++a) {
            const double extent = (double)m->cfg.bounds_max[a] - m->cfg.bounds_min[a];
            c->lo[a] = m->cfg.bounds_min[a];
            c->inv_extent[a] = (float)(1.0 / extent);
            c->inv_step[a] = 16.0 * c->position_cells / extent;
        }
    }
    c->stats.finds++;
    nf_table_cell_of cell;
    const uint64_t key = nf_table_cache_cell(c, ctx, &cell);
    /* splitmix64's finalizer: neighbouring cells' keys differ in their low bits only, and a
     * multiplicative hash alone left runs of them on the same slots (measured: 18 times the
     * builds in the client, cells evicting each other) */
    uint64_t h = key + 0x9e3779b97f4a7c15u;
    h = (h ^ (h >> 30)) * 0xbf58476d1ce4e5b9u;
    h = (h ^ (h >> 27)) * 0x94d049bb133111ebu;
    h ^= h >> 31;
    /* Buckets of eight slots: a cell may take any free slot of its bucket, and keeps it until
     * the model changes. A full bucket builds nothing: replacing a table there would let the
     * bucket's cells evict each other on every find, a build each (measured: 18 times the
     * builds in the client with slots replaced in turn). */
    const uint32_t ways = c->ways, first = (uint32_t)(h & c->bucket_mask) * ways;
    /* A bucket fills in order and empties all at once: its live slots come first, and the first
     * dead one ends the search (a branch-free pass over all eight measured 10-20 ns slower). */
    uint32_t s = first;
    for (; s < first + ways && c->slots[s].epoch == c->epoch; ++s)
        if (c->slots[s].key == key) {
            *table = &c->tables[c->slots[s].table];
            nf_table_prefetch(*table);
            return NF_OK;
        }
    if (!build)
        return NF_OK;
    if (s == first + ways) {
        c->stats.full++;
        return NF_OK;
    }
    nf_context centre;
    nf_table_cache_centre(c, &cell, &centre);
    nf_shading_point point;
    if ((st = nf_point_prepare(m, &centre, NULL, &point)) != NF_OK)
        return st;
    /* A failed build leaves the slot free (nf_table_build writes only on success). */
    /* Tables in the order they are built, not by slot: the cells a render visits take that many
     * tables side by side, not capacity's worth of memory scattered by the hash. */
    if ((st = nf_table_build(m, &point, &c->tables[c->used])) != NF_OK)
        return st;
    c->stats.builds++;
    c->slots[s].key = key;
    c->slots[s].epoch = c->epoch;
    c->slots[s].table = c->used;
    *table = &c->tables[c->used++];
    return NF_OK;
}

nf_status nf_table_cache_get_stats(const nf_table_cache *c, nf_table_cache_stats *stats)
{
    nf_status st = nf_check_pointers("nf_table_cache_get_stats", "c", c, "stats", stats, NULL, NULL,
                                     NULL, NULL);
    if (st == NF_OK)
        *stats = c->stats;
    return st;
}
