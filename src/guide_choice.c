/*
 * guide_choice.c - guided or plain passes (nisflow/guide.h): the relative variance of a
 * kind of pass from per-pixel sums, and the choice of the next pass from what each kind
 * costs and buys. docs/integration.md has the recipe, docs/equal-time.md the measurements.
 */
#include <math.h>

#include "guide_internal.h"

/* Each kind's first passes before any comparison: one pass has no spread to measure. */
#define NF_PASS_WARMUP 2u

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
    /* Only guided passes measure guided passes; plain path tracing is measured by every
     * pass (nf_plain_moment), so it needs no share of its own. */
    if (other == NF_PASS_GUIDED && (double)gm->passes < (double)g->cfg.explore_share * total) {
        out->kind = NF_PASS_GUIDED;
        out->exploring = 1;
    }
    return NF_OK;
}

/* R below this is taken as this: a path plain path tracing would (almost) never trace
 * weighs in its second moment as one it traces once in 10^6. */
#define NF_PLAIN_RATIO_FLOOR 1e-6f

void nf_plain_moment_start(nf_plain_moment *m)
{
    if (!m)
        return;
    m->ratio = 1.0f;
    m->sum = 0.0f;
    m->moment = 0.0f;
}

void nf_plain_moment_scatter(nf_plain_moment *m, float p_bsdf, float p_mix, float g_used)
{
    if (m)
        m->ratio = nf_guide_boost(m->ratio, p_bsdf, p_mix, g_used);
}

void nf_plain_moment_roulette(nf_plain_moment *m, const nf_guide_policy *p, float throughput_max,
                              float q_used)
{
    if (!m || !(q_used > 0.0f) || !isfinite(q_used))
        return;
    float r = fmaxf(m->ratio, NF_PLAIN_RATIO_FLOOR);
    float q_plain = nf_guide_roulette_survival(p, throughput_max / r, 1.0f);
    /* q_plain = 0: plain path tracing would never have gone on (R = 0, floored when used). */
    m->ratio = q_plain > 0.0f ? r * (q_plain / q_used) : 0.0f;
}

void nf_plain_moment_add(nf_plain_moment *m, float c)
{
    if (!m || !(c > 0.0f) || !isfinite(c))
        return;
    float r = fmaxf(m->ratio, NF_PLAIN_RATIO_FLOOR);
    /* c_k^2 / R_k + 2 c_k sum_j c_j / R_j, then the sum takes c_k / R_k. */
    m->moment += c * (c / r + 2.0f * m->sum);
    m->sum += c / r;
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
