/*
 * options.h - the command lines of nf_tracer (a render in a time budget) and nf_paper (the
 * paper's protocol: training iterations, then a fixed number of samples per pixel); --help
 * prints each. The two share every option but their protocol's own.
 */
#ifndef TRACER_OPTIONS_H
#define TRACER_OPTIONS_H

#include <stdint.h>

#include "error.h"
#include "model_setup.h"

/* Which program parses: each refuses the other's protocol options, naming the program that
 * takes them. */
typedef enum options_program { OPTIONS_TRACER, OPTIONS_PAPER } options_program;

typedef struct options {
    options_program program;
    const char *scene;
    const char *out;          /* as given; NULL: out/<scene name>                             */
    const char *reference;
    const char *save_model, *load_model;
    model_prior prior;
    int prior_given;
    int large_model;
    float learning_rate;
    int learning_rate_given;
    int iterations;
    int batch;                /* training paths per iteration                                 */
    int eval_every, eval_spp, spp, spp_given;
    int width, height;        /* 0: the scene's film                                          */
    int max_depth;            /* -2: the scene's                                              */
    int threads;
    nf_isa isa;               /* the library's kernels (NF_ISA_AUTO: the best the CPU runs)    */
    uint64_t seed;
    int guiding;
    int reference_mode;
    float exposure;
    float time_budget;        /* nf_tracer: seconds, from after the scene is loaded (30)     */
    /* The guide: the library's defaults (nf_guide_config_init), which --variant changes. */
    nf_guide_config guide;
    /* The model and the integrator, also changed by --variant only: */
    int phi_interval;         /* NF_PHI_INTERVAL instead of the library's NF_PHI_CIRCULAR    */
    float prior_epsilon;      /* cosine/bsdf defensive mixture weight; < 0: the library's     */
    int sh_bands;             /* the context's normal/wo encoding bands (default 0)           */
    int mis_training;         /* 1 (default): train on the MIS-weighted emission              */
    int no_batching, light_mis_bsdf, guide_depth; /* ablation switches (integrator.h)       */
    const char *variants;     /* --variant as given, for the report; NULL: none              */
    int help, list_variants;
} options;

/* Fills the defaults, then parses argv for `program`. Returns 0 with a message on a bad
 * command line.
 * The defaults are the best configuration docs/equal-time.md measured: the library's guide
 * defaults, a position-only model input (0 SH bands), training on the MIS-weighted emission.
 * Everything else an experiment may want is a --variant (options_print_variants). */
int options_parse(int argc, char **argv, options_program program, options *o, tr_error *err);
/* "nf_tracer" or "nf_paper", for messages. */
const char *options_program_name(options_program program);
/* The help of `program`; `name` is how it was started (argv[0]). */
void options_print_help(options_program program, const char *name);
/* The table of --variant settings, one per line (nf_tracer --variant list). */
void options_print_variants(void);

/* A hash of the command line less the options that may differ between the machines of one
 * distributed job (--threads, --scene, --out, --reference, --save-model, --load-model,
 * --exposure): ranks whose hashes differ were asked for different jobs (docs/distributed.md). */
uint64_t options_job_hash(int argc, char **argv);

#endif /* TRACER_OPTIONS_H */
