/*
 * nisflow/train.h - online training: AdamW steps on the weighted negative log-likelihood,
 * and the parameters.
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
 */
#ifndef NISFLOW_TRAIN_H
#define NISFLOW_TRAIN_H

#include <stddef.h>
#include <stdint.h>

#include "version.h"
#include "model.h"
#include "status.h"

NF_EXTERN_C_BEGIN

/* The stack, in bytes, to allow for one nf_train_step call (or a training task that
 * nf_guide_help runs): 192 KiB,
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

/* One optimisation step on a batch: the loss's gradient by hand-written reverse mode into the
 * model's own gradient buffer, then one AdamW step (decoupled weight decay, bias-corrected
 * moments). *loss (if not NULL) receives the batch's loss before the step.
 * Weights must be finite and >= 0; a batch whose weights are all zero leaves the model
 * unchanged (no step is counted) and reports a loss of 0. A refused batch (any invalid input)
 * or a step whose loss, gradient or new parameters would not be finite (NF_ERROR_NUMERIC,
 * possible with extreme parameters or learning rates) leaves the model exactly as it was.
 * n = 0 is a no-op. Not thread-safe: no other call may use `m` meanwhile. Does not allocate;
 * uses up to NF_TRAINING_STACK_BYTES (192 KiB) of the caller's stack. */
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

/* The number of optimizer steps the model has taken (saved and restored with it). 0 for
 * NULL. Thread-safe. */
NF_API uint64_t nf_model_step_count(const nf_model *m);

/* Changes the AdamW learning rate of an existing model (for schedules): in
 * [NF_LEARNING_RATE_MIN, NF_LEARNING_RATE_MAX] = [1e-9, 1] and below 1 / weight_decay, checked
 * as nf_model_create checks nf_config.learning_rate (NF_ERROR_INVALID_ARGUMENT otherwise, the
 * model unchanged). Not thread-safe. */
NF_API nf_status nf_model_set_learning_rate(nf_model *m, float learning_rate);

NF_EXTERN_C_END

#endif /* NISFLOW_TRAIN_H */
