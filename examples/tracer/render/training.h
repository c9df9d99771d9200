/*
 * training.h - the online training loop (the paper's protocol): each iteration traces a
 * batch of paths with the current model, collects the training samples of their guided
 * vertices and takes one optimizer step (its gradient summed over threads and ranks by the
 * library's nf_guide_train_batch, model_setup.h); every eval_every iterations a whole image is
 * rendered at eval_spp and its MAPE appended to a CSV file.
 */
#ifndef TRACER_TRAINING_H
#define TRACER_TRAINING_H

#include <stdint.h>
#include <stdio.h>

#include <nisflow/nisflow.h>

#include "error.h"
#include "image.h"
#include "integrator.h"

typedef struct training_settings {
    int iterations;
    int batch;                /* training paths per iteration                       */
    int eval_every, eval_spp; /* eval_every 0: no evaluation                        */
    int threads;
    uint64_t seed;
    const image *reference;   /* NULL: the MAPE column stays empty                  */
    const nf_guide_config *guide; /* the step's settings; NULL: the library's defaults  */
    FILE *csv;                /* NULL: no CSV                                       */
} training_settings;

typedef struct training_report {
    uint64_t samples;         /* training samples passed to nf_train_step           */
    uint64_t paths;
    double trace_seconds;     /* tracing the training paths                         */
    double step_seconds;      /* inside nf_train_step                               */
    double trace_cpu_seconds; /* CPU time of all threads while tracing               */
    double step_cpu_seconds;  /* CPU time of the optimizer steps (all threads)        */
    int refused;              /* batches nf_train_step refused                      */
    float last_loss;
    path_stats stats;
} training_report;

/* Trains a guide made from *model and replaces *model by the trained model; t->model is the
 * guide's published model while it renders (NULL on return). Collective (ranks.h): every rank
 * traces its share of each batch and all take the same steps; rank 0 alone passes a
 * reference and a CSV. The report's samples are all ranks'; its times are this rank's. */
int train_guide(tracer *t, nf_model **model, const training_settings *ts,
                training_report *report, tr_error *err);

#endif /* TRACER_TRAINING_H */
