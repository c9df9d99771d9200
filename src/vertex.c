/*
 * vertex.c - one render thread's answers at path vertices (nisflow/vertex.h): a vertex is
 * answered from its cell's table when the caller allows it and the cell has one, else at a
 * shading point; cells that had none are noted and built by nf_vertex_build, outside the
 * vertex's own latency.
 */
#include <stdio.h>

#include "direction_table.h"
#include "internal.h"

#define NF_VERTEX_MAGIC 0x4e465658u /* "NFVX" */
#define NF_VERTEX_PENDING 64u

struct nf_vertex {
    nf_shading_point point; /* first: the allocator's alignment is the struct's               */
    nf_allocator alloc;
    nf_table_cache *cache; /* NULL: tables off                                               */
    const nf_model *model; /* of the last successful set; NULL: none                         */
    const nf_direction_table *table; /* the vertex's table; NULL: the point answers        */
    uint64_t points, tables;
    uint32_t npending;
    nf_context pending[NF_VERTEX_PENDING]; /* cells without a table, by a context in them     */
};

/* An inner call's error under this entry point's name: "nf_point_pdf: x" becomes "fn: x". */
static nf_status nf_vertex_fail(const char *fn, nf_status st)
{
    char inner[256];
    const char *msg = nf_last_error_message();
    const char *colon = strstr(msg, ": ");
    snprintf(inner, sizeof inner, "%s", colon ? colon + 2 : msg);
    return nf_fail(st, "%s: %s", fn, inner);
}

void nf_vertex_config_init(nf_vertex_config *cfg)
{
    if (!cfg)
        return;
    nf_table_cache_config tc;
    nf_table_cache_config_init(&tc);
    memset(cfg, 0, sizeof *cfg);
    cfg->tables = 1;
    cfg->capacity = tc.capacity;
    cfg->position_cells = tc.position_cells;
    cfg->normal_cells = tc.normal_cells;
    cfg->magic_ = NF_VERTEX_MAGIC;
}

nf_status nf_vertex_create(const nf_vertex_config *cfg_in, nf_vertex **out)
{
    static const char fn[] = "nf_vertex_create";
    if (!out)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: out is NULL", fn);
    *out = NULL;
    nf_vertex_config cfg;
    if (cfg_in)
        cfg = *cfg_in;
    else
        nf_vertex_config_init(&cfg);
    if (cfg.magic_ != NF_VERTEX_MAGIC)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                       "%s: cfg was not initialized by nf_vertex_config_init", fn);
    if (cfg.tables > 1)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: cfg->tables = %u: it must be 0 or 1", fn,
                       cfg.tables);
    if ((cfg.allocator.alloc == NULL) != (cfg.allocator.free == NULL))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                       "%s: cfg->allocator needs both alloc and free, or neither", fn);
    nf_allocator alloc = cfg.allocator.alloc ? cfg.allocator : nf_default_allocator();
    nf_table_cache *cache = NULL;
    if (cfg.tables) {
        nf_table_cache_config tc;
        nf_table_cache_config_init(&tc);
        tc.capacity = cfg.capacity;
        tc.position_cells = cfg.position_cells;
        tc.normal_cells = cfg.normal_cells;
        tc.allocator = cfg.allocator;
        nf_status st = nf_table_cache_create(&tc, &cache);
        if (st != NF_OK)
            return nf_vertex_fail(fn, st);
    }
    nf_vertex *v = (nf_vertex *)alloc.alloc(alloc.user, sizeof *v);
    if (!v) {
        nf_table_cache_destroy(cache);
        return nf_fail(NF_ERROR_OUT_OF_MEMORY, "%s: could not allocate %zu bytes", fn, sizeof *v);
    }
    memset(v, 0, sizeof *v);
    v->alloc = alloc;
    v->cache = cache;
    *out = v;
    return NF_OK;
}

void nf_vertex_destroy(nf_vertex *v)
{
    if (!v)
        return;
    nf_table_cache_destroy(v->cache);
    v->alloc.free(v->alloc.user, v);
}

nf_status nf_vertex_set(nf_vertex *v, const nf_model *m, const nf_context *ctx,
                        const nf_prior_callbacks *prior, nf_vertex_route route)
{
    static const char fn[] = "nf_vertex_set";
    nf_status st;
    if (!v || !m || !ctx)
        return nf_check_pointers(fn, "v", v, "m", m, "ctx", ctx, NULL, NULL);
    v->model = NULL;
    v->table = NULL;
    if (route != NF_VERTEX_POINT && route != NF_VERTEX_TABLE)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                       "%s: route = %d is not NF_VERTEX_POINT or NF_VERTEX_TABLE", fn, (int)route);
    /* The context is checked by the cache's find or the point's preparation, whichever runs. */
    const int surface = ctx->normal[0] != 0.0f || ctx->normal[1] != 0.0f || ctx->normal[2] != 0.0f;
    if (route == NF_VERTEX_TABLE && v->cache && !prior && surface) {
        const nf_direction_table *t = NULL;
        if ((st = nf_table_cache_find(v->cache, m, ctx, 0, &t)) != NF_OK)
            return nf_vertex_fail(fn, st);
        if (t) {
            v->model = m;
            v->table = t;
            v->tables++;
            return NF_OK;
        }
        if (v->npending < NF_VERTEX_PENDING)
            v->pending[v->npending++] = *ctx;
    }
    if ((st = nf_point_prepare(m, ctx, prior, &v->point)) != NF_OK)
        return nf_vertex_fail(fn, st);
    v->model = m;
    v->points++;
    return NF_OK;
}

nf_status nf_vertex_sample(nf_vertex *v, const float u[2], float dir[3], float *pdf, size_t n,
                           const float *dirs, float *pdfs)
{
    static const char fn[] = "nf_vertex_sample";
    nf_status st;
    if (!v || !u || !dir)
        return nf_check_pointers(fn, "v", v, "u", u, "dir", dir, NULL, NULL);
    if (n > 0 && (!dirs || !pdfs))
        return nf_check_pointers(fn, "dirs", dirs, "pdfs", pdfs, NULL, NULL, NULL, NULL);
    if (!v->model)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: no vertex is set (nf_vertex_set)", fn);
    if (!isfinite(u[0]) || !isfinite(u[1]))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: u is not finite", fn);
    if (v->table) {
        /* Into locals first, so that a refusal writes nothing; the table's calls check each
         * direction themselves. */
        float d[3], p, q[16];
        if (n > 16 && (st = nf_validate_directions(fn, "dirs", n, dirs)) != NF_OK)
            return st;
        if ((st = nf_table_sample(v->model, v->table, u, d, &p)) != NF_OK)
            return nf_vertex_fail(fn, st);
        for (size_t i = 0; i < n; ++i)
            if ((st = nf_table_pdf(v->model, v->table, dirs + 3 * i, i < 16 ? &q[i] : &pdfs[i])) !=
                NF_OK)
                return nf_vertex_fail(fn, st);
        memcpy(pdfs, q, (n < 16 ? n : 16) * sizeof *q);
        memcpy(dir, d, sizeof d);
        if (pdf)
            *pdf = p;
        return NF_OK;
    }
    if (n == 1)
        st = nf_point_sample_and_pdf(v->model, &v->point, u, dir, pdf, dirs, pdfs);
    else if ((st = nf_point_pdf(v->model, &v->point, n, dirs, pdfs)) == NF_OK)
        st = nf_point_sample(v->model, &v->point, 1, u, dir, pdf);
    return st == NF_OK ? NF_OK : nf_vertex_fail(fn, st);
}

nf_status nf_vertex_pdf(nf_vertex *v, size_t n, const float *dirs, float *pdfs)
{
    static const char fn[] = "nf_vertex_pdf";
    nf_status st;
    if (!v)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: v is NULL", fn);
    if (n == 0)
        return NF_OK;
    if (!dirs || !pdfs)
        return nf_check_pointers(fn, "dirs", dirs, "pdfs", pdfs, NULL, NULL, NULL, NULL);
    if (!v->model)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: no vertex is set (nf_vertex_set)", fn);
    if (v->table) {
        if (n > 16 && (st = nf_validate_directions(fn, "dirs", n, dirs)) != NF_OK)
            return st; /* a refusal writes nothing, though the densities go 16 at a time */
        float p[16];
        for (size_t b = 0; b < n; b += 16) { /* a stale table fails the first, writing nothing */
            size_t k = n - b < 16 ? n - b : 16;
            for (size_t i = 0; i < k; ++i)
                if ((st = nf_table_pdf(v->model, v->table, dirs + 3 * (b + i), &p[i])) != NF_OK)
                    return nf_vertex_fail(fn, st);
            memcpy(pdfs + b, p, k * sizeof *p);
        }
        return NF_OK;
    }
    st = nf_point_pdf(v->model, &v->point, n, dirs, pdfs);
    return st == NF_OK ? NF_OK : nf_vertex_fail(fn, st);
}

nf_status nf_vertex_build(nf_vertex *v)
{
    static const char fn[] = "nf_vertex_build";
    if (!v)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: v is NULL", fn);
    nf_status first = NF_OK;
    const uint32_t n = v->npending;
    v->npending = 0;
    if (!v->cache || !v->model || n == 0)
        return NF_OK;
    for (uint32_t i = 0; i < n; ++i) {
        const nf_direction_table *t = NULL;
        nf_status st = nf_table_cache_find(v->cache, v->model, &v->pending[i], 1, &t);
        if (st == NF_ERROR_STALE)
            return nf_vertex_fail(fn, st);
        if (st != NF_OK && first == NF_OK)
            first = nf_vertex_fail(fn, st);
    }
    return first;
}

nf_status nf_vertex_get_stats(const nf_vertex *v, nf_vertex_stats *out)
{
    static const char fn[] = "nf_vertex_get_stats";
    nf_status st;
    if ((st = nf_check_pointers(fn, "v", v, "out", out, NULL, NULL, NULL, NULL)) != NF_OK)
        return st;
    memset(out, 0, sizeof *out);
    out->points = v->points;
    out->tables = v->tables;
    if (v->cache) {
        nf_table_cache_stats cs;
        if ((st = nf_table_cache_get_stats(v->cache, &cs)) != NF_OK)
            return st;
        out->builds = cs.builds;
        out->full = cs.full;
    }
    return NF_OK;
}
