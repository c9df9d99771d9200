/*
 * budget.c - the time-budgeted job of budget.h: training passes, render passes, and their
 * inverse-variance combination. Training is the library's guide (nisflow/guide.h): the
 * passes' records go to its store, its schedule says when to stop, and render threads sample
 * its published model.
 */
#include "budget.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "guide.h"
#include "metrics.h"
#include "parallel.h"
#include "progress.h"
#include "ranks.h"
#include "render.h"

/* Budget passes use their own random streams, apart from render_image's passes. */
#define PASS_STREAM_BASE 0x100000u
/* Training passes are kept in at most this many groups of equal size. */
#define MAX_GROUPS 32

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
                      int n, image *img, double *render_variance_out)
{
    double render_variance = 0.0;
    size_t floats = g->n, pixels = floats / 3;
    int groups = g->ngroups;
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

/* The records of a pass as the guide's store takes them: structure of arrays, each sample
 * keyed by its place in the pass (records come in tile and path order, the same for any
 * number of threads), its material as the payload (the BSDF prior's callbacks read it). */
typedef struct sample_arrays {
    uint64_t *key;
    nf_context *ctx;
    float *dir, *weight;
    guide_point *payload;
    size_t capacity;
} sample_arrays;

static void samples_free(sample_arrays *a)
{
    free(a->key);
    free(a->ctx);
    free(a->dir);
    free(a->weight);
    free(a->payload);
    memset(a, 0, sizeof *a);
}

static int samples_reserve(sample_arrays *a, size_t n)
{
    if (n <= a->capacity)
        return 1;
    samples_free(a);
    a->key = malloc(n * sizeof *a->key);
    a->ctx = malloc(n * sizeof *a->ctx);
    a->dir = malloc(3 * n * sizeof *a->dir);
    a->weight = malloc(n * sizeof *a->weight);
    a->payload = malloc(n * sizeof *a->payload);
    a->capacity = a->key && a->ctx && a->dir && a->weight && a->payload ? n : 0;
    return a->capacity != 0;
}

/* Hands a pass's records to the guide, then trains on them. Collective (the guide's steps
 * reduce over the ranks). */
static int train_on_pass(nf_guide *g, sample_arrays *a, const record_buffer *rec, int threads,
                         uint32_t pass, budget_report *rep, tr_error *err)
{
    size_t n = rec->count;
    int ok = samples_reserve(a, n ? n : 1) ||
             tr_fail(err, "out of memory for %zu training samples", n);
    if (!ranks_agree(ok, err))
        return 0;
    for (size_t i = 0; i < n; ++i) {
        const train_record *x = &rec->data[i];
        a->key[i] = i;
        a->ctx[i] = x->ctx;
        memcpy(a->dir + 3 * i, x->dir, sizeof x->dir);
        a->weight[i] = x->weight;
        memcpy(a->payload[i].position, x->ctx.position, sizeof x->ctx.position);
        a->payload[i].bp = x->bp;
    }
    nf_status st = nf_guide_add_samples(g, n, a->key, a->ctx, a->dir, a->weight, a->payload);
    if (!ranks_agree(st == NF_OK || tr_fail(err, "training pass %u: %s", pass,
                                             nf_last_error_message()),
                     err))
        return 0;
    nf_guide_pass_report pr;
    guide_hooks hooks;
    guide_hooks_init(&hooks, g, threads);
    st = nf_guide_train_pass(g, &hooks.parallel, hooks.reduce, &pr);
    guide_hooks_end(&hooks);
    if (st != NF_OK) /* the hooks failed (MPI): the same on every rank */
        return tr_fail(err, "training pass %u: %s", pass, nf_last_error_message());
    if (pr.refused && rep->refused < 5 && ranks_rank() == 0)
        fprintf(stderr, "\nnf_tracer: training pass %u: %u steps refused: %s\n", pass,
                pr.refused, nf_last_error_message());
    rep->refused += (int)pr.refused;
    rep->steps += (int)pr.steps;
    rep->samples += pr.new_samples;
    if (isfinite(pr.held_out_loss))
        rep->last_loss = pr.held_out_loss;
    st = nf_guide_publish(g); /* no pass holds a model now */
    return st == NF_OK || tr_fail(err, "training pass %u: %s", pass, nf_last_error_message());
}

/* ---- The job ------------------------------------------------------------------------------- */

/* What rank 0's clock decides before a pass, the same for every rank. */
typedef struct pass_plan {
    int32_t stop_training, stopped_early, stop;
} pass_plan;

int render_with_budget(tracer *t, nf_guide *guide, const budget_settings *bs, image *img,
                       budget_report *rep, tr_error *err)
{
    const scene *s = t->s;
    size_t pixels = (size_t)s->width * (size_t)s->height;
    pass_groups groups;
    sample_arrays arrays;
    record_buffer records = {0};
    image pass = {0};
    double *render_sum = NULL, *render_sq = NULL;
    int ok = 0;
    memset(rep, 0, sizeof *rep);
    memset(&groups, 0, sizeof groups);
    memset(&arrays, 0, sizeof arrays);
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
    /* The BSDF prior's callbacks find each training sample's material in its payload. */
    if (ready && guide && t->bsdf_prior &&
        nf_guide_get_config(guide)->payload_bytes < sizeof(guide_point))
        ready = tr_fail(err, "the guide keeps %zu payload bytes per sample; the BSDF prior needs "
                        "%zu (nf_guide_config.payload_bytes)",
                        nf_guide_get_config(guide)->payload_bytes, sizeof(guide_point));
    if (!ranks_agree(ready, err))
        goto done;

    const double end = bs->start + bs->seconds;
    double last_pass = 0.0;
    int training = guide != NULL && nf_guide_get_config(guide)->train_fraction > 0.0f;
    uint32_t k = 0;
    for (;; ++k) {
        double t0 = now_seconds(), c0 = cpu_seconds();
        /* Rank 0's clock decides; the held-out loss (the guide's patience) is the same on
         * every rank. */
        pass_plan plan = {0, 0, 0};
        if (training && !nf_guide_keep_training(guide, t0 - bs->start, bs->seconds)) {
            plan.stop_training = 1;
            plan.stopped_early = nf_guide_keep_training(guide, t0 - bs->start, 0.0) == 0;
        }
        /* Stop before a pass that would overrun (its time: the last pass's). A budget too
         * short for a single pass still renders one. */
        plan.stop = k > 0 && t0 + last_pass > end;
        if (!ranks_broadcast(&plan, sizeof plan, err))
            goto done;
        if (plan.stop_training) {
            rep->stopped_early = plan.stopped_early;
            training = 0;
        }
        if (plan.stop)
            break;
        const nf_model *m = NULL;
        if (guide && nf_guide_acquire(guide, &m) != NF_OK) {
            tr_fail(err, "%s", nf_last_error_message());
            goto done;
        }
        t->model = m; /* every thread of the pass samples this one */
        int rendered = render_pass(t, bs->seed, PASS_STREAM_BASE + k, bs->threads, &pass,
                                   training ? &records : NULL, &rep->stats, err);
        if (guide)
            nf_guide_release(guide, m);
        if (!ranks_agree(rendered, err))
            goto done;
        double t1 = now_seconds();
        if (training) {
            if (!ranks_agree(groups_add(&groups, &pass) ||
                                 tr_fail(err, "out of memory for a training pass"),
                             err))
                goto done;
            if (!train_on_pass(guide, &arrays, &records, bs->threads, k, rep, err))
                goto done;
            if (ranks_size() > 1 && !guide_models_agree(nf_guide_training_model(guide),
                                                        (int)k + 1, err))
                goto done;
            double t2 = now_seconds();
            rep->train_passes++;
            rep->train_seconds += t2 - t0;
            rep->step_seconds += t2 - t1;
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
    rep->train_weight = combine(&groups, render_sum, render_sq, rep->render_passes, img,
                                &rep->pass_variance);
    rep->seconds = now_seconds() - bs->start;
    ok = 1;

done:
    t->model = NULL;
    groups_free(&groups);
    samples_free(&arrays);
    record_buffer_free(&records);
    image_free(&pass);
    free(render_sum);
    free(render_sq);
    return ok;
}
