/*
 * error.c - tr_fail, the single place where error messages are formatted.
 */
#include "error.h"

#include <stdarg.h>
#include <stdio.h>

int tr_fail(tr_error *err, const char *fmt, ...)
{
    if (err) {
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(err->msg, sizeof err->msg, fmt, ap);
        va_end(ap);
    }
    return 0;
}
