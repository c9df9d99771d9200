/*
 * training.c - the loop of training.h.
 *
 * Each iteration's batch of paths is cut into groups of GROUP_PATHS paths, fixed by the batch
 * alone. The ranks (ranks.h) split the groups, each traces its groups' paths, and the
 * library's guide (nf_guide_train_batch) computes every group's gradient on the threads and
 * sums them exactly over all ranks: the model is the same to the bit for any number of ranks
 * and threads (docs/distributed.md). The CSV's "seconds" column counts the time spent in training
 * iterations (tracing and stepping), not the evaluation renders that measure them.
 */
#include "training.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "metrics.h"
#include "model_setup.h"
#include "path_record.h"
#include "progress.h"
#include "ranks.h"
#include "render.h"

/* Paths per gradient group: a multiple of render.c's chunks of 64; 16 groups in a batch of
 * 4,096, enough to keep 2 threads (or 2 ranks x 8 threads) busy. */
#define GROUP_PATHS 256

/* Renders an evaluation image (every rank its tiles, assembled on rank 0) and writes a CSV
 * row. `samples` is this rank's count; the row has all ranks'. Collective. */
static int evaluate(const tracer *t, const training_settings *ts, int iteration,
                    uint64_t samples, double seconds, tr_error *err)
{
    image img = {0};
    /* Each evaluation gets its own random streams (pass 1000 + iteration). */
    int ok = image_alloc(&img, t->s->width, t->s->height, err) &&
             render_image(t, ts->eval_spp, ts->seed, 1000u + (uint32_t)iteration, ts->threads,
                          &img, NULL, "evaluate", err);
    if (!ranks_agree(ok, err) ||
        !ranks_sum_floats_to_root(img.data, 3 * (size_t)img.width * (size_t)img.height, err) ||
        !ranks_sum_u64(&samples, 1, err)) {
        image_free(&img);
        return 0;
    }
    char mape[64] = "";
    if (ts->reference)
        snprintf(mape, sizeof mape, "%.6f", image_mape(ts->reference, &img));
    image_free(&img);
    if (ts->csv) {
        fprintf(ts->csv, "%d,%llu,%.3f,%s\n", iteration, (unsigned long long)samples, seconds,
                mape);
        fflush(ts->csv);
    }
    printf("  iteration %6d  %10llu samples  %8.2f s  MAPE %s\n", iteration,
           (unsigned long long)samples, seconds, ts->reference ? mape : "(no reference)");
    fflush(stdout);
    return 1;
}

/* This rank's share of an iteration's groups: groups [g0, g1) of `total`. */
static void rank_groups(size_t total, size_t *g0, size_t *g1)
{
    size_t r = (size_t)ranks_rank(), n = (size_t)ranks_size();
    *g0 = total * r / n;
    *g1 = total * (r + 1) / n;
}

/* Paths per gradient group for a batch: GROUP_PATHS, or a larger multiple of it when the batch
 * has more groups than a guide takes (nisflow/guide.h: at most 256). */
static size_t group_paths(size_t paths)
{
    size_t groups = (paths + GROUP_PATHS - 1) / GROUP_PATHS;
    return GROUP_PATHS * ((groups + 255) / 256);
}

/* Trains with `guide` on the iteration's batch (this rank's groups of it): one step of the
 * guide's training model, summed exactly over the groups, threads and ranks. */
static int step_on_batch(nf_guide *guide, const record_arrays *batch, size_t n,
                         const size_t *group_end, size_t groups, int threads, int it,
                         training_report *rep, float *loss, tr_error *err)
{
    training_hooks hooks;
    training_hooks_init(&hooks, threads);
    nf_status st = guide_train_batch(guide, &hooks, n, batch->ctx, batch->points, batch->dir,
                                     batch->weight, groups ? group_end : NULL, groups, loss);
    if (st == NF_ERROR_NUMERIC) {
        /* A refused batch leaves the model unchanged (on every rank): report it, go on. */
        if (rep->refused++ < 5 && ranks_rank() == 0)
            fprintf(stderr, "\nnf_tracer: iteration %d: batch refused: %s\n", it,
                    nf_last_error_message());
        return 1;
    }
    if (st != NF_OK)
        return tr_fail(err, "iteration %d: %s", it, nf_last_error_message());
    if (isfinite(*loss))
        rep->last_loss = *loss;
    st = nf_guide_publish(guide); /* no thread holds a model between iterations */
    return st == NF_OK || tr_fail(err, "iteration %d: %s", it, nf_last_error_message());
}

/* Points t at the guide's newest model for a render (tracing or evaluation). */
static int use_published(tracer *t, nf_guide *guide, tr_error *err)
{
    const nf_model *m = NULL;
    if (nf_guide_acquire(guide, &m) != NF_OK)
        return tr_fail(err, "%s", nf_last_error_message());
    t->model = m;
    return 1;
}

static void end_use(tracer *t, nf_guide *guide)
{
    nf_guide_release(guide, t->model);
    t->model = NULL;
}

int train_guide(tracer *t, nf_model **model, const training_settings *ts,
                training_report *rep, tr_error *err)
{
    record_buffer records = {0};
    record_arrays batch = {0};
    progress bar;
    nf_guide *guide = NULL;
    const size_t paths = (size_t)ts->batch, per_group = group_paths(paths),
                 groups = (paths + per_group - 1) / per_group;
    size_t g0, g1;
    rank_groups(groups, &g0, &g1);
    const size_t first = g0 * per_group,
                 mine = (g1 * per_group < paths ? g1 * per_group : paths) - first;
    size_t *path_end = malloc((mine ? mine : 1) * sizeof *path_end);
    size_t *group_end = malloc((g1 > g0 ? g1 - g0 : 1) * sizeof *group_end);
    /* The guide's store is not used here: the iteration's batch is the step. */
    nf_guide_config gc;
    if (ts->guide)
        gc = *ts->guide;
    else { /* the library's defaults, at the model's own learning rate */
        nf_config cfg;
        nf_guide_config_init(&gc);
        if (nf_model_get_config(*model, &cfg) == NF_OK)
            gc.learning_rate = cfg.learning_rate;
    }
    gc.store_capacity = 1;
    gc.groups = groups < 1 ? 1 : (uint32_t)groups;
    int ok = path_end && group_end ? 1 : tr_fail(err, "out of memory");
    if (ok && nf_guide_create(*model, &gc, &guide) != NF_OK)
        ok = tr_fail(err, "%s", nf_last_error_message());
    ok = ranks_agree(ok, err);
    memset(rep, 0, sizeof *rep);
    if (ts->csv)
        fprintf(ts->csv, "iteration,training_samples,seconds,mape\n");
    if (ok && ts->eval_every > 0 && (ok = use_published(t, guide, err))) {
        ok = evaluate(t, ts, 0, 0, 0.0, err);
        end_use(t, guide);
    }

    progress_start(&bar, "training", (size_t)ts->iterations);
    for (int it = 1; it <= ts->iterations && ok; ++it) {
        double t0 = now_seconds(), c0 = cpu_seconds();
        ok = use_published(t, guide, err);
        if (ok) {
            ok = trace_training_batch(t, first, mine, ts->seed, (uint32_t)it, ts->threads,
                                      &records, path_end, &rep->stats, err);
            end_use(t, guide);
        }
        double t1 = now_seconds(), c1 = cpu_seconds();
        size_t n = records.count;
        if (ok && !record_arrays_from(&batch, &records, 0))
            ok = tr_fail(err, "out of memory for a training batch of %zu samples", n);
        if (!ranks_agree(ok, err)) { /* a rank that failed stops them all */
            ok = 0;
            break;
        }
        for (size_t g = g0; g < g1; ++g) {
            size_t last = (g + 1) * per_group < paths ? (g + 1) * per_group : paths;
            group_end[g - g0] = path_end[last - 1 - first];
        }
        float loss = NAN;
        ok = step_on_batch(guide, &batch, n, group_end, g1 - g0, ts->threads, it, rep, &loss,
                           err);
        double t2 = now_seconds();
        rep->step_cpu_seconds += cpu_seconds() - c1;
        if (!ok)
            break;
        if (ranks_size() > 1 &&
            !(ok = models_agree_across_ranks(nf_guide_training_model(guide), it, err)))
            break;
        rep->samples += n;
        rep->paths += (uint64_t)paths;
        rep->trace_seconds += t1 - t0;
        rep->trace_cpu_seconds += c1 - c0;
        rep->step_seconds += t2 - t1;

        char extra[96];
        snprintf(extra, sizeof extra, "loss %.4f, %zu samples/it", (double)loss, n);
        progress_update(&bar, (size_t)it, extra);
        if (ts->eval_every > 0 && (it % ts->eval_every == 0 || it == ts->iterations) &&
            (ok = use_published(t, guide, err))) {
            progress_finish(&bar);
            ok = evaluate(t, ts, it, rep->samples, rep->trace_seconds + rep->step_seconds, err);
            end_use(t, guide);
        }
    }
    progress_finish(&bar);
    /* The report counts every rank's samples (its times are this rank's). */
    if (ok)
        ok = ranks_sum_u64(&rep->samples, 1, err);
    if (ok) /* the trained model replaces the starting one */
        ok = model_take_trained(guide, model, err);
    nf_guide_destroy(guide);
    record_buffer_free(&records);
    record_arrays_free(&batch);
    free(path_end);
    free(group_end);
    return ok;
}
