/*
 * path.c - nf_path_training_samples (path.h): a path's training samples by the backward
 * radiance walk of docs/model-layer.md section 4, with Russian roulette as path.h states it.
 *
 * Three passes over the vertices, none of which writes before the last: validate every field
 * the walk reads, walk once to count the samples (so that a full buffer writes nothing), walk
 * again to write them. The walk is deterministic, so both walks make the same samples. It
 * runs in double precision: the products of many throughput factors stay finite where floats
 * would overflow, and a weight is kept only if it fits a float. Zero factors are exact zeros,
 * also in front of a tail that overflowed a double, so nothing becomes NaN.
 */
#include <float.h>
#include <math.h>

#include "internal.h"

#include <nisflow/path.h>

static const char *const fn = "nf_path_training_samples";

/* An RGB field: finite and >= 0. */
static nf_status check_rgb(size_t j, const char *field, const float v[3])
{
    for (int c = 0; c < 3; ++c) {
        if (!isfinite(v[c]))
            return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: vertices[%zu].%s[%d] = %g is not finite",
                           fn, j, field, c, (double)v[c]);
        if (v[c] < 0.0f)
            return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: vertices[%zu].%s[%d] = %g is negative",
                           fn, j, field, c, (double)v[c]);
    }
    return NF_OK;
}

/* A vector the library normalizes: finite with a squared length above 1e-30, the rule of
 * validate.c, so that nf_train_step accepts what this call returns. */
static nf_status check_vector(size_t j, const char *field, const float v[3])
{
    double len2 = (double)v[0] * v[0] + (double)v[1] * v[1] + (double)v[2] * v[2];
    if (!nf_all_finite(v, 3) || !(len2 > 1e-30))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                       "%s: vertices[%zu].%s is zero-length or not finite", fn, j, field);
    return NF_OK;
}

static nf_status check_vertex(size_t j, const nf_path_vertex *v)
{
    nf_status st;
    if ((st = check_rgb(j, "direct", v->direct)) != NF_OK ||
        (st = check_rgb(j, "beta", v->beta)) != NF_OK ||
        (st = check_rgb(j, "emitted", v->emitted)) != NF_OK)
        return st;
    if (!(v->emitted_mis >= 0.0f && v->emitted_mis <= 1.0f))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                       "%s: vertices[%zu].emitted_mis = %g is outside [0, 1]", fn, j,
                       (double)v->emitted_mis);
    if (!v->learn)
        return NF_OK;
    if (!nf_all_finite(v->ctx.position, 3))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: vertices[%zu].ctx.position is not finite",
                       fn, j);
    /* A zero normal marks a vertex in a medium (validate.c's rule), whose phase_g is read. */
    int medium = nf_context_in_medium(&v->ctx);
    if (medium && !(fabsf(v->ctx.phase_g) <= NF_PHASE_G_MAX))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                       "%s: vertices[%zu].ctx.phase_g = %g at a point in a medium is not finite "
                       "or beyond +-%g",
                       fn, j, (double)v->ctx.phase_g, (double)NF_PHASE_G_MAX);
    if ((!medium && (st = check_vector(j, "ctx.normal", v->ctx.normal)) != NF_OK) ||
        (st = check_vector(j, "ctx.wo", v->ctx.wo)) != NF_OK ||
        (st = check_vector(j, "dir", v->dir)) != NF_OK)
        return st;
    return check_rgb(j, "f_over_p", v->f_over_p);
}

/* The backward walk. With weight_out NULL it only counts; otherwise it writes the samples
 * in vertex order, knowing there are `total` of them (so the last vertex's sample, found
 * first, goes to index total - 1). Returns the number of samples. */
static size_t walk(size_t n, const nf_path_vertex *v, size_t total, nf_context *ctx_out,
                   float *dir_out, float *weight_out, size_t *vertex_out)
{
    double s[3] = {0.0, 0.0, 0.0}; /* radiance scattered from vertex j + 1 towards j */
    size_t found = 0;
    for (size_t j = n; j-- > 0;) {
        const nf_path_vertex *x = &v[j];
        if (x->learn) {
            double w = 0.0;
            for (int c = 0; c < 3; ++c)
                if (x->f_over_p[c] != 0.0f) /* 0 even where L_i overflowed */
                    w += (double)x->f_over_p[c] * ((double)x->emitted_mis * x->emitted[c] + s[c]);
            w /= 3.0;
            /* The float conversion is only defined in range. */
            float wf = w > 0.0 && w <= (double)FLT_MAX ? (float)w : 0.0f;
            if (wf > 0.0f) {
                ++found;
                if (weight_out) {
                    size_t i = total - found;
                    ctx_out[i] = x->ctx;
                    for (int c = 0; c < 3; ++c)
                        dir_out[3 * i + (size_t)c] = x->dir[c];
                    weight_out[i] = wf;
                    if (vertex_out)
                        vertex_out[i] = j;
                }
            }
        }
        /* A zero beta ends the path: what lies beyond counts 0, even if it overflowed to
         * Inf (so S is never NaN: no Inf - Inf, and no 0 * Inf). */
        for (int c = 0; c < 3; ++c)
            s[c] = (double)x->direct[c] +
                   (x->beta[c] != 0.0f
                        ? (double)x->beta[c] * ((double)x->emitted_mis * x->emitted[c] + s[c])
                        : 0.0);
    }
    return found;
}

nf_status nf_path_training_samples(size_t vertex_count, const nf_path_vertex *vertices,
                                   size_t capacity, nf_context *ctx_out, float *dir_out,
                                   float *weight_out, size_t *vertex_out, size_t *count_out)
{
    if (!count_out)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: count_out is NULL", fn);
    if (vertex_count > NF_PATH_MAX_VERTICES)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: vertex_count = %zu is above %u", fn,
                       vertex_count, NF_PATH_MAX_VERTICES);
    if (vertex_count > 0 && !vertices)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: vertices is NULL with vertex_count = %zu",
                       fn, vertex_count);
    if (capacity > 0 && (!ctx_out || !dir_out || !weight_out))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: %s is NULL with capacity = %zu", fn,
                       !ctx_out   ? "ctx_out"
                       : !dir_out ? "dir_out"
                                  : "weight_out",
                       capacity);
    for (size_t j = 0; j < vertex_count; ++j) {
        nf_status st = check_vertex(j, &vertices[j]);
        if (st != NF_OK)
            return st;
    }
    size_t total = walk(vertex_count, vertices, 0, NULL, NULL, NULL, NULL);
    if (total > capacity) {
        *count_out = total;
        return nf_fail(NF_ERROR_CAPACITY, "%s: the path gives %zu samples, capacity is %zu", fn,
                       total, capacity);
    }
    if (total > 0) {
        size_t again =
            walk(vertex_count, vertices, total, ctx_out, dir_out, weight_out, vertex_out);
        (void)again; /* == total: the walk is deterministic */
    }
    *count_out = total;
    return NF_OK;
}
