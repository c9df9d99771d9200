/*
 * fuzz_schedule.c - libFuzzer target for the schedule (nisflow/schedule.h): a configuration
 * (any bytes for the image's size, the budget, the fixed depth and the paths of a pass, so
 * that images are rendered whole or in subsets; a guide or none, choosing or not) and a
 * program of calls read from the input: plans at any elapsed time (NaN, Inf, negative,
 * backwards), passes of any radiance and moments (NaN, Inf, negative, huge), forged, stale and
 * repeated plans, any times, and the image at any point.
 *
 * Invariants (abort, which libFuzzer reports, when broken):
 *   - every call returns NF_OK or a documented error with a message;
 *   - a plan's todo is one of the four and its depth one the guide can render; the passes of
 *     accepted plans are numbered 0, 1, 2, ... ; STOP, once answered, is answered ever after;
 *     a schedule without a guide plans plain passes only;
 *   - a plan's paths lie in the image (nf_pass_pixel) and are at most pass_paths;
 *   - a refused call changes nothing: a refused nf_schedule_add_pass leaves the plan pending
 *     (the same plan is then accepted with good data), a refused nf_schedule_next leaves
 *     the pass numbering as it was;
 *   - a path whose radiance or moment is not finite, or whose moment is negative, never
 *     makes a pass refused: it is left out and counted (nf_schedule_report.dropped; a huge
 *     finite value whose weighted sum would overflow may be left out too);
 *   - the image is finite and each of its values lies within the range of the values the
 *     accepted passes' paths gave its pixel, or is 0 where none did (the combination has
 *     non-negative weights that sum to one).
 */
#include <float.h>
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "fuzz_common.h"

/* Up to 40 x 40 pixels: beyond a pass of 1,024 paths, so that some images go in subsets. */
#define MAX_SIDE 40
#define MAX_PIXELS (MAX_SIDE * MAX_SIDE)
#define MAX_CALLS 40
/* A value this large may overflow the image's float sums once weighted: it may be left out. */
#define RISKY 1e30f

/* Mostly tame floats, sometimes any bit pattern (NaN, Inf, denormals, huge). */
static float next_float(nf_fuzz_reader *r)
{
    uint8_t kind = nf_fuzz_byte(r);
    if (kind < 220)
        return (float)nf_fuzz_byte(r) / 64.0f;
    uint32_t bits = nf_fuzz_u32(r);
    float f;
    memcpy(&f, &bits, sizeof f);
    return f;
}

static double next_double(nf_fuzz_reader *r)
{
    uint8_t kind = nf_fuzz_byte(r);
    if (kind < 230)
        return (double)nf_fuzz_byte(r) / 16.0;
    uint64_t bits = (uint64_t)nf_fuzz_u32(r) | (uint64_t)nf_fuzz_u32(r) << 32;
    double d;
    memcpy(&d, &bits, sizeof d);
    return d;
}

static void check_status(nf_status s, const char *what)
{
    NF_FUZZ_CHECK(s == NF_OK || s == NF_ERROR_INVALID_ARGUMENT || s == NF_ERROR_OUT_OF_MEMORY,
                  "%s returned %d", what, (int)s);
    if (s != NF_OK)
        NF_FUZZ_CHECK(nf_last_error_message()[0] != '\0', "%s: no message", what);
}

static const nf_model *shared_model(void)
{
    static nf_model *m;
    if (!m) {
        nf_config cfg;
        nf_config_init(&cfg, NF_PRESET_SMALL);
        cfg.sh_bands = 0;
        NF_FUZZ_CHECK(nf_model_create(&cfg, &m) == NF_OK, "model");
    }
    return m;
}

/* What the program knows about the schedule, to check it against. */
typedef struct state {
    size_t pixels;
    uint32_t next_pass; /* the pass number the next accepted plan must have */
    int pending, stopped, has_guide;
    nf_pass_plan plan;
    uint64_t dropped, risky; /* paths that must be left out, and that may be */
    float lo[3 * MAX_PIXELS], hi[3 * MAX_PIXELS];
} state;

static void check_plan(const state *s, const nf_pass_plan *p, uint32_t fixed_depth)
{
    NF_FUZZ_CHECK(p->todo == NF_TODO_TRAIN || p->todo == NF_TODO_GUIDED ||
                      p->todo == NF_TODO_PLAIN || p->todo == NF_TODO_STOP,
                  "todo %d", (int)p->todo);
    if (s->stopped)
        NF_FUZZ_CHECK(p->todo == NF_TODO_STOP, "a plan %d after STOP", (int)p->todo);
    if (!s->has_guide)
        NF_FUZZ_CHECK(p->todo == NF_TODO_PLAIN || p->todo == NF_TODO_STOP,
                      "a guided plan %d without a guide", (int)p->todo);
    if (p->todo == NF_TODO_STOP)
        return;
    NF_FUZZ_CHECK(p->pass == s->next_pass, "pass %u, expected %u", p->pass, s->next_pass);
    NF_FUZZ_CHECK(p->paths >= 1 && p->paths <= MAX_PIXELS, "a pass of %u paths", p->paths);
    for (uint32_t j = 0; j < p->paths; ++j)
        NF_FUZZ_CHECK(nf_pass_pixel(p, j) < s->pixels, "path %u outside the image", j);
    if (p->todo != NF_TODO_PLAIN) {
        int ok = fixed_depth ? p->depth == fixed_depth : p->depth < NF_GUIDE_DEPTHS;
        NF_FUZZ_CHECK(ok, "depth %u (fixed %u)", p->depth, fixed_depth);
    }
}

/* A pass's paths (radiance and moments) from the input. */
static void next_pass(nf_fuzz_reader *r, uint32_t paths, float *rgb, float *moments)
{
    for (size_t i = 0; i < 3 * (size_t)paths; ++i)
        rgb[i] = next_float(r);
    for (size_t i = 0; i < NF_GUIDE_DEPTHS * (size_t)paths; ++i)
        moments[i] = next_float(r) - (nf_fuzz_byte(r) == 7 ? 10.0f : 0.0f);
}

/* An accepted pass into what the program knows: which paths must be left out, and the range
 * of the values each pixel was given. */
static void take_pass(state *k, const nf_pass_plan *p, const float *rgb, const float *moments)
{
    for (uint32_t j = 0; j < p->paths; ++j) {
        const float *c = rgb + 3 * (size_t)j;
        int ok = isfinite(c[0]) && isfinite(c[1]) && isfinite(c[2]);
        for (unsigned m = 0; moments && m < NF_GUIDE_DEPTHS; ++m) {
            float v = moments[(size_t)m * p->paths + j];
            ok = ok && v >= 0.0f && isfinite(v);
        }
        k->dropped += !ok;
        const int image = !p->stride_ || j >= p->measured_; /* measured paths stay out */
        if (!ok || !image)
            continue;
        k->risky += fabsf(c[0]) > RISKY || fabsf(c[1]) > RISKY || fabsf(c[2]) > RISKY;
        size_t i = nf_pass_pixel(p, j);
        for (unsigned ch = 0; ch < 3; ++ch) {
            k->lo[3 * i + ch] = fminf(k->lo[3 * i + ch], c[ch]);
            k->hi[3 * i + ch] = fmaxf(k->hi[3 * i + ch], c[ch]);
        }
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    nf_fuzz_reader r = {data, size};
    nf_schedule_config sc;
    nf_schedule_config_init(&sc);
    const uint32_t magic = sc.magic_;
    uint8_t flags = nf_fuzz_byte(&r);
    if (flags & 1) /* any bytes */
        memcpy(&sc, data, size < sizeof sc ? size : sizeof sc);
    if (!(flags & 2)) /* a config from nf_schedule_config_init, or not */
        sc.magic_ = magic;
    sc.width = nf_fuzz_byte(&r) % (MAX_SIDE + 1);
    sc.height = nf_fuzz_byte(&r) % (MAX_SIDE + 1);
    sc.budget = next_double(&r);
    sc.guide_depth = nf_fuzz_byte(&r) % 4 == 0 ? nf_fuzz_byte(&r) % 3 : 0;
    uint8_t paths = nf_fuzz_byte(&r);
    if (paths % 4 == 1) /* subsets of the image */
        sc.pass_paths = 1024;
    else if (paths % 4 == 2) /* anything: out of range is refused */
        sc.pass_paths = nf_fuzz_u32(&r) % 4096;
    nf_guide *g = NULL;
    if (flags & 4) {
        nf_guide_config gc;
        nf_guide_config_init(&gc);
        gc.store_capacity = 64;
        gc.step_samples = 8;
        gc.steps_per_pass = 1;
        gc.pass_choice = (flags & 8) ? 1u : 0u;
        gc.train_fraction = (float)(nf_fuzz_byte(&r) % 4) / 8.0f;
        NF_FUZZ_CHECK(nf_guide_create(shared_model(), &gc, &g) == NF_OK, "guide");
    }
    nf_schedule *s = NULL;
    nf_status st = nf_schedule_create(g, &sc, &s);
    check_status(st, "nf_schedule_create");
    int valid = sc.magic_ == magic && sc.width >= 1 && sc.height >= 1 && sc.budget > 0.0 &&
                isfinite(sc.budget) && sc.pass_paths >= 1024 && sc.pass_paths <= (1u << 26);
    if (st != NF_OK) {
        NF_FUZZ_CHECK(s == NULL, "a refused create left *out");
        NF_FUZZ_CHECK(!valid || st == NF_ERROR_OUT_OF_MEMORY, "a valid config refused");
        nf_guide_destroy(g);
        return 0;
    }
    static state k;
    memset(&k, 0, sizeof k);
    k.pixels = (size_t)sc.width * sc.height;
    k.has_guide = g != NULL;
    for (size_t i = 0; i < 3 * k.pixels; ++i) {
        k.lo[i] = INFINITY;
        k.hi[i] = -INFINITY;
    }
    float rgb[3 * MAX_PIXELS], moments[NF_GUIDE_DEPTHS * MAX_PIXELS], out[3 * MAX_PIXELS];
    for (int call = 0; call < MAX_CALLS && r.n > 0; ++call) {
        uint8_t op = nf_fuzz_byte(&r) % 4;
        if (op == 0) { /* a plan */
            nf_pass_plan p;
            double elapsed = next_double(&r);
            st = nf_schedule_next(s, elapsed, NULL, &p);
            check_status(st, "nf_schedule_next");
            NF_FUZZ_CHECK(st == NF_OK || k.pending || !(elapsed >= 0.0),
                          "next refused at elapsed %g with no plan pending", elapsed);
            if (st != NF_OK)
                continue;
            check_plan(&k, &p, sc.guide_depth);
            if (p.todo == NF_TODO_STOP) {
                k.stopped = 1;
                continue;
            }
            k.plan = p;
            k.pending = 1;
            k.next_pass++;
        } else if (op == 1 || op == 2) { /* a pass, maybe with a forged plan */
            next_pass(&r, k.pending ? k.plan.paths : (uint32_t)k.pixels, rgb, moments);
            nf_pass_plan p = k.plan;
            uint8_t forge = nf_fuzz_byte(&r) % 8;
            if (forge == 0)
                p.pass += 1 + nf_fuzz_byte(&r);
            else if (forge == 1)
                p.todo = (nf_pass_todo)(nf_fuzz_byte(&r) % 5);
            else if (forge == 2)
                p.first_ += 1u + nf_fuzz_byte(&r);
            int no_moments = nf_fuzz_byte(&r) % 4 == 0;
            double seconds = nf_fuzz_byte(&r) % 8 == 0 ? next_double(&r) : 0.01;
            double cpu = nf_fuzz_byte(&r) % 8 == 0 ? next_double(&r) : 0.02;
            int bad_time = !(seconds >= 0.0) || !isfinite(seconds) || !(cpu >= 0.0) ||
                           !isfinite(cpu);
            int forged = forge <= 2 && memcmp(&p, &k.plan, sizeof p) != 0;
            st = nf_schedule_add_pass(s, &p, rgb, no_moments ? NULL : moments, seconds, cpu,
                                      NULL);
            check_status(st, "nf_schedule_add_pass");
            /* Values never refuse a pass: bad paths are left out. */
            int must_refuse = !k.pending || forged || bad_time ||
                              (no_moments && p.todo != NF_TODO_PLAIN);
            NF_FUZZ_CHECK((st != NF_OK) == must_refuse,
                          "add_pass %s (pending %d, forged %d, times %g %g)",
                          st == NF_OK ? "accepted" : "refused", k.pending, forged, seconds, cpu);
            if (st == NF_OK) {
                k.pending = 0;
                take_pass(&k, &p, rgb, no_moments ? NULL : moments);
            }
        } else { /* the image */
            nf_schedule_report rep;
            st = nf_schedule_combine(s, NULL, out, &rep);
            check_status(st, "nf_schedule_combine");
            NF_FUZZ_CHECK(st == NF_OK, "combine refused");
            NF_FUZZ_CHECK(rep.train_weight >= 0.0 && rep.train_weight <= 1.0,
                          "train weight %g", rep.train_weight);
            NF_FUZZ_CHECK(rep.dropped >= k.dropped && rep.dropped <= k.dropped + k.risky,
                          "%llu paths left out, %llu expected (%llu more may be)",
                          (unsigned long long)rep.dropped, (unsigned long long)k.dropped,
                          (unsigned long long)k.risky);
            for (size_t i = 0; i < 3 * k.pixels; ++i) {
                NF_FUZZ_CHECK(isfinite(out[i]), "pixel value %zu is %g", i, (double)out[i]);
                if (!(k.lo[i] <= k.hi[i])) { /* no path reached this pixel */
                    NF_FUZZ_CHECK(out[i] == 0.0f, "a pixel without paths: %g", (double)out[i]);
                    continue;
                }
                /* Rounding: float sums of at most MAX_CALLS weighted values. */
                float slack = 1e-5f * fmaxf(fabsf(k.lo[i]), fabsf(k.hi[i])) + 1e-30f;
                if (out[i] == 0.0f && fmaxf(fabsf(k.lo[i]), fabsf(k.hi[i])) > RISKY)
                    continue; /* its only paths may have been left out */
                NF_FUZZ_CHECK(out[i] >= k.lo[i] - slack && out[i] <= k.hi[i] + slack,
                              "pixel value %zu = %g outside the passes' [%g, %g]", i,
                              (double)out[i], (double)k.lo[i], (double)k.hi[i]);
            }
        }
    }
    nf_schedule_destroy(s);
    nf_guide_destroy(g);
    return 0;
}
