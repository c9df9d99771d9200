/*
 * schedule_measure.c - what each kind of pass measures (nisflow/schedule.h): the per-pixel
 * reference, the pooled moments of the kinds a pass did not render, the kinds' relative
 * variances for the choice, and a training pass's ratio to a plain pass. The formulas are
 * docs/schedule-theory.md; the rules for which passes measure what are
 * docs/integration.md's "The schedule".
 */
#include <math.h>
#include <string.h>

#include "guide_internal.h"
#include "schedule_internal.h"

/* The most values one exact sum takes (the training groups and the kinds). */
#define NF_SUM_MAX 48u
/* A value's largest magnitude over the processes fills this many bits of the fixed point:
 * 2^13 processes add up without overflow, each to 2^-50 of the largest. */
#define NF_SUM_BITS 50

nf_status nf_schedule_sum(const nf_reduce *red, double *values, size_t n, const char *fn)
{
    if (!red || n == 0)
        return NF_OK;
    if (!red->max_f64 || !red->sum_i64 || n > NF_SUM_MAX)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                       "%s: the reduce hooks need both max_f64 and sum_i64", fn);
    double top[NF_SUM_MAX];
    int64_t fixed[NF_SUM_MAX];
    int shift[NF_SUM_MAX];
    for (size_t i = 0; i < n; ++i)
        top[i] = fabs(values[i]);
    nf_status st = red->max_f64(red->user, top, n);
    if (st != NF_OK)
        return nf_fail(st, "%s: the reduce hook max_f64 failed", fn);
    for (size_t i = 0; i < n; ++i) {
        int e = 0;
        (void)frexp(top[i], &e); /* |value| < 2^e on every process */
        shift[i] = NF_SUM_BITS - e;
        fixed[i] = (int64_t)llrint(ldexp(values[i], shift[i]));
    }
    st = red->sum_i64(red->user, fixed, n);
    if (st != NF_OK)
        return nf_fail(st, "%s: the reduce hook sum_i64 failed", fn);
    for (size_t i = 0; i < n; ++i)
        values[i] = ldexp((double)fixed[i], -shift[i]);
    return NF_OK;
}

void nf_schedule_reference(nf_schedule *s)
{
    double n = s->train.n;
    for (unsigned k = 0; k < NF_KINDS; ++k)
        n += s->kind[k].n;
    for (size_t i = 0; i < s->lay.measured; ++i) {
        double l = s->train.lum[i];
        for (unsigned k = 0; k < NF_KINDS; ++k)
            l += s->kind[k].lum[i];
        s->ref[i] = n > 0.0 ? l / n : 0.0;
    }
}

int nf_schedule_kind_measures(uint32_t k, uint32_t m)
{
    /* Plain path tracing's moment every pass measures; a depth candidate's, the passes that
     * guide at least that deep. */
    if (m == 0)
        return 1;
    uint32_t want = m, have = k; /* kind c guides up to depth c (policy.h) */
    return k < NF_PLAIN && (have == 0 || have >= want);
}

uint32_t nf_schedule_pool(nf_schedule *s, uint32_t m)
{
    /* The kinds that measure m, decided once: the pixel loop runs after many passes. The
     * training passes guide every depth: they measure every moment. */
    const nf_kind_sums *from[NF_KINDS];
    unsigned nk = 0;
    uint32_t n = s->train.n;
    for (uint32_t k = 0; k < NF_KINDS; ++k)
        if (nf_schedule_kind_measures(k, m) && s->kind[k].n > 0) {
            from[nk++] = &s->kind[k];
            n += s->kind[k].n;
        }
    for (size_t i = 0; i < s->lay.measured; ++i) {
        double l = s->train.lum[i], m2 = s->train.m2[m][i];
        for (unsigned k = 0; k < nk; ++k) {
            l += from[k]->lum[i];
            m2 += from[k]->m2[m][i];
        }
        s->pool[i] = l;
        s->pool2[i] = m2;
    }
    return n;
}

void nf_schedule_count(nf_schedule *s)
{
    for (unsigned k = 0; k < NF_KINDS; ++k) {
        /* The cost of a pass is its steady passes' mean once there are some: passes before
         * training ended ran beside training's memory and the job's first pass paid for cold
         * caches (plain passes of the Cornell box: 0.106 CPU s cold, 0.089 steady, which made
         * guiding look 0.86x plain where it was 1.04x). */
        const nf_kind_sums *ks = &s->kind[k];
        s->measured[k].passes = ks->n;
        s->measured[k].seconds = ks->steady_n ? ks->steady_cpu / ks->steady_n * ks->n : ks->cpu;
        if (k < NF_PLAIN) {
            s->depth[k].passes = s->measured[k].passes;
            s->depth[k].seconds = s->measured[k].seconds;
        }
    }
}

/* The variance of one pass from sums over n passes against a reference; the sums are finite
 * (nf_schedule_add_pass checks every pass), so a refusal cannot happen and reads as 0. */
static double nf_variance_of(const nf_schedule *s, const double *s1, const double *s2, uint32_t n,
                             const double *ref)
{
    double v = 0.0;
    if (nf_guide_pass_variance(s->lay.measured, s1, s2, n, ref, NF_SCHEDULE_EPSILON, &v) != NF_OK)
        v = 0.0;
    return v;
}

nf_status nf_schedule_measure(nf_schedule *s, const nf_reduce *red, const char *fn)
{
    /* v[k]: kind k against ref; v[NF_KINDS + c]: guided candidate c against peakless. The
     * depths are ranked against peakless: against ref a rare bright path weighs as its pass
     * count, whatever its brightness, and the choice kept every depth where the first vertex
     * alone did better (guide.h, nf_guide_lower_peaks). */
    double v[NF_KINDS + NF_GUIDE_DEPTHS] = {0.0};
    nf_schedule_reference(s);
    /* Under several processes the neighbours another one renders are zero here. */
    if (nf_guide_lower_peaks(s->lay.grid_width, s->lay.grid_height, s->ref, s->peakless) != NF_OK)
        memcpy(s->peakless, s->ref, s->lay.measured * sizeof *s->ref); /* finite: never */
    nf_schedule_count(s);
    /* Every depth from its own passes, the other kinds from the moments of the passes that
     * measure them: their own first passes miss the rare bright paths that rule them. */
    for (uint32_t k = 0; k < NF_KINDS; ++k) {
        if (k < NF_PLAIN && s->kind[k].n == 0)
            continue;
        const double *s1 = s->kind[k].lum, *s2 = s->kind[k].sq;
        uint32_t n = s->kind[k].n;
        if (k > 0) {
            n = nf_schedule_pool(s, k == NF_PLAIN ? 0u : k);
            s1 = s->pool;
            s2 = s->pool2;
        }
        if (n == 0)
            continue;
        v[k] = nf_variance_of(s, s1, s2, n, s->ref);
        if (k < NF_PLAIN)
            v[NF_KINDS + k] = nf_variance_of(s, s1, s2, n, s->peakless);
    }
    /* Each process's mean covers its pixels (the others are zero): the means add. */
    nf_status st = nf_schedule_sum(red, v, NF_KINDS + NF_GUIDE_DEPTHS, fn);
    if (st != NF_OK)
        return st;
    for (unsigned k = 0; k < NF_KINDS; ++k)
        s->measured[k].variance = v[k];
    for (unsigned c = 0; c < NF_GUIDE_DEPTHS; ++c)
        s->depth[c].variance = v[NF_KINDS + c];
    return NF_OK;
}

nf_status nf_schedule_training_pass(nf_schedule *s, double cpu, const nf_reduce *red,
                                    double *spread, const char *fn)
{
    nf_status st = nf_schedule_measure(s, red, fn);
    if (st != NF_OK)
        return st;
    const size_t n = s->lay.measured;
    uint32_t passes = s->train.n;
    for (unsigned k = 0; k < NF_KINDS; ++k)
        passes += s->kind[k].n;
    /* Its spread about the reference; about 0 while the reference is this pass alone (an
     * overestimate: the first pass weighs little). */
    double sums[2] = {0.0, 0.0};
    for (size_t i = 0; i < n; ++i) {
        double d = s->lum[i] - (passes > 1 ? s->ref[i] : 0.0);
        sums[0] += d * d;
    }
    /* Its relative variance about the reference, as the choice measures plain passes. */
    for (size_t i = 0; i < n; ++i) { /* the pass alone, in the scratch sums */
        s->pool[i] = s->lum[i];
        s->pool2[i] = s->lum[i] * s->lum[i];
    }
    sums[1] = nf_variance_of(s, s->pool, s->pool2, 1, s->ref);
    if ((st = nf_schedule_sum(red, sums, 2, fn)) != NF_OK)
        return st;
    *spread = sums[0] / (double)n;
    if (!s->plain_first)
        return NF_OK;
    const nf_pass_measure *pm = &s->measured[NF_PLAIN];
    double plain = pm->passes ? pm->variance * pm->seconds / pm->passes : 0.0;
    if (pm->passes < 2 || !(plain > 0.0))
        return NF_OK;
    s->rep.train_ratio = sums[1] * cpu / plain;
    return nf_guide_report_training_ratio(s->guide, s->rep.train_ratio);
}
