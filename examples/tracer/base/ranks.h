/*
 * ranks.h - the processes that render one job together: one process on its own, or the N
 * ranks of `mpirun -n N nf_tracer ...` (docs/distributed.md). Everything the tracer exchanges
 * between machines goes through these functions; without MPI (a build without it, or a
 * process not started by an MPI launcher) there is one rank and each of them is a no-op or a
 * copy, so the rest of the tracer reads the same either way.
 *
 * Every function but ranks_rank / ranks_size is collective: all ranks call it, in the same
 * order, or the job hangs. Only the thread that called ranks_init may call them
 * (MPI_THREAD_FUNNELED): the worker threads never do.
 *
 * Failures: a rank that fails must not leave the others waiting in a collective. The tracer
 * calls ranks_agree at each point where a rank can fail (options, scene, model, each training
 * iteration, the render): all ranks learn whether one failed, and which, with its message, and
 * stop together. A rank that dies (a signal, the out-of-memory killer) is mpirun's to handle:
 * Open MPI then ends the other ranks.
 */
#ifndef TRACER_RANKS_H
#define TRACER_RANKS_H

#include <stddef.h>
#include <stdint.h>

#include "error.h"

/* Starts MPI when this process was started by an MPI launcher (Open MPI's mpirun, or any
 * launcher that sets PMI_RANK / PMIX_RANK) and the tracer was built with it; otherwise the
 * job has one rank. Returns 0 with a message when the process was launched by mpirun but the
 * tracer was built without MPI (N copies would each render the whole job), or MPI fails. */
int ranks_init(int *argc, char ***argv, tr_error *err);

/* Ends MPI (if it was started). Call once, on every rank, before main returns. */
void ranks_finalize(void);

int ranks_rank(void);   /* this process's rank, 0 .. ranks_size() - 1 */
int ranks_size(void);   /* the number of ranks, >= 1                   */

/* Whether every rank succeeded. Each rank passes ok (1: success) and, when !ok, the message in
 * *err. Returns 1 when all succeeded. Otherwise returns 0 on every rank with err holding the
 * lowest failing rank's message, prefixed with "rank R of N: " when there are several ranks. */
int ranks_agree(int ok, tr_error *err);

/* In place, on every rank: v[i] = the sum over ranks of v[i] (exact: integers). */
int ranks_sum_i64(int64_t *v, size_t n, tr_error *err);
int ranks_sum_u64(uint64_t *v, size_t n, tr_error *err);

/* In place, on every rank: v[i] = the sum over ranks of v[i], in floating point (the order of
 * the additions is MPI's): for reports, such as the job's CPU seconds. */
int ranks_sum_f64(double *v, size_t n, tr_error *err);

/* In place, on every rank: v[i] = the largest v[i] of any rank (exact). */
int ranks_max_f64(double *v, size_t n, tr_error *err);

/* On every rank: all[r] = rank r's value (`all` holds ranks_size() values). */
int ranks_gather_u64(uint64_t value, uint64_t *all, tr_error *err);

/* FNV-1a: continues hash h (start from RANKS_HASH_START) over n bytes. For checking that the
 * ranks hold the same thing, not for security. */
#define RANKS_HASH_START 1469598103934665603ull
uint64_t ranks_hash(uint64_t h, const void *data, size_t n);

/* Whether every rank's value equals rank 0's. Returns 1 if so; otherwise 0 on every rank, with
 * err = "<what>: rank(s) R, S differ from rank 0". */
int ranks_all_equal(uint64_t value, const char *what, tr_error *err);

/* Rank 0 receives the sum over ranks of data[i]; the other ranks' data is left as it was.
 * Used for images whose pixels each rank renders alone (the others hold 0): then the sum is
 * exact whatever order MPI adds in. */
int ranks_sum_floats_to_root(float *data, size_t n, tr_error *err);

#endif /* TRACER_RANKS_H */
