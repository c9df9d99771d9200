/*
 * budget.c - the time-budgeted job of budget.h: the tracer's loop around the library's
 * schedule (nisflow/schedule.h). The schedule says what each pass is and combines them; this
 * file renders them, trains the guide on the training passes' records, and keeps the ranks in
 * step (every schedule and guide call is collective over them).
 */
#include "budget.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "model_setup.h"
#include "parallel.h"
#include "path_record.h"
#include "progress.h"
#include "ranks.h"
#include "render.h"

/* Budget passes use their own random streams, apart from render_image's passes. */
#define PASS_STREAM_BASE 0x100000u

/* ---- A training pass's samples, chunk by chunk ------------------------------------------ */

/* One render thread's share of a training pass's intake: its arrays, reused from chunk to
 * chunk, and its first failure. */
typedef struct intake_thread {
    record_arrays arrays;
    int failed;
    char message[256];
} intake_thread;

/* The record sink of training passes (render.h): each chunk's records become the guide's
 * samples as soon as the chunk is traced, on its render thread, while the other chunks are
 * traced; no thread waits for a pass's records to be joined. The keys (the chunk, then the
 * record's place in it) sort them as one thread would have traced them, so the guide trains
 * on the same store whatever the number of threads. */
typedef struct pass_intake {
    nf_guide *guide;
    intake_thread *threads; /* one per render thread */
    int count;
} pass_intake;

static void intake_chunk(void *user, size_t chunk, int thread, const record_buffer *rec)
{
    pass_intake *in = user;
    intake_thread *it = &in->threads[thread];
    record_arrays *a = &it->arrays;
    if (it->failed || rec->count == 0)
        return;
    if (rec->out_of_memory || !record_arrays_from(a, rec, (uint64_t)chunk << 32)) {
        it->failed = 1;
        snprintf(it->message, sizeof it->message,
                 "out of memory for the training samples of chunk %zu", chunk);
    } else if (nf_guide_add_samples(in->guide, rec->count, a->key, a->ctx, a->dir, a->weight,
                                    a->points) != NF_OK) {
        it->failed = 1;
        snprintf(it->message, sizeof it->message, "%s", nf_last_error_message());
    }
}

/* The first failure of a pass's intake, into err; 1 when there was none. */
static int intake_ok(pass_intake *in, uint32_t pass, tr_error *err)
{
    for (int i = 0; i < in->count; ++i)
        if (in->threads[i].failed)
            return tr_fail(err, "training pass %u: %s", pass, in->threads[i].message);
    return 1;
}

static void intake_free(pass_intake *in)
{
    for (int i = 0; in->threads && i < in->count; ++i)
        record_arrays_free(&in->threads[i].arrays);
    free(in->threads);
}

/* Trains on the samples the pass added, then publishes. Collective (the guide's steps reduce
 * over the ranks). */
static int train_on_pass(nf_guide *g, int threads, uint32_t pass, budget_report *rep,
                         tr_error *err)
{
    nf_guide_pass_report pr;
    training_hooks hooks;
    training_hooks_init(&hooks, threads);
    nf_status st = guide_train_pass(g, &hooks, &pr);
    if (st != NF_OK) /* the hooks failed (MPI): the same on every rank */
        return tr_fail(err, "training pass %u: %s", pass, nf_last_error_message());
    if (pr.refused && rep->refused < 5 && ranks_rank() == 0)
        fprintf(stderr, "\nnf_tracer: training pass %u: %u steps refused: %s\n", pass,
                pr.refused, nf_last_error_message());
    rep->refused += (int)pr.refused;
    rep->steps += (int)pr.steps;
    rep->samples += pr.new_samples;
    if (isfinite(pr.held_out_loss))
        rep->last_loss = pr.held_out_loss;
    st = nf_guide_publish(g); /* no pass holds a model now */
    return st == NF_OK || tr_fail(err, "training pass %u: %s", pass, nf_last_error_message());
}

/* ---- The job ------------------------------------------------------------------------------- */

/* The pieces of the job that live as long as it. */
typedef struct budget_job {
    nf_schedule *schedule;
    pass_intake intake;
    render_memory mem; /* the passes' per-thread buffers, kept from pass to pass */
    float *rgb;        /* the pass's paths: 3 floats each                          */
    float *moment;     /* and PATH_MOMENTS planes of one float each                */
    uint32_t paths;    /* the paths they hold                                      */
    training_hooks hooks; /* the ranks' reduce for the schedule */
} budget_job;

static void job_free(budget_job *j)
{
    nf_schedule_destroy(j->schedule);
    intake_free(&j->intake);
    render_memory_free(&j->mem);
    free(j->rgb);
    free(j->moment);
}

/* Allocates the job; every step may fail on one rank only, so the ranks agree after it. */
static int job_start(budget_job *j, tracer *t, nf_guide *guide, const budget_settings *bs,
                     image *img, tr_error *err)
{
    const scene *s = t->s;
    nf_schedule_config sc;
    nf_schedule_config_init(&sc);
    sc.width = (uint32_t)s->width;
    sc.height = (uint32_t)s->height;
    sc.budget = bs->seconds;
    sc.guide_depth = (uint32_t)t->guide_depth; /* --variant guide-depth: every guided pass */
    training_hooks_init(&j->hooks, bs->threads);
    int ready = image_alloc(img, s->width, s->height, err);
    j->intake.guide = guide;
    j->intake.count = bs->threads > 0 ? bs->threads : 1;
    j->intake.threads = calloc((size_t)j->intake.count, sizeof *j->intake.threads);
    ready = ready && (j->intake.threads || tr_fail(err, "out of memory for the intake"));
    ready = ready && (nf_schedule_create(guide, &sc, &j->schedule) == NF_OK ||
                      tr_fail(err, "%s", nf_last_error_message()));
    /* The BSDF prior's callbacks find each training sample's material in its payload. */
    if (ready && guide && t->bsdf_prior &&
        nf_guide_get_config(guide)->payload_bytes < sizeof(prior_point))
        ready = tr_fail(err, "the guide keeps %zu payload bytes per sample; the BSDF prior needs "
                        "%zu (nf_guide_config.payload_bytes)",
                        nf_guide_get_config(guide)->payload_bytes, sizeof(prior_point));
    return ranks_agree(ready, err);
}

/* j->rgb and j->moment for the plan's paths (a pass's count varies by one between subsets). */
static int job_buffers(budget_job *j, const nf_pass_plan *plan, tr_error *err)
{
    if (plan->paths <= j->paths)
        return 1;
    free(j->rgb);
    free(j->moment);
    j->rgb = malloc(3 * (size_t)plan->paths * sizeof *j->rgb);
    j->moment = malloc(PATH_MOMENTS * (size_t)plan->paths * sizeof *j->moment);
    j->paths = j->rgb && j->moment ? plan->paths : 0;
    return j->paths || tr_fail(err, "out of memory for a pass of %u paths", plan->paths);
}

/* Renders the pass that `plan` asks for into j->rgb and j->moment, with the guide's newest
 * published model unless it is plain; a training pass's samples go to the guide meanwhile. */
static int job_render(budget_job *j, tracer *t, nf_guide *guide, const budget_settings *bs,
                      const nf_pass_plan *plan, budget_report *rep, tr_error *err)
{
    const nf_model *m = NULL;
    if (!job_buffers(j, plan, err))
        return ranks_agree(0, err);
    if (plan->todo != NF_TODO_PLAIN && nf_guide_acquire(guide, &m) != NF_OK)
        return tr_fail(err, "%s", nf_last_error_message());
    const int fixed_depth = t->guide_depth;
    t->model = m; /* every thread of the pass samples this one; NULL: a plain pass */
    t->guide_depth = (int)plan->depth;
    const record_sink sink = {intake_chunk, &j->intake};
    int rendered = render_pass(t, bs->seed, PASS_STREAM_BASE + plan->pass, plan, bs->threads,
                               j->rgb, j->moment, plan->todo == NF_TODO_TRAIN ? &sink : NULL,
                               &j->mem, &rep->stats, err);
    rendered = rendered && intake_ok(&j->intake, plan->pass, err);
    if (m)
        nf_guide_release(guide, m);
    t->model = NULL;
    t->guide_depth = fixed_depth;
    return ranks_agree(rendered, err);
}

int render_with_budget(tracer *t, nf_guide *guide, const budget_settings *bs, image *img,
                       budget_report *rep, tr_error *err)
{
    budget_job j;
    memset(&j, 0, sizeof j);
    memset(rep, 0, sizeof *rep);
    rep->depth_fixed = t->guide_depth != 0;
    int ok = job_start(&j, t, guide, bs, img, err);
    const nf_reduce *red = j.hooks.reduce;
    while (ok) {
        double t0 = now_seconds(), c0 = cpu_seconds();
        nf_pass_plan plan;
        if (nf_schedule_next(j.schedule, t0 - bs->start, red, &plan) != NF_OK) {
            ok = tr_fail(err, "%s", nf_last_error_message());
            break;
        }
        if (plan.todo == NF_TODO_STOP)
            break;
        if (!(ok = job_render(&j, t, guide, bs, &plan, rep, err)))
            break;
        double t1 = now_seconds(), cpu = cpu_seconds() - c0;
        if (nf_schedule_add_pass(j.schedule, &plan, j.rgb, j.moment, t1 - t0, cpu, red) !=
            NF_OK) {
            ok = tr_fail(err, "%s", nf_last_error_message());
            break;
        }
        if (plan.todo != NF_TODO_TRAIN)
            continue;
        ok = train_on_pass(guide, bs->threads, plan.pass, rep, err) &&
             (ranks_size() == 1 ||
              models_agree_across_ranks(nf_guide_training_model(guide), (int)plan.pass + 1, err));
        rep->train_seconds += now_seconds() - t0;
        rep->step_seconds += now_seconds() - t1;
    }
    /* Each rank combines its pixels; rank 0 receives the others' (each pixel is one rank's:
     * exact sums). */
    ok = ok && (nf_schedule_combine(j.schedule, red, img->data, &rep->sched) == NF_OK ||
                tr_fail(err, "%s", nf_last_error_message()));
    ok = ok && ranks_sum_floats_to_root(img->data, 3 * (size_t)img->width * img->height, err) &&
         ranks_sum_u64((uint64_t *)&rep->stats, sizeof rep->stats / sizeof(uint64_t), err) &&
         ranks_sum_u64(&rep->samples, 1, err);
    rep->seconds = now_seconds() - bs->start;
    t->model = NULL;
    job_free(&j);
    return ok;
}
