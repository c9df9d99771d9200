/*
 * options.c - parsing and help text of the command line. Every number is range-checked
 * here, so the rest of the program can trust the options. The defaults are the library's
 * (nf_guide_config_init) and the best configuration of docs/equal-time.md; what experiments
 * change is one table of --variant settings.
 */
#include "options.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "parallel.h"
#include "ranks.h"

const char *options_program_name(options_program program)
{
    return program == OPTIONS_PAPER ? "nf_paper" : "nf_tracer";
}

/* The options both programs take, in the help's words. */
static const char help_scene[] =
    "Scene and output:\n"
    "  --scene FILE          the scene (Mitsuba 3 XML subset, docs/scene-format.md)\n"
    "  --out PREFIX          output prefix; a directory (existing, or ending in /) gets\n"
    "                        files named after the scene (default out/<scene name>)\n"
    "  --width N, --height N film size (default: the scene's film)\n"
    "  --max-depth N         longest path in segments, -1 unlimited (default: the scene's)\n"
    "  --exposure X          PNG preview brightness in stops (default 0)\n"
    "  --reference FILE      reference EXR for MAPE and relMSE (same size as the render,\n"
    "                        or an integer multiple of it: then it is box-downsampled)\n"
    "\n";
static const char help_guiding[] =
    "  --prior NAME          uniform-direction, uniform-angle, cosine (default) or bsdf\n"
    "  --model NAME          small (default, the paper's) or large\n"
    "  --lr X                AdamW learning rate (default: the library's guide, 5e-3)\n"
    "  --no-guiding          plain path tracing (BSDF sampling and next-event estimation)\n"
    "  --save-model FILE     save the trained model\n"
    "  --load-model FILE     start from a saved model (its prior and architecture replace\n"
    "                        --prior and --model; --lr, if given, replaces its rate)\n"
    "  --variant V[,V...]    experiments' settings, NAME or NAME=VALUE from the table of\n"
    "                        --variant list (ablations, libnisflow 0.1's protocol)\n"
    "\n";
static const char help_execution[] =
    "Execution:\n"
    "  --threads N           worker threads (default: the number of processors); under\n"
    "                        mpirun, per rank\n"
    "  --seed N              random seed (default 1); results are identical for the same\n"
    "                        seed, whatever the number of threads and of MPI ranks\n"
    "  --isa NAME            the library's kernels: auto (default, the best this CPU\n"
    "                        runs), generic, avx2 or avx512 (nf_model_set_isa)\n"
    "  --help                this text\n"
    "\n";

void options_print_help(options_program program, const char *name)
{
    if (program == OPTIONS_TRACER)
        printf("Usage: %s --scene FILE [options]\n"
               "\n"
               "Renders a Mitsuba 3 scene in a time budget with a path tracer guided by a\n"
               "normalizing flow (libnisflow) that it trains while it renders: training passes,\n"
               "then guided or plain render passes, as the library's schedule chooses, combined\n"
               "by inverse variance. The defaults are the best configuration we know. It writes\n"
               "PREFIX.exr (float RGB) and PREFIX.png (sRGB preview). nf_paper runs the paper's\n"
               "protocol instead (training iterations, then a number of samples per pixel).\n"
               "\n%s"
               "Guiding:\n"
               "  --time-budget S       the whole job in S seconds of wall time from after the scene\n"
               "                        is loaded (default 30)\n"
               "%s%s",
               name, help_scene, help_guiding, help_execution);
    else
        printf("Usage: %s --scene FILE [options]\n"
               "\n"
               "The paper's protocol on nf_tracer's path tracer: --iterations training iterations\n"
               "of --batch paths, each followed by one optimizer step, then --spp samples per\n"
               "pixel with the trained model. It writes PREFIX.exr, PREFIX.png and, when it\n"
               "trained, PREFIX.csv (iteration, training samples, seconds, MAPE). Its images are\n"
               "the same bits for the same seed, whatever the threads and ranks: references,\n"
               "studies at equal samples. nf_tracer renders in a time budget instead.\n"
               "\n%s"
               "Guiding:\n%s"
               "The protocol:\n"
               "  --iterations N        training iterations (default 200)\n"
               "  --batch N             training paths per iteration, each through a random film\n"
               "                        position (default 4096)\n"
               "  --spp N               samples per pixel of the final image (default 32)\n"
               "  --eval-every N        evaluate every N iterations, 0 never (default 50)\n"
               "  --eval-spp N          samples per pixel of evaluation renders (default 4)\n"
               "  --reference-mode      render an unguided reference: no training, --spp default\n"
               "                        1024, default output out/<scene name>-reference\n"
               "\n%s",
               name, help_scene, help_guiding, help_execution);
    printf("Several processes or machines (docs/distributed.md): mpirun -n N %s ... splits\n"
           "the training and the film's tiles between N ranks, which train one model; rank 0\n"
           "writes the outputs.\n",
           name);
}

static int parse_int(const char *name, const char *text, long lo, long hi, int *out,
                     tr_error *err)
{
    char *end;
    errno = 0;
    long v = strtol(text, &end, 10);
    if (errno || end == text || *end || v < lo || v > hi)
        return tr_fail(err, "%s: '%s' is not an integer in [%ld, %ld]", name, text, lo, hi);
    *out = (int)v;
    return 1;
}

static int parse_float(const char *name, const char *text, double lo, double hi, float *out,
                       tr_error *err)
{
    char *end;
    errno = 0;
    double v = strtod(text, &end);
    if (errno || end == text || *end || !isfinite(v) || v < lo || v > hi)
        return tr_fail(err, "%s: '%s' is not a number in [%g, %g]", name, text, lo, hi);
    *out = (float)v;
    return 1;
}

/* ---- The variant table ----------------------------------------------------------------- */

/* One --variant setting: a name, its value's range (no value when lo > hi), what it does. */
typedef struct variant {
    const char *name;
    double lo, hi; /* lo > hi: a switch without a value */
    int integer;
    void (*apply)(options *o, double v);
    const char *help;
} variant;

static void v_paper(options *o, double v)
{
    (void)v;
    /* libnisflow 0.1's protocol, the one docs/results.md measured (sections 1 to 7). */
    o->guide.policy.mixture_prob = 0.5f;
    o->guide.policy.max_boost = 0.0f;
    o->guide.policy.light_mis_depth = 0;
    o->guide.policy.min_roughness = 0.0f;
    o->guide.pass_choice = 0; /* every render pass guided */
    o->sh_bands = -1;
    o->mis_training = 0;
}
static void v_guide_prob(options *o, double v) { o->guide.policy.mixture_prob = (float)v; }
static void v_max_boost(options *o, double v) { o->guide.policy.max_boost = (float)v; }
static void v_light_depth(options *o, double v) { o->guide.policy.light_mis_depth = (uint32_t)v; }
static void v_min_rough(options *o, double v) { o->guide.policy.min_roughness = (float)v; }
static void v_train_fraction(options *o, double v) { o->guide.train_fraction = (float)v; }
static void v_patience(options *o, double v) { o->guide.patience = (uint32_t)v; }
static void v_explore(options *o, double v) { o->guide.explore_share = (float)v; }
static void v_guided_passes(options *o, double v)
{
    (void)v;
    o->guide.pass_choice = 0;
}
static void v_step_samples(options *o, double v) { o->guide.step_samples = (uint32_t)v; }
static void v_steps_per_pass(options *o, double v) { o->guide.steps_per_pass = (uint32_t)v; }
static void v_clamp(options *o, double v) { o->guide.clamp_quantile = (float)v; }
static void v_sh_bands(options *o, double v) { o->sh_bands = (int)v; }
static void v_epsilon(options *o, double v) { o->prior_epsilon = (float)v; }
static void v_interval(options *o, double v)
{
    (void)v;
    o->phi_interval = 1;
}
static void v_all_emission(options *o, double v)
{
    (void)v;
    o->mis_training = 0;
}
static void v_no_batching(options *o, double v)
{
    (void)v;
    o->no_batching = 1;
}
static void v_light_bsdf(options *o, double v)
{
    (void)v;
    o->light_mis_bsdf = 1;
}
static void v_guide_depth(options *o, double v) { o->guide_depth = (int)v; }

#define SWITCH 1.0, 0.0, 0
static const variant variants[] = {
    {"paper", SWITCH, v_paper,
     "the paper's protocol as libnisflow 0.1 ran it: guide-prob=0.5, 4 SH bands, training on "
     "all the emission, no boost cap, light MIS by the flow at every depth, smooth conductors "
     "guided, every render pass guided"},
    {"guide-prob", 0.0, 0.99, 0, v_guide_prob, "probability of sampling the flow (0.7)"},
    {"guide-max-boost", 0.0, 1e6, 0, v_max_boost,
     "cap on the mixture's boost over BSDF sampling, 0 none (10)"},
    {"light-mis-depth", 0.0, 1e5, 1, v_light_depth,
     "vertices up to this depth weigh light samples by the flow, 0 all (2)"},
    {"light-mis-bsdf", SWITCH, v_light_bsdf, "light samples weighed by the BSDF at every depth"},
    {"guide-min-roughness", 0.0, 1.0, 0, v_min_rough,
     "rough conductors smoother than this are not guided (0.3)"},
    {"guide-depth", 0.0, 1e5, 1, v_guide_depth, "guided passes guide vertices up to this depth, 0: the guide's choice (0)"},
    {"train-fraction", 0.0, 0.95, 0, v_train_fraction, "share of the budget that trains (0.15)"},
    {"patience", 0.0, 1e6, 1, v_patience,
     "training passes without a 1 % better held-out loss before training stops, 0 never (6)"},
    {"guided-passes", SWITCH, v_guided_passes,
     "every render pass guided, none plain (nf_guide_config.pass_choice 0)"},
    {"explore-share", 0.0, 0.5, 0, v_explore,
     "least share of render passes for the kind that measures worse (0.05)"},
    {"step-samples", 16.0, 1048576.0, 1, v_step_samples, "samples per optimizer step (2048)"},
    {"steps-per-pass", 1.0, 4096.0, 1, v_steps_per_pass,
     "optimizer steps after a training pass (64)"},
    {"clamp-quantile", 0.0, 0.999, 0, v_clamp,
     "training weights clamped at this running quantile, 0 none (0)"},
    {"sh-bands", 0.0, (double)NF_MAX_SH_BANDS, 1, v_sh_bands,
     "spherical-harmonic bands of the normal and wo in the flow's input (0)"},
    {"prior-epsilon", 1e-6, 1.0, 0, v_epsilon,
     "uniform weight mixed into the cosine and bsdf priors (the library's, 0.01)"},
    {"phi-interval", SWITCH, v_interval, "phi's splines fix phi = 0, as libnisflow 0.1"},
    {"all-emission", SWITCH, v_all_emission,
     "train on all the emission found, not its MIS-weighted part"},
    {"no-batching", SWITCH, v_no_batching,
     "passes trace one path at a time and ask the flow at shading points"},
};
#undef SWITCH

void options_print_variants(void)
{
    printf("--variant settings (NAME or NAME=VALUE, comma-separated; defaults in brackets):\n");
    for (size_t i = 0; i < sizeof variants / sizeof variants[0]; ++i) {
        const variant *v = &variants[i];
        char label[64];
        snprintf(label, sizeof label, "%s%s", v->name,
                 v->lo > v->hi ? "" : v->integer ? "=N" : "=X");
        printf("  %-24s %s\n", label, v->help);
    }
}

/* Applies one comma-separated list of settings. */
static int apply_variants(options *o, const char *list, tr_error *err)
{
    char buf[512];
    if (strlen(list) >= sizeof buf)
        return tr_fail(err, "--variant: the list is too long");
    strcpy(buf, list);
    for (char *item = strtok(buf, ","); item; item = strtok(NULL, ",")) {
        char *eq = strchr(item, '=');
        if (eq)
            *eq = '\0';
        const variant *v = NULL;
        for (size_t i = 0; i < sizeof variants / sizeof variants[0]; ++i)
            if (!strcmp(item, variants[i].name))
                v = &variants[i];
        if (!v)
            return tr_fail(err, "--variant: unknown setting '%s' (--variant list shows them)",
                           item);
        double value = 0.0;
        if (v->lo > v->hi) {
            if (eq)
                return tr_fail(err, "--variant: %s takes no value", v->name);
        } else {
            if (!eq)
                return tr_fail(err, "--variant: %s needs a value (%s=...)", v->name, v->name);
            float f = 0.0f;
            int n = 0;
            int ok = v->integer ? parse_int(v->name, eq + 1, (long)v->lo, (long)v->hi, &n, err)
                                : parse_float(v->name, eq + 1, v->lo, v->hi, &f, err);
            if (!ok) {
                char why[sizeof err->msg];
                snprintf(why, sizeof why, "%s", err->msg);
                return tr_fail(err, "--variant: %s", why);
            }
            value = v->integer ? (double)n : (double)f;
        }
        v->apply(o, value);
    }
    return 1;
}

/* Whether `flag` belongs to the other program's protocol; then a message names that program. */
static int other_program_flag(options_program program, const char *flag, tr_error *err)
{
    static const char *const paper_only[] = {"--iterations", "--batch",    "--spp",
                                             "--eval-every", "--eval-spp", "--reference-mode"};
    if (program == OPTIONS_PAPER && !strcmp(flag, "--time-budget")) {
        tr_fail(err, "--time-budget is nf_tracer's: nf_paper runs the paper's protocol "
                "(--iterations, --batch, --spp)");
        return 1;
    }
    for (size_t k = 0; program == OPTIONS_TRACER && k < sizeof paper_only / sizeof *paper_only;
         ++k)
        if (!strcmp(flag, paper_only[k])) {
            tr_fail(err, "%s is the paper's protocol, nf_paper's: nf_tracer renders in "
                    "--time-budget S", flag);
            return 1;
        }
    return 0;
}

/* The defaults: the library's guide, model_default_settings' model, the paper's protocol. */
static void set_defaults(options_program program, options *o)
{
    memset(o, 0, sizeof *o);
    o->program = program;
    nf_guide_config_init(&o->guide);
    /* The model's defaults have one home: model_default_settings. */
    model_settings model = model_default_settings(MODEL_PRIOR_COSINE);
    o->prior = model.prior;
    o->learning_rate = o->guide.learning_rate;
    o->prior_epsilon = model.prior_epsilon;
    o->sh_bands = model.sh_bands;
    o->seed = model.seed;
    o->iterations = 200;
    o->batch = 4096;
    o->eval_every = 50;
    o->eval_spp = 4;
    o->spp = 32;
    o->max_depth = -2;
    o->threads = processor_count();
    o->guiding = 1;
    o->mis_training = 1;
    if (program == OPTIONS_TRACER)
        o->time_budget = 30.0f;
}

/* The index of `v` among `count` names, or -1 with a message that lists them (`list`). */
static int parse_name(const char *flag, const char *v, const char *const *names, int count,
                      const char *list, tr_error *err)
{
    for (int k = 0; k < count; ++k)
        if (!strcmp(v, names[k]))
            return k;
    tr_fail(err, "%s: '%s' is not one of %s", flag, v, list);
    return -1;
}

static int parse_seed(const char *v, uint64_t *seed, tr_error *err)
{
    char *end;
    errno = 0;
    unsigned long long s = strtoull(v, &end, 10);
    if (errno || end == v || *end || v[0] == '-')
        return tr_fail(err, "--seed: '%s' is not a non-negative integer", v);
    *seed = (uint64_t)s;
    return 1;
}

/* One option `a` with its value `v`. Returns 0 with a message. */
static int parse_valued(options *o, const char *a, const char *v, tr_error *err)
{
    static const char *const priors[] = {"uniform-direction", "uniform-angle", "cosine", "bsdf"};
    static const char *const isas[] = {"auto", "generic", "avx2", "avx512"};
    int k;
    if (!strcmp(a, "--scene"))
        o->scene = v;
    else if (!strcmp(a, "--out"))
        o->out = v;
    else if (!strcmp(a, "--reference"))
        o->reference = v;
    else if (!strcmp(a, "--save-model"))
        o->save_model = v;
    else if (!strcmp(a, "--load-model"))
        o->load_model = v;
    else if (!strcmp(a, "--prior")) {
        if ((k = parse_name(a, v, priors, 4, "uniform-direction, uniform-angle, cosine, bsdf",
                            err)) < 0)
            return 0;
        o->prior = (model_prior)k;
        o->prior_given = 1;
    } else if (!strcmp(a, "--model")) {
        if (strcmp(v, "small") && strcmp(v, "large"))
            return tr_fail(err, "--model: '%s' is not small or large", v);
        o->large_model = !strcmp(v, "large");
    } else if (!strcmp(a, "--lr")) {
        o->learning_rate_given = 1;
        return parse_float(a, v, 1e-8, 1.0, &o->learning_rate, err);
    } else if (!strcmp(a, "--iterations"))
        return parse_int(a, v, 0, 10000000, &o->iterations, err);
    else if (!strcmp(a, "--batch"))
        return parse_int(a, v, 1, 1 << 24, &o->batch, err);
    else if (!strcmp(a, "--eval-every"))
        return parse_int(a, v, 0, 10000000, &o->eval_every, err);
    else if (!strcmp(a, "--eval-spp"))
        return parse_int(a, v, 1, 1 << 20, &o->eval_spp, err);
    else if (!strcmp(a, "--spp")) {
        o->spp_given = 1;
        return parse_int(a, v, 1, 1 << 24, &o->spp, err);
    } else if (!strcmp(a, "--width"))
        return parse_int(a, v, 1, 65536, &o->width, err);
    else if (!strcmp(a, "--height"))
        return parse_int(a, v, 1, 65536, &o->height, err);
    else if (!strcmp(a, "--max-depth"))
        return parse_int(a, v, -1, 100000, &o->max_depth, err) &&
               (o->max_depth != 0 || tr_fail(err, "--max-depth must be -1 or >= 1"));
    else if (!strcmp(a, "--threads"))
        return parse_int(a, v, 1, 4096, &o->threads, err);
    else if (!strcmp(a, "--seed"))
        return parse_seed(v, &o->seed, err);
    else if (!strcmp(a, "--isa")) {
        if ((k = parse_name(a, v, isas, 4, "auto, generic, avx2, avx512", err)) < 0)
            return 0;
        o->isa = (nf_isa)k;
    } else if (!strcmp(a, "--time-budget"))
        return parse_float(a, v, 0.01, 1e6, &o->time_budget, err);
    else if (!strcmp(a, "--exposure"))
        return parse_float(a, v, -64.0, 64.0, &o->exposure, err);
    else if (!strcmp(a, "--variant")) {
        o->variants = v;
        if (!strcmp(v, "list"))
            o->list_variants = 1;
        else
            return apply_variants(o, v, err);
    } else
        return tr_fail(err, "unknown option '%s'", a);
    return 1;
}

/* What the options imply together, once all are read. */
static int finish(options *o, tr_error *err)
{
    if (!o->scene)
        return tr_fail(err, "--scene is required");
    if (o->reference_mode) {
        o->guiding = 0;
        if (!o->spp_given)
            o->spp = 1024;
    }
    if (o->guide.policy.mixture_prob == 0.0f)
        o->guiding = 0;
    o->guide.learning_rate = o->learning_rate;
    o->guide.seed = o->seed;
    if (!o->guiding && (o->load_model || o->save_model))
        return tr_fail(err, "--save-model and --load-model need guiding (drop --no-guiding)");
    return 1;
}

int options_parse(int argc, char **argv, options_program program, options *o, tr_error *err)
{
    set_defaults(program, o);
    for (int i = 1; i < argc; ++i) {
        const char *a = argv[i];
        if (other_program_flag(program, a, err))
            return 0;
        /* Options without a value. */
        if (!strcmp(a, "--help") || !strcmp(a, "-h"))
            o->help = 1;
        else if (!strcmp(a, "--no-guiding"))
            o->guiding = 0;
        else if (!strcmp(a, "--reference-mode"))
            o->reference_mode = 1;
        else if (strncmp(a, "--", 2) != 0)
            return tr_fail(err, "unexpected argument '%s'", a);
        else if (i + 1 >= argc)
            return tr_fail(err, "%s needs a value", a);
        else if (!parse_valued(o, a, argv[++i], err))
            return 0;
    }
    return o->help || o->list_variants || finish(o, err);
}

uint64_t options_job_hash(int argc, char **argv)
{
    /* These name files or machine resources, which may differ between machines; the scene and
     * the model are compared by content instead (nf_tracer.c). */
    static const char *const local[] = {"--threads", "--scene", "--out", "--reference",
                                        "--save-model", "--load-model", "--exposure"};
    uint64_t h = RANKS_HASH_START;
    for (int i = 1; i < argc; ++i) {
        int skip = 0;
        for (size_t k = 0; k < sizeof local / sizeof *local; ++k)
            skip |= !strcmp(argv[i], local[k]);
        if (skip) {
            ++i; /* and its value */
            continue;
        }
        h = ranks_hash(h, argv[i], strlen(argv[i]) + 1);
    }
    return h;
}
