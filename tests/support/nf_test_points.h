/*
 * nf_test_points.h - what the shading-point tests share (tests/correctness/test_point.c, the
 * contract; tests/robustness/test_point_input.c, bad input and corrupted points): refused
 * calls and their messages, a custom prior that counts its calls, the models and contexts.
 * Header-only: static inline helpers and the models' custom lobe, one per test program.
 * Include it after cmocka.h.
 */
#ifndef NF_TEST_POINTS_H
#define NF_TEST_POINTS_H

#include <float.h>
#include <math.h>
#include <string.h>

#include <nisflow/nisflow.h>

#include "nf_test_support.h"
#include "point_batch.h"
#include "shading_point.h"

/* Randomized parameters: uniform in [-RANDOM_SCALE, RANDOM_SCALE], as in test_normalization
 * and test_sampling, whose tolerances were measured at this scale. */
#define RANDOM_SCALE 0.3f

static const char *const isa_names[4] = {"auto", "generic", "avx2", "avx512"};

/* ---- refused calls and their messages ------------------------------------------------------ */

/* Messages persist until the next failure on the thread; a refused call must leave one that
 * names it. The message is first set by a failure of another function (nf_model_clone), so
 * a call that failed without recording its own message cannot pass. */
static inline void prime(void)
{
    nf_model *out = NULL;
    (void)nf_model_clone(NULL, &out);
}

static inline void check_refusal(nf_status got, nf_status expected, const char *fn, const char *call,
                          int line)
{
    if (got != expected)
        fail_msg("line %d: %s returned %s (%d), expected %s", line, call, nf_status_string(got),
                 (int)got, nf_status_string(expected));
    const char *msg = nf_last_error_message();
    if (strstr(msg, fn) == NULL)
        fail_msg("line %d: %s: the message \"%s\" does not name %s", line, call, msg, fn);
}

/* `call` (to function `fn`) must return `expected` and record a message naming `fn`. */
#define EXPECT_STATUS(expected, fn, call)                                                      \
    do {                                                                                       \
        prime();                                                                               \
        nf_status st_ = (call);                                                                \
        check_refusal(st_, (expected), (fn), #call, __LINE__);                                 \
    } while (0)

#define EXPECT_INVALID(fn, call) EXPECT_STATUS(NF_ERROR_INVALID_ARGUMENT, fn, call)

/* ---- a custom prior that counts its calls -------------------------------------------------- */

/* A normalized cosine-power lobe around the context's normal in solid-angle terms,
 * p(w) = (e + 1) / (2 pi) max(0, n.w)^e, sampled by inversion; at a point in a medium (zero
 * normal) around the propagation direction -wo. The callbacks count their calls in their
 * user data and check the context they receive. */
typedef struct lobe {
    double exponent;
    const nf_context *want; /* not NULL: every ctx must hold these values (bitwise)         */
    const void *lo, *hi;    /* not NULL: every ctx pointer must lie in [lo, hi)              */
    long samples, pdfs;     /* calls received                                                */
    long bad_ctx;           /* calls whose ctx broke the expectations above                  */
    int refuse;             /* 1: return an invalid density (NF_ERROR_NUMERIC expected)      */
} lobe;

static inline lobe lobe_of(double exponent)
{
    lobe l;
    memset(&l, 0, sizeof l);
    l.exponent = exponent;
    return l;
}

static inline void lobe_check_ctx(lobe *l, const nf_context *ctx)
{
    if (l->want && memcmp(ctx, l->want, sizeof *ctx) != 0)
        l->bad_ctx++;
    if (l->lo && ((const char *)ctx < (const char *)l->lo ||
                  (const char *)(ctx + 1) > (const char *)l->hi))
        l->bad_ctx++;
}

/* The lobe's axis (any length): the normal, or -wo in a medium. */
static inline void lobe_axis(const nf_context *ctx, double n[3])
{
    int medium = ctx->normal[0] == 0.0f && ctx->normal[1] == 0.0f && ctx->normal[2] == 0.0f;
    for (int k = 0; k < 3; ++k)
        n[k] = medium ? -(double)ctx->wo[k] : (double)ctx->normal[k];
}

static inline double lobe_density(double e, const nf_context *ctx, const float dir[3])
{
    double n[3];
    lobe_axis(ctx, n);
    double w[3] = {dir[0], dir[1], dir[2]};
    double c = nft_dot3(n, w) / sqrt(nft_dot3(n, n) * nft_dot3(w, w));
    if (!(c > 0.0))
        return 0.0;
    return (e + 1.0) / (2.0 * NFT_PI) * pow(c, e);
}

static inline float lobe_pdf(void *user, const nf_context *ctx, const float dir[3])
{
    lobe *l = user;
    l->pdfs++;
    lobe_check_ctx(l, ctx);
    if (l->refuse)
        return NAN;
    return (float)lobe_density(l->exponent, ctx, dir);
}

static inline float lobe_sample(void *user, const nf_context *ctx, float u0, float u1, float dir[3])
{
    lobe *l = user;
    l->samples++;
    lobe_check_ctx(l, ctx);
    double axis[3], t[3], b[3], n[3];
    lobe_axis(ctx, axis);
    nft_frame(axis, t, b, n);
    /* cos a in [1e-3, 1]: the density stays clearly above 0, as the library requires. */
    double c = pow(fmin(fmax(1.0 - (double)u0, 0.0), 1.0), 1.0 / (l->exponent + 1.0));
    c = fmin(fmax(c, 1e-3), 1.0);
    double s = sqrt(fmax(0.0, 1.0 - c * c)), phi = 2.0 * NFT_PI * (double)u1, w[3], len = 0.0;
    for (int k = 0; k < 3; ++k) {
        w[k] = s * cos(phi) * t[k] + s * sin(phi) * b[k] + c * n[k];
        len += w[k] * w[k];
    }
    for (int k = 0; k < 3; ++k)
        dir[k] = (float)(w[k] / sqrt(len));
    if (l->refuse)
        return 0.0f;
    return (float)lobe_density(l->exponent, ctx, dir);
}

static inline nf_prior_callbacks lobe_callbacks(lobe *l)
{
    nf_prior_callbacks cb;
    cb.sample = lobe_sample;
    cb.pdf = lobe_pdf;
    cb.user = l;
    return cb;
}

/* The custom prior of the models here: a cosine lobe (exponent 1). */
static lobe model_lobe = {1.0, NULL, NULL, NULL, 0, 0, 0, 0};

/* ---- models ------------------------------------------------------------------------------ */

/* nft_config, with the cosine lobe above as the custom prior. */
static inline nf_config config_for(nf_preset preset, nf_prior_kind prior)
{
    nf_config cfg = nft_config(preset, prior);
    if (prior == NF_PRIOR_CUSTOM)
        cfg.custom_prior = lobe_callbacks(&model_lobe);
    return cfg;
}

/* A model of `cfg` on instruction set `isa`, or NULL where this CPU or build lacks it (the
 * refusal must then be the documented one; the generic kernels always exist). */
static inline nf_model *create_on(nf_config cfg, nf_isa isa)
{
    cfg.isa = isa;
    nf_model *m = NULL;
    nf_status st = nf_model_create(&cfg, &m);
    if (st == NF_OK) {
        assert_non_null(m);
        if (isa != NF_ISA_AUTO)
            assert_string_equal(nf_model_isa_name(m), isa_names[isa]);
        return m;
    }
    assert_int_equal(st, NF_ERROR_INVALID_ARGUMENT);
    assert_null(m);
    assert_true(isa != NF_ISA_GENERIC);
    return NULL;
}

/* `steps` AdamW steps on random data. */
static inline void train(nf_model *m, int steps, uint64_t seed)
{
    enum { B = 32 };
    nf_context ctx[B];
    float dir[3 * B], w[B];
    nft_rng r;
    nft_rng_seed(&r, seed, 17u);
    for (int s = 0; s < steps; ++s) {
        for (int i = 0; i < B; ++i) {
            nft_random_context(&r, &ctx[i]);
            nft_random_unit_vector(&r, dir + 3 * i);
            w[i] = 0.25f + nft_rng_float(&r);
        }
        assert_int_equal(nf_train_step(m, B, ctx, dir, w, NULL), NF_OK);
    }
}

/* Randomized parameters, then two training steps: far from the identity flow, and the
 * parameters have changed three times since creation. */
static inline void perturb(nf_model *m, uint64_t seed)
{
    assert_int_equal(nft_randomize_params(m, RANDOM_SCALE, seed), NF_OK);
    train(m, 2, seed ^ 0x77u);
    assert_int_equal(nf_model_step_count(m), 2u);
}

/* ---- contexts and inputs ------------------------------------------------------------------- */

/* `count` contexts (count >= 6): the normal on both poles and on the phi = 0 seam, positions
 * outside the scene bounds and huge, normal and wo of lengths far from 1, wo below the
 * surface; the rest random. */
static inline void make_contexts(uint64_t seed, nf_context *ctx, int count)
{
    nft_rng r;
    nft_rng_seed(&r, seed, 5u);
    for (int i = 0; i < count; ++i)
        nft_random_context(&r, &ctx[i]);
    ctx[0] = nft_context(0.5f, 0.5f, 0.5f, 0.0f, 0.0f, 1.0f, 0.3f, -0.5f, 0.81f);
    ctx[1] = nft_context(0.0f, 0.0f, 0.0f, 0.0f, 0.0f, -1.0f, 0.2f, 0.4f, -0.89f);
    ctx[2] = nft_context(-3.0f, 0.5f, 7.0f, 1.0f, 0.0f, 0.0f, 0.8f, 0.3f, 0.52f);
    /* Squared lengths 1e-24 and 1e24: valid (above 1e-30, finite), normalized by the library. */
    for (int a = 0; a < 3; ++a) {
        ctx[3].normal[a] *= 1e-12f;
        ctx[3].wo[a] *= 1e12f;
    }
    ctx[3].position[0] = 1e30f;
    ctx[3].position[1] = -FLT_MAX;
    for (int a = 0; a < 3; ++a)
        ctx[4].wo[a] = -ctx[4].wo[a]; /* wo below the surface */
    for (int a = 0; a < 3; ++a)
        ctx[5].normal[a] *= 3.7f;
    /* A surface's phase_g is never read: garbage there changes nothing. */
    ctx[5].phase_g = NAN;
    /* Points in a medium (normal exactly zero) between surfaces, so that tiles mix both, with
     * g over its whole range (the cosine prior's Henyey-Greenstein branch). The first eight
     * contexts, which test_sample_pdf_agree compares at 1e-4, stop at g = 0.9: at |g| = 0.99
     * the prior's log-density changes by ~1e3 per unit of the square near its peak, so the
     * flow's round trip error (~1e-6) alone moves it by ~1e-3 (test_medium.c checks there). */
    static const float g[] = {0.0f, 0.3f, -0.99f, 0.9f, 0.99f, -0.5f, -0.9f};
    for (int i = 6; i < count; i += 2) {
        for (int a = 0; a < 3; ++a)
            ctx[i].normal[a] = i % 4 == 0 ? -0.0f : 0.0f;
        ctx[i].phase_g = g[(i / 2) % 7];
    }
}

/* A small model with `prior`, perturbed (seed), and six contexts of make_contexts (ctx_seed):
 * the points most tests here prepare. */
static inline nf_model *perturbed_model(nf_prior_kind prior, uint64_t seed, uint64_t ctx_seed,
                                        nf_context ctx[6])
{
    nf_model *m = create_on(config_for(NF_PRESET_SMALL, prior), NF_ISA_AUTO);
    assert_non_null(m);
    perturb(m, seed);
    make_contexts(ctx_seed, ctx, 6);
    return m;
}

/* Every function refuses the point on `m` with `expected` and writes nothing. */
static inline void assert_point_refused(const nf_model *m, const nf_shading_point *sp,
                                 nf_status expected)
{
    enum { N = 3 };
    float u[2 * N] = {0.1f, 0.2f, 0.3f, 0.4f, 0.5f, 0.6f};
    float dir_in[3 * N] = {0.0f, 0.0f, 1.0f, 0.6f, 0.0f, 0.8f, -1.0f, 0.0f, 0.0f};
    float dir[3 * N], pdf[N];
    nf_shading_point three[N] = {*sp, *sp, *sp};
    nft_fill_sentinel(dir, 3 * N);
    nft_fill_sentinel(pdf, N);
    EXPECT_STATUS(expected, "nf_point_sample", nf_point_sample(m, sp, N, u, dir, pdf));
    EXPECT_STATUS(expected, "nf_point_sample", nf_point_sample(m, sp, 1, u, dir, NULL));
    EXPECT_STATUS(expected, "nf_point_pdf", nf_point_pdf(m, sp, N, dir_in, pdf));
    EXPECT_STATUS(expected, "nf_point_sample_and_pdf",
                  nf_point_sample_and_pdf(m, sp, u, dir, pdf, dir_in, pdf + 1));
    EXPECT_STATUS(expected, "nf_point_sample_batch", nf_point_sample_batch(m, N, three, u, dir, pdf));
    EXPECT_STATUS(expected, "nf_point_pdf_batch", nf_point_pdf_batch(m, N, three, dir_in, pdf));
    assert_true(nft_untouched(dir, 3 * N) && nft_untouched(pdf, N));
}

#endif /* NF_TEST_POINTS_H */
