/*
 * guide.c - the guide of nisflow/guide.h: its configuration, life cycle, the store that
 * render threads fill, and the double-buffered publication of the model they sample.
 * The schedule and the sharded step are in guide_train.c.
 */
#include <math.h>

#include "guide_internal.h"

void nf_guide_config_init(nf_guide_config *gc)
{
    if (!gc)
        return;
    memset(gc, 0, sizeof *gc);
    gc->magic_ = NF_GUIDE_CONFIG_MAGIC;
    gc->store_capacity = 131072;
    gc->payload_bytes = 0;
    gc->step_samples = 2048;
    gc->steps_per_pass = 64;
    gc->groups = 16;
    gc->patience = 6;
    gc->clamp_quantile = 0.0f;
    gc->train_fraction = 0.15f;
    gc->learning_rate = 5e-3f;
    gc->seed = 1;
    gc->pass_choice = 1;
    gc->explore_share = 0.05f;
    nf_guide_policy_init(&gc->policy);
}

void nf_guide_model_config_init(nf_config *cfg, const float bounds_min[3],
                                const float bounds_max[3])
{
    if (!cfg)
        return;
    nf_config_init(cfg, NF_PRESET_SMALL);
    /* The position alone: four bands of the normal and wo cost more than they gained, the
     * cosine prior already follows the normal (docs/equal-time.md). */
    cfg->sh_bands = 0;
    for (int a = 0; a < 3 && bounds_min && bounds_max; ++a) {
        cfg->bounds_min[a] = bounds_min[a];
        cfg->bounds_max[a] = bounds_max[a];
    }
}

static nf_status nf_guide_config_check(const nf_guide_config *gc, const char *fn)
{
    /* Each refusal names the field, its value and its range, as guide.h states them. */
#define NF_RANGE(cond, field, value, range)                                                        \
    if (!(cond))                                                                                   \
    return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: gc->%s = %g is out of range: it must be %s",    \
                   fn, field, (double)(value), range)
    if (gc->magic_ != NF_GUIDE_CONFIG_MAGIC)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                       "%s: gc was not filled by nf_guide_config_init (call it, then change "
                       "the fields you need)",
                       fn);
    NF_RANGE(gc->store_capacity >= 1 && gc->store_capacity <= ((size_t)1 << 26), "store_capacity",
             gc->store_capacity, "in [1, 2^26 = 67108864]");
    NF_RANGE(gc->payload_bytes <= 4096, "payload_bytes", gc->payload_bytes, "in [0, 4096]");
    NF_RANGE(gc->step_samples >= 1 && gc->step_samples <= (1u << 20), "step_samples",
             gc->step_samples, "in [1, 2^20 = 1048576]");
    NF_RANGE(gc->steps_per_pass >= 1 && gc->steps_per_pass <= 4096, "steps_per_pass",
             gc->steps_per_pass, "in [1, 4096]");
    NF_RANGE(gc->groups >= 1 && gc->groups <= 256, "groups", gc->groups, "in [1, 256]");
    NF_RANGE(gc->clamp_quantile == 0.0f || (gc->clamp_quantile > 0.0f && gc->clamp_quantile < 1.0f),
             "clamp_quantile", gc->clamp_quantile, "0 (no clamp) or in (0, 1)");
    NF_RANGE(gc->train_fraction >= 0.0f && gc->train_fraction <= 1.0f, "train_fraction",
             gc->train_fraction, "in [0, 1]");
    NF_RANGE(gc->pass_choice <= 1, "pass_choice", gc->pass_choice, "0 or 1");
    NF_RANGE(gc->explore_share >= 0.0f && gc->explore_share <= 0.5f, "explore_share",
             gc->explore_share, "in [0, 0.5]");
    NF_RANGE(gc->policy.mixture_prob >= 0.0f && gc->policy.mixture_prob < 1.0f,
             "policy.mixture_prob", gc->policy.mixture_prob, "in [0, 1)");
    NF_RANGE(gc->policy.max_boost == 0.0f ||
                 (gc->policy.max_boost >= 1.0f && isfinite(gc->policy.max_boost)),
             "policy.max_boost", gc->policy.max_boost, "0 (no cap) or finite and >= 1");
    NF_RANGE(gc->policy.max_survival > 0.0f && gc->policy.max_survival <= 1.0f,
             "policy.max_survival", gc->policy.max_survival, "in (0, 1]");
    NF_RANGE(gc->policy.min_roughness >= 0.0f && gc->policy.min_roughness <= 1.0f,
             "policy.min_roughness", gc->policy.min_roughness, "in [0, 1]");
#undef NF_RANGE
    /* The learning rate is checked by nf_model_set_learning_rate, against the model's decay. */
    return NF_OK;
}

static void *nf_guide_alloc(nf_guide *g, size_t count, size_t size, int *ok)
{
    if (count == 0)
        count = 1;
    if (size && count > SIZE_MAX / size) {
        *ok = 0;
        return NULL;
    }
    void *p = g->alloc.alloc(g->alloc.user, count * size);
    if (!p)
        *ok = 0;
    else
        memset(p, 0, count * size);
    return p;
}

static void nf_guide_free_one(nf_guide *g, void *p)
{
    if (p)
        g->alloc.free(g->alloc.user, p);
}

void nf_guide_destroy(nf_guide *g)
{
    if (!g)
        return;
    nf_model_destroy(g->train);
    for (int i = 0; i < NF_GUIDE_PUBLISHED; ++i)
        nf_model_destroy(g->pub[i]);
    void *arrays[] = {g->stage[0],
                      g->stage[1],
                      g->stage_payload[0],
                      g->stage_payload[1],
                      g->ring,
                      g->ring_payload,
                      g->order,
                      g->order_tmp,
                      g->quantile_work,
                      g->step_ctx,
                      g->step_dir,
                      g->step_weight,
                      g->step_slot,
                      g->grads,
                      g->F,
                      g->FL,
                      g->group_status,
                      g->group_message,
                      g->fixed,
                      g->mean,
                      g->group_top};
    for (size_t i = 0; i < sizeof arrays / sizeof arrays[0]; ++i)
        nf_guide_free_one(g, arrays[i]);
    nf_allocator alloc = g->alloc;
    alloc.free(alloc.user, g);
}

nf_status nf_guide_create(const nf_model *model, const nf_guide_config *gc, nf_guide **out)
{
    static const char fn[] = "nf_guide_create";
    if (!out)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: out is NULL", fn);
    *out = NULL;
    if (!model)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: model is NULL", fn);
    nf_guide_config defaults;
    if (!gc) {
        nf_guide_config_init(&defaults);
        gc = &defaults;
    }
    nf_status st = nf_guide_config_check(gc, fn);
    if (st != NF_OK)
        return st;
    nf_allocator alloc = model->cfg.allocator; /* resolved by nf_model_allocate */
    nf_guide *g = (nf_guide *)alloc.alloc(alloc.user, sizeof *g);
    if (!g)
        return nf_fail(NF_ERROR_OUT_OF_MEMORY, "%s: could not allocate the guide", fn);
    memset(g, 0, sizeof *g);
    g->cfg = *gc;
    g->alloc = alloc;
    atomic_init(&g->newest, 0);
    for (int i = 0; i < NF_GUIDE_PUBLISHED; ++i)
        atomic_init(&g->holders[i], 0u);
    atomic_init(&g->training, 0);
    atomic_init(&g->intake, 0);
    for (int i = 0; i < 2; ++i) {
        atomic_init(&g->adders[i], 0u);
        atomic_init(&g->staged[i], (size_t)0);
    }
    atomic_init(&g->dropped, 0ull);
    atomic_init(&g->job_open, 0);
    atomic_init(&g->job_next, (size_t)0);
    atomic_init(&g->job_done, (size_t)0);
    atomic_init(&g->job_helpers, 0u);
    for (int i = 0; i < 1 + NF_GUIDE_PUBLISHED; ++i) {
        nf_model **slot = i == 0 ? &g->train : &g->pub[i - 1];
        if ((st = nf_model_clone(model, slot)) != NF_OK ||
            (st = nf_model_set_learning_rate(*slot, gc->learning_rate)) != NF_OK) {
            nf_guide_destroy(g);
            return st == NF_ERROR_INVALID_ARGUMENT
                       ? nf_fail(st,
                                 "%s: gc->learning_rate = %g is out of range for this "
                                 "model (train.h, nf_model_set_learning_rate)",
                                 fn, (double)gc->learning_rate)
                       : st;
        }
    }
    size_t cap = gc->store_capacity, pb = gc->payload_bytes, step = gc->step_samples;
    size_t groups = gc->groups;
    g->params = nf_model_param_count(model);
    int ok = 1;
    for (int i = 0; i < 2; ++i) {
        g->stage[i] = nf_guide_alloc(g, cap, sizeof *g->stage[i], &ok);
        g->stage_payload[i] = nf_guide_alloc(g, cap, pb, &ok);
    }
    g->ring = nf_guide_alloc(g, cap, sizeof *g->ring, &ok);
    g->ring_payload = nf_guide_alloc(g, cap, pb, &ok);
    g->order = nf_guide_alloc(g, cap, sizeof *g->order, &ok);
    g->order_tmp = nf_guide_alloc(g, cap, sizeof *g->order_tmp, &ok);
    g->quantile_work = nf_guide_alloc(g, cap, sizeof *g->quantile_work, &ok);
    g->step_ctx = nf_guide_alloc(g, step, sizeof *g->step_ctx, &ok);
    g->step_dir = nf_guide_alloc(g, step, 3 * sizeof *g->step_dir, &ok);
    g->step_weight = nf_guide_alloc(g, step, sizeof *g->step_weight, &ok);
    g->step_slot = nf_guide_alloc(g, step, sizeof *g->step_slot, &ok);
    g->grads = nf_guide_alloc(g, groups * g->params, sizeof *g->grads, &ok);
    g->F = nf_guide_alloc(g, groups, sizeof *g->F, &ok);
    g->FL = nf_guide_alloc(g, groups, sizeof *g->FL, &ok);
    g->group_top = nf_guide_alloc(g, groups, sizeof *g->group_top, &ok);
    g->group_status = nf_guide_alloc(g, groups, sizeof *g->group_status, &ok);
    g->group_message = nf_guide_alloc(g, groups, sizeof *g->group_message, &ok);
    g->fixed = nf_guide_alloc(g, g->params + 2, sizeof *g->fixed, &ok);
    g->mean = nf_guide_alloc(g, g->params, sizeof *g->mean, &ok);
    if (!ok) {
        nf_guide_destroy(g);
        return nf_fail(NF_ERROR_OUT_OF_MEMORY,
                       "%s: could not allocate the store of %zu samples (%zu payload bytes "
                       "each) and the step's buffers",
                       fn, cap, pb);
    }
    g->best_loss = INFINITY;
    g->best_ratio = INFINITY;
    g->smooth_loss = NAN;
    g->last_loss = NAN;
    g->rng = gc->seed;
    *out = g;
    return NF_OK;
}

const nf_guide_config *nf_guide_get_config(const nf_guide *g) { return g ? &g->cfg : NULL; }

nf_model *nf_guide_training_model(nf_guide *g) { return g ? g->train : NULL; }

/* ---- Publication ----------------------------------------------------------------------------
 * NF_GUIDE_PUBLISHED published models and a hold count each. A reader counts itself into the
 * newest, then checks that it is still the newest; publish writes only a model that is not
 * the newest and that nobody holds. With sequentially consistent atomics, a reader that
 * re-reads `newest` unchanged holds a model that no publish is writing: a publish that began
 * writing it did so while it was not the newest, and the reader's re-read would then see
 * another one and retry. */

nf_status nf_guide_acquire(nf_guide *g, const nf_model **out)
{
    if (!g || !out)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "nf_guide_acquire: %s is NULL", !g ? "g" : "out");
    for (;;) {
        int i = atomic_load(&g->newest);
        atomic_fetch_add(&g->holders[i], 1u);
        if (atomic_load(&g->newest) == i) {
            *out = g->pub[i];
            return NF_OK;
        }
        atomic_fetch_sub(&g->holders[i], 1u);
    }
}

nf_status nf_guide_release(nf_guide *g, const nf_model *m)
{
    static const char fn[] = "nf_guide_release";
    if (!g || !m)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: %s is NULL", fn, !g ? "g" : "m");
    int i = -1;
    for (int k = 0; k < NF_GUIDE_PUBLISHED; ++k)
        if (m == g->pub[k])
            i = k;
    if (i < 0)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: m was not handed out by this guide", fn);
    unsigned held = atomic_load(&g->holders[i]);
    do {
        if (held == 0)
            return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                           "%s: m is released more often than it was acquired", fn);
    } while (!atomic_compare_exchange_weak(&g->holders[i], &held, held - 1u));
    return NF_OK;
}

/* Marks a training call or publish in flight; refuses another one meanwhile. Adds and
 * acquires go on: they touch only the intake and the hold counts. */
nf_status nf_guide_begin_exclusive(nf_guide *g, const char *fn)
{
    int expected = 0;
    if (!atomic_compare_exchange_strong(&g->training, &expected, 1))
        return nf_fail(NF_ERROR_BUSY,
                       "%s: another training call or nf_guide_publish is running on another "
                       "thread: they must take turns (guide.h)",
                       fn);
    return NF_OK;
}

void nf_guide_end_exclusive(nf_guide *g) { atomic_store(&g->training, 0); }

nf_status nf_guide_publish(nf_guide *g)
{
    static const char fn[] = "nf_guide_publish";
    if (!g)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: g is NULL", fn);
    nf_status st = nf_guide_begin_exclusive(g, fn);
    if (st != NF_OK)
        return st;
    /* Any copy but the newest that nobody holds: a reader that counts itself into it now
     * sees that it is not the newest and moves on (above). */
    const int newest = atomic_load(&g->newest);
    int back = -1;
    for (int k = 1; k < NF_GUIDE_PUBLISHED && back < 0; ++k) {
        int j = (newest + k) % NF_GUIDE_PUBLISHED;
        if (atomic_load(&g->holders[j]) == 0u)
            back = j;
    }
    if (back < 0) {
        nf_guide_end_exclusive(g);
        return nf_fail(NF_ERROR_BUSY,
                       "%s: the %d older published models are all still held (threads hold "
                       "%d generations): release one (nf_guide_release) first",
                       fn, NF_GUIDE_PUBLISHED - 1, NF_GUIDE_PUBLISHED);
    }
    st = nf_model_copy(g->pub[back], g->train);
    if (st == NF_OK)
        atomic_store(&g->newest, back);
    nf_guide_end_exclusive(g);
    return st;
}

/* ---- The store ------------------------------------------------------------------------------ */

nf_status nf_guide_add_samples(nf_guide *g, size_t n, const uint64_t *key, const nf_context *ctx,
                               const float *dir, const float *weight, const void *payload)
{
    static const char fn[] = "nf_guide_add_samples";
    if (!g)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: g is NULL", fn);
    if (n == 0) /* an empty batch, whatever its pointers (an empty std::vector's are NULL) */
        return NF_OK;
    size_t kept = 0;
    nf_status st = nf_check_pointers(fn, "ctx", ctx, "dir", dir, "weight", weight, NULL, NULL);
    if (st != NF_OK || (st = nf_validate_samples(fn, n, ctx, dir, weight, NULL, &kept)) != NF_OK)
        return st;
    /* Count into the intake's stage, then check it is still the intake: a pass that turned it
     * meanwhile may already be waiting for this stage's adds to end, or have drained it. */
    int in;
    for (;;) {
        in = atomic_load(&g->intake);
        atomic_fetch_add(&g->adders[in], 1u);
        if (atomic_load(&g->intake) == in)
            break;
        atomic_fetch_sub(&g->adders[in], 1u);
    }
    size_t cap = g->cfg.store_capacity, pb = g->cfg.payload_bytes;
    nf_guide_entry *stage = g->stage[in];
    unsigned char *stage_payload = g->stage_payload[in];
    size_t slot = atomic_fetch_add(&g->staged[in], kept);
    for (size_t i = 0; i < n; ++i) {
        if (!(weight[i] > 0.0f))
            continue;
        if (slot >= cap) {
            atomic_fetch_add(&g->dropped, 1ull);
        } else {
            nf_guide_entry *e = &stage[slot];
            e->ctx = ctx[i];
            /* A surface's phase_g is never read and may be garbage: stored as 0, so that the
             * store's order (equal keys sort by their bytes) does not depend on it. */
            if (!nf_context_in_medium(&e->ctx))
                e->ctx.phase_g = 0.0f;
            memcpy(e->dir, dir + 3 * i, sizeof e->dir);
            e->weight = weight[i];
            e->key = key ? key[i] : 0u;
            if (pb) {
                unsigned char *dst = stage_payload + slot * pb;
                if (payload)
                    memcpy(dst, (const unsigned char *)payload + i * pb, pb);
                else
                    memset(dst, 0, pb);
            }
        }
        ++slot;
    }
    atomic_fetch_sub(&g->adders[in], 1u);
    return NF_OK;
}

int nf_guide_swap_intake(nf_guide *g)
{
    const int in = atomic_load(&g->intake);
    atomic_store(&g->intake, 1 - in);
    /* An add that counted itself into `in` and then saw it still the intake did both before
     * the store above (sequential consistency), so its count shows here: wait for it. Adds
     * copy at most store_capacity samples and take no lock, so this wait is short. */
    while (atomic_load(&g->adders[in]) != 0u)
        ;
    return in;
}

const void *nf_guide_payload(const nf_guide *g, const nf_context *ctx)
{
    if (!g || !ctx || !g->step_payload_base || g->cfg.payload_bytes == 0)
        return NULL;
    /* Compare addresses as integers: ctx may point anywhere. */
    uintptr_t p = (uintptr_t)ctx, base = (uintptr_t)g->step_ctx;
    if (p < base || (p - base) % sizeof *ctx != 0)
        return NULL;
    size_t i = (p - base) / sizeof *ctx;
    if (i >= g->step_n)
        return NULL;
    return g->step_payload_base + g->step_slot[i] * g->cfg.payload_bytes;
}

size_t nf_guide_pending(const nf_guide *g)
{
    if (!g)
        return 0;
    nf_guide *m = (nf_guide *)g; /* atomics are read, not written */
    size_t n = atomic_load(&m->staged[atomic_load(&m->intake)]);
    return n < g->cfg.store_capacity ? n : g->cfg.store_capacity;
}

nf_status nf_guide_get_stats(const nf_guide *g, nf_guide_stats *out)
{
    if (!g || !out)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "nf_guide_get_stats: %s is NULL",
                       !g ? "g" : "out");
    memset(out, 0, sizeof *out);
    out->samples = g->samples;
    out->dropped = atomic_load(&((nf_guide *)g)->dropped);
    out->stored = g->ring_count;
    out->steps = g->steps;
    out->refused = g->refused;
    out->passes = g->passes;
    out->stale_passes = g->since_best;
    out->last_loss = g->last_loss;
    out->clamp = g->clamp;
    return NF_OK;
}
