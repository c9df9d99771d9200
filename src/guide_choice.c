/*
 * guide_choice.c - guided or plain passes (nisflow/schedule.h): the relative variance of a
 * kind of pass from per-pixel sums, the reference without lone peaks that ranks the guided
 * depths, and the choice of the next pass from what each kind costs and buys.
 * docs/integration.md has the recipe, docs/equal-time.md the measurements.
 */
#include <math.h>
#include <stdint.h>

#include "guide_internal.h"
#include "schedule_atoms.h"

/* Each kind's first passes before any comparison: one pass has no spread to measure. */
#define NF_PASS_WARMUP 2u
/* Plain passes keep explore_share / NF_PLAIN_SHARE_DIV of the render passes. */
#define NF_PLAIN_SHARE_DIV 5.0

nf_status nf_guide_pass_variance(size_t n, const double *sum, const double *sum_sq, uint32_t passes,
                                 const double *reference, double epsilon, double *out)
{
    static const char fn[] = "nf_guide_pass_variance";
    nf_status st = nf_check_pointers(fn, "out", out, "sum", n ? sum : out, "sum_sq",
                                     n ? sum_sq : out, "reference", n ? reference : out);
    if (st != NF_OK)
        return st;
    if (passes == 0)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: passes is 0", fn);
    if (!(epsilon > 0.0) || !isfinite(epsilon))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: epsilon %g is not finite and > 0", fn,
                       epsilon);
    const double k = (double)passes;
    double acc = 0.0;
    for (size_t i = 0; i < n; ++i) {
        double s = sum[i], q = sum_sq[i], r = reference[i];
        if (!isfinite(s) || !isfinite(q) || !isfinite(r) || q < 0.0)
            return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                           "%s: pixel %zu has sum %g, sum_sq %g, reference %g (finite values, "
                           "sum_sq >= 0)",
                           fn, i, s, q, r);
        /* The sum of (x - r)^2 over the passes; rounding may take it just below 0. */
        double m2 = (q - 2.0 * r * s + k * r * r) / k;
        acc += fmax(m2, 0.0) / (r * r + epsilon);
    }
    if (!isfinite(acc))
        return nf_fail(NF_ERROR_NUMERIC, "%s: the squared distances overflow a double", fn);
    *out = n ? acc / (double)n : 0.0;
    return NF_OK;
}

/* The values are checked finite before: a plain comparison, which compiles to one instruction
 * where fmax's NaN rules do not. */
static double nf_larger(double a, double b) { return a > b ? a : b; }

/* The largest of row[x - 1], row[x], row[x + 1] that lie in the row. */
static double nf_row_max3(const double *row, size_t x, size_t width)
{
    double m = row[x];
    if (x > 0)
        m = nf_larger(m, row[x - 1]);
    if (x + 1 < width)
        m = nf_larger(m, row[x + 1]);
    return m;
}

nf_status nf_guide_lower_peaks(size_t width, size_t height, const double *reference, double *out)
{
    static const char fn[] = "nf_guide_lower_peaks";
    if (height != 0 && width > SIZE_MAX / sizeof(double) / height)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: a %zu x %zu image overflows size_t", fn,
                       width, height);
    const size_t n = width * height;
    if (n == 0)
        return NF_OK;
    nf_status st =
        nf_check_pointers(fn, "reference", reference, "out", out, NULL, NULL, NULL, NULL);
    if (st != NF_OK)
        return st;
    /* Whole-array bounds compared as integers: comparing pointers into different arrays is
     * undefined in C. */
    uintptr_t a = (uintptr_t)reference, b = (uintptr_t)out, bytes = n * sizeof(double);
    if (a < b + bytes && b < a + bytes)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: reference and out overlap", fn);
    for (size_t i = 0; i < n; ++i)
        if (!isfinite(reference[i]))
            return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                           "%s: pixel %zu (x %zu, y %zu) is %g, not finite", fn, i, i % width,
                           i / width, reference[i]);
    if (n == 1) {
        out[0] = reference[0];
        return NF_OK;
    }
    /* A pixel's neighbours: the three above, the three below, and its left and right. */
    for (size_t y = 0; y < height; ++y) {
        const double *row = reference + y * width;
        const double *above = y > 0 ? row - width : NULL;
        const double *below = y + 1 < height ? row + width : NULL;
        for (size_t x = 0; x < width; ++x) {
            double peak = -INFINITY;
            if (above)
                peak = nf_larger(peak, nf_row_max3(above, x, width));
            if (below)
                peak = nf_larger(peak, nf_row_max3(below, x, width));
            if (x > 0)
                peak = nf_larger(peak, row[x - 1]);
            if (x + 1 < width)
                peak = nf_larger(peak, row[x + 1]);
            out[y * width + x] = row[x] < peak ? row[x] : peak;
        }
    }
    return NF_OK;
}

static int nf_measure_ok(const nf_pass_measure *m)
{
    return m->seconds >= 0.0 && isfinite(m->seconds) && m->variance >= 0.0 && isfinite(m->variance);
}

nf_status nf_guide_choose_pass(const nf_guide *g, const nf_pass_measure measured[2],
                               nf_pass_choice *out)
{
    static const char fn[] = "nf_guide_choose_pass";
    nf_status st = nf_check_pointers(fn, "g", g, "measured", measured, "out", out, NULL, NULL);
    if (st != NF_OK)
        return st;
    for (int k = 0; k < 2; ++k)
        if (!nf_measure_ok(&measured[k]))
            return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                           "%s: measured[%s] has seconds %g and variance %g (finite, >= 0)", fn,
                           k == NF_PASS_GUIDED ? "NF_PASS_GUIDED" : "NF_PASS_PLAIN",
                           measured[k].seconds, measured[k].variance);
    const nf_pass_measure *gm = &measured[NF_PASS_GUIDED], *pm = &measured[NF_PASS_PLAIN];
    out->kind = NF_PASS_GUIDED;
    out->exploring = 0;
    out->ratio = NAN;
    if (!g->cfg.pass_choice)
        return NF_OK;
    if (gm->passes < NF_PASS_WARMUP || pm->passes < NF_PASS_WARMUP) {
        out->kind = pm->passes < gm->passes ? NF_PASS_PLAIN : NF_PASS_GUIDED;
        return NF_OK;
    }
    /* What a unit of variance costs: variance of one pass x seconds of one pass. */
    double cg = gm->variance * gm->seconds / gm->passes;
    double cp = pm->variance * pm->seconds / pm->passes;
    out->ratio = cg == cp ? 1.0 : cg / cp; /* 0 / 0 is a tie; x / 0 is +inf */
    nf_pass_kind best = out->ratio <= 1.0 ? NF_PASS_GUIDED : NF_PASS_PLAIN;
    nf_pass_kind other = best == NF_PASS_GUIDED ? NF_PASS_PLAIN : NF_PASS_GUIDED;
    double total = (double)gm->passes + (double)pm->passes;
    out->kind = best;
    /* The kind that measured worse keeps a share, so that its measure stays current: guided
     * passes explore_share, as only they measure guided passes; plain ones a fifth of it, as
     * every pass measures plain path tracing's variance (nf_plain_moment) and only its cost
     * needs plain passes. */
    double share = other == NF_PASS_GUIDED ? (double)g->cfg.explore_share
                                           : (double)g->cfg.explore_share / NF_PLAIN_SHARE_DIV;
    const nf_pass_measure *om = other == NF_PASS_GUIDED ? gm : pm;
    if ((double)om->passes < share * total) {
        out->kind = other;
        out->exploring = 1;
    }
    return NF_OK;
}

nf_status nf_guide_choose_depth(const nf_guide *g, const nf_pass_measure measured[NF_GUIDE_DEPTHS],
                                nf_depth_choice *out)
{
    static const char fn[] = "nf_guide_choose_depth";
    nf_status st = nf_check_pointers(fn, "g", g, "measured", measured, "out", out, NULL, NULL);
    if (st != NF_OK)
        return st;
    for (uint32_t c = 0; c < NF_GUIDE_DEPTHS; ++c)
        if (!nf_measure_ok(&measured[c]))
            return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                           "%s: measured[%u] has seconds %g and variance %g (finite, >= 0)", fn, c,
                           measured[c].seconds, measured[c].variance);
    nf_depth_choice r = {0u, 0u, NAN};
    if (g->cfg.pass_choice) {
        uint32_t warm = NF_GUIDE_DEPTHS;
        for (uint32_t c = NF_GUIDE_DEPTHS; c-- > 0;)
            if (measured[c].passes < NF_PASS_WARMUP)
                warm = c;
        if (warm < NF_GUIDE_DEPTHS) {
            r.candidate = warm;
        } else {
            /* What a unit of variance costs, as nf_guide_choose_pass weighs the kinds. */
            double cost[NF_GUIDE_DEPTHS];
            for (uint32_t c = 0; c < NF_GUIDE_DEPTHS; ++c) {
                cost[c] = measured[c].variance * measured[c].seconds / measured[c].passes;
                if (cost[c] < cost[r.candidate])
                    r.candidate = c;
            }
            r.ratio = cost[r.candidate] == cost[0] ? 1.0 : cost[r.candidate] / cost[0];
        }
    }
    r.depth = r.candidate;
    *out = r;
    return NF_OK;
}

/* Training stops paying when the ratio has not fallen by NF_RATIO_STEP for NF_RATIO_PATIENCE
 * training passes while guiding gains less than 1 - NF_RATIO_WORTH over plain passes: a
 * model that buys little and stopped improving does not repay its steps. */
#define NF_RATIO_STEP 0.05
#define NF_RATIO_PATIENCE 3u
#define NF_RATIO_WORTH 0.8

nf_status nf_guide_report_training_ratio(nf_guide *g, double ratio)
{
    static const char fn[] = "nf_guide_report_training_ratio";
    nf_status st = nf_check_pointers(fn, "g", g, NULL, NULL, NULL, NULL, NULL, NULL);
    if (st != NF_OK)
        return st;
    if (!(ratio >= 0.0) || isnan(ratio))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: ratio %g is not >= 0", fn, ratio);
    if (ratio < g->best_ratio * (1.0 - NF_RATIO_STEP)) {
        g->best_ratio = ratio;
        g->ratio_since_best = 0;
    } else {
        g->ratio_since_best++;
    }
    return NF_OK;
}

int nf_guide_training_pays(const nf_guide *g)
{
    if (!g->cfg.pass_choice)
        return 1;
    return !(g->ratio_since_best >= NF_RATIO_PATIENCE && g->best_ratio > NF_RATIO_WORTH);
}
