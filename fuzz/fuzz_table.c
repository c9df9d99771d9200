/*
 * fuzz_table.c - libFuzzer target: the tables of nisflow/table.h on hostile input
 * (docs/robustness.md). The input is a small program. Its first bytes choose a model (the
 * small preset with the cosine or the uniform-direction prior, parameters random up to a
 * scale the program picks, reset for every input so that an input replays alone) and a
 * cache configuration (in and out of range); the rest is a stream of operations on four table
 * slots: build from raw float contexts (NaN, Inf, subnormal, huge, zero vectors), draw from
 * raw u, evaluate raw directions, overwrite a table's bytes after its identity, find in the
 * cache from raw contexts, and change the parameters once.
 *
 * Invariants, checked by abort():
 *   - every status is the documented one: a refused context or point leaves the slot as it
 *     was; a table built before a change of the parameters is NF_ERROR_STALE; a cache config
 *     out of range is refused with *out NULL; a medium or non-finite context is refused by
 *     the cache;
 *   - an intact table's draws are unit directions (within 2e-6) with densities in
 *     [FLT_MIN, FLT_MAX], and its densities, the drawn directions' included, are finite and
 *     >= 0;
 *   - an overwritten table is answered (NF_OK) without a sanitizer report: table.h promises
 *     no more than that.
 */
#include <float.h>
#include <stddef.h>

#include "fuzz_common.h"
#include "point_batch.h"
#include "direction_table.h"
#include "shading_point.h"

enum { SLOTS = 4, MAX_OPS = 48 };

typedef nf_fuzz_reader reader;

static unsigned rd_u8(reader *r) { return nf_fuzz_byte(r); }

static uint32_t rd_u32(reader *r) { return nf_fuzz_u32(r); }

/* A float: raw bits, an edge value, or a value in [-1, 2) (the useful range of u and of
 * positions and directions in the unit box). */
static float rd_float(reader *r)
{
    static const float special[8] = {0.0f, -0.0f, 1.0f, FLT_TRUE_MIN, FLT_MAX, NAN, INFINITY,
                                      0x1.fffffep-1f};
    unsigned sel = rd_u8(r);
    if (sel < 64) {
        uint32_t bits = rd_u32(r);
        float f;
        memcpy(&f, &bits, sizeof f);
        return f;
    }
    if (sel < 96)
        return special[sel & 7u];
    return -1.0f + 3.0f * (float)(rd_u32(r) >> 8) / 16777216.0f;
}

static int finite3(const float *v)
{
    return isfinite(v[0]) && isfinite(v[1]) && isfinite(v[2]);
}

static nf_context rd_context(reader *r)
{
    nf_context c;
    for (int a = 0; a < 3; ++a)
        c.position[a] = rd_float(r);
    for (int a = 0; a < 3; ++a)
        c.normal[a] = (rd_u8(r) & 3u) == 0 ? 0.0f : rd_float(r);
    for (int a = 0; a < 3; ++a)
        c.wo[a] = rd_float(r);
    c.phase_g = rd_float(r);
    return c;
}

/* The two models, made once; their pristine parameters, restored for every input. */
static nf_model *models[2];
static float *pristine[2];

static void make_models(void)
{
    if (models[0])
        return;
    const nf_prior_kind prior[2] = {NF_PRIOR_COSINE, NF_PRIOR_UNIFORM_DIRECTION};
    for (int k = 0; k < 2; ++k) {
        nf_config cfg;
        nf_config_init(&cfg, NF_PRESET_SMALL);
        cfg.prior = prior[k];
        NF_FUZZ_CHECK(nf_model_create(&cfg, &models[k]) == NF_OK, "create");
        size_t n = nf_model_param_count(models[k]);
        pristine[k] = malloc(n * sizeof(float));
        NF_FUZZ_CHECK(pristine[k] != NULL, "out of memory");
        NF_FUZZ_CHECK(nf_model_get_params(models[k], pristine[k]) == NF_OK, "params");
    }
}

/* The model's parameters: pristine plus noise of the program's scale (a deterministic
 * function of the program's bytes). */
static nf_model *program_model(reader *r)
{
    make_models();
    const unsigned k = rd_u8(r) & 1u;
    nf_model *m = models[k];
    const size_t n = nf_model_param_count(m);
    static float p[1u << 16];
    NF_FUZZ_CHECK(n <= sizeof p / sizeof p[0], "a small model");
    const float scale = (float)(rd_u8(r) % 8u) * 0.25f;
    uint32_t seed = rd_u32(r) | 1u;
    for (size_t i = 0; i < n; ++i) {
        seed ^= seed << 13, seed ^= seed >> 17, seed ^= seed << 5;
        p[i] = pristine[k][i] + scale * ((float)(seed >> 8) / 8388608.0f - 1.0f);
    }
    NF_FUZZ_CHECK(nf_model_set_params(m, p) == NF_OK, "set params");
    return m;
}

typedef struct slot {
    nf_direction_table t;
    int built;       /* built on the current parameters */
    int stale;       /* built on earlier ones           */
    int overwritten; /* bytes after the identity flipped */
} slot;

static void check_draw(const nf_model *m, const slot *s, const float u[2])
{
    float dir[3] = {NAN, NAN, NAN}, pdf = NAN, q = NAN;
    nf_status st = nf_table_sample(m, &s->t, u, dir, &pdf);
    if (!s->built && !s->stale) {
        NF_FUZZ_CHECK(st == NF_ERROR_INVALID_ARGUMENT, "a table never built: %d", (int)st);
        return;
    }
    if (s->stale) {
        NF_FUZZ_CHECK(st == NF_ERROR_STALE || st == NF_ERROR_INVALID_ARGUMENT,
                      "a stale table: %d", (int)st);
        return;
    }
    if (!isfinite(u[0]) || !isfinite(u[1])) {
        NF_FUZZ_CHECK(st == NF_ERROR_INVALID_ARGUMENT, "NaN u accepted");
        return;
    }
    NF_FUZZ_CHECK(st == NF_OK, "a draw refused: %d", (int)st);
    if (s->overwritten)
        return;
    const double len = sqrt((double)dir[0] * dir[0] + (double)dir[1] * dir[1] +
                            (double)dir[2] * dir[2]);
    NF_FUZZ_CHECK(fabs(len - 1.0) < 2e-6, "a direction of length %g", len);
    NF_FUZZ_CHECK(pdf >= FLT_MIN && pdf <= FLT_MAX, "a draw's density %g", (double)pdf);
    NF_FUZZ_CHECK(nf_table_pdf(m, &s->t, dir, &q) == NF_OK, "the draw's own density refused");
    /* the same cell's density, or within rounding of an edge the neighbour's (or a surface
     * table's 0 at the horizon): tests/correctness/test_table.c checks how often */
    NF_FUZZ_CHECK(isfinite(q) && q >= 0.0f, "the draw's density by nf_table_pdf: %g", (double)q);
}

static void check_density(const nf_model *m, const slot *s, const float d[3])
{
    float pdf = NAN;
    nf_status st = nf_table_pdf(m, &s->t, d, &pdf);
    if (!s->built || s->stale) {
        NF_FUZZ_CHECK(st != NF_OK, "a table never built or stale answered");
        return;
    }
    const double len2 = (double)d[0] * d[0] + (double)d[1] * d[1] + (double)d[2] * d[2];
    if (!finite3(d) || !(len2 > 1e-30)) {
        NF_FUZZ_CHECK(st == NF_ERROR_INVALID_ARGUMENT, "a bad direction accepted");
        return;
    }
    NF_FUZZ_CHECK(st == NF_OK, "a density refused: %d", (int)st);
    if (!s->overwritten)
        NF_FUZZ_CHECK(isfinite(pdf) && pdf >= 0.0f && pdf <= FLT_MAX, "a density %g",
                      (double)pdf);
}

static void run_cache(const nf_model *m, reader *r, nf_table_cache *cache, int changed)
{
    nf_context c = rd_context(r);
    const int build = (int)(rd_u8(r) & 1u);
    const nf_direction_table *t = (const nf_direction_table *)&c; /* must be reset */
    nf_status st = nf_table_cache_find(cache, m, &c, build, &t);
    const int bad = !finite3(c.position) || !finite3(c.normal) ||
                    !((double)c.normal[0] * c.normal[0] + (double)c.normal[1] * c.normal[1] +
                          (double)c.normal[2] * c.normal[2] >
                      1e-30);
    if (bad) {
        NF_FUZZ_CHECK(st == NF_ERROR_INVALID_ARGUMENT && t == NULL, "a bad context found: %d",
                      (int)st);
        return;
    }
    NF_FUZZ_CHECK(st == NF_OK || st == NF_ERROR_NUMERIC, "a find failed: %d", (int)st);
    if (st != NF_OK || !t)
        return;
    float u[2] = {rd_float(r), rd_float(r)}, dir[3], pdf;
    if (isfinite(u[0]) && isfinite(u[1]))
        NF_FUZZ_CHECK(nf_table_sample(m, t, u, dir, &pdf) == NF_OK, "a found table refused");
    (void)changed;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    reader r = {data, size};
    nf_model *m = program_model(&r);
    nf_table_cache_config cc;
    nf_table_cache_config_init(&cc);
    cc.capacity = 1u + rd_u8(&r) % 64u;
    cc.position_cells = (uint32_t)(rd_u8(&r) % 4u == 0 ? rd_u32(&r) % 2048u : 1u + rd_u8(&r));
    cc.normal_cells = rd_u8(&r) % 18u;
    nf_table_cache *cache = (nf_table_cache *)&cc;
    nf_status st = nf_table_cache_create(&cc, &cache);
    const int cfg_ok = cc.position_cells >= 1 && cc.position_cells <= 1024 &&
                       cc.normal_cells % 2u == 1u && cc.normal_cells <= 15;
    NF_FUZZ_CHECK(cfg_ok ? st == NF_OK : (st == NF_ERROR_INVALID_ARGUMENT && !cache),
                  "cache config: %d", (int)st);
    static slot slots[SLOTS];
    memset(slots, 0, sizeof slots);
    int changed = 0;
    for (int op = 0; op < MAX_OPS && r.n > 0; ++op) {
        slot *s = &slots[rd_u8(&r) % SLOTS];
        switch (rd_u8(&r) % 6u) {
        case 0: { /* build from a raw context */
            nf_context c = rd_context(&r);
            nf_shading_point p;
            if (nf_point_prepare(m, &c, NULL, &p) != NF_OK)
                break;
            nf_direction_table before = s->t;
            st = nf_table_build(m, &p, &s->t);
            NF_FUZZ_CHECK(st == NF_OK || st == NF_ERROR_NUMERIC, "a build failed: %d", (int)st);
            if (st == NF_OK)
                s->built = 1, s->stale = 0, s->overwritten = 0;
            else
                NF_FUZZ_CHECK(memcmp(&before, &s->t, sizeof before) == 0,
                              "a failed build wrote the table");
            break;
        }
        case 1: { /* draw */
            float u[2] = {rd_float(&r), rd_float(&r)};
            check_draw(m, s, u);
            break;
        }
        case 2: { /* evaluate */
            float d[3] = {rd_float(&r), rd_float(&r), rd_float(&r)};
            check_density(m, s, d);
            break;
        }
        case 3: { /* overwrite bytes after the identity */
            if (!s->built)
                break;
            unsigned char *b = (unsigned char *)&s->t;
            const size_t head = offsetof(nf_direction_table, frame_);
            for (unsigned k = 1u + rd_u8(&r) % 8u; k > 0; --k)
                b[head + rd_u32(&r) % (sizeof s->t - head)] ^= (unsigned char)(1u + rd_u8(&r));
            s->overwritten = 1;
            break;
        }
        case 4: /* the cache */
            if (cache != NULL && cfg_ok)
                run_cache(m, &r, cache, changed);
            break;
        default: /* new parameters, once: every built table goes stale */
            if (changed)
                break;
            changed = 1;
            {
                const size_t n = nf_model_param_count(m);
                float *p = malloc(n * sizeof(float));
                NF_FUZZ_CHECK(p != NULL, "out of memory");
                NF_FUZZ_CHECK(nf_model_get_params(m, p) == NF_OK, "params");
                p[rd_u32(&r) % n] += 0.125f;
                NF_FUZZ_CHECK(nf_model_set_params(m, p) == NF_OK, "set params");
                free(p);
            }
            for (int k = 0; k < SLOTS; ++k)
                if (slots[k].built)
                    slots[k].built = 0, slots[k].stale = 1;
            break;
        }
    }
    if (cfg_ok)
        nf_table_cache_destroy(cache);
    return 0;
}
