/*
 * sys.h - the few operating-system services arbor's modules share: a
 * monotonic clock, the core count, the identity of a file, mapping fresh memory in advance, and
 * text made valid UTF-8.
 * Threads come from the pool (pool.h), never from here.
 */
#ifndef ARBOR_SYS_H
#define ARBOR_SYS_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "arbor/err.h"

/* Milliseconds on a monotonic clock (arbitrary origin). */
double arbor_now_ms(void);

/* Online cores, at least 1. */
int arbor_cpu_count(void);

/* The identity of the file at path as it is now: a hash of its inode, size
 * and modification time (never 0), or 0 when there is no such file. A file
 * replaced by a rename gets a new inode, so daemons sharing a folder tell a
 * new version from the one they loaded by this number; it leaves out the
 * device, which differs between hosts mounting one NFS folder. */
uint64_t arbor_file_stamp(const char *path);

/* True when the real path `real` (realpath(3): links and ".." resolved)
 * lies inside the real folder `dir`: the rule for what may be read beside a
 * model (its material libraries). */
bool arbor_real_path_inside(const char *real, const char *dir);

/* Asks the kernel to map now, writable, the whole pages inside [p, p +
 * bytes) of memory about to be written, rather than one page fault at a
 * time as the writes first touch them. Only a hint, for large fresh
 * allocations: a kernel without MADV_POPULATE_WRITE (Linux before 5.14)
 * leaves the faults as they were, and the memory is the same either way. */
void arbor_prefault(void *p, size_t bytes);

/* A file written whole or not at all. What exists at path decides how: a
 * regular file (or a symbolic link to one: the link's target) is written
 * to a temporary file beside it and renamed over it once complete,
 * keeping its permissions; a new file the same way, with 0666 less the
 * umask; something else that exists (/dev/stdout, a FIFO) is written in
 * place, since renaming over it would replace a device node. A write that
 * fails (a full disk) removes only the temporary file, which this made:
 * whatever was at path stays as it was. */
typedef struct {
    FILE *f;             /* write here */
    char path[4096];     /* what is written (a link's target), for messages */
    char tmp[4096 + 8];  /* the temporary file; "" when written in place */
} arbor_file_out;

/* Opens path for writing; on failure (e set) there is nothing to close. */
bool arbor_file_out_open(arbor_file_out *o, const char *path, arbor_err *e);
/* Closes o->f and puts the file in place when the caller says it is
 * complete and every write to it succeeded; otherwise removes the
 * temporary file and fails (naming path and the system's reason for a
 * failed write; e untouched when the caller gave up). */
bool arbor_file_out_close(arbor_file_out *o, bool complete, arbor_err *e);

/* Replaces each byte of text[0, len) that is not part of well-formed UTF-8
 * (RFC 3629) by '?'. Names from requests and file systems reach JSON byte
 * for byte, and JSON is UTF-8; JSON outside its strings is ASCII, so on a
 * JSON text only strings change. */
void arbor_utf8_repair(char *text, size_t len);

#endif
