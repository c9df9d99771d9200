/*
 * train.c - the weighted negative log-likelihood (docs/theory.md section 6), its gradient, AdamW,
 * and parameter access.
 */
#include <math.h>
#include <stdint.h>
#include <string.h>

#include "internal.h"
#include "gradient.h"
#include "kernels/kernels.h"

/* Validates a training batch and returns the sum of its weights in *total. */
static nf_status nf_validate_training(const char *fn, const nf_model *m, size_t n,
                                      const nf_context *ctx, const float *dir, const float *weight,
                                      double *total)
{
    *total = 0.0;
    if (!m)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: model is NULL", fn);
    return nf_validate_samples(fn, n, ctx, dir, weight, total, NULL);
}

/* A valid batch can still give a non-finite loss or gradient when the parameters are extreme
 * (an MLP that overflows, a density beyond double's range). That is NF_ERROR_NUMERIC, not a
 * bad argument: before this check nf_train_step passed the gradient on to nf_apply_gradient,
 * which refused it as NF_ERROR_INVALID_ARGUMENT. */
static nf_status nf_check_result(const char *fn, double loss, const float *grad, size_t count)
{
    if (!isfinite(loss) || !nf_all_finite(grad, count))
        return nf_fail(NF_ERROR_NUMERIC,
                       "%s: the loss or its gradient is not finite for this "
                       "batch (extreme parameters?); the model is unchanged",
                       fn);
    return NF_OK;
}

/* nf_loss_gradient and nf_loss_gradient_with_work; work NULL: the kernels' stack. */
static nf_status nf_loss_gradient_in(const char *fn, const nf_model *m, size_t n,
                                     const nf_context *ctx, const float *dir, const float *weight,
                                     float *loss, float *grad, void *work)
{
    double total = 0.0, value = 0.0;
    nf_status st = nf_validate_training(fn, m, n, ctx, dir, weight, &total);
    if (st != NF_OK)
        return st;
    if (!grad)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: grad is NULL", fn);
    memset(grad, 0, m->param_count * sizeof(float));
    if (total > 0.0 &&
        (st = m->kernels->gradient(m, n, ctx, dir, weight, total, &value, grad, work)) != NF_OK)
        return st;
    if (total > 0.0 && (st = nf_check_result(fn, value, grad, m->param_count)) != NF_OK)
        return st;
    if (loss)
        *loss = (float)value;
    return NF_OK;
}

nf_status nf_loss_gradient(const nf_model *m, size_t n, const nf_context *ctx, const float *dir,
                           const float *weight, float *loss, float *grad)
{
    return nf_loss_gradient_in("nf_loss_gradient", m, n, ctx, dir, weight, loss, grad, NULL);
}

size_t nf_training_work_bytes(void)
{
    size_t bytes = nf_kernels_generic.gradient_work_bytes;
#if defined(NF_HAVE_X86_KERNELS)
    if (nf_kernels_avx2.gradient_work_bytes > bytes)
        bytes = nf_kernels_avx2.gradient_work_bytes;
    if (nf_kernels_avx512.gradient_work_bytes > bytes)
        bytes = nf_kernels_avx512.gradient_work_bytes;
#endif
    return bytes + NF_WORK_ALIGN - 1u; /* room to align any pointer */
}

nf_status nf_loss_gradient_with_work(const nf_model *m, size_t n, const nf_context *ctx,
                                     const float *dir, const float *weight, float *loss,
                                     float *grad, void *work, size_t work_bytes)
{
    static const char fn[] = "nf_loss_gradient_with_work";
    size_t need = nf_training_work_bytes();
    if (!work)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: work is NULL", fn);
    if (work_bytes < need)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                       "%s: work holds %zu bytes, the call needs %zu (nf_training_work_bytes)", fn,
                       work_bytes, need);
    uintptr_t at = ((uintptr_t)work + (NF_WORK_ALIGN - 1u)) & ~(uintptr_t)(NF_WORK_ALIGN - 1u);
    return nf_loss_gradient_in(fn, m, n, ctx, dir, weight, loss, grad, (void *)at);
}

/* One AdamW step with a gradient known to be finite; `fn` names the caller in errors. */
static nf_status nf_adamw_commit(nf_model *m, const float *grad, const char *fn)
{
    size_t count = m->param_count;
    const nf_config *c = &m->cfg;
    double t = (double)(m->step + 1);
    nf_adamw_step adam;
    adam.beta1 = c->beta1;
    adam.beta2 = c->beta2;
    adam.epsilon = c->adam_epsilon;
    float bias1 = (float)(1.0 - pow((double)c->beta1, t));
    float bias2 = (float)(1.0 - pow((double)c->beta2, t));
    adam.step_size = c->learning_rate / bias1;
    adam.inv_sqrt_bias2 = 1.0f / sqrtf(bias2);
    adam.decay = 1.0f - c->learning_rate * c->weight_decay;
    /* The step is computed into staging and committed only if every value is finite, so a
     * refused step leaves the model exactly as it was. */
    if (!m->kernels->adamw(&adam, count, grad, m->params, m->adam_m, m->adam_v, m->staging,
                           m->staging + count, m->staging + 2 * count))
        return nf_fail(NF_ERROR_NUMERIC, "%s: the step would make a parameter non-finite", fn);
    /* Commit by exchanging the two banks of (params, adam_m, adam_v) rather than copying
     * 3 count floats back (about 3 us per step for the small preset). */
    float *committed = m->staging;
    m->staging = m->params;
    m->params = committed;
    m->adam_m = committed + count;
    m->adam_v = committed + 2 * count;
    nf_model_pack(m);
    m->step += 1;
    return NF_OK;
}

nf_status nf_apply_gradient(nf_model *m, const float *grad)
{
    static const char fn[] = "nf_apply_gradient";
    if (!m || !grad)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: %s is NULL", fn, !m ? "m" : "grad");
    if (!nf_all_finite(grad, m->param_count))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: gradient contains NaN or Inf", fn);
    return nf_adamw_commit(m, grad, fn);
}

nf_status nf_train_step(nf_model *m, size_t n, const nf_context *ctx, const float *dir,
                        const float *weight, float *loss)
{
    static const char fn[] = "nf_train_step";
    double total = 0.0, value = 0.0;
    nf_status st = nf_validate_training(fn, m, n, ctx, dir, weight, &total);
    if (st != NF_OK)
        return st;
    if (total > 0.0) {
        memset(m->grad, 0, m->param_count * sizeof(float));
        if ((st = m->kernels->gradient(m, n, ctx, dir, weight, total, &value, m->grad, NULL)) !=
                NF_OK ||
            (st = nf_check_result(fn, value, m->grad, m->param_count)) != NF_OK ||
            (st = nf_adamw_commit(m, m->grad, fn)) != NF_OK)
            return st;
    }
    if (loss)
        *loss = (float)value;
    return NF_OK;
}

size_t nf_model_param_count(const nf_model *m) { return m ? m->param_count : 0; }

nf_status nf_model_get_params(const nf_model *m, float *params)
{
    if (!m || !params)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "nf_model_get_params: %s is NULL",
                       !m ? "m" : "params");
    memcpy(params, m->params, m->param_count * sizeof(float));
    return NF_OK;
}

nf_status nf_model_set_params(nf_model *m, const float *params)
{
    if (!m || !params)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "nf_model_set_params: %s is NULL",
                       !m ? "m" : "params");
    if (!nf_all_finite(params, m->param_count))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "nf_model_set_params: params contain NaN or Inf");
    memcpy(m->params, params, m->param_count * sizeof(float));
    nf_model_pack(m);
    return NF_OK;
}

uint64_t nf_model_step_count(const nf_model *m) { return m ? m->step : 0; }

nf_status nf_model_set_learning_rate(nf_model *m, float learning_rate)
{
    if (!m)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "nf_model_set_learning_rate: model is NULL");
    /* The same check as nf_model_create's, on the configuration it would leave. */
    nf_config next = m->cfg;
    next.learning_rate = learning_rate;
    nf_status st = nf_config_validate(&next, "nf_model_set_learning_rate");
    if (st != NF_OK)
        return st;
    m->cfg.learning_rate = learning_rate;
    return NF_OK;
}
