/*
 * job.h - the steps nf_tracer and nf_paper share around their render: the command line
 * parsed and agreed between the ranks, the outputs checked before any work, the scene loaded
 * (the same on every rank), the reference, the tracer and the model it starts from; at the
 * end the outputs written. Every step is collective (ranks.h): all ranks take it and fail it
 * together, and rank 0 alone prints a failure.
 */
#ifndef TRACER_JOB_H
#define TRACER_JOB_H

#include <nisflow/nisflow.h>

#include "error.h"
#include "image.h"
#include "integrator.h"
#include "model_setup.h"
#include "options.h"
#include "scene.h"

typedef struct job {
    options o;
    char prefix[4096];  /* the outputs' path without its extension                   */
    scene s;
    int scene_loaded;
    image reference;    /* rank 0's; empty without --reference                        */
    tracer t;           /* its model is NULL: the programs set the one they render with */
    nf_model *model;    /* the model guiding starts from (NULL without guiding); the
                         * programs replace it by the trained one, which job_finish saves */
    prior_lookup lookup; /* what the BSDF prior's callbacks of every model here read */
    double t_start;     /* before the scene was loaded (now_seconds)                  */
    double t_job;       /* after it: a time budget counts from here                   */
} job;

/* A program's render: the image (allocated here, freed by the caller) and its statistics
 * from the prepared job; it may replace j->model by a trained one. On failure it returns 0
 * with the message in err and the step that failed ("training", "render") in *what. */
typedef int (*job_render_fn)(job *j, image *img, path_stats *stats, const char **what,
                             tr_error *err);

/* The whole process of `program`: the ranks started (ranks.h; only rank 0 prints), argv
 * parsed, the job prepared, `render` called, the outputs written, everything freed. Returns
 * main's exit code: 0; 2 for a bad command line; 1 for a failure, reported on stderr. */
int job_main(int argc, char **argv, options_program program, job_render_fn render);

#endif /* TRACER_JOB_H */
