/*
 * nf_test_stack.c - measuring how much stack a call uses, for the stack-use tests: the call
 * runs on a thread whose stack is ours, painted before, and the bytes it overwrote are counted.
 */
#define _POSIX_C_SOURCE 200809L /* pthread_attr_setstack */

#include <pthread.h>
#include <stdlib.h>
#include <string.h>

#include "nf_test_support.h"

enum { PAINT = 0x5a };

size_t nft_stack_used(void *(*fn)(void *), void *arg, size_t stack_bytes)
{
    unsigned char *stack = malloc(stack_bytes);
    assert_non_null(stack);
    memset(stack, PAINT, stack_bytes);
    pthread_attr_t attr;
    pthread_t t;
    int ok = pthread_attr_init(&attr) == 0;
    ok = ok && pthread_attr_setstack(&attr, stack, stack_bytes) == 0 &&
         pthread_create(&t, &attr, fn, arg) == 0 && pthread_join(t, NULL) == 0;
    pthread_attr_destroy(&attr);
    size_t low = 0; /* the stack grows down: the untouched paint is at the low end */
    while (low < stack_bytes && stack[low] == PAINT)
        ++low;
    free(stack);
    assert_true(ok); /* the thread ran */
    return stack_bytes - low;
}
