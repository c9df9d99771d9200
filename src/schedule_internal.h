/*
 * schedule_internal.h - the schedule's memory (nisflow/schedule.h), shared by schedule.c (life
 * cycle and the plans), schedule_measure.c (what each kind of pass measures) and
 * schedule_combine.c (the image).
 */
#ifndef NISFLOW_SCHEDULE_INTERNAL_H
#define NISFLOW_SCHEDULE_INTERNAL_H

#include "nisflow/schedule.h"
#include "schedule_atoms.h"

#include "internal.h"

/* The render passes come in NF_KINDS kinds: guided passes by how deep they guide (the
 * guide's candidates: kind c guides up to depth c) and plain passes. */
#define NF_KINDS (NF_GUIDE_DEPTHS + 1u)
#define NF_PLAIN NF_GUIDE_DEPTHS
/* The relative variances use this epsilon (nf_guide_pass_variance), as relMSE does. */
#define NF_SCHEDULE_EPSILON 1e-2

/* A pass's paths at the default: whole images up to this many pixels, larger ones in subsets. */
#define NF_PASS_PATHS_DEFAULT 131072u
#define NF_PASS_PATHS_MIN 1024u
/* At most this share of a subset pass measures (1 / 16: the cost of measuring, stated in
 * schedule.h). */
#define NF_MEASURE_SHARE 16u

/* The passes of one kind (or the training passes), per measured pixel. */
typedef struct nf_kind_sums {
    double *lum; /* the sums of the passes' luminance                                     */
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

/* Which pixels a pass renders (nf_pass_pixel): the measured pixels, a grid of grid_width x
 * grid_height pixels `grid` apart (the whole image when grid is 1 and there is no subset),
 * then, for images larger than a pass, one of `stride` interleaved subsets of the image. */
typedef struct nf_pass_layout {
    uint32_t grid, grid_width, grid_height, measured; /* measured = grid_width x grid_height */
    uint32_t stride; /* 0: no subset, the measured pixels are the image                 */
} nf_pass_layout;

/* The image: every pass's radiance in three sums per pixel, each RGB and its weight (4
 * floats): training passes weighted by their own spread, guided and plain render passes by
 * their count; weighed against each other when the image is made (schedule_combine.c). */
enum { NF_ACC_TRAIN = 0, NF_ACC_GUIDED = 1, NF_ACC_PLAIN = 2, NF_ACCS = 3 };

struct nf_schedule {
    nf_schedule_config cfg;
    nf_guide *guide;
    nf_allocator alloc;
    size_t pixels;
    nf_pass_layout lay;

    /* The measured pixels' sums (lay.measured of each). */
    nf_kind_sums train, kind[NF_KINDS];
    double *ref;          /* per measured pixel: the luminance averaged over every pass  */
    double *peakless;     /* ref with its lone peaks lowered (nf_guide_lower_peaks)       */
    double *pool, *pool2; /* per measured pixel: one policy's moments (scratch)           */
    double *lum;          /* per measured pixel: the pass being added (scratch)           */
    float *acc[NF_ACCS];  /* every pixel: 4 floats, RGB and weight                         */
    double train_unit;    /* the first training pass's spread: the unit of their weights */
    double train_wmax;    /* the largest training pass weight                             */

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

/* The training pass in s->lum (its luminance on the measured pixels), already in the sums:
 * its absolute spread about ref into *spread (its weight in the image: about 0 while ref is
 * this pass alone), and with the choice of passes its variance x cost over a plain pass's
 * reported to the guide (schedule_measure.c). Collective. */
nf_status nf_schedule_training_pass(nf_schedule *s, double cpu, const nf_reduce *red,
                                    double *spread, const char *fn);

/* ref: each measured pixel's luminance averaged over every pass. */
void nf_schedule_reference(nf_schedule *s);

/* pool, pool2 from the passes that measure moment m; returns those passes. */
uint32_t nf_schedule_pool(nf_schedule *s, uint32_t m);

/* Whether the passes of kind k measure moment m. */
int nf_schedule_kind_measures(uint32_t k, uint32_t m);

#define NF_SCHEDULE_CONFIG_MAGIC 0x4e465343u /* "NFSC" */

#endif /* NISFLOW_SCHEDULE_INTERNAL_H */
