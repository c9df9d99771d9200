/*
 * error.h - how the tracer reports failures: a function that can fail returns 0 and writes
 * a human-readable message into a caller-provided tr_error; 1 means success. Nothing below
 * main() prints or exits, so the unit tests can check the exact message of every error.
 */
#ifndef TRACER_ERROR_H
#define TRACER_ERROR_H

typedef struct tr_error {
    char msg[1024];
} tr_error;

#if defined(__GNUC__) || defined(__clang__)
#define TR_PRINTF(a, b) __attribute__((format(printf, a, b)))
#else
#define TR_PRINTF(a, b)
#endif

/* Formats the message into err (if not NULL) and returns 0, so that a failing function can
 * end with `return tr_fail(err, "...", ...);`. */
int tr_fail(tr_error *err, const char *fmt, ...) TR_PRINTF(2, 3);

#endif /* TRACER_ERROR_H */
