/*
 * budget.c - the time-budgeted job of budget.h: training passes, render passes, and their
 * inverse-variance combination.
 */
#include "budget.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gradient_sum.h"
#include "guide.h"
#include "metrics.h"
#include "parallel.h"
#include "progress.h"
#include "ranks.h"
#include "relative.h"
#include "render.h"
#include "selection.h"

/* Budget passes use their own random streams, apart from render_image's passes. */
#define PASS_STREAM_BASE 0x100000u
/* Training passes are kept in at most this many groups of equal size. */
#define MAX_GROUPS 32
#define MAX_SHARDS 16
/* Samples kept for training steps: about 8 passes of a 320 x 180 film at ~0.4 samples per
 * path; ~19 MB. */
#define REPLAY_CAPACITY 131072u

budget_settings budget_default_settings(void)
{
    budget_settings b;
    b.seconds = 30.0;
    b.start = 0.0;
    b.train_fraction = 0.3;
    b.step_samples = 2048;
    b.steps_per_pass = 64;
    b.patience = 6;
    b.combine = 1;
    b.clamp_quantile = 0.0f;
    b.learn_selection = 0;
    b.relative_training = 0;
    b.selection_cost = -1.0f;
    b.threads = 1;
    b.seed = 1;
    return b;
}

/* ---- Accumulating passes -------------------------------------------------------------------- */

/* The training passes: group g holds the sum of `per_group` consecutive passes (the last one
 * possibly fewer). When MAX_GROUPS are full, neighbours merge and groups double. */
typedef struct pass_groups {
    double *sum[MAX_GROUPS];
    int count[MAX_GROUPS];
    int ngroups, per_group;
    size_t n; /* floats per image */
} pass_groups;

static void groups_free(pass_groups *g)
{
    for (int i = 0; i < MAX_GROUPS; ++i)
        free(g->sum[i]);
}

static int groups_add(pass_groups *g, const image *img)
{
    if (g->ngroups > 0 && g->count[g->ngroups - 1] < g->per_group) {
        double *s = g->sum[g->ngroups - 1];
        for (size_t i = 0; i < g->n; ++i)
            s[i] += img->data[i];
        g->count[g->ngroups - 1]++;
        return 1;
    }
    if (g->ngroups == MAX_GROUPS) { /* merge pairs: 32 groups of k become 16 of 2k */
        double *sum[MAX_GROUPS];
        int count[MAX_GROUPS];
        for (int i = 0; i < MAX_GROUPS / 2; ++i) {
            double *a = g->sum[2 * i], *b = g->sum[2 * i + 1];
            for (size_t j = 0; j < g->n; ++j)
                a[j] += b[j];
            sum[i] = a;
            count[i] = g->count[2 * i] + g->count[2 * i + 1];
            sum[MAX_GROUPS / 2 + i] = b; /* reused by the next groups */
            count[MAX_GROUPS / 2 + i] = 0;
        }
        memcpy(g->sum, sum, sizeof sum);
        memcpy(g->count, count, sizeof count);
        g->ngroups = MAX_GROUPS / 2;
        g->per_group *= 2;
        return groups_add(g, img);
    }
    int k = g->ngroups;
    if (!g->sum[k] && !(g->sum[k] = malloc(g->n * sizeof(double))))
        return 0;
    for (size_t i = 0; i < g->n; ++i)
        g->sum[k][i] = img->data[i];
    g->count[k] = 1;
    g->ngroups++;
    return 1;
}

static double luminance(const double *p)
{
    return (p[0] + p[1] + p[2]) / 3.0;
}

/* The mean over pixels of the squared error of `mean` (a mean image, times scale) against
 * `ref`, in luminance. Absolute, not relative: a relative error divides by the reference,
 * which for a render pass's own spread contains that pass's outliers and for a training
 * group's distance does not, and on a scene with fireflies the two would differ tenfold. */
static double squared_error(const double *mean, double scale, const double *ref, size_t pixels)
{
    double sum = 0.0;
    for (size_t i = 0; i < pixels; ++i) {
        double d = scale * luminance(mean + 3 * i) - luminance(ref + 3 * i);
        sum += d * d;
    }
    return sum / (double)pixels;
}

/* Writes into img the inverse-variance combination of the training groups and the render
 * passes (render_sum, render_sq: per-pixel sums of RGB and of luminance squared, n passes).
 * Each group's variance is estimated by its mean squared distance to the render mean, less
 * the render mean's own variance; a slight bias, because the weights come from the same data,
 * which Practical Path Guiding accepts too. Returns the training groups' share. */
static double combine(const pass_groups *g, const double *render_sum, const double *render_sq,
                      int n, int use_training, image *img, double *render_variance_out)
{
    double render_variance = 0.0;
    size_t floats = g->n, pixels = floats / 3;
    int groups = use_training ? g->ngroups : 0;
    double w[MAX_GROUPS] = {0}, w_render = 0.0, total = 0.0;
    if (n >= 2) {
        double *mean = malloc(floats * sizeof *mean);
        if (mean) {
            double var = 0.0, rel = 0.0; /* variance of one render pass, and relative */
            for (size_t i = 0; i < floats; ++i)
                mean[i] = render_sum[i] / n;
            for (size_t i = 0; i < pixels; ++i) {
                double m = luminance(mean + 3 * i);
                double s2 = fmax((render_sq[i] - (double)n * m * m) / (n - 1), 0.0);
                var += s2;
                rel += s2 / (m * m + METRIC_EPSILON);
            }
            var /= (double)pixels;
            rel /= (double)pixels;
            render_variance = rel;
            /* var == 0 (a black image): no estimate, the pass counts decide below. */
            w_render = var > 0.0 ? n / var : 0.0;
            for (int k = 0; k < groups && var > 0.0; ++k) {
                double v = squared_error(g->sum[k], 1.0 / g->count[k], mean, pixels) - var / n;
                /* A group that looks better than the render passes is noise in the estimate:
                 * never trust it more than its pass count says. */
                v = fmax(v, var / g->count[k]);
                w[k] = 1.0 / v;
            }
            free(mean);
        }
    }
    if (w_render == 0.0) { /* no variance estimate: weigh by pass counts */
        w_render = n;
        for (int k = 0; k < groups; ++k)
            w[k] = g->count[k];
    }
    for (int k = 0; k < groups; ++k)
        total += w[k];
    if (render_variance_out)
        *render_variance_out = render_variance;
    double train_share = total / (total + w_render);
    total += w_render;
    for (size_t i = 0; i < floats; ++i) {
        double acc = n > 0 ? w_render * render_sum[i] / n : 0.0;
        for (int k = 0; k < groups; ++k)
            acc += w[k] * g->sum[k][i] / g->count[k];
        img->data[i] = total > 0.0 ? (float)(acc / total) : 0.0f;
    }
    return train_share;
}

/* ---- Training on a pass's records ------------------------------------------------------------ */

typedef struct trainer {
    nf_model *model;
    int shards;          /* this rank's groups per step: one per thread                   */
    size_t total_shards; /* all ranks' groups per step                                    */
    size_t step;         /* this rank's samples per step: its share of step_samples       */
    gradient_sum sum;
    size_t group_end[MAX_SHARDS];
    nf_context *ctx;
    float *dir, *weight;
    guide_point *points;
    size_t capacity;
    float clamp;        /* running clamp of the weights (0: not yet known)            */
    train_record *store; /* replay ring of the latest REPLAY_CAPACITY samples           */
    size_t stored, store_next;
} trainer;

/* One AdamW step on the n samples of the step arrays (the rank's share of the step), their
 * gradient computed in groups on the threads and summed over the ranks
 * (gradient_sum.h; docs/integration.md, "Sharded gradients"). */
static int sharded_step(trainer *tr, size_t n, float *loss, gradient_step *step,
                        nf_status *refusal, tr_error *err)
{
    for (int k = 0; k < tr->shards; ++k)
        tr->group_end[k] = n * (size_t)(k + 1) / (size_t)tr->shards;
    return gradient_sum_step(&tr->sum, tr->model, tr->ctx, tr->dir, tr->weight, tr->group_end,
                             (size_t)tr->shards, tr->total_shards, tr->shards, loss, step,
                             refusal, err);
}

static int trainer_reserve(trainer *tr, size_t n)
{
    if (n <= tr->capacity)
        return 1;
    free(tr->ctx);
    free(tr->dir);
    free(tr->weight);
    free(tr->points);
    tr->ctx = malloc(n * sizeof *tr->ctx);
    tr->dir = malloc(n * 3 * sizeof *tr->dir);
    tr->weight = malloc(n * sizeof *tr->weight);
    tr->points = malloc(n * sizeof *tr->points);
    tr->capacity = tr->ctx && tr->dir && tr->weight && tr->points ? n : 0;
    return tr->capacity != 0;
}

static void trainer_free(trainer *tr)
{
    free(tr->store);
    gradient_sum_free(&tr->sum);
    free(tr->ctx);
    free(tr->dir);
    free(tr->weight);
    free(tr->points);
}

static int compare_float(const void *a, const void *b)
{
    float x = *(const float *)a, y = *(const float *)b;
    return (x > y) - (x < y);
}

/* The q-quantile of the records' weights (the largest of the ranks' quantiles), folded into
 * a running value (geometric mean with the previous passes', so that one pass's outliers do
 * not move it far). Collective. */
static int update_clamp(trainer *tr, const record_buffer *rec, float q, tr_error *err)
{
    size_t n = rec->count;
    double v = 0.0;
    if (n > 0 && trainer_reserve(tr, n)) {
        for (size_t i = 0; i < n; ++i)
            tr->weight[i] = rec->data[i].weight;
        qsort(tr->weight, n, sizeof *tr->weight, compare_float);
        v = tr->weight[(size_t)(q * (float)(n - 1))];
    }
    if (!ranks_max_f64(&v, 1, err))
        return 0;
    if (v > 0.0)
        tr->clamp = tr->clamp > 0.0f ? sqrtf(tr->clamp * (float)v) : (float)v;
    return 1;
}

/* Copies samples into the step arrays, with the running clamp applied. */
static void load_sample(trainer *tr, size_t i, const train_record *x)
{
    tr->ctx[i] = x->ctx;
    memcpy(tr->dir + 3 * i, x->dir, sizeof x->dir);
    tr->weight[i] = tr->clamp > 0.0f ? fminf(x->weight, tr->clamp) : x->weight;
    memcpy(tr->points[i].position, x->ctx.position, sizeof x->ctx.position);
    tr->points[i].bp = x->bp;
}

/* One step on the first n samples of the step arrays (every rank's, together); its loss goes
 * to *loss (NAN if refused or empty). Collective. */
static int step_on_loaded(trainer *tr, const tracer *t, size_t n, uint32_t pass,
                          budget_report *rep, double *loss, tr_error *err)
{
    if (t->bsdf_prior) /* the BSDF prior's callbacks find each sample's material here */
        guide_begin_batch(tr->ctx, tr->points, n);
    float l = NAN;
    gradient_step step;
    nf_status refusal;
    int ok = sharded_step(tr, n, &l, &step, &refusal, err);
    guide_end();
    *loss = NAN;
    if (!ok)
        return 0;
    if (step == GRADIENT_STEP_REFUSED) {
        if (rep->refused++ < 5 && ranks_rank() == 0)
            fprintf(stderr, "\nnf_tracer: training pass %u: step refused: %s%s%s\n", pass,
                    nf_status_string(refusal), tr->sum.message[0] ? ": " : "", tr->sum.message);
    } else if (step == GRADIENT_STEP_TAKEN) {
        rep->steps++;
        *loss = l;
    }
    return 1;
}

/* Trains after one pass. The pass's samples join a replay store of the latest samples (older
 * passes' samples stay valid: their weights f L / p_mix are importance weights for the
 * density that drew them, so the loss estimate stays unbiased). The first step takes only new
 * samples, which the model has not seen: its loss is a held-out loss. The other steps draw
 * uniformly from the store. */
static int train_on_pass(trainer *tr, const tracer *t, record_buffer *rec,
                         const budget_settings *bs, uint32_t pass, budget_report *rep,
                         double *pass_loss, tr_error *err)
{
    size_t n = rec->count, step = tr->step;
    *pass_loss = NAN;
    /* Collective from here: every rank takes part in every step, with samples or without. */
    if (bs->clamp_quantile > 0.0f && !update_clamp(tr, rec, bs->clamp_quantile, err))
        return 0;
    int ok = trainer_reserve(tr, step) ||
             tr_fail(err, "out of memory for %zu training samples", step);
    if (ok && !tr->store && !(tr->store = malloc(REPLAY_CAPACITY * sizeof *tr->store)))
        ok = tr_fail(err, "out of memory for the replay store");
    if (!ranks_agree(ok, err))
        return 0;
    /* Each rank draws its own samples: a stream of its own. */
    rng r = rng_seed(bs->seed, RNG_TRAIN, pass, (uint64_t)ranks_rank());
    for (size_t i = 0; i < n; ++i) { /* into the ring, the oldest out */
        tr->store[tr->store_next] = rec->data[i];
        tr->store_next = (tr->store_next + 1) % REPLAY_CAPACITY;
        if (tr->stored < REPLAY_CAPACITY)
            tr->stored++;
    }
    /* Held-out: a random subset of the new samples (records come in tile order). */
    size_t m = n < step ? n : step;
    for (size_t i = 0; i < m; ++i) {
        size_t j = i + (size_t)(rng_next_u32(&r) % (uint32_t)(n - i)); /* partial shuffle */
        train_record tmp = rec->data[i];
        rec->data[i] = rec->data[j];
        rec->data[j] = tmp;
        load_sample(tr, i, &rec->data[i]);
    }
    /* Nothing to learn anywhere (a scene that no light reaches yet): no steps, which would
     * each cost a start of the threads for nothing. */
    uint64_t counts[2] = {n, tr->stored};
    if (!ranks_sum_u64(counts, 2, err))
        return 0;
    if (counts[0] > 0 && !step_on_loaded(tr, t, m, pass, rep, pass_loss, err))
        return 0;
    for (int s = 1; counts[1] > 0 && s < bs->steps_per_pass; ++s) {
        size_t k = tr->stored ? step : 0;
        for (size_t i = 0; i < k; ++i)
            load_sample(tr, i, &tr->store[rng_next_u32(&r) % (uint32_t)tr->stored]);
        double loss;
        if (!step_on_loaded(tr, t, k, pass, rep, &loss, err))
            return 0;
    }
    rep->samples += n;
    return 1;
}

/* Steps of the learned guiding probability on one pass's records, in SELECTION_STEPS
 * minibatches (the records are in tile order, so each minibatch is a band of the image; the
 * cells of a band get their steps from it). */
#define SELECTION_STEPS 8
static int learn_selection(selection_grid *g, const record_buffer *rec, tr_error *err)
{
    size_t n = rec->count;
    selection_sample *mine = malloc((n ? n : 1) * sizeof *mine), *smp = NULL;
    double *work = malloc(2 * g->cells * sizeof *work);
    int ok = (mine && work) || tr_fail(err, "out of memory for the guiding probabilities");
    for (size_t i = 0; ok && i < n; ++i) {
        const train_record *x = &rec->data[i];
        mine[i].cell = x->cell;
        mine[i].weight = x->weight;
        mine[i].p_flow = x->p_flow;
        mine[i].p_bsdf = x->p_bsdf;
        mine[i].alpha = x->alpha;
    }
    /* Every rank learns from every rank's samples, in the same order: the grids stay equal. */
    void *all = NULL;
    size_t bytes = 0;
    if (ranks_agree(ok, err) &&
        ranks_gather_bytes(mine, n * sizeof *mine, &all, &bytes, err)) {
        smp = all;
        n = bytes / sizeof *smp;
        /* Every cell of the pass in every step: the whole pass's gradient, SELECTION_STEPS
         * times, would be a larger learning rate; instead each step sees all samples once. */
        for (int k = 0; k < SELECTION_STEPS && n > 0; ++k) {
            size_t b = n * (size_t)k / SELECTION_STEPS, e = n * (size_t)(k + 1) / SELECTION_STEPS;
            selection_step(g, smp + b, e - b, work);
        }
        if (n > 0)
            selection_observe(g, smp, n);
    } else {
        ok = 0;
    }
    free(all);
    free(mine);
    free(work);
    return ok;
}

/* ---- The job ------------------------------------------------------------------------------- */

/* What rank 0's clock decides before a pass, the same for every rank. */
typedef struct pass_plan {
    int32_t stop_training, stopped_early, stop;
} pass_plan;

int render_with_budget(tracer *t, nf_model *model, const budget_settings *bs, image *img,
                       budget_report *rep, tr_error *err)
{
    const scene *s = t->s;
    size_t pixels = (size_t)s->width * (size_t)s->height;
    pass_groups groups;
    trainer tr;
    selection_grid selection;
    relative_weights relative;
    record_buffer records = {0};
    image pass = {0};
    double *render_sum = NULL, *render_sq = NULL;
    int ok = 0;
    memset(rep, 0, sizeof *rep);
    memset(&groups, 0, sizeof groups);
    memset(&tr, 0, sizeof tr);
    memset(&selection, 0, sizeof selection);
    memset(&relative, 0, sizeof relative);
    groups.n = 3 * pixels;
    groups.per_group = 1;
    /* Every step of the setup may fail on one rank only: the ranks agree before going on. */
    int ready = image_alloc(img, s->width, s->height, err) &&
                image_alloc(&pass, s->width, s->height, err);
    if (ready) {
        render_sum = calloc(3 * pixels, sizeof *render_sum);
        render_sq = calloc(pixels, sizeof *render_sq);
        ready = (render_sum && render_sq) || tr_fail(err, "out of memory for the image sums");
    }
    if (ready && model && bs->learn_selection) {
        ready = selection_init(&selection, t->s->bounds_min, t->s->bounds_max, t->guide_prob) ||
                tr_fail(err, "out of memory for the guiding probabilities");
        if (bs->selection_cost >= 0.0f)
            selection.cost = bs->selection_cost;
        if (ready)
            t->selection = &selection;
    }
    if (ready && model && bs->relative_training)
        ready = relative_init(&relative, t) ||
                tr_fail(err, "out of memory for the relative training weights");
    uint64_t shards = 0;
    if (model) {
        tr.model = model;
        tr.shards = bs->threads < 1 ? 1 : bs->threads > MAX_SHARDS ? MAX_SHARDS : bs->threads;
        /* The ranks share each step's samples. */
        size_t n = (size_t)ranks_size();
        tr.step = ((size_t)bs->step_samples + n - 1) / n;
        shards = (uint64_t)tr.shards;
    }
    if (!ranks_agree(ready, err) || !ranks_sum_u64(&shards, 1, err))
        goto done;
    tr.total_shards = (size_t)shards;

    const double end = bs->start + bs->seconds;
    const double train_end = bs->start + bs->train_fraction * bs->seconds;
    double best_loss = INFINITY, smooth_loss = NAN, last_pass = 0.0;
    int since_best = 0, training = model != NULL && bs->train_fraction > 0.0;
    uint32_t k = 0;
    for (;; ++k) {
        double t0 = now_seconds(), c0 = cpu_seconds();
        /* Rank 0's clock decides; the held-out loss (since_best) is the same on every rank. */
        pass_plan plan = {0, 0, 0};
        if (training && (t0 >= train_end || (bs->patience > 0 && since_best >= bs->patience))) {
            plan.stop_training = 1;
            plan.stopped_early = t0 < train_end;
        }
        /* Stop before a pass that would overrun (its time: the last pass's). A budget too
         * short for a single pass still renders one. */
        plan.stop = k > 0 && t0 + last_pass > end;
        if (!ranks_broadcast(&plan, sizeof plan, err))
            goto done;
        if (plan.stop_training) {
            rep->stopped_early = plan.stopped_early;
            training = 0;
            if (t->selection)
                selection_freeze(&selection);
        }
        if (plan.stop)
            break;
        if (!ranks_agree(render_pass(t, bs->seed, PASS_STREAM_BASE + k, bs->threads, &pass,
                                     training ? &records : NULL, &rep->stats, err),
                         err))
            goto done;
        double t1 = now_seconds();
        if (training) {
            double loss;
            if (!ranks_agree(groups_add(&groups, &pass) ||
                                 tr_fail(err, "out of memory for a training pass"),
                             err))
                goto done;
            if (relative.sum) { /* this pass enters the pixels' estimate before it is used */
                relative_add_pass(&relative, &pass);
                relative_apply(&relative, &records);
            }
            if (t->selection && !learn_selection(&selection, &records, err))
                goto done;
            if (!train_on_pass(&tr, t, &records, bs, k, rep, &loss, err))
                goto done;
            if (ranks_size() > 1 && !guide_models_agree(model, (int)k + 1, err))
                goto done;
            double t2 = now_seconds();
            rep->train_passes++;
            rep->train_seconds += t2 - t0;
            rep->step_seconds += t2 - t1;
            if (isfinite(loss)) {
                rep->last_loss = (float)loss;
                /* One pass's held-out loss is noisy (a few bright samples weigh much): the
                 * test follows an exponential average over about three passes. */
                smooth_loss = isnan(smooth_loss) ? loss : 0.7 * smooth_loss + 0.3 * loss;
                if (isinf(best_loss) || smooth_loss < best_loss - 0.01 * fabs(best_loss)) {
                    best_loss = smooth_loss;
                    since_best = 0;
                } else {
                    since_best++;
                }
            }
            last_pass = t1 - t0; /* a render pass costs the tracing, not the step */
        } else {
            for (size_t i = 0; i < pixels; ++i) {
                const float *p = pass.data + 3 * i;
                double l = ((double)p[0] + p[1] + p[2]) / 3.0;
                render_sum[3 * i] += p[0];
                render_sum[3 * i + 1] += p[1];
                render_sum[3 * i + 2] += p[2];
                render_sq[i] += l * l;
            }
            rep->render_passes++;
            last_pass = now_seconds() - t0;
            rep->render_seconds += last_pass;
            rep->render_cpu_seconds += cpu_seconds() - c0;
        }
    }
    /* Rank 0 receives the ranks' pixels (each rendered by one rank: exact sums) and combines. */
    for (int g = 0; g < groups.ngroups; ++g)
        if (!ranks_sum_doubles_to_root(groups.sum[g], groups.n, err))
            goto done;
    if (!ranks_sum_doubles_to_root(render_sum, 3 * pixels, err) ||
        !ranks_sum_doubles_to_root(render_sq, pixels, err) ||
        !ranks_sum_u64((uint64_t *)&rep->stats, sizeof rep->stats / sizeof(uint64_t), err) ||
        !ranks_sum_u64(&rep->samples, 1, err) ||
        !ranks_sum_f64(&rep->render_cpu_seconds, 1, err))
        goto done;
    rep->train_weight = combine(&groups, render_sum, render_sq, rep->render_passes,
                                bs->combine, img, &rep->pass_variance);
    if (!bs->combine && rep->render_passes == 0)
        rep->train_weight = combine(&groups, render_sum, render_sq, 0, 1, img, NULL);
    rep->seconds = now_seconds() - bs->start;
    rep->selection_off = t->selection ? selection_off_share(&selection) : 0.0;
    ok = 1;

done:
    t->selection = NULL;
    selection_free(&selection);
    relative_free(&relative);
    groups_free(&groups);
    trainer_free(&tr);
    record_buffer_free(&records);
    image_free(&pass);
    free(render_sum);
    free(render_sq);
    return ok;
}
