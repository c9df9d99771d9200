/*
 * fuzz_point.c - libFuzzer target: the shading-point API (nisflow/point.h) on hostile input
 * (docs/robustness.md). The input is a small program. Its first bytes choose a model (an
 * architecture that fits the point's cache or not, a prior, the kernels) and the scale of
 * its random parameters, up to FLT_MAX; the rest is a stream of operations on four point
 * slots: prepare from raw float contexts (NaN, Inf, subnormal, huge, zero vectors; with or
 * without per-point prior callbacks), sample raw u, evaluate raw directions, batches of
 * points, flip bits of a point, change the parameters (training steps, nf_set_params,
 * nf_apply_gradient, refused changes), copy points, and use them with a clone.
 *
 * Invariants, checked by abort():
 *   - every status is the documented one: a context, direction or u is refused
 *     (NF_ERROR_INVALID_ARGUMENT) exactly when point.h / model.h's rules say so (finite;
 *     squared length above 1e-30), an unprepared point or one whose header bytes (context,
 *     mark, model, generation, normal, cache flag, check) were flipped is refused, a point
 *     prepared before a change of the parameters is NF_ERROR_STALE, a point used with a
 *     clone is refused;
 *   - a refused call writes nothing, and a refused nf_point_prepare leaves the slot's bytes;
 *   - an accepted call gives unit directions (within 2e-6, as
 *     tests/robustness/test_numeric_robustness) and finite positive densities, the same bits
 *     as nf_sample / nf_pdf on the point's context (as one call of n, tiled for n >= 3, and
 *     as calls of 1).
 * Bytes of a point outside its header (reserved, cache) are flipped too; the library does not
 * promise to detect that, so such a point must only not crash the library or trip a
 * sanitizer. Its prior callbacks are never flipped: calling a corrupted function pointer would
 * crash by design, not by a bug.
 */
#include <float.h>
#include <stddef.h>

#include "fuzz_common.h"

enum { SLOTS = 4, MAX_N = 20, MAX_OPS = 32 };

/* ---- reading the program --------------------------------------------------------------------- */

typedef struct reader {
    const uint8_t *p;
    size_t n, at;
} reader;

static unsigned rd_u8(reader *r) { return r->at < r->n ? r->p[r->at++] : 0u; }

static uint32_t rd_u32(reader *r)
{
    uint32_t v = 0;
    for (int i = 0; i < 4; ++i)
        v |= (uint32_t)rd_u8(r) << (8 * i);
    return v;
}

static float bits_to_float(uint32_t bits)
{
    float f;
    memcpy(&f, &bits, sizeof f);
    return f;
}

/* A float: raw bits (any value, NaN and subnormals included) or one of the edge values. */
static float rd_float(reader *r)
{
    static const float special[16] = {
        0.0f,         -0.0f,   1.0f,    -1.0f,    0.5f, 1e-20f,   -1e-15f,        1e-15f,
        FLT_TRUE_MIN, FLT_MIN, FLT_MAX, -FLT_MAX, NAN,  INFINITY, 0x1.fffffep-1f, 0.25f,
    };
    unsigned sel = rd_u8(r);
    if (sel < 96)
        return bits_to_float(rd_u32(r));
    if (sel < 176)
        return special[sel & 15u];
    /* small ordinary values, in steps of 1/64 in [-2, 2) */
    return ((float)sel - 176.0f) / 64.0f * 2.0f - 1.0f;
}

/* ---- the library's documented input rules ---------------------------------------------------- */

static int vector_ok(const float v[3])
{
    if (!isfinite(v[0]) || !isfinite(v[1]) || !isfinite(v[2]))
        return 0;
    double len2 = (double)v[0] * v[0] + (double)v[1] * v[1] + (double)v[2] * v[2];
    return len2 > 1e-30;
}

/* A zero normal is a point in a medium, whose phase_g must be finite within +-0.99. */
static int context_ok(const nf_context *c)
{
    int medium = c->normal[0] == 0.0f && c->normal[1] == 0.0f && c->normal[2] == 0.0f;
    return isfinite(c->position[0]) && isfinite(c->position[1]) && isfinite(c->position[2]) &&
           (medium ? fabsf(c->phase_g) <= NF_PHASE_G_MAX : vector_ok(c->normal)) &&
           vector_ok(c->wo);
}

/* ---- slots ---------------------------------------------------------------------------------- */

typedef struct slot {
    nf_shading_point sp;
    nf_shading_point pristine; /* the bytes nf_point_prepare wrote                      */
    int prepared;              /* pristine is meaningful                                  */
    nf_context ctx;            /* the context it was prepared from                        */
    uint64_t epoch;            /* the parameter epoch it was prepared in                  */
} slot;

/* The header (every field up to and including check_, which nf_point_hash covers): a flip
 * there must be refused. */
static int identity_byte(size_t offset)
{
    return offset < offsetof(nf_shading_point, check_) + sizeof(uint32_t);
}

static int prior_byte(size_t offset)
{
    return offset >= offsetof(nf_shading_point, prior_) &&
           offset < offsetof(nf_shading_point, prior_) + sizeof(nf_prior_callbacks);
}

/* What a call on a slot must do: its point is refused (unprepared, or an identifying byte
 * flipped), stale, or valid; `exact` is 0 when other bytes were flipped (the status is then
 * still determined by the identifying bytes, the results are not). */
enum { S_VALID, S_REFUSED, S_STALE };

static int slot_state(const slot *s, uint64_t epoch, int *exact)
{
    *exact = 1;
    if (!s->prepared)
        return S_REFUSED;
    if (memcmp(&s->sp, &s->pristine, sizeof s->sp) == 0) /* the common case, in one call */
        return s->epoch == epoch ? S_VALID : S_STALE;
    const unsigned char *a = (const unsigned char *)&s->sp;
    const unsigned char *b = (const unsigned char *)&s->pristine;
    for (size_t i = 0; i < sizeof s->sp; ++i) {
        if (a[i] == b[i])
            continue;
        if (identity_byte(i))
            return S_REFUSED;
        *exact = 0;
    }
    return s->epoch == epoch ? S_VALID : S_STALE;
}

/* The states of a call's points and inputs, and whether status `st` is the documented one.
 * Where several refusals apply (a stale point and a bad u, a stale and an unprepared point
 * in one batch), point.h does not order the checks: each of them is allowed. */
typedef struct expect {
    int refused, stale, inputs_ok, exact;
} expect;

static void expect_slot(expect *e, const slot *s, uint64_t epoch)
{
    int exact;
    int state = slot_state(s, epoch, &exact);
    e->refused |= state == S_REFUSED;
    e->stale |= state == S_STALE;
    e->exact &= exact;
}

static int status_allowed(nf_status st, const expect *e)
{
    switch (st) {
    case NF_OK: return !e->refused && !e->stale && e->inputs_ok;
    case NF_ERROR_INVALID_ARGUMENT: return e->refused || !e->inputs_ok;
    case NF_ERROR_STALE: return e->stale;
    default: return 0;
    }
}

/* ---- the machine ----------------------------------------------------------------------------- */

typedef struct machine {
    nf_model *m;
    nf_model *other; /* a second model of the same configuration, for op_clone */
    float *buf;      /* nf_param_count floats of scratch */
    nf_prior_kind prior;
    uint64_t epoch; /* counts accepted changes of the parameters */
    slot slots[SLOTS];
    reader in;
} machine;

static void check_unit_and_pdfs(size_t n, const float *dir, const float *pdf, const char *what)
{
    for (size_t i = 0; i < n; ++i) {
        if (dir) {
            const float *d = dir + 3 * i;
            double len = sqrt((double)d[0] * d[0] + (double)d[1] * d[1] + (double)d[2] * d[2]);
            NF_FUZZ_CHECK(fabs(len - 1.0) <= 2e-6, "%s: direction %zu has length %.9g", what, i,
                          len);
        }
        if (pdf)
            NF_FUZZ_CHECK(isfinite(pdf[i]) && pdf[i] > 0.0f, "%s: pdf[%zu] = %g", what, i,
                          (double)pdf[i]);
    }
}

static const float sentinel = -7.5e33f;

static void fill(float *v, size_t n)
{
    for (size_t i = 0; i < n; ++i)
        v[i] = sentinel;
}

static int untouched(const float *v, size_t n)
{
    for (size_t i = 0; i < n; ++i)
        if (memcmp(&v[i], &sentinel, sizeof sentinel) != 0)
            return 0;
    return 1;
}

static void op_prepare(machine *mc)
{
    reader *r = &mc->in;
    slot *s = &mc->slots[rd_u8(r) % SLOTS];
    unsigned flags = rd_u8(r);
    nf_context c;
    for (int i = 0; i < 3; ++i)
        c.position[i] = rd_float(r);
    for (int i = 0; i < 3; ++i)
        c.normal[i] = rd_float(r);
    for (int i = 0; i < 3; ++i)
        c.wo[i] = rd_float(r);
    /* Flag 8: a point in a medium (zero normal), g from 16 (within +-0.99) or any float;
     * else a surface, whose g is garbage that must not matter. */
    c.phase_g = (flags & 16u) ? ((float)rd_u8(r) / 255.0f * 2.0f - 1.0f) * NF_PHASE_G_MAX
                              : rd_float(r);
    if (flags & 8u)
        c.normal[0] = c.normal[1] = c.normal[2] = 0.0f;
    /* Per-point callbacks: the fuzz prior's functions with a user pointer of their own (they
     * ignore it), so results still equal the batch calls'; or with a callback missing. */
    nf_prior_callbacks cb = nf_fuzz_callbacks();
    cb.user = s;
    if (flags & 4u)
        cb.sample = NULL;
    const nf_prior_callbacks *prior = (flags & 3u) == 3u ? &cb : NULL;
    int ok = context_ok(&c) && (!prior || (mc->prior == NF_PRIOR_CUSTOM && cb.sample != NULL));
    nf_shading_point before = s->sp;
    nf_status st = nf_point_prepare(mc->m, &c, prior, &s->sp);
    NF_FUZZ_CHECK(st == (ok ? NF_OK : NF_ERROR_INVALID_ARGUMENT), "nf_point_prepare: %d", (int)st);
    if (st != NF_OK) {
        NF_FUZZ_CHECK(memcmp(&before, &s->sp, sizeof before) == 0,
                      "a refused nf_point_prepare wrote the point");
        return;
    }
    s->pristine = s->sp;
    s->prepared = 1;
    s->ctx = c;
    s->epoch = mc->epoch;
}

/* nf_sample's bits for n u pairs at the points' contexts: one call of n, n calls of 1. */
static void check_against_batch(const nf_model *m, const nf_context *rep, size_t n, const float *u,
                                const float *dir, const float *pdf)
{
    float d[3 * MAX_N], p[MAX_N];
    NF_FUZZ_CHECK(nf_sample(m, n, rep, u, d, p) == NF_OK, "nf_sample");
    for (size_t i = 0; i < n; ++i)
        NF_FUZZ_CHECK(memcmp(d + 3 * i, dir + 3 * i, 3 * sizeof *d) == 0 &&
                          memcmp(p + i, pdf + i, sizeof *p) == 0,
                      "point sample %zu of %zu differs from nf_sample: u (%a, %a), point (%a, "
                      "%a, %a) %a, nf_sample (%a, %a, %a) %a",
                      i, n, (double)u[2 * i], (double)u[2 * i + 1], (double)dir[3 * i],
                      (double)dir[3 * i + 1], (double)dir[3 * i + 2], (double)pdf[i],
                      (double)d[3 * i], (double)d[3 * i + 1], (double)d[3 * i + 2], (double)p[i]);
    for (size_t i = 0; i < n; ++i) {
        NF_FUZZ_CHECK(nf_sample(m, 1, &rep[i], u + 2 * i, d, p) == NF_OK, "nf_sample n = 1");
        NF_FUZZ_CHECK(memcmp(d, dir + 3 * i, 3 * sizeof *d) == 0 && memcmp(p, pdf + i, 4) == 0,
                      "point sample %zu differs from nf_sample n = 1", i);
    }
}

static void check_against_pdf(const nf_model *m, const nf_context *rep, size_t n, const float *dir,
                              const float *pdf)
{
    float p[MAX_N];
    NF_FUZZ_CHECK(nf_pdf(m, n, rep, dir, p) == NF_OK, "nf_pdf");
    for (size_t i = 0; i < n; ++i)
        NF_FUZZ_CHECK(memcmp(p + i, pdf + i, sizeof *p) == 0,
                      "point pdf %zu of %zu differs from nf_pdf: dir (%a, %a, %a), point %a, "
                      "nf_pdf %a",
                      i, n, (double)dir[3 * i], (double)dir[3 * i + 1], (double)dir[3 * i + 2],
                      (double)pdf[i], (double)p[i]);
    for (size_t i = 0; i < n; ++i) {
        NF_FUZZ_CHECK(nf_pdf(m, 1, &rep[i], dir + 3 * i, p) == NF_OK, "nf_pdf n = 1");
        NF_FUZZ_CHECK(memcmp(p, pdf + i, sizeof *p) == 0, "point pdf %zu differs from nf_pdf n = 1",
                      i);
    }
}

/* The points of a call: one slot for nf_point_* (returned), or a slot per entry for
 * nf_points_* (copied into arr); their contexts go to ctx and their states into *e. */
static slot *pick_points(machine *mc, int batch, size_t n, nf_shading_point *arr, nf_context *ctx,
                         expect *e)
{
    reader *r = &mc->in;
    slot *one = &mc->slots[rd_u8(r) % SLOTS];
    for (size_t i = 0; i < n; ++i) {
        slot *s = batch ? &mc->slots[rd_u8(r) % SLOTS] : one;
        arr[i] = s->sp;
        ctx[i] = s->ctx;
        expect_slot(e, s, mc->epoch);
    }
    return one;
}

static void op_sample(machine *mc, int batch)
{
    reader *r = &mc->in;
    size_t n = 1u + rd_u8(r) % MAX_N;
    expect e = {0, 0, 1, 1};
    nf_shading_point arr[MAX_N];
    nf_context ctx[MAX_N];
    slot *one = pick_points(mc, batch, n, arr, ctx, &e);
    float u[2 * MAX_N], dir[3 * MAX_N], pdf[MAX_N];
    for (size_t i = 0; i < 2 * n; ++i) {
        u[i] = rd_float(r);
        e.inputs_ok &= isfinite(u[i]) != 0;
    }
    int with_pdf = (rd_u8(r) & 7u) != 0;
    fill(dir, 3 * n);
    fill(pdf, n);
    const char *fn = batch ? "nf_points_sample" : "nf_point_sample";
    nf_status st = batch ? nf_points_sample(mc->m, n, arr, u, dir, with_pdf ? pdf : NULL)
                         : nf_point_sample(mc->m, &one->sp, n, u, dir, with_pdf ? pdf : NULL);
    NF_FUZZ_CHECK(status_allowed(st, &e), "%s: status %d (refused %d, stale %d, inputs %d)", fn,
                  (int)st, e.refused, e.stale, e.inputs_ok);
    if (st != NF_OK) {
        NF_FUZZ_CHECK(nf_last_error_message()[0] != '\0', "%s: no message", fn);
        NF_FUZZ_CHECK(untouched(dir, 3 * n) && untouched(pdf, n), "%s: a refused call wrote", fn);
        return;
    }
    check_unit_and_pdfs(n, dir, with_pdf ? pdf : NULL, fn);
    if (!with_pdf)
        NF_FUZZ_CHECK(untouched(pdf, n), "%s: pdf written although NULL was passed", fn);
    if (e.exact && with_pdf)
        check_against_batch(mc->m, ctx, n, u, dir, pdf);
}

static void op_pdf(machine *mc, int batch)
{
    reader *r = &mc->in;
    size_t n = 1u + rd_u8(r) % MAX_N;
    expect e = {0, 0, 1, 1};
    nf_shading_point arr[MAX_N];
    nf_context ctx[MAX_N];
    slot *one = pick_points(mc, batch, n, arr, ctx, &e);
    float dir[3 * MAX_N], pdf[MAX_N];
    for (size_t i = 0; i < n; ++i) {
        for (int a = 0; a < 3; ++a)
            dir[3 * i + (size_t)a] = rd_float(r);
        e.inputs_ok &= vector_ok(dir + 3 * i);
    }
    fill(pdf, n);
    const char *fn = batch ? "nf_points_pdf" : "nf_point_pdf";
    nf_status st =
        batch ? nf_points_pdf(mc->m, n, arr, dir, pdf) : nf_point_pdf(mc->m, &one->sp, n, dir, pdf);
    NF_FUZZ_CHECK(status_allowed(st, &e), "%s: status %d (refused %d, stale %d, inputs %d)", fn,
                  (int)st, e.refused, e.stale, e.inputs_ok);
    if (st != NF_OK) {
        NF_FUZZ_CHECK(nf_last_error_message()[0] != '\0', "%s: no message", fn);
        NF_FUZZ_CHECK(untouched(pdf, n), "%s: a refused call wrote", fn);
        return;
    }
    check_unit_and_pdfs(n, NULL, pdf, fn);
    if (e.exact)
        check_against_pdf(mc->m, ctx, n, dir, pdf);
}

/* Flips the bits of `mask` in one byte of a slot's point, never in its callbacks. */
static void op_corrupt(machine *mc)
{
    reader *r = &mc->in;
    slot *s = &mc->slots[rd_u8(r) % SLOTS];
    unsigned where = rd_u8(r);
    unsigned mask = rd_u8(r) | 1u;
    size_t offset;
    if (where < 128)
        offset = where; /* the header */
    else
        offset = offsetof(nf_shading_point, cache_) + (size_t)(where - 128u) * 8u + (rd_u8(r) & 7u);
    if (prior_byte(offset))
        offset = offsetof(nf_shading_point, check_);
    ((unsigned char *)&s->sp)[offset] ^= (unsigned char)mask;
}

/* Training data: fixed, ordinary contexts. */
static nf_context training_context(int i)
{
    nf_context c;
    for (int a = 0; a < 3; ++a) {
        c.position[a] = 0.25f * (float)(i + a);
        c.normal[a] = a == 2 ? 1.0f : 0.1f * (float)i;
        c.wo[a] = a == i % 3 ? 1.0f : 0.3f;
    }
    return c;
}

/* Changes the parameters (or tries to: refused changes leave points valid). */
static void op_change(machine *mc)
{
    reader *r = &mc->in;
    unsigned kind = rd_u8(r) % 4u;
    size_t count = nf_param_count(mc->m);
    float *buf = mc->buf;
    nf_status st;
    int changes;
    if (kind == 0) {
        enum { B = 4 };
        nf_context ctx[B];
        float dir[3 * B], w[B];
        for (int i = 0; i < B; ++i) {
            ctx[i] = training_context(i);
            for (int a = 0; a < 3; ++a)
                dir[3 * i + a] = a == i % 3 ? 1.0f : 0.25f;
            w[i] = 0.5f + (float)(rd_u8(r) % 4u);
        }
        st = nf_train_step(mc->m, B, ctx, dir, w, NULL);
        NF_FUZZ_CHECK(st == NF_OK || st == NF_ERROR_NUMERIC, "nf_train_step %d", (int)st);
        changes = st == NF_OK;
    } else if (kind == 1) {
        NF_FUZZ_CHECK(nf_get_params(mc->m, buf) == NF_OK, "nf_get_params");
        float v = rd_float(r);
        size_t at = rd_u32(r) % count;
        buf[at] = v;
        st = nf_set_params(mc->m, buf);
        changes = isfinite(v) != 0;
        NF_FUZZ_CHECK(st == (changes ? NF_OK : NF_ERROR_INVALID_ARGUMENT), "nf_set_params %d",
                      (int)st);
    } else if (kind == 2) {
        for (size_t i = 0; i < count; ++i)
            buf[i] = 0.0f;
        float v = rd_float(r);
        buf[rd_u32(r) % count] = v;
        int all_finite = isfinite(v) != 0;
        st = nf_apply_gradient(mc->m, buf);
        if (!all_finite)
            NF_FUZZ_CHECK(st == NF_ERROR_INVALID_ARGUMENT, "nf_apply_gradient %d", (int)st);
        else
            NF_FUZZ_CHECK(st == NF_OK || st == NF_ERROR_NUMERIC, "nf_apply_gradient %d", (int)st);
        changes = st == NF_OK;
    } else {
        /* Calls that change nothing. */
        NF_FUZZ_CHECK(nf_set_learning_rate(mc->m, 1e-4f) == NF_OK, "nf_set_learning_rate");
        nf_context c = training_context(1);
        float zero_w = 0.0f, d[3] = {0.0f, 0.0f, 1.0f};
        NF_FUZZ_CHECK(nf_train_step(mc->m, 1, &c, d, &zero_w, NULL) == NF_OK, "zero weights");
        changes = 0;
    }
    if (changes)
        mc->epoch++;
}

/* A clone refuses every point of the original, and the original every point of the clone. */
/* Another model with the same state (nf_model_copy into the cached second model: a clone
 * without the allocation), which must refuse the points of the first and vice versa. */
static void op_clone(machine *mc)
{
    nf_model *clone = mc->other;
    NF_FUZZ_CHECK(nf_model_copy(clone, mc->m) == NF_OK, "nf_model_copy");
    float u[2] = {0.25f, 0.75f}, dir[3], pdf[1];
    for (int i = 0; i < SLOTS; ++i) {
        fill(dir, 3);
        fill(pdf, 1);
        nf_status st = nf_point_sample(clone, &mc->slots[i].sp, 1, u, dir, pdf);
        NF_FUZZ_CHECK(st == NF_ERROR_INVALID_ARGUMENT, "a clone accepted a point: %d", (int)st);
        NF_FUZZ_CHECK(untouched(dir, 3) && untouched(pdf, 1), "a refused call wrote");
    }
    slot *s = &mc->slots[rd_u8(&mc->in) % SLOTS];
    if (s->prepared && context_ok(&s->ctx)) {
        nf_shading_point own;
        if (nf_point_prepare(clone, &s->ctx, NULL, &own) == NF_OK) {
            NF_FUZZ_CHECK(nf_point_sample(mc->m, &own, 1, u, dir, pdf) == NF_ERROR_INVALID_ARGUMENT,
                          "the original accepted a point of the clone");
            NF_FUZZ_CHECK(nf_point_sample(clone, &own, 1, u, dir, pdf) == NF_OK,
                          "the clone refused its own point");
        }
    }
}

static void op_copy(machine *mc)
{
    slot *to = &mc->slots[rd_u8(&mc->in) % SLOTS];
    const slot *from = &mc->slots[rd_u8(&mc->in) % SLOTS];
    if (to != from)
        *to = *from;
}

/* ---- the model ------------------------------------------------------------------------------- */

/* The models of one shape (the program's first byte, all 256 of them), built once per process
 * on first use and kept: a pristine one, the one a program works on (reset at the start of
 * every input with nf_model_copy, so that an input replays alone), a second one for op_clone,
 * a parameter buffer, and `seeded`, the pristine model with the random parameters of the
 * last (scale, seed) pair a program asked for. Building models per input cost most of an
 * execution (megabytes of fresh pages); drawing and checking every parameter per input cost
 * most of the rest under the sanitizers' instrumentation, and consecutive inputs (mutations
 * of one program) mostly share the pair, so the parameters are drawn again only when it
 * changes. Every path gives the work model the same state for the same input. */
typedef struct shape_models {
    nf_prior_kind prior;
    nf_model *pristine, *work, *other, *seeded;
    float *buf;
    int seeded_valid;
    unsigned seeded_scale;
    uint32_t seeded_seed;
} shape_models;

static shape_models *models_for(unsigned a)
{
    static shape_models cache[256];
    shape_models *c = &cache[a & 255u];
    if (c->pristine)
        return c;
    nf_config cfg;
    nf_config_init(&cfg, (a & 1u) ? NF_PRESET_LARGE : NF_PRESET_SMALL);
    switch ((a >> 1) & 3u) {
    case 1:
        /* Too large for the point's cache (6 layers of 40 units, padded to 48: 288 floats of
         * context sums), with as few parameters as that allows (fewer one-blob bins and SH
         * bands than the presets), so that a program on it costs about what one on a preset
         * costs. */
        cfg.coupling_layers = 6;
        cfg.hidden_width = 40;
        cfg.oneblob_bins = 8;
        cfg.sh_bands = 2;
        break;
    case 2: /* the smallest network */
        cfg.coupling_layers = 1;
        cfg.hidden_width = 1;
        cfg.spline_bins = 2;
        cfg.oneblob_bins = 2;
        cfg.sh_bands = 0;
        break;
    case 3: /* odd widths, the largest SH and one-blob */
        cfg.coupling_layers = 3;
        cfg.hidden_width = 17;
        cfg.sh_bands = NF_MAX_SH_BANDS;
        cfg.oneblob_bins = NF_MAX_ONEBLOB_BINS;
        break;
    default: break;
    }
    cfg.prior = (nf_prior_kind)((a >> 3) & 3u);
    cfg.custom_prior = nf_fuzz_callbacks();
    cfg.isa = (nf_isa)((a >> 5) & 3u);
    cfg.phi_map = (a >> 7) & 1u ? NF_PHI_INTERVAL : NF_PHI_CIRCULAR;
    if (nf_model_create(&cfg, &c->pristine) != NF_OK) {
        /* Kernels this CPU lacks: the best ones instead. */
        NF_FUZZ_CHECK(cfg.isa != NF_ISA_AUTO && cfg.isa != NF_ISA_GENERIC, "nf_model_create");
        cfg.isa = NF_ISA_AUTO;
        NF_FUZZ_CHECK(nf_model_create(&cfg, &c->pristine) == NF_OK, "nf_model_create");
    }
    NF_FUZZ_CHECK(nf_model_clone(c->pristine, &c->work) == NF_OK, "nf_model_clone");
    NF_FUZZ_CHECK(nf_model_clone(c->pristine, &c->other) == NF_OK, "nf_model_clone");
    NF_FUZZ_CHECK(nf_model_clone(c->pristine, &c->seeded) == NF_OK, "nf_model_clone");
    c->buf = (float *)malloc(nf_param_count(c->pristine) * sizeof *c->buf);
    NF_FUZZ_CHECK(c->buf != NULL, "malloc");
    c->prior = cfg.prior;
    c->seeded_valid = 0;
    return c;
}

/* c->seeded as the pristine model with parameters uniform in [-scale, scale] from `seed`
 * (scale index 0: the pristine parameters). */
static void seed_params(shape_models *c, unsigned scale_index, uint32_t seed_bits)
{
    if (c->seeded_valid && c->seeded_scale == scale_index && c->seeded_seed == seed_bits)
        return;
    static const float scales[8] = {0.0f, 0.1f, 0.3f, 1.0f, 10.0f, 1e6f, 1e30f, FLT_MAX};
    float scale = scales[scale_index];
    NF_FUZZ_CHECK(nf_model_copy(c->seeded, c->pristine) == NF_OK, "nf_model_copy");
    if (scale > 0.0f) {
        uint64_t seed = seed_bits | 1u;
        size_t count = nf_param_count(c->seeded);
        float *p = c->buf;
        for (size_t i = 0; i < count; ++i) {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            p[i] = scale * ((float)(seed >> 40) * 0x1p-23f - 1.0f);
        }
        NF_FUZZ_CHECK(nf_set_params(c->seeded, p) == NF_OK, "nf_set_params");
    }
    c->seeded_scale = scale_index;
    c->seeded_seed = seed_bits;
    c->seeded_valid = 1;
}

static void make_model(reader *r, machine *mc)
{
    unsigned a = rd_u8(r), b = rd_u8(r);
    shape_models *c = models_for(a);
    seed_params(c, b & 7u, rd_u32(r));
    NF_FUZZ_CHECK(nf_model_copy(c->work, c->seeded) == NF_OK, "nf_model_copy");
    mc->m = c->work;
    mc->other = c->other;
    mc->buf = c->buf;
    mc->prior = c->prior;
    /* Then a few raw values. */
    unsigned edits = (b >> 3) & 3u;
    if (edits == 0)
        return;
    size_t count = nf_param_count(mc->m);
    float *p = mc->buf;
    NF_FUZZ_CHECK(nf_get_params(mc->m, p) == NF_OK, "nf_get_params");
    for (unsigned k = 0; k < edits; ++k) {
        size_t at = rd_u32(r) % count;
        float v = rd_float(r);
        if (isfinite(v))
            p[at] = v;
    }
    NF_FUZZ_CHECK(nf_set_params(mc->m, p) == NF_OK, "nf_set_params");
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static machine mc;
    memset(&mc, 0, sizeof mc);
    mc.in.p = data;
    mc.in.n = size;
    make_model(&mc.in, &mc);
    /* Unprepared slots hold a byte pattern of the input's choosing. */
    unsigned junk = rd_u8(&mc.in);
    for (int i = 0; i < SLOTS; ++i)
        memset(&mc.slots[i].sp, (int)(junk + (unsigned)i * 0x35u) & 0xff, sizeof mc.slots[i].sp);
    for (int ops = 0; ops < MAX_OPS && mc.in.at < mc.in.n; ++ops) {
        switch (rd_u8(&mc.in) % 10u) {
        case 0:
        case 1: op_prepare(&mc); break;
        case 2: op_sample(&mc, 0); break;
        case 3: op_pdf(&mc, 0); break;
        case 4: op_sample(&mc, 1); break;
        case 5: op_pdf(&mc, 1); break;
        case 6: op_corrupt(&mc); break;
        case 7: op_change(&mc); break;
        case 8: op_clone(&mc); break;
        default: op_copy(&mc); break;
        }
    }
    return 0; /* the models stay cached for the next input (models_for) */
}
