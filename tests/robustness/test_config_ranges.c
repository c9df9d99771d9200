/*
 * test_config_ranges.c - every float of nf_config and of the model format at its bounds, just
 * outside them, denormal, 0, negative, NaN and infinite, through nf_model_create
 * (NF_ERROR_INVALID_ARGUMENT), nf_model_deserialize and nf_model_load (NF_ERROR_FORMAT) and
 * nf_model_set_learning_rate; every refusal names the field. The ranges and their reasons:
 * include/nisflow/model.h and docs/robustness.md, "Configuration ranges".
 *
 * The first test is the reproducer of fuzz_model_api's finding: a valid file (custom prior,
 * checksum fixed) whose prior_epsilon is the denormal 1.4e-45 loaded, and nf_model_prior_pdf then
 * returned exactly 0 where the custom prior is 0.
 */
#include <float.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "nf_test_support.h"

/* Offsets of the header's floats (docs/format.md, format version 1). */
enum { OFF_EPS = 40, OFF_BMIN = 44, OFF_BMAX = 56, OFF_LR = 68, OFF_B1 = 72, OFF_B2 = 76 };
enum { OFF_AEPS = 80, OFF_WD = 84 };

static void put_f32(unsigned char *p, float v)
{
    uint32_t bits;
    memcpy(&bits, &v, 4);
    for (int i = 0; i < 4; ++i)
        p[i] = (unsigned char)(bits >> (8 * i));
}

static void fix_crc(unsigned char *buf, size_t size)
{
    uint32_t crc = nft_crc32_ieee(buf, size - 4);
    for (int i = 0; i < 4; ++i)
        buf[size - 4 + (size_t)i] = (unsigned char)(crc >> (8 * i));
}

/* The bytes of a fresh model of `cfg` (caller frees). */
static unsigned char *serialized(const nf_config *cfg, size_t *size)
{
    nf_model *m = NULL;
    assert_int_equal(nf_model_create(cfg, &m), NF_OK);
    assert_int_equal(nf_model_serialize(m, NULL, 0, size), NF_OK);
    unsigned char *buf = malloc(*size);
    assert_non_null(buf);
    assert_int_equal(nf_model_serialize(m, buf, *size, size), NF_OK);
    nf_model_destroy(m);
    return buf;
}

static void assert_message_names(const char *field)
{
    const char *msg = nf_last_error_message();
    if (!strstr(msg, field) || !strstr(msg, "outside")) {
        print_error("message '%s' does not name %s and its range\n", msg, field);
        fail();
    }
}

/* ---- the reproducer -------------------------------------------------------------------- */

static void test_denormal_prior_epsilon_file_is_refused(void **state)
{
    (void)state;
    nf_config cfg = nft_config(NF_PRESET_SMALL, NF_PRIOR_CUSTOM);
    const nf_prior_callbacks cb = nft_phong_callbacks();
    size_t size = 0;
    unsigned char *buf = serialized(&cfg, &size);
    const char *path = "test_config_ranges_denormal.nfm";
    /* The two values of the fuzzer's findings: 1.4e-45 and 8.4e-45 (bit patterns 1 and 6). */
    const uint32_t patterns[] = {1u, 6u};
    for (size_t k = 0; k < 2; ++k) {
        for (int i = 0; i < 4; ++i)
            buf[OFF_EPS + i] = (unsigned char)(patterns[k] >> (8 * i));
        fix_crc(buf, size);
        nf_model *m = (nf_model *)buf; /* must be overwritten with NULL */
        assert_int_equal(nf_model_deserialize(buf, size, &cb, &m), NF_ERROR_FORMAT);
        assert_null(m);
        assert_message_names("prior_epsilon");
        assert_non_null(strstr(nf_last_error_message(), "denormal"));
        FILE *f = fopen(path, "wb");
        assert_non_null(f);
        assert_int_equal(fwrite(buf, 1, size, f), size);
        assert_int_equal(fclose(f), 0);
        m = (nf_model *)buf;
        assert_int_equal(nf_model_load(path, &cb, &m), NF_ERROR_FORMAT);
        assert_null(m);
        assert_message_names("prior_epsilon");
    }
    remove(path);
    free(buf);
}

/* The cosine prior with the values of the report, through nf_model_create; and at the
 * smallest accepted epsilon the defensive floor is really there: below the surface (where
 * the cosine and the custom prior are 0) nf_model_prior_pdf and nf_pdf are eps / (4 pi). */
static void test_prior_epsilon_floor(void **state)
{
    (void)state;
    const float bad[] = {1.4e-45f, 1e-38f, FLT_MIN, 9.9e-7f};
    for (size_t k = 0; k < sizeof bad / sizeof bad[0]; ++k) {
        nf_config cfg = nft_config(NF_PRESET_SMALL, NF_PRIOR_COSINE);
        cfg.prior_epsilon = bad[k];
        nf_model *m = (nf_model *)&cfg;
        assert_int_equal(nf_model_create(&cfg, &m), NF_ERROR_INVALID_ARGUMENT);
        assert_null(m);
        assert_message_names("prior_epsilon");
    }
    const nf_prior_kind priors[] = {NF_PRIOR_COSINE, NF_PRIOR_CUSTOM};
    for (size_t k = 0; k < 2; ++k) {
        nf_config cfg = nft_config(NF_PRESET_SMALL, priors[k]);
        cfg.prior_epsilon = NF_PRIOR_EPSILON_MIN;
        nf_model *m = nft_model_from(&cfg);
        nf_context ctx = nft_context(0.5f, 0.5f, 0.5f, 0.0f, 0.0f, 1.0f, 0.0f, 0.0f, 1.0f);
        const float below[3] = {0.3f, -0.2f, -0.9f};
        float prior = nft_prior_pdf(m, &ctx, below), pdf = 0.0f;
        assert_int_equal(nf_pdf(m, 1, &ctx, below, &pdf), NF_OK);
        /* eps / (4 pi) in double; the float arithmetic rounds a few times: 1e-5 relative. */
        const double floor_pdf = 1e-6 / (4.0 * 3.14159265358979323846);
        assert_true(fabs(prior - floor_pdf) <= 1e-5 * floor_pdf);
        /* nf_pdf of the fresh (identity) model goes through the square and sin(theta): the
         * same density to float accuracy over a few operations, 1e-4 relative. */
        assert_true(fabs(pdf - floor_pdf) <= 1e-4 * floor_pdf);
        nf_model_destroy(m);
    }
}

/* ---- the table ------------------------------------------------------------------------- */

typedef struct field {
    const char *name;
    size_t offset;   /* in nf_config */
    size_t file_off; /* in the file */
    float lo, hi;
} field;

#define CFG_OFF(member) offsetof(nf_config, member)

static const field fields[] = {
    {"prior_epsilon", CFG_OFF(prior_epsilon), OFF_EPS, NF_PRIOR_EPSILON_MIN, 1.0f},
    {"learning_rate", CFG_OFF(learning_rate), OFF_LR, NF_LEARNING_RATE_MIN, NF_LEARNING_RATE_MAX},
    {"beta1", CFG_OFF(beta1), OFF_B1, 0.0f, NF_BETA1_MAX},
    {"beta2", CFG_OFF(beta2), OFF_B2, 0.0f, NF_BETA2_MAX},
    {"adam_epsilon", CFG_OFF(adam_epsilon), OFF_AEPS, NF_ADAM_EPSILON_MIN, NF_ADAM_EPSILON_MAX},
    {"weight_decay", CFG_OFF(weight_decay), OFF_WD, 0.0f, NF_WEIGHT_DECAY_MAX},
};

/* The probes of one field: its bounds, just outside, denormals, zeros, negatives, NaN and
 * infinities; `ok` says whether the value is in the documented range. */
typedef struct probe {
    float v;
    int ok;
    const char *what;
} probe;

static size_t probes_of(const field *f, probe *p)
{
    size_t n = 0;
    p[n++] = (probe){f->lo, 1, "lower bound"};
    p[n++] = (probe){f->hi, 1, "upper bound"};
    p[n++] = (probe){nextafterf(f->hi, INFINITY), 0, "just above"};
    if (f->lo > 0.0f) {
        p[n++] = (probe){nextafterf(f->lo, 0.0f), 0, "just below"};
        p[n++] = (probe){0.0f, 0, "zero"};
        p[n++] = (probe){-0.0f, 0, "-0"};
    } else {
        p[n++] = (probe){0.0f, 1, "zero"};
        p[n++] = (probe){-0.0f, 1, "-0 (counts as 0)"};
        p[n++] = (probe){FLT_MIN, 1, "FLT_MIN"};
    }
    p[n++] = (probe){FLT_TRUE_MIN, 0, "smallest denormal"};
    p[n++] = (probe){FLT_MIN / 2.0f, 0, "denormal FLT_MIN / 2"};
    p[n++] = (probe){-FLT_TRUE_MIN, 0, "negative denormal"};
    p[n++] = (probe){-f->hi, 0, "negative"};
    p[n++] = (probe){NAN, 0, "NaN"};
    p[n++] = (probe){INFINITY, 0, "Inf"};
    p[n++] = (probe){-INFINITY, 0, "-Inf"};
    return n;
}

/* A create or load of a value in range (expected NF_OK) made model m, which is destroyed; one
 * out of range left m NULL and named the field in its message. */
static void check_outcome(const char *call, nf_status st, nf_status expected, nf_model *m,
                          const char *name, const char *what)
{
    if (st != expected) {
        print_error("%s: %s %s: status %d (%s)\n", call, name, what, (int)st,
                    nf_last_error_message());
        fail();
    }
    if (st == NF_OK) {
        nf_model_destroy(m);
    } else {
        assert_null(m);
        assert_message_names(name);
    }
}

/* Creates and loads `cfg` (whose field `name` holds `v`); both must agree with `ok`. */
static void check_create_and_load(const nf_config *cfg, const unsigned char *valid, size_t size,
                                  const size_t *file_offs, const float *values, size_t count,
                                  const char *name, int ok, const char *what)
{
    nf_model *m = (nf_model *)(uintptr_t)valid;
    nf_status st = nf_model_create(cfg, &m);
    check_outcome("create", st, ok ? NF_OK : NF_ERROR_INVALID_ARGUMENT, m, name, what);
    unsigned char *buf = malloc(size);
    assert_non_null(buf);
    memcpy(buf, valid, size);
    for (size_t k = 0; k < count; ++k)
        put_f32(buf + file_offs[k], values[k]);
    fix_crc(buf, size);
    const nf_prior_callbacks cb = nft_phong_callbacks();
    m = (nf_model *)buf;
    st = nf_model_deserialize(buf, size, &cb, &m);
    check_outcome("load", st, ok ? NF_OK : NF_ERROR_FORMAT, m, name, what);
    free(buf);
}

static void test_every_float_field(void **state)
{
    (void)state;
    const nf_config base = nft_config(NF_PRESET_SMALL, NF_PRIOR_CUSTOM);
    size_t size = 0;
    unsigned char *valid = serialized(&base, &size);
    int checked = 0;
    for (size_t f = 0; f < sizeof fields / sizeof fields[0]; ++f) {
        probe probes[16];
        size_t n = probes_of(&fields[f], probes);
        for (size_t k = 0; k < n; ++k) {
            nf_config cfg = base;
            memcpy((char *)&cfg + fields[f].offset, &probes[k].v, sizeof(float));
            /* Keep learning_rate * weight_decay < 1 out of the way of the field's own range:
             * at the largest weight decay the learning rate is the default, and at the
             * largest learning rate the decay is 0. */
            if (!strcmp(fields[f].name, "learning_rate"))
                cfg.weight_decay = 0.0f;
            size_t offs[2] = {fields[f].file_off, OFF_WD};
            float vals[2] = {probes[k].v, cfg.weight_decay};
            check_create_and_load(&cfg, valid, size, offs, vals, 2, fields[f].name, probes[k].ok,
                                  probes[k].what);
            ++checked;
        }
    }
    free(valid);
    /* 6 fields of 13 or 14 probes each: the table really ran. */
    assert_true(checked >= 6 * 13);
}

/* The bounds: each of the six floats finite and not denormal, and on each axis an extent
 * max - min in [FLT_MIN, FLT_MAX]. */
static void test_bounds(void **state)
{
    (void)state;
    const nf_config base = nft_config(NF_PRESET_SMALL, NF_PRIOR_CUSTOM);
    size_t size = 0;
    unsigned char *valid = serialized(&base, &size);
    const float up = nextafterf(FLT_MIN, INFINITY);
    const struct {
        float lo, hi;
        int ok;
        const char *what, *names;
    } cases[] = {
        {0.0f, 1.0f, 1, "the unit interval", ""},
        {-FLT_MAX / 2.0f, FLT_MAX / 2.0f, 1, "the widest extent", ""},
        {0.0f, FLT_MIN, 1, "extent FLT_MIN", ""},
        {-1e6f, -1e6f + 0.0625f, 1, "a small extent far out", ""},
        {-FLT_MAX, FLT_MAX, 0, "extent overflows", "bounds_max[%d] - bounds_min"},
        {FLT_MIN, up, 0, "denormal extent", "bounds_max[%d] - bounds_min"},
        {1.0f, 1.0f, 0, "zero extent", "bounds_max[%d] - bounds_min"},
        {1.0f, 0.5f, 0, "negative extent", "bounds_max[%d] - bounds_min"},
        {0.0f, FLT_TRUE_MIN, 0, "denormal max", "bounds_max[%d]"},
        {-FLT_TRUE_MIN, 1.0f, 0, "denormal min", "bounds_min[%d]"},
        {NAN, 1.0f, 0, "NaN min", "bounds_min[%d]"},
        {0.0f, NAN, 0, "NaN max", "bounds_max[%d]"},
        {-INFINITY, 1.0f, 0, "-Inf min", "bounds_min[%d]"},
        {0.0f, INFINITY, 0, "Inf max", "bounds_max[%d]"},
    };
    for (size_t c = 0; c < sizeof cases / sizeof cases[0]; ++c) {
        for (int a = 0; a < 3; ++a) {
            nf_config cfg = base;
            cfg.bounds_min[a] = cases[c].lo;
            cfg.bounds_max[a] = cases[c].hi;
            char name[64];
            snprintf(name, sizeof name, cases[c].names, a);
            size_t offs[2] = {OFF_BMIN + 4u * (size_t)a, OFF_BMAX + 4u * (size_t)a};
            float vals[2] = {cases[c].lo, cases[c].hi};
            check_create_and_load(&cfg, valid, size, offs, vals, 2, name, cases[c].ok,
                                  cases[c].what);
        }
    }
    free(valid);
}

/* nf_model_set_learning_rate checks what nf_model_create checks, and a refusal leaves the model
 * bit-identical. */
static void test_set_learning_rate(void **state)
{
    (void)state;
    nf_config cfg = nft_config(NF_PRESET_SMALL, NF_PRIOR_COSINE);
    cfg.weight_decay = 0.0f;
    nf_model *m = nft_model_from(&cfg);
    const field lr = fields[1];
    probe probes[16];
    size_t n = probes_of(&lr, probes);
    for (size_t k = 0; k < n; ++k) {
        nft_snapshot snap = nft_snapshot_of(m);
        nf_status st = nf_model_set_learning_rate(m, probes[k].v);
        assert_int_equal(st, probes[k].ok ? NF_OK : NF_ERROR_INVALID_ARGUMENT);
        if (!probes[k].ok) {
            assert_message_names("learning_rate");
            assert_true(nft_snapshot_equal(m, &snap));
        } else {
            nf_config now;
            assert_int_equal(nf_model_get_config(m, &now), NF_OK);
            assert_true(now.learning_rate == probes[k].v);
        }
        nft_snapshot_free(&snap);
    }
    /* With a weight decay, the product bound: 1 / weight_decay is refused, just below is
     * not. */
    nf_model_destroy(m);
    cfg.weight_decay = 4.0f;
    assert_int_equal(nf_model_create(&cfg, &m), NF_OK);
    assert_int_equal(nf_model_set_learning_rate(m, 0.25f), NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "weight_decay"));
    assert_int_equal(nf_model_set_learning_rate(m, nextafterf(0.25f, 0.0f)), NF_OK);
    nf_model_destroy(m);
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_denormal_prior_epsilon_file_is_refused),
    cmocka_unit_test(test_prior_epsilon_floor),
    cmocka_unit_test(test_every_float_field),
    cmocka_unit_test(test_bounds),
    cmocka_unit_test(test_set_learning_rate),
)
