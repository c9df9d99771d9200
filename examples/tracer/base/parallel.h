/*
 * parallel.h - a minimal pthreads work queue: run fn(item) for items 0..n-1 on a number of
 * threads. Items are handed out in increasing order through an atomic counter, so the work
 * balances itself; results must not depend on which thread ran an item (the tracer's RNG
 * streams are per pixel and per path for exactly that reason). The calling thread draws the
 * progress bar while the workers run; with one thread and no bar it does the work itself,
 * without starting a thread (steps of a few microseconds are common: an empty gradient step,
 * a pass of a tiny film).
 */
#ifndef TRACER_PARALLEL_H
#define TRACER_PARALLEL_H

#include <stddef.h>

#include "error.h"

/* fn(user, item, thread_index). Returns 0 if a thread could not be started. */
typedef void (*parallel_fn)(void *user, size_t item, int thread);
int parallel_for(size_t n, int threads, parallel_fn fn, void *user, const char *progress_label,
                 tr_error *err);

/* The number of processors online (at least 1). */
int processor_count(void);

#endif /* TRACER_PARALLEL_H */
