/*
 * point.c - the public shading-point API (nisflow/point.h): validation of points and inputs,
 * then the kernels (point.h, through kernel.c) of the model's instruction set.
 */
#include "internal.h"
#include "point_batch.h"
#include "kernels/kernels.h"

#if UINTPTR_MAX == UINT64_MAX
/* nf_point_hash reads the header as 64-bit words: it must have no padding, whose bytes a copy
 * of the point need not keep. */
_Static_assert(
    offsetof(nf_shading_point, check_) == 104 && offsetof(nf_shading_point, context_) == 0 &&
        offsetof(nf_shading_point, magic_) == 40 && offsetof(nf_shading_point, cached_) == 44 &&
        offsetof(nf_shading_point, model_id_) == 48 &&
        offsetof(nf_shading_point, generation_) == 56 && offsetof(nf_shading_point, prior_) == 64 &&
        offsetof(nf_shading_point, frame_) == 88 && offsetof(nf_shading_point, zero_) == 100 &&
        offsetof(nf_shading_point, cache_) == 128,
    "the shading point's header is 104 bytes without padding");
#endif

/* A point is usable with `m` when its header is intact, it was prepared on `m`, and m's
 * parameters have not changed since. `i` names the point in messages (SIZE_MAX: the only
 * one). */
nf_status nf_point_usable(const char *fn, const nf_model *m, const nf_shading_point *p, size_t i)
{
    const char *why;
    nf_status st = NF_ERROR_INVALID_ARGUMENT;
    if (p->magic_ != NF_POINT_MAGIC || p->check_ != nf_point_hash(p)) {
        why = "is not a prepared shading point (never prepared, or overwritten): call "
              "nf_point_prepare first";
    } else if (p->model_id_ != m->id) {
        why = "was prepared on another model";
    } else if (nf_generation_moved(m, p->generation_)) {
        why = "was prepared before or while the model's parameters last changed (a training "
              "step, nf_model_set_params or nf_apply_gradient): prepare it again";
        st = NF_ERROR_STALE;
    } else {
        return NF_OK;
    }
    if (i == SIZE_MAX)
        return nf_fail(st, "%s: the point %s", fn, why);
    return nf_fail(st, "%s: points[%zu] %s", fn, i, why);
}

/* A call that overlapped a change of the weights on another thread may have read a mix of two
 * models: its results are refused, not returned as valid. */
nf_status nf_point_checked(const char *fn, const nf_model *m, uint64_t seen, nf_status st)
{
    if (nf_generation_moved(m, seen))
        return nf_fail(NF_ERROR_STALE,
                       "%s: the model's parameters changed during the call (a training step on "
                       "another thread): the outputs are unspecified; prepare the point again",
                       fn);
    return st;
}

nf_status nf_point_prepare(const nf_model *m, const nf_context *ctx,
                           const nf_prior_callbacks *prior, nf_shading_point *point)
{
    static const char fn[] = "nf_point_prepare";
    nf_status st;
    if ((st = nf_check_pointers(fn, "m", m, "ctx", ctx, "point", point, NULL, NULL)) != NF_OK ||
        (st = nf_validate_contexts(fn, 1, ctx)) != NF_OK)
        return st;
    if (prior) {
        if (m->cfg.prior != NF_PRIOR_CUSTOM)
            return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                           "%s: per-point prior callbacks need a model with NF_PRIOR_CUSTOM "
                           "(this one has prior %u)",
                           fn, (unsigned)m->cfg.prior);
        if (!prior->sample || !prior->pdf)
            return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: prior->sample or prior->pdf is NULL",
                           fn);
    }
    /* Validated before anything is written: a failed call leaves a valid point valid. The
     * context is copied first, so that ctx may alias the point's own copy. */
    nf_context copy = *ctx;
    m->kernels->point_prepare(m, &copy, prior, point);
    point->check_ = nf_point_hash(point); /* what every later call verifies */
    return NF_OK;
}

nf_status nf_point_sample(const nf_model *m, const nf_shading_point *point, size_t n,
                          const float *u, float *dir, float *pdf)
{
    static const char fn[] = "nf_point_sample";
    nf_status st;
    /* The model and the point are checked even for n = 0 (the arrays may then be NULL). */
    if ((st = nf_check_pointers(fn, "m", m, "point", point, NULL, NULL, NULL, NULL)) != NF_OK ||
        (st = nf_point_usable(fn, m, point, SIZE_MAX)) != NF_OK || n == 0)
        return st;
    if ((st = nf_check_pointers(fn, "u", u, "dir", dir, NULL, NULL, NULL, NULL)) != NF_OK ||
        (st = nf_validate_batch_size(fn, n)) != NF_OK)
        return st;
    if (!nf_all_finite(u, 2 * n))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: u contains NaN or Inf", fn);
    return nf_point_checked(fn, m, point->generation_,
                            m->kernels->point_sample(m, point, n, 0, u, dir, pdf));
}

nf_status nf_point_pdf(const nf_model *m, const nf_shading_point *point, size_t n, const float *dir,
                       float *pdf)
{
    static const char fn[] = "nf_point_pdf";
    nf_status st;
    if ((st = nf_check_pointers(fn, "m", m, "point", point, NULL, NULL, NULL, NULL)) != NF_OK ||
        (st = nf_point_usable(fn, m, point, SIZE_MAX)) != NF_OK || n == 0)
        return st;
    if ((st = nf_check_pointers(fn, "dir", dir, "pdf", pdf, NULL, NULL, NULL, NULL)) != NF_OK ||
        (st = nf_validate_batch_size(fn, n)) != NF_OK ||
        (st = nf_validate_directions(fn, "dir", n, dir)) != NF_OK)
        return st;
    return nf_point_checked(fn, m, point->generation_,
                            m->kernels->point_pdf(m, point, n, 0, dir, pdf));
}

nf_status nf_point_sample_and_pdf(const nf_model *m, const nf_shading_point *point,
                                  const float u[2], float dir[3], float *pdf,
                                  const float eval_dir[3], float *eval_pdf)
{
    static const char fn[] = "nf_point_sample_and_pdf";
    nf_status st;
    if ((st = nf_check_pointers(fn, "m", m, "point", point, "u", u, "dir", dir)) != NF_OK ||
        (st = nf_check_pointers(fn, "eval_dir", eval_dir, "eval_pdf", eval_pdf, NULL, NULL, NULL,
                                NULL)) != NF_OK ||
        (st = nf_point_usable(fn, m, point, SIZE_MAX)) != NF_OK)
        return st;
    if (!nf_all_finite(u, 2))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: u contains NaN or Inf", fn);
    if ((st = nf_validate_directions(fn, "eval_dir", 1, eval_dir)) != NF_OK)
        return st;
    return nf_point_checked(
        fn, m, point->generation_,
        m->kernels->point_sample_and_pdf(m, point, u, dir, pdf, eval_dir, eval_pdf));
}

static nf_status nf_points_usable(const char *fn, const nf_model *m, size_t n,
                                  const nf_shading_point *points)
{
    for (size_t i = 0; i < n; ++i) {
        nf_status st = nf_point_usable(fn, m, &points[i], i);
        if (st != NF_OK)
            return st;
    }
    return NF_OK;
}

nf_status nf_point_sample_batch(const nf_model *m, size_t n, const nf_shading_point *points,
                                const float *u, float *dir, float *pdf)
{
    static const char fn[] = "nf_point_sample_batch";
    nf_status st;
    if ((st = nf_check_pointers(fn, "m", m, NULL, NULL, NULL, NULL, NULL, NULL)) != NF_OK || n == 0)
        return st;
    if ((st = nf_check_pointers(fn, "points", points, "u", u, "dir", dir, NULL, NULL)) != NF_OK ||
        (st = nf_validate_batch_size(fn, n)) != NF_OK ||
        (st = nf_points_usable(fn, m, n, points)) != NF_OK)
        return st;
    if (!nf_all_finite(u, 2 * n))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: u contains NaN or Inf", fn);
    return nf_point_checked(fn, m, points[0].generation_,
                            m->kernels->point_sample(m, points, n, 1, u, dir, pdf));
}

nf_status nf_point_pdf_batch(const nf_model *m, size_t n, const nf_shading_point *points,
                             const float *dir, float *pdf)
{
    static const char fn[] = "nf_point_pdf_batch";
    nf_status st;
    if ((st = nf_check_pointers(fn, "m", m, NULL, NULL, NULL, NULL, NULL, NULL)) != NF_OK || n == 0)
        return st;
    if ((st = nf_check_pointers(fn, "points", points, "dir", dir, "pdf", pdf, NULL, NULL)) !=
            NF_OK ||
        (st = nf_validate_batch_size(fn, n)) != NF_OK ||
        (st = nf_points_usable(fn, m, n, points)) != NF_OK ||
        (st = nf_validate_directions(fn, "dir", n, dir)) != NF_OK)
        return st;
    return nf_point_checked(fn, m, points[0].generation_,
                            m->kernels->point_pdf(m, points, n, 1, dir, pdf));
}
