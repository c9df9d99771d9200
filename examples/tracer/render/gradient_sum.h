/*
 * gradient_sum.h - one optimizer step on a batch that is spread over groups, threads and
 * ranks, with the same result to the bit however it is spread.
 *
 * The batch's gradient is  sum_g F_g grad_g / sum_g F_g  over groups of samples, F_g a group's
 * weight sum and grad_g its nf_loss_gradient (nisflow/train.h, "Sharded training"). Summed in
 * floating point, the result would depend on the order of the additions, and so on how many
 * threads and ranks there are and in which order MPI adds: two runs of one job on different
 * clusters would train different models. Here each term is rounded once to a 62-bit integer
 * (a fixed point whose scale is set by the largest term of any rank, so that no sum can
 * overflow) and the integers are summed, exactly and in any order. What is left to choose is
 * the groups, which the caller fixes by the batch alone (training.c: 256 paths each).
 *
 * Precision: a term is rounded to 2^-62 of (the largest term x the number of groups), far
 * below float's 2^-24 for every component within 2^30 of the largest; smaller components,
 * which AdamW's normalisation would turn into noise anyway, lose their low bits.
 */
#ifndef TRACER_GRADIENT_SUM_H
#define TRACER_GRADIENT_SUM_H

#include <stddef.h>
#include <stdint.h>

#include <nisflow/nisflow.h>

#include "error.h"

typedef struct gradient_sum {
    size_t params, capacity; /* capacity: groups                                       */
    float *grads;            /* capacity x params: each local group's gradient         */
    double *F, *FL;          /* per local group: weight sum, and weight sum x loss       */
    nf_status *status;       /* per local group                                          */
    char (*messages)[256];   /* per local group: the library's message when refused, read
                              * on the thread that was refused                          */
    int64_t *fixed;          /* params + 2: the fixed-point sums                         */
    float *mean;             /* params: the batch's gradient                             */
    char message[256];       /* after a refusal on this rank: the library's message; else
                              * empty                                                    */
} gradient_sum;

void gradient_sum_free(gradient_sum *g);

/* What a step did, the same on every rank. */
typedef enum gradient_step {
    GRADIENT_STEP_TAKEN,   /* the model took one AdamW step                              */
    GRADIENT_STEP_EMPTY,   /* every weight of every rank was zero: no step (as nf_train_step) */
    GRADIENT_STEP_REFUSED  /* the library refused a group's gradient or the step; the model is
                            * unchanged on every rank                                       */
} gradient_step;

/* Collective (ranks.h): every rank calls it with its own groups. Local group k holds samples
 * [group_end[k - 1], group_end[k]) of ctx / dir / weight (group_end[-1] = 0), and the ranks'
 * groups together are `total_groups` groups. The groups' gradients are computed with
 * nf_loss_gradient on `threads` threads (with the BSDF prior, the caller has published the
 * samples' points: guide_begin_batch), summed exactly over all ranks, and applied with
 * nf_apply_gradient on every rank, so the ranks' models stay identical.
 * *loss receives the batch's loss (NAN unless a step was taken), *step what happened and
 * *refusal the library's status when refused (NF_OK otherwise). Returns 0 with a message
 * only when memory or MPI fails. */
int gradient_sum_step(gradient_sum *g, nf_model *m, const nf_context *ctx, const float *dir,
                      const float *weight, const size_t *group_end, size_t groups,
                      size_t total_groups, int threads, float *loss, gradient_step *step,
                      nf_status *refusal, tr_error *err);

#endif /* TRACER_GRADIENT_SUM_H */
