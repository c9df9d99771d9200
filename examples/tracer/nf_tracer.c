/*
 * nf_tracer.c - the example path tracer's main program: load a scene, train a
 * libnisflow model online while path tracing it, render the final image, write EXR and PNG,
 * report the error against a reference. docs/tracer.md explains what it does and why.
 *
 *   nf_tracer --scene examples/scenes/cornell-box/scene.xml --width 256 --height 256
 */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include <nisflow/nisflow.h>

#include "guide.h"
#include "image.h"
#include "integrator.h"
#include "metrics.h"
#include "options.h"
#include "progress.h"
#include "ranks.h"
#include "render.h"
#include "scene.h"
#include "training.h"
#include "budget.h"

/* ---- Output names ------------------------------------------------------------------------ */

/* Copies at most size - 1 characters of src (always terminated). */
static void copy_string(char *dst, size_t size, const char *src)
{
    size_t n = strlen(src);
    if (n >= size)
        n = size - 1;
    memcpy(dst, src, n);
    dst[n] = '\0';
}

/* "cornell-box" for ".../cornell-box/scene.xml", else the file name without extension. */
static void scene_name(const char *path, char *out, size_t size)
{
    char buf[4096];
    copy_string(buf, sizeof buf, path);
    char *slash = strrchr(buf, '/');
    const char *base = slash ? slash + 1 : buf;
    if (!strcmp(base, "scene.xml") && slash) {
        *slash = '\0';
        char *parent = strrchr(buf, '/');
        copy_string(out, size, parent ? parent + 1 : buf);
        return;
    }
    copy_string(out, size, base);
    char *dot = strrchr(out, '.');
    if (dot && dot != out)
        *dot = '\0';
}

static int is_directory(const char *path)
{
    struct stat st;
    return stat(path, &st) == 0 && S_ISDIR(st.st_mode);
}

/* Creates every missing directory of `path`'s parent (like mkdir -p), saying so for each: a
 * mistyped --out must not create directories silently. */
static int make_parent_dirs(const char *path)
{
    char buf[4096];
    copy_string(buf, sizeof buf, path);
    for (char *p = buf + 1; *p; ++p) {
        if (*p != '/')
            continue;
        *p = '\0';
        if (mkdir(buf, 0777) == 0)
            fprintf(stderr, "nf_tracer: note: created the directory '%s'\n", buf);
        else if (errno != EEXIST)
            return 0;
        *p = '/';
    }
    return 1;
}

/* Whether a file can be created at `path`: its directory exists and is writable. Checked
 * before any work, so that a bad --save-model is not found after the whole render. */
static int can_create(const char *path)
{
    char dir[4096];
    copy_string(dir, sizeof dir, path);
    char *slash = strrchr(dir, '/');
    if (!slash)
        copy_string(dir, sizeof dir, ".");
    else if (slash == dir)
        dir[1] = '\0';
    else
        *slash = '\0';
    return access(dir, W_OK) == 0;
}

static void output_prefix(const options *o, char *out, size_t size)
{
    char name[512];
    scene_name(o->scene, name, sizeof name);
    const char *suffix = o->reference_mode ? "-reference" : "";
    if (!o->out) {
        snprintf(out, size, "out/%s%s", name, suffix);
        return;
    }
    size_t len = strlen(o->out);
    if (len > 0 && (o->out[len - 1] == '/' || is_directory(o->out))) {
        snprintf(out, size, "%s%s%s%s", o->out, o->out[len - 1] == '/' ? "" : "/", name, suffix);
        return;
    }
    copy_string(out, size, o->out);
    len = strlen(out);
    if (len > 4 && !strcmp(out + len - 4, ".exr"))
        out[len - 4] = '\0'; /* "--out x.exr" means the prefix "x" */
}

/* ---- Outputs ----------------------------------------------------------------------------- */

/* Writes the EXR, the PNG and the model, and reports the error against the reference and what
 * the statistics say is wrong with the scene. */
static int write_results(const options *o, const char *prefix, const image *img,
                         const image *reference, const nf_model *model, const path_stats *stats,
                         tr_error *err)
{
    char path[4200];
    if (stats->camera_backfaces > stats->paths / 100)
        fprintf(stderr, "nf_tracer: note: %.0f%% of the camera rays hit the back of a one-sided "
                "material, which is black (Mitsuba's convention). If that is not intended (scenes "
                "from pbrt or Tungsten shade both sides), wrap the material in <bsdf "
                "type=\"twosided\">.\n",
                100.0 * (double)stats->camera_backfaces / (double)stats->paths);
    if (stats->invalid_rays)
        fprintf(stderr, "nf_tracer: warning: %llu rays were outside what Embree accepts and "
                "ended their paths (the scene loader should have refused this scene: please "
                "report it).\n", (unsigned long long)stats->invalid_rays);

    snprintf(path, sizeof path, "%s.exr", prefix);
    if (!image_write_exr(img, path, err))
        return 0;
    printf("wrote      %s\n", path);
    snprintf(path, sizeof path, "%s.png", prefix);
    if (!image_write_png(img, path, o->exposure, err))
        return 0;
    printf("wrote      %s\n", path);
    if (o->reference) {
        double worst, body;
        printf("error      MAPE %.6f, relMSE %.6f (against %s)\n", image_mape(reference, img),
               image_relmse(reference, img), o->reference);
        image_relmse_tail(reference, img, METRIC_TAIL_PIXELS, &worst, &body);
        printf("tail       the worst pixel holds %.1f %% of the relMSE; without the %d worst, "
               "relMSE %.6f\n", 100.0 * worst, METRIC_TAIL_PIXELS, body);
    }
    if (o->save_model) {
        nf_status st = nf_model_save(model, o->save_model);
        if (st != NF_OK)
            return tr_fail(err, "nf_model_save: %s: %s", nf_status_string(st),
                           nf_last_error_message());
        printf("wrote      %s\n", o->save_model);
    }
    if (guide_lookup_failures())
        fprintf(stderr, "nf_tracer: warning: the BSDF prior fell back to a cosine lobe %llu times "
                "(a shading point was not published; please report this)\n",
                guide_lookup_failures());
    return 1;
}

/* The reference, at the render's size (box-downsampled if it is a multiple of it). */
static int read_reference(const options *o, const scene *s, image *reference, tr_error *err)
{
    if (!o->reference)
        return 1;
    image full;
    if (!image_read_exr(o->reference, &full, err))
        return 0;
    if (full.width == s->width && full.height == s->height) {
        *reference = full;
        return 1;
    }
    int ok = image_downsample(&full, s->width, s->height, reference, err);
    image_free(&full);
    if (ok)
        printf("reference  %s, box-downsampled to %d x %d\n", o->reference, s->width, s->height);
    return ok;
}

/* ---- The time-budgeted job ------------------------------------------------------------------ */

/* --time-budget: the whole job in render_with_budget (budget.h), and its report. A guided job
 * trains a guide made from `*model` and, for --save-model, hands back its training model in
 * *model. */
static int render_in_budget(const options *o, tracer *t, nf_model **model, double t_job,
                            image *img, path_stats *stats, tr_error *err)
{
    budget_settings bs;
    budget_report br;
    nf_guide *guide = NULL;
    bs.seconds = o->time_budget;
    bs.start = t_job;
    bs.threads = o->threads;
    bs.seed = o->seed;
    /* The ranks share each step's samples: each draws its part from its own store. */
    nf_guide_config gc = o->guide;
    uint32_t ranks = (uint32_t)ranks_size();
    gc.step_samples = (gc.step_samples + ranks - 1) / ranks;
    if (t->bsdf_prior) /* each sample's material, for the prior's callbacks */
        gc.payload_bytes = sizeof(guide_point);
    if (*model && nf_guide_create(*model, &gc, &guide) != NF_OK)
        return tr_fail(err, "%s", nf_last_error_message());
    int ok = render_with_budget(t, guide, &bs, img, &br, err);
    if (ok && guide) /* the trained model replaces the starting one */
        ok = guide_take_trained(guide, model, err);
    nf_guide_destroy(guide);
    if (!ok)
        return 0;
    *stats = br.stats;
    const nf_schedule_report *sr = &br.sched;
    if (*model)
        printf("trained    %u passes, %d steps on %llu samples in %.2f s (steps %.2f s), last "
               "loss %.4f%s\n",
               sr->train_passes, br.steps, (unsigned long long)br.samples, br.train_seconds,
               br.step_seconds, (double)br.last_loss,
               sr->stopped_early ? ", stopped: the loss or the gain stopped improving" : "");
    if (*model && isfinite(sr->train_ratio))
        printf("training   its last pass's variance x time was %.3g of a plain pass's\n",
               sr->train_ratio);
    printf("budget     %.2f s of %.2f: %u training passes, %u render passes in %.2f s; the "
           "training passes weigh %.2f of the image\n",
           br.seconds, (double)o->time_budget, sr->train_passes, sr->render_passes,
           sr->render_seconds, sr->train_weight);
    uint64_t paths = stats->paths ? stats->paths : 1;
    printf("paths      %.2f rays and %.2f guided vertices per path\n",
           (double)stats->rays / (double)paths, (double)stats->guided_vertices / (double)paths);
    /* The choice between guided and plain render passes (nisflow/guide.h), and its figures. */
    const char *kind_name[2] = {"guided", "plain"};
    double cpu_all = sr->kind_cpu_seconds[0] + sr->kind_cpu_seconds[1];
    for (int k = 0; k < 2; ++k)
        if (sr->kind_passes[k])
            printf("%-10s %u render passes, %.3f CPU s each, relative variance %.4g per pass; "
                   "%.0f %% of the render passes' CPU time\n",
                   kind_name[k], sr->kind_passes[k],
                   sr->kind_cpu_seconds[k] / sr->kind_passes[k], sr->kind_variance[k],
                   cpu_all > 0.0 ? 100.0 * sr->kind_cpu_seconds[k] / cpu_all : 0.0);
    /* How deep the guided render passes guided (nf_guide_choose_depth). */
    if (br.depth_fixed && sr->kind_passes[NF_PASS_GUIDED])
        printf("depth      fixed: guided passes guide vertices up to depth %u\n",
               sr->depth);
    for (uint32_t c = 0; c < NF_GUIDE_DEPTHS && !br.depth_fixed; ++c) {
        if (!sr->depth_passes[c])
            continue;
        char name[32];
        if (c) /* kind c guides up to depth c; 0 every depth */
            snprintf(name, sizeof name, "up to depth %u", c);
        else
            snprintf(name, sizeof name, "every depth");
        printf("depth      %-14s %u guided passes, %.3f CPU s each, relative variance %.4g per "
               "pass\n",
               name, sr->depth_passes[c], sr->depth_cpu_seconds[c] / sr->depth_passes[c],
               sr->depth_variance[c]);
    }
    if (isfinite(sr->depth_ratio))
        printf("choice     guided passes guide %s%.0u: variance x time %.3g of guiding every "
               "depth\n",
               sr->depth ? "vertices up to depth " : "every depth", sr->depth,
               sr->depth_ratio);
    if (isfinite(sr->ratio))
        printf("choice     a guided pass's variance x time is %.3g of a plain pass's: %s pays "
               "(%u passes of the kind that measured worse kept to measure it)\n",
               sr->ratio, sr->ratio <= 1.0 ? "guiding" : "plain path tracing", sr->explored);
    return 1;
}

/* ---- Main ------------------------------------------------------------------------------------- */

/* Reports a failure. Failures are agreed between the ranks first (ranks_agree), so every
 * rank holds the same message and rank 0 alone prints it. */
static int fail(const char *what, const tr_error *e)
{
    if (ranks_rank() == 0)
        fprintf(stderr, "nf_tracer: %s%s%s\n", what ? what : "", what ? ": " : "", e->msg);
    return 1;
}

/* Whether the ranks loaded the same scene at the same settings: a hash of what decides the
 * image (the scene file's path may differ between machines, its content may not). */
static uint64_t scene_hash(const scene *s, uint64_t triangles)
{
    int32_t ints[4] = {s->width, s->height, s->max_depth, s->nshapes};
    uint64_t h = ranks_hash(RANKS_HASH_START, ints, sizeof ints);
    h = ranks_hash(h, &triangles, sizeof triangles);
    h = ranks_hash(h, &s->bounds_min, sizeof s->bounds_min);
    return ranks_hash(h, &s->bounds_max, sizeof s->bounds_max);
}

/* Checks the outputs before any work (rank 0 writes them all), so that a path that cannot
 * be written is found at once, not after the render. */
static int outputs_writable(const options *o, char *prefix, size_t size, tr_error *err)
{
    output_prefix(o, prefix, size);
    if (ranks_rank() != 0)
        return 1;
    if (!make_parent_dirs(prefix) || !can_create(prefix))
        return tr_fail(err, "--out: cannot write into the directory of '%s': %s", prefix,
                       strerror(errno));
    if (o->save_model && !can_create(o->save_model))
        return tr_fail(err, "--save-model: cannot create '%s': %s", o->save_model,
                       strerror(errno));
    return 1;
}

static int run(int argc, char **argv)
{
    options o;
    tr_error err;
    if (!ranks_agree(options_parse(argc, argv, &o, &err), &err)) {
        if (ranks_rank() == 0)
            fprintf(stderr, "nf_tracer: %s (try --help)\n", err.msg);
        return 2;
    }
    if (o.help) {
        options_print_help(argv[0]);
        return 0;
    }
    if (o.list_variants) {
        options_print_variants();
        return 0;
    }
    /* The ranks of one job must have been asked for the same job. */
    if (!ranks_all_equal(options_job_hash(argc, argv), "the ranks were started with different "
                         "options (all but --threads, --scene, --out, --reference, "
                         "--save-model, --load-model and --exposure must be the same)", &err))
        return fail(NULL, &err);

    char prefix[4096], path[4200];
    if (!ranks_agree(outputs_writable(&o, prefix, sizeof prefix, &err), &err))
        return fail(NULL, &err);

    double t_start = now_seconds();
    scene s;
    int loaded = scene_load(o.scene, &s, &err);
    if (!ranks_agree(loaded, &err)) {
        if (loaded)
            scene_free(&s);
        return fail(NULL, &err);
    }
    if (o.width || o.height)
        scene_set_resolution(&s, o.width ? o.width : s.width, o.height ? o.height : s.height);
    if (o.max_depth != -2)
        s.max_depth = o.max_depth;
    uint64_t triangles = 0;
    for (int i = 0; i < s.nshapes; ++i)
        triangles += s.shapes[i].m.ntris;
    printf("scene      %s: %d shapes, %llu triangles, %u light entries, loaded in %.2f s\n",
           o.scene, s.nshapes, (unsigned long long)triangles, s.nlights, now_seconds() - t_start);
    printf("image      %d x %d, max depth %d, %d threads, seed %llu\n", s.width, s.height,
           s.max_depth, o.threads, (unsigned long long)o.seed);
    if (ranks_size() > 1)
        printf("ranks      %d processes (MPI), %d threads each\n", ranks_size(), o.threads);
    if (!ranks_all_equal(scene_hash(&s, triangles), "the ranks loaded different scenes (or "
                         "resolutions)", &err)) {
        scene_free(&s);
        return fail(NULL, &err);
    }
    if (!s.has_lights && ranks_rank() == 0)
        fprintf(stderr, "nf_tracer: warning: the scene has no emitters (no area light, no "
                "environment): the image will be black\n");
    if (s.media_ignored && ranks_rank() == 0)
        fprintf(stderr, "nf_tracer: warning: the scene's media are ignored: the path "
                "integrator renders none, as in Mitsuba 3 (<integrator type=\"volpath\"> "
                "renders them)\n");
    const double t_job = now_seconds(); /* a time budget counts from here */

    int status = 1;
    image reference = {0}, img = {0};
    nf_model *model = NULL;
    FILE *csv = NULL;

    /* The reference, at the render's size (box-downsampled if it is a multiple of it). Rank 0
     * measures the errors: only it reads the reference. */
    if (!ranks_agree(ranks_rank() != 0 || read_reference(&o, &s, &reference, &err), &err)) {
        fail("reference", &err);
        goto done;
    }

    tracer t;
    memset(&t, 0, sizeof t);
    t.s = &s;
    t.policy = o.guide.policy;
    if (!o.guiding)
        t.policy.mixture_prob = 0.0f;
    t.mis_training = o.mis_training;
    t.guide_depth = o.guide_depth;
    t.no_batching = o.no_batching;
    t.light_mis_bsdf = o.light_mis_bsdf;
    t.rank = ranks_rank();
    t.ranks = ranks_size();
    t.model = NULL;
    t.bsdf_prior = 0;
    if (o.guiding) {
        guide_settings gs = guide_default_settings(o.prior);
        gs.large = o.large_model;
        gs.phi_interval = o.phi_interval;
        gs.learning_rate = o.learning_rate;
        gs.prior_epsilon = o.prior_epsilon;
        gs.sh_bands = o.sh_bands;
        gs.seed = o.seed;
        int ok = o.load_model ? guide_load(o.load_model, &model, &err)
                              : guide_create(&s, &gs, &model, &err);
        if (ok && o.load_model && o.learning_rate_given &&
            nf_model_set_learning_rate(model, o.learning_rate) != NF_OK)
            ok = tr_fail(&err, "--lr: %s", nf_last_error_message());
        if (ok && o.isa != NF_ISA_AUTO && nf_model_set_isa(model, o.isa) != NF_OK)
            ok = tr_fail(&err, "--isa: %s", nf_last_error_message());
        /* Every rank starts from the same model, or the steps would differ. */
        if (!ranks_agree(ok, &err) || !guide_models_agree(model, 0, &err)) {
            fail(NULL, &err);
            goto done;
        }
        nf_config cfg;
        nf_model_get_config(model, &cfg);
        t.bsdf_prior = cfg.prior == NF_PRIOR_CUSTOM;
        char mismatch[512];
        if (o.load_model && ranks_rank() == 0 &&
            !guide_bounds_match(&s, model, mismatch, sizeof mismatch))
            fprintf(stderr, "nf_tracer: warning: --load-model %s: %s\n", o.load_model, mismatch);
        if (o.load_model) {
            static const char *const kinds[] = {"uniform-direction", "uniform-angle", "cosine",
                                                "bsdf"};
            printf("model      %s (prior %s, %llu steps taken)\n", o.load_model,
                   kinds[cfg.prior], (unsigned long long)nf_model_step_count(model));
            if (o.prior_given && (int)cfg.prior != (int)o.prior && ranks_rank() == 0)
                fprintf(stderr, "nf_tracer: note: the loaded model's prior (%s) replaces --prior "
                        "%s\n", kinds[cfg.prior], guide_prior_name(o.prior));
        }
        printf("guiding    prior %s, %s model (%zu parameters), %s kernels, lr %g, guide "
               "probability %g%s%s\n",
               t.bsdf_prior ? "bsdf" : guide_prior_name((guide_prior)cfg.prior),
               cfg.coupling_layers > 2 ? "large" : "small", nf_model_param_count(model),
               nf_model_isa_name(model), (double)cfg.learning_rate, (double)t.policy.mixture_prob,
               o.variants ? ", variant " : "", o.variants ? o.variants : "");
        t.model = model;
        o.guide.learning_rate = cfg.learning_rate; /* --lr, or a loaded model's own rate */
    } else {
        printf("guiding    off%s\n", o.reference_mode ? " (reference mode)" : "");
    }

    path_stats stats;
    memset(&stats, 0, sizeof stats);
    if (o.time_budget > 0.0f) {
        if (!render_in_budget(&o, &t, &model, t_job, &img, &stats, &err)) {
            fail("render", &err);
            goto done;
        }
        goto write_outputs;
    }

    /* Training. */
    training_report rep;
    memset(&rep, 0, sizeof rep);
    if (o.guiding && o.iterations > 0) {
        snprintf(path, sizeof path, "%s.csv", prefix);
        int ok = ranks_rank() != 0 || (csv = fopen(path, "w")) != NULL ||
                 tr_fail(&err, "cannot write '%s': %s", path, strerror(errno));
        if (!ranks_agree(ok, &err)) {
            fail(NULL, &err);
            goto done;
        }
        training_settings ts;
        ts.iterations = o.iterations;
        ts.batch = o.batch;
        ts.eval_every = o.eval_every;
        ts.eval_spp = o.eval_spp;
        ts.threads = o.threads;
        ts.seed = o.seed;
        ts.reference = reference.data ? &reference : NULL; /* rank 0's */
        ts.csv = csv;
        printf("training   %d iterations of %d paths\n", o.iterations, o.batch);
        ts.guide = &o.guide;
        if (!train_guide(&t, &model, &ts, &rep, &err)) {
            fail("training", &err);
            goto done;
        }
        /* The times are rank 0's (the job's), the CPU seconds all ranks'. */
        double cpu[2] = {rep.trace_cpu_seconds, rep.step_cpu_seconds};
        if (!ranks_sum_f64(cpu, 2, &err)) {
            fail("training", &err);
            goto done;
        }
        rep.trace_cpu_seconds = cpu[0];
        rep.step_cpu_seconds = cpu[1];
        double it_s = (rep.trace_seconds + rep.step_seconds) / o.iterations;
        printf("trained    %llu samples (%.0f per iteration) in %.2f s: %.1f ms per iteration "
               "(tracing %.1f ms, optimizer steps %.1f ms)%s\n",
               (unsigned long long)rep.samples, (double)rep.samples / o.iterations,
               rep.trace_seconds + rep.step_seconds, 1e3 * it_s,
               1e3 * rep.trace_seconds / o.iterations, 1e3 * rep.step_seconds / o.iterations,
               rep.refused ? " (some batches were refused)" : "");
        printf("throughput steps %.0f samples/s (%.0f per CPU second), tracing %.0f "
               "training paths/s (%.0f per CPU second), last loss %.4f\n",
               rep.step_seconds > 0.0 ? (double)rep.samples / rep.step_seconds : 0.0,
               rep.step_cpu_seconds > 0.0 ? (double)rep.samples / rep.step_cpu_seconds : 0.0,
               rep.trace_seconds > 0.0 ? (double)rep.paths / rep.trace_seconds : 0.0,
               rep.trace_cpu_seconds > 0.0 ? (double)rep.paths / rep.trace_cpu_seconds : 0.0,
               (double)rep.last_loss);
        printf("csv        %s\n", path);
    }

    /* The final image: every rank renders its tiles, rank 0 receives them all. */
    t.model = model; /* the trained one */
    double t0 = now_seconds(), c0 = cpu_seconds();
    int rendered = image_alloc(&img, s.width, s.height, &err) &&
                   render_image(&t, o.spp, o.seed, 0u, o.threads, &img, &stats, "render", &err);
    if (!ranks_agree(rendered, &err) ||
        !ranks_sum_floats_to_root(img.data, 3 * (size_t)s.width * (size_t)s.height, &err) ||
        !ranks_sum_u64((uint64_t *)&stats, sizeof stats / sizeof(uint64_t), &err)) {
        fail("render", &err);
        goto done;
    }
    double render_s = now_seconds() - t0, render_cpu = cpu_seconds() - c0;
    if (!ranks_sum_f64(&render_cpu, 1, &err)) {
        fail("render", &err);
        goto done;
    }
    printf("rendered   %d spp in %.2f s (%.2f CPU s): %.2f M rays/s (%.2f M per CPU second), "
           "%.3f M paths/s, %.2f rays per path%s\n",
           o.spp, render_s, render_cpu, 1e-6 * (double)stats.rays / render_s,
           1e-6 * (double)stats.rays / render_cpu, 1e-6 * (double)stats.paths / render_s,
           (double)stats.rays / (double)stats.paths,
           stats.nf_errors ? " (libnisflow reported errors: paths were cut short)" : "");

write_outputs:
    /* Rank 0 writes the outputs; the others wait for its word, so all end alike. */
    if (!ranks_agree(ranks_rank() != 0 ||
                         write_results(&o, prefix, &img, &reference, model, &stats, &err),
                     &err)) {
        fail(NULL, &err);
        goto done;
    }
    printf("total      %.2f s\n", now_seconds() - t_start);
    status = 0;

done:
    if (csv)
        fclose(csv);
    nf_model_destroy(model);
    image_free(&img);
    image_free(&reference);
    scene_free(&s);
    return status;
}

int main(int argc, char **argv)
{
    tr_error err;
    if (!ranks_init(&argc, &argv, &err)) {
        fprintf(stderr, "nf_tracer: %s\n", err.msg);
        ranks_finalize();
        return 1;
    }
    /* Rank 0 speaks for the job: the others' reports would repeat it N times. */
    if (ranks_rank() != 0 && !freopen("/dev/null", "w", stdout))
        fprintf(stderr, "nf_tracer: rank %d: cannot silence its standard output\n", ranks_rank());
    int status = run(argc, argv);
    ranks_finalize();
    return status;
}
