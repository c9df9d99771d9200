/*
 * test_guide_threads.c - training while other threads sample is either safe or refused, never
 * silently wrong (nisflow/guide.h, nisflow/point.h):
 *
 *   1. through a guide: two render threads sample the published models and add training
 *      samples while a third thread trains and publishes; every answer must be the model's
 *      own (a shading point's density equals nf_pdf's on the same model, to the bit), no add
 *      is refused, and no sample is lost: every one added is trained on or counted as
 *      dropped. .ci/robustness runs this under ThreadSanitizer too: it has no data race.
 *   1b. render threads that help with the guide's steps between tiles (nf_guide_help) take
 *      tasks of a training call run with nf_guide_helpers, and the model has the same bits
 *      as one trained alone.
 *   2. misuse of a bare model: a thread prepares shading points while another takes
 *      nf_train_step on the same model. No point prepared during a step may be accepted
 *      afterwards; every point still accepted must agree with the final model to the bit.
 *      This one races by design, so it is left out under ThreadSanitizer.
 */
#define _POSIX_C_SOURCE 200809L

#include <math.h>
#include <pthread.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <cmocka.h>

#include "nf_test_support.h"
#include "shading_point.h"

#if defined(__SANITIZE_THREAD__)
#define NF_UNDER_TSAN 1
#elif defined(__has_feature)
#if __has_feature(thread_sanitizer)
#define NF_UNDER_TSAN 1
#endif
#endif
#ifndef NF_UNDER_TSAN
#define NF_UNDER_TSAN 0
#endif

#define SAMPLES 512

typedef struct shared {
    nf_guide *g;
    nf_context ctx[SAMPLES];
    float dir[3 * SAMPLES], weight[SAMPLES];
    atomic_int stop;
    atomic_ulong checked, mismatched, refused_adds, added, publishes, models_seen;
} shared;

/* A zeroed `shared` (the test fails without one) holding the samples of `seed`. */
static shared *new_shared(uint64_t seed)
{
    shared *s = calloc(1, sizeof *s);
    assert_non_null(s);
    nft_rng r;
    nft_rng_seed(&r, seed, 3);
    const double mu[3] = {0.3, 0.0, 0.95};
    for (int i = 0; i < SAMPLES; ++i) {
        nft_random_context(&r, &s->ctx[i]);
        nft_vmf_sample(&r, mu, 30.0, s->dir + 3 * i);
        s->weight[i] = 0.5f + nft_rng_float(&r);
    }
    return s;
}

static void *render_thread(void *arg)
{
    shared *s = arg;
    nft_rng r;
    nft_rng_seed(&r, (uint64_t)(uintptr_t)arg, 5);
    const nf_model *last = NULL;
    while (!atomic_load(&s->stop)) {
        const nf_model *m = NULL;
        if (nf_guide_acquire(s->g, &m) != NF_OK)
            break;
        if (m != last)
            atomic_fetch_add(&s->models_seen, 1ul);
        last = m;
        for (int k = 0; k < 20; ++k) {
            const nf_context *ctx = &s->ctx[nft_rng_u32(&r) % SAMPLES];
            nf_shading_point sp, again;
            float u[2] = {nft_rng_float(&r), nft_rng_float(&r)}, dir[3], pdf, dir2[3], pdf2;
            float other, other2, b_dir[3], b_pdf, b_other, b_dir2[3], b_pdf2, b_other2;
            const float *probe = s->dir + 3 * (nft_rng_u32(&r) % SAMPLES);
            int ok = nf_point_prepare(m, ctx, NULL, &sp) == NF_OK &&
                     nf_point_sample(m, &sp, 1, u, dir, &pdf) == NF_OK &&
                     nf_sample(m, 1, ctx, u, b_dir, &b_pdf) == NF_OK &&
                     nf_point_pdf(m, &sp, 1, probe, &other) == NF_OK &&
                     nf_pdf(m, 1, ctx, probe, &b_other) == NF_OK &&
                     nf_point_prepare(m, ctx, NULL, &again) == NF_OK &&
                     nf_point_sample(m, &again, 1, u, dir2, &pdf2) == NF_OK &&
                     nf_sample(m, 1, ctx, u, b_dir2, &b_pdf2) == NF_OK &&
                     nf_point_pdf(m, &again, 1, probe, &other2) == NF_OK &&
                     nf_pdf(m, 1, ctx, probe, &b_other2) == NF_OK;
            /* A held model is stable: every call succeeds, and asked twice, a point prepared
             * twice and the batch calls each answer alike to the bit. (Points and batch calls
             * agree with each other to the bit or within a bound: test_point.c.) */
            if (!ok || memcmp(dir, dir2, sizeof dir) != 0 || memcmp(&pdf, &pdf2, sizeof pdf) != 0 ||
                memcmp(&other, &other2, sizeof other) != 0 ||
                memcmp(b_dir, b_dir2, sizeof b_dir) != 0 ||
                memcmp(&b_pdf, &b_pdf2, sizeof b_pdf) != 0 ||
                memcmp(&b_other, &b_other2, sizeof b_other) != 0)
                atomic_fetch_add(&s->mismatched, 1ul);
            atomic_fetch_add(&s->checked, 1ul);
        }
        /* The pass's training samples, added while the trainer may be training: never
         * refused. */
        uint64_t key[16];
        const size_t first = nft_rng_u32(&r) % (SAMPLES - 16);
        for (int i = 0; i < 16; ++i)
            key[i] = (uint64_t)(first + (size_t)i);
        nf_status st = nf_guide_add_samples(s->g, 16, key, s->ctx + first, s->dir + 3 * first,
                                            s->weight + first, NULL);
        if (st == NF_OK)
            atomic_fetch_add(&s->added, 16ul);
        else
            atomic_fetch_add(&s->refused_adds, 1ul);
        nf_guide_release(s->g, m);
    }
    return NULL;
}

static void test_guide_train_while_sampling(void **state)
{
    nf_model *m = *state;
    shared *s = new_shared(9);
    nf_guide_config gc = nft_guide_config(4096, 128, 2);
    gc.learning_rate = 2e-2f;
    assert_int_equal(nf_guide_create(m, &gc, &s->g), NF_OK);

    pthread_t render[2];
    for (int i = 0; i < 2; ++i)
        assert_int_equal(pthread_create(&render[i], NULL, render_thread, s), 0);
    int busy = 0, busy_publish = 0, trained = 0;
    /* Until 20 publications and 1,000 checked answers (on a loaded machine any thread may
     * wait long for a core), or a bound on the passes. */
    for (int pass = 0; pass < 20000 && (atomic_load(&s->publishes) < 20 ||
                                         atomic_load(&s->checked) < 1000);
         ++pass) {
        nf_status st = nf_guide_train_pass(s->g, NULL, NULL, NULL);
        if (st == NF_ERROR_BUSY) { /* only another training call may refuse it: none here */
            busy++;
            continue;
        }
        assert_int_equal(st, NF_OK);
        trained++;
        /* Refused only while the render threads hold both older published models (each holds
         * one, so both would have to lag): they release theirs within microseconds. */
        for (int tries = 0; tries < 1000; ++tries) {
            st = nf_guide_publish(s->g);
            assert_true(st == NF_OK || st == NF_ERROR_BUSY);
            if (st == NF_OK) {
                atomic_fetch_add(&s->publishes, 1ul);
                break;
            }
            busy_publish++;
            nanosleep(&(struct timespec){0, 20000}, NULL);
        }
    }
    atomic_store(&s->stop, 1);
    for (int i = 0; i < 2; ++i)
        pthread_join(render[i], NULL);
    /* A last pass trains on what the render threads added after the loop's last pass. */
    assert_int_equal(nf_guide_train_pass(s->g, NULL, NULL, NULL), NF_OK);
    nf_guide_stats stats;
    assert_int_equal(nf_guide_get_stats(s->g, &stats), NF_OK);
    print_message("guide: %lu answers checked, %lu wrong; %d passes trained, %d refused busy; "
                  "%lu publications, %d refused busy; %lu samples added, %llu trained on, "
                  "%llu dropped, adds refused %lu; models seen %lu\n",
                  atomic_load(&s->checked), atomic_load(&s->mismatched), trained, busy,
                  atomic_load(&s->publishes), busy_publish, atomic_load(&s->added),
                  (unsigned long long)stats.samples, (unsigned long long)stats.dropped,
                  atomic_load(&s->refused_adds), atomic_load(&s->models_seen));
    assert_int_equal(atomic_load(&s->mismatched), 0);
    assert_int_equal(atomic_load(&s->refused_adds), 0);
    assert_int_equal(busy, 0);
    /* Nothing lost: every sample added went into a pass or was counted as dropped. */
    assert_int_equal(stats.samples + stats.dropped, atomic_load(&s->added));
    assert_true(atomic_load(&s->added) > 0);
    assert_true(atomic_load(&s->checked) > 0);
    assert_true(trained > 0);
    assert_true(atomic_load(&s->publishes) > 0);
    nf_guide_destroy(s->g);
    free(s);
}

/* ---- 1b. Training helped by render threads (nf_guide_helpers, nf_guide_help) ------------ */

typedef struct helping {
    nf_guide *g;
    atomic_int stop;
    atomic_ulong helped;
} helping;

/* A render thread between its tiles: helps whenever a step is in progress. */
static void *helper_thread(void *arg)
{
    helping *h = arg;
    while (!atomic_load(&h->stop)) {
        size_t ran = nf_guide_help(h->g);
        atomic_fetch_add(&h->helped, (unsigned long)ran);
        if (ran == 0)
            nanosleep(&(struct timespec){0, 2000}, NULL); /* a tile's worth of rendering */
    }
    return NULL;
}

/* Two guides train on the same samples, one alone, one with two helper threads: the helpers
 * must take tasks (else nf_guide_help does nothing) and the models end with the same bits. */
static void test_guide_helped_by_render_threads(void **state)
{
    nf_model *m = *state;
    shared *s = new_shared(4);
    nf_guide_config gc = nft_guide_config(4096, 256, 4);
    nf_guide *alone, *helped;
    assert_int_equal(nf_guide_create(m, &gc, &alone), NF_OK);
    assert_int_equal(nf_guide_create(m, &gc, &helped), NF_OK);
    helping h = {.g = helped};
    atomic_init(&h.stop, 0);
    atomic_init(&h.helped, 0ul);
    pthread_t t[2];
    for (int i = 0; i < 2; ++i)
        assert_int_equal(pthread_create(&t[i], NULL, helper_thread, &h), 0);
    uint64_t key[SAMPLES];
    for (int i = 0; i < SAMPLES; ++i)
        key[i] = (uint64_t)i;
    const nf_parallel par = nf_guide_helpers(helped);
    assert_non_null(par.run);
    /* Until the helpers took tasks, or a bound (on a loaded machine they may wait long for a
     * core): each pass is 4 steps of 16 groups. */
    int passes = 0;
    for (; passes < 400 && (passes < 10 || atomic_load(&h.helped) == 0); ++passes) {
        for (int k = 0; k < 2; ++k)
            assert_int_equal(nf_guide_add_samples(k ? helped : alone, SAMPLES, key, s->ctx,
                                                  s->dir, s->weight, NULL),
                             NF_OK);
        assert_int_equal(nf_guide_train_pass(alone, NULL, NULL, NULL), NF_OK);
        assert_int_equal(nf_guide_train_pass(helped, &par, NULL, NULL), NF_OK);
    }
    atomic_store(&h.stop, 1);
    for (int i = 0; i < 2; ++i)
        pthread_join(t[i], NULL);
    assert_int_equal(nf_guide_help(helped), 0); /* no step in progress: nothing to do */
    const size_t P = nf_model_param_count(m);
    float *a = malloc(P * sizeof *a), *b = malloc(P * sizeof *b);
    assert_non_null(a);
    assert_non_null(b);
    assert_int_equal(nf_model_get_params(nf_guide_training_model(alone), a), NF_OK);
    assert_int_equal(nf_model_get_params(nf_guide_training_model(helped), b), NF_OK);
    print_message("helpers: %d passes, %lu of %d tasks run by the two helpers\n", passes,
                  atomic_load(&h.helped), passes * 4 * 16);
    assert_true(atomic_load(&h.helped) > 0);
    assert_memory_equal(a, b, P * sizeof *a);
    free(a);
    free(b);
    nf_guide_destroy(alone);
    nf_guide_destroy(helped);
    free(s);
}

/* ---- 2. A bare model trained while points are prepared ------------------------------------ */

#define POINTS 4000

typedef struct bare {
    nf_model *m;
    nf_context ctx[SAMPLES];
    float dir[3 * SAMPLES], weight[SAMPLES];
    nf_shading_point *points;
    int *which;
    atomic_int stop;
    size_t prepared;
} bare;

static void *bare_trainer(void *arg)
{
    bare *b = arg;
    for (int i = 0; i < 300; ++i)
        nf_train_step(b->m, 64, b->ctx + (i % 8) * 64, b->dir + 3 * (i % 8) * 64,
                      b->weight + (i % 8) * 64, NULL);
    atomic_store(&b->stop, 1);
    return NULL;
}

/* Prepares points until training has ended, keeping the last POINTS (a ring), so that the
 * points prepared during the last steps are among those checked. */
static void *bare_preparer(void *arg)
{
    bare *b = arg;
    size_t n = 0, after = 0;
    while (after < 16) {
        if (atomic_load(&b->stop))
            after++;
        int k = (int)(n % SAMPLES);
        if (nf_point_prepare(b->m, &b->ctx[k], NULL, &b->points[n % POINTS]) == NF_OK) {
            b->which[n % POINTS] = k;
            n++;
        }
    }
    b->prepared = n < POINTS ? n : POINTS;
    return NULL;
}

static void test_bare_model_misuse_detected(void **state)
{
    (void)state;
    if (NF_UNDER_TSAN) {
        print_message("skipped under ThreadSanitizer: this test races on purpose\n");
        skip();
    }
    bare *b = calloc(1, sizeof *b);
    assert_non_null(b);
    b->points = malloc(POINTS * sizeof *b->points);
    b->which = malloc(POINTS * sizeof *b->which);
    assert_non_null(b->points);
    assert_non_null(b->which);
    b->m = nft_make_model(NF_PRESET_SMALL, NF_PRIOR_COSINE);
    assert_int_equal(nf_model_set_learning_rate(b->m, 2e-2f), NF_OK);
    shared *tmp = new_shared(17);
    memcpy(b->ctx, tmp->ctx, sizeof b->ctx);
    memcpy(b->dir, tmp->dir, sizeof b->dir);
    memcpy(b->weight, tmp->weight, sizeof b->weight);
    free(tmp);

    pthread_t t1, t2;
    assert_int_equal(pthread_create(&t2, NULL, bare_preparer, b), 0);
    assert_int_equal(pthread_create(&t1, NULL, bare_trainer, b), 0);
    pthread_join(t1, NULL);
    pthread_join(t2, NULL);
    assert_int_equal(nf_model_step_count(b->m), 300);

    /* The points prepared after the last step (up to 16) are accepted; every other one is
     * stale. */
    size_t accepted = 0, stale = 0, wrong = 0;
    for (size_t i = 0; i < b->prepared; ++i) {
        const float *d = b->dir + 3 * (size_t)b->which[i];
        float p_point, p_batch;
        nf_status st = nf_point_pdf(b->m, &b->points[i], 1, d, &p_point);
        if (st == NF_ERROR_STALE) {
            stale++;
            continue;
        }
        assert_int_equal(st, NF_OK);
        accepted++;
        /* against a point prepared now, on the final parameters: the same path, the same bits */
        nf_shading_point fresh;
        assert_int_equal(nf_point_prepare(b->m, &b->ctx[b->which[i]], NULL, &fresh), NF_OK);
        assert_int_equal(nf_point_pdf(b->m, &fresh, 1, d, &p_batch), NF_OK);
        wrong += memcmp(&p_point, &p_batch, sizeof p_point) != 0;
    }
    print_message("bare model: %zu points prepared, %zu stale after training, %zu accepted, "
                  "%zu of those wrong\n",
                  b->prepared, stale, accepted, wrong);
    assert_true(stale > 0); /* the test saw training happen under it */
    assert_true(accepted > 0); /* those prepared after the last step */
    assert_int_equal(wrong, 0);
    nf_model_destroy(b->m);
    free(b->points);
    free(b->which);
    free(b);
}

NFT_TEST_MAIN(
    NFT_WITH_MODEL(test_guide_train_while_sampling),
    NFT_WITH_MODEL(test_guide_helped_by_render_threads),
    cmocka_unit_test(test_bare_model_misuse_detected),
)
