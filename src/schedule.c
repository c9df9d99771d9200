/*
 * schedule.c - the schedule's life cycle and its plans (nisflow/schedule.h): which pass to
 * render next, and taking in the pass that was rendered. What the passes measure is
 * schedule_measure.c, the image schedule_combine.c.
 */
#include <float.h>
#include <math.h>
#include <string.h>

#include "guide_internal.h"
#include "schedule_internal.h"

/* The largest image: 2^26 pixels, 3.2 GB of sums. */
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
    sc->pass_paths = NF_PASS_PATHS_DEFAULT;
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
    if (sc->pass_paths < NF_PASS_PATHS_MIN || sc->pass_paths > NF_SCHEDULE_MAX_PIXELS)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: pass_paths is %u (in [%u, %zu])", fn,
                       sc->pass_paths, NF_PASS_PATHS_MIN, NF_SCHEDULE_MAX_PIXELS);
    return NF_OK;
}

/* Which pixels the passes render: an image that fits a pass whole; a larger one in subsets
 * of pass_paths less the measured grid, which is at most pass_paths / NF_MEASURE_SHARE pixels
 * as evenly apart in x and y as the image allows. */
static nf_pass_layout nf_layout_of(const nf_schedule_config *sc)
{
    nf_pass_layout l = {1u, sc->width, sc->height, sc->width * sc->height, 0u};
    const size_t pixels = (size_t)sc->width * sc->height;
    if (pixels <= sc->pass_paths)
        return l;
    const size_t most = sc->pass_paths / NF_MEASURE_SHARE;
    while ((size_t)l.grid_width * l.grid_height > most) {
        l.grid++;
        l.grid_width = (sc->width + l.grid - 1) / l.grid;
        l.grid_height = (sc->height + l.grid - 1) / l.grid;
    }
    l.measured = l.grid_width * l.grid_height;
    const size_t subset = sc->pass_paths - l.measured;
    l.stride = (uint32_t)((pixels + subset - 1) / subset);
    return l;
}

uint32_t nf_pass_pixel(const nf_pass_plan *plan, uint32_t j)
{
    if (!plan || j >= plan->paths || !plan->grid_width_)
        return 0u;
    if (j < plan->measured_)
        return (j / plan->grid_width_) * plan->grid_ * plan->width_ +
               (j % plan->grid_width_) * plan->grid_;
    return plan->first_ + (j - plan->measured_) * plan->stride_;
}

/* count zeroed elements of `size` bytes. */
static void *nf_schedule_zeroed(nf_schedule *s, size_t count, size_t size, int *ok)
{
    void *p = NULL;
    if (*ok && count <= SIZE_MAX / size)
        p = s->alloc.alloc(s->alloc.user, count * size);
    if (!p)
        *ok = 0;
    else
        memset(p, 0, count * size);
    return p;
}

static double *nf_schedule_array(nf_schedule *s, size_t count, int *ok)
{
    return (double *)nf_schedule_zeroed(s, count, sizeof(double), ok);
}

static void nf_schedule_release(nf_schedule *s, void *p)
{
    if (p)
        s->alloc.free(s->alloc.user, p);
}

static void nf_kind_arrays(nf_schedule *s, nf_kind_sums *k, int *ok)
{
    k->lum = nf_schedule_array(s, s->lay.measured, ok);
    k->sq = nf_schedule_array(s, s->lay.measured, ok);
    for (unsigned m = 0; m < NF_GUIDE_DEPTHS; ++m)
        k->m2[m] = nf_schedule_array(s, s->lay.measured, ok);
}

static void nf_kind_release(nf_schedule *s, nf_kind_sums *k)
{
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
    for (unsigned a = 0; a < NF_ACCS; ++a)
        nf_schedule_release(s, s->acc[a]);
    nf_schedule_release(s, s->ref);
    nf_schedule_release(s, s->peakless);
    nf_schedule_release(s, s->pool);
    nf_schedule_release(s, s->pool2);
    nf_schedule_release(s, s->lum);
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
    s->lay = nf_layout_of(sc);
    int ok = 1;
    nf_kind_arrays(s, &s->train, &ok);
    for (unsigned k = 0; k < NF_KINDS; ++k)
        nf_kind_arrays(s, &s->kind[k], &ok);
    for (unsigned a = 0; a < NF_ACCS; ++a)
        s->acc[a] = (float *)nf_schedule_zeroed(s, 4 * s->pixels, sizeof(float), &ok);
    s->ref = nf_schedule_array(s, s->lay.measured, &ok);
    s->peakless = nf_schedule_array(s, s->lay.measured, &ok);
    s->pool = nf_schedule_array(s, s->lay.measured, &ok);
    s->pool2 = nf_schedule_array(s, s->lay.measured, &ok);
    s->lum = nf_schedule_array(s, s->lay.measured, &ok);
    if (!ok) {
        nf_schedule_destroy(s);
        return nf_fail(NF_ERROR_OUT_OF_MEMORY,
                       "%s: could not allocate the sums of a %u x %u image (about %zu MB)", fn,
                       sc->width, sc->height, s->pixels * 48u / 1000000u + 1u);
    }
    const nf_guide_config *gc = guide ? nf_guide_get_config(guide) : NULL;
    s->training = gc && gc->train_fraction > 0.0f;
    s->choosing = gc && gc->pass_choice;
    /* With the choice of passes, two plain passes come first: training measures itself
     * against them (nf_guide_report_training_ratio). */
    s->plain_first = s->training && s->choosing ? 2u : 0u;
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
    const nf_pass_layout *l = &s->lay;
    nf_pass_plan p;
    memset(&p, 0, sizeof p);
    p.todo = g ? NF_TODO_GUIDED : NF_TODO_PLAIN;
    p.depth = fixed;
    p.pass = s->next_pass;
    p.kind_ = g ? 0u : NF_PLAIN;
    /* Each pass the next subset, so that every `stride` passes cover the image once. */
    p.width_ = s->cfg.width;
    p.grid_ = l->grid;
    p.grid_width_ = l->grid_width;
    p.measured_ = l->measured;
    p.stride_ = l->stride;
    p.first_ = l->stride ? s->next_pass % l->stride : 0u;
    p.paths = l->measured +
              (l->stride ? (uint32_t)((s->pixels - p.first_ + l->stride - 1) / l->stride) : 0u);
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
     * kind). A budget too short for a single pass still renders one: every pixel has a path. */
    const nf_kind_sums *ks = &s->kind[p.kind_];
    double expect = ks->last_seconds > 0.0 ? ks->last_seconds : s->last_seconds;
    const uint32_t covered = l->stride ? l->stride : 1u;
    const int stop = s->next_pass >= covered && elapsed + expect > s->cfg.budget;
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

/* Whether path j of a pass is usable: its radiance finite, its moments finite and >= 0. */
static int nf_path_ok(const float *rgb, const float *moments, uint32_t paths, uint32_t j)
{
    const float *p = rgb + 3 * (size_t)j;
    if (!isfinite(p[0]) || !isfinite(p[1]) || !isfinite(p[2]))
        return 0;
    for (unsigned m = 0; moments && m < NF_GUIDE_DEPTHS; ++m) {
        float v = moments[(size_t)m * paths + j];
        if (!(v >= 0.0f) || !isfinite(v))
            return 0;
    }
    return 1;
}

/* The pass's measured paths (its first lay.measured) into a kind's sums and their luminance
 * into s->lum; moments NULL: each path's squared luminance (a plain pass). A path left out
 * counts as black: every pass must add to every measured pixel. Returns the paths left out. */
static uint64_t nf_kind_add(nf_schedule *s, nf_kind_sums *k, const float *rgb, const float *moments,
                            uint32_t paths)
{
    uint64_t dropped = 0;
    for (uint32_t i = 0; i < s->lay.measured; ++i) {
        const int ok = nf_path_ok(rgb, moments, paths, i);
        const float *p = rgb + 3 * (size_t)i;
        double l = ok ? ((double)p[0] + p[1] + p[2]) / 3.0 : 0.0;
        dropped += !ok;
        s->lum[i] = l;
        k->lum[i] += l;
        k->sq[i] += l * l;
        if (!moments) /* as a float moment would hold it, where a float holds it */
            k->m2[0][i] += l * l <= FLT_MAX ? (double)(float)(l * l) : l * l;
        for (unsigned m = 0; ok && moments && m < NF_GUIDE_DEPTHS; ++m)
            k->m2[m][i] += moments[(size_t)m * paths + i];
    }
    k->n++;
    return dropped;
}

/* The pass's image paths (all of them for a whole image, the subset's otherwise) into an
 * accumulator with weight w; a path whose weighted value would overflow its pixel's float
 * sum is left out too. Returns the paths left out. */
static uint64_t nf_image_add(nf_schedule *s, float *acc, double w, const nf_pass_plan *plan,
                             const float *rgb, const float *moments)
{
    uint64_t dropped = 0;
    for (uint32_t j = s->lay.stride ? s->lay.measured : 0u; j < plan->paths; ++j) {
        if (!nf_path_ok(rgb, moments, plan->paths, j)) {
            dropped++;
            continue;
        }
        const float *p = rgb + 3 * (size_t)j;
        float *a = acc + 4 * (size_t)nf_pass_pixel(plan, j);
        float sum[3];
        for (unsigned c = 0; c < 3; ++c)
            sum[c] = a[c] + (float)(w * p[c]);
        if (!isfinite(sum[0]) || !isfinite(sum[1]) || !isfinite(sum[2])) {
            dropped++; /* a value whose sum overflows a float */
            continue;
        }
        memcpy(a, sum, sizeof sum);
        a[3] += (float)w;
    }
    return dropped;
}

/* A training pass's weight in the image: its spread's inverse, in the unit of the first
 * training pass's, kept within 10^6 either way (a black pass has no spread). */
static double nf_training_weight(nf_schedule *s, double spread)
{
    if (!(s->train_unit > 0.0))
        s->train_unit = spread > 0.0 ? spread : 1.0;
    double w = spread > 0.0 ? s->train_unit / spread : 1.0;
    w = fmin(fmax(w, 1e-6), 1e6);
    s->train_wmax = fmax(s->train_wmax, w);
    return w;
}

nf_status nf_schedule_add_pass(nf_schedule *s, const nf_pass_plan *plan, const float *rgb,
                               const float *moments, double seconds, double cpu_seconds,
                               const nf_reduce *red)
{
    static const char fn[] = "nf_schedule_add_pass";
    nf_status st = nf_check_pointers(fn, "s", s, "plan", plan, "rgb", rgb, NULL, NULL);
    if (st != NF_OK)
        return st;
    const nf_pass_plan *q = &s->plan;
    if (!s->pending || plan->pass != q->pass || plan->todo != q->todo || plan->kind_ != q->kind_ ||
        plan->depth != q->depth || plan->paths != q->paths || plan->width_ != q->width_ ||
        plan->grid_ != q->grid_ || plan->grid_width_ != q->grid_width_ ||
        plan->measured_ != q->measured_ || plan->first_ != q->first_ ||
        plan->stride_ != q->stride_ || plan->measure_ != q->measure_)
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
    /* The pass's time: the slowest process's wall clock, every process's CPU. */
    if (red && red->max_f64 && (st = red->max_f64(red->user, &seconds, 1)) != NF_OK)
        return nf_fail(st, "%s: the reduce hook max_f64 failed", fn);
    if ((st = nf_schedule_sum(red, &cpu_seconds, 1, fn)) != NF_OK)
        return st;
    s->pending = 0;
    const int train = plan->todo == NF_TODO_TRAIN;
    nf_kind_sums *ks = train ? &s->train : &s->kind[plan->kind_];
    uint64_t dropped = nf_kind_add(s, ks, rgb, moments, plan->paths);
    if (!s->lay.stride) /* the measured paths are the image's: counted there */
        dropped = 0;
    double w = 1.0;
    int acc = plan->kind_ == NF_PLAIN ? NF_ACC_PLAIN : NF_ACC_GUIDED;
    if (train) {
        double spread = 0.0;
        acc = NF_ACC_TRAIN;
        s->rep.train_passes++;
        s->last_seconds = seconds; /* a render pass costs the tracing, not the steps */
        s->rep.train_ratio = NAN;
        st = nf_schedule_training_pass(s, cpu_seconds, red, &spread, fn);
        w = nf_training_weight(s, spread);
    } else {
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
        } else {
            s->since_measure = 0;
            st = nf_schedule_measure(s, red, fn);
        }
    }
    /* The image takes the pass even when a reduce failed: it is this process's own. */
    s->rep.dropped += dropped + nf_image_add(s, s->acc[acc], w, plan, rgb, moments);
    return st;
}
