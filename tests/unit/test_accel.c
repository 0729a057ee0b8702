/*
 * test_accel.c - every tree kind and builder against brute force, through
 * the common accel interface, on real models, the project's own models and
 * a random soup: 100k random rays (closest hit and any hit) and PROTOCOL.md's
 * primary rays, and rays aimed through closed meshes' vertices and edges.
 * The brute-force answers are computed once per model and shared by all
 * eight trees. Then builds on pools: the same tree on pools of any size,
 * and cancelling, before a build starts and from another thread while it
 * runs (leaks show under make asan).
 */
#include <float.h>
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "arbor/accel.h"
#include "arbor/brute.h"
#include "arbor/load.h"
#include "arbor/procgen.h"
#include "../../src/accel/accel_impl.h"
#define SIMD_LANES 4
#include "../../src/accel/tri_pack.h"
#include "support.h"
#include "unity.h"

#define RANDOM_RAYS 100000

void setUp(void) {}
void tearDown(void) {}

/* The hit names a triangle that really is hit at that t. */
static bool hit_is_real(const arbor_mesh *m, const arbor_ray *r, const arbor_hit *h)
{
    if (h->tri >= m->ntris)
        return false;
    arbor_ray_prep p;
    arbor_ray_prepare(r, &p);
    arbor_vec3 a, b, c;
    arbor_mesh_tri(m, h->tri, &a, &b, &c);
    float t, u, v;
    return arbor_triangle_intersect(r, &p, a, b, c, INFINITY, &t, &u, &v) && t == h->t;
}

/* Closest hits of tree on the set agree with brute force; returns mismatches
 * and describes the first in msg. */
static size_t check_closest(const arbor_accel *tree, const arbor_mesh *m, const test_truth *ts, char *msg,
                            size_t msglen)
{
    size_t bad = 0;
    for (size_t i = 0; i < ts->n; i++) {
        arbor_ray r = ts->rays[i];
        arbor_hit h;
        bool found = arbor_accel_intersect(tree, &r, &h);
        bool ok = found == ts->found[i];
        if (ok && found)
            ok = test_close(h.t, ts->hit[i].t, 1e-5f) && r.tmax == h.t && hit_is_real(m, &ts->rays[i], &h);
        if (!ok && bad++ == 0)
            snprintf(msg, msglen, "ray %zu: tree %s t=%g tri=%u, brute %s t=%g tri=%u", i, found ? "hit" : "miss",
                     found ? (double)h.t : 0.0, found ? h.tri : 0, ts->found[i] ? "hit" : "miss",
                     (double)ts->hit[i].t, ts->hit[i].tri);
    }
    return bad;
}

/* Any-hit answers follow from the closest hit: with tmax at half the closest
 * distance nothing is hit, with tmax at twice it something is. The counted
 * query answers the same, and a hit took a node step and a triangle test. */
static size_t check_occluded(const arbor_accel *tree, const test_truth *ts, char *msg, size_t msglen)
{
    size_t bad = 0;
    for (size_t i = 0; i < ts->n; i++) {
        arbor_ray r = ts->rays[i];
        bool expect;
        if (!ts->found[i]) {
            expect = false;
        } else if (i & 1) {
            r.tmax = 0.5f * ts->hit[i].t;
            expect = false;
        } else {
            r.tmax = 2.0f * ts->hit[i].t;
            expect = true;
        }
        arbor_trace_counts c = {0, 0};
        bool counted = arbor_accel_occluded_counted(tree, &r, &c);
        if ((arbor_accel_occluded(tree, &r) != expect || counted != expect) && bad++ == 0)
            snprintf(msg, msglen, "ray %zu: occluded should be %s (tmax %g)", i, expect ? "true" : "false",
                     (double)r.tmax);
        else if (counted && (c.nodes == 0 || c.tris == 0) && bad++ == 0)
            snprintf(msg, msglen, "ray %zu: occluded, counting %llu nodes and %llu triangles", i,
                     (unsigned long long)c.nodes, (unsigned long long)c.tris);
    }
    return bad;
}

/* A tree of that kind and builder over m, which the validator accepts. */
static arbor_accel *build_valid(const arbor_mesh *m, arbor_accel_kind kind, arbor_builder builder, const char *what)
{
    arbor_build_opts o;
    arbor_build_opts_init(&o, kind, builder);
    arbor_err e;
    arbor_accel *tree = arbor_accel_build(m, &o, &e);
    if (tree == NULL) {
        char f[768];
        snprintf(f, sizeof f, "%s: build failed: %s", what, e.msg);
        TEST_FAIL_MESSAGE(f);
    }
    if (!arbor_accel_validate(tree, &e)) {
        char f[768];
        snprintf(f, sizeof f, "%s: invalid tree: %s", what, e.msg);
        TEST_FAIL_MESSAGE(f);
    }
    return tree;
}

/* Builds every kind x builder over m and checks each against the truth sets. */
static void check_all_trees(const char *name, const arbor_mesh *m, const test_truth *random_set,
                            const test_truth *protocol_set)
{
    for (int k = 0; k < ARBOR_ACCEL_KIND_COUNT; k++) {
        for (int b = 0; b < ARBOR_BUILDER_COUNT; b++) {
            char what[128], msg[512] = "";
            snprintf(what, sizeof what, "%s %s %s", name, arbor_accel_kind_name((arbor_accel_kind)k),
                     arbor_builder_name((arbor_builder)b));
            arbor_accel *tree = build_valid(m, (arbor_accel_kind)k, (arbor_builder)b, what);
            size_t bad_r = check_closest(tree, m, random_set, msg, sizeof msg);
            size_t bad_o = bad_r ? 0 : check_occluded(tree, random_set, msg, sizeof msg);
            size_t bad_p = bad_r || bad_o ? 0 : check_closest(tree, m, protocol_set, msg, sizeof msg);
            arbor_accel_free(tree);
            if (bad_r || bad_o || bad_p) {
                char f[1024];
                snprintf(f, sizeof f, "%s: %zu random closest, %zu random any-hit, %zu protocol mismatches; first: %s",
                         what, bad_r, bad_o, bad_p, msg);
                TEST_FAIL_MESSAGE(f);
            }
        }
    }
}

/* stride: PROTOCOL.md's primary rays are all checked on small models, every
 * stride-th pixel in x and y on large ones (brute force is O(triangles)). */
static void check_mesh(const char *name, const arbor_mesh *m, int stride)
{
    test_truth random_set, protocol_set;
    test_truth_compute(&random_set, m, test_random_rays(m, RANDOM_RAYS, 7), RANDOM_RAYS);
    size_t np;
    arbor_ray *prays = test_protocol_rays(m, stride, &np);
    test_truth_compute(&protocol_set, m, prays, np);
    size_t hits = 0;
    for (size_t i = 0; i < random_set.n; i++)
        hits += random_set.found[i];
    /* a ray set that misses everything would prove nothing */
    TEST_ASSERT_TRUE_MESSAGE(hits > RANDOM_RAYS / 10, "too few random rays hit the model");
    check_all_trees(name, m, &random_set, &protocol_set);
    test_truth_free(&random_set);
    test_truth_free(&protocol_set);
}

static void check_file(const char *path, int stride)
{
    arbor_mesh m;
    arbor_err e;
    if (!arbor_load_model(path, &m, &e)) {
        char f[768];
        snprintf(f, sizeof f, "loading %s: %s", path, e.msg);
        TEST_FAIL_MESSAGE(f);
    }
    check_mesh(path, &m, stride);
    arbor_mesh_free(&m);
}

static void test_galleon(void) { check_file(test_shared_model("galleon.obj"), 2); }
static void test_castle(void) { check_file(test_shared_model("castle.obj"), 4); }
static void test_bunny(void) { check_file(test_shared_model("bunny.obj"), 8); }

/* The project's own models: the Cornell box as committed, and the procedural
 * ones generated a level smaller than models/ holds, so that brute force over
 * 100k rays stays affordable. */
static void test_own_models(void)
{
    check_file(test_repo_model("cornell.obj"), 4);
    static const struct {
        const char *name;
        arbor_gen_kind kind;
        arbor_gen_params params;
    } own[] = {
        {"menger level 2", ARBOR_GEN_MENGER, {2, ARBOR_GEN_UNSET}},
        {"sphereflake level 2", ARBOR_GEN_SPHEREFLAKE, {2, 3}},
        {"heightfield 48", ARBOR_GEN_HEIGHTFIELD, {ARBOR_GEN_UNSET, 48}},
    };
    for (size_t i = 0; i < sizeof own / sizeof own[0]; i++) {
        arbor_mesh m;
        arbor_err e;
        arbor_mesh_init(&m);
        TEST_ASSERT_TRUE_MESSAGE(arbor_gen(own[i].kind, own[i].params, &m, &e), e.msg);
        check_mesh(own[i].name, &m, 4);
        arbor_mesh_free(&m);
    }
}

static void test_random_soup_10k(void)
{
    arbor_mesh m;
    test_random_soup(&m, 10000, 42);
    check_mesh("soup", &m, 4);
    arbor_mesh_free(&m);
}

static uint32_t float_bits(float f)
{
    uint32_t u;
    memcpy(&u, &f, sizeof u);
    return u;
}

/* The traversals' in-line next float above a hit's t (tri_pack.h) is libm's
 * nextafterf(t, INFINITY) for every t a hit can have: zeros of both signs,
 * denormals, negatives, the largest float, and random bit patterns (all
 * but NaN and the infinities). */
static void test_next_up_is_nextafterf(void)
{
    const float special[] = {0.0f, -0.0f, 0x1p-149f, -0x1p-149f, 0x1p-126f, -0x1p-126f, -0x1p-127f,
                             1.0f, -1.0f, 0.1f, 3.5e-7f, 1e30f, -1e30f, FLT_MAX, -FLT_MAX};
    for (size_t i = 0; i < sizeof special / sizeof special[0]; i++)
        TEST_ASSERT_EQUAL_HEX32(float_bits(nextafterf(special[i], INFINITY)), float_bits(tri_pack_next_up(special[i])));
    test_rng g;
    test_rng_seed(&g, 12345);
    for (int i = 0; i < 1000000; i++) {
        uint32_t u = test_rng_u32(&g);
        float t;
        memcpy(&t, &u, sizeof t);
        if (!isfinite(t))
            continue;
        TEST_ASSERT_EQUAL_HEX32(float_bits(nextafterf(t, INFINITY)), float_bits(tri_pack_next_up(t)));
    }
}

/* Rays with a NaN or infinite component in the origin or the direction,
 * or a zero direction, every other ray of the set: every tree answers them
 * as brute force does (no hit for the non-finite ones), and none may hang
 * or crash on them. A BVH ray whose slab distances are NaN on every axis
 * enters every box, empty slots included (bvh_internal.h). */
static void test_degenerate_rays(void)
{
    arbor_mesh m;
    test_random_soup(&m, 2000, 13);
    enum { N = 1600 };
    arbor_ray *rays = test_random_rays(&m, N, 14);
    const float bad[] = {NAN, INFINITY, -INFINITY};
    for (int i = 0; i < N; i += 2) {
        float *f[6] = {&rays[i].o.x, &rays[i].o.y, &rays[i].o.z, &rays[i].d.x, &rays[i].d.y, &rays[i].d.z};
        int k = i / 2 % 8;
        if (k < 6) {
            *f[k] = bad[i / 16 % 3];
        } else if (k == 6) {
            for (int a = 3; a < 6; a++)
                *f[a] = bad[i / 16 % 3];
        } else {
            rays[i].d = vec3(0.0f, 0.0f, 0.0f);
        }
    }
    test_truth ts;
    test_truth_compute(&ts, &m, rays, N);
    size_t hits = 0, degenerate_hits = 0;
    for (size_t i = 0; i < ts.n; i++) {
        hits += ts.found[i];
        degenerate_hits += ts.found[i] && i % 2 == 0;
    }
    TEST_ASSERT_TRUE_MESSAGE(hits > N / 10, "too few of the ordinary rays hit the soup");
    TEST_ASSERT_EQUAL_MESSAGE(0, degenerate_hits, "brute force hit with a non-finite or zero-direction ray");
    check_all_trees("degenerate rays", &m, &ts, &ts);
    test_truth_free(&ts);
    arbor_mesh_free(&m);
}

/* Rays from inside a closed mesh aimed exactly through its vertices and edge
 * midpoints: where a triangle test's edge functions come out exactly zero and
 * the watertight test decides in double precision (which the BVH's four-lane
 * test does lane by lane). Every tree must hit every ray, at brute force's
 * distance. To the ulp, not exactly: at a shared vertex each triangle's
 * distance rounds its own way, and a box entry rounded past the nearest one
 * may leave a tree the other triangle, an ulp farther. */
static void check_aimed(const char *name, const arbor_mesh *m, const arbor_vec3 *origins, size_t norigins)
{
    size_t ntargets;
    arbor_vec3 *targets = test_vertices_and_edge_midpoints(m, &ntargets);
    test_truth ts;
    test_truth_compute(&ts, m, test_aimed_rays(origins, norigins, targets, ntargets), norigins * ntargets);
    free(targets);
    for (int k = 0; k < ARBOR_ACCEL_KIND_COUNT; k++)
        for (int b = 0; b < ARBOR_BUILDER_COUNT; b++) {
            char what[128], msg[512] = "";
            snprintf(what, sizeof what, "%s %s %s", name, arbor_accel_kind_name((arbor_accel_kind)k),
                     arbor_builder_name((arbor_builder)b));
            arbor_accel *tree = build_valid(m, (arbor_accel_kind)k, (arbor_builder)b, what);
            size_t bad = 0;
            for (size_t i = 0; i < ts.n; i++) {
                arbor_ray r = ts.rays[i];
                arbor_hit h;
                bool found = arbor_accel_intersect(tree, &r, &h);
                if ((!found || !ts.found[i] || !test_close(h.t, ts.hit[i].t, 1e-6f) || !hit_is_real(m, &ts.rays[i], &h)) &&
                    bad++ == 0)
                    snprintf(msg, sizeof msg, "ray %zu: tree %s t=%.9g, brute %s t=%.9g", i, found ? "hit" : "miss",
                             found ? (double)h.t : 0.0, ts.found[i] ? "hit" : "miss", (double)ts.hit[i].t);
            }
            arbor_accel_free(tree);
            if (bad) {
                char f[768];
                snprintf(f, sizeof f, "%s: %zu of %zu aimed rays differ; first: %s", what, bad, ts.n, msg);
                TEST_FAIL_MESSAGE(f);
            }
        }
    test_truth_free(&ts);
}

static void test_rays_through_vertices_and_edges(void)
{
    arbor_mesh m;
    arbor_err e;
    const arbor_vec3 in_sphere[] = {vec3(0, 0, 0), vec3(0.3f, -0.2f, 0.1f), vec3(-0.55f, 0.4f, 0.25f),
                                    vec3(0.123f, 0.456f, -0.789f)};
    arbor_mesh_init(&m);
    TEST_ASSERT_TRUE_MESSAGE(arbor_gen(ARBOR_GEN_SPHERE, (arbor_gen_params){3, ARBOR_GEN_UNSET}, &m, &e), e.msg);
    check_aimed("sphere level 3", &m, in_sphere, sizeof in_sphere / sizeof in_sphere[0]);
    arbor_mesh_free(&m);
    /* centres of two solid cells of the level-2 sponge's 9^3 lattice */
    const arbor_vec3 in_sponge[] = {vec3(-1 + 1.0f / 9, -1 + 1.0f / 9, -1 + 1.0f / 9),
                                    vec3(-1 + 9.0f / 9, -1 + 1.0f / 9, -1 + 1.0f / 9)};
    arbor_mesh_init(&m);
    TEST_ASSERT_TRUE_MESSAGE(arbor_gen(ARBOR_GEN_MENGER, (arbor_gen_params){2, ARBOR_GEN_UNSET}, &m, &e), e.msg);
    check_aimed("menger level 2", &m, in_sponge, sizeof in_sponge / sizeof in_sponge[0]);
    arbor_mesh_free(&m);
}

/* ---- builds on pools, and cancelling ---- */

/* The unit icosphere subdivided 6 times: 81920 triangles, enough for both
 * kinds to fork and for the bvh's linear passes to split. */
static void big_sphere(arbor_mesh *m)
{
    arbor_err e;
    arbor_mesh_init(m);
    TEST_ASSERT_TRUE_MESSAGE(arbor_gen_sphere(m, 6, &e), e.msg);
}

static void what_of(char *what, size_t len, int k, int b, const char *how)
{
    snprintf(what, len, "%s %s %s", arbor_accel_kind_name((arbor_accel_kind)k),
             arbor_builder_name((arbor_builder)b), how);
}

/* A build with opts.threads fixed makes the same tree, to the last digit of
 * every statistic, on a pool of 1 or 2 workers or none. */
static void test_pool_size_does_not_change_the_tree(void)
{
    arbor_mesh m;
    big_sphere(&m);
    arbor_err e;
    arbor_pool *pools[3] = {NULL, arbor_pool_create(1, &e), arbor_pool_create(2, &e)};
    TEST_ASSERT_NOT_NULL(pools[1]);
    TEST_ASSERT_NOT_NULL(pools[2]);
    for (int k = 0; k < ARBOR_ACCEL_KIND_COUNT; k++)
        for (int b = 0; b < ARBOR_BUILDER_COUNT; b++) {
            arbor_tree_stats s[3];
            for (int p = 0; p < 3; p++) {
                arbor_build_opts o;
                arbor_build_opts_init(&o, (arbor_accel_kind)k, (arbor_builder)b);
                o.threads = 4;
                o.pool = pools[p];
                arbor_accel *tree = arbor_accel_build(&m, &o, &e);
                TEST_ASSERT_NOT_NULL_MESSAGE(tree, e.msg);
                arbor_accel_stats(tree, &s[p]);
                s[p].build_ms = 0.0;
                arbor_accel_free(tree);
            }
            char what[128];
            what_of(what, sizeof what, k, b, "on pools of 0, 1, 2");
            TEST_ASSERT_EQUAL_MEMORY_MESSAGE(&s[0], &s[1], sizeof s[0], what);
            TEST_ASSERT_EQUAL_MEMORY_MESSAGE(&s[0], &s[2], sizeof s[0], what);
        }
    arbor_pool_destroy(pools[1]);
    arbor_pool_destroy(pools[2]);
    arbor_mesh_free(&m);
}

static void assert_cancelled(arbor_accel *tree, const arbor_err *e, const char *what)
{
    TEST_ASSERT_NULL_MESSAGE(tree, what);
    TEST_ASSERT_EQUAL_INT_MESSAGE(ARBOR_ERR_CANCELLED, e->status, what);
    TEST_ASSERT_EQUAL_STRING_MESSAGE("build cancelled", e->msg, what);
}

/* A flag set before the build: every tree fails at once. The builders
 * themselves, called past accel.c's early check, stop at the root, free
 * what they made and leave e alone. */
static void test_build_cancelled_before_it_starts(void)
{
    arbor_mesh m;
    big_sphere(&m);
    arbor_err e;
    arbor_pool *pool = arbor_pool_create(2, &e);
    TEST_ASSERT_NOT_NULL(pool);
    atomic_bool cancel = true;
    for (int k = 0; k < ARBOR_ACCEL_KIND_COUNT; k++)
        for (int b = 0; b < ARBOR_BUILDER_COUNT; b++) {
            char what[128];
            what_of(what, sizeof what, k, b, "cancelled before");
            arbor_build_opts o;
            arbor_build_opts_init(&o, (arbor_accel_kind)k, (arbor_builder)b);
            o.pool = pool;
            o.threads = 2;
            o.cancel = &cancel;
            arbor_err_clear(&e);
            assert_cancelled(arbor_accel_build(&m, &o, &e), &e, what);

            accel_run run;
            TEST_ASSERT_NULL(accel_run_init(&run, &o));
            const arbor_accel_ops *ops = k == ARBOR_ACCEL_BVH ? &arbor_bvh_ops : &arbor_kd_ops;
            arbor_tree_stats stats;
            arbor_err_clear(&e);
            TEST_ASSERT_NULL_MESSAGE(ops->build(&m, &o, &run, &stats, &e), what);
            TEST_ASSERT_TRUE_MESSAGE(accel_stop(&run), what);
            TEST_ASSERT_EQUAL_INT_MESSAGE(ARBOR_OK, e.status, what);
        }
    arbor_pool_destroy(pool);
    arbor_mesh_free(&m);
}

typedef struct {
    atomic_bool *cancel;
    long delay_us;
} canceller;

static void *cancel_later(void *arg)
{
    const canceller *c = arg;
    struct timespec ts = {c->delay_us / 1000000, (c->delay_us % 1000000) * 1000};
    nanosleep(&ts, NULL);
    atomic_store(c->cancel, true);
    return NULL;
}

/* A flag set by another thread while the build runs, on a pool of 2 with
 * the budget of 2 and of 1: the build fails with ARBOR_ERR_CANCELLED or
 * returns a tree the validator accepts; nothing else. Every tree takes tens
 * of milliseconds or more, so some of the delays must catch it mid-way. */
static void test_build_cancelled_while_running(void)
{
    arbor_mesh m;
    big_sphere(&m);
    arbor_err e;
    arbor_pool *pool = arbor_pool_create(2, &e);
    TEST_ASSERT_NOT_NULL(pool);
    const long delays_us[] = {1000, 5000, 20000};
    for (int k = 0; k < ARBOR_ACCEL_KIND_COUNT; k++)
        for (int b = 0; b < ARBOR_BUILDER_COUNT; b++) {
            char what[128];
            what_of(what, sizeof what, k, b, "cancelled while running");
            int cancelled = 0;
            for (int threads = 1; threads <= 2; threads++)
                for (size_t d = 0; d < sizeof delays_us / sizeof *delays_us; d++) {
                    atomic_bool cancel = false;
                    arbor_build_opts o;
                    arbor_build_opts_init(&o, (arbor_accel_kind)k, (arbor_builder)b);
                    o.pool = pool;
                    o.threads = threads;
                    o.cancel = &cancel;
                    canceller c = {&cancel, delays_us[d]};
                    pthread_t th;
                    TEST_ASSERT_EQUAL_INT(0, pthread_create(&th, NULL, cancel_later, &c));
                    arbor_err_clear(&e);
                    arbor_accel *tree = arbor_accel_build(&m, &o, &e);
                    pthread_join(th, NULL);
                    if (tree == NULL) {
                        assert_cancelled(tree, &e, what);
                        cancelled++;
                        continue;
                    }
                    TEST_ASSERT_TRUE_MESSAGE(arbor_accel_validate(tree, &e), e.msg);
                    arbor_accel_free(tree);
                }
            TEST_ASSERT_TRUE_MESSAGE(cancelled > 0, what);
        }
    arbor_pool_destroy(pool);
    arbor_mesh_free(&m);
}

int main(void)
{
    UNITY_BEGIN();
    RUN_TEST(test_next_up_is_nextafterf);
    RUN_TEST(test_random_soup_10k);
    RUN_TEST(test_galleon);
    RUN_TEST(test_castle);
    RUN_TEST(test_bunny);
    RUN_TEST(test_own_models);
    RUN_TEST(test_rays_through_vertices_and_edges);
    RUN_TEST(test_degenerate_rays);
    RUN_TEST(test_pool_size_does_not_change_the_tree);
    RUN_TEST(test_build_cancelled_before_it_starts);
    RUN_TEST(test_build_cancelled_while_running);
    return UNITY_END();
}
