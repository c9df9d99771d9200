/*
 * progress.h - a progress bar on stderr for anything that takes more than a second.
 *
 * It appears only after the first second (short steps stay silent) and only when stderr is
 * a terminal (logs in CI stay clean); it redraws at most ten times per second.
 */
#ifndef TRACER_PROGRESS_H
#define TRACER_PROGRESS_H

#include <stddef.h>

typedef struct progress {
    const char *label;
    size_t total;
    double start, last_draw;
    int shown, enabled;
} progress;

/* Seconds on a monotonic clock, and CPU seconds used by the whole process (all threads):
 * on a shared machine the second shows the work done even when other jobs slow the first. */
double now_seconds(void);
double cpu_seconds(void);

/* label NULL disables the bar. */
void progress_start(progress *p, const char *label, size_t total);
/* `extra` (may be NULL) is printed after the counts, e.g. "loss 1.23". */
void progress_update(progress *p, size_t done, const char *extra);
/* Erases the bar if it was drawn. */
void progress_finish(progress *p);

#endif /* TRACER_PROGRESS_H */
