/*
 * gradient_sum.c - the exact sum of gradient_sum.h: group gradients on threads, a fixed-point
 * scale agreed by all ranks (one max-reduction of four doubles), then one integer sum of
 * params + 2 values over the ranks.
 */
#include "gradient_sum.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "parallel.h"
#include "ranks.h"

/* Terms are scaled so that (the largest |term|) x (the number of groups) < 2^62: any sum of
 * them fits an int64 with a bit to spare. */
#define FIXED_BITS 62

void gradient_sum_free(gradient_sum *g)
{
    free(g->grads);
    free(g->F);
    free(g->FL);
    free(g->status);
    free(g->messages);
    free(g->fixed);
    free(g->mean);
    memset(g, 0, sizeof *g);
}

static int reserve(gradient_sum *g, size_t params, size_t groups, tr_error *err)
{
    if (g->params == params && g->capacity >= groups && g->fixed)
        return 1;
    gradient_sum_free(g);
    size_t cap = groups ? groups : 1;
    g->grads = malloc(cap * params * sizeof *g->grads);
    g->F = malloc(cap * sizeof *g->F);
    g->FL = malloc(cap * sizeof *g->FL);
    g->status = malloc(cap * sizeof *g->status);
    g->messages = malloc(cap * sizeof *g->messages);
    g->fixed = malloc((params + 2) * sizeof *g->fixed);
    g->mean = malloc(params * sizeof *g->mean);
    if (!g->grads || !g->F || !g->FL || !g->status || !g->messages || !g->fixed || !g->mean) {
        gradient_sum_free(g);
        return tr_fail(err, "out of memory for the gradients of %zu groups", cap);
    }
    g->params = params;
    g->capacity = cap;
    return 1;
}

typedef struct group_job {
    gradient_sum *g;
    const nf_model *m;
    const nf_context *ctx;
    const float *dir, *weight;
    const size_t *group_end;
} group_job;

static void group_gradient(void *user, size_t k, int thread)
{
    (void)thread;
    group_job *j = user;
    size_t b = k ? j->group_end[k - 1] : 0, e = j->group_end[k];
    double F = 0.0;
    for (size_t i = b; i < e; ++i)
        F += j->weight[i];
    float loss = 0.0f;
    j->g->status[k] = nf_loss_gradient(j->m, e - b, j->ctx + b, j->dir + 3 * b, j->weight + b,
                                       &loss, j->g->grads + k * j->g->params);
    if (j->g->status[k] != NF_OK) /* the message is this thread's: keep it with the group */
        snprintf(j->g->messages[k], sizeof j->g->messages[k], "%s", nf_last_error_message());
    j->g->F[k] = F;
    j->g->FL[k] = F * (double)loss;
}

/* The power of two that scales terms up to `largest` (over `groups` groups) into the fixed
 * point: largest x groups x 2^s < 2^FIXED_BITS. */
static int fixed_scale(double largest, size_t groups)
{
    if (!(largest > 0.0))
        return 0;
    int e;
    frexp(largest * (double)groups, &e); /* largest x groups < 2^e */
    return FIXED_BITS - e;
}

static int64_t to_fixed(double x, int scale)
{
    return (int64_t)llrint(ldexp(x, scale));
}

int gradient_sum_step(gradient_sum *g, nf_model *m, const nf_context *ctx, const float *dir,
                      const float *weight, const size_t *group_end, size_t groups,
                      size_t total_groups, int threads, float *loss, gradient_step *step,
                      nf_status *refusal, tr_error *err)
{
    const size_t P = nf_param_count(m);
    *loss = NAN;
    *step = GRADIENT_STEP_REFUSED;
    *refusal = NF_OK;
    g->message[0] = '\0';
    group_job job = {g, m, ctx, dir, weight, group_end};
    /* Groups without samples (a rank whose share is empty) need no threads started. */
    int busy = groups > 0 && group_end[groups - 1] > 0;
    int ok = reserve(g, P, groups, err) &&
             (groups == 0 ||
              parallel_for(groups, busy ? threads : 1, group_gradient, &job, NULL, err));
    /* A rank out of memory must not leave the others waiting in the reductions below. */
    if (!ranks_agree(ok, err))
        return 0;

    /* The largest terms, and the worst refusal, over all ranks: max is exact in any order. */
    double top[4] = {0.0, 0.0, 0.0, 0.0}; /* |F grad|, F, |F loss|, refusal status */
    for (size_t k = 0; k < groups; ++k) {
        if (g->status[k] != NF_OK) {
            if (top[3] == 0.0)
                snprintf(g->message, sizeof g->message, "%s", g->messages[k]);
            top[3] = fmax(top[3], (double)g->status[k]);
            continue;
        }
        const float *gr = g->grads + k * P;
        for (size_t p = 0; p < P; ++p)
            top[0] = fmax(top[0], fabs(g->F[k] * (double)gr[p]));
        top[1] = fmax(top[1], g->F[k]);
        top[2] = fmax(top[2], fabs(g->FL[k]));
    }
    if (!ranks_max_f64(top, 4, err))
        return 0;
    if (top[3] > 0.0) { /* refused somewhere: nobody steps */
        *refusal = (nf_status)(int)top[3];
        return 1;
    }
    int s_grad = fixed_scale(top[0], total_groups), s_F = fixed_scale(top[1], total_groups),
        s_FL = fixed_scale(top[2], total_groups);
    memset(g->fixed, 0, (P + 2) * sizeof *g->fixed);
    for (size_t k = 0; k < groups; ++k) {
        const float *gr = g->grads + k * P;
        for (size_t p = 0; p < P; ++p)
            g->fixed[p] += to_fixed(g->F[k] * (double)gr[p], s_grad);
        g->fixed[P] += to_fixed(g->F[k], s_F);
        g->fixed[P + 1] += to_fixed(g->FL[k], s_FL);
    }
    if (!ranks_sum_i64(g->fixed, P + 2, err))
        return 0;
    double F = ldexp((double)g->fixed[P], -s_F);
    if (!(F > 0.0)) {
        *step = GRADIENT_STEP_EMPTY;
        *loss = 0.0f;
        return 1;
    }
    for (size_t p = 0; p < P; ++p)
        g->mean[p] = (float)(ldexp((double)g->fixed[p], -s_grad) / F);
    nf_status st = nf_apply_gradient(m, g->mean);
    if (st != NF_OK) { /* the same on every rank: the same model and gradient */
        *refusal = st;
        snprintf(g->message, sizeof g->message, "%s", nf_last_error_message());
        return 1;
    }
    *loss = (float)(ldexp((double)g->fixed[P + 1], -s_FL) / F);
    *step = GRADIENT_STEP_TAKEN;
    return 1;
}
