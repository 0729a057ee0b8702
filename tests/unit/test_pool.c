/*
 * test_pool.c - the worker pool: every task runs once, done runs once on a
 * worker, jobs in flight are served round-robin, cancel stops a job between
 * tasks, destroy cancels what is queued; parallel loops run every index
 * once, from any thread, nested inside pool tasks with every worker busy,
 * without a pool, within their thread limits, with the same results on any
 * number of threads. A deadlock ends the binary by SIGALRM (a failure).
 */
#include <pthread.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

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

/* ---- parallel loops ---- */

#define LOOP_N 20000

typedef struct {
    atomic_int runs[LOOP_N];
    uint64_t value[LOOP_N];
    atomic_int running, most_running; /* indices running at once, and the most seen */
    long nap_us;                      /* each index sleeps this long (0: none) */
    pthread_t only_thread;            /* when check_thread: every index must run on it */
    bool check_thread;
    atomic_bool wrong_thread;
} loop_log;

static loop_log *new_loop_log(void)
{
    loop_log *l = calloc(1, sizeof *l);
    TEST_ASSERT_NOT_NULL(l);
    return l;
}

static uint64_t mix(uint64_t x)
{
    x ^= x >> 33;
    x *= 0xff51afd7ed558ccdULL;
    x ^= x >> 33;
    return x;
}

static void loop_index(void *ctx, uint32_t i)
{
    loop_log *l = ctx;
    int now = atomic_fetch_add(&l->running, 1) + 1;
    for (int most = atomic_load(&l->most_running); now > most;)
        if (atomic_compare_exchange_weak(&l->most_running, &most, now))
            break;
    if (l->check_thread && !pthread_equal(pthread_self(), l->only_thread))
        atomic_store(&l->wrong_thread, true);
    if (l->nap_us > 0) {
        struct timespec ts = {0, l->nap_us * 1000L};
        nanosleep(&ts, NULL);
    }
    l->value[i] = mix(i + 1);
    atomic_fetch_add(&l->runs[i], 1);
    atomic_fetch_sub(&l->running, 1);
}

static void assert_each_ran_once(loop_log *l, uint32_t n)
{
    for (uint32_t i = 0; i < LOOP_N; i++)
        TEST_ASSERT_EQUAL_INT_MESSAGE(i < n ? 1 : 0, atomic_load(&l->runs[i]), "index runs");
}

static void test_parallel_runs_every_index_once(void)
{
    arbor_err e;
    arbor_pool *p = arbor_pool_create(3, &e);
    TEST_ASSERT_NOT_NULL(p);
    const uint32_t sizes[] = {0, 1, 2, 3, 7, 1000, LOOP_N};
    const uint32_t limits[] = {0, 1, 2, 4, 64};
    for (size_t s = 0; s < sizeof sizes / sizeof *sizes; s++)
        for (size_t t = 0; t < sizeof limits / sizeof *limits; t++) {
            loop_log *l = new_loop_log();
            arbor_pool_parallel(p, sizes[s], limits[t], loop_index, l);
            assert_each_ran_once(l, sizes[s]);
            free(l);
        }
    arbor_pool_destroy(p);
}

static void test_parallel_without_a_pool_runs_on_the_caller(void)
{
    loop_log *l = new_loop_log();
    l->check_thread = true;
    l->only_thread = pthread_self();
    arbor_pool_parallel(NULL, 1000, 8, loop_index, l);
    assert_each_ran_once(l, 1000);
    TEST_ASSERT_FALSE(atomic_load(&l->wrong_thread));
    TEST_ASSERT_EQUAL_INT(1, atomic_load(&l->most_running));
    free(l);
}

/* A loop limited to max_threads never runs more indices at once, and with
 * idle workers and slow indices it does use more than the caller. */
static void test_parallel_stays_within_max_threads(void)
{
    arbor_err e;
    arbor_pool *p = arbor_pool_create(4, &e);
    TEST_ASSERT_NOT_NULL(p);
    for (uint32_t max = 1; max <= 3; max++) {
        loop_log *l = new_loop_log();
        l->nap_us = 2000;
        arbor_pool_parallel(p, 100, max, loop_index, l);
        assert_each_ran_once(l, 100);
        TEST_ASSERT_TRUE(atomic_load(&l->most_running) <= (int)max);
        if (max > 1) {
            TEST_ASSERT_TRUE(atomic_load(&l->most_running) > 1);
        }
        free(l);
    }
    arbor_pool_destroy(p);
}

/* Nested loops: each index of a level runs a loop of NEST_WIDTH indices of
 * the next level, NEST_LEVELS deep; the leaves count themselves. */
#define NEST_LEVELS 4
#define NEST_WIDTH 4
#define NEST_LEAVES (NEST_WIDTH * NEST_WIDTH * NEST_WIDTH * NEST_WIDTH)

typedef struct {
    arbor_pool *pool;
    arbor_pool_budget *budget; /* NULL: each loop limited to NEST_WIDTH threads on its own */
    atomic_int leaf_runs[NEST_LEAVES];
    atomic_int running, most_running;
} nest;

typedef struct {
    nest *n;
    uint32_t level, base; /* base: the leaf number of this subtree's first leaf */
} nest_node;

static void nest_index(void *ctx, uint32_t i);

static void nest_run(nest *n, uint32_t level, uint32_t base)
{
    nest_node node = {n, level, base};
    if (n->budget != NULL)
        arbor_pool_parallel_within(n->pool, n->budget, NEST_WIDTH, nest_index, &node);
    else
        arbor_pool_parallel(n->pool, NEST_WIDTH, NEST_WIDTH, nest_index, &node);
}

static void nest_index(void *ctx, uint32_t i)
{
    const nest_node *node = ctx;
    nest *n = node->n;
    uint32_t base = node->base * NEST_WIDTH + i;
    if (node->level + 1 < NEST_LEVELS) {
        nest_run(n, node->level + 1, base);
        return;
    }
    int now = atomic_fetch_add(&n->running, 1) + 1;
    for (int most = atomic_load(&n->most_running); now > most;)
        if (atomic_compare_exchange_weak(&n->most_running, &most, now))
            break;
    nap_ms(1);
    atomic_fetch_add(&n->leaf_runs[base], 1);
    atomic_fetch_sub(&n->running, 1);
}

static void nest_task(void *ctx, uint32_t task)
{
    (void)task;
    nest_run(ctx, 0, 0);
}

static void assert_every_leaf_once(nest *n)
{
    for (uint32_t i = 0; i < NEST_LEAVES; i++)
        TEST_ASSERT_EQUAL_INT_MESSAGE(1, atomic_load(&n->leaf_runs[i]), "leaf runs");
}

/* Every worker of a pool of 2 runs a task that runs a 4-level nested loop:
 * no worker is idle to help, so each caller must get through alone. */
static void test_nested_parallel_inside_busy_workers(void)
{
    arbor_err e;
    arbor_pool *p = arbor_pool_create(2, &e);
    TEST_ASSERT_NOT_NULL(p);
    nest *trees[2];
    arbor_job *jobs[2];
    for (int k = 0; k < 2; k++) {
        trees[k] = calloc(1, sizeof *trees[k]);
        trees[k]->pool = p;
        jobs[k] = arbor_job_new(1, nest_task, NULL, NULL, trees[k], &e);
        TEST_ASSERT_NOT_NULL(jobs[k]);
        TEST_ASSERT_TRUE(arbor_pool_submit(p, jobs[k], &e));
    }
    /* and a third nest from this thread at the same time */
    nest *outside = calloc(1, sizeof *outside);
    outside->pool = p;
    nest_run(outside, 0, 0);
    for (int k = 0; k < 2; k++) {
        TEST_ASSERT_TRUE(arbor_job_wait(jobs[k]));
        arbor_job_release(jobs[k]);
        assert_every_leaf_once(trees[k]);
        free(trees[k]);
    }
    assert_every_leaf_once(outside);
    free(outside);
    arbor_pool_destroy(p);
}

/* A budget shared by every level of a nested loop holds the whole nest to
 * its thread count, however many loops fork. */
static void test_budget_limits_a_whole_nest(void)
{
    arbor_err e;
    arbor_pool *p = arbor_pool_create(4, &e);
    TEST_ASSERT_NOT_NULL(p);
    for (uint32_t threads = 1; threads <= 3; threads++) {
        arbor_pool_budget b;
        arbor_pool_budget_init(&b, p, threads);
        TEST_ASSERT_EQUAL_INT((int)threads - 1, arbor_pool_budget_spare(&b));
        nest *n = calloc(1, sizeof *n);
        n->pool = p;
        n->budget = &b;
        nest_run(n, 0, 0);
        assert_every_leaf_once(n);
        TEST_ASSERT_TRUE(atomic_load(&n->most_running) <= (int)threads);
        TEST_ASSERT_EQUAL_INT((int)threads - 1, arbor_pool_budget_spare(&b));
        free(n);
    }
    /* without a pool, and without a thread count, the caller alone */
    arbor_pool_budget alone;
    arbor_pool_budget_init(&alone, NULL, 0);
    TEST_ASSERT_EQUAL_INT(0, arbor_pool_budget_spare(&alone));
    arbor_pool_destroy(p);
}

/* The same values in every slot whatever the pool and thread limit. */
static void test_parallel_results_do_not_depend_on_threads(void)
{
    arbor_err e;
    arbor_pool *pools[3] = {NULL, arbor_pool_create(1, &e), arbor_pool_create(4, &e)};
    TEST_ASSERT_NOT_NULL(pools[1]);
    TEST_ASSERT_NOT_NULL(pools[2]);
    loop_log *first = NULL;
    for (int k = 0; k < 3; k++)
        for (uint32_t max = 0; max <= 5; max++) {
            loop_log *l = new_loop_log();
            arbor_pool_parallel(pools[k], LOOP_N, max, loop_index, l);
            assert_each_ran_once(l, LOOP_N);
            if (first == NULL)
                first = l;
            else {
                TEST_ASSERT_EQUAL_MEMORY(first->value, l->value, sizeof l->value);
                free(l);
            }
        }
    free(first);
    arbor_pool_destroy(pools[1]);
    arbor_pool_destroy(pools[2]);
}

/* The only worker is held busy, so the loop's helper task waits in the
 * queue while the caller runs every index; the helper is cancelled and
 * never runs, and the loop's memory is freed later (ASan checks that). Then
 * many quick loops race their helpers' starts against their callers' ends. */
static void test_loop_helpers_that_start_late_or_never(void)
{
    arbor_err e;
    arbor_pool *p = arbor_pool_create(1, &e);
    TEST_ASSERT_NOT_NULL(p);
    atomic_bool gate = false, began = false;
    job_log *busy = new_log(1);
    busy->gate = &gate;
    busy->task0_began = &began;
    arbor_job *j = arbor_job_new(1, log_task, log_done, NULL, busy, &e);
    TEST_ASSERT_TRUE(arbor_pool_submit(p, j, &e));
    while (!atomic_load(&began))
        nap_ms(1);
    loop_log *l = new_loop_log();
    l->check_thread = true;
    l->only_thread = pthread_self();
    arbor_pool_parallel(p, 100, 2, loop_index, l);
    assert_each_ran_once(l, 100);
    TEST_ASSERT_FALSE(atomic_load(&l->wrong_thread));
    free(l);
    atomic_store(&gate, true);
    TEST_ASSERT_TRUE(arbor_job_wait(j));
    arbor_job_release(j);
    free(busy);
    arbor_pool_destroy(p);

    p = arbor_pool_create(2, &e);
    TEST_ASSERT_NOT_NULL(p);
    for (int round = 0; round < 2000; round++) {
        l = new_loop_log();
        arbor_pool_parallel(p, 2, 3, loop_index, l);
        assert_each_ran_once(l, 2);
        free(l);
    }
    arbor_pool_destroy(p);
}

int main(void)
{
    alarm(120);
    UNITY_BEGIN();
    RUN_TEST(test_every_task_runs_once_and_done_on_a_worker);
    RUN_TEST(test_many_jobs_at_once_all_complete);
    RUN_TEST(test_jobs_in_flight_share_the_worker_round_robin);
    RUN_TEST(test_cancel_stops_a_job_between_tasks);
    RUN_TEST(test_cancel_of_a_queued_job_calls_done_on_a_worker);
    RUN_TEST(test_destroy_cancels_queued_jobs);
    RUN_TEST(test_bad_arguments);
    RUN_TEST(test_parallel_runs_every_index_once);
    RUN_TEST(test_parallel_without_a_pool_runs_on_the_caller);
    RUN_TEST(test_parallel_stays_within_max_threads);
    RUN_TEST(test_nested_parallel_inside_busy_workers);
    RUN_TEST(test_budget_limits_a_whole_nest);
    RUN_TEST(test_parallel_results_do_not_depend_on_threads);
    RUN_TEST(test_loop_helpers_that_start_late_or_never);
    return UNITY_END();
}
