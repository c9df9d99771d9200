/*
 * schedule_combine.c - the schedule's image (nisflow/schedule.h): the training groups and the
 * render passes of every kind combined by inverse variance, and the report.
 *
 * Each kind weighs its passes over its variance of one pass, the mean over pixels (absolute):
 * every depth's, and a shallower depth's once it has NF_OWN_SPREAD_PASSES passes, its passes'
 * mean squared distance to the reference (all passes averaged); plain path tracing's and a
 * shallower depth's before that, their second moment about the reference as the passes that
 * guide deeper tell it: their own first passes miss the rare bright paths that rule them, and
 * with them alone they would be trusted far too much, while for a depth the choice keeps
 * rendering, the moments, which one rare path of a deeper pass decides, weighed the whole kind
 * down (docs/equal-time.md, "What the rare paths are"). One weight per kind for the whole image,
 * not per pixel: per-pixel weights follow variances estimated from the same passes, and on the
 * Cornell box, with 43 guided passes beside 800 plain ones, they drew almost nothing from the
 * guided and training passes and left the image 10 % worse. Each training group's variance is
 * its mean squared distance to the render passes' combined mean, less that mean's own
 * variance. The weights come from the same data, a slight bias that Practical Path Guiding
 * accepts too. Absolute, not relative: a relative error divides by the reference, which for a
 * render pass's own spread contains that pass's outliers and for a training group's distance
 * does not, and on a scene with fireflies the two would differ tenfold.
 */
#include <math.h>
#include <string.h>

#include "schedule_internal.h"

/* A guided kind with this many passes is weighed in the image by its own passes' spread. */
#define NF_OWN_SPREAD_PASSES 16u

static double nf_luminance(const double *p) { return (p[0] + p[1] + p[2]) / 3.0; }

/* One pass's variance of each kind, summed over this process's pixels. */
static void nf_kind_spreads(nf_schedule *s, double spread[NF_KINDS])
{
    const double *ref = s->ref;
    for (uint32_t k = 0; k < NF_KINDS; ++k) {
        const nf_kind_sums *ks = &s->kind[k];
        const double *s1 = ks->lum, *s2 = ks->sq;
        double n = ks->n;
        spread[k] = 0.0;
        if (k == NF_PLAIN || (k > 0 && ks->n < NF_OWN_SPREAD_PASSES)) {
            n = nf_schedule_pool(s, k == NF_PLAIN ? 0u : k);
            s1 = s->pool;
            s2 = s->pool2;
        }
        if (n <= 0.0 || (k < NF_PLAIN && ks->n == 0))
            continue;
        for (size_t i = 0; i < s->pixels; ++i)
            spread[k] += fmax((s2[i] - 2.0 * ref[i] * s1[i] + n * ref[i] * ref[i]) / n, 0.0);
    }
}

/* Writes the combination into rgb; returns the training groups' share, or -1 with the
 * status in *st. */
static double nf_combine(nf_schedule *s, const nf_reduce *red, float *rgb, nf_status *st)
{
    static const char fn[] = "nf_schedule_combine";
    const size_t pixels = s->pixels, floats = 3 * pixels;
    const uint32_t groups = s->groups;
    /* sums[k]: kind k's spread; sums[NF_KINDS + g]: group g's squared error. */
    double sums[NF_KINDS + NF_TRAIN_GROUPS] = {0.0}, w[NF_TRAIN_GROUPS] = {0.0};
    double total = 0.0, w_render = 0.0, mean_v[NF_KINDS], wk[NF_KINDS], w_all = 0.0;
    nf_schedule_reference(s);
    nf_kind_spreads(s, sums);
    if ((*st = nf_schedule_sum(red, sums, NF_KINDS, fn)) != NF_OK)
        return -1.0;
    for (uint32_t k = 0; k < NF_KINDS; ++k) {
        mean_v[k] = sums[k] / (double)pixels;
        wk[k] = s->kind[k].n > 0 && mean_v[k] > 0.0 ? s->kind[k].n / mean_v[k] : 0.0;
        w_all += wk[k];
    }
    if (w_all > 0.0) {
        /* The render passes' combined mean, and its variance (the mean over pixels). */
        for (size_t i = 0; i < floats; ++i) {
            double acc = 0.0;
            for (uint32_t k = 0; k < NF_KINDS; ++k)
                if (wk[k] > 0.0)
                    acc += wk[k] * s->kind[k].rgb[i] / s->kind[k].n;
            s->mean[i] = acc / w_all;
        }
        const double var_mean = 1.0 / w_all;
        w_render = w_all;
        /* A group looks better than a render pass of its kind only by chance: never trust it
         * more than its pass count says. Training guides every depth (candidate 0); without
         * such passes, the first guided kind measured, or plain's. */
        double floor = mean_v[NF_PLAIN];
        for (uint32_t k = NF_PLAIN; k-- > 0;)
            if (mean_v[k] > 0.0)
                floor = mean_v[k];
        for (uint32_t g = 0; g < groups; ++g) {
            double acc = 0.0, scale = 1.0 / s->group_count[g];
            for (size_t i = 0; i < pixels; ++i) {
                double d =
                    scale * nf_luminance(s->group[g] + 3 * i) - nf_luminance(s->mean + 3 * i);
                acc += d * d;
            }
            sums[NF_KINDS + g] = acc;
        }
        if ((*st = nf_schedule_sum(red, sums + NF_KINDS, groups, fn)) != NF_OK)
            return -1.0;
        for (uint32_t g = 0; g < groups; ++g) {
            double v = sums[NF_KINDS + g] / (double)pixels - var_mean;
            w[g] = 1.0 / fmax(v, floor / s->group_count[g]);
        }
    } else { /* no variance estimate (a black image, or no render pass): pass counts */
        for (uint32_t k = 0; k < NF_KINDS; ++k)
            w_render += s->kind[k].n;
        for (uint32_t g = 0; g < groups; ++g)
            w[g] = s->group_count[g];
    }
    for (uint32_t g = 0; g < groups; ++g)
        total += w[g];
    double train_share = total + w_render > 0.0 ? total / (total + w_render) : 0.0;
    total += w_render;
    for (size_t i = 0; i < floats; ++i) {
        double acc = 0.0;
        if (w_all > 0.0)
            acc = w_render * s->mean[i];
        else /* pass counts: the render passes' plain mean */
            for (uint32_t k = 0; k < NF_KINDS; ++k)
                acc += s->kind[k].rgb[i];
        for (uint32_t g = 0; g < groups; ++g)
            acc += w[g] * s->group[g][i] / s->group_count[g];
        rgb[i] = total > 0.0 ? (float)(acc / total) : 0.0f;
    }
    return train_share;
}

nf_status nf_schedule_combine(nf_schedule *s, const nf_reduce *red, float *rgb,
                              nf_schedule_report *report)
{
    static const char fn[] = "nf_schedule_combine";
    nf_status st = nf_check_pointers(fn, "s", s, "rgb", rgb, NULL, NULL, NULL, NULL);
    if (st != NF_OK)
        return st;
    /* The measures of every kind, as the last choice saw them and after it. */
    if ((st = nf_schedule_measure(s, red, fn)) != NF_OK)
        return st;
    double share = nf_combine(s, red, rgb, &st);
    if (share < 0.0)
        return st;
    nf_schedule_report *r = &s->rep;
    r->train_weight = share;
    memset(r->kind_passes, 0, sizeof r->kind_passes);
    memset(r->kind_cpu_seconds, 0, sizeof r->kind_cpu_seconds);
    memset(r->kind_variance, 0, sizeof r->kind_variance);
    for (uint32_t k = 0; k < NF_KINDS; ++k) {
        int kind = k == NF_PLAIN ? NF_PASS_PLAIN : NF_PASS_GUIDED;
        if (k < NF_PLAIN) {
            r->depth_passes[k] = s->kind[k].n;
            r->depth_cpu_seconds[k] = s->kind[k].cpu;
            r->depth_variance[k] = s->measured[k].variance;
        }
        r->kind_passes[kind] += s->kind[k].n;
        r->kind_cpu_seconds[kind] += s->kind[k].cpu;
    }
    r->kind_variance[NF_PASS_PLAIN] = s->measured[NF_PLAIN].variance;
    /* A guided pass's variance: the depths' weighted by their passes. */
    for (uint32_t k = 0; k < NF_PLAIN && r->kind_passes[NF_PASS_GUIDED] > 0; ++k)
        r->kind_variance[NF_PASS_GUIDED] +=
            s->measured[k].variance * s->kind[k].n / r->kind_passes[NF_PASS_GUIDED];
    if (report)
        *report = *r;
    return NF_OK;
}
