/*
 * test_pool.c - the worker pool: every task runs once, done runs once on a
 * worker, jobs in flight are served round-robin, cancel stops a job between
 * tasks, destroy cancels what is queued.
 */
#include <pthread.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "arbor/pool.h"
#include "support.h"
#include "unity.h"

#define MAX_TASKS 4096

/* One job's record; `order` collects the tags of tasks in the order any job ran them. */
typedef struct {
    int tag;
    atomic_int runs[MAX_TASKS];
    atomic_int done_calls;
    atomic_bool cancelled;
    pthread_t done_thread;
    atomic_bool *gate;        /* task 0 waits until *gate is true (NULL: no wait) */
    atomic_bool *task0_began; /* set when task 0 starts (may be NULL) */
    int *order;               /* shared log of tags; protected by order_lock */
    int *norder;
    pthread_mutex_t *order_lock;
    atomic_bool released;
} job_log;

void setUp(void) {}
void tearDown(void) {}

static void nap_ms(long ms)
{
    struct timespec ts = {ms / 1000, (ms % 1000) * 1000000L};
    nanosleep(&ts, NULL);
}

static void log_task(void *ctx, uint32_t task)
{
    job_log *l = ctx;
    if (task == 0 && l->task0_began != NULL)
        atomic_store(l->task0_began, true);
    if (task == 0 && l->gate != NULL)
        while (!atomic_load(l->gate))
            nap_ms(1);
    atomic_fetch_add(&l->runs[task], 1);
    if (l->order != NULL) {
        pthread_mutex_lock(l->order_lock);
        l->order[(*l->norder)++] = l->tag;
        pthread_mutex_unlock(l->order_lock);
    }
}

static void log_done(void *ctx, bool cancelled)
{
    job_log *l = ctx;
    l->done_thread = pthread_self();
    atomic_store(&l->cancelled, cancelled);
    atomic_fetch_add(&l->done_calls, 1);
}

static void log_release(void *ctx)
{
    job_log *l = ctx;
    atomic_store(&l->released, true);
}

static job_log *new_log(int tag)
{
    job_log *l = calloc(1, sizeof *l);
    l->tag = tag;
    return l;
}

static int total_runs(job_log *l, uint32_t n)
{
    int sum = 0;
    for (uint32_t i = 0; i < n; i++)
        sum += atomic_load(&l->runs[i]);
    return sum;
}

static void test_every_task_runs_once_and_done_on_a_worker(void)
{
    arbor_err e;
    arbor_pool *p = arbor_pool_create(3, &e);
    TEST_ASSERT_NOT_NULL(p);
    TEST_ASSERT_EQUAL_INT(3, arbor_pool_threads(p));
    job_log *l = new_log(1);
    arbor_job *j = arbor_job_new(1000, log_task, log_done, log_release, l, &e);
    TEST_ASSERT_TRUE(arbor_pool_submit(p, j, &e));
    TEST_ASSERT_TRUE(arbor_job_wait(j));
    for (int i = 0; i < 1000; i++)
        TEST_ASSERT_EQUAL_INT(1, atomic_load(&l->runs[i]));
    TEST_ASSERT_EQUAL_INT(1, atomic_load(&l->done_calls));
    TEST_ASSERT_FALSE(atomic_load(&l->cancelled));
    TEST_ASSERT_FALSE(pthread_equal(l->done_thread, pthread_self()));
    /* submitting the same job again is refused */
    TEST_ASSERT_FALSE(arbor_pool_submit(p, j, &e));
    TEST_ASSERT_EQUAL_INT(ARBOR_ERR_INVALID, e.status);
    TEST_ASSERT_FALSE(atomic_load(&l->released));
    arbor_job_release(j);
    TEST_ASSERT_TRUE(atomic_load(&l->released));
    arbor_pool_destroy(p);
    free(l);
}

static void test_many_jobs_at_once_all_complete(void)
{
    arbor_err e;
    arbor_pool *p = arbor_pool_create(2, &e);
    enum { NJOBS = 12 };
    job_log *logs[NJOBS];
    arbor_job *jobs[NJOBS];
    for (int k = 0; k < NJOBS; k++) {
        logs[k] = new_log(k);
        jobs[k] = arbor_job_new((uint32_t)(50 + 37 * k), log_task, log_done, NULL, logs[k], &e);
        TEST_ASSERT_TRUE(arbor_pool_submit(p, jobs[k], &e));
    }
    for (int k = NJOBS - 1; k >= 0; k--) {
        TEST_ASSERT_TRUE(arbor_job_wait(jobs[k]));
        TEST_ASSERT_EQUAL_INT(50 + 37 * k, total_runs(logs[k], MAX_TASKS));
        TEST_ASSERT_EQUAL_INT(1, atomic_load(&logs[k]->done_calls));
        arbor_job_release(jobs[k]);
        free(logs[k]);
    }
    arbor_pool_destroy(p);
}

/* With one worker held in job A's first task while job B is submitted, the
 * worker then alternates: A, A, B, A, B, ... until one job runs out. */
static void test_jobs_in_flight_share_the_worker_round_robin(void)
{
    arbor_err e;
    arbor_pool *p = arbor_pool_create(1, &e);
    static int order[64];
    int norder = 0;
    pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
    atomic_bool gate = false, began = false;
    job_log *a = new_log(0), *b = new_log(1);
    a->order = b->order = order;
    a->norder = b->norder = &norder;
    a->order_lock = b->order_lock = &lock;
    a->gate = &gate;
    a->task0_began = &began;
    arbor_job *ja = arbor_job_new(10, log_task, log_done, NULL, a, &e);
    arbor_job *jb = arbor_job_new(10, log_task, log_done, NULL, b, &e);
    TEST_ASSERT_TRUE(arbor_pool_submit(p, ja, &e));
    while (!atomic_load(&began))
        nap_ms(1);
    TEST_ASSERT_TRUE(arbor_pool_submit(p, jb, &e));
    atomic_store(&gate, true);
    arbor_job_wait(ja);
    arbor_job_wait(jb);
    TEST_ASSERT_EQUAL_INT(20, norder);
    TEST_ASSERT_EQUAL_INT(0, order[0]);
    for (int i = 1; i < 19; i++)
        TEST_ASSERT_EQUAL_INT_MESSAGE((i + 1) % 2, order[i], "tasks did not alternate between the jobs");
    arbor_job_release(ja);
    arbor_job_release(jb);
    arbor_pool_destroy(p);
    free(a);
    free(b);
}

static void test_cancel_stops_a_job_between_tasks(void)
{
    arbor_err e;
    arbor_pool *p = arbor_pool_create(1, &e);
    atomic_bool gate = false, began = false;
    job_log *l = new_log(0);
    l->gate = &gate;
    l->task0_began = &began;
    arbor_job *j = arbor_job_new(MAX_TASKS, log_task, log_done, NULL, l, &e);
    TEST_ASSERT_TRUE(arbor_pool_submit(p, j, &e));
    while (!atomic_load(&began))
        nap_ms(1);
    arbor_job_cancel(j);
    atomic_store(&gate, true);
    TEST_ASSERT_FALSE(arbor_job_wait(j));
    TEST_ASSERT_TRUE(atomic_load(&l->cancelled));
    TEST_ASSERT_EQUAL_INT(1, total_runs(l, MAX_TASKS)); /* only the task that was running */
    TEST_ASSERT_EQUAL_INT(1, atomic_load(&l->done_calls));
    TEST_ASSERT_FALSE(pthread_equal(l->done_thread, pthread_self()));
    arbor_job_cancel(j); /* after the end: a no-op */
    TEST_ASSERT_EQUAL_INT(1, atomic_load(&l->done_calls));
    arbor_job_release(j);
    arbor_pool_destroy(p);
    free(l);
}

static void test_cancel_of_a_queued_job_calls_done_on_a_worker(void)
{
    arbor_err e;
    arbor_pool *p = arbor_pool_create(1, &e);
    atomic_bool gate = false, began = false;
    job_log *busy = new_log(0), *queued = new_log(1);
    busy->gate = &gate;
    busy->task0_began = &began;
    arbor_job *jb = arbor_job_new(1, log_task, log_done, NULL, busy, &e);
    arbor_job *jq = arbor_job_new(100, log_task, log_done, NULL, queued, &e);
    arbor_pool_submit(p, jb, &e);
    while (!atomic_load(&began))
        nap_ms(1);
    arbor_pool_submit(p, jq, &e);
    arbor_job_cancel(jq);
    atomic_store(&gate, true);
    TEST_ASSERT_FALSE(arbor_job_wait(jq));
    TEST_ASSERT_TRUE(arbor_job_wait(jb));
    TEST_ASSERT_EQUAL_INT(0, total_runs(queued, MAX_TASKS));
    TEST_ASSERT_TRUE(atomic_load(&queued->cancelled));
    TEST_ASSERT_FALSE(pthread_equal(queued->done_thread, pthread_self()));
    arbor_job_release(jb);
    arbor_job_release(jq);
    arbor_pool_destroy(p);
    free(busy);
    free(queued);
}

typedef struct {
    arbor_pool *pool;
} destroyer;

static void *destroy_pool(void *arg)
{
    arbor_pool_destroy(((destroyer *)arg)->pool);
    return NULL;
}

/* destroy while a task runs and another job waits: both are told they were
 * cancelled, on a worker, and destroy returns. */
static void test_destroy_cancels_queued_jobs(void)
{
    arbor_err e;
    arbor_pool *p = arbor_pool_create(1, &e);
    atomic_bool gate = false, began = false;
    job_log *running = new_log(0), *queued = new_log(1);
    running->gate = &gate;
    running->task0_began = &began;
    arbor_job *jr = arbor_job_new(100, log_task, log_done, NULL, running, &e);
    arbor_job *jq = arbor_job_new(100, log_task, log_done, NULL, queued, &e);
    arbor_pool_submit(p, jr, &e);
    while (!atomic_load(&began))
        nap_ms(1);
    arbor_pool_submit(p, jq, &e);
    destroyer d = {p};
    pthread_t th;
    pthread_create(&th, NULL, destroy_pool, &d);
    /* destroy marks the jobs cancelled at once; the nap only makes sure it
     * has done so before task 0 is let go */
    nap_ms(50);
    atomic_store(&gate, true);
    pthread_join(th, NULL);
    TEST_ASSERT_EQUAL_INT(1, atomic_load(&running->done_calls));
    TEST_ASSERT_EQUAL_INT(1, atomic_load(&queued->done_calls));
    TEST_ASSERT_TRUE(atomic_load(&running->cancelled));
    TEST_ASSERT_TRUE(atomic_load(&queued->cancelled));
    TEST_ASSERT_EQUAL_INT(1, total_runs(running, MAX_TASKS));
    TEST_ASSERT_EQUAL_INT(0, total_runs(queued, MAX_TASKS));
    arbor_job_release(jr);
    arbor_job_release(jq);
    free(running);
    free(queued);
}

static void test_bad_arguments(void)
{
    arbor_err e;
    TEST_ASSERT_NULL(arbor_pool_create(-1, &e));
    TEST_ASSERT_EQUAL_INT(ARBOR_ERR_INVALID, e.status);
    TEST_ASSERT_NULL(arbor_job_new(0, log_task, log_done, NULL, NULL, &e));
    TEST_ASSERT_EQUAL_INT(ARBOR_ERR_INVALID, e.status);
}

int main(void)
{
    UNITY_BEGIN();
    RUN_TEST(test_every_task_runs_once_and_done_on_a_worker);
    RUN_TEST(test_many_jobs_at_once_all_complete);
    RUN_TEST(test_jobs_in_flight_share_the_worker_round_robin);
    RUN_TEST(test_cancel_stops_a_job_between_tasks);
    RUN_TEST(test_cancel_of_a_queued_job_calls_done_on_a_worker);
    RUN_TEST(test_destroy_cancels_queued_jobs);
    RUN_TEST(test_bad_arguments);
    return UNITY_END();
}
