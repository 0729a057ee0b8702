/*
 * sys.h - the few operating-system services arbor's modules share:
 * a monotonic clock, the core count, and fork-join on two threads for the
 * parallel tree builders.
 */
#ifndef ARBOR_SYS_H
#define ARBOR_SYS_H

#include <stdbool.h>

/* Milliseconds on a monotonic clock (arbitrary origin). */
double arbor_now_ms(void);

/* Online cores, at least 1. */
int arbor_cpu_count(void);

/* Runs fa(a) and fb(b), fa on a new thread when `parallel` is true (and a
 * thread can be created), fb on the calling thread, and returns when both are
 * done. Builders use it to split the top levels of a tree across cores. */
void arbor_fork_join(void (*fa)(void *), void *a, void (*fb)(void *), void *b, bool parallel);

#endif
