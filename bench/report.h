/*
 * report.h - nf_bench's output: the results table (plain text on stdout, or Markdown for
 * docs/performance.md), the targets of docs/performance.md, and the JSON file of a run.
 */
#ifndef NF_BENCH_REPORT_H
#define NF_BENCH_REPORT_H

#include <stddef.h>
#include <stdio.h>

#include "cases.h"
#include "common.h"
#include "setup.h"

/* One target of docs/performance.md: a figure of the run against its limit. */
typedef struct target {
    int preset;
    const char *what;
    double value, limit;
    int higher_is_better;
    int available; /* 0: the run did not measure what the target needs */
} target;

#define NFB_MAX_TARGETS 32

/* The targets, evaluated on the results res[0 .. count) into t (NFB_MAX_TARGETS at most);
 * returns how many. */
size_t evaluate_targets(const result *res, size_t count, target *t);

/* The available targets on stdout, each met or MISSED; nothing when none is available. */
void print_targets(const target *t, size_t count);

/* The results: plain text (md = 0) or Markdown (md = 1). info is indexed by preset; batches
 * are the batch sizes measured. */
void print_table(FILE *f, int md, const options *o, const preset_info *info,
                 const size_t *batches, size_t batch_count, const result *res, size_t count);

/* The Markdown table into o->markdown_path. -1 when it cannot be written (reported). */
int write_markdown(const options *o, const preset_info *info, const size_t *batches,
                   size_t batch_count, const result *res, size_t count);

/* The whole run into o->json_path: the machine, the presets, every result, the available
 * targets, the peak RSS, the wall time and other processes' load. -1 when it cannot be
 * written (reported). */
int write_json(const options *o, const char *cpu, long nproc, const preset_info *info,
               const result *res, size_t count, const target *t, size_t tcount, long rss_kib,
               double wall_s, double other_load);

#endif /* NF_BENCH_REPORT_H */
