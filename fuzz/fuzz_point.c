/*
 * fuzz_point.c - libFuzzer target: the shading-point API (nisflow/point.h) on hostile input
 * (docs/robustness.md). The input is a small program. Its first bytes choose a model (an
 * architecture that fits the point's cache or not, a prior, the kernels) and the scale of
 * its random parameters, up to FLT_MAX; the rest is a stream of operations on four point
 * slots: prepare from raw float contexts (NaN, Inf, subnormal, huge, zero vectors; with or
 * without per-point prior callbacks), sample raw u, evaluate raw directions, batches of
 * points, flip bits of a point, change the parameters (training steps, nf_model_set_params,
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
 *     tests/robustness/test_numeric_robustness) and finite positive densities, the same
 *     result (same_result: the same bits but on the presets' AVX2 / AVX-512 vector path) as
 *     nf_sample / nf_pdf on the point's context,
 *     as one call of n (tiled for n >= 3) or as calls of 1: a bit of the program chooses
 *     which, per operation.
 * Bytes of a point outside its header (reserved, cache) are flipped too; the library does not
 * promise to detect that, so such a point must only not crash the library or trip a
 * sanitizer. Its prior callbacks are never flipped: calling a corrupted function pointer would
 * crash by design, not by a bug.
 *
 * Run it with -entropic_feature_frequency_threshold=32 (.ci/robustness and
 * scripts/fuzz-long.sh do): libFuzzer's entropic scheduler looks every feature of every
 * execution up in its list of rare features, and with the default threshold (255 hits) that
 * list holds thousands of this target's features, so the lookups took a third of the time,
 * more as the corpus grows. At 32 the list stays short; in measured 60-second runs from the
 * seeds it made 1,760 executions per second against 1,490, with as much coverage
 * (docs/robustness.md, "fuzz_point's speed").
 */
#include <float.h>
#include <stddef.h>

#include "fuzz_common.h"
#include "gradient.h"
#include "internal.h"
#include "point_batch.h"
#include "shading_point.h"

enum { SLOTS = 4, MAX_N = 20, MAX_OPS = 32, MAX_TRAININGS = 1, MAX_WRITES = 1, MAX_EDITS = 3 };

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

/* What the cached models of a shape (shape_models, below) still hold, so that copies between
 * them are made only when something changed: the work model equals `seeded` (the reset at the
 * start of an input can be skipped), `other` equals the work model (op_clone's copy can be
 * skipped). Only op_change and the reset write to the work model. */
typedef struct model_flags {
    int work_is_seeded, other_is_work;
} model_flags;

typedef struct machine {
    nf_model *m;
    model_flags *flags; /* m's shape's (models_for) */
    nf_model **other;   /* a second model of m's configuration, for op_clone; built there */
    float *buf;      /* nf_model_param_count floats of scratch */
    nf_prior_kind prior;
    uint64_t epoch; /* counts accepted changes of the parameters */
    int trainings;  /* training steps tried, against MAX_TRAININGS */
    int writes;     /* nf_model_set_params / nf_apply_gradient tried, against MAX_WRITES */
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

/* Whether the model's shading points take the presets' vector path (src/kernels/point_vector.h,
 * on the AVX2 and AVX-512 kernels), whose results are not the batch's bits. */
static int vector_path(const nf_model *m)
{
    nf_config c;
    NF_FUZZ_CHECK(nf_model_get_config(m, &c) == NF_OK, "nf_model_get_config");
    int preset = c.hidden_width == 16 && c.oneblob_bins == 32 &&
                 ((c.coupling_layers == 2 && c.spline_bins == 8 && c.hidden_layers == 1) ||
                  (c.coupling_layers == 4 && c.spline_bins == 16 && c.hidden_layers == 2));
    const char *isa = nf_model_isa_name(m);
    return preset && (strcmp(isa, "avx512") == 0 || strcmp(isa, "avx2") == 0);
}

/* The oracle's verdict on one value of an accepted point call (a direction component or a
 * density) against the batch call's value for the same input: the same bits, except on the
 * vector path. Its bound (tests/correctness/test_point.c) holds for models of moderate
 * parameters, not for the fuzzer's, whose raw spline parameters reach the clamp: there the
 * point's values are held to validity alone (unit directions, finite positive densities,
 * checked for every call). Every comparison with nf_sample / nf_pdf goes through here. */
static int same_result(int vector, float point_value, float batch_value)
{
    return vector || memcmp(&point_value, &batch_value, sizeof point_value) == 0;
}

/* The batch calls a point call is checked against: one call of all n entries (tiled for
 * n >= 3, as kernel.c tiles) or n calls of 1 (never tiled). Each check makes one of them,
 * chosen by a bit of the program, rather than both: the oracle cost as much as the calls it
 * checks, and a bit the fuzzer can flip still reaches both forms on every input. */
enum { ORACLE_ONE_CALL, ORACLE_CALLS_OF_ONE };

/* nf_sample's results for n u pairs at the points' contexts, in the chosen form, against the
 * point call's. */
static void check_against_batch(const nf_model *m, int form, const nf_context *rep, size_t n,
                                const float *u, const float *dir, const float *pdf)
{
    float d[3 * MAX_N], p[MAX_N];
    if (form == ORACLE_ONE_CALL)
        NF_FUZZ_CHECK(nf_sample(m, n, rep, u, d, p) == NF_OK, "nf_sample");
    else
        for (size_t i = 0; i < n; ++i)
            NF_FUZZ_CHECK(nf_sample(m, 1, &rep[i], u + 2 * i, d + 3 * i, p + i) == NF_OK,
                          "nf_sample n = 1");
    const int v = vector_path(m);
    for (size_t i = 0; i < n; ++i)
        NF_FUZZ_CHECK(same_result(v, dir[3 * i], d[3 * i]) &&
                          same_result(v, dir[3 * i + 1], d[3 * i + 1]) &&
                          same_result(v, dir[3 * i + 2], d[3 * i + 2]) &&
                          same_result(v, pdf[i], p[i]),
                      "point sample %zu of %zu differs from nf_sample (%s): u (%a, %a), point "
                      "(%a, %a, %a) %a, nf_sample (%a, %a, %a) %a",
                      i, n, form == ORACLE_ONE_CALL ? "one call" : "calls of 1",
                      (double)u[2 * i], (double)u[2 * i + 1], (double)dir[3 * i],
                      (double)dir[3 * i + 1], (double)dir[3 * i + 2], (double)pdf[i],
                      (double)d[3 * i], (double)d[3 * i + 1], (double)d[3 * i + 2], (double)p[i]);
}

static void check_against_pdf(const nf_model *m, int form, const nf_context *rep, size_t n,
                              const float *dir, const float *pdf)
{
    float p[MAX_N];
    if (form == ORACLE_ONE_CALL)
        NF_FUZZ_CHECK(nf_pdf(m, n, rep, dir, p) == NF_OK, "nf_pdf");
    else
        for (size_t i = 0; i < n; ++i)
            NF_FUZZ_CHECK(nf_pdf(m, 1, &rep[i], dir + 3 * i, p + i) == NF_OK, "nf_pdf n = 1");
    const int v = vector_path(m);
    for (size_t i = 0; i < n; ++i)
        NF_FUZZ_CHECK(same_result(v, pdf[i], p[i]),
                      "point pdf %zu of %zu differs from nf_pdf (%s): dir (%a, %a, %a), point "
                      "%a, nf_pdf %a",
                      i, n, form == ORACLE_ONE_CALL ? "one call" : "calls of 1",
                      (double)dir[3 * i], (double)dir[3 * i + 1], (double)dir[3 * i + 2],
                      (double)pdf[i], (double)p[i]);
}

/* The points of a call: one slot for nf_point_* (returned), or a slot per entry for
 * nf_points_* (copied into arr); their contexts go to ctx and their states into *e. The
 * slot byte's next bit (unused before) chooses the oracle's form, *form. */
static slot *pick_points(machine *mc, int batch, size_t n, nf_shading_point *arr, nf_context *ctx,
                         expect *e, int *form)
{
    reader *r = &mc->in;
    unsigned pick = rd_u8(r);
    slot *one = &mc->slots[pick % SLOTS];
    *form = (pick / SLOTS) & 1u ? ORACLE_CALLS_OF_ONE : ORACLE_ONE_CALL;
    for (size_t i = 0; i < n; ++i) {
        slot *s = batch ? &mc->slots[rd_u8(r) % SLOTS] : one;
        arr[i] = s->sp;
        ctx[i] = s->ctx;
        expect_slot(e, s, mc->epoch);
    }
    return one;
}

/* nf_point_sample_and_pdf at one slot: u and a direction to evaluate, read from the input;
 * the draw is checked against nf_sample and the density against nf_pdf. */
static void sample_and_pdf(machine *mc, const slot *one, const nf_context *ctx, const float u[2],
                           expect e, int with_pdf)
{
    static const char fn[] = "nf_point_sample_and_pdf";
    reader *r = &mc->in;
    float eval[3], dir[3], pdf[2];
    for (int a = 0; a < 3; ++a)
        eval[a] = rd_float(r);
    e.inputs_ok = isfinite(u[0]) && isfinite(u[1]) && vector_ok(eval);
    fill(dir, 3);
    fill(pdf, 2);
    nf_status st =
        nf_point_sample_and_pdf(mc->m, &one->sp, u, dir, with_pdf ? &pdf[0] : NULL, eval, &pdf[1]);
    NF_FUZZ_CHECK(status_allowed(st, &e), "%s: status %d (refused %d, stale %d, inputs %d)", fn,
                  (int)st, e.refused, e.stale, e.inputs_ok);
    if (st != NF_OK) {
        NF_FUZZ_CHECK(nf_last_error_message()[0] != '\0', "%s: no message", fn);
        NF_FUZZ_CHECK(untouched(dir, 3) && untouched(pdf, 2), "%s: a refused call wrote", fn);
        return;
    }
    check_unit_and_pdfs(1, dir, with_pdf ? pdf : NULL, fn);
    check_unit_and_pdfs(1, NULL, pdf + 1, fn);
    if (!with_pdf)
        NF_FUZZ_CHECK(untouched(pdf, 1), "%s: pdf written although NULL was passed", fn);
    if (e.exact && with_pdf)
        check_against_batch(mc->m, ORACLE_ONE_CALL, ctx, 1, u, dir, pdf);
    if (e.exact)
        check_against_pdf(mc->m, ORACLE_ONE_CALL, ctx, 1, eval, pdf + 1);
}

static void op_sample(machine *mc, int batch)
{
    reader *r = &mc->in;
    size_t n = 1u + rd_u8(r) % MAX_N;
    expect e = {0, 0, 1, 1};
    nf_shading_point arr[MAX_N];
    nf_context ctx[MAX_N];
    int form;
    slot *one = pick_points(mc, batch, n, arr, ctx, &e, &form);
    float u[2 * MAX_N], dir[3 * MAX_N], pdf[MAX_N];
    for (size_t i = 0; i < 2 * n; ++i) {
        u[i] = rd_float(r);
        e.inputs_ok &= isfinite(u[i]) != 0;
    }
    unsigned how = rd_u8(r);
    int with_pdf = (how & 7u) != 0;
    if (!batch && (how & 0x18u) == 0x18u) { /* a quarter of one point's draws */
        sample_and_pdf(mc, one, ctx, u, e, with_pdf);
        return;
    }
    fill(dir, 3 * n);
    fill(pdf, n);
    const char *fn = batch ? "nf_point_sample_batch" : "nf_point_sample";
    nf_status st = batch ? nf_point_sample_batch(mc->m, n, arr, u, dir, with_pdf ? pdf : NULL)
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
        check_against_batch(mc->m, form, ctx, n, u, dir, pdf);
}

static void op_pdf(machine *mc, int batch)
{
    reader *r = &mc->in;
    size_t n = 1u + rd_u8(r) % MAX_N;
    expect e = {0, 0, 1, 1};
    nf_shading_point arr[MAX_N];
    nf_context ctx[MAX_N];
    int form;
    slot *one = pick_points(mc, batch, n, arr, ctx, &e, &form);
    float dir[3 * MAX_N], pdf[MAX_N];
    for (size_t i = 0; i < n; ++i) {
        for (int a = 0; a < 3; ++a)
            dir[3 * i + (size_t)a] = rd_float(r);
        e.inputs_ok &= vector_ok(dir + 3 * i);
    }
    fill(pdf, n);
    const char *fn = batch ? "nf_point_pdf_batch" : "nf_point_pdf";
    nf_status st =
        batch ? nf_point_pdf_batch(mc->m, n, arr, dir, pdf) : nf_point_pdf(mc->m, &one->sp, n, dir, pdf);
    NF_FUZZ_CHECK(status_allowed(st, &e), "%s: status %d (refused %d, stale %d, inputs %d)", fn,
                  (int)st, e.refused, e.stale, e.inputs_ok);
    if (st != NF_OK) {
        NF_FUZZ_CHECK(nf_last_error_message()[0] != '\0', "%s: no message", fn);
        NF_FUZZ_CHECK(untouched(pdf, n), "%s: a refused call wrote", fn);
        return;
    }
    check_unit_and_pdfs(n, NULL, pdf, fn);
    if (e.exact)
        check_against_pdf(mc->m, form, ctx, n, dir, pdf);
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

static void work_changes(machine *mc)
{
    mc->flags->work_is_seeded = 0;
    mc->flags->other_is_work = 0;
}

/* Changes the parameters (or tries to: refused changes leave points valid). An input makes
 * at most MAX_TRAININGS training steps (kind 0) and MAX_WRITES nf_model_set_params /
 * nf_apply_gradient calls (kinds 1 and 2); past that an operation still reads its bytes, so
 * that the rest of the program means the same, but calls nothing. Each of these calls goes
 * over every parameter (a step is a forward and backward pass and Adam: about 200 us with the
 * large preset under the fuzz build's sanitizers, a point call of 16 samples about 40), and
 * what a point call must do after a change (STALE, then valid again once prepared) shows
 * after the first; more changes only move the parameters further, which the scale and raw
 * edits of the model's bytes already do. Kind 3 only validates, and is not capped. */
static void op_change(machine *mc)
{
    reader *r = &mc->in;
    unsigned kind = rd_u8(r) % 4u;
    size_t count = nf_model_param_count(mc->m);
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
        if (mc->trainings++ >= MAX_TRAININGS)
            return;
        work_changes(mc);
        st = nf_train_step(mc->m, B, ctx, dir, w, NULL);
        NF_FUZZ_CHECK(st == NF_OK || st == NF_ERROR_NUMERIC, "nf_train_step %d", (int)st);
        changes = st == NF_OK;
    } else if (kind == 1) {
        float v = rd_float(r);
        size_t at = rd_u32(r) % count;
        if (mc->writes++ >= MAX_WRITES)
            return;
        work_changes(mc);
        NF_FUZZ_CHECK(nf_model_get_params(mc->m, buf) == NF_OK, "nf_model_get_params");
        buf[at] = v;
        st = nf_model_set_params(mc->m, buf);
        changes = isfinite(v) != 0;
        NF_FUZZ_CHECK(st == (changes ? NF_OK : NF_ERROR_INVALID_ARGUMENT), "nf_model_set_params %d",
                      (int)st);
    } else if (kind == 2) {
        float v = rd_float(r);
        size_t at = rd_u32(r) % count;
        if (mc->writes++ >= MAX_WRITES)
            return;
        work_changes(mc);
        memset(buf, 0, count * sizeof *buf); /* all bits zero is 0.0f in IEEE 754 */
        buf[at] = v;
        int all_finite = isfinite(v) != 0;
        st = nf_apply_gradient(mc->m, buf);
        if (!all_finite)
            NF_FUZZ_CHECK(st == NF_ERROR_INVALID_ARGUMENT, "nf_apply_gradient %d", (int)st);
        else
            NF_FUZZ_CHECK(st == NF_OK || st == NF_ERROR_NUMERIC, "nf_apply_gradient %d", (int)st);
        changes = st == NF_OK;
    } else {
        /* Calls that change no parameter (the learning rate is state nf_model_copy resets). */
        work_changes(mc);
        NF_FUZZ_CHECK(nf_model_set_learning_rate(mc->m, 1e-4f) == NF_OK, "nf_model_set_learning_rate");
        nf_context c = training_context(1);
        float zero_w = 0.0f, d[3] = {0.0f, 0.0f, 1.0f};
        NF_FUZZ_CHECK(nf_train_step(mc->m, 1, &c, d, &zero_w, NULL) == NF_OK, "zero weights");
        changes = 0;
    }
    if (changes)
        mc->epoch++;
}

/* Another model with the same state (nf_model_copy into the cached second model: a clone
 * without the allocation; copied again only when the work model changed since), which must
 * refuse the points of the first and vice versa. */
static void op_clone(machine *mc)
{
    if (!*mc->other)
        NF_FUZZ_CHECK(nf_model_clone(mc->m, mc->other) == NF_OK, "nf_model_clone");
    else if (!mc->flags->other_is_work)
        NF_FUZZ_CHECK(nf_model_copy(*mc->other, mc->m) == NF_OK, "nf_model_copy");
    mc->flags->other_is_work = 1;
    nf_model *clone = *mc->other;
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

/* The parameters a program asks for: a scale index and seed, then up to MAX_EDITS raw values
 * (index bits, float bits). All fields are uint32_t, so two keys compare with memcmp. */
typedef struct params_key {
    uint32_t scale, seed, edits;
    uint32_t at[MAX_EDITS], value[MAX_EDITS];
} params_key;

/* The models of one shape (the program's first byte, all 256 of them), built once per process
 * on first use and kept: `seeded`, the fresh model with the parameters (random ones and raw
 * edits) of the last key a program asked for (nf_model_set_params keeps its optimizer state, which
 * stays the fresh one), the fresh model's parameters, the model a program works on (reset
 * from `seeded` at the start of every input with nf_model_copy, so that an input replays
 * alone), a second one for op_clone (built on the shape's first op_clone: a quarter of the
 * shapes' memory, which is fresh pages early in a run) and a parameter buffer. Building
 * models per input cost most of an
 * execution (megabytes of fresh pages); drawing and checking every parameter per input cost
 * most of the rest under the sanitizers' instrumentation, and consecutive inputs (mutations
 * of one program) mostly share the key, so the parameters are set again only when it
 * changes; `flags` says which copies still hold (model_flags). Every path gives the work model
 * (and `other`, when op_clone uses it) the same state for the same input. */
typedef struct shape_models {
    nf_prior_kind prior;
    nf_model *seeded, *work, *other;
    float *fresh_params, *buf;
    int seeded_valid;
    model_flags flags;
    params_key key;
} shape_models;

static shape_models *models_for(unsigned a)
{
    static shape_models cache[256];
    shape_models *c = &cache[a & 255u];
    if (c->seeded)
        return c;
    nf_config cfg;
    nf_config_init(&cfg, (a & 1u) ? NF_PRESET_LARGE : NF_PRESET_SMALL);
    switch ((a >> 1) & 3u) {
    case 1:
        /* Too large for the point's cache (9 layers of 17 units, padded to 32: 288 floats of
         * context sums, above NF_SHADING_POINT_CACHE_FLOATS), with as few parameters as that
         * allows (fewer one-blob bins and SH bands than the presets; the smallest product of
         * layers and width that passes 256 floats with a full and a partial chunk of units):
         * 10,323 parameters (16,965 on the large preset), where 6 layers of 40 units had 15,990
         * (31,734). Every training step, reset and parameter change goes over all of them. */
        cfg.coupling_layers = 9;
        cfg.hidden_width = 17;
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
    if (nf_model_create(&cfg, &c->seeded) != NF_OK) {
        /* Kernels this CPU lacks: the best ones instead. */
        NF_FUZZ_CHECK(cfg.isa != NF_ISA_AUTO && cfg.isa != NF_ISA_GENERIC, "nf_model_create");
        cfg.isa = NF_ISA_AUTO;
        NF_FUZZ_CHECK(nf_model_create(&cfg, &c->seeded) == NF_OK, "nf_model_create");
    }
    NF_FUZZ_CHECK(nf_model_clone(c->seeded, &c->work) == NF_OK, "nf_model_clone");
    size_t count = nf_model_param_count(c->seeded);
    c->fresh_params = (float *)malloc(count * sizeof *c->fresh_params);
    c->buf = (float *)malloc(count * sizeof *c->buf);
    NF_FUZZ_CHECK(c->fresh_params != NULL && c->buf != NULL, "malloc");
    NF_FUZZ_CHECK(nf_model_get_params(c->seeded, c->fresh_params) == NF_OK, "nf_model_get_params");
    c->prior = cfg.prior;
    c->seeded_valid = 0;
    c->flags.work_is_seeded = 0;
    c->flags.other_is_work = 0;
    return c;
}

/* c->seeded as the fresh model with parameters uniform in [-scale, scale] from the key's
 * seed (scale index 0: the fresh parameters), then its finite raw edits. */
static void seed_params(shape_models *c, const params_key *key)
{
    if (c->seeded_valid && memcmp(&c->key, key, sizeof *key) == 0)
        return;
    static const float scales[8] = {0.0f, 0.1f, 0.3f, 1.0f, 10.0f, 1e6f, 1e30f, FLT_MAX};
    float scale = scales[key->scale];
    c->flags.work_is_seeded = 0;
    size_t count = nf_model_param_count(c->seeded);
    float *p = c->buf;
    if (scale > 0.0f) {
        uint64_t seed = key->seed | 1u;
        for (size_t i = 0; i < count; ++i) {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            p[i] = scale * ((float)(seed >> 40) * 0x1p-23f - 1.0f);
        }
    } else {
        memcpy(p, c->fresh_params, count * sizeof *p);
    }
    for (uint32_t k = 0; k < key->edits; ++k) {
        float v = bits_to_float(key->value[k]);
        if (isfinite(v))
            p[key->at[k] % count] = v;
    }
    NF_FUZZ_CHECK(nf_model_set_params(c->seeded, p) == NF_OK, "nf_model_set_params");
    c->key = *key;
    c->seeded_valid = 1;
}

static void make_model(reader *r, machine *mc)
{
    unsigned a = rd_u8(r), b = rd_u8(r);
    shape_models *c = models_for(a);
    params_key key;
    memset(&key, 0, sizeof key);
    key.scale = b & 7u;
    key.seed = rd_u32(r);
    key.edits = (b >> 3) & 3u;
    for (uint32_t k = 0; k < key.edits; ++k) {
        key.at[k] = rd_u32(r);
        float v = rd_float(r);
        memcpy(&key.value[k], &v, sizeof v);
    }
    seed_params(c, &key);
    if (!c->flags.work_is_seeded) {
        NF_FUZZ_CHECK(nf_model_copy(c->work, c->seeded) == NF_OK, "nf_model_copy");
        c->flags.work_is_seeded = 1;
        c->flags.other_is_work = 0;
    }
    mc->flags = &c->flags;
    mc->m = c->work;
    mc->other = &c->other;
    mc->buf = c->buf;
    mc->prior = c->prior;
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
