/* sys.c - clock, core count and fork-join (see include/arbor/sys.h). */
#include <pthread.h>
#include <time.h>
#include <unistd.h>

#include "arbor/sys.h"

double arbor_now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec * 1e3 + (double)ts.tv_nsec * 1e-6;
}

int arbor_cpu_count(void)
{
    long n = sysconf(_SC_NPROCESSORS_ONLN);
    return n > 0 ? (int)n : 1;
}

typedef struct {
    void (*fn)(void *);
    void *arg;
} fork_task;

static void *fork_task_run(void *p)
{
    fork_task *t = p;
    t->fn(t->arg);
    return NULL;
}

void arbor_fork_join(void (*fa)(void *), void *a, void (*fb)(void *), void *b, bool parallel)
{
    fork_task ta = {fa, a};
    pthread_t th;
    /* When a thread cannot be had, run both here: slower, never wrong. */
    if (parallel && pthread_create(&th, NULL, fork_task_run, &ta) == 0) {
        fb(b);
        pthread_join(th, NULL);
        return;
    }
    fa(a);
    fb(b);
}
