/*
 * pool.c - worker threads running jobs split into tasks, round-robin over
 * the jobs in flight (see include/arbor/pool.h).
 *
 * Every piece of scheduling state lives under the pool's one mutex, taken
 * once to fetch a task and once to account for it, never while a task runs.
 * Jobs that still have tasks to hand out form a circular list (the "ring");
 * the pool's cursor points at the job the next fetch takes from and moves on
 * after each fetch. A job leaves the ring when its last task is handed out or
 * it is cancelled. A cancelled job with no task running is put on the
 * `finishing` list so a worker, not the canceller, calls its done callback.
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

/* Marks j cancelled (lock held); queues it for a worker if nothing of it runs. */
/* The last reference is gone: tell the owner, then free. */
static void job_destroy(arbor_job *j)
{
    if (j->release != NULL)
        j->release(j->ctx);
    free(j);
}

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
                          p->shutting_down ? "the render pool is shutting down" : "job submitted twice");
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
