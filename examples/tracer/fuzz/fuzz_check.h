/*
 * fuzz_check.h - the tracer's fuzz targets' invariant check: CHECK(cond, printf-style
 * message) prints where and why, then aborts, which libFuzzer reports with the input.
 */
#ifndef TRACER_FUZZ_CHECK_H
#define TRACER_FUZZ_CHECK_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>

#define CHECK(cond, ...)                                                                       \
    do {                                                                                       \
        if (!(cond)) {                                                                         \
            fprintf(stderr, "fuzz check failed at %s:%d: %s\n  ", __FILE__, __LINE__, #cond);  \
            fprintf(stderr, __VA_ARGS__);                                                      \
            fprintf(stderr, "\n");                                                             \
            abort();                                                                           \
        }                                                                                      \
    } while (0)

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

#endif /* TRACER_FUZZ_CHECK_H */
