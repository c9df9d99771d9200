/*
 * guide_help.c - the guide's own parallel-for (nisflow/guide.h, nf_guide_helpers): a
 * training call posts its step's tasks, runs them itself and lets render threads that call
 * nf_guide_help between their tiles take some. The library starts no thread: the caller
 * finishes every task nobody took, so a step never waits for a helper.
 */
#include "guide_internal.h"

/* Posts the job, runs tasks until none is left, waits for those that helpers took, then
 * closes the job and waits until no helper is inside it, so that the next job's fields are
 * never read by a helper of this one. */
static void nf_helpers_run(void *user, size_t count, nf_task_fn task, void *task_data)
{
    nf_guide *g = user;
    g->job_task = task;
    g->job_data = task_data;
    g->job_count = count;
    atomic_store(&g->job_next, (size_t)0);
    atomic_store(&g->job_done, (size_t)0);
    atomic_store(&g->job_open, 1);
    for (size_t i; (i = atomic_fetch_add(&g->job_next, (size_t)1)) < count;) {
        task(task_data, i);
        atomic_fetch_add(&g->job_done, (size_t)1);
    }
    /* Tasks that helpers took are short (a gradient group); wait for them. */
    while (atomic_load(&g->job_done) != count)
        ;
    atomic_store(&g->job_open, 0);
    while (atomic_load(&g->job_helpers) != 0u)
        ;
}

nf_parallel nf_guide_helpers(nf_guide *g)
{
    nf_parallel p = {NULL, NULL};
    if (g) {
        p.run = nf_helpers_run;
        p.user = g;
    }
    return p;
}

size_t nf_guide_help(nf_guide *g)
{
    if (!g || !atomic_load(&g->job_open))
        return 0;
    /* Count in, then check the job is still open: a run that closed it meanwhile may be
     * waiting for the count to fall, and must not have a helper read the next job's fields
     * before that job is posted (posting opens it after writing them). */
    atomic_fetch_add(&g->job_helpers, 1u);
    size_t ran = 0;
    if (atomic_load(&g->job_open)) {
        const size_t count = g->job_count;
        for (size_t i; (i = atomic_fetch_add(&g->job_next, (size_t)1)) < count; ++ran) {
            g->job_task(g->job_data, i);
            atomic_fetch_add(&g->job_done, (size_t)1);
        }
    }
    atomic_fetch_sub(&g->job_helpers, 1u);
    return ran;
}
