/*
 * nf_tracer.c - the example path tracer's main program: a Mitsuba 3 scene rendered in a time
 * budget, guided by a libnisflow flow that it trains while it renders, written as EXR and PNG
 * with the error against a reference. The library's schedule (nisflow/schedule.h) decides
 * each pass: training, guided or plain (render/budget.c is the loop around it); job.h holds
 * the steps around the render that nf_paper shares. docs/tracer.md explains what it does.
 *
 *   nf_tracer --scene examples/scenes/cornell-box/scene.xml --width 256 --height 256
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include <nisflow/nisflow.h>

#include "budget.h"
#include "job.h"
#include "model_setup.h"
#include "ranks.h"

/* What the budget bought: the training, the passes of each kind and what the schedule chose
 * (nisflow/schedule.h, its report). */
static void report_budget(const options *o, int guided, const budget_report *br)
{
    const nf_schedule_report *sr = &br->sched;
    if (guided)
        printf("trained    %u passes, %d steps on %llu samples in %.2f s (steps %.2f s), last "
               "loss %.4f%s\n",
               sr->train_passes, br->steps, (unsigned long long)br->samples, br->train_seconds,
               br->step_seconds, (double)br->last_loss,
               sr->stopped_early ? ", stopped: the loss or the gain stopped improving" : "");
    if (guided && isfinite(sr->train_ratio))
        printf("training   its last pass's variance x time was %.3g of a plain pass's\n",
               sr->train_ratio);
    printf("budget     %.2f s of %.2f: %u training passes, %u render passes in %.2f s; the "
           "training passes weigh %.2f of the image\n",
           br->seconds, (double)o->time_budget, sr->train_passes, sr->render_passes,
           sr->render_seconds, sr->train_weight);
    uint64_t paths = br->stats.paths ? br->stats.paths : 1;
    printf("paths      %.2f rays and %.2f guided vertices per path\n",
           (double)br->stats.rays / (double)paths, (double)br->stats.guided_vertices / (double)paths);
    /* The choice between guided and plain render passes (nisflow/schedule.h), and its figures. */
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
    if (br->depth_fixed && sr->kind_passes[NF_PASS_GUIDED])
        printf("depth      fixed: guided passes guide vertices up to depth %u\n",
               sr->depth);
    for (uint32_t c = 0; c < NF_GUIDE_DEPTHS && !br->depth_fixed; ++c) {
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
}

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
        gc.payload_bytes = sizeof(prior_point);
    if (*model && nf_guide_create(*model, &gc, &guide) != NF_OK)
        return tr_fail(err, "%s", nf_last_error_message());
    int ok = render_with_budget(t, guide, &bs, img, &br, err);
    if (ok && guide) /* the trained model replaces the starting one */
        ok = model_take_trained(guide, model, err);
    nf_guide_destroy(guide);
    if (!ok)
        return 0;
    *stats = br.stats;
    report_budget(o, *model != NULL, &br);
    return 1;
}

/* ---- Main ------------------------------------------------------------------------------------- */

static int render(job *j, image *img, path_stats *stats, const char **what, tr_error *err)
{
    *what = "render";
    return render_in_budget(&j->o, &j->t, &j->model, j->t_job, img, stats, err);
}

int main(int argc, char **argv) { return job_main(argc, argv, OPTIONS_TRACER, render); }
