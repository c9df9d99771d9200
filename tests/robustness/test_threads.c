/*
 * test_threads.c - the const entry points are safe and deterministic under concurrency
 * (model.h: "functions taking a const nf_model * may run concurrently on one model").
 *
 * Several threads work on disjoint slices of one batch, all released at once by a barrier,
 * for many rounds; every result must be bit-identical to a single-threaded run. Shading points
 * (point.h: "any number of threads may sample one prepared point at once") are shared: all
 * threads sample and evaluate the same prepared points at once, while nf_sample / nf_pdf and
 * nf_point_prepare of private points run beside them. Also the error message is thread-local
 * (status.h).
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
#include "gradient.h"
#include "point_batch.h"
#include "shading_point.h"

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
    assert_int_equal(nft_randomize_params(m, 1.0f, 3000u + (uint64_t)prior), NF_OK);
    const size_t pc = nf_model_param_count(m);
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
    nft_snapshot before = nft_snapshot_of(m);

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

/* ---- shared shading points ------------------------------------------------------------------- */

#define POINTS 32     /* prepared points, shared by every thread                */
#define POINT_DIRS 16 /* directions per point and call                          */
#define POINT_ROUNDS 6

/* What one thread computes in one round: per point, POINT_DIRS samples (dir, pdf) and
 * densities through nf_point_sample / nf_point_pdf, then one direction per point through
 * nf_point_sample_batch / nf_point_pdf_batch. */
enum {
    PR_DIR = 0,
    PR_PDF = PR_DIR + 3 * POINTS * POINT_DIRS,
    PR_EVAL = PR_PDF + POINTS * POINT_DIRS,
    PR_BDIR = PR_EVAL + POINTS * POINT_DIRS,
    PR_BPDF = PR_BDIR + 3 * POINTS,
    PR_BEVAL = PR_BPDF + POINTS,
    PR_FLOATS = PR_BEVAL + POINTS
};

typedef struct point_shared {
    const nf_model *model;
    const nf_shading_point *points; /* POINTS, prepared once, read by every thread        */
    const nf_context *ctx;          /* their contexts                                      */
    const float *u;                 /* 2 * POINTS * POINT_DIRS                              */
    const float *dir_in;            /* 3 * POINTS * POINT_DIRS                              */
    const float *ref;               /* PR_FLOATS, the single-threaded results              */
    const float *batch_ref;         /* nf_sample dir (3 POINTS), pdf, nf_pdf (POINTS each) */
    float *out;                     /* THREADS * POINT_ROUNDS * PR_FLOATS                  */
    pthread_barrier_t barrier;
    nf_status status[THREADS];
    int mismatch[THREADS]; /* side work that differed from the reference */
} point_shared;

typedef struct point_worker {
    point_shared *s;
    int index;
} point_worker;

/* One round of the shared work into out (PR_FLOATS floats). */
static nf_status point_round(const point_shared *s, float *out)
{
    nf_status st = NF_OK;
    for (int p = 0; p < POINTS && st == NF_OK; ++p) {
        size_t o = (size_t)p * POINT_DIRS;
        st = nf_point_sample(s->model, &s->points[p], POINT_DIRS, s->u + 2 * o,
                             out + PR_DIR + 3 * o, out + PR_PDF + o);
        if (st == NF_OK)
            st = nf_point_pdf(s->model, &s->points[p], POINT_DIRS, s->dir_in + 3 * o,
                              out + PR_EVAL + o);
    }
    /* One direction per point: the first u pair and direction of each point. */
    float u1[2 * POINTS], d1[3 * POINTS];
    for (int p = 0; p < POINTS; ++p) {
        memcpy(u1 + 2 * p, s->u + 2 * (size_t)p * POINT_DIRS, 2 * sizeof(float));
        memcpy(d1 + 3 * p, s->dir_in + 3 * (size_t)p * POINT_DIRS, 3 * sizeof(float));
    }
    if (st == NF_OK)
        st = nf_point_sample_batch(s->model, POINTS, s->points, u1, out + PR_BDIR, out + PR_BPDF);
    if (st == NF_OK)
        st = nf_point_pdf_batch(s->model, POINTS, s->points, d1, out + PR_BEVAL);
    return st;
}

/* Beside the shared points: thread 1 runs the batch calls on the points' contexts, thread 2
 * prepares points of its own; both check their results against the references. */
static int side_work(const point_shared *s, int index)
{
    float u1[2 * POINTS], d1[3 * POINTS], dir[3 * POINTS], pdf[POINTS], eval[POINTS];
    for (int p = 0; p < POINTS; ++p) {
        memcpy(u1 + 2 * p, s->u + 2 * (size_t)p * POINT_DIRS, 2 * sizeof(float));
        memcpy(d1 + 3 * p, s->dir_in + 3 * (size_t)p * POINT_DIRS, 3 * sizeof(float));
    }
    if (index == 1) {
        if (nf_sample(s->model, POINTS, s->ctx, u1, dir, pdf) != NF_OK ||
            nf_pdf(s->model, POINTS, s->ctx, d1, eval) != NF_OK)
            return 1;
    } else {
        for (int p = 0; p < POINTS; ++p) {
            nf_shading_point own;
            if (nf_point_prepare(s->model, &s->ctx[p], NULL, &own) != NF_OK ||
                nf_point_sample(s->model, &own, 1, u1 + 2 * p, dir + 3 * p, pdf + p) != NF_OK ||
                nf_point_pdf(s->model, &own, 1, d1 + 3 * p, eval + p) != NF_OK)
                return 1;
        }
    }
    /* Batch calls against their own single-threaded results: the shading points agree with
     * them to the bit or, for the presets' AVX-512 vector path, within test_point.c's bound. */
    const float *want_dir = index == 1 ? s->batch_ref : s->ref + PR_BDIR;
    const float *want_pdf = index == 1 ? s->batch_ref + 3 * POINTS : s->ref + PR_BPDF;
    const float *want_eval = index == 1 ? s->batch_ref + 4 * POINTS : s->ref + PR_BEVAL;
    return memcmp(dir, want_dir, sizeof dir) != 0 || memcmp(pdf, want_pdf, sizeof pdf) != 0 ||
           memcmp(eval, want_eval, sizeof eval) != 0;
}

static void *point_work(void *arg)
{
    point_worker *w = arg;
    point_shared *s = w->s;
    nf_status st = NF_OK;
    for (int round = 0; round < POINT_ROUNDS; ++round) {
        pthread_barrier_wait(&s->barrier);
        if (st != NF_OK)
            continue;
        float *out = s->out + ((size_t)w->index * POINT_ROUNDS + (size_t)round) * PR_FLOATS;
        /* Threads 1 and 2 do their side work first in odd rounds, last in even ones, so it
         * overlaps the others' shared work either way. */
        if ((w->index == 1 || w->index == 2) && round % 2 == 1)
            s->mismatch[w->index] += side_work(s, w->index);
        st = point_round(s, out);
        if ((w->index == 1 || w->index == 2) && round % 2 == 0)
            s->mismatch[w->index] += side_work(s, w->index);
    }
    s->status[w->index] = st;
    return NULL;
}

static void check_shared_points(nf_model *m, const char *what)
{
    nf_context ctx[POINTS];
    static nf_shading_point points[POINTS];
    const size_t dirs = (size_t)POINTS * POINT_DIRS;
    float *u = malloc(2 * dirs * sizeof *u), *dir_in = malloc(3 * dirs * sizeof *dir_in);
    float *ref = malloc(PR_FLOATS * sizeof *ref);
    float *out = calloc((size_t)THREADS * POINT_ROUNDS * PR_FLOATS, sizeof *out);
    assert_true(u && dir_in && ref && out);
    nft_rng r;
    nft_rng_seed(&r, 6000u, 3u);
    for (int p = 0; p < POINTS; ++p) {
        nft_random_context(&r, &ctx[p]);
        assert_int_equal(nf_point_prepare(m, &ctx[p], NULL, &points[p]), NF_OK);
    }
    for (size_t i = 0; i < dirs; ++i) {
        u[2 * i] = nft_rng_float(&r);
        u[2 * i + 1] = nft_rng_float(&r);
        nft_random_unit_vector(&r, dir_in + 3 * i);
    }
    point_shared s;
    memset(&s, 0, sizeof s);
    s.model = m;
    s.points = points;
    s.ctx = ctx;
    s.u = u;
    s.dir_in = dir_in;
    s.ref = ref;
    s.out = out;
    /* The single-threaded reference, which must itself be meaningful. */
    assert_int_equal(point_round(&s, ref), NF_OK);
    for (size_t i = 0; i < dirs; ++i)
        assert_true(isfinite(ref[PR_PDF + i]) && ref[PR_PDF + i] > 0.0f &&
                    isfinite(ref[PR_EVAL + i]) && ref[PR_EVAL + i] > 0.0f);
    /* ... and the batch calls' single-threaded results, which side work compares against. */
    static float batch_ref[5 * POINTS];
    {
        float u1[2 * POINTS], d1[3 * POINTS];
        for (int p = 0; p < POINTS; ++p) {
            memcpy(u1 + 2 * p, u + 2 * (size_t)p * POINT_DIRS, 2 * sizeof(float));
            memcpy(d1 + 3 * p, dir_in + 3 * (size_t)p * POINT_DIRS, 3 * sizeof(float));
        }
        assert_int_equal(nf_sample(m, POINTS, ctx, u1, batch_ref, batch_ref + 3 * POINTS), NF_OK);
        assert_int_equal(nf_pdf(m, POINTS, ctx, d1, batch_ref + 4 * POINTS), NF_OK);
    }
    s.batch_ref = batch_ref;
    assert_int_equal(side_work(&s, 1), 0);
    assert_int_equal(side_work(&s, 2), 0);

    pthread_t t[THREADS];
    point_worker w[THREADS];
    assert_int_equal(pthread_barrier_init(&s.barrier, NULL, THREADS), 0);
    for (int i = 0; i < THREADS; ++i) {
        w[i].s = &s;
        w[i].index = i;
        s.status[i] = NF_ERROR_NUMERIC;
        assert_int_equal(pthread_create(&t[i], NULL, point_work, &w[i]), 0);
    }
    for (int i = 0; i < THREADS; ++i)
        assert_int_equal(pthread_join(t[i], NULL), 0);
    pthread_barrier_destroy(&s.barrier);
    for (int i = 0; i < THREADS; ++i) {
        if (s.status[i] != NF_OK)
            fail_msg("%s: thread %d: %s", what, i, nf_status_string(s.status[i]));
        if (s.mismatch[i])
            fail_msg("%s: thread %d: side work differed from the reference", what, i);
        for (int round = 0; round < POINT_ROUNDS; ++round) {
            const float *o = out + ((size_t)i * POINT_ROUNDS + (size_t)round) * PR_FLOATS;
            if (memcmp(o, ref, PR_FLOATS * sizeof *ref) != 0)
                fail_msg("%s: thread %d, round %d differs from the single-threaded run", what,
                         i, round);
        }
    }
    free(u);
    free(dir_in);
    free(ref);
    free(out);
}

static void test_concurrent_shared_points(void **state)
{
    (void)state;
    /* The custom prior's callbacks run on the worker threads too. */
    nf_model *m = nft_make_model(NF_PRESET_SMALL, NF_PRIOR_CUSTOM);
    assert_int_equal(nft_randomize_params(m, 1.0f, 2100u), NF_OK);
    check_shared_points(m, "small custom");
    nf_model_destroy(m);
    /* Too large for the point's cache (8 x 64 > NF_SHADING_POINT_CACHE_FLOATS): every call
     * recomputes the context's share on its own stack. */
    nf_config cfg = nft_config(NF_PRESET_SMALL, NF_PRIOR_COSINE);
    cfg.coupling_layers = 8;
    cfg.hidden_width = 64;
    assert_int_equal(nf_model_create(&cfg, &m), NF_OK);
    assert_int_equal(nft_randomize_params(m, 0.3f, 2101u), NF_OK);
    check_shared_points(m, "8 x 64 cosine");
    nf_model_destroy(m);
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

NFT_TEST_MAIN(
    cmocka_unit_test(test_concurrent_sample_pdf),
    cmocka_unit_test(test_concurrent_loss_gradient),
    cmocka_unit_test(test_concurrent_shared_points),
    cmocka_unit_test(test_error_message_is_thread_local),
)
