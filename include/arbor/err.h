/*
 * err.h - how arbor's library code reports failure.
 *
 * Library functions never print and never exit. A function that can fail
 * takes an `arbor_err *` (which may be NULL when the caller does not care),
 * fills it with a status and a message that names the file, line, field or
 * value at fault, and returns false / NULL. Only main and the HTTP layer turn
 * an arbor_err into words for people. The struct is plain data owned by the
 * caller; nothing in it needs freeing.
 */
#ifndef ARBOR_ERR_H
#define ARBOR_ERR_H

#include <stdbool.h>

typedef enum {
    ARBOR_OK = 0,
    ARBOR_ERR_IO,        /* file missing, unreadable, truncated */
    ARBOR_ERR_PARSE,     /* malformed input: names file and line */
    ARBOR_ERR_INVALID,   /* a bad argument or option value */
    ARBOR_ERR_NOMEM,     /* allocation failed */
    ARBOR_ERR_CANCELLED, /* the caller asked the work to stop */
    ARBOR_ERR_NOT_FOUND, /* no such model, tree or job */
    ARBOR_ERR_EXISTS,    /* the name is taken */
    ARBOR_ERR_NOSPACE    /* it does not fit in the memory budget */
} arbor_status;

typedef struct {
    arbor_status status;
    char msg[512];
} arbor_err;

/* Records status and a printf-style message in e (if e is non-NULL) and
 * returns false, so that failing paths read `return arbor_fail(e, ...);`. */
bool arbor_fail(arbor_err *e, arbor_status status, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

/* arbor_fail for a system call that failed with errno err: "PATH: WHAT:
 * the system's reason", ARBOR_ERR_NOMEM for ENOMEM, else ARBOR_ERR_IO. */
bool arbor_fail_errno(arbor_err *e, const char *path, const char *what, int err);

/* Resets e to ARBOR_OK with an empty message. */
void arbor_err_clear(arbor_err *e);

/* A short lower-case name for a status ("io", "parse", ...). */
const char *arbor_status_name(arbor_status status);

#endif
