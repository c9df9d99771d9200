/*
 * flow.c - the public nf_sample and nf_pdf: validation of the whole batch, then the kernels
 * (kernel.c) for the model's instruction set.
 */
#include "internal.h"
#include "kernels/kernels.h"

/* Sampling is not thread-safe with a change of the model (model.h); a call that overlaps one
 * on another thread is detected and refused rather than answered with a mix of two models. */
static nf_status nf_changing(const char *fn)
{
    return nf_fail(NF_ERROR_STALE,
                   "%s: the model's parameters changed during the call (a training step on "
                   "another thread): the outputs are unspecified; train and sample one model "
                   "in turn, or through a guide (guide.h)",
                   fn);
}

nf_status nf_sample(const nf_model *m, size_t n, const nf_context *ctx, const float *u, float *dir,
                    float *pdf)
{
    static const char fn[] = "nf_sample";
    nf_status st;
    /* The model is checked even for n = 0 (the arrays may then be NULL). */
    if ((st = nf_check_pointers(fn, "m", m, NULL, NULL, NULL, NULL, NULL, NULL)) != NF_OK)
        return st;
    if (n == 0)
        return NF_OK;
    if ((st = nf_check_pointers(fn, "ctx", ctx, "u", u, "dir", dir, NULL, NULL)) != NF_OK ||
        (st = nf_validate_batch_size(fn, n)) != NF_OK ||
        (st = nf_validate_contexts(fn, n, ctx)) != NF_OK)
        return st;
    if (!nf_all_finite(u, 2 * n))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: u contains NaN or Inf", fn);
    uint64_t seen = nf_generation_read(m);
    if (seen & 1u)
        return nf_changing(fn);
    st = m->kernels->sample(m, n, ctx, u, dir, pdf);
    return nf_generation_moved(m, seen) ? nf_changing(fn) : st;
}

nf_status nf_pdf(const nf_model *m, size_t n, const nf_context *ctx, const float *dir, float *pdf)
{
    static const char fn[] = "nf_pdf";
    nf_status st;
    if ((st = nf_check_pointers(fn, "m", m, NULL, NULL, NULL, NULL, NULL, NULL)) != NF_OK)
        return st;
    if (n == 0)
        return NF_OK;
    if ((st = nf_check_pointers(fn, "ctx", ctx, "dir", dir, "pdf", pdf, NULL, NULL)) != NF_OK ||
        (st = nf_validate_batch_size(fn, n)) != NF_OK ||
        (st = nf_validate_contexts(fn, n, ctx)) != NF_OK ||
        (st = nf_validate_directions(fn, "dir", n, dir)) != NF_OK)
        return st;
    uint64_t seen = nf_generation_read(m);
    if (seen & 1u)
        return nf_changing(fn);
    st = m->kernels->pdf(m, n, ctx, dir, pdf);
    return nf_generation_moved(m, seen) ? nf_changing(fn) : st;
}
