/*
 * validate.c - checks of batch inputs shared by every entry point, so that each refusal
 * names the argument and the index at fault.
 */
#include <math.h>
#include <stdint.h>

#include "internal.h"

int nf_all_finite(const float *v, size_t n) { return nf_floats_finite(v, n); }

nf_status nf_validate_batch_size(const char *fn, size_t n)
{
    /* The largest per-sample array is 3 floats (directions); the caller's byte counts must
     * be representable. */
    if (n > SIZE_MAX / (3u * sizeof(float)))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: n = %zu is too large", fn, n);
    return NF_OK;
}

static int nf_vector_usable(const float v[3])
{
    if (!nf_all_finite(v, 3))
        return 0;
    double len2 = (double)v[0] * v[0] + (double)v[1] * v[1] + (double)v[2] * v[2];
    /* Directions are normalized in float: a squared length below FLT_MIN-ish would
     * underflow to a zero vector. */
    return len2 > 1e-30;
}

nf_status nf_validate_contexts(const char *fn, size_t n, const nf_context *ctx)
{
    for (size_t i = 0; i < n; ++i) {
        if (!nf_all_finite(ctx[i].position, 3))
            return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: ctx[%zu].position is not finite", fn, i);
        /* A zero normal marks a point in a medium; any other normal must normalize. */
        int medium = nf_context_in_medium(&ctx[i]);
        if (!medium && !nf_vector_usable(ctx[i].normal))
            return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                           "%s: ctx[%zu].normal is not finite or too short to normalize "
                           "(exactly zero marks a point in a medium)",
                           fn, i);
        if (!nf_vector_usable(ctx[i].wo))
            return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                           "%s: ctx[%zu].wo is zero-length or not finite", fn, i);
        /* phase_g is read only in a medium: on surfaces, contexts filled before 0.5.0, which
         * leave it uninitialized, stay valid. */
        if (medium && !(fabsf(ctx[i].phase_g) <= NF_PHASE_G_MAX))
            return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                           "%s: ctx[%zu].phase_g = %g at a point in a medium is not finite or "
                           "beyond +-%g",
                           fn, i, (double)ctx[i].phase_g, (double)NF_PHASE_G_MAX);
    }
    return NF_OK;
}

nf_status nf_validate_directions(const char *fn, const char *name, size_t n, const float *dir)
{
    for (size_t i = 0; i < n; ++i)
        if (!nf_vector_usable(dir + 3 * i))
            return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: %s[%zu] is zero-length or not finite",
                           fn, name, i);
    return NF_OK;
}

nf_status nf_check_pointers(const char *fn, const char *name0, const void *p0, const char *name1,
                            const void *p1, const char *name2, const void *p2, const char *name3,
                            const void *p3)
{
    const char *names[4] = {name0, name1, name2, name3};
    const void *ptrs[4] = {p0, p1, p2, p3};
    for (int i = 0; i < 4 && names[i]; ++i)
        if (!ptrs[i])
            return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: %s is NULL", fn, names[i]);
    return NF_OK;
}

nf_status nf_validate_samples(const char *fn, size_t n, const nf_context *ctx, const float *dir,
                              const float *weight, double *total, size_t *positive)
{
    double sum = 0.0;
    size_t kept = 0;
    if (n > 0) {
        nf_status st;
        if ((st = nf_check_pointers(fn, "ctx", ctx, "dir", dir, "weight", weight, NULL, NULL)) !=
                NF_OK ||
            (st = nf_validate_batch_size(fn, n)) != NF_OK ||
            (st = nf_validate_contexts(fn, n, ctx)) != NF_OK ||
            (st = nf_validate_directions(fn, "dir", n, dir)) != NF_OK)
            return st;
        for (size_t i = 0; i < n; ++i) {
            if (!(weight[i] >= 0.0f) || !isfinite(weight[i]))
                return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                               "%s: weight[%zu] = %g is negative or not finite", fn, i,
                               (double)weight[i]);
            sum += weight[i];
            kept += weight[i] > 0.0f;
        }
    }
    if (total)
        *total = sum;
    if (positive)
        *positive = kept;
    return NF_OK;
}
