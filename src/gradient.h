/*
 * gradient.h - the two halves of a training step: the loss gradient of a batch and the
 * AdamW step that applies one. nf_train_step (nisflow/train.h) is the one a renderer calls,
 * and the guide's sharded training (guide_train.c) is built from these. Internal (not
 * installed); the tests, fuzzers and the benchmark call them.
 *
 * Sharded training (several threads or machines): each shard k calls nf_loss_gradient on a
 * const model with its own gradient buffer g_k and knows its weight sum F_k = sum of its
 * weights. The gradient of the whole batch is  g = sum_k F_k g_k / sum_k F_k , which one
 * thread then passes to nf_apply_gradient. docs/model-layer.md shows the loop.
 */
#ifndef NISFLOW_SRC_GRADIENT_H
#define NISFLOW_SRC_GRADIENT_H

#include <stddef.h>

#include "nisflow/model.h"
#include "nisflow/status.h"

/* Computes the batch loss (if loss is not NULL) and its gradient with respect to the
 * parameters into grad (nf_model_param_count floats, overwritten), by hand-written reverse mode.
 * Validation as for nf_train_step; with all weights zero the loss and gradient are 0. When the
 * loss or the gradient would not be finite (extreme parameters) it returns NF_ERROR_NUMERIC;
 * grad's content is then unspecified and *loss is not written.
 * Batches of 4 or more samples are evaluated 16 at a time and single samples one by one; the
 * two sum in different orders, so splitting a batch differently changes the gradient by
 * rounding (~1e-7 relative), not more.
 * Thread-safe on a const model (each thread passes its own grad); never allocates; uses up to
 * NF_TRAINING_STACK_BYTES (192 KiB) of the caller's stack, for every
 * configuration: the activations of 16 samples for the largest networks the configuration
 * limits allow. */
nf_status nf_loss_gradient(const nf_model *m, size_t n, const nf_context *ctx, const float *dir,
                           const float *weight, float *loss, float *grad);

/* The bytes of caller memory that nf_loss_gradient_with_work takes: the work area of a tile of
 * 16 samples, sized for the largest networks the configuration limits allow and for every
 * instruction set this build has, plus 63 bytes so that any pointer can be aligned; about
 * 160 KiB, the same for every model. Thread-safe. */
size_t nf_training_work_bytes(void);

/* nf_loss_gradient with the work area in caller memory instead of on the stack, for threads
 * whose stacks are small (fibers, musl's 128 KiB default): it then uses at most
 * NF_TRAINING_WORK_STACK_BYTES (32 KiB) of the caller's stack. `work` holds work_bytes >=
 * nf_training_work_bytes() bytes, of any alignment; its content on entry does not matter and
 * is unspecified on return; two calls that run at the same time need two work areas (one per
 * thread, allocated once). The results are nf_loss_gradient's, to the bit. A NULL or too small
 * work area is refused with NF_ERROR_INVALID_ARGUMENT; otherwise as nf_loss_gradient
 * (validation, NF_ERROR_NUMERIC, thread-safe on a const model, never allocates). */
nf_status nf_loss_gradient_with_work(const nf_model *m, size_t n, const nf_context *ctx,
                                     const float *dir, const float *weight, float *loss,
                                     float *grad, void *work, size_t work_bytes);

/* One AdamW step (decoupled weight decay, bias-corrected moments) with the given gradient
 * (nf_model_param_count floats). Refuses a non-finite gradient with NF_ERROR_INVALID_ARGUMENT, and
 * a step whose parameters or moments would be non-finite with NF_ERROR_NUMERIC; both leave the
 * model unchanged. An all-zero gradient is still a step (weight decay and moment decay apply
 * and the step count grows): sharded training should skip batches whose weights are all
 * zero, as nf_train_step does. Not thread-safe. Does not allocate. */
nf_status nf_apply_gradient(nf_model *m, const float *grad);

/* The stack, in bytes, to allow for one nf_loss_gradient_with_work call: 32 KiB. Checked like
 * NF_TRAINING_STACK_BYTES (tests/robustness/test_training_stack.c fails above it; the first
 * hidden layer of a tile keeps up to 8 KiB of activations on the stack), with room left for
 * other compilers and versions. A custom prior's callbacks run on top of it. */
#define NF_TRAINING_WORK_STACK_BYTES 32768u

#endif /* NISFLOW_SRC_GRADIENT_H */
