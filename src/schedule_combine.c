/*
 * schedule_combine.c - the schedule's image (nisflow/schedule.h): the training passes and the
 * render passes combined by inverse variance, and the report.
 *
 * The image is three weighted sums per pixel (schedule_internal.h): guided render passes and
 * plain ones, each pass weighing 1, and training passes, each weighing the inverse of its own
 * spread about the reference when it was added (the model improves from pass to pass, and the
 * first ones are far worse). The sums weigh against each other by their variance of one pass,
 * the mean over the measured pixels (absolute): every depth's, and a shallower depth's once it
 * has NF_OWN_SPREAD_PASSES passes, its passes' mean squared distance to the reference (all
 * passes averaged); plain path tracing's and a shallower depth's before that, their second
 * moment about the reference as the passes that guide deeper tell it: their own first passes
 * miss the rare bright paths that rule them, and with them alone they would be trusted far too
 * much, while for a depth the choice keeps rendering, the moments, which one rare path of a
 * deeper pass decides, weighed the whole kind down (docs/equal-time.md, "What the rare paths
 * are"). The guided depths share one sum: the choice soon renders one of them, and a sum per
 * depth would cost 16 bytes a pixel each. One weight per sum for the whole image, not per
 * pixel: per-pixel weights follow variances estimated from the same passes, and on the Cornell
 * box, with 43 guided passes beside 800 plain ones, they drew almost nothing from the guided
 * and training passes and left the image 10 % worse. The training sum's factor is its mean
 * squared distance to the render passes' mean, less that mean's own variance. The weights come
 * from the same data, a slight bias that Practical Path Guiding accepts too. Absolute, not
 * relative: a relative error divides by the reference, which for a render pass's own spread
 * contains that pass's outliers and for a training pass's distance does not, and on a scene
 * with fireflies the two would differ tenfold. The sums are floats: a pixel's value rounds by
 * about 2^-24 per pass added, far below a pass's noise.
 */
#include <math.h>
#include <string.h>

#include "schedule_internal.h"

/* A guided kind with this many passes is weighed in the image by its own passes' spread. */
#define NF_OWN_SPREAD_PASSES 16u

/* One pass's variance of each kind, summed over this process's measured pixels. */
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
        for (size_t i = 0; i < s->lay.measured; ++i)
            spread[k] += fmax((s2[i] - 2.0 * ref[i] * s1[i] + n * ref[i] * ref[i]) / n, 0.0);
    }
}

/* The factor c on the training passes' weights: their sum's variance at a pixel is about
 * c / its weight there. From the sum's squared distance to the render passes' mean, less that
 * mean's own variance (1 / its weight), over the pixels both cover; never below what makes
 * the best training pass weigh as a render pass of the spread `floor`. */
static double nf_training_factor(nf_schedule *s, const nf_reduce *red, const double a[NF_ACCS],
                                 double floor, nf_status *st)
{
    static const char fn[] = "nf_schedule_combine";
    const float *t = s->acc[NF_ACC_TRAIN], *g = s->acc[NF_ACC_GUIDED], *p = s->acc[NF_ACC_PLAIN];
    double d2 = 0.0, inv_r = 0.0, inv_t = 0.0;
    for (size_t i = 0; i < s->pixels; ++i) {
        const size_t o = 4 * i;
        double wr = g[o + 3] * a[NF_ACC_GUIDED] + p[o + 3] * a[NF_ACC_PLAIN];
        if (!(t[o + 3] > 0.0f) || !(wr > 0.0))
            continue;
        double lt = ((double)t[o] + t[o + 1] + t[o + 2]) / 3.0 / t[o + 3];
        double lr = (((double)g[o] + g[o + 1] + g[o + 2]) * a[NF_ACC_GUIDED] +
                     ((double)p[o] + p[o + 1] + p[o + 2]) * a[NF_ACC_PLAIN]) /
                    3.0 / wr;
        d2 += (lt - lr) * (lt - lr);
        inv_r += 1.0 / wr;
        inv_t += 1.0 / t[o + 3];
    }
    /* Each pixel is one process's: the distances add; the weights are every process's. */
    if ((*st = nf_schedule_sum(red, &d2, 1, fn)) != NF_OK)
        return -1.0;
    double low = s->train_wmax * floor, c = inv_t > 0.0 ? (d2 - inv_r) / inv_t : 0.0;
    c = fmax(c, low);
    return c > 0.0 && isfinite(c) ? c : 1.0;
}

/* Writes the combination into rgb; returns the training passes' share, or -1 with the status
 * in *st. */
static double nf_combine(nf_schedule *s, const nf_reduce *red, float *rgb, nf_status *st)
{
    static const char fn[] = "nf_schedule_combine";
    double v[NF_KINDS] = {0.0}, a[NF_ACCS] = {1.0, 1.0, 1.0};
    nf_schedule_reference(s);
    nf_kind_spreads(s, v);
    if ((*st = nf_schedule_sum(red, v, NF_KINDS, fn)) != NF_OK)
        return -1.0;
    /* A guided pass's spread: its depths', weighed by their passes. */
    double guided = 0.0, top = 0.0;
    uint32_t passes = 0;
    for (uint32_t k = 0; k < NF_KINDS; ++k) {
        v[k] /= (double)s->lay.measured;
        top = fmax(top, v[k]);
        if (k < NF_PLAIN) {
            guided += s->kind[k].n * v[k];
            passes += s->kind[k].n;
        }
    }
    guided = passes ? guided / passes : 0.0;
    /* Render passes weigh 1 / their spread each; with no spread measured (a black image, or
     * values whose squares overflow), every pass weighs alike. A spread of 0 beside others
     * weighs as 10^12 times the largest. */
    if (top > 0.0 && isfinite(top)) {
        a[NF_ACC_GUIDED] = 1.0 / fmax(guided, top * 1e-12);
        a[NF_ACC_PLAIN] = 1.0 / fmax(v[NF_PLAIN], top * 1e-12);
    }
    /* Training guides every depth (candidate 0); without such passes, the first guided kind
     * measured, or plain's: a training pass never weighs more than a pass of it. */
    double floor = v[NF_PLAIN];
    for (uint32_t k = NF_PLAIN; k-- > 0;)
        if (v[k] > 0.0)
            floor = v[k];
    double c = nf_training_factor(s, red, a, floor, st);
    if (c < 0.0)
        return -1.0;
    a[NF_ACC_TRAIN] = 1.0 / c;
    double train = 0.0, total = 0.0;
    for (size_t i = 0; i < s->pixels; ++i) {
        double sum[3] = {0.0, 0.0, 0.0}, w = 0.0;
        for (unsigned k = 0; k < NF_ACCS; ++k) {
            const float *x = s->acc[k] + 4 * i;
            for (unsigned ch = 0; ch < 3; ++ch)
                sum[ch] += a[k] * x[ch];
            w += a[k] * x[3];
        }
        train += a[NF_ACC_TRAIN] * s->acc[NF_ACC_TRAIN][4 * i + 3];
        total += w;
        for (unsigned ch = 0; ch < 3; ++ch)
            rgb[3 * i + ch] = w > 0.0 ? (float)(sum[ch] / w) : 0.0f;
    }
    return total > 0.0 ? train / total : 0.0;
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
