/*
 * flow.c - the public nf_sample and nf_pdf: validation of the whole batch, then the kernels
 * (kernel.c) for the model's instruction set.
 */
#include "internal.h"
#include "kernels/kernels.h"

nf_status nf_sample(const nf_model *m, size_t n, const nf_context *ctx, const float *u, float *dir,
                    float *pdf)
{
    static const char fn[] = "nf_sample";
    if (n == 0)
        return NF_OK;
    if (!m || !ctx || !u || !dir)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: NULL model, ctx, u or dir", fn);
    nf_status st;
    if ((st = nf_validate_batch_size(fn, n)) != NF_OK ||
        (st = nf_validate_contexts(fn, n, ctx)) != NF_OK)
        return st;
    if (!nf_all_finite(u, 2 * n))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: u contains NaN or Inf", fn);
    return m->kernels->sample(m, n, ctx, u, dir, pdf);
}

nf_status nf_pdf(const nf_model *m, size_t n, const nf_context *ctx, const float *dir, float *pdf)
{
    static const char fn[] = "nf_pdf";
    if (n == 0)
        return NF_OK;
    if (!m || !ctx || !dir || !pdf)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: NULL model, ctx, dir or pdf", fn);
    nf_status st;
    if ((st = nf_validate_batch_size(fn, n)) != NF_OK ||
        (st = nf_validate_contexts(fn, n, ctx)) != NF_OK ||
        (st = nf_validate_directions(fn, "dir", n, dir)) != NF_OK)
        return st;
    return m->kernels->pdf(m, n, ctx, dir, pdf);
}
