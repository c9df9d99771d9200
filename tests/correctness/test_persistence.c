/*
 * test_persistence.c - saving and loading models (io.h, docs/format.md): bit-exact round
 * trips, resumed training identical to uninterrupted training, and refusal of truncated,
 * corrupted, foreign-version and invalid files with NF_ERROR_FORMAT (never a crash, *out
 * NULL). The CRC-32 is recomputed here with an implementation of our own, to build files that
 * are structurally valid but wrong in one field.
 */
#define _POSIX_C_SOURCE 200809L /* getpid, for a unique file name */

#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <nisflow/nisflow.h>

#include "nf_test_support.h"

/* The layout of format version 2 (docs/format.md); version 1 ends its header at
 * OFF_PHI_MAP. */
#define OFF_VERSION 8u
#define OFF_COUPLING_LAYERS 12u
#define OFF_SPLINE_BINS 16u
#define OFF_HIDDEN_WIDTH 24u
#define OFF_PRIOR 36u
#define OFF_EPSILON 40u
#define OFF_BOUNDS_MIN 44u
#define OFF_BOUNDS_MAX 56u
#define OFF_LEARNING_RATE 68u
#define OFF_BETA2 76u
#define OFF_WEIGHT_DECAY 84u
#define OFF_STEP 96u
#define OFF_PARAM_COUNT 104u
#define OFF_PHI_MAP 112u
#define HEADER_V1 112u
#define HEADER 116u
#define TRAILER 4u

/* ---- helpers ---------------------------------------------------------------------------------- */

static void put_u32(unsigned char *p, uint32_t v)
{
    for (int i = 0; i < 4; ++i)
        p[i] = (unsigned char)(v >> (8 * i));
}

static uint32_t get_u32(const unsigned char *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

static uint64_t get_u64(const unsigned char *p)
{
    return (uint64_t)get_u32(p) | (uint64_t)get_u32(p + 4) << 32;
}

static void put_u64(unsigned char *p, uint64_t v)
{
    put_u32(p, (uint32_t)v);
    put_u32(p + 4, (uint32_t)(v >> 32));
}

static void put_f32(unsigned char *p, float v)
{
    uint32_t bits;
    memcpy(&bits, &v, 4);
    put_u32(p, bits);
}

/* Rewrites the trailing CRC-32 of a buffer so that it is structurally valid again. */
static void fix_crc(unsigned char *buf, size_t size)
{
    put_u32(buf + size - TRAILER, nft_crc32_ieee(buf, size - TRAILER));
}

/* Serializes a model into a new buffer. */
static unsigned char *serialize(const nf_model *m, size_t *size)
{
    assert_int_equal(nf_model_serialize(m, NULL, 0, size), NF_OK);
    unsigned char *buf = malloc(*size);
    assert_non_null(buf);
    size_t written = 0;
    assert_int_equal(nf_model_serialize(m, buf, *size, &written), NF_OK);
    assert_true(written == *size);
    return buf;
}

/* Deserializing must fail with `expect`, leave *out NULL (it starts non-NULL, so the library
 * must clear it), and record a message. */
static void expect_refused(const unsigned char *buf, size_t size,
                           const nf_prior_callbacks *custom, nf_status expect, const char *what)
{
    nf_model *sentinel = (nf_model *)(uintptr_t)0x1; /* never dereferenced */
    nf_model *out = sentinel;
    nf_status st = nf_model_deserialize(buf, size, custom, &out);
    if (st != expect || out != NULL) {
        if (st == NF_OK && out != sentinel)
            nf_model_destroy(out);
        fail_msg("%s: status %d (expected %d), out %s", what, (int)st, (int)expect,
                 out == NULL ? "NULL" : "not NULL");
    }
    assert_true(nf_last_error_message()[0] != '\0');
}

/* A small model with trained (non-initial) parameters and AdamW state. */
static nf_model *trained_model(nf_preset preset, nf_prior_kind prior, int steps, uint64_t seed)
{
    nf_model *m = nft_make_model(preset, prior);
    assert_int_equal(nft_randomize_params(m, 0.2f, seed), NF_OK);
    enum { N = 64 };
    nf_context ctx[N];
    float dir[3 * N], weight[N];
    nft_rng r;
    nft_rng_seed(&r, seed, 3u);
    for (int s = 0; s < steps; ++s) {
        nft_random_samples(&r, N, ctx, dir, weight, 0.0f);
        assert_int_equal(nf_train_step(m, N, ctx, dir, weight, NULL), NF_OK);
    }
    return m;
}

/* The models' outputs are bit-identical: parameters, serialized bytes (hence AdamW state and
 * step), and nf_sample / nf_pdf on a batch. */
static void assert_models_identical(const nf_model *a, const nf_model *b)
{
    size_t count = nf_model_param_count(a);
    assert_true(nf_model_param_count(b) == count);
    assert_true(nf_model_step_count(a) == nf_model_step_count(b));
    float *pa = malloc(count * sizeof *pa), *pb = malloc(count * sizeof *pb);
    assert_true(pa && pb);
    assert_int_equal(nf_model_get_params(a, pa), NF_OK);
    assert_int_equal(nf_model_get_params(b, pb), NF_OK);
    assert_memory_equal(pa, pb, count * sizeof *pa);
    free(pa);
    free(pb);
    size_t sa, sb;
    unsigned char *ba = serialize(a, &sa), *bb = serialize(b, &sb);
    assert_true(sa == sb);
    assert_memory_equal(ba, bb, sa);
    free(ba);
    free(bb);
    enum { N = 128 };
    nf_context ctx[N];
    float u[2 * N], da[3 * N], db[3 * N], pda[N], pdb[N], qa[N], qb[N];
    nft_rng r;
    nft_rng_seed(&r, 5150u, 1u);
    nft_random_queries(&r, N, ctx, u);
    assert_int_equal(nf_sample(a, N, ctx, u, da, pda), NF_OK);
    assert_int_equal(nf_sample(b, N, ctx, u, db, pdb), NF_OK);
    assert_memory_equal(da, db, sizeof da);
    assert_memory_equal(pda, pdb, sizeof pda);
    assert_int_equal(nf_pdf(a, N, ctx, da, qa), NF_OK);
    assert_int_equal(nf_pdf(b, N, ctx, da, qb), NF_OK);
    assert_memory_equal(qa, qb, sizeof qa);
}

/* ---- round trips ------------------------------------------------------------------------------ */

static void check_round_trip(nf_preset preset, nf_prior_kind prior)
{
    nf_model *m = trained_model(preset, prior, 3, 10u + (uint64_t)prior);
    size_t size;
    unsigned char *buf = serialize(m, &size);
    /* The documented size: header, three float arrays, checksum. */
    assert_true(size == HEADER + 12u * nf_model_param_count(m) + TRAILER);
    assert_memory_equal(buf, "NISFLOW\0", 8);
    assert_true(get_u32(buf + OFF_VERSION) == 2u);
    assert_true(get_u32(buf + OFF_PHI_MAP) == (uint32_t)nft_phi_map());
    assert_true(get_u64(buf + OFF_PARAM_COUNT) == nf_model_param_count(m));
    assert_true(get_u64(buf + OFF_STEP) == 3u);
    /* Our own CRC agrees with the stored one (little-endian, all preceding bytes). */
    assert_true(get_u32(buf + size - TRAILER) == nft_crc32_ieee(buf, size - TRAILER));
    nf_prior_callbacks cb = nft_phong_callbacks();
    nf_model *back = NULL;
    assert_int_equal(nf_model_deserialize(buf, size, prior == NF_PRIOR_CUSTOM ? &cb : NULL,
                                          &back),
                     NF_OK);
    assert_non_null(back);
    /* The buffer is only read and may be freed. */
    free(buf);
    assert_models_identical(m, back);
    nf_config ca, cb2;
    assert_int_equal(nf_model_get_config(m, &ca), NF_OK);
    assert_int_equal(nf_model_get_config(back, &cb2), NF_OK);
    assert_true(ca.coupling_layers == cb2.coupling_layers && ca.spline_bins == cb2.spline_bins &&
                ca.hidden_layers == cb2.hidden_layers && ca.hidden_width == cb2.hidden_width &&
                ca.oneblob_bins == cb2.oneblob_bins && ca.sh_bands == cb2.sh_bands &&
                ca.prior == cb2.prior && ca.prior_epsilon == cb2.prior_epsilon &&
                ca.learning_rate == cb2.learning_rate && ca.beta1 == cb2.beta1 &&
                ca.beta2 == cb2.beta2 && ca.adam_epsilon == cb2.adam_epsilon &&
                ca.weight_decay == cb2.weight_decay && ca.seed == cb2.seed);
    nf_model_destroy(back);
    nf_model_destroy(m);
}

static void test_round_trip_small(void **state)
{
    (void)state;
    check_round_trip(NF_PRESET_SMALL, NF_PRIOR_COSINE);
    check_round_trip(NF_PRESET_SMALL, NF_PRIOR_UNIFORM_DIRECTION);
    check_round_trip(NF_PRESET_SMALL, NF_PRIOR_UNIFORM_ANGLE);
    check_round_trip(NF_PRESET_SMALL, NF_PRIOR_CUSTOM);
}

static void test_round_trip_large(void **state)
{
    (void)state;
    check_round_trip(NF_PRESET_LARGE, NF_PRIOR_COSINE);
}

/* A non-default configuration survives (scene bounds, encodings, AdamW settings, a learning
 * rate changed after creation). */
static void test_round_trip_config(void **state)
{
    (void)state;
    nf_config cfg = nft_config(NF_PRESET_SMALL, NF_PRIOR_COSINE);
    cfg.coupling_layers = 3;
    cfg.spline_bins = 5;
    cfg.hidden_layers = 2;
    cfg.hidden_width = 7;
    cfg.oneblob_bins = 9;
    cfg.sh_bands = 2;
    cfg.prior_epsilon = 0.25f;
    cfg.bounds_min[0] = -10.0f;
    cfg.bounds_max[2] = 3.5f;
    cfg.beta1 = 0.5f;
    cfg.adam_epsilon = 1e-5f;
    cfg.weight_decay = 0.0f;
    cfg.seed = 0x123456789abcdefull;
    cfg.phi_map = NF_PHI_INTERVAL; /* not the default */
    nf_model *m = nft_model_from(&cfg);
    assert_int_equal(nf_model_set_learning_rate(m, 0.02f), NF_OK);
    size_t size;
    unsigned char *buf = serialize(m, &size);
    nf_model *back = NULL;
    assert_int_equal(nf_model_deserialize(buf, size, NULL, &back), NF_OK);
    nf_config c;
    assert_int_equal(nf_model_get_config(back, &c), NF_OK);
    assert_true(c.coupling_layers == 3 && c.spline_bins == 5 && c.hidden_layers == 2 &&
                c.hidden_width == 7 && c.oneblob_bins == 9 && c.sh_bands == 2);
    assert_true(c.prior_epsilon == 0.25f && c.bounds_min[0] == -10.0f &&
                c.bounds_max[2] == 3.5f && c.beta1 == 0.5f && c.adam_epsilon == 1e-5f &&
                c.weight_decay == 0.0f && c.learning_rate == 0.02f &&
                c.seed == 0x123456789abcdefull && c.phi_map == NF_PHI_INTERVAL);
    assert_int_equal(get_u32(buf + OFF_PHI_MAP), NF_PHI_INTERVAL);
    assert_models_identical(m, back);
    free(buf);
    nf_model_destroy(back);
    nf_model_destroy(m);
}

/* nf_model_save / nf_model_load through a file in the working directory. */
static void test_save_load_file(void **state)
{
    (void)state;
    char path[128];
    snprintf(path, sizeof path, "nf_test_persistence_%ld.nfm", (long)getpid());
    nf_model *m = trained_model(NF_PRESET_SMALL, NF_PRIOR_CUSTOM, 2, 20u);
    assert_int_equal(nf_model_save(m, path), NF_OK);
    /* The file holds exactly the serialized bytes. */
    size_t size;
    unsigned char *buf = serialize(m, &size);
    FILE *f = fopen(path, "rb");
    assert_non_null(f);
    unsigned char *file = malloc(size + 1);
    assert_non_null(file);
    size_t got = fread(file, 1, size + 1, f);
    fclose(f);
    assert_true(got == size);
    assert_memory_equal(file, buf, size);
    free(file);
    free(buf);
    nf_prior_callbacks cb = nft_phong_callbacks();
    nf_model *back = NULL;
    nf_status st = nf_model_load(path, &cb, &back);
    /* Without the callbacks a custom-prior model cannot be loaded. */
    nf_model *none = (nf_model *)(uintptr_t)0x1;
    nf_status st_none = nf_model_load(path, NULL, &none);
    remove(path);
    assert_int_equal(st, NF_OK);
    assert_int_equal(st_none, NF_ERROR_INVALID_ARGUMENT);
    assert_null(none);
    assert_models_identical(m, back);
    nf_model_destroy(back);
    nf_model_destroy(m);
}

/* A missing file is an I/O error; so is an unwritable path. */
static void test_load_missing_file(void **state)
{
    (void)state;
    char path[128];
    snprintf(path, sizeof path, "nf_test_persistence_missing_%ld.nfm", (long)getpid());
    nf_model *out = (nf_model *)(uintptr_t)0x1;
    assert_int_equal(nf_model_load(path, NULL, &out), NF_ERROR_IO);
    assert_null(out);
    nf_model *m = nft_make_model(NF_PRESET_SMALL, NF_PRIOR_COSINE);
    assert_int_equal(nf_model_save(m, "nf_no_such_directory_for_tests/model.nfm"), NF_ERROR_IO);
    nf_model_destroy(m);
}

/* nf_model_serialize with a too-small buffer: NF_ERROR_CAPACITY, *size set, the buffer
 * untouched. */
static void test_serialize_capacity(void **state)
{
    nf_model *m = *state;
    size_t need = 0;
    assert_int_equal(nf_model_serialize(m, NULL, 0, &need), NF_OK);
    assert_true(need == HEADER + 12u * nf_model_param_count(m) + TRAILER);
    unsigned char *buf = malloc(need);
    assert_non_null(buf);
    memset(buf, 0xA5, need);
    size_t size = 0;
    assert_int_equal(nf_model_serialize(m, buf, need - 1, &size), NF_ERROR_CAPACITY);
    assert_true(size == need);
    size = 0;
    assert_int_equal(nf_model_serialize(m, buf, 0, &size), NF_ERROR_CAPACITY);
    assert_true(size == need);
    for (size_t i = 0; i < need; ++i)
        assert_true(buf[i] == 0xA5);
    /* A larger buffer is fine and reports the bytes written. */
    unsigned char *big = malloc(need + 100);
    assert_non_null(big);
    assert_int_equal(nf_model_serialize(m, big, need + 100, &size), NF_OK);
    assert_true(size == need);
    free(big);
    free(buf);
}

/* ---- resumed training ------------------------------------------------------------------------- */

/* Training k steps, saving, loading and training n more steps gives bit-identically the model
 * that trained k + n steps without stopping (same batches): the file carries the AdamW
 * moments and the step count that drives the bias correction. */
static void test_resume_training(void **state)
{
    (void)state;
    enum { N = 48, K = 5, MORE = 7 };
    static nf_context ctx[K + MORE][N];
    static float dir[K + MORE][3 * N], weight[K + MORE][N];
    nft_rng r;
    nft_rng_seed(&r, 30u, 1u);
    for (int s = 0; s < K + MORE; ++s) {
        for (int i = 0; i < N; ++i) {
            nft_random_context(&r, &ctx[s][i]);
            nft_random_unit_vector(&r, dir[s] + 3 * i);
            weight[s][i] = nft_rng_float(&r) * 3.0f;
        }
    }
    char path[128];
    snprintf(path, sizeof path, "nf_test_persistence_resume_%ld.nfm", (long)getpid());
    for (int preset = 0; preset < 2; ++preset) {
        nf_model *straight = nft_make_model((nf_preset)preset, NF_PRIOR_COSINE);
        nf_model *first = nft_make_model((nf_preset)preset, NF_PRIOR_COSINE);
        assert_true(straight && first);
        for (int s = 0; s < K; ++s) {
            assert_int_equal(nf_train_step(straight, N, ctx[s], dir[s], weight[s], NULL), NF_OK);
            assert_int_equal(nf_train_step(first, N, ctx[s], dir[s], weight[s], NULL), NF_OK);
        }
        assert_int_equal(nf_model_save(first, path), NF_OK);
        nf_model_destroy(first);
        nf_model *resumed = NULL;
        nf_status st = nf_model_load(path, NULL, &resumed);
        remove(path);
        assert_int_equal(st, NF_OK);
        assert_true(nf_model_step_count(resumed) == K);
        for (int s = K; s < K + MORE; ++s) {
            float l1, l2;
            assert_int_equal(nf_train_step(straight, N, ctx[s], dir[s], weight[s], &l1), NF_OK);
            assert_int_equal(nf_train_step(resumed, N, ctx[s], dir[s], weight[s], &l2), NF_OK);
            assert_true(memcmp(&l1, &l2, sizeof l1) == 0);
        }
        assert_true(nf_model_step_count(straight) == K + MORE);
        assert_models_identical(straight, resumed);
        nf_model_destroy(straight);
        nf_model_destroy(resumed);
    }
}

/* ---- hostile input ---------------------------------------------------------------------------- */

/* Every length below the header + checksum, a stride of lengths beyond, and the last 64:
 * NF_ERROR_FORMAT, *out NULL. (All lengths would be ~72000 CRC passes over ~36 kB.) */
static void test_truncated(void **state)
{
    (void)state;
    nf_model *m = trained_model(NF_PRESET_SMALL, NF_PRIOR_COSINE, 1, 40u);
    size_t size;
    unsigned char *buf = serialize(m, &size);
    int tried = 0;
    for (size_t len = 0; len < size; ++len) {
        if (!(len <= HEADER + TRAILER + 8 || len % 97 == 0 || len + 64 >= size))
            continue;
        /* A copy of exactly len bytes, so that reading past it is caught by sanitizers. */
        unsigned char *copy = malloc(len ? len : 1);
        assert_non_null(copy);
        memcpy(copy, buf, len);
        char what[64];
        snprintf(what, sizeof what, "truncated to %zu bytes", len);
        expect_refused(copy, len, NULL, NF_ERROR_FORMAT, what);
        free(copy);
        ++tried;
    }
    assert_true(tried > 800);
    /* A truncated file with a recomputed checksum is refused too (the size does not match the
     * parameter count). */
    unsigned char *copy = malloc(size);
    assert_non_null(copy);
    memcpy(copy, buf, size);
    size_t short_size = size - 4 * 5;
    fix_crc(copy, short_size);
    expect_refused(copy, short_size, NULL, NF_ERROR_FORMAT, "truncated, valid checksum");
    /* Extra bytes after a valid file, with or without a matching checksum at the new end. */
    unsigned char *longer = malloc(size + 8);
    assert_non_null(longer);
    memcpy(longer, buf, size);
    memset(longer + size, 0, 8);
    expect_refused(longer, size + 8, NULL, NF_ERROR_FORMAT, "trailing bytes");
    fix_crc(longer, size + 8);
    expect_refused(longer, size + 8, NULL, NF_ERROR_FORMAT, "trailing bytes, valid checksum");
    free(longer);
    free(copy);
    free(buf);
    nf_model_destroy(m);
}

/* Single bit flips: every bit of the header, the checksum's bits, and a sample of positions in
 * the body (parameters, moments): a CRC-32 detects every single-bit error. */
static void test_bit_flips(void **state)
{
    (void)state;
    nf_model *m = trained_model(NF_PRESET_SMALL, NF_PRIOR_COSINE, 1, 50u);
    size_t size;
    unsigned char *buf = serialize(m, &size);
    nft_rng r;
    nft_rng_seed(&r, 51u, 1u);
    int tried = 0;
    for (size_t pos = 0; pos < size; ++pos) {
        int header = pos < HEADER, trailer = pos >= size - TRAILER;
        if (!header && !trailer && nft_rng_u32(&r) % 97 != 0)
            continue;
        int bits = (header || trailer) ? 8 : 1;
        for (int k = 0; k < bits; ++k) {
            int bit = bits == 8 ? k : (int)(nft_rng_u32(&r) % 8);
            buf[pos] ^= (unsigned char)(1u << bit);
            char what[64];
            snprintf(what, sizeof what, "bit %d of byte %zu flipped", bit, pos);
            expect_refused(buf, size, NULL, NF_ERROR_FORMAT, what);
            buf[pos] ^= (unsigned char)(1u << bit);
            ++tried;
        }
    }
    assert_true(tried > 8 * (int)(HEADER + TRAILER) + 500);
    /* Restored, it loads again. */
    nf_model *back = NULL;
    assert_int_equal(nf_model_deserialize(buf, size, NULL, &back), NF_OK);
    nf_model_destroy(back);
    free(buf);
    nf_model_destroy(m);
}

/* Each of `values` written as the u32 at `offset` of a valid file, with a valid checksum:
 * NF_ERROR_FORMAT, with a message containing `word`. */
static void expect_u32_refused(size_t offset, const uint32_t *values, size_t count,
                               const char *word)
{
    nf_model *m = nft_make_model(NF_PRESET_SMALL, NF_PRIOR_COSINE);
    size_t size;
    unsigned char *buf = serialize(m, &size);
    for (size_t i = 0; i < count; ++i) {
        put_u32(buf + offset, values[i]);
        fix_crc(buf, size);
        expect_refused(buf, size, NULL, NF_ERROR_FORMAT, word);
        if (!strstr(nf_last_error_message(), word))
            fail_msg("%s %u refused with \"%s\"", word, values[i], nf_last_error_message());
    }
    free(buf);
    nf_model_destroy(m);
}

/* A different format version: refused, and the message says it is the version. */
static void test_other_version(void **state)
{
    (void)state;
    static const uint32_t versions[] = {0u, 3u, 7u, 0x01000000u, 0xFFFFFFFFu};
    expect_u32_refused(OFF_VERSION, versions, sizeof versions / sizeof versions[0], "version");
}

/* A version-2 file written as version 1: the header without phi_map, the rest the same. */
static unsigned char *as_version_1(const unsigned char *buf, size_t size, size_t *size_v1)
{
    *size_v1 = size - 4u;
    unsigned char *v1 = malloc(*size_v1);
    assert_non_null(v1);
    memcpy(v1, buf, HEADER_V1);
    memcpy(v1 + HEADER_V1, buf + HEADER, size - HEADER);
    put_u32(v1 + OFF_VERSION, 1u);
    fix_crc(v1, *size_v1);
    return v1;
}

/* The context of a line of tests/data/model-v1.txt: position, normal, wo. */
static nf_context line_context(const float line[13])
{
    nf_context c;
    memcpy(c.position, line, sizeof c.position);
    memcpy(c.normal, line + 3, sizeof c.normal);
    memcpy(c.wo, line + 6, sizeof c.wo);
    return c;
}

/* Densities of `m` at the contexts and directions of `lines` against the density each line
 * stores; returns the worst relative difference. */
static double worst_pdf_difference(const nf_model *m, const float (*lines)[13], int count)
{
    double worst = 0.0;
    for (int k = 0; k < count; ++k) {
        nf_context c = line_context(lines[k]);
        float pdf;
        assert_int_equal(nf_pdf(m, 1, &c, lines[k] + 9, &pdf), NF_OK);
        worst = fmax(worst, fabs((double)pdf - lines[k][12]) / lines[k][12]);
    }
    return worst;
}

/* Files of format version 1 still load, as NF_PHI_INTERVAL models (the only map version 1
 * could hold) with the densities they had: the file libnisflow 0.1.0 wrote
 * (tests/data/make_model_v1.c), against the densities that library computed with the generic
 * kernels: the same arithmetic, so the same values up to the compiler's contraction of
 * multiply-adds, which moves them by ~1e-6 relative (model.h, nf_isa); 1e-5 allowed. And a
 * version-2 file of an interval model rewritten as version 1 gives the same bits. */
static void test_version_1_files(void **state)
{
    (void)state;
    nf_model *old = NULL;
    assert_int_equal(nf_model_load(NF_TEST_SOURCE_DIR "/data/model-v1.nfm", NULL, &old), NF_OK);
    nf_config c;
    assert_int_equal(nf_model_get_config(old, &c), NF_OK);
    assert_int_equal(c.phi_map, NF_PHI_INTERVAL);
    assert_int_equal(nf_model_set_isa(old, NF_ISA_GENERIC), NF_OK);
    FILE *f = fopen(NF_TEST_SOURCE_DIR "/data/model-v1.txt", "r");
    assert_non_null(f);
    static float lines[64][13];
    int count = 0;
    while (count < 64) {
        int got = 0;
        for (int j = 0; j < 13; ++j)
            got += fscanf(f, "%a", &lines[count][j]);
        if (got != 13)
            break;
        ++count;
    }
    fclose(f);
    assert_int_equal(count, 64);
    double worst = worst_pdf_difference(old, (const float(*)[13])lines, count);
    print_message("version-1 file: worst relative density difference %.3g over %d\n", worst,
                  count);
    assert_true(worst < 1e-5);

    /* Saved again it is a version-2 file of an interval model, with the same densities. */
    size_t size, size_v1;
    unsigned char *buf = serialize(old, &size);
    assert_int_equal(get_u32(buf + OFF_VERSION), 2u);
    assert_int_equal(size, HEADER + 12u * nf_model_param_count(old) + TRAILER);
    unsigned char *v1 = as_version_1(buf, size, &size_v1);
    nf_model *again = NULL;
    assert_int_equal(nf_model_deserialize(v1, size_v1, NULL, &again), NF_OK);
    assert_int_equal(nf_model_set_isa(again, NF_ISA_GENERIC), NF_OK);
    assert_models_identical(old, again);
    for (int k = 0; k < count; ++k) {
        nf_context ctx = line_context(lines[k]);
        float a, b;
        assert_int_equal(nf_pdf(old, 1, &ctx, lines[k] + 9, &a), NF_OK);
        assert_int_equal(nf_pdf(again, 1, &ctx, lines[k] + 9, &b), NF_OK);
        assert_memory_equal(&a, &b, sizeof a);
    }
    /* A version-1 file one byte short or long of its size is refused like any other. */
    expect_refused(v1, size_v1 - 1u, NULL, NF_ERROR_FORMAT, "version 1, truncated");
    free(v1);
    free(buf);
    nf_model_destroy(again);
    nf_model_destroy(old);
}

/* A phi map outside the enum: refused, and the message names it. */
static void test_unknown_phi_map(void **state)
{
    (void)state;
    static const uint32_t maps[] = {2u, 0x80000000u, 0xFFFFFFFFu};
    expect_u32_refused(OFF_PHI_MAP, maps, sizeof maps / sizeof maps[0], "phi map");
}

/* Structurally valid files (valid checksum, right size) whose content is invalid. */
static void test_invalid_content(void **state)
{
    (void)state;
    nf_model *m = trained_model(NF_PRESET_SMALL, NF_PRIOR_COSINE, 2, 60u);
    size_t size;
    unsigned char *orig = serialize(m, &size), *buf = malloc(size);
    assert_non_null(buf);
    size_t P = nf_model_param_count(m);
    struct {
        const char *what;
        size_t offset;
        int kind; /* 0: u32, 1: f32, 2: u64 */
        uint32_t u;
        float f;
        uint64_t u64;
    } cases[] = {
        {"spline_bins = 1", OFF_SPLINE_BINS, 0, 1u, 0.0f, 0},
        {"spline_bins = 65", OFF_SPLINE_BINS, 0, NF_MAX_SPLINE_BINS + 1u, 0.0f, 0},
        {"coupling_layers = 0", OFF_COUPLING_LAYERS, 0, 0u, 0.0f, 0},
        {"coupling_layers = 2^32 - 1", OFF_COUPLING_LAYERS, 0, 0xFFFFFFFFu, 0.0f, 0},
        {"hidden_width = 0", OFF_HIDDEN_WIDTH, 0, 0u, 0.0f, 0},
        {"prior = 4", OFF_PRIOR, 0, 4u, 0.0f, 0},
        {"prior_epsilon = 0", OFF_EPSILON, 1, 0, 0.0f, 0},
        {"prior_epsilon = NaN", OFF_EPSILON, 1, 0, NAN, 0},
        {"prior_epsilon = 1.5", OFF_EPSILON, 1, 0, 1.5f, 0},
        {"bounds_max[0] = bounds_min[0]", OFF_BOUNDS_MAX, 1, 0, 0.0f, 0},
        {"bounds_min[1] = -inf", OFF_BOUNDS_MIN + 4, 1, 0, -INFINITY, 0},
        {"learning_rate = -1", OFF_LEARNING_RATE, 1, 0, -1.0f, 0},
        {"beta2 = 1", OFF_BETA2, 1, 0, 1.0f, 0},
        {"weight_decay = 2000 (lr wd >= 1)", OFF_WEIGHT_DECAY, 1, 0, 2000.0f, 0},
        {"param_count + 1", OFF_PARAM_COUNT, 2, 0, 0.0f, 0},
        {"param_count = 2^64 - 1", OFF_PARAM_COUNT, 2, 0, 0.0f, ~(uint64_t)0},
        {"parameter 17 = NaN", HEADER + 4u * 17u, 1, 0, NAN, 0},
        {"last parameter = inf", HEADER + 4u * (P - 1u), 1, 0, INFINITY, 0},
        {"first moment = -inf", HEADER + 4u * (P + 3u), 1, 0, -INFINITY, 0},
        {"second moment < 0", HEADER + 4u * (2u * P + 5u), 1, 0, -1.0f, 0},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; ++i) {
        memcpy(buf, orig, size);
        if (cases[i].kind == 0)
            put_u32(buf + cases[i].offset, cases[i].u);
        else if (cases[i].kind == 1)
            put_f32(buf + cases[i].offset, cases[i].f);
        else
            put_u64(buf + cases[i].offset, cases[i].u64 ? cases[i].u64 : (uint64_t)P + 1u);
        fix_crc(buf, size);
        expect_refused(buf, size, NULL, NF_ERROR_FORMAT, cases[i].what);
    }
    /* The unmodified buffer with our recomputed CRC still loads: the checks above failed on
     * the field, not on our checksum. */
    memcpy(buf, orig, size);
    fix_crc(buf, size);
    assert_memory_equal(buf, orig, size);
    nf_model *back = NULL;
    assert_int_equal(nf_model_deserialize(buf, size, NULL, &back), NF_OK);
    nf_model_destroy(back);
    /* Negative zero is a valid second moment... and a finite parameter change is accepted:
     * structurally valid files with valid content load. */
    put_f32(buf + HEADER + 4u * (2u * P + 5u), -0.0f);
    put_f32(buf + HEADER + 4u * 3u, 0.125f);
    fix_crc(buf, size);
    back = NULL;
    assert_int_equal(nf_model_deserialize(buf, size, NULL, &back), NF_OK);
    float *p = malloc(P * sizeof *p);
    assert_non_null(p);
    assert_int_equal(nf_model_get_params(back, p), NF_OK);
    assert_true(p[3] == 0.125f);
    free(p);
    nf_model_destroy(back);
    free(buf);
    free(orig);
    nf_model_destroy(m);
}

/* A model with NF_PRIOR_CUSTOM loads only when callbacks are passed; the prior of a
 * non-custom model in a file edited to say "custom" needs them too. */
static void test_custom_prior_callbacks(void **state)
{
    (void)state;
    nf_model *m = trained_model(NF_PRESET_SMALL, NF_PRIOR_CUSTOM, 1, 70u);
    size_t size;
    unsigned char *buf = serialize(m, &size);
    expect_refused(buf, size, NULL, NF_ERROR_INVALID_ARGUMENT, "custom prior, no callbacks");
    nf_prior_callbacks half = nft_phong_callbacks();
    half.pdf = NULL;
    expect_refused(buf, size, &half, NF_ERROR_INVALID_ARGUMENT, "custom prior, no pdf");
    nf_prior_callbacks cb = nft_phong_callbacks();
    nf_model *back = NULL;
    assert_int_equal(nf_model_deserialize(buf, size, &cb, &back), NF_OK);
    assert_models_identical(m, back);
    nf_model_destroy(back);
    free(buf);
    nf_model_destroy(m);

    /* A cosine model: callbacks are ignored; edited to custom, they become required. */
    m = nft_make_model(NF_PRESET_SMALL, NF_PRIOR_COSINE);
    buf = serialize(m, &size);
    back = NULL;
    assert_int_equal(nf_model_deserialize(buf, size, &cb, &back), NF_OK);
    nf_config c;
    assert_int_equal(nf_model_get_config(back, &c), NF_OK);
    assert_true(c.prior == NF_PRIOR_COSINE);
    nf_model_destroy(back);
    put_u32(buf + OFF_PRIOR, (uint32_t)NF_PRIOR_CUSTOM);
    fix_crc(buf, size);
    expect_refused(buf, size, NULL, NF_ERROR_INVALID_ARGUMENT, "edited to custom");
    back = NULL;
    assert_int_equal(nf_model_deserialize(buf, size, &cb, &back), NF_OK);
    assert_int_equal(nf_model_get_config(back, &c), NF_OK);
    assert_true(c.prior == NF_PRIOR_CUSTOM);
    nf_model_destroy(back);
    free(buf);
    nf_model_destroy(m);
}

/* NULL arguments. */
static void test_null_arguments(void **state)
{
    nf_model *m = *state;
    size_t size;
    unsigned char *buf = serialize(m, &size);
    nf_model *out = (nf_model *)(uintptr_t)0x1;
    assert_int_equal(nf_model_deserialize(NULL, size, NULL, &out), NF_ERROR_INVALID_ARGUMENT);
    assert_null(out);
    assert_int_equal(nf_model_deserialize(buf, size, NULL, NULL), NF_ERROR_INVALID_ARGUMENT);
    out = (nf_model *)(uintptr_t)0x1;
    assert_int_equal(nf_model_load(NULL, NULL, &out), NF_ERROR_INVALID_ARGUMENT);
    assert_null(out);
    assert_int_equal(nf_model_save(NULL, "x.nfm"), NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_model_save(m, NULL), NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_model_serialize(NULL, buf, size, &size), NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_model_serialize(m, buf, size, NULL), NF_ERROR_INVALID_ARGUMENT);
    free(buf);
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_round_trip_small),
    cmocka_unit_test(test_round_trip_large),
    cmocka_unit_test(test_round_trip_config),
    cmocka_unit_test(test_save_load_file),
    cmocka_unit_test(test_load_missing_file),
    NFT_WITH_MODEL(test_serialize_capacity),
    cmocka_unit_test(test_resume_training),
    cmocka_unit_test(test_truncated),
    cmocka_unit_test(test_bit_flips),
    cmocka_unit_test(test_other_version),
    cmocka_unit_test(test_version_1_files),
    cmocka_unit_test(test_unknown_phi_map),
    cmocka_unit_test(test_invalid_content),
    cmocka_unit_test(test_custom_prior_callbacks),
    NFT_WITH_MODEL(test_null_arguments),
)
