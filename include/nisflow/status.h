/*
 * nisflow/status.h - status codes and error messages.
 *
 * Every fallible libnisflow call returns an nf_status. The library never aborts, exits or
 * prints: a refused call returns a non-zero status, leaves every model it was given unchanged,
 * and records a human-readable explanation that nf_last_error_message() returns.
 */
#ifndef NISFLOW_STATUS_H
#define NISFLOW_STATUS_H

#include "version.h"

NF_EXTERN_C_BEGIN

/* The values are part of the ABI: they are explicit and are never renumbered. */
typedef enum nf_status {
    NF_OK = 0,
    NF_ERROR_INVALID_ARGUMENT = 1, /* NULL, NaN/Inf, zero vector, bad size, bad config ...   */
    NF_ERROR_OUT_OF_MEMORY = 2,    /* the allocator returned NULL                            */
    NF_ERROR_IO = 3,               /* a file could not be opened, read or written            */
    NF_ERROR_FORMAT = 4,           /* a model file or buffer is truncated, corrupt or foreign */
    NF_ERROR_NUMERIC = 5,          /* a result would be non-finite (the call was refused)    */
    NF_ERROR_STALE = 6,            /* a vertex was set before a change of the model's
                                      parameters: set it again (nisflow/vertex.h)          */
    NF_ERROR_CAPACITY = 7,         /* an output buffer is too small; nothing was written and
                                      the call says how much it needs (nisflow/path.h)     */
    NF_ERROR_BUSY = 8              /* the guide is in use by a call that may not overlap this
                                      one; nothing changed: retry after it (nisflow/guide.h) */
} nf_status;

/* A short static description of a status code ("invalid argument", ...); "unknown status" for
 * values outside the enum. Never NULL, never freed by the caller. Thread-safe. */
NF_API const char *nf_status_string(nf_status s);

/* A detailed message about the most recent call that failed on the calling thread, for
 * example "nf_pdf: ctx[17].normal has zero length". The storage is thread-local and owned by
 * the library; it stays valid until the next failing call on the same thread. Successful calls
 * do not change it. Returns "" if no call has failed on this thread. Thread-safe. */
NF_API const char *nf_last_error_message(void);

NF_EXTERN_C_END

#endif /* NISFLOW_STATUS_H */
