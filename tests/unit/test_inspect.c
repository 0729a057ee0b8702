/*
 * test_inspect.c - the inspectors of the accel layer: arbor_accel_walk (the
 * viewer's box overlay) and arbor_accel_intersect_traced (the ray path).
 *
 * Independent truths: the traced query must return exactly what the plain
 * and counted queries return (hit, triangle, counts), and the visited
 * nodes' tests and tris must add up to the counts; walked boxes must nest
 * (every child inside its parent), the root must be the mesh's bounds, and
 * the walked nodes, leaves and leaves' triangles must be those the
 * statistics count for the layout rays traverse (the bvh's wide tree).
 */
#include <stdlib.h>
#include <string.h>

#include "arbor/accel.h"
#include "arbor/load.h"
#include "support.h"
#include "unity.h"

void setUp(void) {}
void tearDown(void) {}

#define MAX_WALK 200000

typedef struct {
    uint64_t tests, tris, steps;
    bool monotone;        /* every step's depth is at most one more than the last's */
    uint32_t last_depth;
} path_sum;

static bool sum_step(void *user, const arbor_node_info *n)
{
    path_sum *p = user;
    if (p->steps > 0 && n->depth > p->last_depth + 1)
        p->monotone = false;
    p->last_depth = n->depth;
    p->tests += n->tests;
    p->tris += n->tris;
    p->steps++;
    return true;
}

static void load(const char *file, arbor_mesh *m)
{
    arbor_err e;
    TEST_ASSERT_TRUE_MESSAGE(arbor_load_model(test_repo_model(file), m, &e), e.msg);
}

static arbor_accel *build(const arbor_mesh *m, arbor_accel_kind k, arbor_builder b)
{
    arbor_build_opts o;
    arbor_build_opts_init(&o, k, b);
    o.threads = 1;
    arbor_err e;
    arbor_accel *a = arbor_accel_build(m, &o, &e);
    TEST_ASSERT_NOT_NULL_MESSAGE(a, e.msg);
    return a;
}

static void check_traced_equals_counted(const arbor_mesh *m, const arbor_accel *a)
{
    size_t n = 4000;
    arbor_ray *rays = test_random_rays(m, n, 7);
    for (size_t i = 0; i < n; i++) {
        arbor_ray r1 = rays[i], r2 = rays[i], r3 = rays[i];
        arbor_hit h1, h2, h3;
        arbor_trace_counts c1 = {0, 0}, c2 = {0, 0};
        path_sum p = {0, 0, 0, true, 0};
        bool f1 = arbor_accel_intersect(a, &r1, &h1);
        bool f2 = arbor_accel_intersect_counted(a, &r2, &h2, &c1);
        bool f3 = arbor_accel_intersect_traced(a, &r3, &h3, &c2, sum_step, &p);
        TEST_ASSERT_EQUAL(f1, f3);
        TEST_ASSERT_EQUAL(f2, f3);
        if (f3) {
            TEST_ASSERT_EQUAL_UINT32(h1.tri, h3.tri);
            TEST_ASSERT_EQUAL_FLOAT(h1.t, h3.t);
        }
        TEST_ASSERT_EQUAL_UINT64(c1.nodes, c2.nodes);
        TEST_ASSERT_EQUAL_UINT64(c1.tris, c2.tris);
        TEST_ASSERT_EQUAL_UINT64(c2.nodes, p.tests);
        TEST_ASSERT_EQUAL_UINT64(c2.tris, p.tris);
        TEST_ASSERT_TRUE(p.monotone);
        TEST_ASSERT_TRUE(p.steps > 0 || !f3);
    }
    free(rays);
}

static void test_traced_path_matches_the_counted_traversal(void)
{
    const char *files[] = {"cornell.obj", "menger.obj", "sphereflake.obj"};
    for (size_t f = 0; f < sizeof files / sizeof files[0]; f++) {
        arbor_mesh m;
        load(files[f], &m);
        for (int k = 0; k < ARBOR_ACCEL_KIND_COUNT; k++)
            for (int b = 0; b < ARBOR_BUILDER_COUNT; b++) {
                arbor_accel *a = build(&m, (arbor_accel_kind)k, (arbor_builder)b);
                check_traced_equals_counted(&m, a);
                arbor_accel_free(a);
            }
        arbor_mesh_free(&m);
    }
}

/* ---- walks ---- */

typedef struct {
    arbor_node_info nodes[MAX_WALK];
    uint32_t n;
} walk_log;

static bool log_node(void *user, const arbor_node_info *n)
{
    walk_log *w = user;
    TEST_ASSERT_LESS_THAN_UINT32(MAX_WALK, w->n);
    w->nodes[w->n++] = *n;
    return true;
}

static bool inside(arbor_aabb in, arbor_aabb out)
{
    return in.lo.x >= out.lo.x && in.lo.y >= out.lo.y && in.lo.z >= out.lo.z && in.hi.x <= out.hi.x &&
           in.hi.y <= out.hi.y && in.hi.z <= out.hi.z;
}

/* Depth first, parents before children: a node's parent is the latest
 * earlier node one level up. */
static void check_walk(const arbor_mesh *m, const arbor_accel *a)
{
    static walk_log w;
    w.n = 0;
    arbor_accel_walk(a, 255, log_node, &w);
    TEST_ASSERT_TRUE(w.n > 0);
    TEST_ASSERT_EQUAL_UINT32(0, w.nodes[0].depth);
    TEST_ASSERT_TRUE(inside(m->bounds, w.nodes[0].box) && inside(w.nodes[0].box, m->bounds));
    arbor_tree_stats s;
    arbor_accel_stats(a, &s);
    uint64_t refs = 0, leaves = 0;
    uint32_t parent_at[256];
    for (uint32_t i = 0; i < w.n; i++) {
        const arbor_node_info *n = &w.nodes[i];
        if (n->depth > 0) {
            TEST_ASSERT_TRUE(inside(n->box, w.nodes[parent_at[n->depth - 1]].box));
        }
        parent_at[n->depth] = i;
        refs += n->tris;
        leaves += n->leaf;
    }
    /* the walk is of the tree rays traverse: the bvh's wide layout */
    arbor_layout_stats l;
    TEST_ASSERT_TRUE(arbor_tree_layout_stats(&s, s.has_wide ? ARBOR_LAYOUT_WIDE : ARBOR_LAYOUT_BINARY, &l));
    TEST_ASSERT_EQUAL_UINT64(l.nodes, w.n);
    TEST_ASSERT_EQUAL_UINT64(l.leaves, leaves);
    TEST_ASSERT_EQUAL_UINT64(l.refs, refs);

    /* a walk to depth 1 is the root and its children: the whole walk's
     * nodes at depth 1, two of them in a binary tree (the kd tree) */
    static walk_log top;
    top.n = 0;
    arbor_accel_walk(a, 1, log_node, &top);
    uint32_t children = 0;
    for (uint32_t i = 0; i < w.n; i++)
        children += w.nodes[i].depth == 1;
    for (uint32_t i = 0; i < top.n; i++)
        TEST_ASSERT_TRUE(top.nodes[i].depth <= 1);
    TEST_ASSERT_EQUAL_UINT32(1 + children, top.n);
    if (!s.has_wide)
        TEST_ASSERT_EQUAL_UINT32(w.nodes[0].leaf ? 0 : 2, children);
}

static bool stop_at_once(void *user, const arbor_node_info *n)
{
    (void)n;
    (*(int *)user)++;
    return false;
}

static void test_walk_nests_and_counts_the_tree(void)
{
    arbor_mesh m;
    load("sphere.obj", &m);
    for (int k = 0; k < ARBOR_ACCEL_KIND_COUNT; k++)
        for (int b = 0; b < ARBOR_BUILDER_COUNT; b++) {
            arbor_accel *a = build(&m, (arbor_accel_kind)k, (arbor_builder)b);
            check_walk(&m, a);
            int calls = 0;
            arbor_accel_walk(a, 255, stop_at_once, &calls);
            TEST_ASSERT_EQUAL_INT(1, calls);
            arbor_accel_free(a);
        }
    arbor_mesh_free(&m);
}

int main(void)
{
    UNITY_BEGIN();
    RUN_TEST(test_traced_path_matches_the_counted_traversal);
    RUN_TEST(test_walk_nests_and_counts_the_tree);
    return UNITY_END();
}
