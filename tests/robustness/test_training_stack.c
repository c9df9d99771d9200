/*
 * test_training_stack.c - the stack nf_loss_gradient and nf_train_step use, against the figure
 * train.h documents (NF_TRAINING_STACK_BYTES, 192 KiB), and nf_loss_gradient_with_work's
 * against NF_TRAINING_WORK_STACK_BYTES (32 KiB). A renderer that trains on its own
 * threads sizes their stacks from it (musl's default 128 KiB is too small), so the figure must
 * stay true: this test fails when the training kernels grow past it.
 *
 * A thread runs each call on a stack of our own that is painted first; the deepest byte
 * changed, minus that of the same thread doing everything but the library call, is what the
 * call used, libm included. Every instruction set the CPU runs, the presets and the largest
 * network the configuration allows, batches that take the per-sample path (1, 3) and the
 * tiled one (16, 37). Only in optimized builds without sanitizers: the figure is for those,
 * and sanitizers grow every frame.
 */

#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "nf_test_support.h"
#include "gradient.h"

#if NFT_STACK_CHECK
enum { STACK_BYTES = 512 * 1024, N = 37 };

typedef struct stack_job {
    nf_model *m;
    size_t n;
    const nf_context *ctx;
    const float *dir, *weight;
    float *grad;
    int call; /* 0: nothing, 1: nf_loss_gradient, 2: nf_train_step,
               * 3: nf_loss_gradient_with_work */
    nf_status status;
    void *work; /* nf_training_work_bytes(), for call 3 */
} stack_job;

static void *stack_thread(void *arg)
{
    stack_job *j = arg;
    float loss = 0.0f;
    switch (j->call) {
    case 1:
        j->status = nf_loss_gradient(j->m, j->n, j->ctx, j->dir, j->weight, &loss, j->grad);
        break;
    case 2: j->status = nf_train_step(j->m, j->n, j->ctx, j->dir, j->weight, &loss); break;
    case 3:
        j->status = nf_loss_gradient_with_work(j->m, j->n, j->ctx, j->dir, j->weight, &loss,
                                               j->grad, j->work, nf_training_work_bytes());
        break;
    default: j->status = NF_OK; break;
    }
    volatile float sink = loss; /* the same frame for every case */
    (void)sink;
    return NULL;
}

#endif

static void test_training_stack_bound(void **state)
{
    (void)state;
#if !NFT_STACK_CHECK
    skip();
#else
    static const nf_isa isas[3] = {NF_ISA_GENERIC, NF_ISA_AVX2, NF_ISA_AVX512};
    static const char *shapes[3] = {"small preset", "large preset", "largest network"};
    static const size_t sizes[4] = {1, 3, 16, N};
    static nf_context ctx[N];
    static float dir[3 * N], weight[N];
    nft_rng r;
    nft_rng_seed(&r, 21u, 1u);
    nft_random_samples(&r, N, ctx, dir, weight, 0.25f);
    size_t worst[4] = {0, 0, 0, 0};
    char where[4][96] = {"", "", "", ""};
    void *work = malloc(nf_training_work_bytes());
    assert_non_null(work);
    for (int k = 0; k < 3; ++k) {
        for (int s = 0; s < 3; ++s) {
            nf_config cfg;
            nf_config_init(&cfg, s == 0 ? NF_PRESET_SMALL : NF_PRESET_LARGE);
            cfg.isa = isas[k];
            if (s == 2) /* every limit at once: the tape cannot hold all layers */
                nft_config_largest(&cfg);
            nf_model *m = NULL;
            if (nf_model_create(&cfg, &m) != NF_OK)
                continue; /* a CPU without the set */
            float *grad = malloc(nf_model_param_count(m) * sizeof(float));
            assert_non_null(grad);
            stack_job j = {m, 0, ctx, dir, weight, grad, 0, NF_OK, work};
            size_t base = nft_stack_used(stack_thread, &j, STACK_BYTES);
            for (int call = 1; call <= 3; ++call) {
                for (size_t b = 0; b < 4; ++b) {
                    j.call = call;
                    j.n = sizes[b];
                    size_t used = nft_stack_used(stack_thread, &j, STACK_BYTES);
                    assert_int_equal(j.status, NF_OK);
                    size_t extra = used > base ? used - base : 0;
                    if (extra > worst[call]) {
                        worst[call] = extra;
                        snprintf(where[call], sizeof where[call], "%s, n = %zu, %s", shapes[s],
                                 sizes[b], nf_model_isa_name(m));
                    }
                }
            }
            free(grad);
            nf_model_destroy(m);
        }
    }
    print_message("nf_loss_gradient at most %zu bytes of stack (%s)\n", worst[1], where[1]);
    print_message("nf_train_step    at most %zu bytes of stack (%s)\n", worst[2], where[2]);
    print_message("nf_loss_gradient_with_work at most %zu bytes of stack (%s)\n", worst[3],
                  where[3]);
    free(work);
    /* Not vacuous: the tiled gradient keeps its whole work area on the stack. */
    assert_true(worst[1] > 64 * 1024);
    for (int call = 1; call <= 2; ++call)
        if (worst[call] > NF_TRAINING_STACK_BYTES)
            fail_msg("%s used %zu bytes of stack, more than train.h's NF_TRAINING_STACK_BYTES "
                     "= %u (%s)",
                     call == 1 ? "nf_loss_gradient" : "nf_train_step", worst[call],
                     (unsigned)NF_TRAINING_STACK_BYTES, where[call]);
    /* The work area moved off the stack: what is left is far below the stack calls'. */
    assert_true(worst[3] < worst[1] / 4);
    if (worst[3] > NF_TRAINING_WORK_STACK_BYTES)
        fail_msg("nf_loss_gradient_with_work used %zu bytes of stack, more than train.h's "
                 "NF_TRAINING_WORK_STACK_BYTES = %u (%s)",
                 worst[3], (unsigned)NF_TRAINING_WORK_STACK_BYTES, where[3]);
#endif
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_training_stack_bound),
)
