/*
 * fuzz_guide.c - libFuzzer target for the guide (nisflow/guide.h): a configuration and a
 * program of calls read from the input. The configuration's fields take any bytes (out of
 * range ones must be refused with a message); the program adds hostile samples (NaN, Inf,
 * zero vectors, negative and huge weights, any keys and payloads), trains passes and batches
 * with caller groups of any shape, publishes, acquires and releases (foreign and unbalanced
 * releases included), and calls the path policy with any floats.
 *
 * Invariants (abort, which libFuzzer reports, when broken):
 *   - every call returns NF_OK or a documented error with a message;
 *   - a refused add leaves the store as it was (the next pass sees only accepted samples);
 *     no add is refused as busy;
 *   - the training model's parameters stay finite, and the published model acquire hands out
 *     has the parameters of the last successful publish;
 *   - the policy functions are total: probabilities in [0, 1), survival in [0, 1], the boost
 *     finite and positive when it was;
 *   - the choice of passes answers a kind and a ratio >= 0 or NaN, the variance is finite and
 *     >= 0 or refused, a plain moment is never NaN or negative, and the reference without
 *     lone peaks keeps or lowers each pixel to a neighbour's value, or is refused untouched.
 * The model is built once per process, so that an execution costs the guide's work only.
 */
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "fuzz_common.h"
#include "guide_internal.h"
#include "policy_atoms.h"
#include "schedule_atoms.h"

#define MAX_SAMPLES 48
#define MAX_PARAMS 8192

/* Mostly tame floats, sometimes any bit pattern (NaN, Inf, denormals, huge). */
static float next_float(nf_fuzz_reader *r)
{
    uint8_t kind = nf_fuzz_byte(r);
    if (kind < 200)
        return (float)(nf_fuzz_byte(r)) / 255.0f * 2.0f - 0.5f;
    uint32_t bits = nf_fuzz_u32(r);
    float f;
    memcpy(&f, &bits, sizeof f);
    return f;
}

static const nf_model *shared_model(void)
{
    static nf_model *m;
    if (!m) {
        nf_config cfg;
        nf_config_init(&cfg, NF_PRESET_SMALL);
        cfg.sh_bands = 0;
        NF_FUZZ_CHECK(nf_model_create(&cfg, &m) == NF_OK, "model");
        NF_FUZZ_CHECK(nf_model_param_count(m) <= MAX_PARAMS, "param count");
    }
    return m;
}

static int known_status(nf_status s)
{
    return s == NF_OK || s == NF_ERROR_INVALID_ARGUMENT || s == NF_ERROR_OUT_OF_MEMORY ||
           s == NF_ERROR_NUMERIC || s == NF_ERROR_BUSY || s == NF_ERROR_STALE;
}

static void check_status(nf_status s, const char *what)
{
    NF_FUZZ_CHECK(known_status(s), "%s returned %d", what, (int)s);
    if (s != NF_OK)
        NF_FUZZ_CHECK(nf_last_error_message()[0] != '\0', "%s: no message", what);
}

static void check_policy(nf_fuzz_reader *r, const nf_guide_policy *p)
{
    float boost = next_float(r), c = next_float(r);
    float g = nf_guide_mixture_prob(p, boost);
    NF_FUZZ_CHECK(g >= 0.0f && g < 1.0f, "mixture prob %g for boost %g", (double)g,
                  (double)boost);
    float q = nf_guide_roulette_survival(p, c, boost);
    NF_FUZZ_CHECK(q >= 0.0f && q <= 1.0f, "survival %g", (double)q);
    float b = nf_guide_boost(boost, next_float(r), next_float(r), g);
    if (boost > 0.0f && isfinite(boost))
        NF_FUZZ_CHECK(!(b < 0.0f) && !isnan(b), "boost %g from %g", (double)b, (double)boost);
}

static double next_double(nf_fuzz_reader *r)
{
    uint8_t kind = nf_fuzz_byte(r);
    if (kind < 200)
        return (double)next_float(r);
    uint64_t bits = (uint64_t)nf_fuzz_u32(r) | (uint64_t)nf_fuzz_u32(r) << 32;
    double d;
    memcpy(&d, &bits, sizeof d);
    return d;
}

/* The reference without lone peaks for any image of up to 4 x 4, in place or shifted when the
 * input asks: refused with out untouched, or every pixel kept or lowered to a neighbour's
 * value (never raised, never another value). */
static void check_peaks(nf_fuzz_reader *r)
{
    double in[16], out[20];
    size_t w = nf_fuzz_byte(r) % 5, h = nf_fuzz_byte(r) % 5;
    for (size_t i = 0; i < w * h; ++i)
        in[i] = next_double(r);
    for (size_t i = 0; i < 20; ++i)
        out[i] = -7.0;
    uint8_t where = nf_fuzz_byte(r) % 8;
    double *dst = where == 0 ? in : where == 1 ? in + 1 : out;
    nf_status st = nf_guide_lower_peaks(w, h, in, dst);
    check_status(st, "nf_guide_lower_peaks");
    size_t n = w * h;
    NF_FUZZ_CHECK(st != NF_OK || dst == out || n == 0 || (dst == in + 1 && n == 1),
                  "lower_peaks accepted overlapping arrays (%zu pixels)", n);
    if (st != NF_OK || dst != out) {
        for (size_t i = 0; i < 20; ++i)
            NF_FUZZ_CHECK(out[i] == -7.0, "refused lower_peaks wrote out[%zu]", i);
        return;
    }
    for (size_t i = 0; i < w * h; ++i) {
        int from_neighbour = 0;
        for (size_t j = 0; j < w * h; ++j) {
            size_t dx = i % w > j % w ? i % w - j % w : j % w - i % w;
            size_t dy = i / w > j / w ? i / w - j / w : j / w - i / w;
            from_neighbour |= i != j && dx <= 1 && dy <= 1 && out[i] == in[j];
        }
        NF_FUZZ_CHECK(out[i] == in[i] || (out[i] < in[i] && from_neighbour),
                      "pixel %zu lowered from %g to %g", i, in[i], out[i]);
    }
}

/* The choice of passes and of their depth with any measures, the variance with any sums, the
 * training ratio and the plain and depth moments fed any floats: documented statuses, answers
 * in range, *out untouched when refused, the moments never NaN or negative. */
static void check_choice(nf_fuzz_reader *r, nf_guide *g, const nf_guide_policy *pol)
{
    nf_pass_measure m[2];
    for (int k = 0; k < 2; ++k) {
        m[k].passes = nf_fuzz_byte(r) % 8;
        m[k].seconds = next_double(r);
        m[k].variance = next_double(r);
    }
    nf_pass_choice c;
    nf_status st = nf_guide_choose_pass(g, m, &c);
    check_status(st, "nf_guide_choose_pass");
    if (st == NF_OK)
        NF_FUZZ_CHECK((c.kind == NF_PASS_GUIDED || c.kind == NF_PASS_PLAIN) &&
                          (c.exploring == 0 || c.exploring == 1) && !(c.ratio < 0.0),
                      "choice %d %d %g", (int)c.kind, c.exploring, c.ratio);
    double sum[4], sq[4], ref[4], v = -1.0;
    size_t n = nf_fuzz_byte(r) % 5;
    for (size_t i = 0; i < n; ++i) {
        sum[i] = next_double(r);
        sq[i] = next_double(r);
        ref[i] = next_double(r);
    }
    st = nf_guide_pass_variance(n, sum, sq, nf_fuzz_byte(r) % 4, ref, next_double(r), &v);
    check_status(st, "nf_guide_pass_variance");
    NF_FUZZ_CHECK(st == NF_OK ? v >= 0.0 && isfinite(v) : v == -1.0, "variance %g (status %d)", v,
                  (int)st);
    check_peaks(r);
    check_status(nf_guide_report_training_ratio(g, next_double(r)),
                 "nf_guide_report_training_ratio");
    nf_plain_moment pm;
    nf_plain_moment_start(&pm);
    for (int k = nf_fuzz_byte(r) % 8; k > 0; --k) {
        switch (nf_fuzz_byte(r) % 3) {
        case 0:
            nf_plain_moment_scatter(&pm, next_float(r), next_float(r), next_float(r));
            break;
        case 1:
            nf_plain_moment_roulette(&pm, pol, next_float(r), next_float(r));
            break;
        default:
            nf_plain_moment_add(&pm, next_float(r));
        }
        NF_FUZZ_CHECK(pm.moment >= 0.0f, "plain moment %g", (double)pm.moment);
    }
    nf_depth_moment dmo[3];
    for (int k = 0; k < 3; ++k)
        nf_depth_moment_start(&dmo[k], nf_fuzz_byte(r) % 4);
    for (int k = nf_fuzz_byte(r) % 8; k > 0; --k) {
        uint32_t depth = nf_fuzz_byte(r) % 6;
        size_t n = nf_fuzz_byte(r) % 4;
        switch (nf_fuzz_byte(r) % 3) {
        case 0:
            nf_depth_moment_scatter(dmo, n, depth, next_float(r), next_float(r), next_float(r));
            break;
        case 1:
            nf_depth_moment_roulette(dmo, n, pol, depth, next_float(r), next_float(r));
            break;
        default:
            nf_depth_moment_add(dmo, n, depth, next_float(r), next_float(r));
        }
        for (int j = 0; j < 3; ++j)
            NF_FUZZ_CHECK(dmo[j].moment >= 0.0f, "depth moment %g", (double)dmo[j].moment);
    }
    nf_pass_measure dm[NF_GUIDE_DEPTHS];
    for (uint32_t k = 0; k < NF_GUIDE_DEPTHS; ++k) {
        dm[k].passes = nf_fuzz_byte(r) % 8;
        dm[k].seconds = next_double(r);
        dm[k].variance = next_double(r);
    }
    nf_depth_choice dc = {NF_GUIDE_DEPTHS, 99u, -1.0};
    st = nf_guide_choose_depth(g, dm, &dc);
    check_status(st, "nf_guide_choose_depth");
    NF_FUZZ_CHECK(st == NF_OK ? dc.candidate < NF_GUIDE_DEPTHS &&
                                    dc.depth == dc.candidate &&
                                    !(dc.ratio < 0.0)
                              : dc.candidate == NF_GUIDE_DEPTHS && dc.depth == 99u,
                  "depth choice %u %u %g (status %d)", dc.candidate, dc.depth, dc.ratio, (int)st);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    nf_fuzz_reader r = {data, size};
    const nf_model *model = shared_model();
    static float params[MAX_PARAMS], published[MAX_PARAMS], got[MAX_PARAMS];
    const size_t P = nf_model_param_count(model);

    nf_guide_config gc;
    nf_guide_config_init(&gc);
    /* Capacities in range stay small (the fuzzer's memory limit); 0 and 2^26 + 1 are out. */
    uint8_t cap = nf_fuzz_byte(&r);
    gc.store_capacity = cap == 0 ? 0u : cap == 1 ? ((size_t)1 << 26) + 1u : (size_t)cap;
    gc.payload_bytes = nf_fuzz_byte(&r) % 16;
    gc.step_samples = 1u + nf_fuzz_byte(&r) % 64;
    gc.steps_per_pass = 1u + nf_fuzz_byte(&r) % 3;
    gc.groups = nf_fuzz_byte(&r) % 10;
    gc.patience = nf_fuzz_byte(&r) % 4;
    if (nf_fuzz_byte(&r) % 4 == 0)
        gc.clamp_quantile = next_float(&r);
    if (nf_fuzz_byte(&r) % 4 == 0)
        gc.learning_rate = next_float(&r);
    if (nf_fuzz_byte(&r) % 4 == 0)
        gc.policy.mixture_prob = next_float(&r);
    if (nf_fuzz_byte(&r) % 4 == 0)
        gc.policy.max_boost = next_float(&r);
    nf_guide *g = NULL;
    nf_status st = nf_guide_create(model, &gc, &g);
    check_status(st, "nf_guide_create");
    if (st != NF_OK) {
        NF_FUZZ_CHECK(g == NULL, "a refused create wrote *out");
        return 0;
    }
    NF_FUZZ_CHECK(nf_model_get_params(nf_guide_training_model(g), published) == NF_OK, "params");

    nf_context ctx[MAX_SAMPLES];
    float dir[3 * MAX_SAMPLES], weight[MAX_SAMPLES];
    uint64_t key[MAX_SAMPLES];
    uint8_t payload[MAX_SAMPLES * 16];
    size_t group_end[16];
    const nf_model *held[4] = {NULL, NULL, NULL, NULL};
    uint64_t accepted = 0;
    for (int op = 0; op < 24 && r.n > 0; ++op) {
        switch (nf_fuzz_byte(&r) % 8) {
        case 0:
        case 1: { /* add samples */
            size_t n = nf_fuzz_byte(&r) % (MAX_SAMPLES + 1);
            for (size_t i = 0; i < n; ++i) {
                for (int a = 0; a < 3; ++a) {
                    ctx[i].position[a] = next_float(&r);
                    ctx[i].normal[a] = a == 2 ? 1.0f : next_float(&r);
                    ctx[i].wo[a] = a == 2 ? 1.0f : next_float(&r);
                    dir[3 * i + (size_t)a] = next_float(&r);
                }
                /* Sometimes a point in a medium (zero normal) with a g of any value (mostly
                 * within +-0.99, which the library accepts); on surfaces g is garbage. */
                ctx[i].phase_g = next_float(&r);
                if (nf_fuzz_byte(&r) % 4 == 0)
                    ctx[i].normal[0] = ctx[i].normal[1] = ctx[i].normal[2] = 0.0f;
                weight[i] = next_float(&r) * (nf_fuzz_byte(&r) % 2 ? 1.0f : 100.0f);
                key[i] = nf_fuzz_u32(&r) % 7u;
            }
            for (size_t i = 0; i < n * gc.payload_bytes; ++i)
                payload[i] = nf_fuzz_byte(&r);
            size_t positive = 0;
            for (size_t i = 0; i < n; ++i)
                positive += weight[i] > 0.0f;
            st = nf_guide_add_samples(g, n, nf_fuzz_byte(&r) % 4 ? key : NULL, ctx, dir, weight,
                                      nf_fuzz_byte(&r) % 2 ? payload : NULL);
            check_status(st, "nf_guide_add_samples");
            NF_FUZZ_CHECK(st != NF_ERROR_BUSY, "an add was refused as busy");
            if (st == NF_OK)
                accepted += positive;
            break;
        }
        case 2: { /* a training pass */
            nf_guide_stats before, after;
            NF_FUZZ_CHECK(nf_guide_get_stats(g, &before) == NF_OK, "stats");
            nf_guide_pass_report rep;
            NF_FUZZ_CHECK(nf_guide_pending(g) <= gc.store_capacity, "pending above capacity");
            /* Sometimes through the guide's own parallel-for (no helper: the caller runs it). */
            const nf_parallel helpers = nf_guide_helpers(g);
            st = nf_guide_train_pass(g, nf_fuzz_byte(&r) % 2 ? &helpers : NULL, NULL, &rep);
            check_status(st, "nf_guide_train_pass");
            NF_FUZZ_CHECK(nf_guide_help(g) == 0, "help outside a training call ran tasks");
            if (st == NF_OK)
                NF_FUZZ_CHECK(nf_guide_pending(g) == 0, "samples pending after a pass");
            NF_FUZZ_CHECK(nf_guide_get_stats(g, &after) == NF_OK, "stats");
            if (st == NF_OK)
                NF_FUZZ_CHECK(after.samples + after.dropped == accepted,
                              "kept %llu + dropped %llu, accepted %llu",
                              (unsigned long long)after.samples,
                              (unsigned long long)after.dropped, (unsigned long long)accepted);
            NF_FUZZ_CHECK(nf_model_get_params(nf_guide_training_model(g), params) == NF_OK, "params");
            for (size_t i = 0; i < P; ++i)
                NF_FUZZ_CHECK(isfinite(params[i]), "parameter %zu = %g", i, (double)params[i]);
            break;
        }
        case 3: { /* a batch with the caller's groups, maybe malformed */
            size_t n = nf_fuzz_byte(&r) % (MAX_SAMPLES + 1), ng = nf_fuzz_byte(&r) % 17;
            for (size_t i = 0; i < n; ++i) {
                ctx[i] = (nf_context){{0.1f * (float)(i % 7), 0.5f, 0.5f}, {0, 0, 1}, {0, 0, 1}, 0.0f};
                for (int a = 0; a < 3; ++a)
                    dir[3 * i + (size_t)a] = next_float(&r);
                weight[i] = next_float(&r);
            }
            for (size_t k = 0; k < ng; ++k)
                group_end[k] = nf_fuzz_byte(&r) % (n + 2);
            float loss;
            const size_t *ends = nf_fuzz_byte(&r) % 3 ? group_end : NULL;
            st = nf_guide_train_batch(g, n, ctx, dir, weight, ends, ng, NULL, NULL, &loss);
            check_status(st, "nf_guide_train_batch");
            break;
        }
        case 4: /* publish: the newest is the training model's parameters */
            st = nf_guide_publish(g);
            check_status(st, "nf_guide_publish");
            if (st == NF_OK)
                NF_FUZZ_CHECK(nf_model_get_params(nf_guide_training_model(g), published) == NF_OK,
                              "params");
            break;
        case 5: { /* acquire into a slot; the newest published parameters come back */
            size_t k = nf_fuzz_byte(&r) % 4;
            if (held[k])
                break;
            st = nf_guide_acquire(g, &held[k]);
            check_status(st, "nf_guide_acquire");
            NF_FUZZ_CHECK(st == NF_OK && held[k], "acquire failed");
            NF_FUZZ_CHECK(nf_model_get_params(held[k], got) == NF_OK, "params");
            NF_FUZZ_CHECK(memcmp(got, published, P * sizeof *got) == 0,
                          "acquire handed out a model other than the last published");
            break;
        }
        case 7: /* guided or plain passes, with any measures */
            check_choice(&r, g, &gc.policy);
            break;
        case 6: { /* release: a held one, or a foreign one (refused) */
            size_t k = nf_fuzz_byte(&r) % 4;
            st = nf_guide_release(g, held[k] ? held[k] : model);
            check_status(st, "nf_guide_release");
            NF_FUZZ_CHECK((st == NF_OK) == (held[k] != NULL), "release of slot %zu", k);
            held[k] = NULL;
            break;
        }
        }
        check_policy(&r, &gc.policy);
    }
    (void)nf_guide_keep_training(g, (double)next_float(&r), (double)next_float(&r));
    for (size_t k = 0; k < 4; ++k)
        if (held[k])
            NF_FUZZ_CHECK(nf_guide_release(g, held[k]) == NF_OK, "final release");
    nf_guide_destroy(g);
    return 0;
}
