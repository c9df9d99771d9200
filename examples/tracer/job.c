/*
 * job.c - the steps nf_tracer and nf_paper share (job.h): the outputs' names and the check
 * that they can be written, the scene loaded and compared between the ranks, the reference,
 * the model guiding starts from, and the outputs written at the end.
 */
#include "job.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "metrics.h"
#include "model_setup.h"
#include "progress.h"
#include "ranks.h"

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
static int make_parent_dirs(const char *program, const char *path)
{
    char buf[4096];
    copy_string(buf, sizeof buf, path);
    for (char *p = buf + 1; *p; ++p) {
        if (*p != '/')
            continue;
        *p = '\0';
        if (mkdir(buf, 0777) == 0)
            fprintf(stderr, "%s: note: created the directory '%s'\n", program, buf);
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
static int write_results(const options *o, const char *program, const char *prefix,
                         const image *img, const image *reference, const nf_model *model,
                         const path_stats *stats, tr_error *err)
{
    char path[4200];
    if (stats->camera_backfaces > stats->paths / 100)
        fprintf(stderr, "%s: note: %.0f%% of the camera rays hit the back of a one-sided "
                "material, which is black (Mitsuba's convention). If that is not intended (scenes "
                "from pbrt or Tungsten shade both sides), wrap the material in <bsdf "
                "type=\"twosided\">.\n",
                program, 100.0 * (double)stats->camera_backfaces / (double)stats->paths);
    if (stats->invalid_rays)
        fprintf(stderr, "%s: warning: %llu rays were outside what Embree accepts and "
                "ended their paths (the scene loader should have refused this scene: please "
                "report it).\n", program, (unsigned long long)stats->invalid_rays);

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
    if (prior_lookup_failures(model))
        fprintf(stderr, "%s: warning: the BSDF prior fell back to a cosine lobe %llu times "
                "(a shading point was not published; please report this)\n",
                program, prior_lookup_failures(model));
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
    if (!make_parent_dirs(options_program_name(o->program), prefix) || !can_create(prefix))
        return tr_fail(err, "--out: cannot write into the directory of '%s': %s", prefix,
                       strerror(errno));
    if (o->save_model && !can_create(o->save_model))
        return tr_fail(err, "--save-model: cannot create '%s': %s", o->save_model,
                       strerror(errno));
    return 1;
}

/* ---- The steps ------------------------------------------------------------------------------ */

static int job_fail(const job *j, const char *what, const tr_error *e)
{
    if (ranks_rank() == 0)
        fprintf(stderr, "%s: %s%s%s\n", options_program_name(j->o.program), what ? what : "",
                what ? ": " : "", e->msg);
    return 1;
}

/* The scene, with the command line's film and depth, the same on every rank. */
static int load_scene(job *j, tr_error *err)
{
    const options *o = &j->o;
    j->scene_loaded = scene_load(o->scene, &j->s, err);
    if (!ranks_agree(j->scene_loaded, err))
        return 0;
    scene *s = &j->s;
    if (o->width || o->height)
        scene_set_resolution(s, o->width ? o->width : s->width, o->height ? o->height : s->height);
    if (o->max_depth != -2)
        s->max_depth = o->max_depth;
    uint64_t triangles = 0;
    for (int i = 0; i < s->nshapes; ++i)
        triangles += s->shapes[i].m.ntris;
    printf("scene      %s: %d shapes, %llu triangles, %u light entries, loaded in %.2f s\n",
           o->scene, s->nshapes, (unsigned long long)triangles, s->nlights,
           now_seconds() - j->t_start);
    printf("image      %d x %d, max depth %d, %d threads, seed %llu\n", s->width, s->height,
           s->max_depth, o->threads, (unsigned long long)o->seed);
    if (ranks_size() > 1)
        printf("ranks      %d processes (MPI), %d threads each\n", ranks_size(), o->threads);
    if (!ranks_all_equal(scene_hash(s, triangles),
                         "the ranks loaded different scenes (or resolutions)", err))
        return 0;
    const char *name = options_program_name(o->program);
    if (!s->has_lights && ranks_rank() == 0)
        fprintf(stderr, "%s: warning: the scene has no emitters (no area light, no "
                "environment): the image will be black\n", name);
    if (s->upgraded && ranks_rank() == 0)
        printf("format     version %d.%d.%d, upgraded in memory as Mitsuba 3 does\n",
               s->upgraded_from[0], s->upgraded_from[1], s->upgraded_from[2]);
    for (int i = 0; i < s->nwarnings && ranks_rank() == 0; ++i)
        fprintf(stderr, "%s: warning: %s\n", name, s->warnings[i]);
    if (s->media_ignored && ranks_rank() == 0)
        fprintf(stderr, "%s: warning: the scene's media are ignored: the path integrator "
                "renders none, as in Mitsuba 3 (<integrator type=\"volpath\"> renders them)\n",
                name);
    return 1;
}

/* The model guiding starts from: loaded (--load-model) or made for the scene, the same on
 * every rank; the tracer learns whether it uses the BSDF prior. */
static int make_model(job *j, tr_error *err)
{
    const options *o = &j->o;
    model_settings gs = model_default_settings(o->prior);
    gs.large = o->large_model;
    gs.phi_interval = o->phi_interval;
    gs.learning_rate = o->learning_rate;
    gs.prior_epsilon = o->prior_epsilon;
    gs.sh_bands = o->sh_bands;
    gs.seed = o->seed;
    int ok = o->load_model ? model_load_file(o->load_model, &j->lookup, &j->model, err)
                           : model_create_for_scene(&j->s, &gs, &j->lookup, &j->model, err);
    if (ok && o->load_model && o->learning_rate_given &&
        nf_model_set_learning_rate(j->model, o->learning_rate) != NF_OK)
        ok = tr_fail(err, "--lr: %s", nf_last_error_message());
    if (ok && o->isa != NF_ISA_AUTO && nf_model_set_isa(j->model, o->isa) != NF_OK)
        ok = tr_fail(err, "--isa: %s", nf_last_error_message());
    /* Every rank starts from the same model, or the steps would differ. */
    if (!ranks_agree(ok, err) || !models_agree_across_ranks(j->model, 0, err))
        return 0;
    nf_config cfg;
    nf_model_get_config(j->model, &cfg);
    j->t.bsdf_prior = cfg.prior == NF_PRIOR_CUSTOM;
    const char *name = options_program_name(o->program);
    char mismatch[512];
    if (o->load_model && ranks_rank() == 0 &&
        !model_bounds_match(&j->s, j->model, mismatch, sizeof mismatch))
        fprintf(stderr, "%s: warning: --load-model %s: %s\n", name, o->load_model, mismatch);
    if (o->load_model) {
        static const char *const kinds[] = {"uniform-direction", "uniform-angle", "cosine",
                                            "bsdf"};
        printf("model      %s (prior %s, %llu steps taken)\n", o->load_model, kinds[cfg.prior],
               (unsigned long long)nf_model_step_count(j->model));
        if (o->prior_given && (int)cfg.prior != (int)o->prior && ranks_rank() == 0)
            fprintf(stderr, "%s: note: the loaded model's prior (%s) replaces --prior %s\n",
                    name, kinds[cfg.prior], model_prior_name(o->prior));
    }
    printf("guiding    prior %s, %s model (%zu parameters), %s kernels, lr %g, guide "
           "probability %g%s%s\n",
           j->t.bsdf_prior ? "bsdf" : model_prior_name((model_prior)cfg.prior),
           cfg.coupling_layers > 2 ? "large" : "small", nf_model_param_count(j->model),
           nf_model_isa_name(j->model), (double)cfg.learning_rate,
           (double)j->t.policy.mixture_prob, o->variants ? ", variant " : "",
           o->variants ? o->variants : "");
    j->o.guide.learning_rate = cfg.learning_rate; /* --lr, or a loaded model's own rate */
    return 1;
}

/* The tracer's settings from the command line; its model stays NULL (job.h). */
static void set_up_tracer(job *j)
{
    const options *o = &j->o;
    tracer *t = &j->t;
    memset(t, 0, sizeof *t);
    t->s = &j->s;
    t->policy = o->guide.policy;
    if (!o->guiding)
        t->policy.mixture_prob = 0.0f;
    t->mis_training = o->mis_training;
    t->guide_depth = o->guide_depth;
    t->no_batching = o->no_batching;
    t->light_mis_bsdf = o->light_mis_bsdf;
    t->rank = ranks_rank();
    t->ranks = ranks_size();
}

/* Parses argv for `program` and prepares the job. Returns 1 when it is ready to render; else
 * 0 with the exit code in *exit_code: 0 after --help or --variant list, 2 after a bad
 * command line, 1 after a failure it reported. */
static int job_start(int argc, char **argv, options_program program, job *j, int *exit_code)
{
    memset(j, 0, sizeof *j);
    prior_lookup_init(&j->lookup);
    options *o = &j->o;
    tr_error err;
    const char *name = options_program_name(program);
    *exit_code = 2;
    if (!ranks_agree(options_parse(argc, argv, program, o, &err), &err)) {
        if (ranks_rank() == 0)
            fprintf(stderr, "%s: %s (try --help)\n", name, err.msg);
        return 0;
    }
    *exit_code = 0;
    if (o->help || o->list_variants) {
        if (o->help)
            options_print_help(program, argv[0]);
        else
            options_print_variants();
        return 0;
    }
    *exit_code = 1;
    /* The ranks of one job must have been asked for the same job. */
    if (!ranks_all_equal(options_job_hash(argc, argv), "the ranks were started with different "
                         "options (all but --threads, --scene, --out, --reference, "
                         "--save-model, --load-model and --exposure must be the same)", &err) ||
        !ranks_agree(outputs_writable(o, j->prefix, sizeof j->prefix, &err), &err))
        return job_fail(j, NULL, &err), 0;
    j->t_start = now_seconds();
    if (!load_scene(j, &err))
        return job_fail(j, NULL, &err), 0;
    j->t_job = now_seconds();
    /* Rank 0 measures the errors: only it reads the reference. */
    if (!ranks_agree(ranks_rank() != 0 || read_reference(o, &j->s, &j->reference, &err), &err))
        return job_fail(j, "reference", &err), 0;
    set_up_tracer(j);
    if (o->guiding && !make_model(j, &err))
        return job_fail(j, NULL, &err), 0;
    if (!o->guiding)
        printf("guiding    off%s\n", o->reference_mode ? " (reference mode)" : "");
    return 1;
}

/* Rank 0 writes the outputs (write_results); returns the exit code. */
static int job_finish(job *j, const image *img, const path_stats *stats)
{
    tr_error err;
    /* Rank 0 writes the outputs; the others wait for its word, so all end alike. */
    if (!ranks_agree(ranks_rank() != 0 || write_results(&j->o, options_program_name(j->o.program),
                                                        j->prefix, img, &j->reference, j->model,
                                                        stats, &err),
                     &err))
        return job_fail(j, NULL, &err);
    printf("total      %.2f s\n", now_seconds() - j->t_start);
    return 0;
}

static void job_free(job *j)
{
    nf_model_destroy(j->model);
    j->model = NULL;
    image_free(&j->reference);
    if (j->scene_loaded)
        scene_free(&j->s);
    j->scene_loaded = 0;
}

int job_main(int argc, char **argv, options_program program, job_render_fn render)
{
    tr_error err;
    const char *name = options_program_name(program);
    if (!ranks_init(&argc, &argv, &err)) {
        fprintf(stderr, "%s: %s\n", name, err.msg);
        ranks_finalize();
        return 1;
    }
    /* Rank 0 speaks for the job: the others' reports would repeat it N times. */
    if (ranks_rank() != 0 && !freopen("/dev/null", "w", stdout))
        fprintf(stderr, "%s: rank %d: cannot silence its standard output\n", name, ranks_rank());
    job j;
    int code;
    if (job_start(argc, argv, program, &j, &code)) {
        image img = {0};
        path_stats stats;
        memset(&stats, 0, sizeof stats);
        const char *what = NULL;
        code = render(&j, &img, &stats, &what, &err) ? job_finish(&j, &img, &stats)
                                                     : job_fail(&j, what, &err);
        image_free(&img);
    }
    job_free(&j);
    ranks_finalize();
    return code;
}
