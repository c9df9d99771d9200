/*
 * test_gradient_sum.c - the exact step of gradient_sum.h (one process: a single rank):
 *   - the same groups on 1 and 3 threads give the same model to the bit;
 *   - the summed gradient is the batch's (nf_loss_gradient on the whole batch) up to rounding;
 *   - a group the library refuses stops the step, leaves the model as it was and keeps the
 *     library's message; a batch of zero weights takes no step.
 */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include <nisflow/nisflow.h>

#include "gradient_sum.h"
#include "rng.h"

enum { N = 300, GROUPS = 5 };

typedef struct batch {
    nf_context ctx[N];
    float dir[3 * N], weight[N];
    size_t group_end[GROUPS];
} batch;

static void unit(rng *r, float v[3])
{
    for (;;) {
        for (int i = 0; i < 3; ++i)
            v[i] = 2.0f * rng_next(r) - 1.0f;
        float l = sqrtf(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        if (l > 0.1f && l <= 1.0f) {
            for (int i = 0; i < 3; ++i)
                v[i] /= l;
            return;
        }
    }
}

/* Random contexts, directions and weights; groups of unequal sizes (one empty). */
static void make_batch(batch *b, uint64_t seed)
{
    rng r = rng_seed(seed, RNG_TRAIN, 0, 0);
    for (int i = 0; i < N; ++i) {
        for (int a = 0; a < 3; ++a)
            b->ctx[i].position[a] = rng_next(&r);
        unit(&r, b->ctx[i].normal);
        unit(&r, b->ctx[i].wo);
        unit(&r, b->dir + 3 * i);
        b->weight[i] = 0.1f + 2.0f * rng_next(&r);
    }
    const size_t ends[GROUPS] = {40, 40, 170, 171, N};
    memcpy(b->group_end, ends, sizeof ends);
}

static nf_model *make_model(void)
{
    nf_config cfg;
    nf_config_init(&cfg, NF_PRESET_SMALL);
    cfg.prior = NF_PRIOR_COSINE;
    nf_model *m = NULL;
    assert_int_equal(nf_model_create(&cfg, &m), NF_OK);
    /* Non-zero output layers, so that the gradient reaches every parameter. */
    size_t count = nf_param_count(m);
    float *p = malloc(count * sizeof *p);
    assert_non_null(p);
    assert_int_equal(nf_get_params(m, p), NF_OK);
    rng r = rng_seed(5u, RNG_TRAIN, 1, 0);
    for (size_t i = 0; i < count; ++i)
        p[i] += 0.2f * (2.0f * rng_next(&r) - 1.0f);
    assert_int_equal(nf_set_params(m, p), NF_OK);
    free(p);
    return m;
}

static float *params_of(const nf_model *m)
{
    float *p = malloc(nf_param_count(m) * sizeof *p);
    assert_non_null(p);
    assert_int_equal(nf_get_params(m, p), NF_OK);
    return p;
}

static void test_same_bits_for_any_thread_count(void **state)
{
    (void)state;
    static batch b;
    make_batch(&b, 3u);
    nf_model *one = make_model(), *three = NULL;
    assert_int_equal(nf_model_clone(one, &three), NF_OK);
    gradient_sum g1 = {0}, g3 = {0};
    tr_error err;
    for (int step = 0; step < 3; ++step) {
        float l1, l3;
        gradient_step s1, s3;
        nf_status r1, r3;
        assert_true(gradient_sum_step(&g1, one, b.ctx, b.dir, b.weight, b.group_end, GROUPS,
                                      GROUPS, 1, &l1, &s1, &r1, &err));
        assert_true(gradient_sum_step(&g3, three, b.ctx, b.dir, b.weight, b.group_end, GROUPS,
                                      GROUPS, 3, &l3, &s3, &r3, &err));
        assert_int_equal(s1, GRADIENT_STEP_TAKEN);
        assert_int_equal(s3, GRADIENT_STEP_TAKEN);
        assert_true(memcmp(&l1, &l3, sizeof l1) == 0);
    }
    float *p1 = params_of(one), *p3 = params_of(three);
    assert_memory_equal(p1, p3, nf_param_count(one) * sizeof *p1);
    assert_int_equal(nf_model_step_count(one), 3);
    free(p1);
    free(p3);
    gradient_sum_free(&g1);
    gradient_sum_free(&g3);
    nf_model_destroy(one);
    nf_model_destroy(three);
}

static void test_sum_is_the_batch_gradient(void **state)
{
    (void)state;
    static batch b;
    make_batch(&b, 4u);
    nf_model *m = make_model();
    size_t count = nf_param_count(m);
    float *whole = malloc(count * sizeof *whole), loss_whole;
    assert_non_null(whole);
    assert_int_equal(nf_loss_gradient(m, N, b.ctx, b.dir, b.weight, &loss_whole, whole), NF_OK);
    gradient_sum g = {0};
    tr_error err;
    float loss;
    gradient_step s;
    nf_status refusal;
    assert_true(gradient_sum_step(&g, m, b.ctx, b.dir, b.weight, b.group_end, GROUPS, GROUPS, 2,
                                  &loss, &s, &refusal, &err));
    assert_int_equal(s, GRADIENT_STEP_TAKEN);
    double norm = 0.0;
    for (size_t i = 0; i < count; ++i)
        norm += (double)whole[i] * whole[i];
    norm = sqrt(norm);
    assert_true(norm > 0.0);
    /* The groups sum per-sample terms in other orders than the whole batch (train.h: ~1e-7
     * relative), and each term is rounded once to 2^-62 of the largest: 1e-5 of the norm,
     * as tests/correctness/test_gradient.c allows for shards. */
    for (size_t i = 0; i < count; ++i)
        if (fabs((double)g.mean[i] - whole[i]) > 1e-5 * norm)
            fail_msg("parameter %zu: groups %.9g, whole batch %.9g", i, (double)g.mean[i],
                     (double)whole[i]);
    assert_true(fabs((double)loss - loss_whole) <= 1e-6 * fabs((double)loss_whole) + 1e-7);
    free(whole);
    gradient_sum_free(&g);
    nf_model_destroy(m);
}

static void test_refused_and_empty(void **state)
{
    (void)state;
    static batch b;
    make_batch(&b, 5u);
    nf_model *m = make_model();
    float *before = params_of(m);
    gradient_sum g = {0};
    tr_error err;
    float loss;
    gradient_step s;
    nf_status refusal;

    b.dir[3 * 100] = NAN; /* in the third group */
    assert_true(gradient_sum_step(&g, m, b.ctx, b.dir, b.weight, b.group_end, GROUPS, GROUPS, 2,
                                  &loss, &s, &refusal, &err));
    assert_int_equal(s, GRADIENT_STEP_REFUSED);
    assert_int_equal(refusal, NF_ERROR_INVALID_ARGUMENT);
    assert_true(isnan(loss));
    assert_non_null(strstr(g.message, "nf_loss_gradient"));
    float *after = params_of(m);
    assert_memory_equal(before, after, nf_param_count(m) * sizeof *before);
    assert_int_equal(nf_model_step_count(m), 0);
    free(after);

    b.dir[3 * 100] = 1.0f;
    b.dir[3 * 100 + 1] = 0.0f;
    b.dir[3 * 100 + 2] = 0.0f;
    memset(b.weight, 0, sizeof b.weight);
    assert_true(gradient_sum_step(&g, m, b.ctx, b.dir, b.weight, b.group_end, GROUPS, GROUPS, 2,
                                  &loss, &s, &refusal, &err));
    assert_int_equal(s, GRADIENT_STEP_EMPTY);
    assert_true(loss == 0.0f && g.message[0] == '\0');
    after = params_of(m);
    assert_memory_equal(before, after, nf_param_count(m) * sizeof *before);
    assert_int_equal(nf_model_step_count(m), 0);
    free(after);
    free(before);
    gradient_sum_free(&g);
    nf_model_destroy(m);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_same_bits_for_any_thread_count),
        cmocka_unit_test(test_sum_is_the_batch_gradient),
        cmocka_unit_test(test_refused_and_empty),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
