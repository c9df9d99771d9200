/*
 * guide_internal.h - the guide's memory (nisflow/guide.h), shared by guide.c (life cycle, the
 * store, publication) and guide_train.c (the schedule and the exact sharded step).
 */
#ifndef NISFLOW_GUIDE_INTERNAL_H
#define NISFLOW_GUIDE_INTERNAL_H

#include <stdatomic.h>

#include "internal.h"

/* One training sample as stored. The first 52 bytes (context, direction, weight) are
 * contiguous floats, which the sort compares as bytes to order equal keys. */
typedef struct nf_guide_entry {
    nf_context ctx;
    float dir[3];
    float weight;
    uint64_t key;
} nf_guide_entry;

#define NF_GUIDE_ENTRY_BYTES 52u
#define NF_GUIDE_MESSAGE 160

/* Published copies of the model: acquire hands out the newest; publish writes one that no
 * thread holds, so holders of one older generation never hold publication up. */
#define NF_GUIDE_PUBLISHED 3

struct nf_guide {
    nf_guide_config cfg;
    nf_allocator alloc;
    nf_model *train;                   /* what steps change; never handed out              */
    nf_model *pub[NF_GUIDE_PUBLISHED]; /* published copies; `newest` is what acquire hands out */
    atomic_int newest;
    atomic_uint holders[NF_GUIDE_PUBLISHED];
    atomic_int training; /* a training call or publish in flight                           */

    /* The intake: two stages. Adds go to stage `intake`; a training pass turns the intake to
     * the other stage, waits for the adds still writing into its own (adders), and drains
     * it, while new adds fill the other one for the next pass. */
    atomic_int intake;
    atomic_uint adders[2];   /* nf_guide_add_samples calls writing into each stage        */
    atomic_size_t staged[2]; /* slots reserved in each stage (may exceed capacity)        */
    atomic_ullong dropped;

    /* The job of nf_guide_helpers' parallel-for (guide_help.c): its fields are written
     * before job_open is set and read by helpers only after they see it set. */
    atomic_int job_open;
    atomic_size_t job_next, job_done;
    atomic_uint job_helpers;
    nf_task_fn job_task;
    void *job_data;
    size_t job_count;

    nf_guide_entry *stage[2], *ring; /* capacity each                                        */
    unsigned char *stage_payload[2], *ring_payload;
    const nf_guide_entry *drain; /* the stage a pass drains (its sort reads it)   */
    const unsigned char *drain_payload;
    size_t ring_next, ring_count;
    uint32_t *order, *order_tmp; /* capacity each: the sort and the held-out shuffle          */
    float *quantile_work;        /* capacity                                                  */

    /* The step being computed: samples from ring slots step_slot[i]. */
    nf_context *step_ctx;
    float *step_dir, *step_weight;
    size_t *step_slot;
    size_t step_n;
    const unsigned char *step_payload_base; /* ring_payload while a store step runs, else NULL */

    /* One gradient per group, and the exact sums. */
    size_t params;
    float *grads;
    double *F, *FL;
    double *group_top; /* per group: the largest |F grad| of its gradient                  */
    nf_status *group_status;
    char (*group_message)[NF_GUIDE_MESSAGE];
    int64_t *fixed; /* params + 2 */
    float *mean;    /* params     */

    /* The schedule. */
    float clamp;
    double best_loss, smooth_loss;
    uint32_t since_best, passes;
    double best_ratio;         /* the lowest guided / plain ratio of a training pass so far */
    uint32_t ratio_since_best; /* training passes since it last fell by NF_RATIO_STEP       */
    float last_loss;
    uint64_t samples, steps, refused;
    uint64_t rng;
};

/* Marks the start and end of a training call or publish (guide.c): NF_ERROR_BUSY while
 * another such call runs. */
nf_status nf_guide_begin_exclusive(nf_guide *g, const char *fn);
void nf_guide_end_exclusive(nf_guide *g);

/* Turns the intake to the other stage and waits until no add writes into the one it left;
 * returns that stage's index, whose staged samples the caller then drains (guide.c). Call
 * between begin and end_exclusive. */
int nf_guide_swap_intake(nf_guide *g);

/* Whether the guided / plain ratios reported by nf_guide_report_training_ratio still say
 * that training pays (guide_choice.c). */
int nf_guide_training_pays(const nf_guide *g);

/* Marks a guide config as initialized. */
#define NF_GUIDE_CONFIG_MAGIC 0x4e464743u /* "NFGC" */

/* ---- What the schedule asks of the guide ---------------------------------------------- */

/* Whether training still pays: 0 once `elapsed` reaches train_fraction of `budget` (both in
 * the caller's unit, seconds say; budget <= 0: no budget), the held-out loss has not
 * improved by 1 % for `patience` passes, or the reported training ratios say it buys too
 * little (nf_guide_report_training_ratio). Every process gets the same answer for the same
 * arguments. Thread-safe on a guide no training call changes meanwhile. */
int nf_guide_keep_training(const nf_guide *g, double elapsed, double budget);

/* The samples added since the last training pass began, which the next pass will train on
 * (at most store_capacity; the rest are dropped), adds still running included: a trainer on
 * its own thread can wait for enough of them before it trains. 0 for NULL. Thread-safe with
 * every call but nf_guide_destroy; lock-free. */
size_t nf_guide_pending(const nf_guide *g);

#endif /* NISFLOW_GUIDE_INTERNAL_H */
