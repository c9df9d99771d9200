/*
 * model_setup.c - the tracer's models and their training calls (see model_setup.h).
 */
#include "model_setup.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "parallel.h"
#include "ranks.h"

/* ---- The library's hooks -------------------------------------------------------------------- */

typedef struct task_call {
    nf_task_fn task;
    void *data;
} task_call;

static void run_task(void *user, size_t item, int thread)
{
    (void)thread;
    const task_call *c = user;
    c->task(c->data, item);
}

static void run_parallel(void *user, size_t count, nf_task_fn task, void *data)
{
    const training_hooks *h = user;
    task_call c = {task, data};
    tr_error err;
    /* parallel_for fails only before any item ran (no memory for its threads): then the
     * items run here. */
    if (!parallel_for(count, h->threads, run_task, &c, NULL, &err))
        for (size_t i = 0; i < count; ++i)
            task(data, i);
}

static nf_status reduce_max(void *user, double *v, size_t n)
{
    (void)user;
    tr_error err;
    return ranks_max_f64(v, n, &err) ? NF_OK : NF_ERROR_IO;
}

static nf_status reduce_sum(void *user, int64_t *v, size_t n)
{
    (void)user;
    tr_error err;
    return ranks_sum_i64(v, n, &err) ? NF_OK : NF_ERROR_IO;
}

void training_hooks_init(training_hooks *h, int threads)
{
    h->threads = threads < 1 ? 1 : threads;
    h->parallel.run = run_parallel;
    h->parallel.user = h;
    h->reduce_storage.max_f64 = reduce_max;
    h->reduce_storage.sum_i64 = reduce_sum;
    h->reduce_storage.user = NULL;
    h->reduce = ranks_size() > 1 ? &h->reduce_storage : NULL;
}

nf_status guide_train_pass(nf_guide *g, const training_hooks *h, nf_guide_pass_report *report)
{
    prior_lookup *l = prior_lookup_of(nf_guide_training_model(g));
    if (l)
        l->guide = g;
    nf_status st = nf_guide_train_pass(g, &h->parallel, h->reduce, report);
    if (l)
        l->guide = NULL;
    return st;
}

nf_status guide_train_batch(nf_guide *g, const training_hooks *h, size_t n, const nf_context *ctx,
                            const prior_point *points, const float *dir, const float *weight,
                            const size_t *group_end, size_t groups, float *loss)
{
    prior_lookup *l = prior_lookup_of(nf_guide_training_model(g));
    if (l) {
        l->batch_ctx = ctx;
        l->batch_points = points;
        l->batch_count = n;
    }
    nf_status st = nf_guide_train_batch(g, n, ctx, dir, weight, group_end, groups, &h->parallel,
                                        h->reduce, loss);
    if (l) {
        l->batch_ctx = NULL;
        l->batch_points = NULL;
        l->batch_count = 0;
    }
    return st;
}

int model_take_trained(nf_guide *g, nf_model **model, tr_error *err)
{
    nf_model *trained = NULL;
    if (nf_model_clone(nf_guide_training_model(g), &trained) != NF_OK)
        return tr_fail(err, "%s", nf_last_error_message());
    nf_model_destroy(*model);
    *model = trained;
    return 1;
}

/* ---- Models ---------------------------------------------------------------------------------- */

const char *model_prior_name(model_prior p)
{
    static const char *const names[] = {"uniform-direction", "uniform-angle", "cosine", "bsdf"};
    return names[p];
}

model_settings model_default_settings(model_prior prior)
{
    model_settings g;
    g.prior = prior;
    g.large = 0;
    g.phi_interval = 0;
    g.learning_rate = 5e-3f;
    g.prior_epsilon = -1.0f;
    g.sh_bands = 0; /* the position alone: 4 bands cost more than they gained (equal-time.md) */
    g.seed = 1;
    return g;
}

/* The model's position bounds for a scene: its bounds padded by 1% so that no position sits
 * exactly on the clamp, which also gives flat scenes a non-zero extent on every axis. */
static void model_bounds(const scene *s, float lo_out[3], float hi_out[3])
{
    vec3 lo = s->bounds_min, hi = s->bounds_max;
    float pad = 0.01f * fmaxf(v3_max_abs(v3_sub(hi, lo)), 1e-3f);
    float l[3] = {lo.x, lo.y, lo.z}, h[3] = {hi.x, hi.y, hi.z};
    for (int a = 0; a < 3; ++a) {
        lo_out[a] = l[a] - pad;
        hi_out[a] = h[a] + pad;
    }
}

int model_bounds_match(const scene *s, const nf_model *m, char *msg, size_t size)
{
    float lo[3], hi[3];
    nf_config cfg;
    model_bounds(s, lo, hi);
    if (nf_model_get_config(m, &cfg) != NF_OK)
        return 1; /* not a model: nothing to compare (the caller's calls will say why) */
    float extent = 0.0f;
    for (int a = 0; a < 3; ++a)
        extent = fmaxf(extent, hi[a] - lo[a]);
    /* A saved model of this scene matches to the float; 1% of the extent tolerates a scene
     * edited slightly, not one moved or another scene. */
    int match = 1;
    for (int a = 0; a < 3; ++a)
        match &= fabsf(cfg.bounds_min[a] - lo[a]) <= 0.01f * extent &&
                 fabsf(cfg.bounds_max[a] - hi[a]) <= 0.01f * extent;
    if (!match)
        snprintf(msg, size,
                 "the model's position bounds [%g %g %g] - [%g %g %g] are not this scene's "
                 "[%g %g %g] - [%g %g %g]: it was trained for another scene (or this one "
                 "changed), so its positions mean other places and guiding will be poor",
                 (double)cfg.bounds_min[0], (double)cfg.bounds_min[1], (double)cfg.bounds_min[2],
                 (double)cfg.bounds_max[0], (double)cfg.bounds_max[1], (double)cfg.bounds_max[2],
                 (double)lo[0], (double)lo[1], (double)lo[2], (double)hi[0], (double)hi[1],
                 (double)hi[2]);
    return match;
}

int model_create_for_scene(const scene *s, const model_settings *settings, prior_lookup *lookup,
                 nf_model **out, tr_error *err)
{
    nf_config cfg;
    nf_config_init(&cfg, settings->large ? NF_PRESET_LARGE : NF_PRESET_SMALL);
    static const nf_prior_kind kinds[] = {NF_PRIOR_UNIFORM_DIRECTION, NF_PRIOR_UNIFORM_ANGLE,
                                          NF_PRIOR_COSINE, NF_PRIOR_CUSTOM};
    cfg.prior = kinds[settings->prior];
    if (settings->phi_interval)
        cfg.phi_map = NF_PHI_INTERVAL;
    if (settings->prior == MODEL_PRIOR_BSDF)
        cfg.custom_prior = bsdf_prior_callbacks(lookup);
    if (settings->prior_epsilon >= 0.0f)
        cfg.prior_epsilon = settings->prior_epsilon;
    if (settings->sh_bands >= 0)
        cfg.sh_bands = (uint32_t)settings->sh_bands;
    model_bounds(s, cfg.bounds_min, cfg.bounds_max);
    cfg.learning_rate = settings->learning_rate;
    cfg.seed = settings->seed;
    nf_status st = nf_model_create(&cfg, out);
    if (st != NF_OK)
        return tr_fail(err, "nf_model_create: %s: %s", nf_status_string(st),
                       nf_last_error_message());
    return 1;
}

int model_load_file(const char *path, prior_lookup *lookup, nf_model **out, tr_error *err)
{
    nf_prior_callbacks cb = bsdf_prior_callbacks(lookup);
    nf_status st = nf_model_load(path, &cb, out);
    if (st != NF_OK)
        return tr_fail(err, "%s: nf_model_load: %s: %s", path, nf_status_string(st),
                       nf_last_error_message());
    return 1;
}

int models_agree_across_ranks(const nf_model *m, int iteration, tr_error *err)
{
    size_t n = nf_model_param_count(m);
    uint64_t steps = nf_model_step_count(m), hash = RANKS_HASH_START;
    float *params = malloc(n * sizeof *params);
    int ok = params && nf_model_get_params(m, params) == NF_OK;
    if (ok)
        hash = ranks_hash(ranks_hash(hash, params, n * sizeof *params), &steps, sizeof steps);
    else
        tr_fail(err, "out of memory for the model check");
    free(params);
    if (!ranks_agree(ok, err))
        return 0;
    char what[160];
    if (iteration == 0)
        snprintf(what, sizeof what, "the models differ before training (a --load-model file "
                 "that differs between machines?)");
    else
        snprintf(what, sizeof what, "the models differ after iteration %d (libnisflow builds "
                 "or instruction sets that differ between machines? docs/distributed.md)",
                 iteration);
    return ranks_all_equal(hash, what, err);
}
