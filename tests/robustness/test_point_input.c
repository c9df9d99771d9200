/*
 * test_point_input.c - the shading-point API (nisflow/point.h) against bad input and
 * corrupted points (its contract otherwise: tests/correctness/test_point.c).
 *
 *   - bad input: every refused call returns NF_ERROR_INVALID_ARGUMENT, records a message that
 *     names the function and writes nothing; a failed prepare leaves a prepared point intact;
 *     unprepared points are refused; u outside [0, 1) is clamped;
 *   - corrupted points: a point whose header (identity or context) was overwritten, byte by
 *     byte, is refused, never answered.
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

#include "nf_test_points.h"
#include "nf_test_support.h"
#include "point_batch.h"
#include "shading_point.h"

static const nf_prior_kind all_priors[4] = {NF_PRIOR_UNIFORM_DIRECTION, NF_PRIOR_UNIFORM_ANGLE,
                                            NF_PRIOR_COSINE, NF_PRIOR_CUSTOM};

/* The point answers on `m` as a point freshly prepared at `ctx` does, to the bit (points agree
 * with each other on every path: point.h). */
static void assert_point_intact(const nf_model *m, const nf_shading_point *sp,
                                const nf_context *ctx)
{
    enum { N = 5 };
    float u[2 * N], dir[3 * N], d1[3 * N], d2[3 * N], p1[N], p2[N], e1[N], e2[N];
    nft_rng r;
    nft_rng_seed(&r, 8u, 8u);
    nft_random_u_dir(&r, N, u, dir);
    nf_shading_point fresh;
    assert_int_equal(nf_point_prepare(m, ctx, NULL, &fresh), NF_OK);
    assert_int_equal(nf_point_sample(m, &fresh, N, u, d1, p1), NF_OK);
    assert_int_equal(nf_point_pdf(m, &fresh, N, dir, e1), NF_OK);
    assert_int_equal(nf_point_sample(m, sp, N, u, d2, p2), NF_OK);
    assert_int_equal(nf_point_pdf(m, sp, N, dir, e2), NF_OK);
    assert_memory_equal(d1, d2, sizeof d1);
    assert_memory_equal(p1, p2, sizeof p1);
    assert_memory_equal(e1, e2, sizeof e1);
}

/* ---- bad input ----------------------------------------------------------------------------- */

/* Batch sizes whose byte counts overflow size_t. */
static const size_t huge_n[3] = {SIZE_MAX, SIZE_MAX / 2u, SIZE_MAX / (3u * sizeof(float)) + 1u};

static void test_prepare_bad_input(void **state)
{
    (void)state;
    nf_model *m = create_on(config_for(NF_PRESET_SMALL, NF_PRIOR_COSINE), NF_ISA_AUTO);
    nf_model *custom = create_on(config_for(NF_PRESET_SMALL, NF_PRIOR_CUSTOM), NF_ISA_AUTO);
    assert_non_null(m);
    assert_non_null(custom);
    perturb(m, 1u);
    perturb(custom, 2u);
    nf_context ctx[6];
    make_contexts(3u, ctx, 6);
    const nf_context *good = &ctx[5];
    nf_shading_point sp, before;
    assert_int_equal(nf_point_prepare(m, good, NULL, &sp), NF_OK);
    before = sp;
    char what[96];

    EXPECT_INVALID("nf_point_prepare", nf_point_prepare(NULL, good, NULL, &sp));
    EXPECT_INVALID("nf_point_prepare", nf_point_prepare(m, NULL, NULL, &sp));
    EXPECT_INVALID("nf_point_prepare", nf_point_prepare(m, good, NULL, NULL));
    assert_memory_equal(&sp, &before, sizeof sp);
    for (int which = 0; which < NFT_BAD_CONTEXTS; ++which) {
        nf_context bad = nft_bad_context(good, which, what, sizeof what);
        prime();
        nf_status st = nf_point_prepare(m, &bad, NULL, &sp);
        check_refusal(st, NF_ERROR_INVALID_ARGUMENT, "nf_point_prepare", what, __LINE__);
        if (memcmp(&sp, &before, sizeof sp) != 0)
            fail_msg("nf_point_prepare with %s wrote the point", what);
    }
    /* Just valid: squared lengths 3e-30 (components 1e-15) and a huge position. */
    nf_context edge = *good;
    edge.normal[0] = edge.normal[1] = edge.normal[2] = 1e-15f;
    edge.wo[0] = -1e-15f;
    edge.wo[1] = edge.wo[2] = 1e-15f;
    edge.position[1] = FLT_MAX;
    nf_shading_point se;
    assert_int_equal(nf_point_prepare(m, &edge, NULL, &se), NF_OK);
    assert_point_intact(m, &se, &edge);

    /* Prior callbacks: refused on a model with another prior, and with a NULL callback. */
    lobe l = lobe_of(4.0);
    nf_prior_callbacks cb = lobe_callbacks(&l);
    EXPECT_INVALID("nf_point_prepare", nf_point_prepare(m, good, &cb, &sp));
    assert_memory_equal(&sp, &before, sizeof sp);
    nf_shading_point cp;
    assert_int_equal(nf_point_prepare(custom, good, NULL, &cp), NF_OK);
    nf_shading_point cp_before = cp;
    nf_prior_callbacks half = cb;
    half.sample = NULL;
    EXPECT_INVALID("nf_point_prepare", nf_point_prepare(custom, good, &half, &cp));
    half = cb;
    half.pdf = NULL;
    EXPECT_INVALID("nf_point_prepare", nf_point_prepare(custom, good, &half, &cp));
    memset(&half, 0, sizeof half);
    EXPECT_INVALID("nf_point_prepare", nf_point_prepare(custom, good, &half, &cp));
    /* A bad context with good callbacks. */
    nf_context bad = nft_bad_context(good, 0, what, sizeof what);
    EXPECT_INVALID("nf_point_prepare", nf_point_prepare(custom, &bad, &cb, &cp));
    assert_memory_equal(&cp, &cp_before, sizeof cp);
    assert_int_equal(l.samples + l.pdfs, 0);

    /* The points refused above are still valid and unchanged in behavior. */
    assert_point_intact(m, &sp, good);
    assert_point_intact(custom, &cp, good);

    /* ctx may be the point's own copy of its context (point.h's implementation note: the
     * context is copied first); the result is the point prepared from the same values. */
    nf_shading_point self = sp;
    assert_int_equal(nf_point_prepare(m, &self.context_, NULL, &self), NF_OK);
    assert_memory_equal(&self, &sp, sizeof sp);

    nf_model_destroy(m);
    nf_model_destroy(custom);
}

static void test_sample_pdf_bad_input(void **state)
{
    (void)state;
    enum { N = 6 };
    nf_context ctx[6];
    nf_model *m = perturbed_model(NF_PRIOR_CUSTOM, 9u, 10u, ctx);
    nf_shading_point sp, pts[N];
    assert_int_equal(nf_point_prepare(m, &ctx[5], NULL, &sp), NF_OK);
    for (int i = 0; i < N; ++i)
        assert_int_equal(nf_point_prepare(m, &ctx[i], NULL, &pts[i]), NF_OK);
    nft_rng r;
    nft_rng_seed(&r, 11u, 1u);
    float u[2 * N], din[3 * N], dir[3 * N], pdf[N];
    nft_random_u_dir(&r, N, u, din);
    nft_fill_sentinel(dir, 3 * N);
    nft_fill_sentinel(pdf, N);
    const long calls = model_lobe.samples + model_lobe.pdfs;

    /* NULL arguments (pdf may be NULL for the samplers only). */
    EXPECT_INVALID("nf_point_sample", nf_point_sample(NULL, &sp, N, u, dir, pdf));
    EXPECT_INVALID("nf_point_sample", nf_point_sample(m, NULL, N, u, dir, pdf));
    EXPECT_INVALID("nf_point_sample", nf_point_sample(m, &sp, N, NULL, dir, pdf));
    EXPECT_INVALID("nf_point_sample", nf_point_sample(m, &sp, N, u, NULL, pdf));
    EXPECT_INVALID("nf_point_pdf", nf_point_pdf(NULL, &sp, N, din, pdf));
    EXPECT_INVALID("nf_point_pdf", nf_point_pdf(m, NULL, N, din, pdf));
    EXPECT_INVALID("nf_point_pdf", nf_point_pdf(m, &sp, N, NULL, pdf));
    EXPECT_INVALID("nf_point_pdf", nf_point_pdf(m, &sp, N, din, NULL));
    EXPECT_INVALID("nf_point_sample_and_pdf",
                   nf_point_sample_and_pdf(NULL, &sp, u, dir, pdf, din, pdf + 1));
    EXPECT_INVALID("nf_point_sample_and_pdf",
                   nf_point_sample_and_pdf(m, NULL, u, dir, pdf, din, pdf + 1));
    EXPECT_INVALID("nf_point_sample_and_pdf",
                   nf_point_sample_and_pdf(m, &sp, NULL, dir, pdf, din, pdf + 1));
    EXPECT_INVALID("nf_point_sample_and_pdf",
                   nf_point_sample_and_pdf(m, &sp, u, NULL, pdf, din, pdf + 1));
    EXPECT_INVALID("nf_point_sample_and_pdf",
                   nf_point_sample_and_pdf(m, &sp, u, dir, pdf, NULL, pdf + 1));
    EXPECT_INVALID("nf_point_sample_and_pdf",
                   nf_point_sample_and_pdf(m, &sp, u, dir, pdf, din, NULL));
    EXPECT_INVALID("nf_point_sample_batch", nf_point_sample_batch(NULL, N, pts, u, dir, pdf));
    EXPECT_INVALID("nf_point_sample_batch", nf_point_sample_batch(m, N, NULL, u, dir, pdf));
    EXPECT_INVALID("nf_point_sample_batch", nf_point_sample_batch(m, N, pts, NULL, dir, pdf));
    EXPECT_INVALID("nf_point_sample_batch", nf_point_sample_batch(m, N, pts, u, NULL, pdf));
    EXPECT_INVALID("nf_point_pdf_batch", nf_point_pdf_batch(NULL, N, pts, din, pdf));
    EXPECT_INVALID("nf_point_pdf_batch", nf_point_pdf_batch(m, N, NULL, din, pdf));
    EXPECT_INVALID("nf_point_pdf_batch", nf_point_pdf_batch(m, N, pts, NULL, pdf));
    EXPECT_INVALID("nf_point_pdf_batch", nf_point_pdf_batch(m, N, pts, din, NULL));
    /* Sizes whose byte counts overflow. */
    for (int k = 0; k < 3; ++k) {
        EXPECT_INVALID("nf_point_sample", nf_point_sample(m, &sp, huge_n[k], u, dir, pdf));
        EXPECT_INVALID("nf_point_pdf", nf_point_pdf(m, &sp, huge_n[k], din, pdf));
        EXPECT_INVALID("nf_point_sample_batch", nf_point_sample_batch(m, huge_n[k], pts, u, dir, pdf));
        EXPECT_INVALID("nf_point_pdf_batch", nf_point_pdf_batch(m, huge_n[k], pts, din, pdf));
    }
    assert_true(nft_untouched(dir, 3 * N) && nft_untouched(pdf, N));

    /* NaN and infinite u, in the last pair: nothing of the batch may be written. */
    const float bad_u[3] = {NAN, INFINITY, -INFINITY};
    for (int k = 0; k < 6; ++k) {
        float bu[2 * N];
        memcpy(bu, u, sizeof u);
        bu[2 * (N - 1) + (k & 1)] = bad_u[k / 2];
        EXPECT_INVALID("nf_point_sample", nf_point_sample(m, &sp, N, bu, dir, pdf));
        EXPECT_INVALID("nf_point_sample_batch", nf_point_sample_batch(m, N, pts, bu, dir, pdf));
        EXPECT_INVALID("nf_point_sample_and_pdf",
                       nf_point_sample_and_pdf(m, &sp, bu + 2 * (N - 1), dir, pdf, din, pdf + 1));
        assert_true(nft_untouched(dir, 3 * N) && nft_untouched(pdf, N));
    }
    /* Bad directions in the last entry: NaN, +-Inf in any component, zero, too short. */
    for (int k = 0; k < 11; ++k) {
        float bd[3 * N];
        memcpy(bd, din, sizeof din);
        float *d = bd + 3 * (N - 1);
        if (k < 9) {
            d[k % 3] = bad_u[k / 3];
        } else {
            d[0] = d[1] = d[2] = k == 9 ? 0.0f : 1e-16f;
        }
        EXPECT_INVALID("nf_point_pdf", nf_point_pdf(m, &sp, N, bd, pdf));
        EXPECT_INVALID("nf_point_pdf_batch", nf_point_pdf_batch(m, N, pts, bd, pdf));
        EXPECT_INVALID("nf_point_sample_and_pdf",
                       nf_point_sample_and_pdf(m, &sp, u, dir, pdf, d, pdf + 1));
        assert_true(nft_untouched(dir, 3 * N) && nft_untouched(pdf, N));
    }
    /* No refused call reached the prior's callbacks. */
    assert_int_equal(model_lobe.samples + model_lobe.pdfs, calls);

    /* Unprepared points: zeroed, and random bytes (the check hash makes a false accept
     * 2^-32 per try); on their own and as the last of a batch. */
    nf_shading_point junk;
    for (int t = 0; t < 65; ++t) {
        if (t == 0) {
            memset(&junk, 0, sizeof junk);
        } else {
            for (size_t b = 0; b < sizeof junk; ++b)
                ((unsigned char *)&junk)[b] = (unsigned char)nft_rng_u32(&r);
        }
        assert_point_refused(m, &junk, NF_ERROR_INVALID_ARGUMENT);
        nf_shading_point batch[N];
        memcpy(batch, pts, sizeof batch);
        batch[N - 1] = junk;
        EXPECT_INVALID("nf_point_sample_batch", nf_point_sample_batch(m, N, batch, u, dir, pdf));
        EXPECT_INVALID("nf_point_pdf_batch", nf_point_pdf_batch(m, N, batch, din, pdf));
        assert_true(nft_untouched(dir, 3 * N) && nft_untouched(pdf, N));
    }
    assert_int_equal(model_lobe.samples + model_lobe.pdfs, calls);

    /* n = 0 is a no-op, with NULL pointers or with outputs that stay unwritten. */
    assert_int_equal(nf_point_sample(m, &sp, 0, NULL, NULL, NULL), NF_OK);
    assert_int_equal(nf_point_pdf(m, &sp, 0, NULL, NULL), NF_OK);
    assert_int_equal(nf_point_sample_batch(m, 0, NULL, NULL, NULL, NULL), NF_OK);
    assert_int_equal(nf_point_pdf_batch(m, 0, NULL, NULL, NULL), NF_OK);
    assert_int_equal(nf_point_sample(m, &sp, 0, u, dir, pdf), NF_OK);
    assert_int_equal(nf_point_pdf(m, &sp, 0, din, pdf), NF_OK);
    assert_int_equal(nf_point_sample_batch(m, 0, pts, u, dir, pdf), NF_OK);
    assert_int_equal(nf_point_pdf_batch(m, 0, pts, din, pdf), NF_OK);
    assert_true(nft_untouched(dir, 3 * N) && nft_untouched(pdf, N));
    assert_int_equal(model_lobe.samples + model_lobe.pdfs, calls);

    /* After all of that, the points still work. */
    assert_point_intact(m, &sp, &ctx[5]);
    nf_model_destroy(m);
}

/* u outside [0, 1) is clamped to [0, 0x1.fffffep-1] (nf_sample's rule), not refused. */
static void test_u_clamped(void **state)
{
    (void)state;
    for (int p = 0; p < 4; ++p) {
        nf_context ctx[6];
        nf_model *m = perturbed_model(all_priors[p], 20u + (uint64_t)p, 21u, ctx);
        nf_shading_point sp;
        assert_int_equal(nf_point_prepare(m, &ctx[5], NULL, &sp), NF_OK);
        const float one_below = 0x1.fffffep-1f;
        const float in[][2] = {{-0.5f, 0.3f}, {0.3f, -3.0f}, {1.5f, 0.3f}, {0.3f, 7.0f},
                               {1.0f, 1.0f}, {-FLT_MAX, FLT_MAX}, {-FLT_TRUE_MIN, 0.3f}};
        const float clamped[][2] = {{0.0f, 0.3f}, {0.3f, 0.0f}, {one_below, 0.3f},
                                    {0.3f, one_below}, {one_below, one_below},
                                    {0.0f, one_below}, {0.0f, 0.3f}};
        for (int k = 0; k < 7; ++k) {
            float d[3], pd, dc[3], pc;
            assert_int_equal(nf_point_sample(m, &sp, 1, in[k], d, &pd), NF_OK);
            assert_int_equal(nf_point_sample(m, &sp, 1, clamped[k], dc, &pc), NF_OK);
            assert_memory_equal(d, dc, sizeof d);
            assert_memory_equal(&pd, &pc, sizeof pd);
            assert_true(isfinite(pd) && pd > 0.0f);
            assert_true(fabs(nft_length3f(d) - 1.0) <= 1e-5);
        }
        nf_model_destroy(m);
    }
}

/* ---- corrupted points ---------------------------------------------------------------------- */

/* A byte range of the point's header, by field. */
typedef struct field {
    const char *name;
    size_t offset, size;
} field;

#define FIELD(f) {#f, offsetof(nf_shading_point, f), sizeof(((nf_shading_point *)0)->f)}

/* Flips bits of every byte of `f` in a prepared point (three masks per byte); returns how
 * many corrupted points some function accepted, and asserts that every refusal was the
 * documented one with nothing written. */
static int count_accepted_flips(const nf_model *m, const nf_shading_point *sp, field f)
{
    static const unsigned char masks[3] = {0x01, 0x80, 0xff};
    float u[2] = {0.3f, 0.7f}, din[3] = {0.6f, 0.0f, 0.8f}, dir[3], pdf[1];
    int accepted = 0;
    for (size_t b = 0; b < f.size; ++b) {
        for (int k = 0; k < 3; ++k) {
            nf_shading_point bad = *sp;
            ((unsigned char *)&bad)[f.offset + b] ^= masks[k];
            nft_fill_sentinel(dir, 3);
            nft_fill_sentinel(pdf, 1);
            nf_status s1 = nf_point_sample(m, &bad, 1, u, dir, pdf);
            nf_status s2 = nf_point_pdf(m, &bad, 1, din, pdf);
            nf_status s3 = nf_point_sample_batch(m, 1, &bad, u, dir, pdf);
            nf_status s4 = nf_point_pdf_batch(m, 1, &bad, din, pdf);
            if (s1 == NF_OK || s2 == NF_OK || s3 == NF_OK || s4 == NF_OK) {
                ++accepted;
                continue;
            }
            if (s1 != NF_ERROR_INVALID_ARGUMENT || s2 != NF_ERROR_INVALID_ARGUMENT ||
                s3 != NF_ERROR_INVALID_ARGUMENT || s4 != NF_ERROR_INVALID_ARGUMENT)
                fail_msg("%s byte %zu ^ 0x%02x: statuses %d %d %d %d", f.name, b, masks[k],
                         (int)s1, (int)s2, (int)s3, (int)s4);
            if (!nft_untouched(dir, 3) || !nft_untouched(pdf, 1))
                fail_msg("%s byte %zu ^ 0x%02x: a refused call wrote its output", f.name, b,
                         masks[k]);
        }
    }
    return accepted;
}

/* Flips bits of each of `fields` in a point of a small model and of an uncached one (seeded
 * by `seed`) and fails, naming them, when any flip is accepted; the point left behind must
 * still work. */
static void check_flips_refused(const field *fields, size_t count, uint64_t seed)
{
    char report[256] = "";
    size_t used = 0;
    for (int big = 0; big < 2; ++big) {
        nf_config cfg = config_for(NF_PRESET_SMALL, NF_PRIOR_COSINE);
        if (big) { /* uncached */
            cfg.coupling_layers = 8;
            cfg.hidden_width = 64;
        }
        nf_model *m = create_on(cfg, NF_ISA_AUTO);
        assert_non_null(m);
        perturb(m, seed);
        nf_context ctx[6];
        make_contexts(seed + 1u, ctx, 6);
        nf_shading_point sp;
        assert_int_equal(nf_point_prepare(m, &ctx[5], NULL, &sp), NF_OK);
        for (size_t f = 0; f < count; ++f) {
            int accepted = count_accepted_flips(m, &sp, fields[f]);
            if (accepted && used < sizeof report)
                used += (size_t)snprintf(report + used, sizeof report - used,
                                         " %s%s: %d of %zu;", fields[f].name,
                                         big ? " (uncached)" : "", accepted,
                                         3 * fields[f].size);
        }
        assert_point_intact(m, &sp, &ctx[5]);
        nf_model_destroy(m);
    }
    if (used)
        fail_msg("corrupted points accepted (bit flips accepted of those tried):%s", report);
}

/* The fields that identify a point: its mark, model, parameter generation, cache flag and
 * check hash. Any flipped bit must be refused as NF_ERROR_INVALID_ARGUMENT (a corrupted
 * point, point.h), not NF_ERROR_STALE, with nothing written. */
static void test_corrupted_identity_refused(void **state)
{
    (void)state;
    const field fields[] = {FIELD(magic_), FIELD(model_id_), FIELD(generation_), FIELD(cached_),
                            FIELD(check_)};
    check_flips_refused(fields, sizeof fields / sizeof fields[0], 31u);
}

/* The other fields that point.h's check_ claims to cover ("a hash of the fields above"): the
 * context, the prior callbacks and the frame. A point with a flipped bit there describes
 * another context (or calls another function) than the one it was prepared for; point.h
 * promises NF_ERROR_INVALID_ARGUMENT for a corrupted point. (Only a model without a custom
 * prior is used, so that an accepted corrupted callback pointer is never called.) */
static void test_corrupted_context_refused(void **state)
{
    (void)state;
    const field fields[] = {FIELD(context_), FIELD(prior_), FIELD(frame_)};
    check_flips_refused(fields, sizeof fields / sizeof fields[0], 33u);
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_prepare_bad_input),
    cmocka_unit_test(test_sample_pdf_bad_input),
    cmocka_unit_test(test_u_clamped),
    cmocka_unit_test(test_corrupted_identity_refused),
    cmocka_unit_test(test_corrupted_context_refused),
)
