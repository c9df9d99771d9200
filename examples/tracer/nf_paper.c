/*
 * nf_paper.c - the paper's protocol on the example path tracer (Müller et al. 2019, section
 * 6): --iterations training iterations, each a batch of --batch paths and one optimizer step
 * (render/training.c), then the final image at --spp samples per pixel with the trained model.
 * Its images are the same bits for a seed whatever the threads and ranks: the references and
 * the studies at equal samples use it; nf_tracer renders in a time budget instead. job.h holds
 * the steps around the render that both share. docs/tracer.md, "The paper's protocol".
 *
 *   nf_paper --scene examples/scenes/cornell-box/scene.xml --iterations 200 --spp 32
 */
#include <errno.h>
#include <stdio.h>
#include <string.h>

#include <nisflow/nisflow.h>

#include "job.h"
#include "progress.h"
#include "ranks.h"
#include "render.h"
#include "training.h"

/* The training iterations, with their CSV (PREFIX.csv, rank 0's) and report; the trained model
 * replaces j->model. */
static int train_by_iterations(job *j, tr_error *err)
{
    const options *o = &j->o;
    char path[4200];
    snprintf(path, sizeof path, "%s.csv", j->prefix);
    FILE *csv = NULL;
    int ok = ranks_rank() != 0 || (csv = fopen(path, "w")) != NULL ||
             tr_fail(err, "cannot write '%s': %s", path, strerror(errno));
    if (!ranks_agree(ok, err))
        return 0;
    training_settings ts = {
        .iterations = o->iterations,
        .batch = o->batch,
        .eval_every = o->eval_every,
        .eval_spp = o->eval_spp,
        .threads = o->threads,
        .seed = o->seed,
        .reference = j->reference.data ? &j->reference : NULL, /* rank 0's */
        .guide = &o->guide,
        .csv = csv,
    };
    training_report rep;
    memset(&rep, 0, sizeof rep);
    printf("training   %d iterations of %d paths\n", o->iterations, o->batch);
    ok = train_guide(&j->t, &j->model, &ts, &rep, err);
    if (csv)
        fclose(csv);
    /* The times are rank 0's (the job's), the CPU seconds all ranks'. */
    double cpu[2] = {rep.trace_cpu_seconds, rep.step_cpu_seconds};
    if (!ok || !ranks_sum_f64(cpu, 2, err))
        return 0;
    double it_s = (rep.trace_seconds + rep.step_seconds) / o->iterations;
    printf("trained    %llu samples (%.0f per iteration) in %.2f s: %.1f ms per iteration "
           "(tracing %.1f ms, optimizer steps %.1f ms)%s\n",
           (unsigned long long)rep.samples, (double)rep.samples / o->iterations,
           rep.trace_seconds + rep.step_seconds, 1e3 * it_s,
           1e3 * rep.trace_seconds / o->iterations, 1e3 * rep.step_seconds / o->iterations,
           rep.refused ? " (some batches were refused)" : "");
    printf("throughput steps %.0f samples/s (%.0f per CPU second), tracing %.0f "
           "training paths/s (%.0f per CPU second), last loss %.4f\n",
           rep.step_seconds > 0.0 ? (double)rep.samples / rep.step_seconds : 0.0,
           cpu[1] > 0.0 ? (double)rep.samples / cpu[1] : 0.0,
           rep.trace_seconds > 0.0 ? (double)rep.paths / rep.trace_seconds : 0.0,
           cpu[0] > 0.0 ? (double)rep.paths / cpu[0] : 0.0, (double)rep.last_loss);
    printf("csv        %s\n", path);
    return 1;
}

/* The final image at --spp: every rank renders its tiles, rank 0 receives them all. */
static int render_spp(job *j, image *img, path_stats *stats, tr_error *err)
{
    const options *o = &j->o;
    const scene *s = &j->s;
    j->t.model = j->model; /* the trained one, or NULL */
    double t0 = now_seconds(), c0 = cpu_seconds();
    int rendered = image_alloc(img, s->width, s->height, err) &&
                   render_image(&j->t, o->spp, o->seed, 0u, o->threads, img, stats, "render", err);
    if (!ranks_agree(rendered, err) ||
        !ranks_sum_floats_to_root(img->data, 3 * (size_t)s->width * (size_t)s->height, err) ||
        !ranks_sum_u64((uint64_t *)stats, sizeof *stats / sizeof(uint64_t), err))
        return 0;
    double render_s = now_seconds() - t0, render_cpu = cpu_seconds() - c0;
    if (!ranks_sum_f64(&render_cpu, 1, err))
        return 0;
    printf("rendered   %d spp in %.2f s (%.2f CPU s): %.2f M rays/s (%.2f M per CPU second), "
           "%.3f M paths/s, %.2f rays per path%s\n",
           o->spp, render_s, render_cpu, 1e-6 * (double)stats->rays / render_s,
           1e-6 * (double)stats->rays / render_cpu, 1e-6 * (double)stats->paths / render_s,
           (double)stats->rays / (double)stats->paths,
           stats->nf_errors ? " (libnisflow reported errors: paths were cut short)" : "");
    return 1;
}

static int render(job *j, image *img, path_stats *stats, const char **what, tr_error *err)
{
    *what = "training";
    if (j->o.guiding && j->o.iterations > 0 && !train_by_iterations(j, err))
        return 0;
    *what = "render";
    return render_spp(j, img, stats, err);
}

int main(int argc, char **argv) { return job_main(argc, argv, OPTIONS_PAPER, render); }
