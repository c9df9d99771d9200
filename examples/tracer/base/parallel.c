/*
 * parallel.c - the work queue of parallel.h.
 */
#include "parallel.h"

#include <pthread.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "progress.h"

typedef struct queue {
    parallel_fn fn;
    void *user;
    size_t n;
    atomic_size_t next, done;
} queue;

typedef struct worker {
    queue *q;
    int index;
} worker;

static void *worker_main(void *arg)
{
    worker *w = arg;
    queue *q = w->q;
    for (;;) {
        size_t i = atomic_fetch_add(&q->next, 1);
        if (i >= q->n)
            break;
        q->fn(q->user, i, w->index);
        atomic_fetch_add(&q->done, 1);
    }
    return NULL;
}

int parallel_for(size_t n, int threads, parallel_fn fn, void *user, const char *progress_label,
                 tr_error *err)
{
    queue q;
    q.fn = fn;
    q.user = user;
    q.n = n;
    atomic_init(&q.next, 0);
    atomic_init(&q.done, 0);
    if (threads < 1)
        threads = 1;
    if ((size_t)threads > n)
        threads = n > 0 ? (int)n : 1;
    if (threads == 1 && !progress_label) { /* one worker: this thread, without starting one */
        worker w;
        w.q = &q;
        w.index = 0;
        worker_main(&w);
        return 1;
    }
    pthread_t *ids = calloc((size_t)threads, sizeof *ids);
    worker *ws = calloc((size_t)threads, sizeof *ws);
    if (!ids || !ws) {
        free(ids);
        free(ws);
        return tr_fail(err, "out of memory");
    }
    int started = 0;
    for (int t = 0; t < threads; ++t) {
        ws[t].q = &q;
        ws[t].index = t;
        if (pthread_create(&ids[t], NULL, worker_main, &ws[t]) != 0)
            break; /* the threads that did start do all the work */
        ++started;
    }
    if (started == 0) { /* no thread at all: do the work here */
        ws[0].q = &q;
        ws[0].index = 0;
        worker_main(&ws[0]);
    }
    progress bar;
    progress_start(&bar, progress_label, n);
    /* Poll only when a bar is drawn: otherwise joining right away costs no latency. */
    while (bar.enabled && started > 0 && atomic_load(&q.done) < n) {
        struct timespec ts = {0, 50 * 1000 * 1000};
        nanosleep(&ts, NULL);
        progress_update(&bar, atomic_load(&q.done), NULL);
    }
    for (int t = 0; t < started; ++t)
        pthread_join(ids[t], NULL);
    progress_finish(&bar);
    free(ids);
    free(ws);
    return 1;
}

int processor_count(void)
{
    long n = sysconf(_SC_NPROCESSORS_ONLN);
    return n > 0 ? (int)n : 1;
}
