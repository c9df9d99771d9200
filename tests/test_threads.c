/*
 * test_threads.c - the const entry points are safe and deterministic under concurrency
 * (model.h: "functions taking a const nf_model * may run concurrently on one model").
 *
 * Several threads work on disjoint slices of one batch, all released at once by a barrier,
 * for many rounds; every result must be bit-identical to a single-threaded run. Also the
 * error message is thread-local (status.h).
 */
#define _POSIX_C_SOURCE 200809L

#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <nisflow/nisflow.h>

#include "nf_test_support.h"

#define THREADS 4
#define BATCH 1024 /* per round, split into THREADS slices of different sizes */
#define ROUNDS 10

typedef struct shared {
    const nf_model *model;
    const nf_context *ctx;
    const float *u;
    const float *dir_in; /* directions for nf_pdf and training */
    const float *weight;
    float *dir_out;      /* nf_sample directions, per round */
    float *pdf_sample;   /* nf_sample pdfs, per round      */
    float *pdf_eval;     /* nf_pdf values, per round       */
    float *grad;         /* THREADS gradient buffers       */
    float *loss;         /* THREADS losses                 */
    size_t param_count;
    size_t begin[THREADS + 1]; /* slice boundaries         */
    pthread_barrier_t barrier;
    int mode;                  /* 0: sample + pdf, 1: loss gradient */
    nf_status status[THREADS];
} shared;

typedef struct worker {
    shared *s;
    int index;
} worker;

static void *work(void *arg)
{
    worker *w = arg;
    shared *s = w->s;
    const size_t b = s->begin[w->index], n = s->begin[w->index + 1] - b;
    nf_status st = NF_OK;
    for (int round = 0; round < ROUNDS; ++round) {
        /* Every thread reaches every barrier, even after a failure, so none can hang. */
        pthread_barrier_wait(&s->barrier);
        if (st != NF_OK)
            continue;
        const size_t o = (size_t)round * BATCH + b; /* this round's slice */
        if (s->mode == 0) {
            st = nf_sample(s->model, n, s->ctx + o, s->u + 2u * o, s->dir_out + 3u * o,
                           s->pdf_sample + o);
            if (st == NF_OK)
                st = nf_pdf(s->model, n, s->ctx + o, s->dir_in + 3u * o, s->pdf_eval + o);
        } else {
            st = nf_loss_gradient(s->model, n, s->ctx + o, s->dir_in + 3u * o, s->weight + o,
                                  &s->loss[w->index],
                                  s->grad + (size_t)w->index * s->param_count);
        }
    }
    s->status[w->index] = st;
    return NULL;
}

/* Runs `work` on THREADS threads; asserts every call succeeded. */
static void run_threads(shared *s)
{
    pthread_t t[THREADS];
    worker w[THREADS];
    assert_int_equal(pthread_barrier_init(&s->barrier, NULL, THREADS), 0);
    for (int i = 0; i < THREADS; ++i) {
        w[i].s = s;
        w[i].index = i;
        s->status[i] = NF_ERROR_NUMERIC;
        assert_int_equal(pthread_create(&t[i], NULL, work, &w[i]), 0);
    }
    for (int i = 0; i < THREADS; ++i)
        assert_int_equal(pthread_join(t[i], NULL), 0);
    pthread_barrier_destroy(&s->barrier);
    for (int i = 0; i < THREADS; ++i)
        if (s->status[i] != NF_OK)
            fail_msg("thread %d: %s", i, nf_status_string(s->status[i]));
}

/* Batch data for ROUNDS rounds: random contexts, u, directions and weights. */
typedef struct batch {
    nf_context *ctx;
    float *u, *dir, *weight;
} batch;

static void make_batch(batch *b, uint64_t seed)
{
    const size_t total = (size_t)ROUNDS * BATCH;
    b->ctx = malloc(total * sizeof *b->ctx);
    b->u = malloc(2u * total * sizeof *b->u);
    b->dir = malloc(3u * total * sizeof *b->dir);
    b->weight = malloc(total * sizeof *b->weight);
    assert_non_null(b->ctx);
    assert_non_null(b->u);
    assert_non_null(b->dir);
    assert_non_null(b->weight);
    nft_rng r;
    nft_rng_seed(&r, seed, 9u);
    for (size_t i = 0; i < total; ++i) {
        nft_random_context(&r, &b->ctx[i]);
        b->u[2 * i] = nft_rng_float(&r);
        b->u[2 * i + 1] = nft_rng_float(&r);
        nft_random_unit_vector(&r, b->dir + 3 * i);
        b->weight[i] = (i % 5 == 0) ? 0.0f : 4.0f * nft_rng_float(&r);
    }
}

static void free_batch(batch *b)
{
    free(b->ctx);
    free(b->u);
    free(b->dir);
    free(b->weight);
}

/* Uneven slices, so the threads' batches differ in length. */
static void make_slices(shared *s)
{
    const size_t cut[THREADS + 1] = {0, BATCH / 8, BATCH / 2, BATCH / 2 + 1, BATCH};
    memcpy(s->begin, cut, sizeof cut);
}

static void check_sample_pdf(nf_prior_kind prior, nf_preset preset)
{
    const size_t total = (size_t)ROUNDS * BATCH;
    nf_model *m = nft_make_model(preset, prior);
    assert_non_null(m);
    assert_int_equal(nft_randomize_params(m, 1.0f, 2000u + (uint64_t)prior), NF_OK);
    batch b;
    make_batch(&b, 4000u + (uint64_t)prior);
    float *dir_ref = malloc(3u * total * sizeof *dir_ref);
    float *pdf_s_ref = malloc(total * sizeof *pdf_s_ref);
    float *pdf_e_ref = malloc(total * sizeof *pdf_e_ref);
    float *dir = calloc(3u * total, sizeof *dir);
    float *pdf_s = calloc(total, sizeof *pdf_s);
    float *pdf_e = calloc(total, sizeof *pdf_e);
    assert_true(dir_ref && pdf_s_ref && pdf_e_ref && dir && pdf_s && pdf_e);

    /* Single-threaded reference, one whole batch per round. */
    for (size_t round = 0; round < ROUNDS; ++round) {
        size_t o = round * BATCH;
        assert_int_equal(nf_sample(m, BATCH, b.ctx + o, b.u + 2 * o, dir_ref + 3 * o,
                                   pdf_s_ref + o),
                         NF_OK);
        assert_int_equal(nf_pdf(m, BATCH, b.ctx + o, b.dir + 3 * o, pdf_e_ref + o), NF_OK);
    }

    shared s;
    memset(&s, 0, sizeof s);
    s.model = m;
    s.ctx = b.ctx;
    s.u = b.u;
    s.dir_in = b.dir;
    s.dir_out = dir;
    s.pdf_sample = pdf_s;
    s.pdf_eval = pdf_e;
    s.mode = 0;
    make_slices(&s);
    run_threads(&s);

    assert_memory_equal(dir, dir_ref, 3u * total * sizeof *dir);
    assert_memory_equal(pdf_s, pdf_s_ref, total * sizeof *pdf_s);
    assert_memory_equal(pdf_e, pdf_e_ref, total * sizeof *pdf_e);
    /* The reference itself is meaningful: finite, positive densities. */
    for (size_t i = 0; i < total; ++i)
        assert_true(isfinite(pdf_e_ref[i]) && pdf_e_ref[i] > 0.0f);

    free(dir_ref);
    free(pdf_s_ref);
    free(pdf_e_ref);
    free(dir);
    free(pdf_s);
    free(pdf_e);
    free_batch(&b);
    nf_model_destroy(m);
}

static void test_concurrent_sample_pdf(void **state)
{
    (void)state;
    check_sample_pdf(NF_PRIOR_COSINE, NF_PRESET_SMALL);
    /* The custom prior's callbacks run on the worker threads too. */
    check_sample_pdf(NF_PRIOR_CUSTOM, NF_PRESET_SMALL);
    check_sample_pdf(NF_PRIOR_UNIFORM_DIRECTION, NF_PRESET_LARGE);
}

static void check_loss_gradient(nf_prior_kind prior)
{
    nf_model *m = nft_make_model(NF_PRESET_SMALL, prior);
    assert_non_null(m);
    assert_int_equal(nft_randomize_params(m, 1.0f, 3000u + (uint64_t)prior), NF_OK);
    const size_t pc = nf_param_count(m);
    assert_true(pc > 0);
    batch b;
    make_batch(&b, 5000u + (uint64_t)prior);
    shared s;
    memset(&s, 0, sizeof s);
    s.model = m;
    s.ctx = b.ctx;
    s.dir_in = b.dir;
    s.weight = b.weight;
    s.param_count = pc;
    s.grad = calloc(THREADS * pc, sizeof *s.grad);
    s.loss = calloc(THREADS, sizeof *s.loss);
    s.mode = 1;
    make_slices(&s);
    float *ref = malloc(pc * sizeof *ref);
    assert_true(s.grad && s.loss && ref);
    nft_snapshot before;
    assert_int_equal(nft_snapshot_take(m, &before), 0);

    run_threads(&s);

    /* Each thread's buffer holds its slice of the last round; recompute it alone. */
    const size_t last = (size_t)(ROUNDS - 1) * BATCH;
    for (int t = 0; t < THREADS; ++t) {
        size_t o = last + s.begin[t], n = s.begin[t + 1] - s.begin[t];
        float loss_ref = -1.0f;
        assert_int_equal(nf_loss_gradient(m, n, b.ctx + o, b.dir + 3 * o, b.weight + o,
                                          &loss_ref, ref),
                         NF_OK);
        assert_memory_equal(s.grad + (size_t)t * pc, ref, pc * sizeof *ref);
        assert_memory_equal(&s.loss[t], &loss_ref, sizeof loss_ref);
        assert_true(isfinite(loss_ref));
        /* A non-trivial gradient (the slices carry positive weights). */
        size_t nonzero = 0;
        for (size_t i = 0; i < pc; ++i)
            nonzero += ref[i] != 0.0f;
        assert_true(nonzero > pc / 50);
    }
    /* The const calls left the model as it was. */
    assert_true(nft_snapshot_equal(m, &before));
    nft_snapshot_free(&before);
    free(ref);
    free(s.grad);
    free(s.loss);
    free_batch(&b);
    nf_model_destroy(m);
}

static void test_concurrent_loss_gradient(void **state)
{
    (void)state;
    check_loss_gradient(NF_PRIOR_COSINE);
    check_loss_gradient(NF_PRIOR_CUSTOM);
}

/* ---- thread-local error messages ------------------------------------------------------------- */

typedef struct message_check {
    pthread_barrier_t *barrier;
    int which;
    char first[256];  /* the message right after this thread's failure        */
    char second[256]; /* the message after the other thread's failure          */
    char initial[256];
} message_check;

static void *message_thread(void *arg)
{
    message_check *c = arg;
    snprintf(c->initial, sizeof c->initial, "%s", nf_last_error_message());
    /* Thread 0 fails first, then thread 1; then thread 0 reads its message again. */
    if (c->which == 0) {
        nf_model *out = NULL;
        (void)nf_model_create(NULL, &out);
        snprintf(c->first, sizeof c->first, "%s", nf_last_error_message());
    }
    pthread_barrier_wait(c->barrier);
    if (c->which == 1) {
        float p = 0.0f, dir[3] = {NAN, 0.0f, 1.0f};
        nf_context ctx = nft_context(0.5f, 0.5f, 0.5f, 0, 0, 1, 0, 0, 1);
        (void)nf_pdf(NULL, 1, &ctx, dir, &p);
        snprintf(c->first, sizeof c->first, "%s", nf_last_error_message());
    }
    pthread_barrier_wait(c->barrier);
    snprintf(c->second, sizeof c->second, "%s", nf_last_error_message());
    return NULL;
}

static void test_error_message_is_thread_local(void **state)
{
    (void)state;
    pthread_barrier_t barrier;
    assert_int_equal(pthread_barrier_init(&barrier, NULL, 2), 0);
    message_check c[2];
    pthread_t t[2];
    memset(c, 0, sizeof c);
    for (int i = 0; i < 2; ++i) {
        c[i].barrier = &barrier;
        c[i].which = i;
        assert_int_equal(pthread_create(&t[i], NULL, message_thread, &c[i]), 0);
    }
    for (int i = 0; i < 2; ++i)
        assert_int_equal(pthread_join(t[i], NULL), 0);
    pthread_barrier_destroy(&barrier);
    /* Fresh threads start with "" (status.h). */
    assert_string_equal(c[0].initial, "");
    assert_string_equal(c[1].initial, "");
    /* Both failures were described, differently (different functions and causes). */
    assert_true(strlen(c[0].first) > 0);
    assert_true(strlen(c[1].first) > 0);
    assert_string_not_equal(c[0].first, c[1].first);
    /* Thread 1's failure did not overwrite thread 0's message. */
    assert_string_equal(c[0].second, c[0].first);
    assert_string_equal(c[1].second, c[1].first);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_concurrent_sample_pdf),
        cmocka_unit_test(test_concurrent_loss_gradient),
        cmocka_unit_test(test_error_message_is_thread_local),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
