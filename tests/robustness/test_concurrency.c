/*
 * test_concurrency.c - the thread-safe entry points that test_threads.c does not cover, run
 * concurrently (model.h, io.h, train.h): on one shared const model, nf_model_clone,
 * nf_model_serialize, nf_model_save (whose temporary buffer comes from an allocator shared by
 * every thread), nf_model_get_config, nf_model_get_params, nf_model_prior_pdf, nf_sample and nf_pdf; and, on
 * models of their own, nf_model_create (kernel dispatch), nf_model_deserialize, nf_model_load,
 * nf_train_step, nf_model_set_params and nf_model_destroy, plus failing calls (thread-local error
 * messages). Every result must be bit-identical to the single-threaded reference.
 *
 * It is meant for the ThreadSanitizer build of .ci/robustness, which fails on any data race
 * report; in ordinary builds it checks the results.
 */
#define _POSIX_C_SOURCE 200809L /* pthread_barrier_t, getpid */

#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <nisflow/nisflow.h>

#include "nf_test_support.h"

#define THREADS 4
#define ROUNDS 4
#define N 64

/* A thread-safe counting allocator: model.h requires one when models sharing it are saved
 * from several threads. */
typedef struct counting {
    atomic_long live;
    atomic_long calls;
} counting;

static void *counting_alloc(void *user, size_t size)
{
    counting *c = user;
    atomic_fetch_add(&c->calls, 1);
    void *p = malloc(size);
    if (p)
        atomic_fetch_add(&c->live, 1);
    return p;
}

static void counting_free(void *user, void *ptr)
{
    counting *c = user;
    atomic_fetch_sub(&c->live, 1);
    free(ptr);
}

typedef struct shared {
    const nf_model *model;      /* the shared const model                      */
    const unsigned char *bytes; /* its serialized bytes (reference)            */
    size_t size;
    counting *alloc;
    nf_context ctx[N];
    float u[2 * N], dir[3 * N], weight[N];
    float ref_dir[3 * N], ref_sample_pdf[N], ref_pdf[N], ref_prior[N];
    float *ref_params;
    float ref_loss[THREADS];    /* each thread's own model after its step      */
    pthread_barrier_t barrier;
} shared;

typedef struct worker {
    shared *s;
    int index;
    char failure[256]; /* the first failed check, empty if none */
} worker;

#define CHECK(w, cond)                                                                          \
    do {                                                                                        \
        if (!(cond) && (w)->failure[0] == '\0')                                                 \
            snprintf((w)->failure, sizeof (w)->failure, "thread %d, line %d: %s", (w)->index,   \
                     __LINE__, #cond);                                                          \
    } while (0)

static int same_bytes(const nf_model *m, const unsigned char *ref, size_t size)
{
    size_t got = 0;
    if (nf_model_serialize(m, NULL, 0, &got) != NF_OK || got != size)
        return 0;
    unsigned char *buf = malloc(size);
    int equal = buf && nf_model_serialize(m, buf, size, &got) == NF_OK && got == size &&
                memcmp(buf, ref, size) == 0;
    free(buf);
    return equal;
}

/* A model of the thread's own, created, trained one step and compared with the reference
 * loss that the same steps gave single-threaded. */
static float own_model_loss(const shared *s, int index, counting *alloc, nf_status *st)
{
    nf_config cfg = nft_config(NF_PRESET_SMALL, (nf_prior_kind)(index % 4));
    cfg.seed = 100u + (uint64_t)index;
    cfg.allocator.alloc = counting_alloc;
    cfg.allocator.free = counting_free;
    cfg.allocator.user = alloc;
    nf_model *m = NULL;
    float loss = NAN;
    *st = nf_model_create(&cfg, &m);
    if (*st != NF_OK)
        return loss;
    *st = nf_train_step(m, N, s->ctx, s->dir, s->weight, &loss);
    nf_model_destroy(m);
    return loss;
}

static void *work(void *arg)
{
    worker *w = arg;
    shared *s = w->s;
    const size_t count = nf_model_param_count(s->model);
    float *params = malloc(count * sizeof *params);
    CHECK(w, params != NULL);
    char path[128];
    snprintf(path, sizeof path, "nf_test_concurrency_%ld_%d.nfm", (long)getpid(), w->index);
    for (int round = 0; round < ROUNDS && params; ++round) {
        pthread_barrier_wait(&s->barrier);
        nf_status st;
        /* clone of the shared model, through the shared allocator */
        nf_model *copy = NULL;
        CHECK(w, nf_model_clone(s->model, &copy) == NF_OK);
        CHECK(w, copy && same_bytes(copy, s->bytes, s->size));
        nf_model_destroy(copy);
        /* serialize, save (allocates), load, deserialize */
        CHECK(w, same_bytes(s->model, s->bytes, s->size));
        CHECK(w, nf_model_save(s->model, path) == NF_OK);
        nf_model *loaded = NULL;
        CHECK(w, nf_model_load(path, NULL, &loaded) == NF_OK);
        CHECK(w, loaded && same_bytes(loaded, s->bytes, s->size));
        nf_model_destroy(loaded);
        nf_model *back = NULL;
        CHECK(w, nf_model_deserialize(s->bytes, s->size, NULL, &back) == NF_OK);
        CHECK(w, back && same_bytes(back, s->bytes, s->size));
        /* write access to a model of its own while others read the shared one */
        if (back) {
            CHECK(w, nf_model_get_params(back, params) == NF_OK);
            params[0] += 1.0f;
            CHECK(w, nf_model_set_params(back, params) == NF_OK);
            CHECK(w, nf_train_step(back, N, s->ctx, s->dir, s->weight, NULL) == NF_OK);
            CHECK(w, nf_model_step_count(back) == nf_model_step_count(s->model) + 1u);
        }
        nf_model_destroy(back);
        /* accessors */
        nf_config cfg;
        CHECK(w, nf_model_get_config(s->model, &cfg) == NF_OK && cfg.allocator.user == s->alloc);
        CHECK(w, nf_model_get_params(s->model, params) == NF_OK);
        CHECK(w, memcmp(params, s->ref_params, count * sizeof *params) == 0);
        CHECK(w, nf_model_isa_name(s->model)[0] != '\0');
        /* the const hot path */
        float dir[3 * N], pdf[N];
        CHECK(w, nf_sample(s->model, N, s->ctx, s->u, dir, pdf) == NF_OK);
        CHECK(w, memcmp(dir, s->ref_dir, sizeof dir) == 0);
        CHECK(w, memcmp(pdf, s->ref_sample_pdf, sizeof pdf) == 0);
        CHECK(w, nf_pdf(s->model, N, s->ctx, s->dir, pdf) == NF_OK);
        CHECK(w, memcmp(pdf, s->ref_pdf, sizeof pdf) == 0);
        for (int i = 0; i < N; ++i) {
            float q = nft_prior_pdf(s->model, &s->ctx[i], s->dir + 3 * i);
            CHECK(w, memcmp(&q, &s->ref_prior[i], sizeof q) == 0);
        }
        /* a model of its own, created and trained concurrently with the others */
        float loss = own_model_loss(s, w->index, s->alloc, &st);
        CHECK(w, st == NF_OK && memcmp(&loss, &s->ref_loss[w->index], sizeof loss) == 0);
        /* a failing call: this thread's message, whatever the others do */
        nf_model *none = NULL;
        char expect[64];
        snprintf(expect, sizeof expect, "ctx[%d].normal", w->index);
        nf_context bad[THREADS];
        memcpy(bad, s->ctx, sizeof bad);
        bad[w->index].normal[0] = NAN;
        CHECK(w, nf_pdf(s->model, THREADS, bad, s->dir, pdf) == NF_ERROR_INVALID_ARGUMENT);
        CHECK(w, nf_model_clone(NULL, &none) == NF_ERROR_INVALID_ARGUMENT);
        CHECK(w, strstr(nf_last_error_message(), "nf_model_clone") != NULL);
        CHECK(w, nf_pdf(s->model, THREADS, bad, s->dir, pdf) == NF_ERROR_INVALID_ARGUMENT);
        pthread_barrier_wait(&s->barrier); /* all threads have failed once more */
        CHECK(w, strstr(nf_last_error_message(), expect) != NULL);
    }
    remove(path);
    free(params);
    return NULL;
}

static void test_concurrent_const_and_io(void **state)
{
    (void)state;
    static shared s;
    counting alloc;
    atomic_init(&alloc.live, 0);
    atomic_init(&alloc.calls, 0);
    nf_config cfg = nft_config(NF_PRESET_SMALL, NF_PRIOR_COSINE);
    cfg.allocator.alloc = counting_alloc;
    cfg.allocator.free = counting_free;
    cfg.allocator.user = &alloc;
    nf_model *m = nft_model_from(&cfg);
    assert_int_equal(nft_randomize_params(m, 0.3f, 1u), NF_OK);
    s.alloc = &alloc;
    nft_rng r;
    nft_rng_seed(&r, 2u, 3u);
    nft_random_batch(&r, N, s.ctx, s.u, s.dir, s.weight, 0.0f);
    assert_int_equal(nf_train_step(m, N, s.ctx, s.dir, s.weight, NULL), NF_OK);
    /* single-threaded references */
    assert_int_equal(nf_model_serialize(m, NULL, 0, &s.size), NF_OK);
    unsigned char *bytes = malloc(s.size);
    assert_non_null(bytes);
    assert_int_equal(nf_model_serialize(m, bytes, s.size, &s.size), NF_OK);
    s.bytes = bytes;
    s.ref_params = malloc(nf_model_param_count(m) * sizeof *s.ref_params);
    assert_non_null(s.ref_params);
    assert_int_equal(nf_model_get_params(m, s.ref_params), NF_OK);
    assert_int_equal(nf_sample(m, N, s.ctx, s.u, s.ref_dir, s.ref_sample_pdf), NF_OK);
    assert_int_equal(nf_pdf(m, N, s.ctx, s.dir, s.ref_pdf), NF_OK);
    for (int i = 0; i < N; ++i)
        s.ref_prior[i] = nft_prior_pdf(m, &s.ctx[i], s.dir + 3 * i);
    for (int t = 0; t < THREADS; ++t) {
        nf_status st;
        s.ref_loss[t] = own_model_loss(&s, t, &alloc, &st);
        assert_int_equal(st, NF_OK);
    }
    s.model = m;
    const long live_before = atomic_load(&alloc.live);
    assert_int_equal(live_before, 1);

    pthread_t threads[THREADS];
    static worker w[THREADS];
    assert_int_equal(pthread_barrier_init(&s.barrier, NULL, THREADS), 0);
    for (int t = 0; t < THREADS; ++t) {
        memset(&w[t], 0, sizeof w[t]);
        w[t].s = &s;
        w[t].index = t;
        assert_int_equal(pthread_create(&threads[t], NULL, work, &w[t]), 0);
    }
    for (int t = 0; t < THREADS; ++t)
        assert_int_equal(pthread_join(threads[t], NULL), 0);
    pthread_barrier_destroy(&s.barrier);
    for (int t = 0; t < THREADS; ++t)
        if (w[t].failure[0])
            fail_msg("%s", w[t].failure);
    /* The shared model is unchanged and every allocation through the shared allocator was
     * returned (saves, clones, the threads' own models). */
    assert_true(same_bytes(m, s.bytes, s.size));
    assert_int_equal(atomic_load(&alloc.live), live_before);
    assert_true(atomic_load(&alloc.calls) > THREADS * ROUNDS * 3);
    free(bytes);
    free(s.ref_params);
    nf_model_destroy(m);
    assert_int_equal(atomic_load(&alloc.live), 0);
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_concurrent_const_and_io),
)
