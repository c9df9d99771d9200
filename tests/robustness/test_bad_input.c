/*
 * test_bad_input.c - every public entry point refuses every class of bad argument.
 *
 * A refused call must return the documented status (NF_ERROR_INVALID_ARGUMENT for bad
 * arguments), record a non-empty message for nf_last_error_message, write no output where
 * the header promises so, and leave the model exactly as it was: parameters, serialized
 * bytes (which include the configuration and the AdamW state) and step count.
 */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <nisflow/nisflow.h>

#include "nf_test_support.h"
#include "blocks.h"
#include "gradient.h"

/* ---- checking that a call wrote its own error message ------------------------------------- */

/* Messages persist until the next failure on the thread, so a stale message would satisfy a
 * naive "non-empty" check. Before each bad call the message is primed with one of two known
 * failures; if afterwards it still equals the primer, the call is repeated after the other
 * primer, and then it must differ. */
static char primer_text[2][512];

static void prime(int which)
{
    if (which == 0) {
        nf_model *out = NULL;
        (void)nf_model_clone(NULL, &out);
    } else {
        float p[1];
        (void)nf_model_get_params(NULL, p);
    }
}

static int message_is_primer(int which)
{
    return strcmp(nf_last_error_message(), primer_text[which]) == 0;
}

static int setup_primers(void **state)
{
    (void)state;
    for (int i = 0; i < 2; ++i) {
        prime(i);
        snprintf(primer_text[i], sizeof primer_text[i], "%s", nf_last_error_message());
        if (primer_text[i][0] == '\0')
            return -1;
    }
    return strcmp(primer_text[0], primer_text[1]) == 0 ? -1 : 0;
}

/* `call` must return `expected` and write a non-empty message. `call` is evaluated once or
 * twice, so it must be free of side effects other than the library's. */
#define EXPECT_STATUS(expected, call)                                                          \
    do {                                                                                       \
        prime(0);                                                                              \
        nf_status st_ = (call);                                                                \
        if (st_ != (expected))                                                                 \
            fail_msg("%s returned %s (%d), expected %s", #call, nf_status_string(st_),         \
                     (int)st_, nf_status_string(expected));                                    \
        if (message_is_primer(0)) {                                                            \
            prime(1);                                                                          \
            st_ = (call);                                                                      \
            if (st_ != (expected) || message_is_primer(1))                                     \
                fail_msg("%s did not record its own error message", #call);                    \
        }                                                                                      \
        if (nf_last_error_message()[0] == '\0')                                                \
            fail_msg("%s left an empty error message", #call);                                 \
    } while (0)

#define EXPECT_INVALID(call) EXPECT_STATUS(NF_ERROR_INVALID_ARGUMENT, call)

/* nf_model_prior_pdf refuses bad input and writes nothing. */
#define EXPECT_PRIOR_PDF_INVALID(m, ctx, dir)                                                  \
    do {                                                                                       \
        float q_ = -7.0f;                                                                      \
        EXPECT_INVALID(nf_model_prior_pdf((m), (ctx), (dir), &q_));                            \
        if (q_ != -7.0f)                                                                       \
            fail_msg("nf_model_prior_pdf wrote %g on bad input", (double)q_);                  \
    } while (0)

#define EXPECT_UNCHANGED(m, snap)                                                              \
    do {                                                                                       \
        if (!nft_snapshot_equal((m), (snap)))                                                  \
            fail_msg("line %d: the model changed", __LINE__);                                  \
    } while (0)

/* ---- fixtures ---------------------------------------------------------------------------- */

enum { N = 8 };

typedef struct batch {
    nf_context ctx[N];
    float u[2 * N];
    float dir[3 * N];
    float weight[N];
} batch;

static batch valid_batch(void)
{
    batch b;
    nft_rng r;
    nft_rng_seed(&r, 12u, 34u);
    nft_random_batch(&r, N, b.ctx, b.u, b.dir, b.weight, 0.5f);
    return b;
}

/* A randomized model that has taken two AdamW steps, so its optimizer state is non-trivial
 * and "unchanged" covers it. */
static nf_model *trained_model(nf_prior_kind prior)
{
    nf_model *m = nft_make_model(NF_PRESET_SMALL, prior);
    assert_int_equal(nft_randomize_params(m, 0.5f, 1u), NF_OK);
    batch b = valid_batch();
    for (int k = 0; k < 2; ++k)
        assert_int_equal(nf_train_step(m, N, b.ctx, b.dir, b.weight, NULL), NF_OK);
    assert_int_equal(nf_model_step_count(m), 2u);
    return m;
}

/* Batch sizes whose byte counts overflow size_t. */
static const size_t huge_n[3] = {SIZE_MAX, SIZE_MAX / 2u, SIZE_MAX / (3u * sizeof(float)) + 1u};

/* Bad direction components: NaN, +Inf, -Inf, and the zero vector (index 3). */
static void make_bad_direction(float d[3], int which)
{
    const float values[3] = {NAN, INFINITY, -INFINITY};
    if (which < 3) {
        d[1] = values[which];
    } else {
        d[0] = d[1] = d[2] = 0.0f;
    }
}

/* ---- configuration and life cycle ------------------------------------------------------- */

/* Applies bad mutation `i` to a default config; returns 0 past the last one. */
static int bad_config(int i, nf_config *c, const char **what)
{
    nf_config_init(c, NF_PRESET_SMALL);
#define CASE(text, stmt)                                                                       \
    if (i-- == 0) {                                                                            \
        stmt;                                                                                  \
        *what = text;                                                                          \
        return 1;                                                                              \
    }
    CASE("coupling_layers 0", c->coupling_layers = 0)
    CASE("coupling_layers max+1", c->coupling_layers = NF_MAX_COUPLING_LAYERS + 1u)
    CASE("coupling_layers UINT32_MAX", c->coupling_layers = UINT32_MAX)
    CASE("spline_bins 0", c->spline_bins = 0)
    CASE("spline_bins 1", c->spline_bins = 1)
    CASE("spline_bins max+1", c->spline_bins = NF_MAX_SPLINE_BINS + 1u)
    CASE("hidden_layers 0", c->hidden_layers = 0)
    CASE("hidden_layers max+1", c->hidden_layers = NF_MAX_HIDDEN_LAYERS + 1u)
    CASE("hidden_width 0", c->hidden_width = 0)
    CASE("hidden_width max+1", c->hidden_width = NF_MAX_HIDDEN_WIDTH + 1u)
    CASE("oneblob_bins 0", c->oneblob_bins = 0)
    CASE("oneblob_bins 1", c->oneblob_bins = 1)
    CASE("oneblob_bins max+1", c->oneblob_bins = NF_MAX_ONEBLOB_BINS + 1u)
    CASE("sh_bands max+1", c->sh_bands = NF_MAX_SH_BANDS + 1u)
    CASE("prior 4", c->prior = (nf_prior_kind)4)
    CASE("prior -1", c->prior = (nf_prior_kind)-1)
    CASE("phi_map 2", c->phi_map = (nf_phi_map)2)
    CASE("phi_map -1", c->phi_map = (nf_phi_map)-1)
    CASE("prior_epsilon 0", c->prior_epsilon = 0.0f)
    CASE("prior_epsilon -0.1", c->prior_epsilon = -0.1f)
    CASE("prior_epsilon 1.0001", c->prior_epsilon = 1.0001f)
    CASE("prior_epsilon 2", c->prior_epsilon = 2.0f)
    CASE("prior_epsilon NaN", c->prior_epsilon = NAN)
    CASE("prior_epsilon Inf", c->prior_epsilon = INFINITY)
    CASE("prior_epsilon denormal", c->prior_epsilon = 1.4e-45f)
    CASE("prior_epsilon 0 (custom prior)",
         (*c = nft_config(NF_PRESET_SMALL, NF_PRIOR_CUSTOM), c->prior_epsilon = 0.0f))
    CASE("custom prior without sample",
         (*c = nft_config(NF_PRESET_SMALL, NF_PRIOR_CUSTOM), c->custom_prior.sample = NULL))
    CASE("custom prior without pdf",
         (*c = nft_config(NF_PRESET_SMALL, NF_PRIOR_CUSTOM), c->custom_prior.pdf = NULL))
    CASE("custom prior without callbacks", c->prior = NF_PRIOR_CUSTOM)
    CASE("bounds_min[0] NaN", c->bounds_min[0] = NAN)
    CASE("bounds_min[1] -Inf", c->bounds_min[1] = -INFINITY)
    CASE("bounds_max[2] NaN", c->bounds_max[2] = NAN)
    CASE("bounds_max[0] Inf", c->bounds_max[0] = INFINITY)
    CASE("bounds min == max", c->bounds_min[1] = c->bounds_max[1])
    CASE("bounds min > max", (c->bounds_min[2] = 2.0f, c->bounds_max[2] = 1.0f))
    CASE("learning_rate 0", c->learning_rate = 0.0f)
    CASE("learning_rate -1e-3", c->learning_rate = -1e-3f)
    CASE("learning_rate NaN", c->learning_rate = NAN)
    CASE("learning_rate Inf", c->learning_rate = INFINITY)
    CASE("beta1 -0.1", c->beta1 = -0.1f)
    CASE("beta1 1", c->beta1 = 1.0f)
    CASE("beta1 NaN", c->beta1 = NAN)
    CASE("beta2 1", c->beta2 = 1.0f)
    CASE("beta2 -1e-6", c->beta2 = -1e-6f)
    CASE("beta2 NaN", c->beta2 = NAN)
    CASE("adam_epsilon 0", c->adam_epsilon = 0.0f)
    CASE("adam_epsilon -1e-8", c->adam_epsilon = -1e-8f)
    CASE("adam_epsilon NaN", c->adam_epsilon = NAN)
    CASE("adam_epsilon Inf", c->adam_epsilon = INFINITY)
    CASE("weight_decay -0.01", c->weight_decay = -0.01f)
    CASE("weight_decay NaN", c->weight_decay = NAN)
    CASE("weight_decay Inf", c->weight_decay = INFINITY)
    CASE("learning_rate * weight_decay = 1", (c->learning_rate = 0.5f, c->weight_decay = 2.0f))
    CASE("learning_rate * weight_decay > 1", (c->learning_rate = 1.0f, c->weight_decay = 3.0f))
    CASE("isa 4", c->isa = (nf_isa)4)
    CASE("isa -1", c->isa = (nf_isa)-1)
#undef CASE
    return 0;
}

static nf_model *const not_null = (nf_model *)&primer_text; /* never dereferenced */

static void test_create_refuses_bad_configs(void **state)
{
    (void)state;
    nf_config cfg;
    const char *what = NULL;
    int count = 0;
    for (int i = 0; bad_config(i, &cfg, &what); ++i, ++count) {
        nf_model *out = not_null;
        prime(0);
        nf_status st = nf_model_create(&cfg, &out);
        if (st != NF_ERROR_INVALID_ARGUMENT)
            fail_msg("config with %s: nf_model_create returned %s", what, nf_status_string(st));
        if (out != NULL)
            fail_msg("config with %s: *out is not NULL after the error", what);
        if (message_is_primer(0) || nf_last_error_message()[0] == '\0')
            fail_msg("config with %s: no error message", what);
        /* The same through EXPECT_INVALID (message written even after the other primer). */
        EXPECT_INVALID(nf_model_create(&cfg, &out));
    }
    assert_true(count >= 40);

    nf_model *out = not_null;
    nf_config_init(&cfg, NF_PRESET_SMALL);
    EXPECT_INVALID(nf_model_create(NULL, &out));
    assert_null(out);
    EXPECT_INVALID(nf_model_create(&cfg, NULL));
    /* nf_config_init(NULL) is ignored. */
    nf_config_init(NULL, NF_PRESET_SMALL);
}

/* A half-specified allocator cannot work (memory allocated with one function could not be
 * freed); it must be refused, not silently mixed with malloc/free. */
static void *user_alloc(void *user, size_t size)
{
    (void)user;
    return malloc(size);
}

static void user_free(void *user, void *ptr)
{
    (void)user;
    free(ptr);
}

static void test_create_refuses_half_allocator(void **state)
{
    (void)state;
    nf_config cfg;
    nf_config_init(&cfg, NF_PRESET_SMALL);
    cfg.allocator.alloc = user_alloc;
    nf_model *out = not_null;
    EXPECT_INVALID(nf_model_create(&cfg, &out));
    assert_null(out);
    nf_config_init(&cfg, NF_PRESET_SMALL);
    cfg.allocator.free = user_free;
    out = not_null;
    EXPECT_INVALID(nf_model_create(&cfg, &out));
    assert_null(out);
    /* Both given: accepted. */
    cfg.allocator.alloc = user_alloc;
    assert_int_equal(nf_model_create(&cfg, &out), NF_OK);
    nf_model_destroy(out);
}

/* The limits themselves are valid (each alone), so the refusals above are about range. */
static void test_create_accepts_boundary_configs(void **state)
{
    (void)state;
    for (int i = 0;; ++i) {
        nf_config c;
        nf_config_init(&c, NF_PRESET_SMALL);
        const char *what;
        switch (i) {
        case 0: c.coupling_layers = 1; what = "coupling_layers 1"; break;
        case 1: c.coupling_layers = NF_MAX_COUPLING_LAYERS; what = "coupling_layers max"; break;
        case 2: c.spline_bins = 2; what = "spline_bins 2"; break;
        case 3: c.spline_bins = NF_MAX_SPLINE_BINS; what = "spline_bins max"; break;
        case 4: c.hidden_layers = NF_MAX_HIDDEN_LAYERS; what = "hidden_layers max"; break;
        case 5: c.hidden_width = 1; what = "hidden_width 1"; break;
        case 6: c.hidden_width = NF_MAX_HIDDEN_WIDTH; what = "hidden_width max"; break;
        case 7: c.oneblob_bins = 2; what = "oneblob_bins 2"; break;
        case 8: c.oneblob_bins = NF_MAX_ONEBLOB_BINS; what = "oneblob_bins max"; break;
        case 9: c.sh_bands = 0; what = "sh_bands 0"; break;
        case 10: c.sh_bands = NF_MAX_SH_BANDS; what = "sh_bands max"; break;
        case 11: c.prior_epsilon = 1.0f; what = "prior_epsilon 1"; break;
        case 12: c.prior_epsilon = NF_PRIOR_EPSILON_MIN; what = "prior_epsilon min"; break;
        case 13: c.beta1 = 0.0f; c.beta2 = 0.0f; what = "betas 0"; break;
        case 14: c.weight_decay = 0.0f; what = "weight_decay 0"; break;
        case 15:
            c.bounds_min[0] = -1e6f;
            c.bounds_max[0] = -1e6f + 1.0f;
            what = "shifted bounds";
            break;
        default: return;
        }
        nf_model *m = NULL;
        nf_status st = nf_model_create(&c, &m);
        if (st != NF_OK || m == NULL)
            fail_msg("config with %s refused: %s (%s)", what, nf_status_string(st),
                     nf_last_error_message());
        nf_model_destroy(m);
    }
}

static void test_life_cycle_null(void **state)
{
    (void)state;
    nf_model *m = trained_model(NF_PRIOR_COSINE);
    nft_snapshot snap = nft_snapshot_of(m);
    nf_model *out = not_null;
    EXPECT_INVALID(nf_model_clone(NULL, &out));
    assert_null(out);
    EXPECT_INVALID(nf_model_clone(m, NULL));
    nf_config cfg;
    EXPECT_INVALID(nf_model_get_config(NULL, &cfg));
    EXPECT_INVALID(nf_model_get_config(m, NULL));
    nf_model_destroy(NULL); /* a no-op */
    assert_int_equal(nf_model_param_count(NULL), 0u);
    assert_int_equal(nf_model_step_count(NULL), 0u);
    EXPECT_UNCHANGED(m, &snap);
    nft_snapshot_free(&snap);
    nf_model_destroy(m);
}

/* ---- nf_sample, nf_pdf, nf_model_prior_pdf ---------------------------------------------------- */

static void test_sample_bad_input(void **state)
{
    (void)state;
    nf_model *m = trained_model(NF_PRIOR_COSINE);
    nft_snapshot snap = nft_snapshot_of(m);
    batch b = valid_batch();
    float dir[3 * N], pdf[N];
    char what[64];

    nft_fill_sentinel(dir, 3 * N);
    nft_fill_sentinel(pdf, N);
    EXPECT_INVALID(nf_sample(NULL, N, b.ctx, b.u, dir, pdf));
    EXPECT_INVALID(nf_sample(m, N, NULL, b.u, dir, pdf));
    EXPECT_INVALID(nf_sample(m, N, b.ctx, NULL, dir, pdf));
    EXPECT_INVALID(nf_sample(m, N, b.ctx, b.u, NULL, pdf));
    assert_true(nft_untouched(dir, 3 * N) && nft_untouched(pdf, N));
    for (int k = 0; k < 3; ++k) {
        EXPECT_INVALID(nf_sample(m, huge_n[k], b.ctx, b.u, dir, pdf));
        assert_true(nft_untouched(dir, 3 * N) && nft_untouched(pdf, N));
    }
    /* A bad context in the last element: nothing of the batch may be written. */
    for (int which = 0; which < NFT_BAD_CONTEXTS; ++which) {
        batch bad = b;
        bad.ctx[N - 1] = nft_bad_context(&b.ctx[N - 1], which, what, sizeof what);
        prime(0);
        nf_status st = nf_sample(m, N, bad.ctx, bad.u, dir, pdf);
        if (st != NF_ERROR_INVALID_ARGUMENT || message_is_primer(0))
            fail_msg("nf_sample with %s: %s", what, nf_status_string(st));
        if (!nft_untouched(dir, 3 * N) || !nft_untouched(pdf, N))
            fail_msg("nf_sample with %s wrote its outputs", what);
    }
    /* NaN and infinite u (finite values outside [0,1) are clamped, see below). */
    const float bad_u[3] = {NAN, INFINITY, -INFINITY};
    for (int k = 0; k < 6; ++k) {
        batch bad = b;
        bad.u[2 * (N - 1) + (k & 1)] = bad_u[k / 2];
        EXPECT_INVALID(nf_sample(m, N, bad.ctx, bad.u, dir, pdf));
        assert_true(nft_untouched(dir, 3 * N) && nft_untouched(pdf, N));
    }
    /* n = 0 is a no-op, with or without pointers. */
    assert_int_equal(nf_sample(m, 0, NULL, NULL, NULL, NULL), NF_OK);
    assert_int_equal(nf_sample(m, 0, b.ctx, b.u, dir, pdf), NF_OK);
    assert_true(nft_untouched(dir, 3 * N) && nft_untouched(pdf, N));
    /* pdf NULL is allowed. */
    assert_int_equal(nf_sample(m, N, b.ctx, b.u, dir, NULL), NF_OK);
    assert_false(nft_untouched(dir, 3));
    EXPECT_UNCHANGED(m, &snap);
    nft_snapshot_free(&snap);
    nf_model_destroy(m);
}

/* u outside [0, 1) is clamped (model.h), not refused. */
static void test_sample_clamps_u(void **state)
{
    (void)state;
    nf_model *m = trained_model(NF_PRIOR_CUSTOM);
    batch b = valid_batch();
    const float u_in[4][2] = {{-0.5f, 0.3f}, {0.3f, -3.0f}, {1.5f, 0.3f}, {0.3f, 7.0f}};
    const float u_clamped[2][2] = {{0.0f, 0.3f}, {0.3f, 0.0f}};
    for (int k = 0; k < 4; ++k) {
        float d[3], p;
        assert_int_equal(nf_sample(m, 1, b.ctx, u_in[k], d, &p), NF_OK);
        assert_true(isfinite(p) && p > 0.0f);
        /* Unit length within 1e-5, as promised. */
        assert_true(fabs(nft_length3f(d) - 1.0) <= 1e-5);
        if (k < 2) {
            float dc[3], pc;
            assert_int_equal(nf_sample(m, 1, b.ctx, u_clamped[k], dc, &pc), NF_OK);
            assert_memory_equal(d, dc, sizeof d);
            assert_memory_equal(&p, &pc, sizeof p);
        }
    }
    nf_model_destroy(m);
}

static void test_pdf_bad_input(void **state)
{
    (void)state;
    nf_model *m = trained_model(NF_PRIOR_CUSTOM);
    nft_snapshot snap = nft_snapshot_of(m);
    batch b = valid_batch();
    float pdf[N];
    char what[64];

    nft_fill_sentinel(pdf, N);
    EXPECT_INVALID(nf_pdf(NULL, N, b.ctx, b.dir, pdf));
    EXPECT_INVALID(nf_pdf(m, N, NULL, b.dir, pdf));
    EXPECT_INVALID(nf_pdf(m, N, b.ctx, NULL, pdf));
    EXPECT_INVALID(nf_pdf(m, N, b.ctx, b.dir, NULL));
    for (int k = 0; k < 3; ++k)
        EXPECT_INVALID(nf_pdf(m, huge_n[k], b.ctx, b.dir, pdf));
    assert_true(nft_untouched(pdf, N));
    for (int which = 0; which < NFT_BAD_CONTEXTS; ++which) {
        batch bad = b;
        bad.ctx[N - 1] = nft_bad_context(&b.ctx[N - 1], which, what, sizeof what);
        prime(0);
        nf_status st = nf_pdf(m, N, bad.ctx, bad.dir, pdf);
        if (st != NF_ERROR_INVALID_ARGUMENT || message_is_primer(0))
            fail_msg("nf_pdf with %s: %s", what, nf_status_string(st));
        if (!nft_untouched(pdf, N))
            fail_msg("nf_pdf with %s wrote its output", what);
    }
    for (int which = 0; which < 4; ++which) {
        batch bad = b;
        make_bad_direction(bad.dir + 3 * (N - 1), which);
        EXPECT_INVALID(nf_pdf(m, N, bad.ctx, bad.dir, pdf));
        assert_true(nft_untouched(pdf, N));
    }
    assert_int_equal(nf_pdf(m, 0, NULL, NULL, NULL), NF_OK);
    assert_int_equal(nf_pdf(m, 0, b.ctx, b.dir, pdf), NF_OK);
    assert_true(nft_untouched(pdf, N));
    EXPECT_UNCHANGED(m, &snap);
    nft_snapshot_free(&snap);
    nf_model_destroy(m);
}

static void test_prior_pdf_bad_input(void **state)
{
    (void)state;
    nf_model *m = trained_model(NF_PRIOR_COSINE);
    batch b = valid_batch();
    char what[64];
    EXPECT_PRIOR_PDF_INVALID(NULL, b.ctx, b.dir);
    EXPECT_PRIOR_PDF_INVALID(m, NULL, b.dir);
    EXPECT_PRIOR_PDF_INVALID(m, b.ctx, NULL);
    EXPECT_INVALID(nf_model_prior_pdf(m, b.ctx, b.dir, NULL));
    for (int which = 0; which < 4; ++which) {
        float d[3] = {b.dir[0], b.dir[1], b.dir[2]};
        make_bad_direction(d, which);
        EXPECT_PRIOR_PDF_INVALID(m, b.ctx, d);
    }
    for (int which = 0; which < NFT_BAD_CONTEXTS; ++which) {
        nf_context c = nft_bad_context(&b.ctx[0], which, what, sizeof what);
        float q = -7.0f;
        prime(0);
        if (nf_model_prior_pdf(m, &c, b.dir, &q) != NF_ERROR_INVALID_ARGUMENT || q != -7.0f ||
            message_is_primer(0))
            fail_msg("nf_model_prior_pdf with %s: not refused with a message of its own", what);
    }
    /* And a valid call gives a positive density. */
    float q = 0.0f;
    assert_int_equal(nf_model_prior_pdf(m, b.ctx, b.dir, &q), NF_OK);
    assert_true(q > 0.0f);
    nf_model_destroy(m);
}

/* ---- training ------------------------------------------------------------------------------ */

/* Applies the bad batch `which` (0..count) to a copy of b; 0 past the last. */
static int bad_batch(int which, const batch *b, batch *out, char *what, size_t size)
{
    *out = *b;
    if (which < NFT_BAD_CONTEXTS) {
        out->ctx[N - 1] = nft_bad_context(&b->ctx[N - 1], which, what, size);
        return 1;
    }
    which -= NFT_BAD_CONTEXTS;
    if (which < 4) {
        make_bad_direction(out->dir + 3 * (N - 1), which);
        snprintf(what, size, "bad direction %d", which);
        return 1;
    }
    which -= 4;
    const float weights[5] = {NAN, INFINITY, -INFINITY, -1.0f, -1e-30f};
    if (which < 5) {
        out->weight[N - 1] = weights[which];
        snprintf(what, size, "weight %g", (double)weights[which]);
        return 1;
    }
    return 0;
}

static void test_train_step_bad_input(void **state)
{
    (void)state;
    nf_model *m = trained_model(NF_PRIOR_COSINE);
    nft_snapshot snap = nft_snapshot_of(m);
    batch b = valid_batch(), bad;
    char what[64];
    float loss = NFT_SENTINEL;

    EXPECT_INVALID(nf_train_step(NULL, N, b.ctx, b.dir, b.weight, &loss));
    EXPECT_INVALID(nf_train_step(m, N, NULL, b.dir, b.weight, &loss));
    EXPECT_INVALID(nf_train_step(m, N, b.ctx, NULL, b.weight, &loss));
    EXPECT_INVALID(nf_train_step(m, N, b.ctx, b.dir, NULL, &loss));
    EXPECT_UNCHANGED(m, &snap);
    for (int k = 0; k < 3; ++k)
        EXPECT_INVALID(nf_train_step(m, huge_n[k], b.ctx, b.dir, b.weight, &loss));
    EXPECT_UNCHANGED(m, &snap);
    for (int which = 0; bad_batch(which, &b, &bad, what, sizeof what); ++which) {
        prime(0);
        nf_status st = nf_train_step(m, N, bad.ctx, bad.dir, bad.weight, &loss);
        if (st != NF_ERROR_INVALID_ARGUMENT || message_is_primer(0))
            fail_msg("nf_train_step with %s: %s", what, nf_status_string(st));
        if (!nft_snapshot_equal(m, &snap))
            fail_msg("nf_train_step with %s changed the model", what);
    }
    /* n = 0 and all-zero weights are no-ops (no step counted, loss 0). */
    assert_int_equal(nf_train_step(m, 0, NULL, NULL, NULL, NULL), NF_OK);
    EXPECT_UNCHANGED(m, &snap);
    float zero[N] = {0};
    loss = NFT_SENTINEL;
    assert_int_equal(nf_train_step(m, N, b.ctx, b.dir, zero, &loss), NF_OK);
    assert_true(loss == 0.0f);
    EXPECT_UNCHANGED(m, &snap);
    /* A valid step does change it (the comparison can fail). */
    assert_int_equal(nf_train_step(m, N, b.ctx, b.dir, b.weight, NULL), NF_OK);
    assert_false(nft_snapshot_equal(m, &snap));
    nft_snapshot_free(&snap);
    nf_model_destroy(m);
}

static void test_loss_gradient_bad_input(void **state)
{
    (void)state;
    nf_model *m = trained_model(NF_PRIOR_CUSTOM);
    nft_snapshot snap = nft_snapshot_of(m);
    const size_t pc = nf_model_param_count(m);
    float *grad = malloc(pc * sizeof *grad);
    assert_non_null(grad);
    batch b = valid_batch(), bad;
    char what[64];
    float loss;

    EXPECT_INVALID(nf_loss_gradient(NULL, N, b.ctx, b.dir, b.weight, &loss, grad));
    EXPECT_INVALID(nf_loss_gradient(m, N, NULL, b.dir, b.weight, &loss, grad));
    EXPECT_INVALID(nf_loss_gradient(m, N, b.ctx, NULL, b.weight, &loss, grad));
    EXPECT_INVALID(nf_loss_gradient(m, N, b.ctx, b.dir, NULL, &loss, grad));
    EXPECT_INVALID(nf_loss_gradient(m, N, b.ctx, b.dir, b.weight, &loss, NULL));
    for (int k = 0; k < 3; ++k)
        EXPECT_INVALID(nf_loss_gradient(m, huge_n[k], b.ctx, b.dir, b.weight, &loss, grad));
    for (int which = 0; bad_batch(which, &b, &bad, what, sizeof what); ++which) {
        prime(0);
        nf_status st = nf_loss_gradient(m, N, bad.ctx, bad.dir, bad.weight, &loss, grad);
        if (st != NF_ERROR_INVALID_ARGUMENT || message_is_primer(0))
            fail_msg("nf_loss_gradient with %s: %s", what, nf_status_string(st));
    }
    EXPECT_UNCHANGED(m, &snap);
    /* All-zero weights: loss and gradient 0. loss may be NULL. */
    float zero[N] = {0};
    nft_fill_sentinel(grad, pc);
    loss = NFT_SENTINEL;
    assert_int_equal(nf_loss_gradient(m, N, b.ctx, b.dir, zero, &loss, grad), NF_OK);
    assert_true(loss == 0.0f);
    for (size_t i = 0; i < pc; ++i)
        assert_true(grad[i] == 0.0f);
    assert_int_equal(nf_loss_gradient(m, N, b.ctx, b.dir, b.weight, NULL, grad), NF_OK);
    assert_int_equal(nf_loss_gradient(m, 0, NULL, NULL, NULL, &loss, grad), NF_OK);
    EXPECT_UNCHANGED(m, &snap);

    /* nf_loss_gradient_with_work: its own two arguments, then the same validation. A refused
     * call writes neither the gradient nor the loss. */
    const size_t wb = nf_training_work_bytes();
    void *work = malloc(wb);
    assert_non_null(work);
    nft_fill_sentinel(grad, pc);
    loss = NFT_SENTINEL;
    EXPECT_INVALID(nf_loss_gradient_with_work(m, N, b.ctx, b.dir, b.weight, &loss, grad, NULL, wb));
    EXPECT_INVALID(nf_loss_gradient_with_work(m, N, b.ctx, b.dir, b.weight, &loss, grad, work, 0));
    EXPECT_INVALID(
        nf_loss_gradient_with_work(m, N, b.ctx, b.dir, b.weight, &loss, grad, work, wb - 1));
    EXPECT_INVALID(nf_loss_gradient_with_work(NULL, N, b.ctx, b.dir, b.weight, &loss, grad, work, wb));
    EXPECT_INVALID(nf_loss_gradient_with_work(m, N, b.ctx, b.dir, b.weight, &loss, NULL, work, wb));
    for (int which = 0; bad_batch(which, &b, &bad, what, sizeof what); ++which) {
        prime(0);
        nf_status st =
            nf_loss_gradient_with_work(m, N, bad.ctx, bad.dir, bad.weight, &loss, grad, work, wb);
        if (st != NF_ERROR_INVALID_ARGUMENT || message_is_primer(0))
            fail_msg("nf_loss_gradient_with_work with %s: %s", what, nf_status_string(st));
    }
    assert_true(nft_untouched(grad, pc) && loss == NFT_SENTINEL);
    prime(0);
    assert_int_equal(nf_loss_gradient_with_work(m, N, b.ctx, b.dir, b.weight, &loss, grad, work,
                                                wb - 1),
                     NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "nf_training_work_bytes"));
    EXPECT_UNCHANGED(m, &snap);
    free(work);
    free(grad);
    nft_snapshot_free(&snap);
    nf_model_destroy(m);
}

static void test_params_bad_input(void **state)
{
    (void)state;
    nf_model *m = trained_model(NF_PRIOR_UNIFORM_DIRECTION);
    nft_snapshot snap = nft_snapshot_of(m);
    const size_t pc = nf_model_param_count(m);
    float *p = malloc(pc * sizeof *p);
    assert_non_null(p);
    EXPECT_INVALID(nf_model_get_params(NULL, p));
    EXPECT_INVALID(nf_model_get_params(m, NULL));
    EXPECT_INVALID(nf_model_set_params(NULL, p));
    EXPECT_INVALID(nf_model_set_params(m, NULL));
    const float bad[3] = {NAN, INFINITY, -INFINITY};
    const size_t where[2] = {0, pc - 1};
    for (int k = 0; k < 3; ++k)
        for (int w = 0; w < 2; ++w) {
            assert_int_equal(nf_model_get_params(m, p), NF_OK);
            for (size_t i = 0; i < pc; ++i)
                p[i] *= 0.5f; /* otherwise valid new values */
            p[where[w]] = bad[k];
            EXPECT_INVALID(nf_model_set_params(m, p));
            EXPECT_UNCHANGED(m, &snap);
        }
    free(p);
    nft_snapshot_free(&snap);
    nf_model_destroy(m);
}

static void test_apply_gradient_bad_input(void **state)
{
    (void)state;
    nf_model *m = trained_model(NF_PRIOR_COSINE);
    nft_snapshot snap = nft_snapshot_of(m);
    const size_t pc = nf_model_param_count(m);
    float *g = malloc(pc * sizeof *g);
    assert_non_null(g);
    for (size_t i = 0; i < pc; ++i)
        g[i] = 1e-3f;
    EXPECT_INVALID(nf_apply_gradient(NULL, g));
    EXPECT_INVALID(nf_apply_gradient(m, NULL));
    const float bad[3] = {INFINITY, -INFINITY, NAN};
    for (int k = 0; k < 3; ++k) {
        g[k == 2 ? 0 : pc - 1] = bad[k];
        EXPECT_INVALID(nf_apply_gradient(m, g));
        EXPECT_UNCHANGED(m, &snap);
        g[0] = g[pc - 1] = 1e-3f;
    }
    /* Finite but so large that the second moment (1 - beta2) g^2 overflows float. */
    for (size_t i = 0; i < pc; ++i)
        g[i] = FLT_MAX;
    EXPECT_STATUS(NF_ERROR_NUMERIC, nf_apply_gradient(m, g));
    EXPECT_UNCHANGED(m, &snap);
    free(g);
    nft_snapshot_free(&snap);
    nf_model_destroy(m);
}

static void test_learning_rate_bad_input(void **state)
{
    (void)state;
    nf_model *m = trained_model(NF_PRIOR_COSINE);
    nft_snapshot snap = nft_snapshot_of(m);
    nf_config before, after;
    assert_int_equal(nf_model_get_config(m, &before), NF_OK);
    EXPECT_INVALID(nf_model_set_learning_rate(NULL, 1e-3f));
    EXPECT_INVALID(nf_model_set_learning_rate(m, 0.0f));
    EXPECT_INVALID(nf_model_set_learning_rate(m, -1e-3f));
    EXPECT_INVALID(nf_model_set_learning_rate(m, NAN));
    EXPECT_INVALID(nf_model_set_learning_rate(m, INFINITY));
    /* learning_rate * weight_decay must stay below 1 (weight_decay is 0.01 here). */
    assert_true(before.weight_decay > 0.0f);
    EXPECT_INVALID(nf_model_set_learning_rate(m, 1.0f / before.weight_decay));
    EXPECT_INVALID(nf_model_set_learning_rate(m, 2.0f / before.weight_decay));
    assert_int_equal(nf_model_get_config(m, &after), NF_OK);
    assert_memory_equal(&before.learning_rate, &after.learning_rate, sizeof(float));
    EXPECT_UNCHANGED(m, &snap);
    nft_snapshot_free(&snap);
    nf_model_destroy(m);
}

/* ---- persistence ------------------------------------------------------------------------------ */

static void test_io_bad_input(void **state)
{
    (void)state;
    nf_model *m = trained_model(NF_PRIOR_COSINE);
    nft_snapshot snap = nft_snapshot_of(m);
    nf_model *out = not_null;
    const char *missing_dir = "nf_test_no_such_directory/model.nf";

    EXPECT_INVALID(nf_model_save(NULL, "nf_test_bad_input.nf"));
    EXPECT_INVALID(nf_model_save(m, NULL));
    EXPECT_STATUS(NF_ERROR_IO, nf_model_save(m, missing_dir));
    EXPECT_INVALID(nf_model_load(NULL, NULL, &out));
    assert_null(out);
    EXPECT_INVALID(nf_model_load("nf_test_bad_input.nf", NULL, NULL));
    out = not_null;
    EXPECT_STATUS(NF_ERROR_IO, nf_model_load(missing_dir, NULL, &out));
    assert_null(out);

    /* Serialization: size query, too-small buffers. */
    size_t need = 0, size = 0;
    assert_int_equal(nf_model_serialize(m, NULL, 0, &need), NF_OK);
    assert_true(need > nf_model_param_count(m) * sizeof(float));
    unsigned char *buf = malloc(need);
    assert_non_null(buf);
    EXPECT_INVALID(nf_model_serialize(NULL, buf, need, &size));
    EXPECT_INVALID(nf_model_serialize(m, buf, need, NULL));
    size = 0;
    EXPECT_STATUS(NF_ERROR_CAPACITY, nf_model_serialize(m, buf, need - 1u, &size));
    assert_int_equal(size, need);
    size = 0;
    EXPECT_STATUS(NF_ERROR_CAPACITY, nf_model_serialize(m, buf, 0, &size));
    assert_int_equal(size, need);
    assert_int_equal(nf_model_serialize(m, buf, need, &size), NF_OK);
    assert_int_equal(size, need);

    out = not_null;
    EXPECT_INVALID(nf_model_deserialize(NULL, need, NULL, &out));
    assert_null(out);
    EXPECT_INVALID(nf_model_deserialize(buf, need, NULL, NULL));
    out = not_null;
    EXPECT_STATUS(NF_ERROR_FORMAT, nf_model_deserialize(buf, need - 1u, NULL, &out));
    assert_null(out);
    EXPECT_UNCHANGED(m, &snap);
    free(buf);

    /* A custom-prior model needs its callbacks back: refused without them. */
    nf_model *c = trained_model(NF_PRIOR_CUSTOM);
    assert_int_equal(nf_model_serialize(c, NULL, 0, &need), NF_OK);
    buf = malloc(need);
    assert_non_null(buf);
    assert_int_equal(nf_model_serialize(c, buf, need, &size), NF_OK);
    out = not_null;
    EXPECT_INVALID(nf_model_deserialize(buf, need, NULL, &out));
    assert_null(out);
    nf_prior_callbacks none = {NULL, NULL, NULL};
    out = not_null;
    EXPECT_INVALID(nf_model_deserialize(buf, need, &none, &out));
    assert_null(out);
    const char *custom_file = "nf_test_bad_input_custom.nf";
    assert_int_equal(nf_model_save(c, custom_file), NF_OK);
    out = not_null;
    EXPECT_INVALID(nf_model_load(custom_file, NULL, &out));
    assert_null(out);
    out = not_null;
    EXPECT_INVALID(nf_model_load(custom_file, &none, &out));
    assert_null(out);
    remove(custom_file);
    nf_prior_callbacks cb = nft_phong_callbacks();
    assert_int_equal(nf_model_deserialize(buf, need, &cb, &out), NF_OK);
    nf_model_destroy(out);
    free(buf);
    nf_model_destroy(c);
    nft_snapshot_free(&snap);
    nf_model_destroy(m);
}

/* ---- custom prior callbacks that misbehave ------------------------------------------------ */

/* A Phong prior that returns `bad_value` (from the sampler, the pdf, or both) for contexts
 * whose position[0] equals MARKER, and behaves everywhere else. */
#define MARKER 0.77f

typedef struct faulty {
    float exponent;
    float bad_value;
    int bad_sample, bad_pdf;
} faulty;

static float faulty_sample(void *user, const nf_context *ctx, float u0, float u1, float dir[3])
{
    faulty *f = user;
    float p = nft_phong_sample(&f->exponent, ctx, u0, u1, dir);
    return f->bad_sample && ctx->position[0] == MARKER ? f->bad_value : p;
}

static float faulty_pdf(void *user, const nf_context *ctx, const float dir[3])
{
    faulty *f = user;
    float p = nft_phong_pdf(&f->exponent, ctx, dir);
    return f->bad_pdf && ctx->position[0] == MARKER ? f->bad_value : p;
}

/* model.h: a sampler density <= 0 or non-finite, or a pdf that is negative or non-finite,
 * refuses the batch with NF_ERROR_NUMERIC; outputs before the failing sample may be written,
 * later ones are not; training leaves the model as it was. */
static void test_custom_callbacks_misbehave(void **state)
{
    (void)state;
    static faulty f = {NFT_PHONG_EXPONENT, 0.0f, 0, 0};
    nf_config cfg = nft_config(NF_PRESET_SMALL, NF_PRIOR_CUSTOM);
    cfg.custom_prior.sample = faulty_sample;
    cfg.custom_prior.pdf = faulty_pdf;
    cfg.custom_prior.user = &f;
    nf_model *m = nft_model_from(&cfg);
    assert_int_equal(nft_randomize_params(m, 0.3f, 3u), NF_OK);
    batch b = valid_batch();
    const int k = 5; /* the faulty sample; u0 = 0.5 picks the custom component */
    b.ctx[k].position[0] = MARKER;
    b.u[2 * k] = 0.5f;
    nft_snapshot snap = nft_snapshot_of(m);
    float dir[3 * N], pdf[N], loss;
    float *grad = malloc(nf_model_param_count(m) * sizeof *grad);
    assert_non_null(grad);
    const float bad_sample_values[4] = {0.0f, -1.0f, NAN, INFINITY};
    const float bad_pdf_values[3] = {-1.0f, NAN, INFINITY};

    for (int v = 0; v < 4; ++v) {
        f.bad_sample = 1;
        f.bad_pdf = 0;
        f.bad_value = bad_sample_values[v];
        nft_fill_sentinel(dir, 3 * N);
        nft_fill_sentinel(pdf, N);
        EXPECT_STATUS(NF_ERROR_NUMERIC, nf_sample(m, N, b.ctx, b.u, dir, pdf));
        if (!nft_untouched(dir + 3 * (k + 1), 3 * (N - k - 1)) || !nft_untouched(pdf + k + 1, N - k - 1))
            fail_msg("sampler density %g: outputs after the failing sample were written",
                     (double)f.bad_value);
    }
    for (int v = 0; v < 3; ++v) {
        f.bad_sample = 0;
        f.bad_pdf = 1;
        f.bad_value = bad_pdf_values[v];
        nft_fill_sentinel(pdf, N);
        EXPECT_STATUS(NF_ERROR_NUMERIC, nf_pdf(m, N, b.ctx, b.dir, pdf));
        if (!nft_untouched(pdf + k + 1, N - k - 1))
            fail_msg("pdf callback %g: outputs after the failing sample were written",
                     (double)f.bad_value);
        EXPECT_STATUS(NF_ERROR_NUMERIC, nf_train_step(m, N, b.ctx, b.dir, b.weight, &loss));
        EXPECT_UNCHANGED(m, &snap);
        EXPECT_STATUS(NF_ERROR_NUMERIC,
                      nf_loss_gradient(m, N, b.ctx, b.dir, b.weight, &loss, grad));
    }
    /* Well behaved again: everything works (so the failures above were the callbacks'). */
    f.bad_sample = f.bad_pdf = 0;
    assert_int_equal(nf_sample(m, N, b.ctx, b.u, dir, pdf), NF_OK);
    assert_int_equal(nf_pdf(m, N, b.ctx, b.dir, pdf), NF_OK);
    EXPECT_UNCHANGED(m, &snap);
    free(grad);
    nft_snapshot_free(&snap);
    nf_model_destroy(m);
}

/* ---- building blocks ---------------------------------------------------------------------- */

static void test_blocks_bad_input(void **state)
{
    (void)state;
    float raw[3 * (NF_MAX_SPLINE_BINS + 1) + 1] = {0}; /* room for the bins = max+1 case */
    float y = NFT_SENTINEL, dydx = NFT_SENTINEL;
    EXPECT_INVALID(nf_spline_forward(8, NULL, 0.5f, &y, &dydx));
    EXPECT_INVALID(nf_spline_forward(8, raw, 0.5f, NULL, &dydx));
    EXPECT_INVALID(nf_spline_forward(1, raw, 0.5f, &y, &dydx));
    EXPECT_INVALID(nf_spline_forward(0, raw, 0.5f, &y, &dydx));
    EXPECT_INVALID(nf_spline_forward(NF_MAX_SPLINE_BINS + 1u, raw, 0.5f, &y, &dydx));
    EXPECT_INVALID(nf_spline_forward(8, raw, NAN, &y, &dydx));
    EXPECT_INVALID(nf_spline_inverse(8, NULL, 0.5f, &y, &dydx));
    EXPECT_INVALID(nf_spline_inverse(8, raw, 0.5f, NULL, &dydx));
    EXPECT_INVALID(nf_spline_inverse(1, raw, 0.5f, &y, &dydx));
    EXPECT_INVALID(nf_spline_inverse(NF_MAX_SPLINE_BINS + 1u, raw, 0.5f, &y, &dydx));
    EXPECT_INVALID(nf_spline_inverse(8, raw, NAN, &y, &dydx));
    /* A non-finite raw parameter, in each of the three groups (widths, heights, derivs). */
    const int where[3] = {0, 8, 24};
    const float bad[2] = {NAN, INFINITY};
    for (int w = 0; w < 3; ++w)
        for (int k = 0; k < 2; ++k) {
            raw[where[w]] = bad[k];
            EXPECT_INVALID(nf_spline_forward(8, raw, 0.5f, &y, &dydx));
            EXPECT_INVALID(nf_spline_inverse(8, raw, 0.5f, &y, &dydx));
            raw[where[w]] = 0.0f;
        }
    /* Valid: dydx NULL, x outside [0,1] clamped. */
    assert_int_equal(nf_spline_forward(8, raw, 0.25f, &y, NULL), NF_OK);
    assert_int_equal(nf_spline_forward(8, raw, -3.0f, &y, &dydx), NF_OK);
    assert_true(y == 0.0f);
    assert_int_equal(nf_spline_inverse(8, raw, 4.0f, &y, &dydx), NF_OK);
    assert_true(y == 1.0f);

    /* Encodings: documented no-ops and zero outputs. */
    float out[NF_MAX_SH_BANDS * NF_MAX_SH_BANDS];
    nft_fill_sentinel(out, sizeof out / sizeof out[0]);
    nf_encode_oneblob(0.5f, 0, out);
    nf_encode_sh((const float[3]){0.0f, 0.0f, 1.0f}, 0, out);
    assert_true(nft_untouched(out, sizeof out / sizeof out[0]));
    nf_encode_oneblob(0.5f, 8, NULL);
    nf_encode_sh((const float[3]){0.0f, 0.0f, 1.0f}, 4, NULL);
    const float bad_dirs[4][3] = {{0, 0, 0}, {NAN, 0, 1}, {0, INFINITY, 0}, {0, 0, -INFINITY}};
    for (int k = 0; k < 4; ++k) {
        nft_fill_sentinel(out, 16);
        nf_encode_sh(bad_dirs[k], 4, out);
        for (int i = 0; i < 16; ++i)
            if (out[i] != 0.0f)
                fail_msg("nf_encode_sh of bad direction %d: out[%d] = %g", k, i,
                         (double)out[i]);
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_create_refuses_bad_configs),
        cmocka_unit_test(test_create_refuses_half_allocator),
        cmocka_unit_test(test_create_accepts_boundary_configs),
        cmocka_unit_test(test_life_cycle_null),
        cmocka_unit_test(test_sample_bad_input),
        cmocka_unit_test(test_sample_clamps_u),
        cmocka_unit_test(test_pdf_bad_input),
        cmocka_unit_test(test_prior_pdf_bad_input),
        cmocka_unit_test(test_train_step_bad_input),
        cmocka_unit_test(test_loss_gradient_bad_input),
        cmocka_unit_test(test_params_bad_input),
        cmocka_unit_test(test_apply_gradient_bad_input),
        cmocka_unit_test(test_learning_rate_bad_input),
        cmocka_unit_test(test_io_bad_input),
        cmocka_unit_test(test_custom_callbacks_misbehave),
        cmocka_unit_test(test_blocks_bad_input),
    };
    return cmocka_run_group_tests(tests, setup_primers, NULL);
}
