/*
 * nisflow/train.h - online training: the weighted negative log-likelihood, its gradient, and
 * AdamW steps.
 *
 * A training sample is (context, direction w, weight f >= 0) where f is the renderer's
 * estimate of f_s(wo, x, w) L_i(x, w) |cos| divided by the density it sampled w with. The
 * loss of a batch is  - sum_i f_i log p(w_i | ctx_i) / sum_i f_i  (docs/theory.md section 6).
 *
 * Where the directions come from decides how steady training is. Drawn from the flow alone,
 * a weight f / p has no bound: a direction the flow has made too rare (a lobe's tail) can
 * carry 15 to 50 times its batch's mean weight, and the step it dominates can throw the model
 * off for dozens of steps. Drawn from the mixture a guided renderer samples with (the flow
 * with probability g, the BSDF otherwise; nisflow/guide.h's policy) and weighted by f over
 * the mixture's density, a weight is at most f / ((1 - g) p_bsdf). docs/results.md section 8
 * measures both.
 *
 * Sharded training (several threads or machines): each shard k calls nf_loss_gradient on a
 * const model with its own gradient buffer g_k and knows its weight sum F_k = sum of its
 * weights. The gradient of the whole batch is  g = sum_k F_k g_k / sum_k F_k , which one
 * thread then passes to nf_apply_gradient. docs/model-layer.md shows the loop.
 */
#ifndef NISFLOW_TRAIN_H
#define NISFLOW_TRAIN_H

#include <stddef.h>
#include <stdint.h>

#include "version.h"
#include "model.h"
#include "status.h"

NF_EXTERN_C_BEGIN

/* The stack, in bytes, to allow for one nf_loss_gradient or nf_train_step call: 192 KiB,
 * whatever the configuration within its limits and the instruction set. The calls keep the
 * work area of a tile of 16 samples on the stack, sized for the largest networks the limits
 * allow, so the presets use as much as the largest networks. Checked by stack painting
 * (tests/robustness/test_training_stack.c fails above this figure and prints the use, libm
 * included; docs/performance.md has it for GCC and clang), with room left for other
 * compilers and versions. A custom prior's
 * callbacks run on top of it. Threads that train need this much beyond their own use: the
 * default stacks of glibc (8 MiB), macOS (512 KiB) and Windows (1 MiB) suffice, musl's 128 KiB
 * and small fiber stacks do not (pthread_attr_setstacksize). */
#define NF_TRAINING_STACK_BYTES 196608u

/* One optimisation step on a batch: nf_loss_gradient into the model's own gradient buffer,
 * then nf_apply_gradient. *loss (if not NULL) receives the batch's loss before the step.
 * Weights must be finite and >= 0; a batch whose weights are all zero leaves the model
 * unchanged (no step is counted) and reports a loss of 0. A refused batch (any invalid input)
 * or a step whose loss, gradient or new parameters would not be finite (NF_ERROR_NUMERIC,
 * possible with extreme parameters or learning rates) leaves the model exactly as it was.
 * n = 0 is a no-op. Not thread-safe: no other call may use `m` meanwhile. Does not allocate;
 * uses up to NF_TRAINING_STACK_BYTES (192 KiB) of the caller's stack, as nf_loss_gradient. */
NF_API nf_status nf_train_step(nf_model *m, size_t n, const nf_context *ctx, const float *dir,
                               const float *weight, float *loss);

/* The number of trainable parameters (floats). 0 for NULL. Thread-safe. */
NF_API size_t nf_model_param_count(const nf_model *m);

/* Copies the parameters into `params` (nf_model_param_count floats). The layout: for each coupling
 * layer, for each linear layer of its conditioner from input to output, the weight matrix
 * stored input-major (W[in][out]) followed by the bias (out floats). Thread-safe. */
NF_API nf_status nf_model_get_params(const nf_model *m, float *params);

/* Replaces the parameters (nf_model_param_count floats, layout as above). Refuses non-finite values
 * with NF_ERROR_INVALID_ARGUMENT and leaves the model unchanged. Every finite value is
 * accepted: the conditioners clamp the spline parameters they compute, so that sampling and
 * densities stay finite even for weights near FLT_MAX (docs/robustness.md); training such a
 * model may be refused with NF_ERROR_NUMERIC. The optimizer state is kept.
 * Not thread-safe. */
NF_API nf_status nf_model_set_params(nf_model *m, const float *params);

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
NF_API nf_status nf_loss_gradient(const nf_model *m, size_t n, const nf_context *ctx,
                                  const float *dir, const float *weight, float *loss, float *grad);

/* The bytes of caller memory that nf_loss_gradient_with_work takes: the work area of a tile of
 * 16 samples, sized for the largest networks the configuration limits allow and for every
 * instruction set this build has, plus 63 bytes so that any pointer can be aligned; about
 * 160 KiB, the same for every model. Thread-safe. */
NF_API size_t nf_training_work_bytes(void);

/* nf_loss_gradient with the work area in caller memory instead of on the stack, for threads
 * whose stacks are small (fibers, musl's 128 KiB default): it then uses at most
 * NF_TRAINING_WORK_STACK_BYTES (32 KiB) of the caller's stack. `work` holds work_bytes >=
 * nf_training_work_bytes() bytes, of any alignment; its content on entry does not matter and
 * is unspecified on return; two calls that run at the same time need two work areas (one per
 * thread, allocated once). The results are nf_loss_gradient's, to the bit. A NULL or too small
 * work area is refused with NF_ERROR_INVALID_ARGUMENT; otherwise as nf_loss_gradient
 * (validation, NF_ERROR_NUMERIC, thread-safe on a const model, never allocates). */
NF_API nf_status nf_loss_gradient_with_work(const nf_model *m, size_t n, const nf_context *ctx,
                                            const float *dir, const float *weight, float *loss,
                                            float *grad, void *work, size_t work_bytes);

/* The stack, in bytes, to allow for one nf_loss_gradient_with_work call: 32 KiB. Checked like
 * NF_TRAINING_STACK_BYTES (tests/robustness/test_training_stack.c fails above it; the first
 * hidden layer of a tile keeps up to 8 KiB of activations on the stack), with room left for
 * other compilers and versions. A custom prior's callbacks run on top of it. */
#define NF_TRAINING_WORK_STACK_BYTES 32768u

/* One AdamW step (decoupled weight decay, bias-corrected moments) with the given gradient
 * (nf_model_param_count floats). Refuses a non-finite gradient with NF_ERROR_INVALID_ARGUMENT, and
 * a step whose parameters or moments would be non-finite with NF_ERROR_NUMERIC; both leave the
 * model unchanged. An all-zero gradient is still a step (weight decay and moment decay apply
 * and the step count grows): sharded training should skip batches whose weights are all
 * zero, as nf_train_step does. Not thread-safe. Does not allocate. */
NF_API nf_status nf_apply_gradient(nf_model *m, const float *grad);

/* The number of optimizer steps the model has taken (saved and restored with it). 0 for
 * NULL. Thread-safe. */
NF_API uint64_t nf_model_step_count(const nf_model *m);

/* Changes the AdamW learning rate of an existing model (for schedules): in
 * [NF_LEARNING_RATE_MIN, NF_LEARNING_RATE_MAX] = [1e-9, 1] and below 1 / weight_decay, checked
 * as nf_model_create checks nf_config.learning_rate (NF_ERROR_INVALID_ARGUMENT otherwise, the
 * model unchanged). Not thread-safe. */
NF_API nf_status nf_model_set_learning_rate(nf_model *m, float learning_rate);

/* ---- Names kept until 0.10 (CHANGELOG.md, 0.8.1) ------------------------------------------ */

NF_API NF_DEPRECATED("nf_model_param_count") size_t nf_param_count(const nf_model *m);
NF_API NF_DEPRECATED("nf_model_get_params") nf_status
    nf_get_params(const nf_model *m, float *params);
NF_API NF_DEPRECATED("nf_model_set_params") nf_status
    nf_set_params(nf_model *m, const float *params);
NF_API NF_DEPRECATED("nf_model_set_learning_rate") nf_status
    nf_set_learning_rate(nf_model *m, float learning_rate);

NF_EXTERN_C_END

#endif /* NISFLOW_TRAIN_H */
