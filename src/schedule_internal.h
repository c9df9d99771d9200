/*
 * schedule_internal.h - the schedule's memory (nisflow/schedule.h), shared by schedule.c (life
 * cycle and the plans), schedule_measure.c (what each kind of pass measures) and
 * schedule_combine.c (the image).
 */
#ifndef NISFLOW_SCHEDULE_INTERNAL_H
#define NISFLOW_SCHEDULE_INTERNAL_H

#include "nisflow/schedule.h"

#include "internal.h"

/* The render passes come in NF_KINDS kinds: guided passes by how deep they guide (the
 * guide's candidates: kind c guides up to depth c) and plain passes. */
#define NF_KINDS (NF_GUIDE_DEPTHS + 1u)
#define NF_PLAIN NF_GUIDE_DEPTHS
/* Training passes are kept in at most this many groups of equal size. */
#define NF_TRAIN_GROUPS 32
/* The relative variances use this epsilon (nf_guide_pass_variance), as relMSE does. */
#define NF_SCHEDULE_EPSILON 1e-2

/* The passes of one kind (or the training passes), per pixel. */
typedef struct nf_kind_sums {
    double *rgb; /* 3 per pixel: the sums of the passes' RGB                              */
    double *lum; /* the sums of their luminance                                           */
    double *sq;  /* the sums of their luminance squared                                   */
    double *
        m2[NF_GUIDE_DEPTHS]; /* the sums of the paths' second moments: [0] plain path
                              * tracing's, [c] depth candidate c's; a plain pass's are its square */
    uint32_t n;          /* passes                                                                */
    double cpu;          /* their CPU seconds, every thread and process                           */
    uint32_t steady_n;   /* passes after training ended, not the job's first              */
    double steady_cpu;   /* their CPU seconds: what the choice weighs once there are some */
    double last_seconds; /* the wall-clock seconds of its latest pass (0: none)           */
} nf_kind_sums;

struct nf_schedule {
    nf_schedule_config cfg;
    nf_guide *guide;
    nf_allocator alloc;
    size_t pixels;

    nf_kind_sums train, kind[NF_KINDS];
    /* The training passes: group k holds the sum of `per_group` consecutive passes (the
     * last one possibly fewer). When all are full, neighbours merge and groups double. */
    double *group[NF_TRAIN_GROUPS];
    uint32_t group_count[NF_TRAIN_GROUPS], groups, per_group;
    double *ref;          /* per pixel: the luminance averaged over every pass          */
    double *peakless;     /* ref with its lone peaks lowered (nf_guide_lower_peaks)      */
    double *pool, *pool2; /* per pixel: one policy's first and second moments (scratch)  */
    double *mean;         /* 3 per pixel: the render passes' combined mean (scratch)     */

    nf_pass_measure measured[NF_KINDS];     /* every kind against ref               */
    nf_pass_measure depth[NF_GUIDE_DEPTHS]; /* the guided kinds against peakless    */

    int training;         /* training passes are still due                                */
    int choosing;         /* the guide chooses the passes (pass_choice)                   */
    uint32_t plain_first; /* plain passes before training                              */
    uint32_t next_pass;   /* the index of the next plan                                */
    int pending;          /* a plan was handed out and not added                       */
    nf_pass_plan plan;    /* the latest plan                                           */
    int stopped;
    double last_seconds;    /* the latest pass's wall-clock seconds, any kind            */
    uint32_t since_measure; /* render passes since the kinds were last measured        */

    nf_schedule_report rep; /* what the plans chose, kept as they are made            */
};

/* values[0..n) summed over the processes of `red` (none: unchanged), exactly: in a fixed
 * point scaled by each value's largest magnitude over the processes, so that every process
 * gets the same bits in any order (schedule_measure.c). */
nf_status nf_schedule_sum(const nf_reduce *red, double *values, size_t n, const char *fn);

/* Each kind's passes and CPU seconds into measured[] and depth[], variances unchanged. */
void nf_schedule_count(nf_schedule *s);

/* Measures every kind: passes, CPU seconds and relative variance (schedule_measure.c).
 * Collective. */
nf_status nf_schedule_measure(nf_schedule *s, const nf_reduce *red, const char *fn);

/* The relative variance of the pass in pool/pool2 against ref, a training pass's ratio to a
 * plain pass reported to the guide (schedule_measure.c). Collective. */
nf_status nf_schedule_training_ratio(nf_schedule *s, const float *rgb, double cpu,
                                     const nf_reduce *red, const char *fn);

/* ref: each pixel's luminance averaged over every pass. */
void nf_schedule_reference(nf_schedule *s);

/* pool, pool2 from the passes that measure moment m; returns those passes. */
uint32_t nf_schedule_pool(nf_schedule *s, uint32_t m);

/* Whether the passes of kind k measure moment m. */
int nf_schedule_kind_measures(uint32_t k, uint32_t m);

#define NF_SCHEDULE_CONFIG_MAGIC 0x4e465343u /* "NFSC" */

#endif /* NISFLOW_SCHEDULE_INTERNAL_H */
