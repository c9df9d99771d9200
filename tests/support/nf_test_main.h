/*
 * nf_test_main.h - a cmocka test program's main, shared by the library's tests and the example
 * tracer's (header only: it needs nothing but cmocka).
 */
#ifndef NF_TEST_MAIN_H
#define NF_TEST_MAIN_H

#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>

/* A cmocka entry that runs `fn` under the name `label` with *state holding the integer `value`
 * (a prior, a mode), so that one function checks every case under a name of its own; `fn` reads
 * the value with nft_case(state). cmocka hands a test its initial state as it is, NULL for 0. */
#define NFT_TEST_CASE(label, fn, value)                                                        \
    {                                                                                          \
        .name = (label), .test_func = (fn), .initial_state = (void *)(uintptr_t)(value)        \
    }

static inline int nft_case(void **state) { return (int)(uintptr_t)*state; }

/* A test program's main: its cmocka tests, one group without setup, run in order; main returns
 * the number of tests that failed. The arguments are cmocka entries (cmocka_unit_test(...),
 * NFT_TEST_CASE, a fixture's entry), each with a trailing comma. */
#define NFT_TEST_MAIN(...)                                                                     \
    int main(void)                                                                             \
    {                                                                                          \
        const struct CMUnitTest tests[] = {__VA_ARGS__};                                       \
        return cmocka_run_group_tests(tests, NULL, NULL);                                      \
    }

#endif /* NF_TEST_MAIN_H */
