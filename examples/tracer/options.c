/*
 * options.c - parsing and help text of the command line. Every number is range-checked
 * here, so the rest of the program can trust the options.
 */
#include "options.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "parallel.h"
#include "ranks.h"

void options_print_help(const char *program)
{
    printf(
        "Usage: %s --scene FILE [options]\n"
        "\n"
        "Renders a Mitsuba 3 scene with a path tracer guided by a normalizing flow (libnisflow),\n"
        "trained online: each iteration traces a batch of paths with the current model and\n"
        "takes one training step on the samples they recorded. Then it renders the final\n"
        "image and writes PREFIX.exr (float RGB), PREFIX.png (sRGB preview) and, when it\n"
        "trained, PREFIX.csv (iteration, training samples, seconds, MAPE).\n"
        "\n"
        "Scene and output:\n"
        "  --scene FILE          the scene (Mitsuba 3 XML subset, see docs/tracer.md)\n"
        "  --out PREFIX          output prefix; a directory (existing, or ending in /) gets\n"
        "                        files named after the scene (default out/<scene name>)\n"
        "  --width N, --height N film size (default: the scene's film)\n"
        "  --max-depth N         longest path in segments, -1 unlimited (default: the scene's)\n"
        "  --exposure X          PNG preview brightness in stops (default 0)\n"
        "\n"
        "Guiding and training:\n"
        "  --prior NAME          uniform-direction, uniform-angle, cosine (default) or bsdf\n"
        "  --model NAME          small (default, the paper's) or large\n"
        "  --phi-map NAME        circular (default: the seam phi = 0 is no boundary) or\n"
        "                        interval (phi's splines fix phi = 0, as libnisflow 0.1)\n"
        "  --lr X                AdamW learning rate (default 5e-3)\n"
        "  --iterations N        training iterations (default 200)\n"
        "  --batch N             training paths per iteration, each through a random film\n"
        "                        position (default 4096)\n"
        "  --guide-prob P        probability of sampling the flow at a guided vertex (default 0.5)\n"
        "  --prior-epsilon E     weight of the uniform density mixed into the cosine and bsdf\n"
        "                        priors, in (0, 1] (default: the library's, 0.01)\n"
        "  --sh-bands N          spherical-harmonic bands of the normal and of the\n"
        "                        outgoing direction in the flow's input, 0-6; 0: the\n"
        "                        position alone (default: the model's, 4)\n"
        "  --no-guiding          plain path tracing (BSDF sampling and next-event estimation)\n"
        "  --save-model FILE     save the trained model\n"
        "  --load-model FILE     start from a saved model (its prior, epsilon and architecture\n"
        "                        replace --prior, --prior-epsilon, --sh-bands and --model;\n"
        "                        --lr, if given, replaces its rate)\n"
        "\n"
        "Rendering and evaluation:\n"
        "  --spp N               samples per pixel of the final image (default 32)\n"
        "  --eval-every N        evaluate every N iterations, 0 never (default 50)\n"
        "  --eval-spp N          samples per pixel of evaluation renders (default 4)\n"
        "  --reference FILE      reference EXR for MAPE and relMSE (same size as the render,\n"
        "                        or an integer multiple of it: then it is box-downsampled)\n"
        "  --reference-mode      render an unguided reference: no training, --spp default 1024,\n"
        "                        default output out/<scene name>-reference\n"
        "\n"
        , program);
    printf(
        "Time budget (the equal-time job, docs/equal-time.md):\n"
        "  --time-budget S       the whole job, training and rendering, in S seconds of wall\n"
        "                        time from after the scene is loaded: training passes of one\n"
        "                        path per pixel (their radiance kept), then render passes with\n"
        "                        the model frozen; the passes are combined by inverse variance.\n"
        "                        Replaces --iterations, --batch and --spp\n"
        "  --train-fraction F    at most this share of the budget trains (default 0.3)\n"
        "  --patience N          stop training after N passes in which the held-out loss\n"
        "                        (averaged over ~3 passes) did not get 1%% better than its\n"
        "                        best (default 6, 0 never)\n"
        "  --step-samples N      training samples per optimizer step (default 2048)\n"
        "  --steps-per-pass N    optimizer steps after each training pass, on samples drawn\n"
        "                        from the latest passes (default 64)\n"
        "  --clamp-quantile Q    clamp training weights at a running Q-quantile (default 0,\n"
        "                        off; for example 0.99)\n"
        "  --no-combine          leave the training passes out of the image\n"
        "  --learn-selection     learn the guiding probability per cell of a grid (position\n"
        "                        and normal); where it falls below 0.1, or where the mixture\n"
        "                        does not cut the estimate's second moment by 1 + C, the\n"
        "                        flow is not used\n"
        "  --selection-cost C    a guided vertex's relative extra cost (default 1)\n"
        "  --relative-training   divide each training weight by its pixel's estimated\n"
        "                        value (blurred training passes), so that the flow learns\n"
        "                        where the relative error is, not only where it is bright\n"
        "  --plain-mixture       weigh a flow sample by the flow's density and a BSDF sample\n"
        "                        by the BSDF's (instead of both by the mixture's): the flow\n"
        "                        is evaluated only at vertices where it samples\n"
        "  --light-mis-bsdf      weigh light samples against scattering by the BSDF's\n"
        "                        density, not the mixture's: the flow is not asked the\n"
        "                        density of a light sample's direction (the scattered\n"
        "                        direction still weighs by the mixture)\n"
        "  --light-mis-depth N   --light-mis-bsdf at vertices deeper than N segments, the\n"
        "                        mixture's density up to N (default 0: at every depth)\n"
        );
    printf(
        "  --no-batching         passes trace one path at a time and ask the flow at\n"
        "                        shading points, instead of advancing 256 paths together\n"
        "                        and batching their questions (the same image, slower)\n"
        "  --mis-training        train the flow on the MIS-weighted emission its directions\n"
        "                        find (the part next-event estimation leaves to scattering)\n"
        "  --guide-min-roughness A  rough conductors with alpha below A are not guided\n"
        "                        (default 0)\n"
        "  --guide-depth N       guide vertices up to N segments deep, 0 all (default 0)\n"
        "  --guide-max-boost B   lower the guiding probability along a path so that the\n"
        "                        mixture raises its throughput over BSDF sampling's at\n"
        "                        most B-fold (default 0: no cap)\n"
        "  --throughput-roulette  Russian roulette on the guided path's throughput as the\n"
        "                        mixture weighed it, instead of the larger of it and the\n"
        "                        throughput BSDF sampling would have given the same path\n"
        "                        (the default, which lets a guided path live as plain path\n"
        "                        tracing would)\n"
        "\n"
        "Execution:\n"
        "  --threads N           worker threads (default: the number of processors); under\n"
        "                        mpirun, per rank\n"
        "  --seed N              random seed (default 1); results are identical for the same\n"
        "                        seed, whatever the number of threads and of MPI ranks\n"
        "  --help                this text\n"
        "\n"
        "Several processes or machines (docs/distributed.md): mpirun -n N %s ... splits each\n"
        "training batch and the film's tiles between N ranks, which train one model; rank 0\n"
        "writes the outputs.\n", program);
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

int options_parse(int argc, char **argv, options *o, tr_error *err)
{
    memset(o, 0, sizeof *o);
    /* The model's defaults have one home: guide_default_settings. */
    guide_settings model = guide_default_settings(GUIDE_PRIOR_COSINE);
    o->prior = model.prior;
    o->learning_rate = model.learning_rate;
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
    o->guide_prob = 0.5f;
    o->guiding = 1;
    o->train_fraction = 0.3f;
    o->step_samples = 2048;
    o->steps_per_pass = 64;
    o->patience = 6;
    o->combine = 1;
    o->selection_cost = -1.0f;

    for (int i = 1; i < argc; ++i) {
        const char *a = argv[i];
        /* Options without a value. */
        if (!strcmp(a, "--help") || !strcmp(a, "-h")) {
            o->help = 1;
            continue;
        }
        if (!strcmp(a, "--no-guiding")) {
            o->guiding = 0;
            continue;
        }
        if (!strcmp(a, "--learn-selection")) {
            o->learn_selection = 1;
            continue;
        }
        if (!strcmp(a, "--relative-training")) {
            o->relative_training = 1;
            continue;
        }
        if (!strcmp(a, "--plain-mixture")) {
            o->plain_mixture = 1;
            continue;
        }
        if (!strcmp(a, "--no-batching")) {
            o->no_batching = 1;
            continue;
        }
        if (!strcmp(a, "--light-mis-bsdf")) {
            o->light_mis_bsdf = 1;
            continue;
        }
        if (!strcmp(a, "--throughput-roulette")) {
            o->throughput_roulette = 1;
            continue;
        }
        if (!strcmp(a, "--mis-training")) {
            o->mis_training = 1;
            continue;
        }
        if (!strcmp(a, "--no-combine")) {
            o->combine = 0;
            continue;
        }
        if (!strcmp(a, "--reference-mode")) {
            o->reference_mode = 1;
            continue;
        }
        if (strncmp(a, "--", 2) != 0)
            return tr_fail(err, "unexpected argument '%s'", a);
        if (i + 1 >= argc)
            return tr_fail(err, "%s needs a value", a);
        const char *v = argv[++i];
        int ok = 1;
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
            static const char *const names[] = {"uniform-direction", "uniform-angle", "cosine",
                                                "bsdf"};
            int found = -1;
            for (int k = 0; k < 4; ++k)
                if (!strcmp(v, names[k]))
                    found = k;
            if (found < 0)
                return tr_fail(err, "--prior: '%s' is not one of uniform-direction, "
                               "uniform-angle, cosine, bsdf", v);
            o->prior = (guide_prior)found;
            o->prior_given = 1;
        } else if (!strcmp(a, "--phi-map")) {
            if (strcmp(v, "circular") && strcmp(v, "interval"))
                return tr_fail(err, "--phi-map: '%s' is not circular or interval", v);
            o->phi_interval = !strcmp(v, "interval");
        } else if (!strcmp(a, "--model")) {
            if (strcmp(v, "small") && strcmp(v, "large"))
                return tr_fail(err, "--model: '%s' is not small or large", v);
            o->large_model = !strcmp(v, "large");
        } else if (!strcmp(a, "--lr")) {
            ok = parse_float(a, v, 1e-8, 1.0, &o->learning_rate, err);
            o->learning_rate_given = 1;
        } else if (!strcmp(a, "--iterations"))
            ok = parse_int(a, v, 0, 10000000, &o->iterations, err);
        else if (!strcmp(a, "--batch"))
            ok = parse_int(a, v, 1, 1 << 24, &o->batch, err);
        else if (!strcmp(a, "--eval-every"))
            ok = parse_int(a, v, 0, 10000000, &o->eval_every, err);
        else if (!strcmp(a, "--eval-spp"))
            ok = parse_int(a, v, 1, 1 << 20, &o->eval_spp, err);
        else if (!strcmp(a, "--spp")) {
            ok = parse_int(a, v, 1, 1 << 24, &o->spp, err);
            o->spp_given = 1;
        } else if (!strcmp(a, "--width"))
            ok = parse_int(a, v, 1, 65536, &o->width, err);
        else if (!strcmp(a, "--height"))
            ok = parse_int(a, v, 1, 65536, &o->height, err);
        else if (!strcmp(a, "--max-depth")) {
            ok = parse_int(a, v, -1, 100000, &o->max_depth, err) &&
                 (o->max_depth != 0 || tr_fail(err, "--max-depth must be -1 or >= 1"));
        } else if (!strcmp(a, "--threads"))
            ok = parse_int(a, v, 1, 4096, &o->threads, err);
        else if (!strcmp(a, "--seed")) {
            char *end;
            errno = 0;
            unsigned long long s = strtoull(v, &end, 10);
            if (errno || end == v || *end || v[0] == '-')
                return tr_fail(err, "--seed: '%s' is not a non-negative integer", v);
            o->seed = (uint64_t)s;
        } else if (!strcmp(a, "--guide-prob"))
            ok = parse_float(a, v, 0.0, 0.99, &o->guide_prob, err);
        else if (!strcmp(a, "--prior-epsilon"))
            ok = parse_float(a, v, 1e-6, 1.0, &o->prior_epsilon, err);
        else if (!strcmp(a, "--sh-bands"))
            ok = parse_int(a, v, 0, NF_MAX_SH_BANDS, &o->sh_bands, err);
        else if (!strcmp(a, "--time-budget"))
            ok = parse_float(a, v, 0.01, 1e6, &o->time_budget, err);
        else if (!strcmp(a, "--train-fraction"))
            ok = parse_float(a, v, 0.0, 0.95, &o->train_fraction, err);
        else if (!strcmp(a, "--step-samples"))
            ok = parse_int(a, v, 16, 1 << 24, &o->step_samples, err);
        else if (!strcmp(a, "--steps-per-pass"))
            ok = parse_int(a, v, 1, 1000000, &o->steps_per_pass, err);
        else if (!strcmp(a, "--patience"))
            ok = parse_int(a, v, 0, 1000000, &o->patience, err);
        else if (!strcmp(a, "--clamp-quantile"))
            ok = parse_float(a, v, 0.0, 1.0, &o->clamp_quantile, err);
        else if (!strcmp(a, "--selection-cost"))
            ok = parse_float(a, v, 0.0, 1000.0, &o->selection_cost, err);
        else if (!strcmp(a, "--guide-min-roughness"))
            ok = parse_float(a, v, 0.0, 1.0, &o->guide_min_roughness, err);
        else if (!strcmp(a, "--guide-max-boost"))
            ok = parse_float(a, v, 0.0, 1e6, &o->guide_max_boost, err);
        else if (!strcmp(a, "--light-mis-depth"))
            ok = parse_int(a, v, 0, 100000, &o->light_mis_depth, err);
        else if (!strcmp(a, "--guide-depth"))
            ok = parse_int(a, v, 0, 100000, &o->guide_depth, err);
        else if (!strcmp(a, "--exposure"))
            ok = parse_float(a, v, -64.0, 64.0, &o->exposure, err);
        else
            return tr_fail(err, "unknown option '%s'", a);
        if (!ok)
            return 0;
    }
    if (o->help)
        return 1;
    if (!o->scene)
        return tr_fail(err, "--scene is required");
    if (o->reference_mode) {
        o->guiding = 0;
        if (!o->spp_given)
            o->spp = 1024;
    }
    if (o->guide_prob == 0.0f)
        o->guiding = 0;
    if (!o->guiding && (o->load_model || o->save_model))
        return tr_fail(err, "--save-model and --load-model need guiding (drop --no-guiding)");
    return 1;
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
