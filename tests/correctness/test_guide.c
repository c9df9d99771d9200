/*
 * test_guide.c - the guide of nisflow/guide.h: its configuration, the path policy at exact
 * points, the store, the schedule (clamp, held-out loss, patience), the exact sharded step
 * (same bits for any threads and any split over processes) and publication.
 */
#define _POSIX_C_SOURCE 200809L /* pthread barriers */

#include <math.h>
#include <pthread.h>
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "nf_test_support.h"
#include "guide_internal.h"
#include "internal.h"
#include "policy_atoms.h"
#include "shading_point.h"

/* ---- Helpers ------------------------------------------------------------------------------ */

/* Training samples of a lobe around +z at random positions, with heavy-tailed weights so
 * that the clamp has something to clamp. */
typedef struct samples {
    size_t n;
    nf_context *ctx;
    float *dir, *weight;
    uint64_t *key;
} samples;

static samples make_samples(size_t n, uint64_t seed)
{
    samples s = {n, malloc(n * sizeof(nf_context)), malloc(3 * n * sizeof(float)),
                 malloc(n * sizeof(float)), malloc(n * sizeof(uint64_t))};
    assert_non_null(s.ctx);
    assert_non_null(s.dir);
    assert_non_null(s.weight);
    assert_non_null(s.key);
    nft_rng r;
    nft_rng_seed(&r, seed, 7);
    const double mu[3] = {0.0, 0.0, 1.0};
    for (size_t i = 0; i < n; ++i) {
        nft_random_context(&r, &s.ctx[i]);
        nft_vmf_sample(&r, mu, 20.0, s.dir + 3 * i);
        float u = nft_rng_float(&r);
        /* a few zeros, a few bright ones, and a spread */
        s.weight[i] = u < 0.03f ? 0.0f : u > 0.97f ? 50.0f * u : 0.1f + u;
        s.key[i] = seed * 1000003u + i;
    }
    return s;
}

static void free_samples(samples *s)
{
    free(s->ctx);
    free(s->dir);
    free(s->weight);
    free(s->key);
}

static nf_guide *make_guide(const nf_model *m, nf_guide_config *gc)
{
    nf_guide *g = NULL;
    assert_int_equal(nf_guide_create(m, gc, &g), NF_OK);
    assert_non_null(g);
    return g;
}

static void params_of(nf_guide *g, float *out)
{
    assert_int_equal(nf_model_get_params(nf_guide_training_model(g), out), NF_OK);
}

/* A parallel-for on `threads` pthreads, tasks handed out through an atomic counter. */
typedef struct pool {
    int threads;
    size_t count;
    nf_task_fn task;
    void *data;
    size_t next;
    pthread_mutex_t lock;
} pool;

static void *pool_worker(void *arg)
{
    pool *p = arg;
    for (;;) {
        pthread_mutex_lock(&p->lock);
        size_t i = p->next++;
        pthread_mutex_unlock(&p->lock);
        if (i >= p->count)
            return NULL;
        p->task(p->data, i);
    }
}

static void pool_run(void *user, size_t count, nf_task_fn task, void *data)
{
    pool *p = user;
    pthread_t t[8];
    p->count = count;
    p->task = task;
    p->data = data;
    p->next = 0;
    pthread_mutex_init(&p->lock, NULL);
    for (int i = 0; i < p->threads; ++i)
        assert_int_equal(pthread_create(&t[i], NULL, pool_worker, p), 0);
    for (int i = 0; i < p->threads; ++i)
        pthread_join(t[i], NULL);
    pthread_mutex_destroy(&p->lock);
}

/* ---- Configuration ---------------------------------------------------------------------- */

static void test_config_checked(void **state)
{
    nf_model *m = *state;
    nf_guide *g = NULL;
    nf_guide_config gc;
    memset(&gc, 0, sizeof gc);
    assert_int_equal(nf_guide_create(m, &gc, &g), NF_ERROR_INVALID_ARGUMENT);
    assert_null(g);
    assert_non_null(strstr(nf_last_error_message(), "nf_guide_config_init"));

    nf_guide_config_init(&gc);
    gc.store_capacity = 0;
    assert_int_equal(nf_guide_create(m, &gc, &g), NF_ERROR_INVALID_ARGUMENT);
    /* The message names the field, the value and the range. */
    assert_non_null(strstr(nf_last_error_message(),
                           "gc->store_capacity = 0 is out of range: it must be in [1, 2^26"));
    nf_guide_config_init(&gc);
    gc.groups = 300;
    assert_int_equal(nf_guide_create(m, &gc, &g), NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "gc->groups = 300 is out of range: it must "
                                                     "be in [1, 256]"));
    nf_guide_config_init(&gc);
    gc.clamp_quantile = 1.0f;
    assert_int_equal(nf_guide_create(m, &gc, &g), NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "clamp_quantile"));
    nf_guide_config_init(&gc);
    gc.policy.mixture_prob = 1.0f;
    assert_int_equal(nf_guide_create(m, &gc, &g), NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "policy.mixture_prob"));
    nf_guide_config_init(&gc);
    gc.learning_rate = NAN;
    assert_int_equal(nf_guide_create(m, &gc, &g), NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "learning_rate"));
    assert_int_equal(nf_guide_create(NULL, NULL, &g), NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "model is NULL"));
    assert_int_equal(nf_guide_create(m, NULL, NULL), NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "out is NULL"));

    /* The defaults are the study's configuration (docs/equal-time.md). */
    nf_guide_config_init(&gc);
    assert_int_equal(gc.step_samples, 2048);
    assert_int_equal(gc.steps_per_pass, 64);
    assert_true(gc.clamp_quantile == 0.0f);
    assert_true(gc.train_fraction == 0.15f);
    assert_true(gc.policy.mixture_prob == 0.7f);
    assert_true(gc.policy.max_boost == 10.0f);
    assert_int_equal(gc.policy.light_mis_depth, 2);
    g = make_guide(m, NULL);
    assert_int_equal(nf_guide_get_config(g)->store_capacity, gc.store_capacity);
    nf_guide_destroy(g);
    nf_guide_destroy(NULL);
}

/* ---- The path policy ------------------------------------------------------------------- */

/* The guide's model configuration: the small preset with its bounds and sh_bands 0, and a
 * model made from it; NULL bounds keep the preset's. */
static void test_model_config(void **state)
{
    (void)state;
    const float lo[3] = {-2.0f, 0.5f, 3.0f}, hi[3] = {1.0f, 4.0f, 3.25f};
    nf_config cfg, preset;
    nf_guide_model_config_init(&cfg, lo, hi);
    nf_config_init(&preset, NF_PRESET_SMALL);
    assert_int_equal(cfg.sh_bands, 0);
    assert_int_equal(cfg.prior, preset.prior);
    assert_int_equal(cfg.hidden_width, preset.hidden_width);
    assert_int_equal(cfg.coupling_layers, preset.coupling_layers);
    assert_int_equal(cfg.spline_bins, preset.spline_bins);
    assert_memory_equal(cfg.bounds_min, lo, sizeof lo);
    assert_memory_equal(cfg.bounds_max, hi, sizeof hi);
    nf_model *m = nft_model_from(&cfg);
    nf_model_destroy(m);
    nf_guide_model_config_init(&cfg, NULL, hi);
    assert_memory_equal(cfg.bounds_min, preset.bounds_min, sizeof lo);
    assert_memory_equal(cfg.bounds_max, preset.bounds_max, sizeof hi);
    nf_guide_model_config_init(NULL, lo, hi); /* ignored */
}

static void test_policy_points(void **state)
{
    (void)state;
    nf_guide_policy p;
    nf_guide_policy_init(&p);
    /* The cap: g while boost / (1 - g) <= 10, then 1 - boost / 10, then 0 below 0.05. */
    assert_true(nf_guide_mixture_prob(&p, 1.0f) == 0.7f);
    assert_true(nf_guide_mixture_prob(&p, 3.0f) == 0.7f);
    assert_true(nf_guide_mixture_prob(&p, 5.0f) == 0.5f);
    assert_true(nf_guide_mixture_prob(&p, 9.6f) == 0.0f); /* 0.04 is below 0.05 */
    assert_true(nf_guide_mixture_prob(&p, NAN) == 0.0f);
    assert_true(nf_guide_mixture_prob(NULL, 1.0f) == 0.0f);
    p.max_boost = 0.0f; /* no cap */
    assert_true(nf_guide_mixture_prob(&p, 1000.0f) == 0.7f);
    nf_guide_policy_init(&p);

    /* The boost: p_bsdf / p_mix per vertex, 1 / (1 - g) for a delta lobe. */
    assert_true(nf_guide_boost(1.0f, 0.5f, 0.25f, 0.7f) == 2.0f);
    assert_true(fabsf(nf_guide_boost(1.0f, 0.0f, 0.0f, 0.75f) - 4.0f) < 1e-6f);
    assert_true(nf_guide_boost(3.0f, NAN, 1.0f, 0.7f) == 3.0f);

    /* Roulette: the larger of c and c / boost, at most 0.95. */
    assert_true(nf_guide_roulette_survival(&p, 0.5f, 1.0f) == 0.5f);
    assert_true(nf_guide_roulette_survival(&p, 0.2f, 0.5f) == 0.4f);  /* flow towards light */
    assert_true(nf_guide_roulette_survival(&p, 0.2f, 4.0f) == 0.2f);  /* not the quotient  */
    assert_true(nf_guide_roulette_survival(&p, 3.0f, 1.0f) == 0.95f);
    assert_true(nf_guide_roulette_survival(&p, NAN, 1.0f) == 0.0f);

    /* Light MIS by the flow up to depth 2. */
    assert_int_equal(nf_guide_light_mis_uses_flow(&p, 1), 1);
    assert_int_equal(nf_guide_light_mis_uses_flow(&p, 2), 1);
    assert_int_equal(nf_guide_light_mis_uses_flow(&p, 3), 0);
    p.light_mis_depth = 0;
    assert_int_equal(nf_guide_light_mis_uses_flow(&p, 30), 1);
}

/* ---- The store --------------------------------------------------------------------------- */

static void test_store_bounds(void **state)
{
    nf_model *m = *state;
    nf_guide_config gc = nft_guide_config(100, 32, 2);
    gc.clamp_quantile = 0.99f; /* off by default; this test asks for it */
    nf_guide *g = make_guide(m, &gc);
    samples s = make_samples(150, 3);
    size_t zeros = 0;
    for (size_t i = 0; i < s.n; ++i)
        zeros += s.weight[i] == 0.0f;
    assert_true(zeros > 0); /* the test needs some */

    /* A bad sample refuses the whole call: nothing is added. */
    float keep = s.weight[70];
    s.weight[70] = -1.0f;
    assert_int_equal(nf_guide_add_samples(g, s.n, s.key, s.ctx, s.dir, s.weight, NULL),
                     NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "weight[70]"));
    s.weight[70] = keep;
    /* n = 0 is a no-op whatever the pointers (an empty std::vector's data() may be NULL);
     * the guide itself must still be given. */
    assert_int_equal(nf_guide_add_samples(g, 0, NULL, NULL, NULL, NULL, NULL), NF_OK);
    assert_int_equal(nf_guide_add_samples(NULL, 0, NULL, NULL, NULL, NULL, NULL),
                     NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_guide_add_samples(g, s.n, s.key, NULL, s.dir, s.weight, NULL),
                     NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "ctx is NULL"));

    assert_int_equal(nf_guide_pending(g), 0);
    assert_int_equal(nf_guide_add_samples(g, s.n, s.key, s.ctx, s.dir, s.weight, NULL), NF_OK);
    /* Waiting for the next pass: the kept ones, at most the capacity. */
    assert_int_equal(nf_guide_pending(g), 100);
    assert_int_equal(nf_guide_pending(NULL), 0);
    nf_guide_pass_report rep;
    assert_int_equal(nf_guide_train_pass(g, NULL, NULL, &rep), NF_OK);
    assert_int_equal(nf_guide_pending(g), 0);
    nf_guide_stats st;
    assert_int_equal(nf_guide_get_stats(g, &st), NF_OK);
    /* Zero weights are skipped; beyond the capacity, samples are dropped and counted. */
    assert_int_equal(rep.new_samples, 100);
    assert_int_equal(st.dropped, s.n - zeros - 100);
    assert_int_equal(st.stored, 100);
    assert_int_equal(rep.steps, 2);
    assert_true(isfinite(rep.held_out_loss));
    assert_true(rep.clamp > 0.0f);
    free_samples(&s);
    nf_guide_destroy(g);
}

/* ---- Same bits for any threads and any order of adds ------------------------------------ */

static void train_two_passes(nf_guide *g, const samples *a, const samples *b, int reverse,
                             const nf_parallel *par)
{
    const samples *pass[2] = {a, b};
    for (int k = 0; k < 2; ++k) {
        const samples *s = pass[k];
        if (reverse) { /* added in reverse chunks, as threads might */
            for (size_t e = s->n; e > 0;) {
                size_t b0 = e >= 37 ? e - 37 : 0;
                assert_int_equal(nf_guide_add_samples(g, e - b0, s->key + b0, s->ctx + b0,
                                                      s->dir + 3 * b0, s->weight + b0, NULL),
                                 NF_OK);
                e = b0;
            }
        } else {
            assert_int_equal(nf_guide_add_samples(g, s->n, s->key, s->ctx, s->dir, s->weight, NULL),
                             NF_OK);
        }
        assert_int_equal(nf_guide_train_pass(g, par, NULL, NULL), NF_OK);
    }
}

static void test_same_bits_any_threads(void **state)
{
    nf_model *m = *state;
    nf_guide_config gc = nft_guide_config(4096, 512, 4);
    samples a = make_samples(1500, 11), b = make_samples(1200, 12);
    size_t P = nf_model_param_count(m);
    float *ref = malloc(P * sizeof *ref), *got = malloc(P * sizeof *got);
    float *start = malloc(P * sizeof *start);
    assert_non_null(ref);
    assert_non_null(got);
    assert_non_null(start);
    assert_int_equal(nf_model_get_params(m, start), NF_OK);

    nf_guide *g = make_guide(m, &gc);
    train_two_passes(g, &a, &b, 0, NULL);
    params_of(g, ref);
    assert_true(memcmp(ref, start, P * sizeof *ref) != 0); /* it trained */
    nf_guide_stats st;
    assert_int_equal(nf_guide_get_stats(g, &st), NF_OK);
    assert_int_equal(st.steps, 8);
    nf_guide_destroy(g);

    for (int threads = 1; threads <= 4; threads *= 2) {
        pool p = {.threads = threads};
        nf_parallel par = {pool_run, &p};
        g = make_guide(m, &gc);
        train_two_passes(g, &a, &b, 1, &par);
        params_of(g, got);
        assert_memory_equal(got, ref, P * sizeof *ref);
        nf_guide_destroy(g);
    }
    free_samples(&a);
    free_samples(&b);
    free(ref);
    free(got);
    free(start);
}

/* ---- Exact sums across processes ---------------------------------------------------------- */

/* Two "processes" (threads), each with its own guide, reduce through a barrier. */
typedef struct exchange {
    pthread_barrier_t barrier;
    double maxv[2][8];
    int64_t *sumv[2];
    size_t capacity;
} exchange;

typedef struct process {
    exchange *x;
    int rank;
    nf_guide *g;
    const samples *s;
    size_t begin, end;    /* this process's samples                        */
    size_t group_end[16]; /* its groups, relative to begin                  */
    size_t ngroups;
    float loss;
    nf_status st;
} process;

static nf_status exchange_max(void *user, double *v, size_t n)
{
    process *p = user;
    memcpy(p->x->maxv[p->rank], v, n * sizeof *v);
    pthread_barrier_wait(&p->x->barrier);
    for (size_t i = 0; i < n; ++i)
        v[i] = fmax(p->x->maxv[0][i], p->x->maxv[1][i]);
    pthread_barrier_wait(&p->x->barrier);
    return NF_OK;
}

static nf_status exchange_sum(void *user, int64_t *v, size_t n)
{
    process *p = user;
    if (n > p->x->capacity)
        return NF_ERROR_CAPACITY;
    memcpy(p->x->sumv[p->rank], v, n * sizeof *v);
    pthread_barrier_wait(&p->x->barrier);
    /* The other process adds in the other order: integers do not care. */
    for (size_t i = 0; i < n; ++i)
        v[i] = p->rank ? p->x->sumv[1][i] + p->x->sumv[0][i] : p->x->sumv[0][i] + p->x->sumv[1][i];
    pthread_barrier_wait(&p->x->barrier);
    return NF_OK;
}

static void *process_main(void *arg)
{
    process *p = arg;
    nf_reduce red = {exchange_max, exchange_sum, p};
    size_t b = p->begin;
    p->st = nf_guide_train_batch(p->g, p->end - b, p->s->ctx + b, p->s->dir + 3 * b,
                                 p->s->weight + b, p->group_end, p->ngroups, NULL, &red,
                                 &p->loss);
    return NULL;
}

static void test_exact_across_processes(void **state)
{
    nf_model *m = *state;
    nf_guide_config gc;
    nf_guide_config_init(&gc);
    gc.store_capacity = 16;
    samples s = make_samples(1024, 21);
    size_t P = nf_model_param_count(m);
    float *one = malloc(P * sizeof *one), *two = malloc(P * sizeof *two);
    assert_non_null(one);
    assert_non_null(two);

    /* One process, 16 groups of 64 samples. */
    size_t ends[16];
    for (size_t k = 0; k < 16; ++k)
        ends[k] = 64 * (k + 1);
    nf_guide *g = make_guide(m, &gc);
    float loss1 = NAN;
    assert_int_equal(nf_guide_train_batch(g, s.n, s.ctx, s.dir, s.weight, ends, 16, NULL, NULL,
                                          &loss1),
                     NF_OK);
    params_of(g, one);
    nf_guide_destroy(g);

    /* Two processes, 8 of the same groups each. */
    exchange x;
    x.capacity = P + 2;
    x.sumv[0] = malloc(x.capacity * sizeof(int64_t));
    x.sumv[1] = malloc(x.capacity * sizeof(int64_t));
    assert_non_null(x.sumv[0]);
    assert_non_null(x.sumv[1]);
    pthread_barrier_init(&x.barrier, NULL, 2);
    process pr[2];
    pthread_t t[2];
    for (int r = 0; r < 2; ++r) {
        memset(&pr[r], 0, sizeof pr[r]);
        pr[r].x = &x;
        pr[r].rank = r;
        pr[r].g = make_guide(m, &gc);
        pr[r].s = &s;
        pr[r].begin = 512u * (size_t)r;
        pr[r].end = pr[r].begin + 512u;
        pr[r].ngroups = 8;
        for (size_t k = 0; k < 8; ++k)
            pr[r].group_end[k] = 64 * (k + 1);
        assert_int_equal(pthread_create(&t[r], NULL, process_main, &pr[r]), 0);
    }
    for (int r = 0; r < 2; ++r)
        pthread_join(t[r], NULL);
    pthread_barrier_destroy(&x.barrier);
    free(x.sumv[0]);
    free(x.sumv[1]);
    for (int r = 0; r < 2; ++r) {
        assert_int_equal(pr[r].st, NF_OK);
        params_of(pr[r].g, two);
        assert_memory_equal(two, one, P * sizeof *one);
        assert_true(pr[r].loss == loss1);
        nf_guide_destroy(pr[r].g);
    }

    /* Bad groups are refused before any step. */
    g = make_guide(m, &gc);
    ends[15] = s.n - 1;
    assert_int_equal(
        nf_guide_train_batch(g, s.n, s.ctx, s.dir, s.weight, ends, 16, NULL, NULL, NULL),
        NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "group_end[15]"));
    assert_int_equal(
        nf_guide_train_batch(g, s.n, s.ctx, s.dir, s.weight, ends, 17, NULL, NULL, NULL),
        NF_ERROR_INVALID_ARGUMENT);
    nf_guide_destroy(g);
    free_samples(&s);
    free(one);
    free(two);
}

/* ---- The schedule: patience ----------------------------------------------------------------- */

static void test_patience(void **state)
{
    nf_model *m = *state;
    nf_guide_config gc = nft_guide_config(512, 256, 1);
    gc.patience = 3;
    gc.learning_rate = 1e-9f; /* the model cannot improve: only patience ends training */
    nf_guide *g = make_guide(m, &gc);
    samples s = make_samples(256, 31);
    int passes = 0;
    while (nf_guide_keep_training(g, 0.0, 0.0) && passes < 50) {
        assert_int_equal(nf_guide_add_samples(g, s.n, s.key, s.ctx, s.dir, s.weight, NULL),
                         NF_OK);
        assert_int_equal(nf_guide_train_pass(g, NULL, NULL, NULL), NF_OK);
        passes++;
    }
    /* The same samples every pass: the loss is flat, the first pass sets the best, then three
     * passes without a 1 % improvement. */
    assert_int_equal(passes, 4);
    /* The budget's share: 0.15 of 30 s is 4.5 s (0.15f is a little above 0.15). */
    nf_guide_destroy(g);
    g = make_guide(m, &gc);
    assert_int_equal(nf_guide_keep_training(g, 4.49, 30.0), 1);
    assert_int_equal(nf_guide_keep_training(g, 4.51, 30.0), 0);
    nf_guide_destroy(g);
    free_samples(&s);
}

/* ---- Publication -------------------------------------------------------------------------- */

static void test_publish(void **state)
{
    nf_model *m = *state;
    nf_guide_config gc = nft_guide_config(1024, 256, 2);
    nf_guide *g = make_guide(m, &gc);
    size_t P = nf_model_param_count(m);
    float *a = malloc(P * sizeof *a), *b = malloc(P * sizeof *b);
    assert_non_null(a);
    assert_non_null(b);
    samples s = make_samples(600, 41);

    const nf_model *held = NULL, *other = NULL;
    assert_int_equal(nf_guide_acquire(g, &held), NF_OK);
    assert_int_equal(nf_model_get_params(held, a), NF_OK);
    assert_int_equal(nf_guide_add_samples(g, s.n, s.key, s.ctx, s.dir, s.weight, NULL), NF_OK);
    assert_int_equal(nf_guide_train_pass(g, NULL, NULL, NULL), NF_OK);
    /* The held model does not change with training... */
    assert_int_equal(nf_model_get_params(held, b), NF_OK);
    assert_memory_equal(a, b, P * sizeof *a);
    /* ...nor with publication, which writes the other one. */
    assert_int_equal(nf_guide_publish(g), NF_OK);
    assert_int_equal(nf_model_get_params(held, b), NF_OK);
    assert_memory_equal(a, b, P * sizeof *a);
    assert_int_equal(nf_guide_acquire(g, &other), NF_OK);
    assert_ptr_not_equal(other, held);
    assert_int_equal(nf_model_get_params(other, b), NF_OK);
    params_of(g, a);
    assert_memory_equal(a, b, P * sizeof *a); /* the newest is the trained one */

    /* Two generations held, the older by a thread that lags: publication goes on into the
     * third copy, and neither held model changes. */
    float *c = malloc(P * sizeof *c);
    assert_non_null(c);
    assert_int_equal(nf_model_get_params(other, c), NF_OK);
    assert_int_equal(nf_guide_publish(g), NF_OK);
    assert_int_equal(nf_model_get_params(held, b), NF_OK);
    assert_int_equal(nf_model_get_params(other, a), NF_OK);
    assert_memory_equal(a, c, P * sizeof *a);
    const nf_model *third = NULL;
    assert_int_equal(nf_guide_acquire(g, &third), NF_OK);
    assert_ptr_not_equal(third, held);
    assert_ptr_not_equal(third, other);
    /* Three generations held: publication is refused, says why, and changes nothing. */
    assert_int_equal(nf_guide_publish(g), NF_ERROR_BUSY);
    assert_non_null(strstr(nf_last_error_message(), "3 generations"));
    assert_non_null(strstr(nf_last_error_message(), "release"));
    assert_int_equal(nf_model_get_params(other, a), NF_OK);
    assert_memory_equal(a, c, P * sizeof *a);
    free(c);
    /* Releasing what was not handed out, or twice, is refused. */
    assert_int_equal(nf_guide_release(g, m), NF_ERROR_INVALID_ARGUMENT);
    assert_int_equal(nf_guide_release(g, held), NF_OK);
    assert_int_equal(nf_guide_release(g, held), NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "more often"));
    assert_int_equal(nf_guide_publish(g), NF_OK);
    assert_int_equal(nf_guide_release(g, other), NF_OK);
    assert_int_equal(nf_guide_release(g, third), NF_OK);
    free_samples(&s);
    free(a);
    free(b);
    nf_guide_destroy(g);
}

/* ---- A custom prior finds each sample's payload ------------------------------------------- */

static const nf_guide *payload_guide;
static int payload_misses;

static float payload_sample(void *user, const nf_context *ctx, float u0, float u1, float dir[3])
{
    const float *lobe = nf_guide_payload(payload_guide, ctx);
    if (payload_guide && (!lobe || lobe[0] != ctx->position[0]))
        payload_misses++;
    return nft_phong_sample(user, ctx, u0, u1, dir);
}

static float payload_pdf(void *user, const nf_context *ctx, const float dir[3])
{
    const float *lobe = nf_guide_payload(payload_guide, ctx);
    if (payload_guide && (!lobe || lobe[0] != ctx->position[0]))
        payload_misses++;
    return nft_phong_pdf(user, ctx, dir);
}

static void test_payload(void **state)
{
    (void)state;
    nf_config cfg = nft_config(NF_PRESET_SMALL, NF_PRIOR_CUSTOM);
    cfg.custom_prior.sample = payload_sample;
    cfg.custom_prior.pdf = payload_pdf; /* user stays nft_phong_callbacks()'s */
    nf_model *m = nft_model_from(&cfg);
    nf_guide_config gc;
    nf_guide_config_init(&gc);
    gc.store_capacity = 300;
    gc.payload_bytes = sizeof(float);
    gc.step_samples = 128;
    gc.steps_per_pass = 2;
    gc.groups = 1; /* the counter of misses is not atomic: one thread */
    nf_guide *g = make_guide(m, &gc);
    samples s = make_samples(300, 51);
    float *payload = malloc(s.n * sizeof *payload);
    assert_non_null(payload);
    for (size_t i = 0; i < s.n; ++i)
        payload[i] = s.ctx[i].position[0]; /* what the callbacks check */
    assert_int_equal(nf_guide_add_samples(g, s.n, s.key, s.ctx, s.dir, s.weight, payload),
                     NF_OK);
    payload_guide = g;
    payload_misses = 0;
    assert_int_equal(nf_guide_train_pass(g, NULL, NULL, NULL), NF_OK);
    payload_guide = NULL;
    assert_int_equal(payload_misses, 0);
    nf_guide_stats st;
    assert_int_equal(nf_guide_get_stats(g, &st), NF_OK);
    assert_int_equal(st.steps, 2);
    /* Outside a step, nothing is found. */
    assert_null(nf_guide_payload(g, &s.ctx[0]));
    free(payload);
    free_samples(&s);
    nf_guide_destroy(g);
    nf_model_destroy(m);
}

/* A reduce hook that fails refuses the step on this process: the status comes back with a
 * message, and the model is as before the step. */
static nf_status failing_max(void *user, double *v, size_t n)
{
    (void)user;
    (void)v;
    (void)n;
    return NF_ERROR_IO;
}

static nf_status passing_sum(void *user, int64_t *v, size_t n)
{
    (void)user;
    (void)v;
    (void)n;
    return NF_OK;
}

static void test_failing_reduce_changes_nothing(void **state)
{
    nf_model *m = *state;
    nf_guide_config gc;
    nf_guide_config_init(&gc);
    gc.store_capacity = 64;
    nf_guide *g = make_guide(m, &gc);
    samples s = make_samples(64, 71);
    size_t P = nf_model_param_count(m);
    float *before = malloc(P * sizeof *before), *after = malloc(P * sizeof *after);
    assert_non_null(before);
    assert_non_null(after);
    params_of(g, before);
    nf_reduce red = {failing_max, passing_sum, NULL};
    float loss = 1.0f;
    assert_int_equal(nf_guide_train_batch(g, s.n, s.ctx, s.dir, s.weight, NULL, 0, NULL, &red,
                                          &loss),
                     NF_ERROR_IO);
    assert_non_null(strstr(nf_last_error_message(), "max_f64"));
    assert_true(isnan(loss));
    params_of(g, after);
    assert_memory_equal(before, after, P * sizeof *before);
    assert_int_equal(nf_guide_add_samples(g, s.n, s.key, s.ctx, s.dir, s.weight, NULL), NF_OK);
    assert_int_equal(nf_guide_train_pass(g, NULL, &red, NULL), NF_ERROR_IO);
    params_of(g, after);
    assert_memory_equal(before, after, P * sizeof *before);
    /* The guide is usable afterwards: no call is left marked as running. */
    assert_int_equal(nf_guide_publish(g), NF_OK);
    assert_int_equal(nf_guide_train_batch(g, s.n, s.ctx, s.dir, s.weight, NULL, 0, NULL, NULL,
                                          &loss),
                     NF_OK);
    free(before);
    free(after);
    free_samples(&s);
    nf_guide_destroy(g);
}

/* nf_model_copy, which publication uses: dst becomes src (parameters, optimizer state, step
 * count) without allocating, its points go stale, and another configuration is refused. */
static void test_model_copy(void **state)
{
    (void)state;
    nf_model *a = nft_make_model(NF_PRESET_SMALL, NF_PRIOR_COSINE);
    nf_model *b = nft_make_model(NF_PRESET_SMALL, NF_PRIOR_COSINE);
    nf_model *large = nft_make_model(NF_PRESET_LARGE, NF_PRIOR_COSINE);
    samples s = make_samples(256, 61);
    assert_int_equal(nf_train_step(a, s.n, s.ctx, s.dir, s.weight, NULL), NF_OK);
    assert_int_equal(nf_train_step(a, s.n, s.ctx, s.dir, s.weight, NULL), NF_OK);
    nf_shading_point sp;
    assert_int_equal(nf_point_prepare(b, &s.ctx[0], NULL, &sp), NF_OK);
    assert_int_equal(nf_model_copy(b, a), NF_OK);
    size_t P = nf_model_param_count(a);
    float *pa = malloc(P * sizeof *pa), *pb = malloc(P * sizeof *pb);
    assert_non_null(pa);
    assert_non_null(pb);
    assert_int_equal(nf_model_get_params(a, pa), NF_OK);
    assert_int_equal(nf_model_get_params(b, pb), NF_OK);
    assert_memory_equal(pa, pb, P * sizeof *pa);
    assert_int_equal(nf_model_step_count(b), 2);
    float pdf_a, pdf_b;
    assert_int_equal(nf_pdf(a, 1, &s.ctx[1], s.dir + 3, &pdf_a), NF_OK);
    assert_int_equal(nf_pdf(b, 1, &s.ctx[1], s.dir + 3, &pdf_b), NF_OK);
    assert_true(pdf_a == pdf_b);
    float u[2] = {0.5f, 0.5f}, d[3];
    assert_int_equal(nf_point_sample(b, &sp, 1, u, d, NULL), NF_ERROR_STALE);
    /* The same next step from the same state: the optimizer state came along. */
    assert_int_equal(nf_train_step(a, s.n, s.ctx, s.dir, s.weight, NULL), NF_OK);
    assert_int_equal(nf_train_step(b, s.n, s.ctx, s.dir, s.weight, NULL), NF_OK);
    assert_int_equal(nf_model_get_params(a, pa), NF_OK);
    assert_int_equal(nf_model_get_params(b, pb), NF_OK);
    assert_memory_equal(pa, pb, P * sizeof *pa);
    assert_int_equal(nf_model_copy(large, a), NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "configuration"));
    assert_int_equal(nf_model_copy(NULL, a), NF_ERROR_INVALID_ARGUMENT);
    free(pa);
    free(pb);
    free_samples(&s);
    nf_model_destroy(a);
    nf_model_destroy(b);
    nf_model_destroy(large);
}

NFT_TEST_MAIN(
    NFT_WITH_MODEL(test_config_checked),   cmocka_unit_test(test_policy_points),
    cmocka_unit_test(test_model_config),
    NFT_WITH_MODEL(test_store_bounds),     NFT_WITH_MODEL(test_same_bits_any_threads),
    NFT_WITH_MODEL(test_exact_across_processes), NFT_WITH_MODEL(test_patience),
    NFT_WITH_MODEL(test_publish),          cmocka_unit_test(test_payload),
    cmocka_unit_test(test_model_copy),
    NFT_WITH_MODEL(test_failing_reduce_changes_nothing),
)
