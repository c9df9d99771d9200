/*
 * ranks.c - ranks.h on MPI (NF_TRACER_HAVE_MPI, set by CMake when it finds MPI) or, without
 * it, for a single process. Only the world communicator is used; its error handler returns
 * errors instead of aborting, so a failing collective becomes a message.
 */
#include "ranks.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#ifdef NF_TRACER_HAVE_MPI
#include <mpi.h>
#endif

static int g_rank = 0, g_size = 1, g_active = 0;

/* The world size an MPI launcher announces in the environment, 0 when there is none. Open MPI
 * sets OMPI_COMM_WORLD_SIZE, MPICH's Hydra PMI_SIZE; a PMIx launcher sets PMIX_RANK. */
static int launcher_world_size(void)
{
    const char *names[] = {"OMPI_COMM_WORLD_SIZE", "PMI_SIZE"};
    for (size_t i = 0; i < sizeof names / sizeof *names; ++i) {
        const char *v = getenv(names[i]);
        if (v && *v)
            return atoi(v) > 0 ? atoi(v) : 1;
    }
    return getenv("PMIX_RANK") ? 1 : 0;
}

uint64_t ranks_hash(uint64_t h, const void *data, size_t n)
{
    const unsigned char *b = data;
    for (size_t i = 0; i < n; ++i)
        h = (h ^ b[i]) * 1099511628211ull;
    return h;
}

int ranks_all_equal(uint64_t value, const char *what, tr_error *err)
{
    if (g_size == 1)
        return 1;
    uint64_t *all = malloc((size_t)g_size * sizeof *all);
    if (!ranks_agree(all != NULL || tr_fail(err, "out of memory"), err) ||
        !ranks_gather_u64(value, all, err)) {
        free(all);
        return 0;
    }
    char differ[200] = "";
    size_t len = 0;
    int count = 0;
    for (int r = 1; r < g_size; ++r) {
        if (all[r] == all[0])
            continue;
        if (len + 16 < sizeof differ)
            len += (size_t)snprintf(differ + len, sizeof differ - len, "%s%d", count ? ", " : "",
                                    r);
        count++;
    }
    free(all);
    if (count == 0)
        return 1;
    return tr_fail(err, "%s: rank%s %s differ%s from rank 0", what, count > 1 ? "s" : "", differ,
                   count > 1 ? "" : "s");
}

int ranks_rank(void) { return g_rank; }
int ranks_size(void) { return g_size; }

#ifdef NF_TRACER_HAVE_MPI

static int mpi_fail(tr_error *err, const char *what, int code)
{
    char text[MPI_MAX_ERROR_STRING];
    int len = 0;
    if (MPI_Error_string(code, text, &len) != MPI_SUCCESS)
        snprintf(text, sizeof text, "MPI error %d", code);
    return tr_fail(err, "%s failed: %s", what, text);
}

int ranks_init(int *argc, char ***argv, tr_error *err)
{
    if (launcher_world_size() == 0)
        return 1; /* started on its own: one rank, no MPI */
    int provided = 0, code = MPI_Init_thread(argc, argv, MPI_THREAD_FUNNELED, &provided);
    if (code != MPI_SUCCESS)
        return tr_fail(err, "MPI_Init_thread failed (code %d)", code);
    g_active = 1;
    MPI_Comm_set_errhandler(MPI_COMM_WORLD, MPI_ERRORS_RETURN);
    if (provided < MPI_THREAD_FUNNELED)
        return tr_fail(err, "the MPI library does not allow threads (MPI_THREAD_FUNNELED)");
    MPI_Comm_rank(MPI_COMM_WORLD, &g_rank);
    MPI_Comm_size(MPI_COMM_WORLD, &g_size);
    return 1;
}

void ranks_finalize(void)
{
    if (g_active)
        MPI_Finalize();
    g_active = 0;
}

int ranks_agree(int ok, tr_error *err)
{
    if (!g_active)
        return ok;
    /* The lowest failing rank, or g_size when none failed. */
    int mine = ok ? g_size : g_rank, first = g_size;
    int code = MPI_Allreduce(&mine, &first, 1, MPI_INT, MPI_MIN, MPI_COMM_WORLD);
    if (code != MPI_SUCCESS)
        return mpi_fail(err, "MPI_Allreduce (agreement)", code);
    if (first == g_size)
        return 1;
    tr_error msg;
    memset(&msg, 0, sizeof msg);
    if (g_rank == first && err)
        memcpy(msg.msg, err->msg, sizeof msg.msg);
    code = MPI_Bcast(msg.msg, (int)sizeof msg.msg, MPI_CHAR, first, MPI_COMM_WORLD);
    if (code != MPI_SUCCESS)
        return mpi_fail(err, "MPI_Bcast (a failure's message)", code);
    msg.msg[sizeof msg.msg - 1] = '\0';
    if (g_size > 1)
        return tr_fail(err, "rank %d of %d: %s", first, g_size, msg.msg);
    return tr_fail(err, "%s", msg.msg);
}

/* MPI counts are ints: large arrays go in slices. */
#define SLICE ((size_t)1 << 28)

static int allreduce(void *v, size_t n, MPI_Datatype type, size_t size, MPI_Op op,
                     const char *what, tr_error *err)
{
    for (size_t at = 0; g_active && at < n; at += SLICE) {
        int count = (int)(n - at < SLICE ? n - at : SLICE);
        int code = MPI_Allreduce(MPI_IN_PLACE, (char *)v + at * size, count, type, op,
                                 MPI_COMM_WORLD);
        if (code != MPI_SUCCESS)
            return mpi_fail(err, what, code);
    }
    return 1;
}

int ranks_sum_i64(int64_t *v, size_t n, tr_error *err)
{
    return allreduce(v, n, MPI_INT64_T, sizeof *v, MPI_SUM, "MPI_Allreduce (sum)", err);
}

int ranks_sum_u64(uint64_t *v, size_t n, tr_error *err)
{
    return allreduce(v, n, MPI_UINT64_T, sizeof *v, MPI_SUM, "MPI_Allreduce (sum)", err);
}

int ranks_sum_f64(double *v, size_t n, tr_error *err)
{
    return allreduce(v, n, MPI_DOUBLE, sizeof *v, MPI_SUM, "MPI_Allreduce (sum)", err);
}

int ranks_max_f64(double *v, size_t n, tr_error *err)
{
    return allreduce(v, n, MPI_DOUBLE, sizeof *v, MPI_MAX, "MPI_Allreduce (max)", err);
}

int ranks_gather_u64(uint64_t value, uint64_t *all, tr_error *err)
{
    if (!g_active) {
        all[0] = value;
        return 1;
    }
    int code = MPI_Allgather(&value, 1, MPI_UINT64_T, all, 1, MPI_UINT64_T, MPI_COMM_WORLD);
    return code == MPI_SUCCESS || mpi_fail(err, "MPI_Allgather", code);
}

int ranks_sum_floats_to_root(float *data, size_t n, tr_error *err)
{
    for (size_t at = 0; g_active && at < n; at += SLICE) {
        int count = (int)(n - at < SLICE ? n - at : SLICE);
        void *send = g_rank == 0 ? MPI_IN_PLACE : (void *)(data + at);
        int code = MPI_Reduce(send, data + at, count, MPI_FLOAT, MPI_SUM, 0, MPI_COMM_WORLD);
        if (code != MPI_SUCCESS)
            return mpi_fail(err, "MPI_Reduce (the image)", code);
    }
    return 1;
}

#else /* one process, no MPI */

int ranks_init(int *argc, char ***argv, tr_error *err)
{
    (void)argc;
    (void)argv;
    int n = launcher_world_size();
    if (n > 1)
        return tr_fail(err, "started by an MPI launcher as one of %d processes, but this "
                            "tracer was built without MPI: each process would render the "
                            "whole job alone. Install libopenmpi-dev and rebuild "
                            "(docs/distributed.md)", n);
    return 1;
}

void ranks_finalize(void) {}

int ranks_agree(int ok, tr_error *err)
{
    (void)err;
    return ok;
}

int ranks_sum_i64(int64_t *v, size_t n, tr_error *err)
{
    (void)v;
    (void)n;
    (void)err;
    return 1;
}

int ranks_sum_u64(uint64_t *v, size_t n, tr_error *err)
{
    (void)v;
    (void)n;
    (void)err;
    return 1;
}

int ranks_sum_f64(double *v, size_t n, tr_error *err)
{
    (void)v;
    (void)n;
    (void)err;
    return 1;
}

int ranks_max_f64(double *v, size_t n, tr_error *err)
{
    (void)v;
    (void)n;
    (void)err;
    return 1;
}

int ranks_gather_u64(uint64_t value, uint64_t *all, tr_error *err)
{
    (void)err;
    all[0] = value;
    return 1;
}

int ranks_sum_floats_to_root(float *data, size_t n, tr_error *err)
{
    (void)data;
    (void)n;
    (void)err;
    return 1;
}

#endif
