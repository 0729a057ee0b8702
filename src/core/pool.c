/*
 * pool.c - worker threads running jobs split into tasks, round-robin over
 * the jobs in flight, and parallel loops on them (see include/arbor/pool.h).
 *
 * Every piece of scheduling state lives under the pool's one mutex, taken
 * once to fetch a task and once to account for it, never while a task runs.
 * Jobs that still have tasks to hand out form a circular list (the "ring");
 * the pool's cursor points at the job the next fetch takes from and moves on
 * after each fetch. A job leaves the ring when its last task is handed out or
 * it is cancelled. A cancelled job with no task running is put on the
 * `finishing` list so a worker, not the canceller, calls its done callback.
 *
 * A parallel loop is a helper job whose context, the loop, holds the index
 * counter; the job's references keep the loop alive for helper tasks that
 * start after the caller has returned. See the end of this file.
 */
#include <pthread.h>
#include <stdatomic.h>
#include <stdlib.h>

#include "arbor/pool.h"
#include "arbor/sys.h"

struct arbor_job {
    arbor_task_fn run;
    arbor_job_done_fn done;
    arbor_job_release_fn release;
    void *ctx;
    uint32_t ntasks;
    atomic_int refs;  /* caller's + the pool's while submitted */
    arbor_pool *pool; /* set once by submit */

    /* protected by pool->lock from submission on */
    uint32_t next_task;       /* tasks handed out */
    uint32_t running;         /* handed out, not yet finished */
    uint32_t completed;       /* finished */
    bool cancelled;           /* cancel was asked for before finishing */
    bool finishing;           /* done is being (or has been) called; no more state changes */
    bool finished;            /* done has returned */
    arbor_job *prev, *next;   /* ring links, when in the ring */
    arbor_job *finish_next;   /* `finishing` list link */
};

struct arbor_pool {
    pthread_mutex_t lock;
    pthread_cond_t work;     /* signalled when a task or a finishing job appears, or on shutdown */
    pthread_cond_t finished; /* broadcast when any job's done has returned */
    arbor_job *ring;         /* protected by lock: next job to take a task from; NULL when none */
    arbor_job *finishing;    /* protected by lock: cancelled jobs waiting for a worker to call done */
    bool shutting_down;      /* protected by lock */
    int nthreads;
    pthread_t *threads;
};

/* Removes j from the ring (lock held). */
static void ring_remove(arbor_pool *p, arbor_job *j)
{
    if (j->next == j) {
        p->ring = NULL;
    } else {
        j->prev->next = j->next;
        j->next->prev = j->prev;
        if (p->ring == j)
            p->ring = j->next;
    }
    j->prev = j->next = NULL;
}

/* Appends j just before the cursor, so it is served last in this round (lock held). */
static void ring_insert(arbor_pool *p, arbor_job *j)
{
    if (p->ring == NULL) {
        j->prev = j->next = j;
        p->ring = j;
    } else {
        j->next = p->ring;
        j->prev = p->ring->prev;
        j->prev->next = j;
        p->ring->prev = j;
    }
}

static bool in_ring(const arbor_job *j)
{
    return j->next != NULL;
}

/* The last reference is gone: tell the owner, then free. */
static void job_destroy(arbor_job *j)
{
    if (j->release != NULL)
        j->release(j->ctx);
    free(j);
}

/* Marks j cancelled (lock held); queues it for a worker if nothing of it runs. */
static void cancel_locked(arbor_pool *p, arbor_job *j)
{
    if (j->finishing)
        return;
    j->cancelled = true;
    if (in_ring(j))
        ring_remove(p, j);
    if (j->running == 0) {
        j->finishing = true;
        j->finish_next = p->finishing;
        p->finishing = j;
        pthread_cond_signal(&p->work);
    }
}

/* Calls done outside the lock, then publishes `finished` and drops the
 * pool's reference. Entered with the lock held and j->finishing set; returns
 * with the lock held. */
static void finish_job(arbor_pool *p, arbor_job *j)
{
    bool cancelled = j->completed < j->ntasks;
    pthread_mutex_unlock(&p->lock);
    if (j->done != NULL)
        j->done(j->ctx, cancelled);
    pthread_mutex_lock(&p->lock);
    j->finished = true;
    pthread_cond_broadcast(&p->finished);
    /* Drop the pool's reference before unlocking: waiters need the lock to
     * see `finished`, so when arbor_job_wait returns only the caller's
     * references are left and its release is the one that frees the job. */
    bool last = atomic_fetch_sub(&j->refs, 1) == 1;
    pthread_mutex_unlock(&p->lock);
    if (last)
        job_destroy(j);
    pthread_mutex_lock(&p->lock);
}

/* Runs one task of the job under the cursor (lock held on entry and exit). */
static void run_next_task(arbor_pool *p)
{
    arbor_job *j = p->ring;
    uint32_t task = j->next_task++;
    j->running++;
    if (j->next_task == j->ntasks)
        ring_remove(p, j);
    else
        p->ring = j->next;
    pthread_mutex_unlock(&p->lock);
    j->run(j->ctx, task);
    pthread_mutex_lock(&p->lock);
    j->running--;
    j->completed++;
    if (j->running == 0 && !j->finishing && (j->completed == j->ntasks || j->cancelled)) {
        j->finishing = true;
        finish_job(p, j);
    }
}

static void *worker_main(void *arg)
{
    arbor_pool *p = arg;
    pthread_mutex_lock(&p->lock);
    for (;;) {
        if (p->finishing != NULL) {
            arbor_job *j = p->finishing;
            p->finishing = j->finish_next;
            finish_job(p, j);
        } else if (p->ring != NULL) {
            run_next_task(p);
        } else if (p->shutting_down) {
            break;
        } else {
            pthread_cond_wait(&p->work, &p->lock);
        }
    }
    pthread_mutex_unlock(&p->lock);
    return NULL;
}

arbor_pool *arbor_pool_create(int threads, arbor_err *e)
{
    if (threads < 0) {
        arbor_fail(e, ARBOR_ERR_INVALID, "pool threads must be >= 0, not %d", threads);
        return NULL;
    }
    if (threads == 0)
        threads = arbor_cpu_count();
    arbor_pool *p = calloc(1, sizeof *p);
    if (p == NULL || (p->threads = calloc((size_t)threads, sizeof *p->threads)) == NULL) {
        free(p);
        arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory creating a pool of %d threads", threads);
        return NULL;
    }
    pthread_mutex_init(&p->lock, NULL);
    pthread_cond_init(&p->work, NULL);
    pthread_cond_init(&p->finished, NULL);
    for (int i = 0; i < threads; i++) {
        if (pthread_create(&p->threads[i], NULL, worker_main, p) != 0) {
            p->nthreads = i;
            arbor_pool_destroy(p);
            arbor_fail(e, ARBOR_ERR_NOMEM, "cannot start worker thread %d of %d", i + 1, threads);
            return NULL;
        }
    }
    p->nthreads = threads;
    return p;
}

int arbor_pool_threads(const arbor_pool *p)
{
    return p->nthreads;
}

void arbor_pool_destroy(arbor_pool *p)
{
    if (p == NULL)
        return;
    pthread_mutex_lock(&p->lock);
    p->shutting_down = true;
    while (p->ring != NULL)
        cancel_locked(p, p->ring);
    pthread_cond_broadcast(&p->work);
    pthread_mutex_unlock(&p->lock);
    for (int i = 0; i < p->nthreads; i++)
        pthread_join(p->threads[i], NULL);
    pthread_cond_destroy(&p->finished);
    pthread_cond_destroy(&p->work);
    pthread_mutex_destroy(&p->lock);
    free(p->threads);
    free(p);
}

arbor_job *arbor_job_new(uint32_t ntasks, arbor_task_fn run, arbor_job_done_fn done, arbor_job_release_fn release,
                         void *ctx, arbor_err *e)
{
    if (ntasks == 0) {
        arbor_fail(e, ARBOR_ERR_INVALID, "a job needs at least one task");
        return NULL;
    }
    arbor_job *j = calloc(1, sizeof *j);
    if (j == NULL) {
        arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory creating a job");
        return NULL;
    }
    j->run = run;
    j->done = done;
    j->release = release;
    j->ctx = ctx;
    j->ntasks = ntasks;
    atomic_init(&j->refs, 1);
    return j;
}

bool arbor_pool_submit(arbor_pool *p, arbor_job *j, arbor_err *e)
{
    pthread_mutex_lock(&p->lock);
    if (p->shutting_down || j->pool != NULL) {
        pthread_mutex_unlock(&p->lock);
        return arbor_fail(e, p->shutting_down ? ARBOR_ERR_CANCELLED : ARBOR_ERR_INVALID,
                          p->shutting_down ? "the pool is shutting down" : "job submitted twice");
    }
    j->pool = p;
    atomic_fetch_add(&j->refs, 1);
    ring_insert(p, j);
    pthread_cond_signal(&p->work);
    pthread_mutex_unlock(&p->lock);
    return true;
}

void arbor_job_cancel(arbor_job *j)
{
    arbor_pool *p = j->pool;
    if (p == NULL)
        return;
    pthread_mutex_lock(&p->lock);
    cancel_locked(p, j);
    pthread_mutex_unlock(&p->lock);
}

bool arbor_job_wait(arbor_job *j)
{
    arbor_pool *p = j->pool;
    pthread_mutex_lock(&p->lock);
    while (!j->finished)
        pthread_cond_wait(&p->finished, &p->lock);
    bool complete = j->completed == j->ntasks;
    pthread_mutex_unlock(&p->lock);
    return complete;
}

void arbor_job_release(arbor_job *j)
{
    if (j != NULL && atomic_fetch_sub(&j->refs, 1) == 1)
        job_destroy(j);
}

/* ---- parallel loops ---- */

/* One loop, the context of its helper job. `budget` may be touched only by
 * a helper counted in `active` that found the loop open: the caller waits
 * for those before it returns, and the budget need not outlive the caller. */
typedef struct {
    void (*fn)(void *ctx, uint32_t i);
    void *ctx;
    uint32_t n;
    atomic_uint_fast64_t next; /* the next index to claim; 64 bits, so claims past n cannot wrap */
    atomic_uint active;        /* helpers between their start and their end */
    atomic_bool closed;        /* every index is claimed: a helper starting now must do nothing */
    arbor_pool_budget *budget;
    pthread_mutex_t lock;
    pthread_cond_t idle;       /* broadcast when `active` drops to 0 */
} parallel_loop;

void arbor_pool_budget_init(arbor_pool_budget *b, const arbor_pool *p, uint32_t threads)
{
    if (threads == 0)
        threads = p != NULL ? (uint32_t)p->nthreads : 1;
    if (threads > (uint32_t)INT32_MAX)
        threads = (uint32_t)INT32_MAX;
    atomic_init(&b->spare, (int)threads - 1);
    b->helpers = (int)threads - 1;
}

int arbor_pool_budget_spare(const arbor_pool_budget *b)
{
    return atomic_load_explicit(&b->spare, memory_order_relaxed);
}

static bool budget_take(arbor_pool_budget *b)
{
    int spare = atomic_load_explicit(&b->spare, memory_order_relaxed);
    while (spare > 0)
        if (atomic_compare_exchange_weak(&b->spare, &spare, spare - 1))
            return true;
    return false;
}

static void budget_give(arbor_pool_budget *b)
{
    atomic_fetch_add(&b->spare, 1);
}

/* Runs indices until none is left to claim. */
static void loop_claim(parallel_loop *l)
{
    for (uint64_t i; (i = atomic_fetch_add_explicit(&l->next, 1, memory_order_relaxed)) < l->n;)
        l->fn(l->ctx, (uint32_t)i);
}

/* A helper task. It registers in `active` before it looks at `closed`
 * (the caller sets `closed` before it reads `active`; both sequentially
 * consistent), so either the caller waits for it or it sees the loop closed
 * and leaves the budget alone. */
static void loop_help(void *arg, uint32_t task)
{
    (void)task;
    parallel_loop *l = arg;
    atomic_fetch_add(&l->active, 1);
    if (!atomic_load(&l->closed) && budget_take(l->budget)) {
        loop_claim(l);
        budget_give(l->budget);
    }
    if (atomic_fetch_sub(&l->active, 1) == 1) {
        pthread_mutex_lock(&l->lock);
        pthread_cond_broadcast(&l->idle);
        pthread_mutex_unlock(&l->lock);
    }
}

/* The helper job's last reference is gone. */
static void loop_free(void *arg)
{
    parallel_loop *l = arg;
    pthread_cond_destroy(&l->idle);
    pthread_mutex_destroy(&l->lock);
    free(l);
}

/* A submitted helper job of `helpers` tasks for the loop, or NULL when one
 * cannot be had (out of memory, the pool shutting down). */
static arbor_job *loop_start(arbor_pool *p, arbor_pool_budget *b, uint32_t n, uint32_t helpers,
                             void (*fn)(void *ctx, uint32_t i), void *ctx)
{
    parallel_loop *l = calloc(1, sizeof *l);
    if (l == NULL)
        return NULL;
    l->fn = fn;
    l->ctx = ctx;
    l->n = n;
    l->budget = b;
    atomic_init(&l->next, 0);
    atomic_init(&l->active, 0);
    atomic_init(&l->closed, false);
    pthread_mutex_init(&l->lock, NULL);
    pthread_cond_init(&l->idle, NULL);
    arbor_job *j = arbor_job_new(helpers, loop_help, NULL, loop_free, l, NULL);
    if (j == NULL) {
        loop_free(l);
        return NULL;
    }
    if (!arbor_pool_submit(p, j, NULL)) {
        arbor_job_release(j);
        return NULL;
    }
    return j;
}

/* The caller's part: indices until none is left, then the wait for the
 * helpers still running. They are running (not queued), so they finish. */
static void loop_finish(arbor_job *j)
{
    parallel_loop *l = j->ctx;
    loop_claim(l);
    atomic_store(&l->closed, true);
    arbor_job_cancel(j);
    pthread_mutex_lock(&l->lock);
    while (atomic_load(&l->active) != 0)
        pthread_cond_wait(&l->idle, &l->lock);
    pthread_mutex_unlock(&l->lock);
    arbor_job_release(j);
}

void arbor_pool_parallel_within(arbor_pool *p, arbor_pool_budget *b, uint32_t n, void (*fn)(void *ctx, uint32_t i),
                                void *ctx)
{
    /* No more helpers than indices to share, workers, or threads the budget
     * allows besides the caller (not only those spare now: see pool.h). A
     * budget of one thread costs the loop no allocation at all. */
    uint32_t helpers = p != NULL && n > 1 && b->helpers > 0 ? n - 1 : 0;
    if (helpers > (uint32_t)b->helpers)
        helpers = (uint32_t)b->helpers;
    if (p != NULL && helpers > (uint32_t)p->nthreads)
        helpers = (uint32_t)p->nthreads;
    arbor_job *j = helpers > 0 ? loop_start(p, b, n, helpers, fn, ctx) : NULL;
    if (j != NULL) {
        loop_finish(j);
        return;
    }
    for (uint32_t i = 0; i < n; i++)
        fn(ctx, i);
}

void arbor_pool_parallel(arbor_pool *p, uint32_t n, uint32_t max_threads, void (*fn)(void *ctx, uint32_t i), void *ctx)
{
    arbor_pool_budget b;
    arbor_pool_budget_init(&b, p, max_threads);
    arbor_pool_parallel_within(p, &b, n, fn, ctx);
}
