/*
 * test_store.c - the model store over a real pool: adding, listing,
 * replacing and removing models; trees acquired ready and pending, built
 * once however many threads ask, equal to trees built directly; references
 * that outlive a remove or a replace; the memory budget (LRU eviction of
 * idle trees only, ARBOR_ERR_NOSPACE with the bytes needed, nothing loaded
 * touched); cancelling; model names; destroy with builds in flight.
 *
 * The meshes are the procedural icospheres of arbor_gen_sphere (level 3:
 * 1,280 triangles, level 4: 5,120, ...), generated twice where a test needs
 * an independent copy to check a tree the store built against brute force.
 */
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "arbor/brute.h"
#include "arbor/procgen.h"
#include "arbor/store.h"
#include "support.h"
#include "unity.h"

#define BUILD_THREADS 2

static arbor_pool *pool;

void setUp(void) {}
void tearDown(void) {}

/* ---- helpers ---- */

static void sleep_ms(long ms)
{
    struct timespec ts = {ms / 1000, (ms % 1000) * 1000000L};
    nanosleep(&ts, NULL);
}

static void make_sphere(arbor_mesh *m, int level)
{
    arbor_err e;
    TEST_ASSERT_TRUE_MESSAGE(arbor_gen_sphere(m, level, &e), e.msg);
}

/* Counts the builds the store reports through on_build. */
typedef struct {
    atomic_int builds, ok;
} build_count;

static void count_build(void *user, arbor_accel_kind kind, arbor_builder builder, double ms, bool ok)
{
    (void)kind, (void)builder, (void)ms;
    build_count *c = user;
    atomic_fetch_add(&c->builds, 1);
    atomic_fetch_add(&c->ok, ok);
}

static arbor_store *store_new(uint64_t max_memory, build_count *count)
{
    arbor_store_config c = {pool, BUILD_THREADS, max_memory, count != NULL ? count_build : NULL, count};
    arbor_err e;
    arbor_store *s = arbor_store_create(&c, &e);
    TEST_ASSERT_NOT_NULL_MESSAGE(s, e.msg);
    return s;
}

/* Adds an icosphere of that level under name; its version. */
static uint64_t add_sphere(arbor_store *s, const char *name, int level, unsigned flags)
{
    arbor_mesh m;
    make_sphere(&m, level);
    uint64_t version = 0;
    arbor_err e;
    TEST_ASSERT_TRUE_MESSAGE(arbor_store_add_model(s, name, "sphere.obj", &m, flags, &version, &e), e.msg);
    TEST_ASSERT_EQUAL_UINT32(0, m.ntris); /* moved into the store */
    arbor_mesh_free(&m);
    return version;
}

/* What a `ready` callback was given; the main thread waits on it. */
typedef struct {
    pthread_mutex_t lock;
    pthread_cond_t cond;
    int calls;
    arbor_tree *tree;
    arbor_err err;
    bool release;   /* release the tree in the callback (destroy tests) */
} ready_box;

static void box_init(ready_box *b)
{
    memset(b, 0, sizeof *b);
    pthread_mutex_init(&b->lock, NULL);
    pthread_cond_init(&b->cond, NULL);
}

static void box_free(ready_box *b)
{
    pthread_mutex_destroy(&b->lock);
    pthread_cond_destroy(&b->cond);
}

static void on_ready(void *user, arbor_tree *t, const arbor_err *e)
{
    ready_box *b = user;
    if (b->release)
        arbor_tree_release(t);
    pthread_mutex_lock(&b->lock);
    b->calls++;
    b->tree = b->release ? NULL : t;
    if (e != NULL)
        b->err = *e;
    pthread_cond_broadcast(&b->cond);
    pthread_mutex_unlock(&b->lock);
}

static void box_wait(ready_box *b)
{
    pthread_mutex_lock(&b->lock);
    while (b->calls == 0)
        pthread_cond_wait(&b->cond, &b->lock);
    pthread_mutex_unlock(&b->lock);
}

static int box_calls(ready_box *b)
{
    pthread_mutex_lock(&b->lock);
    int n = b->calls;
    pthread_mutex_unlock(&b->lock);
    return n;
}

/* The model's tree, built first if need be (READY or PENDING, then waited
 * for); the caller holds the reference. */
static arbor_tree *tree_of(arbor_store *s, arbor_model *m, arbor_accel_kind kind, arbor_builder builder)
{
    ready_box box;
    box_init(&box);
    arbor_tree *t = NULL;
    arbor_err e;
    arbor_acquire r = arbor_store_acquire_tree(s, m, kind, builder, &t, on_ready, &box, &e);
    TEST_ASSERT_NOT_EQUAL_MESSAGE(ARBOR_ACQUIRE_FAILED, r, e.msg);
    if (r == ARBOR_ACQUIRE_PENDING) {
        box_wait(&box);
        TEST_ASSERT_NOT_NULL_MESSAGE(box.tree, box.err.msg);
        t = box.tree;
    }
    TEST_ASSERT_EQUAL_INT(r == ARBOR_ACQUIRE_PENDING, box_calls(&box));
    box_free(&box);
    return t;
}

/* The same by model name; the tree's reference keeps the model. */
static arbor_tree *tree_named(arbor_store *s, const char *name, arbor_accel_kind kind)
{
    arbor_model *m = arbor_store_acquire_model(s, name);
    TEST_ASSERT_NOT_NULL_MESSAGE(m, name);
    arbor_tree *t = tree_of(s, m, kind, ARBOR_BUILD_SAH);
    arbor_model_release(m);
    return t;
}

/* Acquires and releases a tree, which marks it used. */
static void touch(arbor_store *s, const char *name)
{
    arbor_tree_release(tree_named(s, name, ARBOR_ACCEL_BVH));
}

static arbor_tree_state state_of(arbor_store *s, const char *name, arbor_accel_kind kind)
{
    arbor_model *m = arbor_store_acquire_model(s, name);
    TEST_ASSERT_NOT_NULL_MESSAGE(m, name);
    arbor_tree_info info;
    arbor_model_tree_info(s, m, kind, ARBOR_BUILD_SAH, &info);
    arbor_model_release(m);
    return info.state;
}

static arbor_store_usage usage_of(arbor_store *s)
{
    arbor_store_usage u;
    arbor_store_usage_of(s, &u);
    return u;
}

/* The usage once the store is quiet: a build's job counts as building, and
 * holds its model, until just after its waiters have been called, so the
 * counts are polled for up to five seconds before they are asserted. */
static void assert_usage(arbor_store *s, uint64_t models, uint64_t trees)
{
    arbor_store_usage u = usage_of(s);
    for (int i = 0; i < 5000 && !(u.models == models && u.trees == trees && u.building == 0); i++) {
        sleep_ms(1);
        u = usage_of(s);
    }
    TEST_ASSERT_EQUAL_UINT64(models, u.models);
    TEST_ASSERT_EQUAL_UINT64(trees, u.trees);
    TEST_ASSERT_EQUAL_UINT64(0, u.reserved);
    TEST_ASSERT_EQUAL_UINT32(0, u.building);
}

static arbor_accel *build_direct(const arbor_mesh *m, arbor_accel_kind kind, arbor_builder builder)
{
    arbor_build_opts o;
    arbor_build_opts_init(&o, kind, builder);
    o.pool = pool;
    o.threads = BUILD_THREADS;
    o.drop_binary = true; /* as the store builds */
    arbor_err e;
    arbor_accel *a = arbor_accel_build(m, &o, &e);
    TEST_ASSERT_NOT_NULL_MESSAGE(a, e.msg);
    return a;
}

/* Bytes the store counts for a model of an icosphere of that level, and for
 * its bvh sah tree: measured on a store without a budget (a model's bytes
 * include the store's own record of it, which only the store knows). */
static uint64_t model_bytes_of(int level)
{
    arbor_store *s = store_new(0, NULL);
    add_sphere(s, "probe", level, 0);
    arbor_model *m = arbor_store_acquire_model(s, "probe");
    uint64_t b = arbor_model_bytes(m);
    arbor_model_release(m);
    arbor_store_destroy(s);
    return b;
}

static uint64_t tree_bytes_of(int level)
{
    arbor_mesh m;
    make_sphere(&m, level);
    arbor_accel *a = build_direct(&m, ARBOR_ACCEL_BVH, ARBOR_BUILD_SAH);
    arbor_tree_stats st;
    arbor_accel_stats(a, &st);
    arbor_accel_free(a);
    arbor_mesh_free(&m);
    return st.bytes;
}

static void assert_failed(bool ok, const arbor_err *e, arbor_status status)
{
    TEST_ASSERT_FALSE(ok);
    TEST_ASSERT_EQUAL_INT_MESSAGE(status, e->status, e->msg);
}

/* A NOSPACE error names the bytes needed: "needs N bytes"; returns N. */
static uint64_t bytes_needed(const arbor_err *e)
{
    TEST_ASSERT_EQUAL_INT_MESSAGE(ARBOR_ERR_NOSPACE, e->status, e->msg);
    const char *p = strstr(e->msg, "needs ");
    TEST_ASSERT_NOT_NULL_MESSAGE(p, e->msg);
    unsigned long long n = 0;
    char unit[8] = "";
    TEST_ASSERT_EQUAL_INT_MESSAGE(2, sscanf(p, "needs %llu %7s", &n, unit), e->msg);
    TEST_ASSERT_EQUAL_STRING_MESSAGE("bytes;", unit, e->msg);
    return n;
}

static void assert_same_stats(const arbor_tree_stats *want, const arbor_tree_stats *got)
{
    TEST_ASSERT_EQUAL_UINT64(want->nodes, got->nodes);
    TEST_ASSERT_EQUAL_UINT64(want->leaves, got->leaves);
    TEST_ASSERT_EQUAL_UINT64(want->empty_leaves, got->empty_leaves);
    TEST_ASSERT_EQUAL_UINT32(want->max_depth, got->max_depth);
    TEST_ASSERT_EQUAL_DOUBLE(want->mean_leaf_depth, got->mean_leaf_depth);
    TEST_ASSERT_EQUAL_DOUBLE(want->mean_tris_per_leaf, got->mean_tris_per_leaf);
    TEST_ASSERT_EQUAL_UINT64(want->refs, got->refs);
    TEST_ASSERT_EQUAL_UINT64(want->bytes, got->bytes);
    TEST_ASSERT_EQUAL_DOUBLE(want->sah_cost, got->sah_cost);
}

/* Random rays through the tree agree with brute force on `truth`, an
 * independent copy of the tree's mesh. */
static void assert_traces_like_brute_force(const arbor_tree *t, const arbor_mesh *truth)
{
    const size_t n = 1000;
    arbor_ray *rays = test_random_rays(truth, n, 7);
    size_t hits = 0;
    for (size_t i = 0; i < n; i++) {
        arbor_ray a = rays[i], b = rays[i];
        arbor_hit ha, hb;
        bool fa = arbor_accel_intersect(arbor_tree_accel(t), &a, &ha);
        bool fb = arbor_brute_intersect(truth, &b, &hb);
        TEST_ASSERT_EQUAL_INT(fb, fa);
        if (fb) {
            TEST_ASSERT_TRUE(test_close(hb.t, ha.t, 1e-6f));
        }
        hits += fb;
    }
    TEST_ASSERT_TRUE(hits > n / 4);
    free(rays);
}

/* ---- models ---- */

static void test_add_acquire_list_remove(void)
{
    arbor_store *s = store_new(0, NULL);
    const char *names[] = {"zeta", "alpha", "Beta", "alpha.v2", "_x", "9"};
    const size_t n = sizeof names / sizeof names[0];
    uint64_t last = 0;
    for (size_t i = 0; i < n; i++) {
        uint64_t v = add_sphere(s, names[i], 2, 0);
        TEST_ASSERT_TRUE(v > last);
        last = v;
    }
    /* listed sorted by strcmp, each once */
    const char *sorted[sizeof names / sizeof names[0]];
    memcpy(sorted, names, sizeof names);
    for (size_t i = 0; i < n; i++)
        for (size_t j = i + 1; j < n; j++)
            if (strcmp(sorted[j], sorted[i]) < 0) {
                const char *tmp = sorted[i];
                sorted[i] = sorted[j];
                sorted[j] = tmp;
            }
    arbor_model **list;
    uint32_t listed;
    arbor_err e;
    TEST_ASSERT_TRUE_MESSAGE(arbor_store_list_models(s, &list, &listed, &e), e.msg);
    TEST_ASSERT_EQUAL_UINT32(n, listed);
    for (size_t i = 0; i < n; i++) {
        TEST_ASSERT_EQUAL_STRING(sorted[i], arbor_model_name(list[i]));
        TEST_ASSERT_EQUAL_STRING("sphere.obj", arbor_model_file(list[i]));
        TEST_ASSERT_EQUAL_UINT32(320, arbor_model_mesh(list[i])->ntris);
        arbor_model_release(list[i]);
    }
    free(list);

    arbor_model *m = arbor_store_acquire_model(s, "alpha");
    TEST_ASSERT_NOT_NULL(m);
    TEST_ASSERT_EQUAL_STRING("alpha", arbor_model_name(m));
    arbor_model_release(m);
    TEST_ASSERT_NULL(arbor_store_acquire_model(s, "alph"));
    TEST_ASSERT_NULL(arbor_store_acquire_model(s, "ALPHA"));

    TEST_ASSERT_TRUE(arbor_store_remove_model(s, "alpha", &e));
    TEST_ASSERT_NULL(arbor_store_acquire_model(s, "alpha"));
    assert_failed(arbor_store_remove_model(s, "alpha", &e), &e, ARBOR_ERR_NOT_FOUND);
    TEST_ASSERT_NOT_NULL_MESSAGE(strstr(e.msg, "alpha"), e.msg);
    TEST_ASSERT_TRUE_MESSAGE(arbor_store_list_models(s, &list, &listed, &e), e.msg);
    TEST_ASSERT_EQUAL_UINT32(n - 1, listed);
    for (size_t i = 0; i < n - 1; i++) {
        TEST_ASSERT_TRUE(strcmp(arbor_model_name(list[i]), "alpha") != 0);
        arbor_model_release(list[i]);
    }
    free(list);
    TEST_ASSERT_EQUAL_UINT32(n - 1, usage_of(s).nmodels);
    arbor_store_destroy(s);
}

static void test_exists_without_replace_and_version_on_replace(void)
{
    arbor_store *s = store_new(0, NULL);
    uint64_t v1 = add_sphere(s, "m", 2, 0);
    arbor_model *old = arbor_store_acquire_model(s, "m");

    arbor_mesh mesh;
    make_sphere(&mesh, 3);
    arbor_err e;
    uint64_t v = 0;
    assert_failed(arbor_store_add_model(s, "m", "other.obj", &mesh, 0, &v, &e), &e, ARBOR_ERR_EXISTS);
    TEST_ASSERT_EQUAL_UINT32(1280, mesh.ntris); /* untouched on failure */
    TEST_ASSERT_EQUAL_UINT32(320, arbor_model_mesh(old)->ntris);

    TEST_ASSERT_TRUE_MESSAGE(
        arbor_store_add_model(s, "m", "other.obj", &mesh, ARBOR_ADD_REPLACE, &v, &e), e.msg);
    TEST_ASSERT_TRUE(v > v1);
    arbor_model *now = arbor_store_acquire_model(s, "m");
    TEST_ASSERT_TRUE(now != old);
    TEST_ASSERT_EQUAL_UINT64(v, arbor_model_version(now));
    TEST_ASSERT_EQUAL_UINT64(v1, arbor_model_version(old));
    TEST_ASSERT_EQUAL_UINT32(1280, arbor_model_mesh(now)->ntris);
    TEST_ASSERT_EQUAL_STRING("other.obj", arbor_model_file(now));
    /* the old model, still held, is intact but detached: no new trees */
    TEST_ASSERT_EQUAL_UINT32(320, arbor_model_mesh(old)->ntris);
    arbor_tree *t;
    TEST_ASSERT_EQUAL_INT(ARBOR_ACQUIRE_FAILED,
                          arbor_store_acquire_tree(s, old, ARBOR_ACCEL_BVH, ARBOR_BUILD_SAH, &t, NULL, NULL, &e));
    TEST_ASSERT_EQUAL_INT(ARBOR_ERR_NOT_FOUND, e.status);
    TEST_ASSERT_NULL(t);
    assert_usage(s, arbor_model_bytes(old) + arbor_model_bytes(now), 0);
    /* removing the model that was checked does not remove its replacement */
    assert_failed(arbor_store_remove_this_model(s, old, &e), &e, ARBOR_ERR_NOT_FOUND);
    arbor_model *still = arbor_store_acquire_model(s, "m");
    TEST_ASSERT_TRUE(still == now);
    arbor_model_release(still);
    arbor_model_release(old);
    assert_usage(s, arbor_model_bytes(now), 0);
    TEST_ASSERT_TRUE_MESSAGE(arbor_store_remove_this_model(s, now, &e), e.msg);
    TEST_ASSERT_NULL(arbor_store_acquire_model(s, "m"));
    arbor_model_release(now);
    arbor_mesh_free(&mesh);
    arbor_store_destroy(s);
}

static void test_model_names(void)
{
    char longest[ARBOR_MODEL_NAME_MAX + 2];
    memset(longest, 'a', ARBOR_MODEL_NAME_MAX);
    longest[ARBOR_MODEL_NAME_MAX] = '\0';
    const char *good[] = {"a", "Z", "0", "castle", "A-z_0.9", "a..b", "a.", longest};
    for (size_t i = 0; i < sizeof good / sizeof good[0]; i++)
        TEST_ASSERT_TRUE_MESSAGE(arbor_model_name_valid(good[i]), good[i]);
    longest[ARBOR_MODEL_NAME_MAX] = 'a';
    longest[ARBOR_MODEL_NAME_MAX + 1] = '\0';
    const char *bad[] = {"", ".", "..", "...", ".hidden", "a/b", "../x", "a b", "rose+vase", "a\\b", "a:b", "caf\xc3\xa9",
                         "tab\t", "new\nline", "q?", "%2e", longest};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++)
        TEST_ASSERT_FALSE_MESSAGE(arbor_model_name_valid(bad[i]), bad[i]);

    /* the store refuses them, leaving the mesh with the caller */
    arbor_store *s = store_new(0, NULL);
    arbor_mesh m;
    make_sphere(&m, 1);
    arbor_err e;
    assert_failed(arbor_store_add_model(s, "../etc", "x.obj", &m, 0, NULL, &e), &e, ARBOR_ERR_INVALID);
    TEST_ASSERT_EQUAL_UINT32(80, m.ntris);
    TEST_ASSERT_EQUAL_UINT32(0, usage_of(s).nmodels);
    arbor_mesh_free(&m);
    arbor_store_destroy(s);
}

/* ---- trees ---- */

/* Absent, then PENDING with one callback, then READY with none; the tree
 * equals one built directly with the same options. */
static void test_tree_pending_then_ready(void)
{
    build_count count = {0};
    arbor_store *s = store_new(0, &count);
    add_sphere(s, "m", 4, 0);
    arbor_model *m = arbor_store_acquire_model(s, "m");
    for (int kind = 0; kind < ARBOR_ACCEL_KIND_COUNT; kind++) {
        arbor_tree_info info;
        arbor_model_tree_info(s, m, (arbor_accel_kind)kind, ARBOR_BUILD_SAH, &info);
        TEST_ASSERT_EQUAL_INT(ARBOR_TREE_ABSENT, info.state);

        ready_box box;
        box_init(&box);
        arbor_tree *t = NULL;
        arbor_err e;
        TEST_ASSERT_EQUAL_INT(ARBOR_ACQUIRE_PENDING, arbor_store_acquire_tree(s, m, (arbor_accel_kind)kind,
                                                                              ARBOR_BUILD_SAH, &t, on_ready,
                                                                              &box, &e));
        TEST_ASSERT_NULL(t);
        box_wait(&box);
        TEST_ASSERT_NOT_NULL_MESSAGE(box.tree, box.err.msg);
        TEST_ASSERT_TRUE(arbor_tree_model(box.tree) == m);

        arbor_tree *again = NULL;
        TEST_ASSERT_EQUAL_INT(ARBOR_ACQUIRE_READY, arbor_store_acquire_tree(s, m, (arbor_accel_kind)kind,
                                                                            ARBOR_BUILD_SAH, &again, on_ready,
                                                                            &box, &e));
        TEST_ASSERT_TRUE(again == box.tree);

        arbor_accel *direct = build_direct(arbor_model_mesh(m), (arbor_accel_kind)kind, ARBOR_BUILD_SAH);
        arbor_tree_stats want, got;
        arbor_accel_stats(direct, &want);
        arbor_accel_stats(arbor_tree_accel(again), &got);
        assert_same_stats(&want, &got);
        arbor_model_tree_info(s, m, (arbor_accel_kind)kind, ARBOR_BUILD_SAH, &info);
        TEST_ASSERT_EQUAL_INT(ARBOR_TREE_READY, info.state);
        assert_same_stats(&want, &info.stats);
        arbor_accel_free(direct);

        /* a callback for each PENDING only: the READY acquire did not call it */
        TEST_ASSERT_EQUAL_INT(1, box_calls(&box));
        arbor_tree_release(again);
        arbor_tree_release(box.tree);
        box_free(&box);
    }
    TEST_ASSERT_EQUAL_INT(2, atomic_load(&count.builds));
    TEST_ASSERT_EQUAL_INT(2, atomic_load(&count.ok));
    arbor_model_release(m);
    arbor_store_destroy(s);
}

/* A build runs on the store's pool within its thread budget (store.h:
 * "builds run here"; accel.h: a daemon gives every build its one pool), as
 * the options the tree was built with record. */
static void test_builds_run_on_the_store_pool(void)
{
    arbor_store *s = store_new(0, NULL);
    add_sphere(s, "m", 3, 0);
    arbor_tree *t = tree_named(s, "m", ARBOR_ACCEL_BVH);
    const arbor_build_opts o = *arbor_accel_opts(arbor_tree_accel(t));
    arbor_tree_release(t);
    arbor_store_destroy(s);
    TEST_ASSERT_EQUAL_INT(BUILD_THREADS, o.threads);
    TEST_ASSERT_TRUE_MESSAGE(o.pool == pool, "the build ran on a pool of its own, not the store's");
}

#define RACERS 16

typedef struct {
    arbor_store *store;
    arbor_model *model;
    pthread_barrier_t *start;
    arbor_acquire result;
    arbor_tree *tree;
    ready_box box;
} racer;

static void *race_acquire(void *arg)
{
    racer *r = arg;
    arbor_err e;
    pthread_barrier_wait(r->start);
    r->result = arbor_store_acquire_tree(r->store, r->model, ARBOR_ACCEL_KD, ARBOR_BUILD_SAH, &r->tree, on_ready,
                                         &r->box, &e);
    return NULL;
}

/* 16 threads ask for the same absent tree at once: one build, and every
 * one of them gets that tree, either at once or through one callback. */
static void test_concurrent_acquires_build_once(void)
{
    build_count count = {0};
    arbor_store *s = store_new(0, &count);
    add_sphere(s, "m", 5, 0);
    arbor_model *m = arbor_store_acquire_model(s, "m");
    pthread_barrier_t start;
    pthread_barrier_init(&start, NULL, RACERS);
    racer racers[RACERS];
    pthread_t threads[RACERS];
    for (int i = 0; i < RACERS; i++) {
        box_init(&racers[i].box);
        racers[i].store = s;
        racers[i].model = m;
        racers[i].start = &start;
        racers[i].result = ARBOR_ACQUIRE_FAILED;
        racers[i].tree = NULL;
        TEST_ASSERT_EQUAL_INT(0, pthread_create(&threads[i], NULL, race_acquire, &racers[i]));
    }
    for (int i = 0; i < RACERS; i++)
        pthread_join(threads[i], NULL);
    arbor_tree *tree = NULL;
    int pending = 0;
    for (int i = 0; i < RACERS; i++) {
        racer *r = &racers[i];
        TEST_ASSERT_NOT_EQUAL(ARBOR_ACQUIRE_FAILED, r->result);
        if (r->result == ARBOR_ACQUIRE_PENDING) {
            pending++;
            box_wait(&r->box);
            r->tree = r->box.tree;
        }
        TEST_ASSERT_NOT_NULL(r->tree);
        if (tree == NULL)
            tree = r->tree;
        TEST_ASSERT_TRUE(r->tree == tree);
    }
    TEST_ASSERT_TRUE(pending >= 1); /* the first caller found it absent */
    sleep_ms(20);                   /* a second call of any callback would show now */
    for (int i = 0; i < RACERS; i++) {
        TEST_ASSERT_EQUAL_INT(racers[i].result == ARBOR_ACQUIRE_PENDING, box_calls(&racers[i].box));
        arbor_tree_release(racers[i].tree);
        box_free(&racers[i].box);
    }
    TEST_ASSERT_EQUAL_INT(1, atomic_load(&count.builds));
    pthread_barrier_destroy(&start);
    arbor_model_release(m);
    arbor_store_destroy(s);
}

/* A frame's tree reference keeps the mesh: after remove_model the tree
 * still traces like brute force on an independent copy of the mesh, and
 * the bytes come back when it is released. */
static void test_tree_outlives_remove(void)
{
    arbor_store *s = store_new(0, NULL);
    add_sphere(s, "m", 4, 0);
    arbor_mesh truth;
    make_sphere(&truth, 4);
    arbor_tree *t = tree_named(s, "m", ARBOR_ACCEL_BVH);
    uint64_t model = arbor_model_bytes(arbor_tree_model(t)), tree = usage_of(s).trees;
    TEST_ASSERT_TRUE(tree > 0);

    arbor_err e;
    TEST_ASSERT_TRUE_MESSAGE(arbor_store_remove_model(s, "m", &e), e.msg);
    TEST_ASSERT_NULL(arbor_store_acquire_model(s, "m"));
    TEST_ASSERT_EQUAL_UINT32(0, usage_of(s).nmodels);
    assert_usage(s, model, tree); /* still held */
    assert_traces_like_brute_force(t, &truth);
    arbor_tree_release(t);
    assert_usage(s, 0, 0);
    arbor_mesh_free(&truth);
    arbor_store_destroy(s);
}

/* The same across a replace: the old tree traces its old mesh, and once
 * released the usage is the new model's alone. */
static void test_tree_outlives_replace(void)
{
    arbor_store *s = store_new(0, NULL);
    add_sphere(s, "m", 4, 0);
    arbor_mesh truth;
    make_sphere(&truth, 4);
    arbor_tree *t = tree_named(s, "m", ARBOR_ACCEL_KD);
    uint64_t old_model = arbor_model_bytes(arbor_tree_model(t)), tree = usage_of(s).trees;

    add_sphere(s, "m", 3, ARBOR_ADD_REPLACE);
    arbor_model *now = arbor_store_acquire_model(s, "m");
    TEST_ASSERT_TRUE(now != arbor_tree_model(t));
    TEST_ASSERT_EQUAL_INT(ARBOR_TREE_ABSENT, state_of(s, "m", ARBOR_ACCEL_KD));
    assert_usage(s, old_model + arbor_model_bytes(now), tree);
    assert_traces_like_brute_force(t, &truth);
    arbor_tree_release(t);
    assert_usage(s, arbor_model_bytes(now), 0);
    /* the new model's own tree is built over the new mesh */
    arbor_tree *fresh = tree_of(s, now, ARBOR_ACCEL_KD, ARBOR_BUILD_SAH);
    TEST_ASSERT_TRUE(arbor_accel_mesh(arbor_tree_accel(fresh)) == arbor_model_mesh(now));
    TEST_ASSERT_EQUAL_UINT32(1280, arbor_model_mesh(now)->ntris);
    arbor_tree_release(fresh);
    arbor_model_release(now);
    arbor_mesh_free(&truth);
    arbor_store_destroy(s);
}

/* A model held (by a frame, a listing) across its removal still answers
 * arbor_model_tree_info: its trees are gone, so not READY, and no crash.
 * Run in a child process, since the failure this guards against is a NULL
 * dereference. */
#define READY_EXIT 42

static void test_tree_info_of_a_removed_model(void)
{
    arbor_store *s = store_new(0, NULL);
    add_sphere(s, "m", 3, 0);
    arbor_model *m = arbor_store_acquire_model(s, "m");
    arbor_tree_release(tree_of(s, m, ARBOR_ACCEL_BVH, ARBOR_BUILD_SAH));
    arbor_err e;
    TEST_ASSERT_TRUE(arbor_store_remove_model(s, "m", &e));
    fflush(NULL);
    pid_t child = fork();
    TEST_ASSERT_TRUE(child >= 0);
    if (child == 0) {
        arbor_tree_info info;
        arbor_model_tree_info(s, m, ARBOR_ACCEL_BVH, ARBOR_BUILD_SAH, &info);
        _exit(info.state == ARBOR_TREE_READY ? READY_EXIT : 0);
    }
    int status = 0;
    pid_t waited = waitpid(child, &status, 0);
    arbor_model_release(m);
    arbor_store_destroy(s);
    TEST_ASSERT_EQUAL_INT(child, waited);
    /* killed by a signal, or (under ASan) exited with its error status */
    bool crashed = !WIFEXITED(status) || (WEXITSTATUS(status) != 0 && WEXITSTATUS(status) != READY_EXIT);
    TEST_ASSERT_FALSE_MESSAGE(crashed, "arbor_model_tree_info crashed on a removed model");
    TEST_ASSERT_EQUAL_INT_MESSAGE(0, WEXITSTATUS(status), "a removed model's tree is still READY");
}

/* A tree asked for while its model is removed: the waiter hears an error
 * (the model is gone or the build was stopped), never a tree, and nothing
 * is left counted. */
static void test_remove_while_building(void)
{
    arbor_store *s = store_new(0, NULL);
    add_sphere(s, "m", 6, 0);
    arbor_model *m = arbor_store_acquire_model(s, "m");
    ready_box box;
    box_init(&box);
    arbor_tree *t;
    arbor_err e;
    TEST_ASSERT_EQUAL_INT(ARBOR_ACQUIRE_PENDING,
                          arbor_store_acquire_tree(s, m, ARBOR_ACCEL_KD, ARBOR_BUILD_SAH, &t, on_ready, &box, &e));
    TEST_ASSERT_TRUE(arbor_store_remove_model(s, "m", &e));
    box_wait(&box);
    TEST_ASSERT_NULL(box.tree);
    TEST_ASSERT_TRUE_MESSAGE(box.err.status == ARBOR_ERR_NOT_FOUND || box.err.status == ARBOR_ERR_CANCELLED,
                             box.err.msg);
    arbor_model_release(m);
    assert_usage(s, 0, 0);
    TEST_ASSERT_EQUAL_INT(1, box_calls(&box));
    box_free(&box);
    arbor_store_destroy(s);
}

/* arbor_store_cancel_builds stops a build that is running: its waiter is
 * called with ARBOR_ERR_CANCELLED, not with the finished tree. The build
 * (a kd sah tree of 327,680 triangles) takes over a second on two threads;
 * it is cancelled 100 ms after it starts. */
static void test_cancel_stops_a_running_build(void)
{
    arbor_store *s = store_new(0, NULL);
    add_sphere(s, "big", 7, 0);
    arbor_model *m = arbor_store_acquire_model(s, "big");
    ready_box box;
    box_init(&box);
    arbor_tree *t;
    arbor_err e;
    TEST_ASSERT_EQUAL_INT(ARBOR_ACQUIRE_PENDING,
                          arbor_store_acquire_tree(s, m, ARBOR_ACCEL_KD, ARBOR_BUILD_SAH, &t, on_ready, &box, &e));
    sleep_ms(100);
    TEST_ASSERT_EQUAL_INT_MESSAGE(0, box_calls(&box), "the build finished before it could be cancelled");
    arbor_store_cancel_builds(s);
    box_wait(&box);
    bool got_tree = box.tree != NULL;
    arbor_err err = box.err;
    arbor_tree_release(box.tree);
    box_free(&box);
    arbor_model_release(m);
    arbor_store_destroy(s);
    TEST_ASSERT_FALSE_MESSAGE(got_tree, "cancel_builds did not stop the build: its waiter got the tree");
    TEST_ASSERT_EQUAL_INT_MESSAGE(ARBOR_ERR_CANCELLED, err.status, err.msg);
}

/* ---- the memory budget ---- */

/* Three equal models and room for two and a half of their bvh trees: the
 * third tree evicts the least recently used idle one; a held tree is never
 * evicted; what cannot fit is refused with the bytes it needs, touching
 * nothing; a model that needs room evicts idle trees, LRU first. */
static void test_budget_evicts_lru_idle_trees(void)
{
    const uint64_t model = model_bytes_of(4), tree = tree_bytes_of(4);
    const uint64_t limit = 3 * model + 2 * tree + tree / 2;
    build_count count = {0};
    arbor_store *s = store_new(limit, &count);
    add_sphere(s, "a", 4, 0);
    add_sphere(s, "b", 4, 0);
    add_sphere(s, "c", 4, 0);
    assert_usage(s, 3 * model, 0);

    touch(s, "a");
    touch(s, "b");
    touch(s, "a"); /* b is now the least recently used */
    assert_usage(s, 3 * model, 2 * tree);
    touch(s, "c");
    TEST_ASSERT_EQUAL_INT(ARBOR_TREE_READY, state_of(s, "a", ARBOR_ACCEL_BVH));
    TEST_ASSERT_EQUAL_INT(ARBOR_TREE_ABSENT, state_of(s, "b", ARBOR_ACCEL_BVH));
    TEST_ASSERT_EQUAL_INT(ARBOR_TREE_READY, state_of(s, "c", ARBOR_ACCEL_BVH));
    assert_usage(s, 3 * model, 2 * tree);

    /* a held is the least recently used, but only c, idle, may go */
    arbor_tree *held_a = tree_named(s, "a", ARBOR_ACCEL_BVH);
    touch(s, "c");
    arbor_tree *held_b = tree_named(s, "b", ARBOR_ACCEL_BVH);
    TEST_ASSERT_EQUAL_INT(ARBOR_TREE_READY, state_of(s, "a", ARBOR_ACCEL_BVH));
    TEST_ASSERT_EQUAL_INT(ARBOR_TREE_READY, state_of(s, "b", ARBOR_ACCEL_BVH));
    TEST_ASSERT_EQUAL_INT(ARBOR_TREE_ABSENT, state_of(s, "c", ARBOR_ACCEL_BVH));
    assert_usage(s, 3 * model, 2 * tree);
    TEST_ASSERT_EQUAL_INT(4, atomic_load(&count.builds));

    /* both trees held: a third cannot fit */
    arbor_model *c = arbor_store_acquire_model(s, "c");
    arbor_tree *t = NULL;
    arbor_err e;
    arbor_err_clear(&e);
    TEST_ASSERT_EQUAL_INT(ARBOR_ACQUIRE_FAILED,
                          arbor_store_acquire_tree(s, c, ARBOR_ACCEL_BVH, ARBOR_BUILD_SAH, &t, NULL, NULL, &e));
    TEST_ASSERT_NULL(t);
    TEST_ASSERT_TRUE_MESSAGE(bytes_needed(&e) > limit - (3 * model + 2 * tree), e.msg);
    arbor_model_release(c);
    TEST_ASSERT_EQUAL_INT(ARBOR_TREE_READY, state_of(s, "a", ARBOR_ACCEL_BVH));
    TEST_ASSERT_EQUAL_INT(ARBOR_TREE_READY, state_of(s, "b", ARBOR_ACCEL_BVH));
    assert_usage(s, 3 * model, 2 * tree);
    TEST_ASSERT_EQUAL_INT(4, atomic_load(&count.builds));

    /* nor can a bigger model; its mesh stays with the caller */
    const uint64_t overhead = model - arbor_mesh_bytes(arbor_model_mesh(arbor_tree_model(held_a)));
    arbor_mesh big;
    make_sphere(&big, 5);
    /* between the room left and that room plus one tree: the sphere's first
     * triangles (its vertices stay, unused ones included) */
    while (big.ntris > 256 && arbor_mesh_bytes(&big) + overhead > limit - (3 * model + tree))
        big.ntris -= 256;
    const uint32_t big_tris = big.ntris;
    const uint64_t big_bytes = arbor_mesh_bytes(&big) + overhead;
    TEST_ASSERT_TRUE(big_bytes > limit - (3 * model + 2 * tree)); /* the premise */
    TEST_ASSERT_TRUE(big_bytes <= limit - (3 * model + tree));
    arbor_err_clear(&e);
    assert_failed(arbor_store_add_model(s, "d", "d.obj", &big, 0, NULL, &e), &e, ARBOR_ERR_NOSPACE);
    TEST_ASSERT_EQUAL_UINT64(big_bytes, bytes_needed(&e));
    TEST_ASSERT_EQUAL_UINT32(big_tris, big.ntris);
    TEST_ASSERT_NULL(arbor_store_acquire_model(s, "d"));
    TEST_ASSERT_EQUAL_UINT32(3, usage_of(s).nmodels);
    TEST_ASSERT_EQUAL_INT(ARBOR_TREE_READY, state_of(s, "a", ARBOR_ACCEL_BVH));
    TEST_ASSERT_EQUAL_INT(ARBOR_TREE_READY, state_of(s, "b", ARBOR_ACCEL_BVH));
    assert_usage(s, 3 * model, 2 * tree);

    /* released, they may go: one tree (a, the least recently used) makes room */
    arbor_tree_release(held_a);
    arbor_tree_release(held_b);
    TEST_ASSERT_TRUE_MESSAGE(arbor_store_add_model(s, "d", "d.obj", &big, 0, NULL, &e), e.msg);
    TEST_ASSERT_EQUAL_INT(ARBOR_TREE_ABSENT, state_of(s, "a", ARBOR_ACCEL_BVH));
    TEST_ASSERT_EQUAL_INT(ARBOR_TREE_READY, state_of(s, "b", ARBOR_ACCEL_BVH));
    assert_usage(s, 3 * model + big_bytes, tree);
    TEST_ASSERT_TRUE(3 * model + big_bytes + tree <= limit);
    arbor_mesh_free(&big);
    arbor_store_destroy(s);
}

/* Replacing a model gives its bytes back: a replacement that fits once the
 * old model is gone is accepted, whether or not the old model had an idle
 * tree (the store's own tree is no frame holding the model). The budget is
 * exactly the new model's bytes. */
static void replace_within_budget(bool with_tree)
{
    const uint64_t small = model_bytes_of(3), big = model_bytes_of(5);
    TEST_ASSERT_TRUE(small + tree_bytes_of(3) <= big); /* the premise: the old model and its tree fit */
    arbor_store *s = store_new(big, NULL);
    add_sphere(s, "m", 3, 0);
    if (with_tree)
        touch(s, "m");
    arbor_mesh mesh;
    make_sphere(&mesh, 5);
    arbor_err e;
    arbor_err_clear(&e);
    bool replaced = arbor_store_add_model(s, "m", "m.obj", &mesh, ARBOR_ADD_REPLACE, NULL, &e);
    arbor_mesh_free(&mesh); /* empty when it was moved into the store */
    if (replaced)
        assert_usage(s, big, 0);
    arbor_store_destroy(s);
    TEST_ASSERT_TRUE_MESSAGE(replaced, e.msg);
}

static void test_replace_within_budget_without_trees(void)
{
    replace_within_budget(false);
}

static void test_replace_within_budget_with_an_idle_tree(void)
{
    replace_within_budget(true);
}

/* ---- destroy ---- */

/* Destroy with sixteen builds queued or running: every waiter is called
 * once (with a tree it releases, or an error), destroy returns, and under
 * ASan nothing leaks or is touched after it is freed. Repeated, since the
 * end of a build races with destroy. */
static void test_destroy_with_builds_in_flight(void)
{
    for (int round = 0; round < 20; round++) {
        arbor_store *s = store_new(0, NULL);
        add_sphere(s, "a", 3, 0);
        add_sphere(s, "b", 4, 0);
        ready_box boxes[2][ARBOR_ACCEL_KIND_COUNT][ARBOR_BUILDER_COUNT];
        for (int i = 0; i < 2; i++) {
            arbor_model *m = arbor_store_acquire_model(s, i == 0 ? "a" : "b");
            for (int k = 0; k < ARBOR_ACCEL_KIND_COUNT; k++)
                for (int b = 0; b < ARBOR_BUILDER_COUNT; b++) {
                    ready_box *box = &boxes[i][k][b];
                    box_init(box);
                    box->release = true;
                    arbor_tree *t;
                    arbor_err e;
                    TEST_ASSERT_EQUAL_INT(ARBOR_ACQUIRE_PENDING,
                                          arbor_store_acquire_tree(s, m, (arbor_accel_kind)k, (arbor_builder)b, &t,
                                                                   on_ready, box, &e));
                }
            arbor_model_release(m);
        }
        arbor_store_destroy(s);
        for (int i = 0; i < 2; i++)
            for (int k = 0; k < ARBOR_ACCEL_KIND_COUNT; k++)
                for (int b = 0; b < ARBOR_BUILDER_COUNT; b++) {
                    TEST_ASSERT_EQUAL_INT(1, boxes[i][k][b].calls);
                    box_free(&boxes[i][k][b]);
                }
    }
}

int main(void)
{
    arbor_err e;
    pool = arbor_pool_create(2, &e);
    UNITY_BEGIN();
    RUN_TEST(test_add_acquire_list_remove);
    RUN_TEST(test_exists_without_replace_and_version_on_replace);
    RUN_TEST(test_model_names);
    RUN_TEST(test_tree_pending_then_ready);
    RUN_TEST(test_builds_run_on_the_store_pool);
    RUN_TEST(test_concurrent_acquires_build_once);
    RUN_TEST(test_tree_outlives_remove);
    RUN_TEST(test_tree_outlives_replace);
    RUN_TEST(test_tree_info_of_a_removed_model);
    RUN_TEST(test_remove_while_building);
    RUN_TEST(test_cancel_stops_a_running_build);
    RUN_TEST(test_budget_evicts_lru_idle_trees);
    RUN_TEST(test_replace_within_budget_without_trees);
    RUN_TEST(test_replace_within_budget_with_an_idle_tree);
    RUN_TEST(test_destroy_with_builds_in_flight);
    int failures = UNITY_END();
    arbor_pool_destroy(pool);
    return failures;
}
