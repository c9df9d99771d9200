/*
 * report.c - nf_bench's output (see report.h): the results as a table in plain text or
 * Markdown, the targets of docs/performance.md met or missed, and the JSON file.
 *
 * The formats are read by people and by scripts that compare runs: keep the columns, the
 * row order and the JSON field names as they are.
 */
#include "report.h"

#include <stdio.h>
#include "shading_point.h"

/* s as a JSON string: quotes, backslashes and control characters escaped (a label or a CPU
 * name can hold any of them). */
static void json_string(FILE *f, const char *s)
{
    fputc('"', f);
    for (; *s; ++s) {
        unsigned char ch = (unsigned char)*s;
        if (ch == '"' || ch == '\\')
            fprintf(f, "\\%c", ch);
        else if (ch < 0x20)
            fprintf(f, "\\u%04x", ch);
        else
            fputc(ch, f);
    }
    fputc('"', f);
}

/* The measured result of (preset, op, threads, batch); NULL when there is none. */
static const result *find_result(const result *res, size_t count, int preset, int op,
                                 int threads, size_t batch)
{
    for (size_t i = 0; i < count; ++i)
        if (res[i].preset == preset && res[i].op == op && res[i].threads == threads &&
            res[i].batch == batch && res[i].measured)
            return &res[i];
    return NULL;
}

/* The targets of docs/performance.md. Batched ops: small preset, batch 4096 (and the n = 1
 * streams against it). Shading points: per-call latencies of the small preset on 1 thread,
 * the vertex of the large preset, and the vertex's 2-thread scaling (small preset, as the
 * other scaling targets). */
size_t evaluate_targets(const result *res, size_t count, target *t)
{
    size_t k = 0;
    static const char *const abs_name[OP_BATCHED_COUNT] = {
        "sample, 1 thread, batch 4096 (ns/sample)", "pdf, 1 thread, batch 4096 (ns/sample)",
        "train, 1 thread, batch 4096 (ns/sample)", "guide, 1 thread, batch 4096 (ns/sample)"};
    static const double abs_limit[OP_BATCHED_COUNT] = {150.0, 150.0, 600.0, 600.0};
    static const char *const n1_name[OP_BATCHED_COUNT] = {
        "sample, n=1 / batch 4096 (1 thread)", "pdf, n=1 / batch 4096 (1 thread)",
        "train, n=1 / batch 4096 (1 thread)", "guide, n=1 / batch 4096 (1 thread)"};
    static const char *const sc_name[OP_BATCHED_COUNT] = {
        "sample, 2 threads / 1 thread, batch 4096", "pdf, 2 threads / 1 thread, batch 4096",
        "train, 2 threads / 1 thread, batch 4096", "guide, 2 threads / 1 thread, batch 4096"};
    static const double sc_limit[OP_BATCHED_COUNT] = {1.8, 1.8, 1.6, 1.8};
    for (int op = 0; op < OP_BATCHED_COUNT; ++op) {
        const result *b = find_result(res, count, 0, op, 1, 4096);
        t[k++] = (target){0, abs_name[op], b ? b->ns_median : 0.0, abs_limit[op], 0, b != NULL};
    }
    for (int op = 0; op < OP_BATCHED_COUNT; ++op) {
        const result *b = find_result(res, count, 0, op, 1, 4096);
        const result *s = find_result(res, count, 0, op, 1, 1);
        t[k++] = (target){0, n1_name[op], b && s ? s->ns_median / b->ns_median : 0.0, 2.0, 0,
                          b && s};
    }
    for (int op = 0; op < OP_BATCHED_COUNT; ++op) {
        const result *b = find_result(res, count, 0, op, 1, 4096);
        const result *s = find_result(res, count, 0, op, 2, 4096);
        t[k++] = (target){0, sc_name[op], b && s ? b->ns_median / s->ns_median : 0.0,
                          sc_limit[op], 1, b && s};
    }
    /* The shading-point ops are stored with batch 1 (n = 1 per call). */
    static const struct {
        int preset, op;
        const char *what;
        double limit;
    } point_abs[] = {
        {0, OP_PREPARE, "prepare, 1 thread (ns/call)", 100.0},
        {0, OP_POINT_SAMPLE, "point-sample, 1 thread (ns/call)", 70.0},
        {0, OP_POINT_PDF, "point-pdf, 1 thread (ns/call)", 60.0},
        {0, OP_VERTEX, "vertex, 1 thread (ns/vertex)", 220.0},
        {1, OP_VERTEX, "vertex, 1 thread (ns/vertex)", 600.0},
    };
    for (size_t i = 0; i < sizeof point_abs / sizeof point_abs[0]; ++i) {
        const result *r = find_result(res, count, point_abs[i].preset, point_abs[i].op, 1, 1);
        t[k++] = (target){point_abs[i].preset, point_abs[i].what, r ? r->ns_median : 0.0,
                          point_abs[i].limit, 0, r != NULL};
    }
    /* A vertex against a batch's sample of the same preset and run: the ratio a renderer that
     * cannot batch pays, comparable across machines. */
    static const double per_batch_limit[2] = {2.3, 3.0};
    for (int preset = 0; preset < 2; ++preset) {
        const result *v = find_result(res, count, preset, OP_VERTEX, 1, 1);
        const result *b = find_result(res, count, preset, OP_SAMPLE, 1, 4096);
        t[k++] = (target){preset, "vertex / sample at batch 4096, 1 thread",
                          v && b ? v->ns_median / b->ns_median : 0.0, per_batch_limit[preset], 0,
                          v && b};
    }
    const result *v1 = find_result(res, count, 0, OP_VERTEX, 1, 1);
    const result *v2 = find_result(res, count, 0, OP_VERTEX, 2, 1);
    t[k++] = (target){0, "vertex, 2 threads / 1 thread",
                      v1 && v2 ? v1->ns_median / v2->ns_median : 0.0, 1.8, 1, v1 && v2};
    return k;
}

static int target_met(const target *t)
{
    return t->higher_is_better ? t->value >= t->limit : t->value <= t->limit;
}

void print_targets(const target *t, size_t count)
{
    int any = 0;
    for (size_t i = 0; i < count; ++i)
        any |= t[i].available;
    if (!any)
        return;
    printf("\ntargets (docs/performance.md):\n");
    for (size_t i = 0; i < count; ++i) {
        if (!t[i].available)
            continue;
        printf("  %-5s %-44s %9.2f  %s %6.2f  %s\n", PRESET_NAME[t[i].preset], t[i].what,
               t[i].value, t[i].higher_is_better ? ">=" : "<=", t[i].limit,
               target_met(&t[i]) ? "met" : "MISSED");
    }
}

/* The thread columns of a table's header: ns (per `unit`) and GFLOP/s per thread count,
 * then the 2T/1T scaling, and the Markdown separator row after `lead` ("|---|..." of the
 * leading columns). */
static void print_thread_header(FILE *f, int md, const options *o, const char *unit,
                                int has_scaling, const char *lead)
{
    for (int ti = 0; ti < o->thread_count; ++ti) {
        char h1[32], h2[32];
        snprintf(h1, sizeof h1, "%s %dT", unit, o->threads[ti]);
        snprintf(h2, sizeof h2, "GFLOP/s %dT", o->threads[ti]);
        if (md)
            fprintf(f, " | %s | %s", h1, h2);
        else
            fprintf(f, " | %11s %10s", h1, h2);
    }
    if (has_scaling)
        fprintf(f, md ? " | %s" : " | %5s", "2T/1T");
    fprintf(f, md ? " |\n" : "\n");
    if (md) {
        fprintf(f, "%s", lead);
        for (int ti = 0; ti < o->thread_count; ++ti)
            fprintf(f, "--:|--:|");
        fprintf(f, has_scaling ? "--:|\n" : "\n");
    }
}

/* The thread columns of one row (preset, op, batch), ending the line; *marked is set when a
 * figure is flagged as disturbed. */
static void print_thread_cells(FILE *f, int md, const options *o, const preset_info *info,
                               const result *res, size_t count, int preset, int op,
                               size_t batch, int has_scaling, int *marked)
{
    const result *r1 = NULL, *r2 = NULL;
    for (int ti = 0; ti < o->thread_count; ++ti) {
        const result *r = find_result(res, count, preset, op, o->threads[ti], batch);
        if (ti == 0)
            r1 = r;
        else
            r2 = r;
        if (r) {
            int busy = r->disturbed;
            double gf = flops_per_sample(&info[preset], op) / r->ns_median;
            if (md)
                fprintf(f, " | %.1f%s | %.2f", r->ns_median, busy ? "\\*" : "", gf);
            else
                fprintf(f, " | %10.1f%c %10.2f", r->ns_median, busy ? '*' : ' ', gf);
            *marked |= busy;
        } else {
            fprintf(f, md ? " | n/a | n/a" : " | %11s %10s", "n/a", "n/a");
        }
    }
    if (has_scaling) {
        if (r1 && r2)
            fprintf(f, md ? " | %.2fx" : " | %4.2fx", r1->ns_median / r2->ns_median);
        else
            fprintf(f, md ? " | n/a" : " | %5s", "n/a");
    }
    fprintf(f, md ? " |\n" : "\n");
}

/* The results: plain text (md = 0) or Markdown (md = 1) for docs/performance.md. Two
 * tables: the batched ops, a row per batch size; then the shading-point ops, per-call
 * latencies with no batch size, a row per op. Each is printed when --op selected any of its
 * ops. */
void print_table(FILE *f, int md, const options *o, const preset_info *info,
                 const size_t *batches, size_t batch_count, const result *res, size_t count)
{
    int has_scaling = o->thread_count == 2 && o->threads[0] == 1;
    int marked = 0;
    if (o->op_mask & OP_MASK_BATCHED) {
        if (md)
            fprintf(f, "| preset | op | batch");
        else
            fprintf(f, "%-6s %-6s %6s", "preset", "op", "batch");
        print_thread_header(f, md, o, "ns/smp", has_scaling, "|---|---|--:|");
        for (int pi = 0; pi < o->preset_count; ++pi) {
            int preset = o->presets[pi];
            for (int op = 0; op < OP_BATCHED_COUNT; ++op) {
                if (!(o->op_mask & (1 << op)))
                    continue;
                for (size_t bi = 0; bi < batch_count; ++bi) {
                    if (md)
                        fprintf(f, "| %s | %s | %zu", PRESET_NAME[preset], OP_NAME[op],
                                batches[bi]);
                    else
                        fprintf(f, "%-6s %-6s %6zu", PRESET_NAME[preset], OP_NAME[op],
                                batches[bi]);
                    print_thread_cells(f, md, o, info, res, count, preset, op, batches[bi],
                                       has_scaling, &marked);
                }
            }
        }
    }
    if (o->op_mask & OP_MASK_POINT) {
        if (o->op_mask & OP_MASK_BATCHED)
            fprintf(f, "\n");
        if (md)
            fprintf(f, "Shading points (`nf_point_*`, one call with n = 1 each, ns per call; "
                       "`vertex` = `nf_point_prepare` + `nf_point_sample_and_pdf` (a draw and "
                       "another direction's density), `vertex-calls` = `nf_point_prepare` + "
                       "`nf_point_sample` + `nf_point_pdf`, ns per vertex):\n\n| preset | op");
        else
            fprintf(f, "shading points (n = 1 per call, ns per call; vertex = prepare + "
                       "sample_and_pdf, vertex-calls = prepare + point-sample + point-pdf of\n"
                       "another direction, ns per vertex):\n"
                       "%-6s %-12s",
                    "preset", "op");
        print_thread_header(f, md, o, "ns/call", has_scaling, "|---|---|");
        for (int pi = 0; pi < o->preset_count; ++pi) {
            int preset = o->presets[pi];
            for (int op = OP_BATCHED_COUNT; op < OP_COUNT; ++op) {
                if (!(o->op_mask & (1 << op)))
                    continue;
                if (md)
                    fprintf(f, "| %s | %s", PRESET_NAME[preset], OP_NAME[op]);
                else
                    fprintf(f, "%-6s %-12s", PRESET_NAME[preset], OP_NAME[op]);
                print_thread_cells(f, md, o, info, res, count, preset, op, 1, has_scaling,
                                   &marked);
            }
        }
    }
    if (marked)
        fprintf(f,
                "%s disturbed: other processes used more than the idle CPUs + %.1f during this "
                "measurement (the quietest of up to %d attempts); an upper bound\n",
                md ? "\n\\*" : "*", o->busy_threshold, o->retries + 1);
}

int write_markdown(const options *o, const preset_info *info, const size_t *batches,
                   size_t batch_count, const result *res, size_t count)
{
    FILE *md = fopen(o->markdown_path, "w");
    if (!md) {
        fprintf(stderr, "nf_bench: cannot write %s\n", o->markdown_path);
        return -1;
    }
    print_table(md, 1, o, info, batches, batch_count, res, count);
    if (fclose(md) != 0) {
        fprintf(stderr, "nf_bench: error writing %s\n", o->markdown_path);
        return -1;
    }
    return 0;
}

int write_json(const options *o, const char *cpu, long nproc, const preset_info *info,
               const result *res, size_t count, const target *t, size_t tcount, long rss_kib,
               double wall_s, double other_load)
{
    FILE *f = fopen(o->json_path, "w");
    if (!f) {
        fprintf(stderr, "nf_bench: cannot write %s\n", o->json_path);
        return -1;
    }
    fprintf(f, "{\n  \"library_version\": ");
    json_string(f, nf_version_string());
    fprintf(f, ",\n  \"label\": ");
    json_string(f, o->label ? o->label : "");
    fprintf(f, ",\n  \"cpu\": ");
    json_string(f, cpu);
    fprintf(f, ",\n  \"online_cpus\": %ld,\n  \"prior\": ", nproc);
    json_string(f, o->prior_name);
    fprintf(f, ",\n  \"phi_map\": ");
    json_string(f, o->phi_map_name);
    fprintf(f,
            ",\n  \"quick\": %s,\n  \"reps\": %d,\n  \"min_rep_ms\": %.1f,\n"
            "  \"batch1_stream_calls\": %u,\n"
            "  \"flop_count\": \"2 * multiply-adds of the conditioner MLPs, input layer with "
            "one-blob sparsity exploited; training = 3 x forward; prepare = the context's "
            "share of the input layers, point-sample and point-pdf = the rest, vertex and "
            "vertex-calls = prepare + 2 directions\",\n"
            "  \"point_ops\": \"prepare, point-sample, point-pdf, vertex and vertex-calls are "
            "calls with n = 1 (batch 1); ns_per_sample is per call, for vertex per guided "
            "vertex (nf_point_prepare + nf_point_sample_and_pdf), for vertex-calls per vertex "
            "of three calls (nf_point_prepare + nf_point_sample + nf_point_pdf)\",\n"
            "  \"presets\": [",
            o->quick ? "true" : "false", o->reps, o->min_rep_s * 1e3, NFB_STREAM);
    for (int pi = 0; pi < o->preset_count; ++pi) {
        const preset_info *p = &info[o->presets[pi]];
        fprintf(f,
                "%s\n    {\"name\": \"%s\", \"coupling_layers\": %u, \"spline_bins\": %u, "
                "\"hidden_layers\": %u, \"hidden_width\": %u, \"params\": %zu, "
                "\"model_bytes\": %zu, \"forward_flops_sparse\": %.0f, "
                "\"forward_flops_dense\": %.0f, \"train_flops\": %.0f, "
                "\"prepare_flops\": %.0f, \"point_direction_flops\": %.0f, "
                "\"sharded_gradient_rel_diff\": %.2e, \"point_check_inputs\": %zu, "
                "\"point_check_mismatches\": %zu, \"point_check_worst_pdf_rel_diff\": %.2e, "
                "\"kernels\": \"%s\"}",
                pi ? "," : "", p->name, p->cfg.coupling_layers, p->cfg.spline_bins,
                p->cfg.hidden_layers, p->cfg.hidden_width, p->params, p->model_bytes,
                p->flops_sparse, p->flops_dense, 3.0 * p->flops_sparse,
                flops_per_sample(p, OP_PREPARE), flops_per_sample(p, OP_POINT_SAMPLE),
                p->shard_check, p->point_checked, p->point_mismatches, p->point_worst, p->isa);
    }
    fprintf(f, "\n  ],\n  \"results\": [");
    int first = 1;
    for (size_t i = 0; i < count; ++i) {
        const result *r = &res[i];
        fprintf(f, "%s\n    {\"preset\": \"%s\", \"op\": \"%s\", \"threads\": %d, \"batch\": %zu",
                first ? "" : ",", PRESET_NAME[r->preset], OP_NAME[r->op], r->threads,
                r->batch);
        first = 0;
        if (!r->measured) {
            fprintf(f, ", \"ns_per_sample\": null, \"note\": \"not applicable\"}");
            continue;
        }
        double fl = flops_per_sample(&info[r->preset], r->op);
        fprintf(f,
                ", \"ns_per_sample\": %.3f, \"ns_min\": %.3f, \"ns_max\": %.3f, "
                "\"samples_per_second\": %.1f, \"gflops\": %.3f, \"reps\": %d, "
                "\"samples_per_rep\": %zu, \"other_load_cpus\": %.3f, \"disturbed\": %s, "
                "\"attempts\": %d}",
                r->ns_median, r->ns_min, r->ns_max, 1e9 / r->ns_median, fl / r->ns_median,
                r->reps, r->samples_per_rep, r->foreign_cpus, r->disturbed ? "true" : "false",
                r->attempts);
    }
    fprintf(f, "\n  ],\n  \"targets\": [");
    first = 1;
    for (size_t i = 0; i < tcount; ++i) {
        if (!t[i].available)
            continue;
        fprintf(f, "%s\n    {\"preset\": \"%s\", \"what\": ", first ? "" : ",",
                PRESET_NAME[t[i].preset]);
        first = 0;
        json_string(f, t[i].what);
        fprintf(f, ", \"value\": %.3f, \"limit\": \"%s %.2f\", \"met\": %s}", t[i].value,
                t[i].higher_is_better ? ">=" : "<=", t[i].limit,
                target_met(&t[i]) ? "true" : "false");
    }
    fprintf(f,
            "\n  ],\n  \"peak_rss_kib\": %ld,\n  \"wall_seconds\": %.1f,\n"
            "  \"other_load_cpus\": %.3f\n}\n",
            rss_kib, wall_s, other_load);
    if (fclose(f) != 0) {
        fprintf(stderr, "nf_bench: error writing %s\n", o->json_path);
        return -1;
    }
    return 0;
}
