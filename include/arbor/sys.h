/*
 * sys.h - the few operating-system services arbor's modules share: a
 * monotonic clock, the core count and the identity of a file. Threads come from the pool (pool.h),
 * never from here.
 */
#ifndef ARBOR_SYS_H
#define ARBOR_SYS_H

#include <stdint.h>

/* Milliseconds on a monotonic clock (arbitrary origin). */
double arbor_now_ms(void);

/* Online cores, at least 1. */
int arbor_cpu_count(void);

/* The identity of the file at path as it is now: a hash of its device,
 * inode, size and modification time (never 0), or 0 when there is no such
 * file. A file replaced by a rename gets a new inode, so daemons sharing a
 * folder tell a new version from the one they loaded by this number. */
uint64_t arbor_file_stamp(const char *path);

#endif
