/*
 * training.c - the loop of training.h.
 *
 * The batch is handed to nf_train_step from this one thread, in path order, so training is
 * as deterministic as the tracing. The CSV's "seconds" column counts the time spent in
 * training iterations (tracing and stepping), not the evaluation renders that measure them.
 */
#include "training.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "guide.h"
#include "metrics.h"
#include "progress.h"
#include "render.h"

/* Structure-of-arrays copies of a batch, as nf_train_step takes them. */
typedef struct batch_arrays {
    nf_context *ctx;
    float *dir, *weight;
    guide_point *points; /* the BSDF prior's material of each context */
    size_t capacity;
} batch_arrays;

static int batch_reserve(batch_arrays *b, size_t n)
{
    if (n <= b->capacity)
        return 1;
    size_t cap = b->capacity ? b->capacity : 1024;
    while (cap < n)
        cap *= 2;
    nf_context *ctx = realloc(b->ctx, cap * sizeof *ctx);
    if (ctx)
        b->ctx = ctx;
    float *dir = realloc(b->dir, cap * 3 * sizeof *dir);
    if (dir)
        b->dir = dir;
    float *weight = realloc(b->weight, cap * sizeof *weight);
    if (weight)
        b->weight = weight;
    guide_point *points = realloc(b->points, cap * sizeof *points);
    if (points)
        b->points = points;
    if (!ctx || !dir || !weight || !points)
        return 0;
    b->capacity = cap;
    return 1;
}

static void batch_free(batch_arrays *b)
{
    free(b->ctx);
    free(b->dir);
    free(b->weight);
    free(b->points);
}

/* Renders an evaluation image and writes a CSV row. */
static int evaluate(const tracer *t, const training_settings *ts, int iteration,
                    uint64_t samples, double seconds, tr_error *err)
{
    image img;
    if (!image_alloc(&img, t->s->width, t->s->height, err))
        return 0;
    /* Each evaluation gets its own random streams (pass 1000 + iteration). */
    if (!render_image(t, ts->eval_spp, ts->seed, 1000u + (uint32_t)iteration, ts->threads, &img,
                      NULL, "evaluate", err)) {
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

int train_guide(const tracer *t, nf_model *model, const training_settings *ts,
                training_report *rep, tr_error *err)
{
    record_buffer records = {0};
    batch_arrays batch = {0};
    progress bar;
    int ok = 1;
    memset(rep, 0, sizeof *rep);
    if (ts->csv)
        fprintf(ts->csv, "iteration,training_samples,seconds,mape\n");
    if (ts->eval_every > 0 && !evaluate(t, ts, 0, 0, 0.0, err))
        return 0;

    progress_start(&bar, "training", (size_t)ts->iterations);
    for (int it = 1; it <= ts->iterations && ok; ++it) {
        double t0 = now_seconds(), c0 = cpu_seconds();
        ok = trace_training_batch(t, (size_t)ts->batch, ts->seed, (uint32_t)it, ts->threads,
                                  &records, &rep->stats, err);
        double t1 = now_seconds(), c1 = cpu_seconds();
        if (!ok)
            break;
        size_t n = records.count;
        if (!batch_reserve(&batch, n)) {
            ok = tr_fail(err, "out of memory for a training batch of %zu samples", n);
            break;
        }
        for (size_t i = 0; i < n; ++i) {
            const train_record *r = &records.data[i];
            batch.ctx[i] = r->ctx;
            memcpy(batch.dir + 3 * i, r->dir, 3 * sizeof(float));
            batch.weight[i] = r->weight;
            memcpy(batch.points[i].position, r->ctx.position, sizeof r->ctx.position);
            batch.points[i].bp = r->bp;
        }
        if (t->bsdf_prior) /* the BSDF prior's callbacks look the materials up here */
            guide_begin_batch(batch.ctx, batch.points, n);
        float loss = 0.0f;
        double s0 = thread_cpu_seconds();
        nf_status st = nf_train_step(model, n, batch.ctx, batch.dir, batch.weight, &loss);
        guide_end();
        double t2 = now_seconds();
        rep->step_cpu_seconds += thread_cpu_seconds() - s0;
        if (st != NF_OK) {
            /* A refused batch leaves the model unchanged: report it and go on. */
            if (rep->refused++ < 5)
                fprintf(stderr, "\nnf_tracer: iteration %d: batch refused: %s: %s\n", it,
                        nf_status_string(st), nf_last_error_message());
        } else {
            rep->last_loss = loss;
        }
        rep->samples += n;
        rep->paths += (uint64_t)ts->batch;
        rep->trace_seconds += t1 - t0;
        rep->trace_cpu_seconds += c1 - c0;
        rep->step_seconds += t2 - t1;

        if (getenv("NF_TRACER_LOSS")) fprintf(stderr, "it %d loss %.5f n %zu\n", it, (double)loss, n);
        char extra[96];
        snprintf(extra, sizeof extra, "loss %.4f, %zu samples/it", (double)loss, n);
        progress_update(&bar, (size_t)it, extra);
        if (ts->eval_every > 0 && (it % ts->eval_every == 0 || it == ts->iterations)) {
            progress_finish(&bar);
            ok = evaluate(t, ts, it, rep->samples, rep->trace_seconds + rep->step_seconds, err);
        }
    }
    progress_finish(&bar);
    record_buffer_free(&records);
    batch_free(&batch);
    return ok;
}
