/*
 * budget.c - the time-budgeted job of budget.h: training passes, render passes guided or
 * plain, and their inverse-variance combination. Training and the choice of passes are the
 * library's guide (nisflow/guide.h): the passes' records go to its store, its schedule says
 * when to stop, the measures of both kinds of pass say which to render next, and render
 * threads sample its published model.
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
/* A guided kind with this many passes is weighed in the image by its own passes' spread. */
#define OWN_SPREAD_PASSES 16
/* Measuring every kind reads a dozen arrays of the image (measure_kinds): 3.7 ms on 256x256,
 * 7 % of a Cornell box pass, when it ran after every render pass. After a kind's first
 * MEASURE_FIRST_PASSES passes its variance moves slowly, and the budget measures again only
 * while measuring has cost at most MEASURE_SHARE of the render passes' time; the passes and
 * seconds stay current (count_kinds). */
#define MEASURE_FIRST_PASSES 3
#define MEASURE_SHARE 0.01

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

/* The render passes come in KINDS kinds: guided passes by how deep they guide (the guide's
 * candidates, nf_guide_depth_of: kind c for candidate c) and plain passes (PLAIN). */
#define KINDS (NF_GUIDE_DEPTHS + 1u)
#define PLAIN NF_GUIDE_DEPTHS

/* The passes of one kind (or the training passes, guided at every depth), per pixel. */
typedef struct kind_sums {
    double *rgb; /* 3 per pixel: the sums of the passes' RGB                              */
    double *lum; /* the sums of their luminance                                           */
    double *sq;  /* the sums of their luminance squared                                   */
    double *m2[PATH_MOMENTS]; /* the sums of the paths' estimates of second moments of the
                  * luminance: [0] plain path tracing's (nf_plain_moment), [c] the guide's
                  * depth candidate c's (nf_depth_moment); a plain pass's are its square */
    int n;       /* passes                                                                */
    double cpu;  /* their CPU seconds, every thread and rank                              */
} kind_sums;

static void kind_free(kind_sums *k)
{
    free(k->rgb);
    free(k->lum);
    free(k->sq);
    for (int m = 0; m < PATH_MOMENTS; ++m)
        free(k->m2[m]);
}

static int kind_alloc(kind_sums *k, size_t pixels)
{
    k->rgb = calloc(3 * pixels, sizeof *k->rgb);
    k->lum = calloc(pixels, sizeof *k->lum);
    k->sq = calloc(pixels, sizeof *k->sq);
    int ok = k->rgb && k->lum && k->sq;
    for (int m = 0; m < PATH_MOMENTS; ++m)
        ok = (k->m2[m] = calloc(pixels, sizeof *k->m2[m])) != NULL && ok;
    return ok;
}

static void kind_add(kind_sums *k, const image *pass, const float *moment, size_t pixels)
{
    for (size_t i = 0; i < pixels; ++i) {
        const float *p = pass->data + 3 * i;
        double l = ((double)p[0] + p[1] + p[2]) / 3.0;
        k->rgb[3 * i] += p[0];
        k->rgb[3 * i + 1] += p[1];
        k->rgb[3 * i + 2] += p[2];
        k->lum[i] += l;
        k->sq[i] += l * l;
        for (int m = 0; m < PATH_MOMENTS; ++m)
            k->m2[m][i] += moment[m * pixels + i];
    }
    k->n++;
}

/* What the budget job measures its passes with: the sums of the training passes and of the
 * render passes of each kind, and scratch for the estimates. */
typedef struct pass_sums {
    kind_sums train, kind[KINDS];
    double *ref;          /* per pixel: the luminance averaged over every pass         */
    double *peakless;     /* ref with its lone peaks lowered (sums_peakless)           */
    double *pool, *pool2; /* per pixel: plain path tracing's first and second moments  */
    size_t pixels, width;
    nf_pass_measure depth[NF_GUIDE_DEPTHS]; /* the guided kinds against peakless         */
} pass_sums;

static void sums_free(pass_sums *ps)
{
    kind_free(&ps->train);
    for (unsigned k = 0; k < KINDS; ++k)
        kind_free(&ps->kind[k]);
    free(ps->ref);
    free(ps->peakless);
    free(ps->pool);
    free(ps->pool2);
}

static int sums_alloc(pass_sums *ps, size_t width, size_t height)
{
    size_t pixels = width * height;
    memset(ps, 0, sizeof *ps);
    ps->pixels = pixels;
    ps->width = width;
    ps->ref = calloc(pixels, sizeof *ps->ref);
    ps->peakless = calloc(pixels, sizeof *ps->peakless);
    ps->pool = calloc(pixels, sizeof *ps->pool);
    ps->pool2 = calloc(pixels, sizeof *ps->pool2);
    int ok = kind_alloc(&ps->train, pixels) && ps->ref && ps->peakless && ps->pool && ps->pool2;
    for (unsigned k = 0; k < KINDS; ++k)
        ok = ok && kind_alloc(&ps->kind[k], pixels);
    return ok;
}

/* ps->ref: each pixel's luminance averaged over every pass, training and every kind, the
 * reference that the kinds' spreads are measured against (nf_guide_pass_variance). */
static void sums_reference(pass_sums *ps)
{
    double n = ps->train.n;
    for (unsigned k = 0; k < KINDS; ++k)
        n += ps->kind[k].n;
    for (size_t i = 0; i < ps->pixels; ++i) {
        double l = ps->train.lum[i];
        for (unsigned k = 0; k < KINDS; ++k)
            l += ps->kind[k].lum[i];
        ps->ref[i] = n > 0.0 ? l / n : 0.0;
    }
}

/* ps->peakless: ps->ref without lone peaks (nf_guide_lower_peaks), against which the guided
 * kinds' depths are ranked: a rare bright path weighs there as it weighs in relMSE. Under
 * ranks, the neighbours another rank renders are zero here. The pixels are finite (pass_pixel
 * keeps them so): a refusal would be a bug, and is reported. */
static int sums_peakless(pass_sums *ps, tr_error *err)
{
    size_t height = ps->width ? ps->pixels / ps->width : 0;
    return nf_guide_lower_peaks(ps->width, height, ps->ref, ps->peakless) == NF_OK ||
           tr_fail(err, "%s", nf_last_error_message());
}

/* Whether the passes of kind k measure moment m (path_state.moments): plain path tracing's
 * (m = 0) every pass does; a depth candidate's, the passes that guide at least that deep. */
static int kind_measures(unsigned k, int m)
{
    if (m == 0)
        return 1;
    uint32_t want = nf_guide_depth_of((uint32_t)m), have = nf_guide_depth_of(k);
    return k < PLAIN && (have == 0 || have >= want);
}

/* ps->pool, pool2: the first and second moments of the policy of moment m (plain path
 * tracing's, or a depth candidate's) as the passes that measure it tell them, summed: a pass
 * that guides deeper (training included) by its paths' nf_depth_moment, a pass of that very
 * policy by its own values. Returns the passes. */
static int sums_pool(pass_sums *ps, int m)
{
    /* The kinds that measure m, decided once: the pixel loop runs after every pass. */
    const kind_sums *from[KINDS];
    unsigned nk = 0;
    int n = ps->train.n;
    for (unsigned k = 0; k < KINDS; ++k)
        if (kind_measures(k, m) && ps->kind[k].n > 0) {
            from[nk++] = &ps->kind[k];
            n += ps->kind[k].n;
        }
    for (size_t i = 0; i < ps->pixels; ++i) {
        double l = ps->train.lum[i], m2 = ps->train.m2[m][i];
        for (unsigned k = 0; k < nk; ++k) {
            l += from[k]->lum[i];
            m2 += from[k]->m2[m][i];
        }
        ps->pool[i] = l;
        ps->pool2[i] = m2;
    }
    return n;
}

/* Writes into img the inverse-variance combination of the training groups and the render passes
 * of every kind. Each kind weighs its passes over its variance of one pass, the mean over
 * pixels (absolute): every depth's, and a shallower depth's once it has OWN_SPREAD_PASSES
 * passes, its passes' mean squared distance to the reference (all passes averaged); plain path
 * tracing's and a shallower depth's before that, their second moment about the reference as the
 * passes that guide deeper tell it (sums_pool: their own first passes miss the rare bright paths
 * that rule them, and with them alone they would be trusted far too much; a depth the choice
 * keeps rendering has passes enough, and there the moments, which a single rare path of a
 * deeper pass decides, weighed a whole kind down: docs/equal-time.md, "What the rare paths
 * are"). One weight per kind for the whole image, not per pixel: per-pixel weights follow
 * variances estimated from the same passes, and on the Cornell box, with 43 guided passes beside
 * 800 plain ones, they drew almost nothing from the guided and training passes and left the image
 * 10 % worse than one weight per kind (docs/equal-time.md, "Guided or plain passes"). Each
 * group's variance is its mean squared distance to the render passes' combined mean, less that
 * mean's own variance, and it is weighed against that mean for the whole image. The weights
 * come from the same data, a slight bias that Practical Path Guiding accepts too. Absolute, not
 * relative: a relative error divides by the reference, which for a render pass's own spread
 * contains that pass's outliers and for a training group's distance does not, and on a scene
 * with fireflies the two would differ tenfold. Returns the training groups' share. */
static double combine(const pass_groups *g, pass_sums *ps, image *img)
{
    size_t floats = g->n, pixels = floats / 3;
    const kind_sums *ks = ps->kind;
    int groups = g->ngroups;
    double w[MAX_GROUPS] = {0}, total = 0.0, w_render = 0.0, mean_v[KINDS] = {0.0};
    sums_reference(ps);
    const double *ref = ps->ref;
    /* One pass's variance of each kind, the mean over pixels: every depth's (kind 0) from its
     * own passes, the others' from the moments of the passes that measure them (sums_pool),
     * plain's whenever any pass measured it. */
    for (unsigned k = 0; k < KINDS; ++k) {
        const double *s1 = ks[k].lum, *s2 = ks[k].sq;
        double n = ks[k].n;
        if (k == PLAIN || (k > 0 && ks[k].n < OWN_SPREAD_PASSES)) {
            n = sums_pool(ps, k == PLAIN ? 0 : (int)k);
            s1 = ps->pool;
            s2 = ps->pool2;
        }
        if (n <= 0.0 || (k < PLAIN && ks[k].n == 0))
            continue;
        double acc = 0.0;
        for (size_t i = 0; i < pixels; ++i)
            acc += fmax((s2[i] - 2.0 * ref[i] * s1[i] + n * ref[i] * ref[i]) / n, 0.0);
        mean_v[k] = acc / (double)pixels;
    }
    /* Each kind's weight: its passes over its variance of one pass; 0 without passes. */
    double wk[KINDS], w_all = 0.0;
    for (unsigned k = 0; k < KINDS; ++k) {
        wk[k] = ks[k].n > 0 && mean_v[k] > 0.0 ? ks[k].n / mean_v[k] : 0.0;
        w_all += wk[k];
    }
    double *mean = w_all > 0.0 ? malloc(floats * sizeof *mean) : NULL;
    if (mean) {
        /* The render passes' combined mean, and its variance (the mean over pixels). */
        for (size_t i = 0; i < floats; ++i) {
            double acc = 0.0;
            for (unsigned k = 0; k < KINDS; ++k)
                if (wk[k] > 0.0)
                    acc += wk[k] * ks[k].rgb[i] / ks[k].n;
            mean[i] = acc / w_all;
        }
        const double var_mean = 1.0 / w_all;
        w_render = w_all;
        /* A group looks better than a render pass of its kind only by chance: never trust it
         * more than its pass count says. Training guides every depth (candidate 0); without
         * such passes, the first guided kind measured, or plain's. */
        double floor = mean_v[PLAIN];
        for (unsigned k = PLAIN; k-- > 0;)
            if (mean_v[k] > 0.0)
                floor = mean_v[k];
        for (int k = 0; k < groups; ++k) {
            double v = squared_error(g->sum[k], 1.0 / g->count[k], mean, pixels) - var_mean;
            w[k] = 1.0 / fmax(v, floor / g->count[k]);
        }
    } else { /* no variance estimate (a black image, or no render pass): pass counts */
        for (unsigned k = 0; k < KINDS; ++k)
            w_render += ks[k].n;
        for (int k = 0; k < groups; ++k)
            w[k] = g->count[k];
    }
    for (int k = 0; k < groups; ++k)
        total += w[k];
    double train_share = total + w_render > 0.0 ? total / (total + w_render) : 0.0;
    total += w_render;
    for (size_t i = 0; i < floats; ++i) {
        double acc = 0.0;
        if (mean)
            acc = w_render * mean[i];
        else /* pass counts: the render passes' plain mean */
            for (unsigned k = 0; k < KINDS; ++k)
                acc += ks[k].rgb[i];
        for (int k = 0; k < groups; ++k)
            acc += w[k] * g->sum[k][i] / g->count[k];
        img->data[i] = total > 0.0 ? (float)(acc / total) : 0.0f;
    }
    free(mean);
    return train_share;
}

/* The passes and CPU seconds of every kind into m and ps->depth, the variances left as the
 * last measure_kinds found them: between measurements the choice sees every pass's cost. */
static void count_kinds(pass_sums *ps, nf_pass_measure m[KINDS])
{
    for (unsigned k = 0; k < KINDS; ++k) {
        m[k].passes = (uint32_t)ps->kind[k].n;
        m[k].seconds = ps->kind[k].cpu;
        if (k < PLAIN) {
            ps->depth[k].passes = m[k].passes;
            ps->depth[k].seconds = m[k].seconds;
        }
    }
}

/* Measures every kind of render pass for nf_guide_choose_pass (m[c] for guided candidate c,
 * m[PLAIN]) and nf_guide_choose_depth (ps->depth[c]): passes, CPU seconds and relative variance
 * (every depth: its passes' spread; plain path tracing and the shallower kinds: their moments as
 * the passes that guide deeper tell them), against ps->ref, and the guided kinds' against
 * ps->peakless too, the same on every rank (each rank's pixels are its own: their sums add).
 * The depths are ranked against peakless: against ref veach-bidir's rare paths were
 * invisible, and the choice kept every depth where the first vertex alone did better
 * (docs/equal-time.md). Collective. */
static int measure_kinds(pass_sums *ps, nf_pass_measure m[KINDS], tr_error *err)
{
    const kind_sums *kinds = ps->kind;
    /* v[k]: kind k against ref; v[KINDS + c]: guided candidate c against peakless. */
    double v[KINDS + NF_GUIDE_DEPTHS] = {0.0};
    sums_reference(ps);
    if (!sums_peakless(ps, err))
        return 0;
    count_kinds(ps, m);
    /* Every depth from its own passes, the other kinds from the moments of the passes that
     * measure them (sums_pool). A non-finite pixel fails an estimate; pass_pixel keeps them
     * out, so never. */
    for (unsigned k = 0; k < KINDS; ++k) {
        if (k < PLAIN && kinds[k].n == 0)
            continue;
        const double *s1 = kinds[k].lum, *s2 = kinds[k].sq;
        int n = kinds[k].n;
        if (k > 0) {
            n = sums_pool(ps, k == PLAIN ? 0 : (int)k);
            s1 = ps->pool;
            s2 = ps->pool2;
        }
        if (n <= 0)
            continue;
        if (nf_guide_pass_variance(ps->pixels, s1, s2, (uint32_t)n, ps->ref, METRIC_EPSILON,
                                   &v[k]) != NF_OK)
            v[k] = 0.0;
        if (k < PLAIN && nf_guide_pass_variance(ps->pixels, s1, s2, (uint32_t)n, ps->peakless,
                                                METRIC_EPSILON, &v[KINDS + k]) != NF_OK)
            v[KINDS + k] = 0.0;
    }
    /* Each rank's mean covers its pixels (the others are zero): the ranks' means add. */
    if (!ranks_sum_f64(v, KINDS + NF_GUIDE_DEPTHS, err))
        return 0;
    for (unsigned k = 0; k < KINDS; ++k)
        m[k].variance = v[k];
    for (unsigned c = 0; c < NF_GUIDE_DEPTHS; ++c)
        ps->depth[c].variance = v[KINDS + c];
    return 1;
}

/* Tells the guide what the training pass just rendered (pass, its tracing CPU seconds `cpu`
 * on this rank) buys against plain passes: its variance about the reference x its cost over
 * a plain pass's (nf_guide_report_training_ratio). *ratio receives it (NaN before two plain
 * passes). Collective. */
static int report_training_ratio(nf_guide *guide, pass_sums *ps, const image *pass, double cpu,
                                 nf_pass_measure *measured, double *ratio, tr_error *err)
{
    if (!measure_kinds(ps, measured, err))
        return 0;
    for (size_t i = 0; i < ps->pixels; ++i) { /* the pass alone, in the scratch sums */
        const float *p = pass->data + 3 * i;
        ps->pool[i] = ((double)p[0] + p[1] + p[2]) / 3.0;
        ps->pool2[i] = ps->pool[i] * ps->pool[i];
    }
    double v[2] = {0.0, cpu};
    if (nf_guide_pass_variance(ps->pixels, ps->pool, ps->pool2, 1, ps->ref, METRIC_EPSILON,
                               &v[0]) != NF_OK)
        v[0] = 0.0;
    if (!ranks_sum_f64(v, 2, err))
        return 0;
    const nf_pass_measure *pm = &measured[PLAIN];
    double plain = pm->passes ? pm->variance * pm->seconds / pm->passes : 0.0;
    *ratio = NAN;
    if (pm->passes < 2 || !(plain > 0.0))
        return 1;
    *ratio = v[0] * v[1] / plain;
    return nf_guide_report_training_ratio(guide, *ratio) == NF_OK ||
           tr_fail(err, "%s", nf_last_error_message());
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

/* What rank 0 decides before a pass, the same for every rank. */
typedef struct pass_plan {
    int32_t stop_training, stopped_early, stop, kind, depth, measure;
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
    pass_sums sums;
    float *moment = NULL;
    int ok = 0;
    memset(rep, 0, sizeof *rep);
    memset(&groups, 0, sizeof groups);
    memset(&arrays, 0, sizeof arrays);
    rep->ratio = rep->train_ratio = rep->depth_ratio = NAN;
    rep->depth = t->guide_depth;
    rep->depth_fixed = t->guide_depth != 0;
    groups.n = 3 * pixels;
    groups.per_group = 1;
    /* Every step of the setup may fail on one rank only: the ranks agree before going on. */
    int ready =
        image_alloc(img, s->width, s->height, err) && image_alloc(&pass, s->width, s->height, err);
    int summed = sums_alloc(&sums, (size_t)s->width, (size_t)s->height);
    moment = calloc(PATH_MOMENTS * pixels, sizeof *moment);
    ready = ready && ((summed && moment) || tr_fail(err, "out of memory for the image sums"));
    /* The BSDF prior's callbacks find each training sample's material in its payload. */
    if (ready && guide && t->bsdf_prior &&
        nf_guide_get_config(guide)->payload_bytes < sizeof(guide_point))
        ready = tr_fail(err, "the guide keeps %zu payload bytes per sample; the BSDF prior needs "
                        "%zu (nf_guide_config.payload_bytes)",
                        nf_guide_get_config(guide)->payload_bytes, sizeof(guide_point));
    if (!ranks_agree(ready, err))
        goto done;

    const double end = bs->start + bs->seconds;
    double last_pass = 0.0, last_kind[KINDS] = {0.0};
    nf_pass_measure measured[KINDS];
    memset(measured, 0, sizeof measured);
    int training = guide != NULL && nf_guide_get_config(guide)->train_fraction > 0.0f;
    /* With the choice of passes, two plain passes come first: training measures itself
     * against them (nf_guide_report_training_ratio). */
    const int choosing = guide != NULL && nf_guide_get_config(guide)->pass_choice;
    const int plain_first = training && choosing ? 2 : 0;
    /* A depth the user fixed (--variant guide-depth) holds for every guided pass, training
     * too, and its passes are kind 0; otherwise the guide chooses it for render passes. */
    const int fixed_depth = t->guide_depth;
    double measure_seconds = 0.0; /* rank 0's time in measure_kinds after render passes */
    int32_t cold_kind = -1;       /* the kind of the run's first pass, if a render pass    */
    double cold_cpu = 0.0;        /* and its CPU seconds                                   */
    uint32_t k = 0;
    for (;; ++k) {
        double t0 = now_seconds(), c0 = cpu_seconds();
        /* Rank 0's clock decides; the held-out loss (the guide's patience) and the measures
         * are the same on every rank. */
        pass_plan plan = {0, 0, 0, guide ? 0 : (int32_t)PLAIN, fixed_depth, 0};
        if (training && !nf_guide_keep_training(guide, t0 - bs->start, bs->seconds)) {
            plan.stop_training = 1;
            plan.stopped_early = nf_guide_keep_training(guide, t0 - bs->start, 0.0) == 0;
        }
        if (guide && (!training || plan.stop_training)) {
            /* How deep a guided pass would guide, then guided against plain with that kind's
             * measure. */
            nf_depth_choice depth = {0u, (uint32_t)fixed_depth, NAN};
            nf_pass_choice choice;
            if ((!fixed_depth && nf_guide_choose_depth(guide, sums.depth, &depth) != NF_OK) ||
                nf_guide_choose_pass(guide,
                                     (nf_pass_measure[2]){measured[depth.candidate],
                                                          measured[PLAIN]},
                                     &choice) != NF_OK) {
                tr_fail(err, "%s", nf_last_error_message());
                goto done;
            }
            plan.kind = choice.kind == NF_PASS_GUIDED ? (int32_t)depth.candidate : (int32_t)PLAIN;
            plan.depth = (int32_t)depth.depth;
            rep->ratio = choice.ratio;
            rep->explored += choice.exploring;
            rep->depth_ratio = depth.ratio;
            rep->depth = (int)depth.depth;
        } else if (training && sums.kind[PLAIN].n < plain_first) {
            plan.kind = PLAIN;
        }
        /* Stop before a pass that would overrun (its time: the last pass of its kind, or of
         * any kind). A budget too short for a single pass still renders one. */
        double expect = last_kind[plan.kind] > 0.0 ? last_kind[plan.kind] : last_pass;
        plan.stop = k > 0 && t0 + expect > end;
        plan.measure = choosing && (sums.kind[plan.kind].n < MEASURE_FIRST_PASSES ||
                                    measure_seconds <= MEASURE_SHARE * rep->render_seconds);
        if (!ranks_broadcast(&plan, sizeof plan, err))
            goto done;
        if (plan.stop_training) {
            rep->stopped_early = plan.stopped_early;
            training = 0;
        }
        if (plan.stop)
            break;
        const int guided = plan.kind != (int32_t)PLAIN, train_pass = training && guided;
        const nf_model *m = NULL;
        if (guided && guide && nf_guide_acquire(guide, &m) != NF_OK) {
            tr_fail(err, "%s", nf_last_error_message());
            goto done;
        }
        t->model = m; /* every thread of the pass samples this one; NULL: a plain pass */
        t->guide_depth = plan.depth;
        int rendered = render_pass(t, bs->seed, PASS_STREAM_BASE + k, bs->threads, &pass, moment,
                                   train_pass ? &records : NULL, &rep->stats, err);
        if (m)
            nf_guide_release(guide, m);
        t->model = NULL;
        t->guide_depth = fixed_depth;
        if (!ranks_agree(rendered, err))
            goto done;
        double t1 = now_seconds(), c1 = cpu_seconds();
        if (train_pass) {
            if (!ranks_agree(groups_add(&groups, &pass) ||
                                 tr_fail(err, "out of memory for a training pass"),
                             err))
                goto done;
            kind_add(&sums.train, &pass, moment, pixels);
            if (plain_first && !report_training_ratio(guide, &sums, &pass, c1 - c0, measured,
                                                      &rep->train_ratio, err))
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
            kind_sums *ks = &sums.kind[plan.kind];
            kind_add(ks, &pass, moment, pixels);
            double cpu = cpu_seconds() - c0;
            if (!ranks_sum_f64(&cpu, 1, err))
                goto done;
            /* The run's first pass pays for cold caches and first-touched pages: 8 to 12 %
             * more CPU than the next (plain passes of the Cornell box with smoke), and plain
             * passes are measured on two passes only, before training. It is charged its
             * kind's second pass's cost once there is one. */
            if (k == 0) {
                cold_kind = plan.kind;
                cold_cpu = cpu;
            } else if (plan.kind == cold_kind && ks->n == 2) {
                ks->cpu += cpu - cold_cpu;
            }
            ks->cpu += cpu;
            /* The choice reads the measures before every pass, measured again when the plan
             * says (MEASURE_SHARE); a fixed policy only reports them, once, after the last. */
            double m0 = now_seconds();
            if (!plan.measure)
                count_kinds(&sums, measured);
            else if (!measure_kinds(&sums, measured, err))
                goto done;
            measure_seconds += now_seconds() - m0;
            rep->render_passes++;
            last_pass = last_kind[plan.kind] = now_seconds() - t0;
            rep->render_seconds += last_pass;
            rep->render_cpu_seconds += cpu;
        }
    }
    /* The measures of every kind, as the last choice saw them and after it; the guided
     * kinds' sums are the report's guided passes. */
    if (!measure_kinds(&sums, measured, err))
        goto done;
    for (unsigned i = 0; i < KINDS; ++i) {
        int r = i == PLAIN ? NF_PASS_PLAIN : NF_PASS_GUIDED;
        if (i < PLAIN) {
            rep->depth_passes[i] = sums.kind[i].n;
            rep->depth_cpu_seconds[i] = sums.kind[i].cpu;
            rep->depth_variance[i] = measured[i].variance;
        }
        rep->kind_passes[r] += sums.kind[i].n;
        rep->kind_cpu_seconds[r] += sums.kind[i].cpu;
    }
    rep->kind_variance[NF_PASS_PLAIN] = measured[PLAIN].variance;
    /* A guided pass's variance: the kinds' weighted by their passes. */
    for (unsigned i = 0; i < PLAIN && rep->kind_passes[NF_PASS_GUIDED] > 0; ++i)
        rep->kind_variance[NF_PASS_GUIDED] +=
            measured[i].variance * sums.kind[i].n / rep->kind_passes[NF_PASS_GUIDED];
    /* Rank 0 receives the ranks' pixels (each rendered by one rank: exact sums) and combines. */
    for (int g = 0; g < groups.ngroups; ++g)
        if (!ranks_sum_doubles_to_root(groups.sum[g], groups.n, err))
            goto done;
    kind_sums *all[KINDS + 1] = {&sums.train};
    for (unsigned i = 0; i < KINDS; ++i)
        all[i + 1] = &sums.kind[i];
    for (unsigned i = 0; i < KINDS + 1; ++i) {
        if (!ranks_sum_doubles_to_root(all[i]->rgb, 3 * pixels, err) ||
            !ranks_sum_doubles_to_root(all[i]->lum, pixels, err) ||
            !ranks_sum_doubles_to_root(all[i]->sq, pixels, err))
            goto done;
        for (int m = 0; m < PATH_MOMENTS; ++m)
            if (!ranks_sum_doubles_to_root(all[i]->m2[m], pixels, err))
                goto done;
    }
    if (!ranks_sum_u64((uint64_t *)&rep->stats, sizeof rep->stats / sizeof(uint64_t), err) ||
        !ranks_sum_u64(&rep->samples, 1, err))
        goto done;
    rep->train_weight = combine(&groups, &sums, img);
    rep->seconds = now_seconds() - bs->start;
    ok = 1;

done:
    t->model = NULL;
    groups_free(&groups);
    samples_free(&arrays);
    record_buffer_free(&records);
    image_free(&pass);
    sums_free(&sums);
    free(moment);
    return ok;
}
