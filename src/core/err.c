/* err.c - filling arbor_err records (see include/arbor/err.h). */
#include <errno.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "arbor/err.h"

bool arbor_fail(arbor_err *e, arbor_status status, const char *fmt, ...)
{
    if (e == NULL)
        return false;
    e->status = status;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(e->msg, sizeof e->msg, fmt, ap);
    va_end(ap);
    return false;
}

bool arbor_fail_errno(arbor_err *e, const char *path, const char *what, int err)
{
    char reason[128];
    if (strerror_r(err, reason, sizeof reason) != 0)
        snprintf(reason, sizeof reason, "error %d", err);
    return arbor_fail(e, err == ENOMEM ? ARBOR_ERR_NOMEM : ARBOR_ERR_IO, "%s: %s: %s", path, what, reason);
}

void arbor_err_clear(arbor_err *e)
{
    if (e == NULL)
        return;
    e->status = ARBOR_OK;
    e->msg[0] = '\0';
}

const char *arbor_status_name(arbor_status status)
{
    switch (status) {
    case ARBOR_OK: return "ok";
    case ARBOR_ERR_IO: return "io";
    case ARBOR_ERR_PARSE: return "parse";
    case ARBOR_ERR_INVALID: return "invalid";
    case ARBOR_ERR_NOMEM: return "nomem";
    case ARBOR_ERR_CANCELLED: return "cancelled";
    case ARBOR_ERR_NOT_FOUND: return "not_found";
    case ARBOR_ERR_EXISTS: return "exists";
    case ARBOR_ERR_NOSPACE: return "nospace";
    }
    return "unknown";
}
