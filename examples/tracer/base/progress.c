/*
 * progress.c - the progress bar of progress.h.
 */
#include "progress.h"

#include <stdio.h>
#include <time.h>
#include <unistd.h>

double now_seconds(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

double cpu_seconds(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

void progress_start(progress *p, const char *label, size_t total)
{
    p->label = label;
    p->total = total;
    p->start = now_seconds();
    p->last_draw = 0.0;
    p->shown = 0;
    p->enabled = label != NULL && isatty(fileno(stderr));
}

void progress_update(progress *p, size_t done, const char *extra)
{
    if (!p->enabled)
        return;
    double t = now_seconds(), elapsed = t - p->start;
    if (elapsed < 1.0 || (t - p->last_draw < 0.1 && done < p->total))
        return;
    p->last_draw = t;
    p->shown = 1;
    enum { WIDTH = 30 };
    double frac = p->total ? (double)done / (double)p->total : 1.0;
    int fill = (int)(frac * WIDTH + 0.5);
    char bar[WIDTH + 1];
    for (int i = 0; i < WIDTH; ++i)
        bar[i] = i < fill ? '#' : '.';
    bar[WIDTH] = '\0';
    double eta = frac > 0.0 ? elapsed * (1.0 - frac) / frac : 0.0;
    fprintf(stderr, "\r%-10s [%s] %3d%% %zu/%zu  %.0fs, %.0fs left  %s\033[K", p->label, bar,
            (int)(100.0 * frac + 0.5), done, p->total, elapsed, eta, extra ? extra : "");
    fflush(stderr);
}

void progress_finish(progress *p)
{
    if (p->enabled && p->shown) {
        fprintf(stderr, "\r\033[K");
        fflush(stderr);
    }
    p->shown = 0;
}
