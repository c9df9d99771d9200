/*
 * schedule.c - the schedule's life cycle and its plans (nisflow/schedule.h): which pass to
 * render next, and taking in the pass that was rendered. What the passes measure is
 * schedule_measure.c, the image schedule_combine.c.
 */
#include <math.h>
#include <string.h>

#include "guide_internal.h"
#include "schedule_internal.h"

/* The largest image: 2^26 pixels, about 80 GB of sums. */
#define NF_SCHEDULE_MAX_SIDE 65536u
#define NF_SCHEDULE_MAX_PIXELS ((size_t)1 << 26)
/* Each kind's first passes are measured after each pass; later, measuring every kind reads a
 * dozen arrays of the image (7 % of a 256 x 256 Cornell box pass), and the kinds are measured
 * again after 1 / NF_MEASURE_EVERY of the render passes so far: their variances move slowly
 * by then, and the passes and seconds stay current between measurements. */
#define NF_MEASURE_FIRST_PASSES 3u
/* Plain passes rendered after training before the choice: their cost is the steady one. */
#define NF_STEADY_PLAIN 2u
#define NF_MEASURE_EVERY 16u

void nf_schedule_config_init(nf_schedule_config *sc)
{
    if (!sc)
        return;
    memset(sc, 0, sizeof *sc);
    sc->magic_ = NF_SCHEDULE_CONFIG_MAGIC;
}

static nf_status nf_schedule_check_config(const nf_schedule_config *sc, const char *fn)
{
    if (sc->magic_ != NF_SCHEDULE_CONFIG_MAGIC)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                       "%s: the config is not from nf_schedule_config_init", fn);
    if (sc->width < 1 || sc->width > NF_SCHEDULE_MAX_SIDE || sc->height < 1 ||
        sc->height > NF_SCHEDULE_MAX_SIDE)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                       "%s: the image is %u x %u pixels (each side in [1, %u])", fn, sc->width,
                       sc->height, NF_SCHEDULE_MAX_SIDE);
    if ((size_t)sc->width * sc->height > NF_SCHEDULE_MAX_PIXELS)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                       "%s: the image is %u x %u pixels (at most %zu in all)", fn, sc->width,
                       sc->height, NF_SCHEDULE_MAX_PIXELS);
    if (!(sc->budget > 0.0) || !isfinite(sc->budget))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: budget is %g (finite and > 0)", fn,
                       sc->budget);
    return NF_OK;
}

/* An array of count doubles, zeroed unless `zero` is 0 (an array written before it is read:
 * its pages are then first touched when used, and a short job that fills few training groups
 * never pays for the others). */
static double *nf_schedule_array_of(nf_schedule *s, size_t count, int zero, int *ok)
{
    double *p = NULL;
    if (*ok && count <= SIZE_MAX / sizeof(double))
        p = (double *)s->alloc.alloc(s->alloc.user, count * sizeof(double));
    if (!p)
        *ok = 0;
    else if (zero)
        memset(p, 0, count * sizeof(double));
    return p;
}

static double *nf_schedule_array(nf_schedule *s, size_t count, int *ok)
{
    return nf_schedule_array_of(s, count, 1, ok);
}

static void nf_schedule_release(nf_schedule *s, double *p)
{
    if (p)
        s->alloc.free(s->alloc.user, p);
}

static void nf_kind_arrays(nf_schedule *s, nf_kind_sums *k, int *ok)
{
    k->rgb = nf_schedule_array(s, 3 * s->pixels, ok);
    k->lum = nf_schedule_array(s, s->pixels, ok);
    k->sq = nf_schedule_array(s, s->pixels, ok);
    for (unsigned m = 0; m < NF_GUIDE_DEPTHS; ++m)
        k->m2[m] = nf_schedule_array(s, s->pixels, ok);
}

static void nf_kind_release(nf_schedule *s, nf_kind_sums *k)
{
    nf_schedule_release(s, k->rgb);
    nf_schedule_release(s, k->lum);
    nf_schedule_release(s, k->sq);
    for (unsigned m = 0; m < NF_GUIDE_DEPTHS; ++m)
        nf_schedule_release(s, k->m2[m]);
}

void nf_schedule_destroy(nf_schedule *s)
{
    if (!s)
        return;
    nf_kind_release(s, &s->train);
    for (unsigned k = 0; k < NF_KINDS; ++k)
        nf_kind_release(s, &s->kind[k]);
    for (unsigned g = 0; g < NF_TRAIN_GROUPS; ++g)
        nf_schedule_release(s, s->group[g]);
    nf_schedule_release(s, s->ref);
    nf_schedule_release(s, s->peakless);
    nf_schedule_release(s, s->pool);
    nf_schedule_release(s, s->pool2);
    nf_schedule_release(s, s->mean);
    nf_allocator alloc = s->alloc;
    alloc.free(alloc.user, s);
}

nf_status nf_schedule_create(nf_guide *guide, const nf_schedule_config *sc, nf_schedule **out)
{
    static const char fn[] = "nf_schedule_create";
    nf_status st = nf_check_pointers(fn, "sc", sc, "out", out, NULL, NULL, NULL, NULL);
    if (st != NF_OK)
        return st;
    *out = NULL;
    if ((st = nf_schedule_check_config(sc, fn)) != NF_OK)
        return st;
    nf_allocator alloc = guide ? guide->alloc : nf_default_allocator();
    nf_schedule *s = (nf_schedule *)alloc.alloc(alloc.user, sizeof *s);
    if (!s)
        return nf_fail(NF_ERROR_OUT_OF_MEMORY, "%s: could not allocate the schedule", fn);
    memset(s, 0, sizeof *s);
    s->cfg = *sc;
    s->guide = guide;
    s->alloc = alloc;
    s->pixels = (size_t)sc->width * sc->height;
    int ok = 1;
    nf_kind_arrays(s, &s->train, &ok);
    for (unsigned k = 0; k < NF_KINDS; ++k)
        nf_kind_arrays(s, &s->kind[k], &ok);
    for (unsigned g = 0; g < NF_TRAIN_GROUPS; ++g) /* nf_groups_add writes a group first */
        s->group[g] = nf_schedule_array_of(s, 3 * s->pixels, 0, &ok);
    s->ref = nf_schedule_array(s, s->pixels, &ok);
    s->peakless = nf_schedule_array(s, s->pixels, &ok);
    s->pool = nf_schedule_array(s, s->pixels, &ok);
    s->pool2 = nf_schedule_array(s, s->pixels, &ok);
    s->mean = nf_schedule_array(s, 3 * s->pixels, &ok);
    if (!ok) {
        nf_schedule_destroy(s);
        return nf_fail(NF_ERROR_OUT_OF_MEMORY,
                       "%s: could not allocate the sums of a %u x %u image (about %zu MB)", fn,
                       sc->width, sc->height, s->pixels * 1200u / 1000000u);
    }
    const nf_guide_config *gc = guide ? nf_guide_get_config(guide) : NULL;
    s->training = gc && gc->train_fraction > 0.0f;
    s->choosing = gc && gc->pass_choice;
    /* With the choice of passes, two plain passes come first: training measures itself
     * against them (nf_guide_report_training_ratio). */
    s->plain_first = s->training && s->choosing ? 2u : 0u;
    s->per_group = 1;
    s->rep.ratio = s->rep.depth_ratio = s->rep.train_ratio = NAN;
    s->rep.depth = sc->guide_depth;
    *out = s;
    return NF_OK;
}

/* ---- The plans ---------------------------------------------------------------------------- */

nf_status nf_schedule_next(nf_schedule *s, double elapsed, const nf_reduce *red, nf_pass_plan *plan)
{
    static const char fn[] = "nf_schedule_next";
    nf_status st = nf_check_pointers(fn, "s", s, "plan", plan, NULL, NULL, NULL, NULL);
    if (st != NF_OK)
        return st;
    if (!(elapsed >= 0.0))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: elapsed is %g (>= 0)", fn, elapsed);
    if (s->pending)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                       "%s: the plan of pass %u was not added (nf_schedule_add_pass)", fn,
                       s->plan.pass);
    /* The latest clock decides, so that every process plans alike. */
    if (red && red->max_f64 && (st = red->max_f64(red->user, &elapsed, 1)) != NF_OK)
        return nf_fail(st, "%s: the reduce hook max_f64 failed", fn);
    nf_guide *g = s->guide;
    const uint32_t fixed = s->cfg.guide_depth;
    nf_pass_plan p = {g ? NF_TODO_GUIDED : NF_TODO_PLAIN, fixed, s->next_pass, g ? 0u : NF_PLAIN,
                      0u};
    if (s->stopped) {
        p.todo = NF_TODO_STOP;
        *plan = p;
        return NF_OK;
    }
    int stop_training = 0, stopped_early = 0;
    if (s->training && !nf_guide_keep_training(g, elapsed, s->cfg.budget)) {
        stop_training = 1;
        stopped_early = nf_guide_keep_training(g, elapsed, 0.0) == 0;
    }
    nf_depth_choice depth = {0u, fixed, NAN};
    nf_pass_choice choice = {NF_PASS_GUIDED, 0, NAN};
    const int choose = g && (!s->training || stop_training);
    if (choose && s->plain_first && s->kind[NF_PLAIN].steady_n < NF_STEADY_PLAIN) {
        /* The plain passes before training were cold: measure steady ones first. */
        p.kind_ = NF_PLAIN;
    } else if (choose) {
        /* How deep a guided pass would guide, then guided against plain with that kind's
         * measure. */
        nf_pass_measure pair[2];
        if (!fixed && (st = nf_guide_choose_depth(g, s->depth, &depth)) != NF_OK)
            return st;
        pair[NF_PASS_GUIDED] = s->measured[depth.candidate];
        pair[NF_PASS_PLAIN] = s->measured[NF_PLAIN];
        if ((st = nf_guide_choose_pass(g, pair, &choice)) != NF_OK)
            return st;
        p.kind_ = choice.kind == NF_PASS_GUIDED ? depth.candidate : NF_PLAIN;
        p.depth = depth.depth;
    } else if (s->training && s->kind[NF_PLAIN].n < s->plain_first) {
        p.kind_ = NF_PLAIN;
    }
    /* Stop before a pass that would overrun (its time: the latest pass of its kind, or of any
     * kind). A budget too short for a single pass still renders one. */
    const nf_kind_sums *ks = &s->kind[p.kind_];
    double expect = ks->last_seconds > 0.0 ? ks->last_seconds : s->last_seconds;
    const int stop = s->next_pass > 0 && elapsed + expect > s->cfg.budget;
    p.measure_ = s->choosing && (ks->n < NF_MEASURE_FIRST_PASSES ||
                                 s->since_measure * NF_MEASURE_EVERY >= s->rep.render_passes);
    /* Nothing failed: the plan takes effect. */
    if (stop_training) {
        s->training = 0;
        s->rep.stopped_early = stopped_early;
    }
    if (choose) {
        s->rep.ratio = choice.ratio;
        s->rep.explored += (uint32_t)choice.exploring;
        s->rep.depth_ratio = depth.ratio;
        s->rep.depth = depth.depth;
    }
    if (stop) {
        s->stopped = 1;
        p.todo = NF_TODO_STOP;
        *plan = p;
        return NF_OK;
    }
    p.todo = p.kind_ == NF_PLAIN ? NF_TODO_PLAIN : s->training ? NF_TODO_TRAIN : NF_TODO_GUIDED;
    s->plan = p;
    s->pending = 1;
    s->next_pass++;
    *plan = p;
    return NF_OK;
}

/* ---- Taking in a pass ----------------------------------------------------------------------- */

static nf_status nf_check_pass(const nf_schedule *s, const float *rgb, const float *moments,
                               const char *fn)
{
    for (size_t i = 0; i < 3 * s->pixels; ++i)
        if (!isfinite(rgb[i]))
            return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                           "%s: pixel %zu (x %zu, y %zu) has rgb[%zu] = %g (finite)", fn, i / 3,
                           i / 3 % s->cfg.width, i / 3 / s->cfg.width, i, (double)rgb[i]);
    for (size_t i = 0; moments && i < NF_GUIDE_DEPTHS * s->pixels; ++i)
        if (!(moments[i] >= 0.0f) || !isfinite(moments[i])) {
            size_t px = i % s->pixels;
            return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                           "%s: pixel %zu (x %zu, y %zu) has moment %zu = %g (finite, >= 0)", fn,
                           px, px % s->cfg.width, px / s->cfg.width, i / s->pixels,
                           (double)moments[i]);
        }
    return NF_OK;
}

/* One pass into a kind's sums; moments NULL: the pass's squared luminance (a plain pass). */
static void nf_kind_add(nf_kind_sums *k, size_t pixels, const float *rgb, const float *moments)
{
    for (size_t i = 0; i < pixels; ++i) {
        const float *p = rgb + 3 * i;
        double l = ((double)p[0] + p[1] + p[2]) / 3.0;
        k->rgb[3 * i] += p[0];
        k->rgb[3 * i + 1] += p[1];
        k->rgb[3 * i + 2] += p[2];
        k->lum[i] += l;
        k->sq[i] += l * l;
        if (!moments)
            k->m2[0][i] += (double)(float)(l * l);
        for (unsigned m = 0; moments && m < NF_GUIDE_DEPTHS; ++m)
            k->m2[m][i] += moments[m * pixels + i];
    }
    k->n++;
}

/* A training pass into the groups: when all are full, neighbours merge and groups double. */
static void nf_groups_add(nf_schedule *s, const float *rgb)
{
    const size_t floats = 3 * s->pixels;
    if (s->groups > 0 && s->group_count[s->groups - 1] < s->per_group) {
        double *sum = s->group[s->groups - 1];
        for (size_t i = 0; i < floats; ++i)
            sum[i] += rgb[i];
        s->group_count[s->groups - 1]++;
        return;
    }
    if (s->groups == NF_TRAIN_GROUPS) { /* 32 groups of k become 16 of 2k */
        double *sum[NF_TRAIN_GROUPS];
        uint32_t count[NF_TRAIN_GROUPS];
        for (unsigned i = 0; i < NF_TRAIN_GROUPS / 2; ++i) {
            double *a = s->group[2 * i], *b = s->group[2 * i + 1];
            for (size_t j = 0; j < floats; ++j)
                a[j] += b[j];
            sum[i] = a;
            count[i] = s->group_count[2 * i] + s->group_count[2 * i + 1];
            sum[NF_TRAIN_GROUPS / 2 + i] = b; /* reused by the next groups */
            count[NF_TRAIN_GROUPS / 2 + i] = 0;
        }
        memcpy(s->group, sum, sizeof sum);
        memcpy(s->group_count, count, sizeof count);
        s->groups = NF_TRAIN_GROUPS / 2;
        s->per_group *= 2;
    }
    double *sum = s->group[s->groups];
    for (size_t i = 0; i < floats; ++i)
        sum[i] = rgb[i];
    s->group_count[s->groups++] = 1;
}

nf_status nf_schedule_add_pass(nf_schedule *s, const nf_pass_plan *plan, const float *rgb,
                               const float *moments, double seconds, double cpu_seconds,
                               const nf_reduce *red)
{
    static const char fn[] = "nf_schedule_add_pass";
    nf_status st = nf_check_pointers(fn, "s", s, "plan", plan, "rgb", rgb, NULL, NULL);
    if (st != NF_OK)
        return st;
    if (!s->pending || plan->pass != s->plan.pass || plan->todo != s->plan.todo ||
        plan->kind_ != s->plan.kind_ || plan->depth != s->plan.depth)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                       "%s: the plan of pass %u is not the latest from nf_schedule_next, or was "
                       "added already",
                       fn, plan->pass);
    if (!moments && plan->todo != NF_TODO_PLAIN)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                       "%s: moments is NULL for a guided pass (only plain passes may omit them)",
                       fn);
    if (!(seconds >= 0.0) || !isfinite(seconds) || !(cpu_seconds >= 0.0) || !isfinite(cpu_seconds))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                       "%s: seconds %g and cpu_seconds %g (finite, >= 0)", fn, seconds,
                       cpu_seconds);
    if ((st = nf_check_pass(s, rgb, moments, fn)) != NF_OK)
        return st;
    /* The pass's time: the slowest process's wall clock, every process's CPU. */
    if (red && red->max_f64 && (st = red->max_f64(red->user, &seconds, 1)) != NF_OK)
        return nf_fail(st, "%s: the reduce hook max_f64 failed", fn);
    if ((st = nf_schedule_sum(red, &cpu_seconds, 1, fn)) != NF_OK)
        return st;
    s->pending = 0;
    if (plan->todo == NF_TODO_TRAIN) {
        nf_groups_add(s, rgb);
        nf_kind_add(&s->train, s->pixels, rgb, moments);
        s->rep.train_passes++;
        s->last_seconds = seconds; /* a render pass costs the tracing, not the steps */
        s->rep.train_ratio = NAN;
        return s->plain_first ? nf_schedule_training_ratio(s, rgb, cpu_seconds, red, fn) : NF_OK;
    }
    nf_kind_sums *ks = &s->kind[plan->kind_];
    nf_kind_add(ks, s->pixels, rgb, moments);
    ks->cpu += cpu_seconds;
    if (plan->pass > 0 && !s->training) {
        ks->steady_n++;
        ks->steady_cpu += cpu_seconds;
    }
    ks->last_seconds = s->last_seconds = seconds;
    s->rep.render_passes++;
    s->rep.render_seconds += seconds;
    if (!plan->measure_) {
        nf_schedule_count(s);
        s->since_measure++;
        return NF_OK;
    }
    s->since_measure = 0;
    return nf_schedule_measure(s, red, fn);
}
