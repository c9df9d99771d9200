/*
 * fuzz_path.c - libFuzzer target for nf_path_training_samples (path.h, docs/robustness.md):
 * the training-sample builder on any path a renderer could record, hostile values included.
 *
 * Input: byte 0 the vertex count (mod MAX_VERTICES + 1), byte 1 the capacity (mod
 * MAX_VERTICES + 2), byte 2 flags (bit 0..2: ctx_out, dir_out, weight_out NULL; bit 3:
 * vertex_out NULL; bit 4: count_out NULL), then per vertex one byte `learn` and 25 values
 * (ctx 9, dir 3, f_over_p 3, beta 3, direct 3, emitted 3, emitted_mis 1), each coded as one
 * byte: 0..15 a special value (0, -0, NaN, +-Inf, -1, FLT_MAX, FLT_MIN, FLT_TRUE_MIN, 1e-30,
 * 1e30, 20, 1e-16, 1, 0.5, -FLT_TRUE_MIN), 255 followed by 4 bytes of any float bit pattern,
 * else (b - 16) / 64 in [0, 3.7]. Missing bytes read as 0.
 *
 * Invariants, checked by abort():
 *   - the status is NF_ERROR_INVALID_ARGUMENT exactly when the input breaks path.h's rules
 *     (checked here independently), and then nothing is written, count included;
 *   - otherwise, with C samples the path gives (a second call with room for all): NF_OK with
 *     count C <= capacity, or NF_ERROR_CAPACITY with count C > capacity and nothing else
 *     written; on NF_OK the samples are those of the full call, bit for bit;
 *   - every sample has a finite weight > 0, comes from a learned vertex (vertex_out rises
 *     strictly), carries that vertex's context and direction unchanged, and nothing is
 *     written past count;
 *   - against an independent forward computation in double, L_i(w_j) = E_j + sum_{k>j}
 *     (prod_{j<m<k} beta_m) (D_k + beta_k H_k E_k): a learned vertex whose reference weight
 *     is in [1e-37, 1e37] has its sample with a relative error below 1e-6 (the library rounds
 *     a double to float once, 6e-8; the two double computations differ by ~1e-14), and one
 *     whose reference weight is exactly 0 has none. Weights outside that range sit where float
 *     rounding (denormals, FLT_MAX) decides, and the reference may overflow differently.
 */
#include <float.h>

#include "fuzz_common.h"

/* The floats of one context, which the sentinel checks walk. */
#define NF_CTX_FLOATS (sizeof(nf_context) / sizeof(float))

#define MAX_VERTICES 64
#define OUT_CAP (MAX_VERTICES + 2)
#define SIZE_SENTINEL ((size_t)0x5eed5eedu)
#define FLOAT_SENTINEL (-7.5e33f)

typedef struct reader {
    const uint8_t *p;
    size_t left;
} reader;

static uint8_t next_byte(reader *r)
{
    if (!r->left)
        return 0;
    --r->left;
    return *r->p++;
}

static float next_value(reader *r)
{
    static const float special[16] = {
        0.0f,         -0.0f,  NAN,   INFINITY, -INFINITY, -1.0f, FLT_MAX, FLT_MIN,
        FLT_TRUE_MIN, 1e-30f, 1e30f, 20.0f,    1e-16f,    1.0f,  0.5f,    -FLT_TRUE_MIN};
    uint8_t b = next_byte(r);
    if (b < 16)
        return special[b];
    if (b == 255) {
        uint32_t bits = 0;
        for (int i = 0; i < 4; ++i)
            bits |= (uint32_t)next_byte(r) << (8 * i);
        float v;
        memcpy(&v, &bits, sizeof v);
        return v;
    }
    return (float)(b - 16) / 64.0f;
}

static int rgb_ok(const float v[3])
{
    for (int c = 0; c < 3; ++c)
        if (!isfinite(v[c]) || v[c] < 0.0f)
            return 0;
    return 1;
}

static int vector_ok(const float v[3])
{
    if (!isfinite(v[0]) || !isfinite(v[1]) || !isfinite(v[2]))
        return 0;
    return (double)v[0] * v[0] + (double)v[1] * v[1] + (double)v[2] * v[2] > 1e-30;
}

static int vertex_ok(const nf_path_vertex *v)
{
    if (!rgb_ok(v->direct) || !rgb_ok(v->beta) || !rgb_ok(v->emitted))
        return 0;
    if (!(v->emitted_mis >= 0.0f && v->emitted_mis <= 1.0f))
        return 0;
    if (!v->learn)
        return 1;
    /* A zero normal (either sign of zero) is a point in a medium, whose phase_g counts. */
    const float *n = v->ctx.normal;
    int medium = n[0] == 0.0f && n[1] == 0.0f && n[2] == 0.0f;
    int normal_ok = medium ? fabsf(v->ctx.phase_g) <= NF_PHASE_G_MAX : vector_ok(n);
    return isfinite(v->ctx.position[0]) && isfinite(v->ctx.position[1]) &&
           isfinite(v->ctx.position[2]) && normal_ok && vector_ok(v->ctx.wo) &&
           vector_ok(v->dir) && rgb_ok(v->f_over_p);
}

/* The forward reference of the weight of learned vertex j, in double. */
static double reference_weight(const nf_path_vertex *v, size_t n, size_t j)
{
    double w = 0.0;
    for (int c = 0; c < 3; ++c) {
        double li = (double)v[j].emitted_mis * v[j].emitted[c], carry = 1.0;
        for (size_t k = j + 1; k < n; ++k) {
            li += carry *
                  (v[k].direct[c] + (double)v[k].beta[c] * v[k].emitted_mis * v[k].emitted[c]);
            carry *= v[k].beta[c];
        }
        w += (double)v[j].f_over_p[c] * li;
    }
    return w / 3.0;
}

typedef struct outputs {
    nf_context ctx[OUT_CAP];
    float dir[3 * OUT_CAP];
    float weight[OUT_CAP];
    size_t vertex[OUT_CAP];
    size_t count;
} outputs;

static void fill(outputs *o)
{
    float *c = (float *)o->ctx;
    for (size_t i = 0; i < NF_CTX_FLOATS * OUT_CAP; ++i)
        c[i] = FLOAT_SENTINEL;
    for (size_t i = 0; i < 3 * OUT_CAP; ++i)
        o->dir[i] = FLOAT_SENTINEL;
    for (size_t i = 0; i < OUT_CAP; ++i) {
        o->weight[i] = FLOAT_SENTINEL;
        o->vertex[i] = SIZE_SENTINEL;
    }
    o->count = SIZE_SENTINEL;
}

/* Entries from `from` on still hold the sentinels. */
static int untouched_from(const outputs *o, size_t from)
{
    const float *c = (const float *)o->ctx;
    for (size_t i = NF_CTX_FLOATS * from; i < NF_CTX_FLOATS * OUT_CAP; ++i)
        if (memcmp(&c[i], &(float){FLOAT_SENTINEL}, sizeof(float)) != 0)
            return 0;
    for (size_t i = 3 * from; i < 3 * OUT_CAP; ++i)
        if (memcmp(&o->dir[i], &(float){FLOAT_SENTINEL}, sizeof(float)) != 0)
            return 0;
    for (size_t i = from; i < OUT_CAP; ++i)
        if (memcmp(&o->weight[i], &(float){FLOAT_SENTINEL}, sizeof(float)) != 0 ||
            o->vertex[i] != SIZE_SENTINEL)
            return 0;
    return 1;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    reader r = {data, size};
    size_t n = next_byte(&r) % (MAX_VERTICES + 1);
    size_t capacity = next_byte(&r) % (MAX_VERTICES + 2);
    uint8_t flags = next_byte(&r);
    nf_path_vertex v[MAX_VERTICES];
    memset(v, 0, sizeof v);
    int valid = 1;
    for (size_t j = 0; j < n; ++j) {
        v[j].learn = next_byte(&r) & 1;
        float *fields[8] = {v[j].ctx.position, v[j].ctx.normal, v[j].ctx.wo, v[j].dir,
                            v[j].f_over_p,     v[j].beta,       v[j].direct, v[j].emitted};
        for (int f = 0; f < 8; ++f)
            for (int c = 0; c < 3; ++c)
                fields[f][c] = next_value(&r);
        v[j].emitted_mis = next_value(&r);
        v[j].ctx.phase_g = next_value(&r);
        valid = valid && vertex_ok(&v[j]);
    }

    outputs o;
    fill(&o);
    nf_context *ctx_out = flags & 1 ? NULL : o.ctx;
    float *dir_out = flags & 2 ? NULL : o.dir;
    float *weight_out = flags & 4 ? NULL : o.weight;
    size_t *vertex_out = flags & 8 ? NULL : o.vertex;
    size_t *count_out = flags & 16 ? NULL : &o.count;
    int args_ok = count_out && (capacity == 0 || (ctx_out && dir_out && weight_out));
    nf_status st = nf_path_training_samples(n, v, capacity, ctx_out, dir_out, weight_out,
                                            vertex_out, count_out);
    if (!args_ok || !valid) {
        NF_FUZZ_CHECK(st == NF_ERROR_INVALID_ARGUMENT, "status %d for invalid input (args %d)",
                      (int)st, args_ok);
        NF_FUZZ_CHECK(untouched_from(&o, 0) && o.count == SIZE_SENTINEL, "a refused call wrote");
        NF_FUZZ_CHECK(strstr(nf_last_error_message(), "nf_path_training_samples") != NULL,
                      "message without the function's name");
        return 0;
    }

    /* The truth: room for every sample. */
    outputs all;
    fill(&all);
    nf_status st_all = nf_path_training_samples(n, v, OUT_CAP, all.ctx, all.dir, all.weight,
                                                all.vertex, &all.count);
    NF_FUZZ_CHECK(st_all == NF_OK, "status %d with room for all", (int)st_all);
    size_t count = all.count;
    NF_FUZZ_CHECK(count <= n, "%zu samples from %zu vertices", count, n);
    NF_FUZZ_CHECK(untouched_from(&all, count), "written past count");
    for (size_t i = 0; i < count; ++i) {
        size_t j = all.vertex[i];
        NF_FUZZ_CHECK(j < n && v[j].learn, "sample %zu from vertex %zu", i, j);
        NF_FUZZ_CHECK(i == 0 || all.vertex[i - 1] < j, "vertex order");
        NF_FUZZ_CHECK(isfinite(all.weight[i]) && all.weight[i] > 0.0f, "weight %g",
                      (double)all.weight[i]);
        NF_FUZZ_CHECK(memcmp(&all.ctx[i], &v[j].ctx, sizeof(nf_context)) == 0, "context");
        NF_FUZZ_CHECK(memcmp(&all.dir[3 * i], v[j].dir, 3 * sizeof(float)) == 0, "direction");
    }
    size_t i = 0;
    for (size_t j = 0; j < n; ++j) {
        if (!v[j].learn)
            continue;
        int has = i < count && all.vertex[i] == j;
        double w = reference_weight(v, n, j);
        if (w == 0.0)
            NF_FUZZ_CHECK(!has, "vertex %zu: a sample of weight %g where 0 was expected", j,
                          (double)all.weight[i]);
        if (w >= 1e-37 && w <= 1e37) {
            NF_FUZZ_CHECK(has, "vertex %zu: no sample, expected weight %g", j, w);
            double err = fabs((double)all.weight[i] - w) / w;
            NF_FUZZ_CHECK(err < 1e-6, "vertex %zu: weight %.9g, expected %.9g", j,
                          (double)all.weight[i], w);
        }
        i += has;
    }

    /* The call as the fuzzer asked for it. */
    if (count > capacity) {
        NF_FUZZ_CHECK(st == NF_ERROR_CAPACITY, "status %d, %zu samples, capacity %zu", (int)st,
                      count, capacity);
        NF_FUZZ_CHECK(o.count == count, "count %zu, expected %zu", o.count, count);
        NF_FUZZ_CHECK(untouched_from(&o, 0), "a full buffer was written");
    } else {
        NF_FUZZ_CHECK(st == NF_OK, "status %d, %zu samples, capacity %zu", (int)st, count,
                      capacity);
        NF_FUZZ_CHECK(o.count == count, "count %zu, expected %zu", o.count, count);
        NF_FUZZ_CHECK(untouched_from(&o, count), "written past count");
        NF_FUZZ_CHECK(memcmp(o.weight, all.weight, count * sizeof(float)) == 0, "weights");
        NF_FUZZ_CHECK(memcmp(o.ctx, all.ctx, count * sizeof(nf_context)) == 0, "contexts");
        NF_FUZZ_CHECK(memcmp(o.dir, all.dir, 3 * count * sizeof(float)) == 0, "directions");
        if (vertex_out)
            NF_FUZZ_CHECK(memcmp(o.vertex, all.vertex, count * sizeof(size_t)) == 0, "vertices");
        else
            for (size_t k = 0; k < OUT_CAP; ++k)
                NF_FUZZ_CHECK(o.vertex[k] == SIZE_SENTINEL, "vertex_out NULL but written");
    }
    return 0;
}
