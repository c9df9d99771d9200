/*
 * nf_bench.c - the libnisflow benchmark: nanoseconds per sample of nf_sample, nf_pdf and
 * training, for the small and large presets, batch sizes 1, 64, 4096 and 65536, with 1 and 2
 * threads; the per-call latencies of the shading-point API (nisflow/point.h); the model's
 * FLOPs per sample, the achieved GFLOP/s and the peak memory.
 *
 * This file is the command line and main: it parses the options, builds each preset's model
 * and checks it (setup.c), runs the preset's cases (cases.c, which says what exactly is
 * timed and how), and prints and writes the results (report.c). common.h lists the parts.
 *
 * The benchmark assumes an otherwise idle machine; it measures how busy other processes kept
 * the CPUs, re-measures the cases they disturbed and flags those that stayed disturbed.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "cases.h"
#include "harness.h"
#include "common.h"
#include "report.h"
#include "setup.h"
#include "point_batch.h"
#include "direction_table.h"
#include "shading_point.h"

#define NFB_POOL 65536u     /* distinct inputs (a multiple of every batch size) */
#define NFB_MAX_RESULTS 256 /* room for every case of a run: 2 presets x 32 at most */

const char *const OP_NAME[OP_COUNT] = {"sample",    "pdf",          "train",
                                       "guide",     "prepare",      "point-sample",
                                       "point-pdf", "vertex",       "vertex-calls",
                                       "table-build", "table-vertex", "table-find",
                                       "cell-vertex"};
const char *const PRESET_NAME[2] = {"small", "large"};

/* ---- Command line ------------------------------------------------------------------------ */

static void usage(FILE *f)
{
    fprintf(f,
            "usage: nf_bench [options]\n"
            "  --preset small|large|all   presets to measure (default all)\n"
            "  --threads 1|2|all|N        thread counts (default all = 1 and 2)\n"
            "  --op LIST                  operations to measure, comma-separated (default\n"
            "                             all): sample, pdf, train, guide; the shading-point ops\n"
            "                             prepare, point-sample, point-pdf, vertex,\n"
            "                             vertex-calls, table-build, table-vertex,\n"
            "                             table-find, cell-vertex; point (those nine);\n"
            "                             all\n"
            "  --reps N                   timed repetitions, median reported (default 7)\n"
            "  --min-rep-ms X             minimum length of one repetition (default 50)\n"
            "  --prior NAME               cosine (default), uniform-direction,\n"
            "                             uniform-angle, or custom (a cosine lobe given as\n"
            "                             callbacks)\n"
            "  --phi-map NAME             circular (default) or interval (nf_config.phi_map)\n"
            "  --json FILE                write the results as JSON (default bench.json)\n"
            "  --markdown FILE            also write the table as Markdown\n"
            "  --label TEXT               a free-form label stored in the JSON and printed\n"
            "  --retries N                re-measure a case up to N times when other\n"
            "                             processes disturbed it (default 2)\n"
            "  --batch 1|64|4096|65536    measure only this batch size of sample, pdf and\n"
            "                             train (for profiling; the shading-point ops have\n"
            "                             none: select them or not with --op)\n"
            "  --isa auto|generic|avx2|avx512\n"
            "                             kernels to use (default auto, the library's choice)\n"
            "  --quick                    smoke run: batches 1, 64, 4096; 3 reps of >= 5 ms\n"
            "  --help                     this text\n"
            "Batch sizes 1, 64, 4096, 65536. Batch 1 is streams of calls with n = 1, in units\n"
            "of %u calls. The shading-point ops are such streams too, timed per call:\n"
            "prepare (nf_point_prepare on a new context), point-sample and point-pdf (one\n"
            "direction at a prepared point), vertex (prepare + nf_point_sample_and_pdf: a\n"
            "draw and another direction's density, per vertex), vertex-calls (the same as\n"
            "prepare + point-sample + point-pdf, per vertex), table-build (nf_table_build\n"
            "from a prepared point), table-vertex (nf_table_sample + nf_table_pdf of another\n"
            "direction on a built table, per vertex), table-find (nf_table_cache_find of a\n"
            "cell on the walls of the model's bounds whose table is built), cell-vertex (that\n"
            "find, then table-vertex's two calls on the table it found, per vertex).\n",
            NFB_STREAM);
}

/* *out = s when s is, as a whole, a decimal integer in [lo, hi]; else -1. */
static int parse_int(const char *s, int lo, int hi, int *out)
{
    char *end;
    long v = strtol(s, &end, 10);
    if (end == s || *end != '\0' || v < lo || v > hi)
        return -1;
    *out = (int)v;
    return 0;
}

/* --op: a comma-separated list of op names, "point" (the four shading-point ops) or "all". */
static int parse_ops(const char *list, int *mask)
{
    int m = 0;
    const char *s = list;
    for (;;) {
        size_t len = strcspn(s, ",");
        int found = 0;
        if (len == 3 && strncmp(s, "all", len) == 0) {
            m |= OP_MASK_ALL;
            found = 1;
        } else if (len == 5 && strncmp(s, "point", len) == 0) {
            m |= OP_MASK_POINT;
            found = 1;
        }
        for (int op = 0; op < OP_COUNT && !found; ++op) {
            if (strlen(OP_NAME[op]) == len && strncmp(s, OP_NAME[op], len) == 0) {
                m |= 1 << op;
                found = 1;
            }
        }
        if (!found)
            return -1; /* also an empty name: "", "a,,b", "a," */
        if (s[len] == '\0')
            break;
        s += len + 1;
    }
    *mask = m;
    return 0;
}

/* The values of --prior and --isa, and what each selects. */
static const char *const PRIOR_NAME[] = {"cosine", "uniform-direction", "uniform-angle",
                                         "custom"};
static const nf_prior_kind PRIOR[] = {NF_PRIOR_COSINE, NF_PRIOR_UNIFORM_DIRECTION,
                                      NF_PRIOR_UNIFORM_ANGLE, NF_PRIOR_CUSTOM};
static const char *const ISA_NAME[] = {"auto", "generic", "avx2", "avx512"};
static const nf_isa ISA[] = {NF_ISA_AUTO, NF_ISA_GENERIC, NF_ISA_AVX2, NF_ISA_AVX512};

#define NFB_COUNT_OF(a) ((int)(sizeof(a) / sizeof((a)[0])))

/* The index of name in names[0 .. count); -1 when it is none of them. */
static int find_name(const char *name, const char *const *names, int count)
{
    for (int k = 0; k < count; ++k)
        if (strcmp(name, names[k]) == 0)
            return k;
    return -1;
}

/* The options into *o, defaults first. --help prints the usage and exits; -1 on a bad
 * option, already reported (the caller adds the usage). */
static int parse_args(int argc, char **argv, options *o)
{
    memset(o, 0, sizeof *o);
    o->presets[0] = 0;
    o->presets[1] = 1;
    o->preset_count = 2;
    o->threads[0] = 1;
    o->threads[1] = 2;
    o->thread_count = 2;
    o->reps = -1;
    o->min_rep_s = -1.0;
    o->prior = NF_PRIOR_COSINE;
    o->prior_name = "cosine";
    o->phi_map = NF_PHI_CIRCULAR;
    o->phi_map_name = "circular";
    o->json_path = "bench.json";
    o->retries = 2;
    o->busy_threshold = 0.2;
    o->op_mask = OP_MASK_ALL;
    for (int i = 1; i < argc; ++i) {
        const char *a = argv[i];
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) {
            usage(stdout);
            exit(EXIT_SUCCESS);
        } else if (strcmp(a, "--quick") == 0) {
            o->quick = 1;
            continue;
        }
        if (!v) {
            fprintf(stderr, "nf_bench: unknown option or missing value: %s\n", a);
            return -1;
        }
        ++i;
        if (strcmp(a, "--preset") == 0) {
            if (strcmp(v, "small") == 0) {
                o->presets[0] = 0;
                o->preset_count = 1;
            } else if (strcmp(v, "large") == 0) {
                o->presets[0] = 1;
                o->preset_count = 1;
            } else if (strcmp(v, "all") == 0) {
                o->preset_count = 2;
            } else {
                fprintf(stderr, "nf_bench: --preset takes small, large or all\n");
                return -1;
            }
        } else if (strcmp(a, "--threads") == 0) {
            int n;
            if (strcmp(v, "all") == 0) {
                o->threads[0] = 1;
                o->threads[1] = 2;
                o->thread_count = 2;
            } else if (parse_int(v, 1, NFB_MAX_THREADS, &n) == 0) {
                o->threads[0] = n;
                o->thread_count = 1;
            } else {
                fprintf(stderr, "nf_bench: --threads takes 1, 2, all or N in [1, %d]\n",
                        NFB_MAX_THREADS);
                return -1;
            }
        } else if (strcmp(a, "--reps") == 0) {
            if (parse_int(v, 1, 64, &o->reps) != 0) {
                fprintf(stderr, "nf_bench: --reps takes an integer in [1, 64]\n");
                return -1;
            }
        } else if (strcmp(a, "--min-rep-ms") == 0) {
            char *end;
            double ms = strtod(v, &end);
            if (end == v || *end != '\0' || !(ms > 0.0) || ms > 60000.0) {
                fprintf(stderr, "nf_bench: --min-rep-ms takes a number in (0, 60000]\n");
                return -1;
            }
            o->min_rep_s = ms * 1e-3;
        } else if (strcmp(a, "--prior") == 0) {
            int k = find_name(v, PRIOR_NAME, NFB_COUNT_OF(PRIOR_NAME));
            if (k < 0) {
                fprintf(stderr, "nf_bench: unknown prior %s\n", v);
                return -1;
            }
            o->prior = PRIOR[k];
            o->prior_name = v;
        } else if (strcmp(a, "--phi-map") == 0) {
            if (strcmp(v, "circular") != 0 && strcmp(v, "interval") != 0) {
                fprintf(stderr, "nf_bench: --phi-map takes circular or interval\n");
                return -1;
            }
            o->phi_map = strcmp(v, "circular") == 0 ? NF_PHI_CIRCULAR : NF_PHI_INTERVAL;
            o->phi_map_name = v;
        } else if (strcmp(a, "--op") == 0) {
            if (parse_ops(v, &o->op_mask) != 0) {
                fprintf(stderr, "nf_bench: --op takes a comma-separated list of sample, pdf, "
                                "train, prepare, point-sample, point-pdf, vertex, vertex-calls, point, "
                                "all\n");
                return -1;
            }
        } else if (strcmp(a, "--isa") == 0) {
            int k = find_name(v, ISA_NAME, NFB_COUNT_OF(ISA_NAME));
            if (k < 0) {
                fprintf(stderr, "nf_bench: --isa takes auto, generic, avx2 or avx512\n");
                return -1;
            }
            o->isa = ISA[k];
        } else if (strcmp(a, "--batch") == 0) {
            int n;
            if (parse_int(v, 1, 65536, &n) != 0 || (n != 1 && n != 64 && n != 4096 && n != 65536)) {
                fprintf(stderr, "nf_bench: --batch takes 1, 64, 4096 or 65536\n");
                return -1;
            }
            o->batch = (size_t)n;
        } else if (strcmp(a, "--retries") == 0) {
            if (parse_int(v, 0, 10, &o->retries) != 0) {
                fprintf(stderr, "nf_bench: --retries takes an integer in [0, 10]\n");
                return -1;
            }
        } else if (strcmp(a, "--json") == 0) {
            o->json_path = v;
        } else if (strcmp(a, "--markdown") == 0) {
            o->markdown_path = v;
        } else if (strcmp(a, "--label") == 0) {
            o->label = v;
        } else {
            fprintf(stderr, "nf_bench: unknown option %s\n", a);
            return -1;
        }
    }
    if (o->reps < 0)
        o->reps = o->quick ? 3 : 7;
    if (o->min_rep_s < 0.0)
        o->min_rep_s = o->quick ? 5e-3 : 50e-3;
    return 0;
}

/* ---- A preset's start -------------------------------------------------------------------- */

/* Prints the preset's model, draws the directions that pdf and training use (the model's own
 * samples), and runs the start-up checks, printing what they found. A check's failed call is
 * an error (-1, reported); results that differ are a warning, and the figures still come. */
static int start_preset(const options *o, const nf_model *model, bench_data *data,
                        preset_info *inf)
{
    printf("\npreset %s: %u coupling layers, %u bins, %u x %u hidden; %zu params, model "
           "%.1f KiB; %s kernels;\n  forward FLOP/sample %.0f (one-blob sparse input) / "
           "%.0f (dense); training counted as 3x forward = %.0f\n",
           inf->name, inf->cfg.coupling_layers, inf->cfg.spline_bins, inf->cfg.hidden_layers,
           inf->cfg.hidden_width, inf->params, inf->model_bytes / 1024.0, inf->isa,
           inf->flops_sparse, inf->flops_dense, 3.0 * inf->flops_sparse);
    fflush(stdout);
    if (report_status(nf_sample(model, data->n, data->ctx, data->u, data->dir, data->out_pdf),
                      "nf_sample") != 0)
        return -1;
    double shard_rel = 0.0;
    if (check_sharding(model, data, 4096, inf->params, &shard_rel) != 0)
        return -1;
    printf("  sharded gradient check (2 halves of 4096 samples vs the whole batch): max "
           "relative difference %.1e%s\n",
           shard_rel, shard_rel > 1e-4 ? "  WARNING: larger than 1e-4" : "");
    inf->shard_check = shard_rel;
    if (o->op_mask & OP_MASK_POINT) {
        /* data->dir and data->out_pdf still hold the nf_sample results of above. */
        inf->point_checked = data->n < 4096 ? data->n : 4096;
        if (check_points(model, data, inf->point_checked, &inf->point_mismatches,
                         &inf->point_worst) != 0)
            return -1;
        if (inf->point_mismatches) /* the presets' vector path (docs/architecture.md) */
            printf("  shading-point check: nf_point_sample / nf_point_pdf differ from "
                   "nf_sample / nf_pdf on %zu of %zu inputs, densities by %.2g at most\n",
                   inf->point_mismatches, inf->point_checked, inf->point_worst);
        else
            printf("  shading-point check (nf_point_sample / nf_point_pdf vs nf_sample / "
                   "nf_pdf, %zu inputs): bit-identical\n",
                   inf->point_checked);
    }
    fflush(stdout);
    return 0;
}

/* One gradient buffer per thread and their weighted sum, for `params` parameters, in place
 * of the previous preset's: 64-byte aligned, so that no two threads share a cache line. */
static int alloc_gradients(float **grad, float **grad_sum, int threads, size_t params)
{
    size_t bytes = (params * sizeof(float) + 63u) / 64u * 64u; /* aligned_alloc's multiple */
    for (int k = 0; k < threads; ++k) {
        free(grad[k]);
        grad[k] = (float *)aligned_alloc(64, bytes);
    }
    free(*grad_sum);
    *grad_sum = (float *)aligned_alloc(64, bytes);
    int ok = *grad_sum != NULL;
    for (int k = 0; k < threads; ++k)
        ok &= grad[k] != NULL;
    if (!ok) {
        fprintf(stderr, "nf_bench: out of memory for gradients\n");
        return -1;
    }
    return 0;
}

/* ---- main -------------------------------------------------------------------------------- */

int main(int argc, char **argv)
{
    options o;
    if (parse_args(argc, argv, &o) != 0) {
        usage(stderr);
        return EXIT_FAILURE;
    }
    double t_start = now_s();
    cpu_snapshot run_start;
    take_cpu_snapshot(&run_start);
    size_t all_batches[] = {1, 64, 4096, 65536};
    size_t batch_count = o.quick ? 3 : 4;
    if (o.batch) {
        all_batches[0] = o.batch;
        batch_count = 1;
    }
    int max_threads = 1;
    for (int i = 0; i < o.thread_count; ++i)
        if (o.threads[i] > max_threads)
            max_threads = o.threads[i];

    char cpu[256];
    read_cpu_model(cpu, sizeof cpu);
    long nproc = sysconf(_SC_NPROCESSORS_ONLN);
    o.nproc = nproc > 0 ? nproc : 1;
    printf("libnisflow %s benchmark%s%s\n", nf_version_string(), o.label ? ": " : "",
           o.label ? o.label : "");
    printf("cpu: %s, %ld online CPUs; prior %s, phi map %s; median of %d reps, each >= %.0f "
           "ms%s\n",
           cpu, nproc, o.prior_name, o.phi_map_name, o.reps, o.min_rep_s * 1e3,
           o.quick ? " (quick)" : "");
    fflush(stdout);

    int rc = EXIT_FAILURE;
    counting_allocator ca;
    atomic_init(&ca.live, 0);
    atomic_init(&ca.peak, 0);
    preset_info info[2];
    memset(info, 0, sizeof info);
    result *res = (result *)calloc(NFB_MAX_RESULTS, sizeof *res);
    size_t res_count = 0;
    bench_data data;
    memset(&data, 0, sizeof data);
    nf_model *model = NULL;
    float *grad[NFB_MAX_THREADS] = {NULL};
    float *grad_sum = NULL;
    pool pl;
    memset(&pl, 0, sizeof pl);
    int pool_ok = 0;
    target targets[NFB_MAX_TARGETS];
    size_t target_count = 0;

    if (!res) {
        fprintf(stderr, "nf_bench: out of memory\n");
        goto done;
    }
    {
        nf_config cfg;
        nf_config_init(&cfg, NF_PRESET_SMALL); /* bounds are the same for both presets */
        size_t n = o.quick ? 4096u : NFB_POOL;
        if (bench_data_alloc(&data, n, &cfg) != 0) {
            fprintf(stderr, "nf_bench: out of memory for %zu inputs\n", n);
            goto done;
        }
    }
    if (max_threads > 1) {
        if (pool_create(&pl, max_threads) != 0) {
            fprintf(stderr, "nf_bench: cannot create the thread pool\n");
            goto done;
        }
        pool_ok = 1;
    }

    for (int pi = 0; pi < o.preset_count; ++pi) {
        int preset = o.presets[pi];
        preset_info *inf = &info[preset];
        if (make_model(preset, &o, &ca, inf, &model) != 0 ||
            start_preset(&o, model, &data, inf) != 0 ||
            alloc_gradients(grad, &grad_sum, max_threads, inf->params) != 0)
            goto done;
        case_env env = {&o, max_threads > 1 ? &pl : NULL, &data, model, preset, inf, grad,
                        grad_sum};
        if (run_preset_cases(&env, all_batches, batch_count, res, &res_count,
                             NFB_MAX_RESULTS) != 0)
            goto done;
        nf_model_destroy(model);
        model = NULL;
    }

    {
        long rss = peak_rss_kib();
        double wall = now_s() - t_start;
        cpu_snapshot run_end;
        take_cpu_snapshot(&run_end);
        double other = foreign_cpu_load(&run_start, &run_end);
        printf("\n");
        print_table(stdout, 0, &o, info, all_batches, batch_count, res, res_count);
        if (o.markdown_path &&
            write_markdown(&o, info, all_batches, batch_count, res, res_count) != 0)
            goto done;
        target_count = evaluate_targets(res, res_count, targets);
        print_targets(targets, target_count);
        printf("\npeak RSS %.1f MiB (bench inputs %.1f MiB, models at most %.1f KiB live); "
               "wall time %.1f s\n",
               rss / 1024.0, (double)bench_data_bytes(&data) / (1024.0 * 1024.0),
               atomic_load(&ca.peak) / 1024.0, wall);
        if (other >= 0.0)
            printf("other processes kept %.2f of %ld CPUs busy on average during the run%s\n",
                   other, nproc, other >= o.busy_threshold ? " (the machine was not idle)" : "");
        if (write_json(&o, cpu, nproc, info, res, res_count, targets, target_count, rss,
                       wall, other) != 0)
            goto done;
        printf("results written to %s\n", o.json_path);
    }
    rc = EXIT_SUCCESS;

done:
    nf_model_destroy(model);
    if (pool_ok)
        pool_destroy(&pl);
    for (int k = 0; k < NFB_MAX_THREADS; ++k)
        free(grad[k]);
    free(grad_sum);
    bench_data_free(&data);
    free(res);
    if (rc == EXIT_SUCCESS && atomic_load(&ca.live) != 0) {
        fprintf(stderr, "nf_bench: %zu bytes of model memory not freed\n",
                (size_t)atomic_load(&ca.live));
        rc = EXIT_FAILURE;
    }
    return rc;
}
