/*
 * sys.h - the few operating-system services arbor's modules share: a
 * monotonic clock and the core count. Threads come from the pool (pool.h),
 * never from here.
 */
#ifndef ARBOR_SYS_H
#define ARBOR_SYS_H

/* Milliseconds on a monotonic clock (arbitrary origin). */
double arbor_now_ms(void);

/* Online cores, at least 1. */
int arbor_cpu_count(void);

#endif
