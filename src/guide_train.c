/*
 * guide_train.c - the guide's training (nisflow/guide.h): a pass's samples sorted into the
 * store, the running clamp of the weights, the held-out loss and its patience, and the step
 * sharded into gradient groups whose weighted sum is exact.
 *
 * The exact sum. The step's gradient is  sum_k F_k grad_k / sum_k F_k  over groups k (train.h,
 * "Sharded training"). Summed in floating point it would depend on the order of the additions,
 * so on the threads and on the order in which an allreduce adds. Each term is instead rounded
 * once to a 62-bit integer (a fixed point whose scale is set by the largest term of any
 * process, so that no sum overflows) and the integers are summed, exactly and in any order.
 * A term is rounded to 2^-62 of (the largest term x the number of groups), far below float's
 * 2^-24 for every component within 2^30 of the largest; smaller components, which AdamW's
 * normalisation turns into noise anyway, lose their low bits.
 */
#include <math.h>
#include <stdio.h>

#include "gradient.h"
#include "guide_internal.h"

#define NF_FIXED_BITS 62

/* ---- Random draws: PCG32 (O'Neill), the same sequence on every platform ----------------- */

static uint32_t nf_guide_next_u32(uint64_t *state)
{
    uint64_t old = *state;
    *state = old * 6364136223846793005ull + 1442695040888963407ull;
    uint32_t x = (uint32_t)(((old >> 18u) ^ old) >> 27u), rot = (uint32_t)(old >> 59u);
    return (x >> rot) | (x << ((32u - rot) & 31u));
}

/* A draw in [0, n), n >= 1: the 64-bit product keeps the bias below n / 2^32. */
static size_t nf_guide_below(uint64_t *state, size_t n)
{
    return (size_t)(((uint64_t)nf_guide_next_u32(state) * (uint64_t)n) >> 32u);
}

/* ---- The reductions ------------------------------------------------------------------------ */

static nf_status nf_reduce_max(const nf_reduce *red, double *v, size_t n, const char *fn)
{
    if (!red || !red->max_f64)
        return NF_OK;
    nf_status st = red->max_f64(red->user, v, n);
    return st == NF_OK ? NF_OK : nf_fail(st, "%s: the reduce hook max_f64 failed", fn);
}

static nf_status nf_reduce_sum(const nf_reduce *red, int64_t *v, size_t n, const char *fn)
{
    if (!red || !red->sum_i64)
        return NF_OK;
    nf_status st = red->sum_i64(red->user, v, n);
    return st == NF_OK ? NF_OK : nf_fail(st, "%s: the reduce hook sum_i64 failed", fn);
}

/* ---- One sharded step ------------------------------------------------------------------------ */

typedef struct nf_group_job {
    nf_guide *g;
    size_t n;
    const nf_context *ctx;
    const float *dir, *weight;
    const size_t *group_end; /* NULL: equal groups */
    size_t groups;
} nf_group_job;

static void nf_group_bounds(const nf_group_job *j, size_t k, size_t *b, size_t *e)
{
    if (j->group_end) {
        *b = k ? j->group_end[k - 1] : 0;
        *e = j->group_end[k];
    } else {
        *b = j->n * k / j->groups;
        *e = j->n * (k + 1) / j->groups;
    }
}

static void nf_group_task(void *data, size_t k)
{
    nf_group_job *j = (nf_group_job *)data;
    nf_guide *g = j->g;
    size_t b, e;
    nf_group_bounds(j, k, &b, &e);
    double F = 0.0;
    for (size_t i = b; i < e; ++i)
        F += j->weight[i];
    float loss = 0.0f;
    float *grad = g->grads + k * g->params;
    nf_status st =
        nf_loss_gradient(g->train, e - b, j->ctx + b, j->dir + 3 * b, j->weight + b, &loss, grad);
    g->group_status[k] = st;
    if (st != NF_OK) /* the message is this thread's: keep it with the group */
        snprintf(g->group_message[k], NF_GUIDE_MESSAGE, "%s", nf_last_error_message());
    g->F[k] = F;
    g->FL[k] = F * (double)loss;
    /* The group's largest term, for the fixed point's scale: max is exact in any order. */
    double top = 0.0;
    for (size_t p = 0; st == NF_OK && p < g->params; ++p)
        top = fmax(top, fabs(F * (double)grad[p]));
    g->group_top[k] = top;
}

static void nf_run_tasks(const nf_parallel *par, size_t count, nf_task_fn task, void *data)
{
    if (par && par->run) {
        par->run(par->user, count, task, data);
        return;
    }
    for (size_t i = 0; i < count; ++i)
        task(data, i);
}

/* largest x groups x 2^s < 2^NF_FIXED_BITS */
static int nf_fixed_scale(double largest, double groups)
{
    if (!(largest > 0.0))
        return 0;
    int e;
    frexp(largest * groups, &e);
    return NF_FIXED_BITS - e;
}

/* x 2^s rounded to an integer; `scale` is 2^s, so the product is exact (ldexp's result). */
static int64_t nf_to_fixed(double x, double scale) { return (int64_t)llrint(x * scale); }

/* The fixed-point sum of the groups' terms for a range of parameters: a second parallel phase
 * (integer sums: the same bits however the ranges are run). */
typedef struct nf_sum_job {
    nf_guide *g;
    size_t groups, chunks;
    double scale;
} nf_sum_job;

static void nf_sum_task(void *data, size_t c)
{
    const nf_sum_job *j = (const nf_sum_job *)data;
    nf_guide *g = j->g;
    const size_t P = g->params, p0 = P * c / j->chunks, p1 = P * (c + 1) / j->chunks;
    for (size_t k = 0; k < j->groups; ++k) {
        const float *gr = g->grads + k * P;
        const double F = g->F[k];
        for (size_t p = p0; p < p1; ++p)
            g->fixed[p] += nf_to_fixed(F * (double)gr[p], j->scale);
    }
}

/* What one step did. */
typedef enum { NF_STEP_TAKEN, NF_STEP_EMPTY, NF_STEP_REFUSED } nf_step_result;

/* One step of the training model on the job's samples: group gradients through `par`, the
 * exact sum through `red`, then AdamW. A status other than NF_OK is a failure of the hooks or
 * of the arguments; a model that refused (NF_ERROR_NUMERIC) is *result NF_STEP_REFUSED with
 * its status in *refusal, and the model unchanged on every process. */
static nf_status nf_sharded_step(nf_guide *g, nf_group_job *j, const nf_parallel *par,
                                 const nf_reduce *red, const char *fn, float *loss,
                                 nf_step_result *result, nf_status *refusal)
{
    const size_t P = g->params, G = j->groups;
    *loss = NAN;
    *result = NF_STEP_REFUSED;
    *refusal = NF_OK;
    if (j->n > 0)
        nf_run_tasks(par, G, nf_group_task, j);
    else
        for (size_t k = 0; k < G; ++k) { /* nothing here: no tasks to start */
            g->group_status[k] = NF_OK;
            g->F[k] = g->FL[k] = 0.0;
        }
    /* The largest terms and the worst refusal over all processes: max is exact in any order.
     * The group count is summed first, so that every process scales by the same total. */
    double top[4] = {0.0, 0.0, 0.0, 0.0}; /* |F grad|, F, |F loss|, status */
    size_t failed = G;
    for (size_t k = 0; k < G; ++k) {
        if (g->group_status[k] != NF_OK) {
            if (failed == G)
                failed = k;
            top[3] = fmax(top[3], (double)g->group_status[k]);
            continue;
        }
        if (j->n > 0)
            top[0] = fmax(top[0], g->group_top[k]);
        top[1] = fmax(top[1], g->F[k]);
        top[2] = fmax(top[2], fabs(g->FL[k]));
    }
    int64_t total_groups = (int64_t)G;
    nf_status st;
    if ((st = nf_reduce_sum(red, &total_groups, 1, fn)) != NF_OK ||
        (st = nf_reduce_max(red, top, 4, fn)) != NF_OK)
        return st;
    if (top[3] > 0.0) { /* refused somewhere: nobody steps */
        *refusal = (nf_status)(int)top[3];
        if (failed < G)
            nf_fail(*refusal, "%s: group %zu: %s", fn, failed, g->group_message[failed]);
        else
            nf_fail(*refusal, "%s: another process's gradient was refused", fn);
        return NF_OK;
    }
    double groups = (double)total_groups;
    int s_grad = nf_fixed_scale(top[0], groups), s_F = nf_fixed_scale(top[1], groups),
        s_FL = nf_fixed_scale(top[2], groups);
    memset(g->fixed, 0, (P + 2) * sizeof *g->fixed);
    if (j->n > 0) {
        nf_sum_job sum = {g, G, G, ldexp(1.0, s_grad)};
        nf_run_tasks(par, G, nf_sum_task, &sum);
        for (size_t k = 0; k < G; ++k) {
            g->fixed[P] += nf_to_fixed(g->F[k], ldexp(1.0, s_F));
            g->fixed[P + 1] += nf_to_fixed(g->FL[k], ldexp(1.0, s_FL));
        }
    }
    if ((st = nf_reduce_sum(red, g->fixed, P + 2, fn)) != NF_OK)
        return st;
    double F = ldexp((double)g->fixed[P], -s_F);
    if (!(F > 0.0)) {
        *result = NF_STEP_EMPTY;
        return NF_OK;
    }
    const double unscale = ldexp(1.0, -s_grad);
    for (size_t p = 0; p < P; ++p)
        g->mean[p] = (float)((double)g->fixed[p] * unscale / F);
    st = nf_apply_gradient(g->train, g->mean);
    if (st != NF_OK) { /* the same on every process: the same model and gradient */
        *refusal = st;
        return NF_OK;
    }
    *loss = (float)(ldexp((double)g->fixed[P + 1], -s_FL) / F);
    *result = NF_STEP_TAKEN;
    return NF_OK;
}

nf_status nf_guide_train_batch(nf_guide *g, size_t n, const nf_context *ctx, const float *dir,
                               const float *weight, const size_t *group_end, size_t ngroups,
                               const nf_parallel *par, const nf_reduce *red, float *loss)
{
    static const char fn[] = "nf_guide_train_batch";
    if (loss)
        *loss = NAN;
    if (!g)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: g is NULL", fn);
    if (group_end) {
        if (ngroups == 0 || ngroups > g->cfg.groups)
            return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                           "%s: ngroups = %zu is outside [1, %u] (the guide's groups)", fn, ngroups,
                           (unsigned)g->cfg.groups);
        for (size_t k = 0; k < ngroups; ++k)
            if (group_end[k] < (k ? group_end[k - 1] : 0) || group_end[k] > n)
                return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                               "%s: group_end[%zu] = %zu is below its predecessor or above n", fn,
                               k, group_end[k]);
        if (group_end[ngroups - 1] != n)
            return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: group_end[%zu] = %zu must be n = %zu",
                           fn, ngroups - 1, group_end[ngroups - 1], n);
    }
    /* Validate the whole batch before any process-wide call: a bad batch is refused here. */
    nf_status st = nf_validate_samples(fn, n, ctx, dir, weight, NULL, NULL);
    if (st != NF_OK)
        return st;
    st = nf_guide_begin_exclusive(g, fn);
    if (st != NF_OK)
        return st;
    nf_group_job job = {g, n, ctx, dir, weight, group_end, group_end ? ngroups : g->cfg.groups};
    float l;
    nf_step_result result;
    nf_status refusal;
    st = nf_sharded_step(g, &job, par, red, fn, &l, &result, &refusal);
    if (st == NF_OK && result == NF_STEP_REFUSED) {
        g->refused++;
        st = refusal;
    } else if (st == NF_OK && result == NF_STEP_TAKEN) {
        g->steps++;
        if (loss)
            *loss = l;
    }
    nf_guide_end_exclusive(g);
    return st;
}

/* ---- The pass ------------------------------------------------------------------------------ */

/* Orders staged samples: by key, then by their bytes, so that the order does not depend on
 * which thread added a sample first. */
static int nf_entry_before(const nf_guide *g, uint32_t a, uint32_t b)
{
    const nf_guide_entry *x = &g->drain[a], *y = &g->drain[b];
    if (x->key != y->key)
        return x->key < y->key;
    int c = memcmp(x, y, NF_GUIDE_ENTRY_BYTES);
    if (c == 0 && g->cfg.payload_bytes)
        c = memcmp(g->drain_payload + (size_t)a * g->cfg.payload_bytes,
                   g->drain_payload + (size_t)b * g->cfg.payload_bytes, g->cfg.payload_bytes);
    return c < 0;
}

/* Bottom-up merge sort of g->order[0, n) (stable, n log n, the scratch allocated at creation). */
static void nf_sort_staged(nf_guide *g, size_t n)
{
    uint32_t *src = g->order, *dst = g->order_tmp;
    for (size_t i = 0; i < n; ++i)
        src[i] = (uint32_t)i;
    for (size_t width = 1; width < n; width *= 2) {
        for (size_t lo = 0; lo < n; lo += 2 * width) {
            size_t mid = lo + width < n ? lo + width : n;
            size_t hi = lo + 2 * width < n ? lo + 2 * width : n;
            size_t a = lo, b = mid, o = lo;
            while (a < mid && b < hi)
                dst[o++] = nf_entry_before(g, src[b], src[a]) ? src[b++] : src[a++];
            while (a < mid)
                dst[o++] = src[a++];
            while (b < hi)
                dst[o++] = src[b++];
        }
        uint32_t *t = src;
        src = dst;
        dst = t;
    }
    if (src != g->order)
        memcpy(g->order, src, n * sizeof *src);
}

/* The k-th smallest of v[0, n), k < n (selection with a three-way partition; v is
 * reordered). The weights are finite, so every comparison is meaningful. */
static float nf_select(float *v, size_t n, size_t k)
{
    size_t lo = 0, hi = n; /* [lo, hi) holds the k-th */
    while (hi - lo > 1) {
        float pivot = v[lo + (hi - lo) / 2], t;
        size_t lt = lo, i = lo, gt = hi;
        while (i < gt) {
            if (v[i] < pivot) {
                t = v[lt], v[lt] = v[i], v[i] = t;
                ++lt, ++i;
            } else if (v[i] > pivot) {
                --gt;
                t = v[gt], v[gt] = v[i], v[i] = t;
            } else {
                ++i;
            }
        }
        if (k < lt)
            hi = lt;
        else if (k >= gt)
            lo = gt;
        else
            return pivot;
    }
    return v[lo];
}

/* Copies ring slot `slot` into the step arrays at i, with the running clamp. */
static void nf_load_sample(nf_guide *g, size_t i, size_t slot)
{
    const nf_guide_entry *e = &g->ring[slot];
    g->step_ctx[i] = e->ctx;
    memcpy(g->step_dir + 3 * i, e->dir, sizeof e->dir);
    g->step_weight[i] = g->clamp > 0.0f ? fminf(e->weight, g->clamp) : e->weight;
    g->step_slot[i] = slot;
}

/* A step on the first n samples of the step arrays; counts it and returns its loss (NaN when
 * none was taken). */
static nf_status nf_step_loaded(nf_guide *g, size_t n, const nf_parallel *par, const nf_reduce *red,
                                const char *fn, nf_guide_pass_report *rep, float *loss)
{
    g->step_n = n;
    g->step_payload_base = g->ring_payload;
    nf_group_job job = {g, n, g->step_ctx, g->step_dir, g->step_weight, NULL, g->cfg.groups};
    nf_step_result result;
    nf_status refusal;
    nf_status st = nf_sharded_step(g, &job, par, red, fn, loss, &result, &refusal);
    g->step_payload_base = NULL;
    g->step_n = 0;
    if (st != NF_OK)
        return st;
    if (result == NF_STEP_TAKEN) {
        g->steps++;
        rep->steps++;
    } else if (result == NF_STEP_REFUSED) {
        g->refused++;
        rep->refused++;
    }
    return NF_OK;
}

static nf_status nf_train_pass_locked(nf_guide *g, const nf_parallel *par, const nf_reduce *red,
                                      nf_guide_pass_report *rep, const char *fn)
{
    const size_t cap = g->cfg.store_capacity, pb = g->cfg.payload_bytes;
    /* The samples added up to now; adds from here on fill the other stage for the next pass. */
    const int drained = nf_guide_swap_intake(g);
    size_t staged = atomic_load(&g->staged[drained]);
    size_t n = staged < cap ? staged : cap;
    atomic_store(&g->staged[drained], (size_t)0);
    g->drain = g->stage[drained];
    g->drain_payload = g->stage_payload[drained];
    nf_status st;

    /* The clamp: the q-quantile of the pass's weights (the largest of the processes'), folded
     * into a running value by a geometric mean, so that one pass's outliers do not move it
     * far. */
    if (g->cfg.clamp_quantile > 0.0f) {
        double v = 0.0;
        if (n > 0) {
            for (size_t i = 0; i < n; ++i)
                g->quantile_work[i] = g->drain[i].weight;
            v = nf_select(g->quantile_work, n, (size_t)(g->cfg.clamp_quantile * (float)(n - 1)));
        }
        if ((st = nf_reduce_max(red, &v, 1, fn)) != NF_OK)
            return st;
        if (v > 0.0)
            g->clamp = g->clamp > 0.0f ? sqrtf(g->clamp * (float)v) : (float)v;
    }

    /* Into the ring in key order, the oldest out. */
    nf_sort_staged(g, n);
    size_t first = g->ring_next;
    for (size_t i = 0; i < n; ++i) {
        uint32_t s = g->order[i];
        g->ring[g->ring_next] = g->drain[s];
        if (pb)
            memcpy(g->ring_payload + g->ring_next * pb, g->drain_payload + (size_t)s * pb, pb);
        g->ring_next = (g->ring_next + 1) % cap;
        if (g->ring_count < cap)
            g->ring_count++;
    }
    g->samples += n;
    rep->new_samples = n;

    /* Every process takes part in every step, with samples or without. */
    int64_t counts[2] = {(int64_t)n, (int64_t)g->ring_count};
    if ((st = nf_reduce_sum(red, counts, 2, fn)) != NF_OK)
        return st;

    uint64_t rng = g->rng ^ (0x9e3779b97f4a7c15ull * (uint64_t)(g->passes + 1));
    const size_t step = g->cfg.step_samples;
    /* Held out: a random subset of the new samples, which the model has not seen yet. */
    size_t m = n < step ? n : step;
    for (size_t i = 0; i < n; ++i)
        g->order[i] = (uint32_t)i;
    for (size_t i = 0; i < m; ++i) { /* a partial shuffle */
        size_t j = i + nf_guide_below(&rng, n - i);
        uint32_t t = g->order[i];
        g->order[i] = g->order[j];
        g->order[j] = t;
        nf_load_sample(g, i, (first + g->order[i]) % cap);
    }
    float held_out = NAN;
    if (counts[0] > 0 && (st = nf_step_loaded(g, m, par, red, fn, rep, &held_out)) != NF_OK)
        return st;
    for (uint32_t s = 1; counts[1] > 0 && s < g->cfg.steps_per_pass; ++s) {
        size_t k = g->ring_count ? step : 0;
        for (size_t i = 0; i < k; ++i)
            nf_load_sample(g, i, nf_guide_below(&rng, g->ring_count));
        float loss;
        if ((st = nf_step_loaded(g, k, par, red, fn, rep, &loss)) != NF_OK)
            return st;
    }
    g->passes++;

    /* Patience: one pass's held-out loss is noisy (a few bright samples weigh much), so the
     * test follows an exponential average over about three passes. */
    rep->held_out_loss = held_out;
    if (isfinite(held_out)) {
        double loss = held_out;
        g->last_loss = held_out;
        g->smooth_loss = isnan(g->smooth_loss) ? loss : 0.7 * g->smooth_loss + 0.3 * loss;
        if (isinf(g->best_loss) || g->smooth_loss < g->best_loss - 0.01 * fabs(g->best_loss)) {
            g->best_loss = g->smooth_loss;
            g->since_best = 0;
        } else {
            g->since_best++;
        }
    }
    return NF_OK;
}

nf_status nf_guide_train_pass(nf_guide *g, const nf_parallel *par, const nf_reduce *red,
                              nf_guide_pass_report *rep)
{
    static const char fn[] = "nf_guide_train_pass";
    nf_guide_pass_report local;
    if (!rep)
        rep = &local;
    memset(rep, 0, sizeof *rep);
    rep->held_out_loss = NAN;
    if (!g)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: g is NULL", fn);
    nf_status st = nf_guide_begin_exclusive(g, fn);
    if (st != NF_OK)
        return st;
    st = nf_train_pass_locked(g, par, red, rep, fn);
    rep->clamp = g->clamp;
    rep->keep_training = nf_guide_keep_training(g, 0.0, 0.0);
    nf_guide_end_exclusive(g);
    return st;
}

int nf_guide_keep_training(const nf_guide *g, double elapsed, double budget)
{
    if (!g)
        return 0;
    if (budget > 0.0 && !(elapsed < (double)g->cfg.train_fraction * budget))
        return 0;
    if (!nf_guide_training_pays(g))
        return 0;
    return g->cfg.patience == 0 || g->since_best < g->cfg.patience;
}
