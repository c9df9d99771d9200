/*
 * options.h - the command line of nf_tracer (nf_tracer --help prints it).
 */
#ifndef TRACER_OPTIONS_H
#define TRACER_OPTIONS_H

#include <stdint.h>

#include "error.h"
#include "guide.h"

typedef struct options {
    const char *scene;
    const char *out;          /* as given; NULL: out/<scene name>                             */
    const char *reference;
    const char *save_model, *load_model;
    guide_prior prior;
    int prior_given;
    int large_model;
    int phi_interval;         /* --phi-map interval: NF_PHI_INTERVAL instead of the default  */
    float learning_rate;
    int learning_rate_given;
    int iterations;
    int batch;                /* training paths per iteration                                 */
    int eval_every, eval_spp, spp, spp_given;
    int width, height;        /* 0: the scene's film                                          */
    int max_depth;            /* -2: the scene's                                              */
    int threads;
    uint64_t seed;
    float guide_prob;
    float prior_epsilon;      /* cosine/bsdf defensive mixture weight; < 0: the library's     */
    int sh_bands;             /* the context's normal/wo encoding bands; < 0: the preset's    */
    int guiding;
    int reference_mode;
    float exposure;
    /* The time-budgeted job (budget.h); time_budget 0: iterations, then spp.              */
    float time_budget;        /* seconds, from after the scene is loaded                      */
    float train_fraction;     /* at most this share of the budget trains                      */
    int step_samples;         /* training samples per optimizer step                          */
    int steps_per_pass;       /* optimizer steps after each training pass                     */
    int patience;             /* passes without a better loss before training stops, 0 never  */
    int combine;              /* 0: --no-combine, training passes left out of the image       */
    float clamp_quantile;     /* 0: training weights unclamped                                */
    int learn_selection;      /* --learn-selection                                            */
    int relative_training;    /* --relative-training                                          */
    float selection_cost;     /* --selection-cost; < 0: the default                          */
    int mis_training;         /* --mis-training                                               */
    int plain_mixture;        /* --plain-mixture                                              */
    int no_batching;          /* --no-batching                                                */
    int light_mis_bsdf;       /* --light-mis-bsdf                                             */
    float guide_min_roughness; /* --guide-min-roughness                                      */
    float guide_max_boost;     /* --guide-max-boost; 0: none                                 */
    int throughput_roulette;   /* --throughput-roulette                                      */
    int guide_depth;          /* guide vertices up to this depth (segments), 0: all           */
    int light_mis_depth;      /* --light-mis-depth; 0: the mixture's weighting at every depth */
    int help;
} options;

/* Fills the defaults, then parses argv. Returns 0 with a message on a bad command line. */
int options_parse(int argc, char **argv, options *o, tr_error *err);
void options_print_help(const char *program);

/* A hash of the command line less the options that may differ between the machines of one
 * distributed job (--threads, --scene, --out, --reference, --save-model, --load-model,
 * --exposure): ranks whose hashes differ were asked for different jobs (docs/distributed.md). */
uint64_t options_job_hash(int argc, char **argv);

#endif /* TRACER_OPTIONS_H */
