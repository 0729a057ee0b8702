/*
 * pool.h - a pool of worker threads that runs jobs split into tasks (the
 * renderer's frames split into tiles), and parallel loops on it (the tree
 * builders' recursions, ray sets). It is the one source of threads for the
 * layers above core, so that work running at once (concurrent requests to
 * the daemon) shares the cores instead of oversubscribing them.
 *
 * A job is ntasks independent tasks plus a completion callback. Any number
 * of jobs may be in flight at once: each time a worker takes its next task
 * it takes it from the next active job in turn (round-robin), so frames that
 * are rendering at the same time share the workers fairly. A job can be
 * cancelled at any time; the tasks already running finish, no new one
 * starts.
 *
 * The completion callback `done(ctx, cancelled)` (may be NULL) runs exactly
 * once per submitted job, always on a worker thread (never inside submit, cancel or
 * destroy), after the last task has finished or, for a cancelled job, after
 * the tasks that were running have finished. `cancelled` is true when some
 * tasks never ran. Only after done has returned does arbor_job_wait return.
 *
 * Ownership: a job is reference-counted. arbor_job_new returns the caller's
 * reference; arbor_pool_submit adds one the pool drops after done has
 * returned; `release(ctx)` runs when the last reference goes, so the task
 * context lives exactly as long as anyone can still use it. arbor_job_wait
 * and arbor_job_cancel may be called only before arbor_pool_destroy;
 * arbor_job_release at any time (including inside done).
 *
 * arbor_pool_destroy cancels every job not yet finished, lets the workers
 * call their done callbacks, and joins the workers. It must not be called
 * from a task or a done callback (it would wait for its own thread), nor
 * while a parallel loop on the pool is running.
 *
 * Parallel loops. arbor_pool_parallel runs fn(ctx, i) for every i in
 * [0, n) and returns when all have returned. It may be called from any
 * thread, pool workers included, and nested to any depth (a loop's fn may
 * run loops of its own): it never deadlocks, because the caller never waits
 * for work that has not started. The caller takes indices from a shared
 * counter itself; a helper job of up to max_threads - 1 tasks lets idle
 * workers take indices from the same counter. When the counter runs out the
 * caller waits only for the indices helpers are running, then cancels the
 * helper tasks that have not started. Indices are claimed in ascending
 * order; which thread runs which index is unspecified: results must not
 * depend on it. Without a pool (p NULL), or when the helper job cannot be
 * made, every index runs on the caller.
 *
 * A budget limits the threads a whole piece of work keeps busy at once,
 * across every loop nested inside it (a tree build: at most opts.threads
 * threads, however deep the recursion forks). The thread that starts the
 * work counts as one; a helper task takes one of the rest for as long as it
 * works and gives it back when it runs out of indices, and one that finds
 * none left returns at once. A loop queues its helpers even when the budget
 * has none spare at the time, so that a thread freed by another loop of the
 * same work takes over what the caller has not reached yet.
 */
#ifndef ARBOR_POOL_H
#define ARBOR_POOL_H

#include <stdatomic.h>
#include <stdbool.h>
#include <stdint.h>

#include "arbor/err.h"

typedef struct arbor_pool arbor_pool;
typedef struct arbor_job arbor_job;

/* Runs task number `task` (0 <= task < ntasks) of the job. */
typedef void (*arbor_task_fn)(void *ctx, uint32_t task);
/* The job is over; see above. */
typedef void (*arbor_job_done_fn)(void *ctx, bool cancelled);
/* The last reference to the job is gone: free ctx. May be NULL. */
typedef void (*arbor_job_release_fn)(void *ctx);

/* A pool of `threads` workers (0 = one per core). NULL on failure. */
arbor_pool *arbor_pool_create(int threads, arbor_err *e);
int arbor_pool_threads(const arbor_pool *p);
void arbor_pool_destroy(arbor_pool *p);

/* A job of ntasks (>= 1) tasks, not yet submitted. NULL when out of memory. */
arbor_job *arbor_job_new(uint32_t ntasks, arbor_task_fn run, arbor_job_done_fn done, arbor_job_release_fn release,
                         void *ctx, arbor_err *e);
/* Queues the job. Fails (and the job stays unsubmitted, its done never
 * called) when the pool is shutting down or the job was submitted before. */
bool arbor_pool_submit(arbor_pool *p, arbor_job *j, arbor_err *e);
/* Asks the job to stop; a no-op once it is finishing. Never blocks on tasks. */
void arbor_job_cancel(arbor_job *j);
/* Blocks until done has returned; true when the job ran to completion,
 * false when it was cancelled. The job must have been submitted. */
bool arbor_job_wait(arbor_job *j);
/* Drops the caller's reference. */
void arbor_job_release(arbor_job *j);

/* Threads a piece of work may keep busy at once; see above. Plain data the
 * caller owns, shared by the loops that name it. */
typedef struct {
    atomic_int spare; /* threads not yet taken, besides the one that started the work */
    int helpers;      /* threads besides that one: at most this many helpers per loop */
} arbor_pool_budget;

/* A budget of `threads` threads, the calling thread included (0 = as many
 * as p has, or 1 when p is NULL). */
void arbor_pool_budget_init(arbor_pool_budget *b, const arbor_pool *p, uint32_t threads);

/* The threads b has spare at this moment: a hint (another thread may take
 * or give one back at once), for work that is laid out better when it
 * knows whether a loop is likely to run on the caller alone. */
int arbor_pool_budget_spare(const arbor_pool_budget *b);

/* Runs fn(ctx, i) for every i in [0, n) on the caller and idle workers of p
 * within budget b, and returns when all have returned. Cannot fail: what no
 * helper takes runs on the caller. b must outlive the call only. */
void arbor_pool_parallel_within(arbor_pool *p, arbor_pool_budget *b, uint32_t n, void (*fn)(void *ctx, uint32_t i),
                                void *ctx);

/* The same on at most max_threads threads, the caller included (0 = as
 * many as p has). */
void arbor_pool_parallel(arbor_pool *p, uint32_t n, uint32_t max_threads, void (*fn)(void *ctx, uint32_t i), void *ctx);

#endif
