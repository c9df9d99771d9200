/*
 * error.c - status strings, the thread-local error message, and the version string.
 */
#include <stdarg.h>
#include <stdio.h>

#include "internal.h"

#define NF_STR2(x) #x
#define NF_STR(x) NF_STR2(x)

/* One message buffer per thread, so that concurrent const calls never race on it. */
static _Thread_local char nf_message[256];

const char *nf_version_string(void)
{
    return NF_STR(NF_VERSION_MAJOR) "." NF_STR(NF_VERSION_MINOR) "." NF_STR(NF_VERSION_PATCH);
}

const char *nf_status_string(nf_status s)
{
    switch (s) {
    case NF_OK: return "ok";
    case NF_ERROR_INVALID_ARGUMENT: return "invalid argument";
    case NF_ERROR_OUT_OF_MEMORY: return "out of memory";
    case NF_ERROR_IO: return "input/output error";
    case NF_ERROR_FORMAT: return "invalid model format";
    case NF_ERROR_NUMERIC: return "non-finite numeric result";
    case NF_ERROR_STALE: return "stale shading point";
    case NF_ERROR_CAPACITY: return "output buffer too small";
    case NF_ERROR_BUSY: return "guide busy";
    }
    return "unknown status";
}

const char *nf_last_error_message(void) { return nf_message; }

nf_status nf_fail(nf_status status, const char *fmt, ...)
{
    va_list args;
    va_start(args, fmt);
    /* vsnprintf formats into memory only: the library still never prints. */
    vsnprintf(nf_message, sizeof nf_message, fmt, args);
    va_end(args);
    return status;
}
