/*
 * test_bvh.c - the BVH kind: every builder on random soups and hand-made
 * degenerate meshes (none, one triangle, one shared centroid, copies of one
 * triangle, one plane, tiny with huge, a run that drives the spatial split
 * deep), and rays with a nearly zero direction component, checked by the
 * validator and against brute force for closest hits,
 * any hits, the counted query, and the (tmin, tmax) interval; statistics
 * worked out by hand; the SAH build leaving pack-sized nodes unsplit unless
 * that shrinks their area; the parallel build equal to the serial one; the
 * validator failing on corrupted trees; and the real models galleon, castle
 * and bunny (built on two threads) of ../shared/models.
 *
 * Brute force is the truth throughout. The heavy cross-kind agreement runs
 * are test_accel.c's; these stay small enough to run in seconds.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "arbor/accel.h"
#include "arbor/brute.h"
#include "arbor/load.h"
#include "../../src/accel/bvh_internal.h"
#include "support.h"
#include "unity.h"

void setUp(void) {}
void tearDown(void) {}

static const arbor_builder builders[] = {ARBOR_BUILD_SPATIAL, ARBOR_BUILD_MEDIAN, ARBOR_BUILD_MEAN, ARBOR_BUILD_SAH};
#define NBUILDERS (sizeof builders / sizeof builders[0])

/* Builds a bvh over m and requires it to validate. */
static arbor_accel *build_valid(const arbor_mesh *m, arbor_build_opts *o)
{
    arbor_err e;
    arbor_accel *a = arbor_accel_build(m, o, &e);
    char msg[768];
    snprintf(msg, sizeof msg, "%s build: %s", arbor_builder_name(o->builder), a ? "" : e.msg);
    TEST_ASSERT_NOT_NULL_MESSAGE(a, msg);
    if (!arbor_accel_validate(a, &e)) {
        snprintf(msg, sizeof msg, "%s: invalid tree: %s", arbor_builder_name(o->builder), e.msg);
        TEST_FAIL_MESSAGE(msg);
    }
    return a;
}

static arbor_accel *build_bvh(const arbor_mesh *m, arbor_builder b, int threads)
{
    arbor_build_opts o;
    arbor_build_opts_init(&o, ARBOR_ACCEL_BVH, b);
    o.threads = threads;
    return build_valid(m, &o);
}

/* Rays with brute force's answers. For every eighth ray that hits, two more
 * probe the interval: one starting at the hit (tmin = t) and one ending
 * there (tmax = t). Any hit in a ray's interval exists exactly when a
 * closest one does, so `found` is the any-hit truth too. */
static test_truth truth_make(const arbor_mesh *m, const arbor_ray *rays, size_t n)
{
    test_truth ts;
    ts.rays = malloc(2 * n * sizeof *ts.rays);
    ts.hit = malloc(2 * n * sizeof *ts.hit);
    ts.found = malloc(2 * n * sizeof *ts.found);
    TEST_ASSERT_TRUE(ts.rays && ts.hit && ts.found);
    memcpy(ts.rays, rays, n * sizeof *rays);
    arbor_brute_intersect_many(NULL, m, ts.rays, n, ts.hit, ts.found, 0);
    ts.n = n;
    for (size_t i = 1; i < n; i += 8) {
        if (!ts.found[i])
            continue;
        ts.rays[ts.n] = rays[i];
        ts.rays[ts.n++].tmin = ts.hit[i].t;
        ts.rays[ts.n] = rays[i];
        ts.rays[ts.n++].tmax = ts.hit[i].t;
    }
    arbor_brute_intersect_many(NULL, m, ts.rays + n, ts.n - n, ts.hit + n, ts.found + n, 0);
    return ts;
}

/* The tree's closest hit for ray i against brute force's: same found, same
 * t to 1e-5 relative, tmax shrunk to it, and the reported triangle really
 * hit there with those barycentrics. */
static void expect_same_hit(const arbor_accel *a, const arbor_mesh *m, const test_truth *ts, size_t i, bool counted,
                            const char *what)
{
    const arbor_ray *ray = &ts->rays[i];
    arbor_ray rt = *ray;
    arbor_hit ht;
    arbor_trace_counts c = {0, 0};
    bool ft = counted ? arbor_accel_intersect_counted(a, &rt, &ht, &c) : arbor_accel_intersect(a, &rt, &ht);
    char msg[256];
    snprintf(msg, sizeof msg, "%s ray %zu (%s): tree %s t=%g, brute %s t=%g", what, i, counted ? "counted" : "plain",
             ft ? "hit" : "miss", ft ? (double)ht.t : 0.0, ts->found[i] ? "hit" : "miss",
             ts->found[i] ? (double)ts->hit[i].t : 0.0);
    TEST_ASSERT_EQUAL_MESSAGE(ts->found[i], ft, msg);
    if (counted) {
        TEST_ASSERT_TRUE_MESSAGE(c.nodes > 0 && (!ft || c.tris > 0), msg);
    }
    if (!ft) {
        TEST_ASSERT_TRUE_MESSAGE(rt.tmax == ray->tmax, msg);
        return;
    }
    TEST_ASSERT_TRUE_MESSAGE(test_close(ht.t, ts->hit[i].t, 1e-5f), msg);
    TEST_ASSERT_TRUE_MESSAGE(rt.tmax == ht.t, msg);
    TEST_ASSERT_TRUE_MESSAGE(ht.tri < m->ntris, msg);
    arbor_ray_prep p;
    arbor_ray_prepare(ray, &p);
    arbor_vec3 va, vb, vc;
    arbor_mesh_tri(m, ht.tri, &va, &vb, &vc);
    float t, u, v;
    TEST_ASSERT_TRUE_MESSAGE(arbor_triangle_intersect(ray, &p, va, vb, vc, ray->tmax, &t, &u, &v) && t == ht.t &&
                                 u == ht.u && v == ht.v,
                             msg);
}

/* Closest hit (every fourth ray counted) and any hit for every ray of ts. */
static void check_rays(const arbor_accel *a, const arbor_mesh *m, const test_truth *ts, const char *what)
{
    for (size_t i = 0; i < ts->n; i++) {
        expect_same_hit(a, m, ts, i, i % 4 == 0, what);
        char msg[192];
        snprintf(msg, sizeof msg, "%s ray %zu: occluded", what, i);
        TEST_ASSERT_EQUAL_MESSAGE(ts->found[i], arbor_accel_occluded(a, &ts->rays[i]), msg);
    }
}

/* Every builder over m, validated and checked on the rays. */
static void check_builders(const arbor_mesh *m, const arbor_ray *rays, size_t n, int threads, const char *name)
{
    test_truth ts = truth_make(m, rays, n);
    size_t hits = 0;
    for (size_t i = 0; i < n; i++)
        hits += ts.found[i];
    /* rays that all miss would prove nothing */
    TEST_ASSERT_TRUE_MESSAGE(hits >= n / 50, name);
    for (size_t k = 0; k < NBUILDERS; k++) {
        arbor_accel *a = build_bvh(m, builders[k], threads);
        char what[128];
        snprintf(what, sizeof what, "%s %s", name, arbor_builder_name(builders[k]));
        check_rays(a, m, &ts, what);
        arbor_accel_free(a);
    }
    test_truth_free(&ts);
}

/* check_builders on n of test_random_rays. */
static void check_mesh(const arbor_mesh *m, size_t n, const char *name)
{
    arbor_ray *rays = test_random_rays(m, n, 99);
    check_builders(m, rays, n, 1, name);
    free(rays);
}

static void add_tri(arbor_mesh *m, arbor_vec3 a, arbor_vec3 b, arbor_vec3 c)
{
    uint32_t v = m->nverts;
    TEST_ASSERT_TRUE(arbor_mesh_add_vert(m, a, NULL) && arbor_mesh_add_vert(m, b, NULL) &&
                     arbor_mesh_add_vert(m, c, NULL));
    TEST_ASSERT_TRUE(arbor_mesh_add_tri(m, v, v + 1, v + 2, 0, NULL));
}

static arbor_vec3 random_point(test_rng *g, float lo, float hi)
{
    return vec3(lo + (hi - lo) * test_rng_float(g), lo + (hi - lo) * test_rng_float(g),
                lo + (hi - lo) * test_rng_float(g));
}

/* A triangle of three random points within s of c on every axis. */
static void add_tri_near(arbor_mesh *m, test_rng *g, arbor_vec3 c, float s)
{
    arbor_vec3 a = vec3_add(c, random_point(g, -s, s)), b = vec3_add(c, random_point(g, -s, s));
    add_tri(m, a, b, vec3_add(c, random_point(g, -s, s)));
}

static void test_random_soups(void)
{
    static const uint32_t sizes[] = {40, 300, 3000};
    for (size_t i = 0; i < sizeof sizes / sizeof sizes[0]; i++) {
        arbor_mesh m;
        test_random_soup(&m, sizes[i], 1000 + i);
        char name[64];
        snprintf(name, sizeof name, "soup %u", sizes[i]);
        check_mesh(&m, sizes[i] < 1000 ? 4000 : 20000, name);
        arbor_mesh_free(&m);
    }
}

/* The daemon's trees drop the binary tree once collapsed: the tree rays
 * traverse is the same, so are the hits (brute force's), the statistics
 * but bytes, and the walk; only the binary layout's bytes are gone. */
static void test_dropped_binary_tree(void)
{
    arbor_mesh m;
    test_random_soup(&m, 3000, 77);
    arbor_ray *rays = test_random_rays(&m, 4000, 5);
    test_truth ts = truth_make(&m, rays, 4000);
    for (size_t k = 0; k < NBUILDERS; k++) {
        arbor_build_opts o;
        arbor_build_opts_init(&o, ARBOR_ACCEL_BVH, builders[k]);
        o.threads = 1;
        arbor_accel *kept = build_valid(&m, &o);
        o.drop_binary = true;
        arbor_accel *dropped = build_valid(&m, &o);
        check_rays(dropped, &m, &ts, arbor_builder_name(builders[k]));
        arbor_tree_stats a, b;
        arbor_accel_stats(kept, &a);
        arbor_accel_stats(dropped, &b);
        TEST_ASSERT_EQUAL_UINT64(a.nodes, b.nodes);
        TEST_ASSERT_EQUAL_DOUBLE(a.sah_cost, b.sah_cost);
        TEST_ASSERT_EQUAL_UINT64(a.wide.nodes, b.wide.nodes);
        TEST_ASSERT_EQUAL_UINT64(a.wide.bytes, b.wide.bytes);
        TEST_ASSERT_EQUAL_UINT64(a.wide.bytes, b.bytes);
        TEST_ASSERT_TRUE(a.bytes > b.bytes);
        /* the binary layout's bytes are the tree's as built, held or not */
        arbor_layout_stats binary;
        TEST_ASSERT_TRUE(arbor_tree_layout_stats(&b, ARBOR_LAYOUT_BINARY, &binary));
        TEST_ASSERT_EQUAL_UINT64(a.bytes - a.wide.bytes, binary.bytes);
        TEST_ASSERT_EQUAL_UINT64(a.nodes * 32 + m.ntris * sizeof(uint32_t), binary.bytes); /* 32: a node */
        arbor_accel_free(kept);
        arbor_accel_free(dropped);
    }
    test_truth_free(&ts);
    free(rays);
    arbor_mesh_free(&m);
}

static void test_empty_mesh_misses_everything(void)
{
    arbor_mesh m;
    arbor_mesh_init(&m);
    TEST_ASSERT_TRUE(arbor_mesh_finish(&m, NULL));
    arbor_ray r = {vec3(0, 0, 0), 0.0f, vec3(0, 0, 1), INFINITY};
    for (size_t k = 0; k < NBUILDERS; k++) {
        arbor_accel *a = build_bvh(&m, builders[k], 1);
        arbor_tree_stats s;
        arbor_accel_stats(a, &s);
        TEST_ASSERT_EQUAL_UINT64(0, s.nodes);
        TEST_ASSERT_EQUAL_UINT64(0, s.refs);
        arbor_hit h;
        arbor_trace_counts c = {0, 0};
        arbor_ray q = r;
        TEST_ASSERT_FALSE(arbor_accel_intersect(a, &q, &h));
        TEST_ASSERT_FALSE(arbor_accel_intersect_counted(a, &q, &h, &c));
        TEST_ASSERT_FALSE(arbor_accel_occluded(a, &q));
        TEST_ASSERT_TRUE(q.tmax == INFINITY);
        arbor_accel_free(a);
    }
    arbor_mesh_free(&m);
}

/* One triangle: a single leaf, sah_cost 1, and exact hits. */
static void test_one_triangle(void)
{
    arbor_mesh m;
    arbor_mesh_init(&m);
    add_tri(&m, vec3(0, 0, 0), vec3(1, 0, 0), vec3(0, 1, 0));
    TEST_ASSERT_TRUE(arbor_mesh_finish(&m, NULL));
    for (size_t k = 0; k < NBUILDERS; k++) {
        arbor_accel *a = build_bvh(&m, builders[k], 1);
        arbor_tree_stats s;
        arbor_accel_stats(a, &s);
        TEST_ASSERT_EQUAL_UINT64(1, s.nodes);
        TEST_ASSERT_EQUAL_UINT64(1, s.leaves);
        TEST_ASSERT_EQUAL_UINT32(0, s.max_depth);
        TEST_ASSERT_EQUAL_DOUBLE(1.0, s.sah_cost);
        TEST_ASSERT_EQUAL_DOUBLE(1.0, s.mean_tris_per_leaf);
        arbor_ray r = {vec3(0.25f, 0.25f, 2.0f), 0.0f, vec3(0, 0, -1), INFINITY};
        arbor_hit h;
        TEST_ASSERT_TRUE(arbor_accel_intersect(a, &r, &h));
        TEST_ASSERT_EQUAL_FLOAT(2.0f, h.t);
        TEST_ASSERT_EQUAL_UINT32(0, h.tri);
        arbor_ray away = {vec3(0.25f, 0.25f, 2.0f), 0.0f, vec3(0, 0, 1), INFINITY};
        TEST_ASSERT_FALSE(arbor_accel_intersect(a, &away, &h));
        arbor_accel_free(a);
    }
    arbor_mesh_free(&m);
}

/* Two unit right triangles 10 apart in x with leaves of one: the root and
 * two leaves, and sah_cost = 1 + (A(left) + A(right)) / A(root) by hand. */
static void test_stats_by_hand(void)
{
    arbor_mesh m;
    arbor_mesh_init(&m);
    add_tri(&m, vec3(0, 0, 0), vec3(1, 0, 0), vec3(0, 1, 1));
    add_tri(&m, vec3(10, 0, 0), vec3(11, 0, 0), vec3(10, 1, 1));
    TEST_ASSERT_TRUE(arbor_mesh_finish(&m, NULL));
    /* each leaf box is 1 x 1 x 1: area 6; the root is 11 x 1 x 1: area 2 (11 + 1 + 11) */
    double expect = 1.0 + (6.0 + 6.0) / 46.0;
    for (size_t k = 0; k < NBUILDERS; k++) {
        arbor_build_opts o;
        arbor_build_opts_init(&o, ARBOR_ACCEL_BVH, builders[k]);
        o.max_leaf_tris = 1;
        arbor_accel *a = build_valid(&m, &o);
        arbor_tree_stats s;
        arbor_accel_stats(a, &s);
        TEST_ASSERT_EQUAL_UINT64(3, s.nodes);
        TEST_ASSERT_EQUAL_UINT64(2, s.leaves);
        TEST_ASSERT_EQUAL_UINT64(0, s.empty_leaves);
        TEST_ASSERT_EQUAL_UINT32(1, s.max_depth);
        TEST_ASSERT_EQUAL_DOUBLE(1.0, s.mean_leaf_depth);
        TEST_ASSERT_EQUAL_DOUBLE(1.0, s.mean_tris_per_leaf);
        TEST_ASSERT_EQUAL_UINT64(2, s.refs);
        /* binary: 3 nodes and 2 indices; wide: the two triangles make one
         * leaf, a root with one pack (36 floats of vertices and 4 bytes of
         * index per lane) */
        TEST_ASSERT_EQUAL_UINT64(3 * 32 + 2 * 4 + 32 * BVH_WIDTH + 40 * BVH_WIDTH, s.bytes);
        TEST_ASSERT_DOUBLE_WITHIN(1e-9, expect, s.sah_cost);
        arbor_accel_free(a);
    }
    arbor_mesh_free(&m);
}

/* Triangles of every size and shape whose boxes share one centre: no plane
 * separates their centroids, yet every builder must stop with small leaves. */
static void test_same_centroid(void)
{
    arbor_mesh m;
    arbor_mesh_init(&m);
    test_rng g;
    test_rng_seed(&g, 5);
    arbor_vec3 c = vec3(0.5f, 0.5f, 0.5f);
    for (int i = 0; i < 300; i++) {
        float s = 0.01f + 0.4f * test_rng_float(&g);
        arbor_vec3 d = vec3(s, s * test_rng_float(&g), s * test_rng_float(&g));
        /* corners c - d and c + d make the box centre c; the third vertex lies inside */
        arbor_vec3 inside = vec3_add(c, vec3_mul(d, random_point(&g, -1.0f, 1.0f)));
        add_tri(&m, vec3_sub(c, d), vec3_add(c, d), inside);
    }
    TEST_ASSERT_TRUE(arbor_mesh_finish(&m, NULL));
    check_mesh(&m, 4000, "same centroid");
    for (size_t k = 0; k < NBUILDERS; k++) {
        arbor_accel *a = build_bvh(&m, builders[k], 1);
        arbor_tree_stats s;
        arbor_accel_stats(a, &s);
        TEST_ASSERT_TRUE(s.mean_tris_per_leaf <= 8.0);
        TEST_ASSERT_TRUE(s.max_depth < 64);
        arbor_accel_free(a);
    }
    arbor_mesh_free(&m);
}

static void test_copies_of_one_triangle(void)
{
    arbor_mesh m;
    arbor_mesh_init(&m);
    for (int i = 0; i < 500; i++)
        add_tri(&m, vec3(0.1f, 0.2f, 0.3f), vec3(0.9f, 0.1f, 0.5f), vec3(0.4f, 0.8f, 0.6f));
    TEST_ASSERT_TRUE(arbor_mesh_finish(&m, NULL));
    check_mesh(&m, 2000, "copies");
    arbor_mesh_free(&m);
}

/* Everything in the plane z = 0.5: every box is flat in z. Besides random
 * rays, rays straight down the z axis (two zero direction components, one
 * of them -0) and rays lying in the plane itself. */
static void test_one_plane(void)
{
    arbor_mesh m;
    arbor_mesh_init(&m);
    test_rng g;
    test_rng_seed(&g, 6);
    for (int i = 0; i < 1000; i++) {
        arbor_vec3 c = random_point(&g, 0.0f, 1.0f);
        float s = 0.01f + 0.19f * test_rng_float(&g);
        arbor_vec3 p[3];
        for (int k = 0; k < 3; k++)
            p[k] = vec3(c.x + s * (test_rng_float(&g) - 0.5f), c.y + s * (test_rng_float(&g) - 0.5f), 0.5f);
        add_tri(&m, p[0], p[1], p[2]);
    }
    TEST_ASSERT_TRUE(arbor_mesh_finish(&m, NULL));
    check_mesh(&m, 4000, "plane");
    arbor_ray rays[2000];
    for (int i = 0; i < 2000; i++) {
        arbor_vec3 o = random_point(&g, 0.0f, 1.0f);
        if (i & 1) {
            arbor_ray r = {vec3(o.x, o.y, 2.0f), 0.0f, vec3(-0.0f, 0.0f, -1.0f), INFINITY};
            rays[i] = r;
        } else {
            arbor_ray r = {vec3(-1.0f, o.y, 0.5f), 0.0f, vec3(1.0f, 0.0f, 0.0f), INFINITY};
            rays[i] = r;
        }
    }
    check_builders(&m, rays, 2000, 1, "plane, axis rays");
    arbor_mesh_free(&m);
}

/* Rays along the axes whose origins lie exactly on the planes of the mesh's
 * and the triangles' boxes: 0 * inf in the slab test must not lose a hit. */
static void test_axis_rays_on_box_planes(void)
{
    arbor_mesh m;
    test_random_soup(&m, 500, 8);
    test_rng g;
    test_rng_seed(&g, 9);
    enum { N = 3000 };
    static arbor_ray rays[N];
    for (int i = 0; i < N; i++) {
        /* a vertex of a random triangle: an exact box plane on every axis */
        arbor_vec3 v = m.verts[test_rng_u32(&g) % m.nverts];
        int axis = i % 3;
        float sign = (i / 3) & 1 ? 1.0f : -1.0f;
        arbor_vec3 d = vec3(axis == 0 ? sign : 0.0f, axis == 1 ? sign : 0.0f, axis == 2 ? sign : 0.0f);
        arbor_vec3 o = vec3_sub(v, vec3_scale(d, 3.0f));
        if (i & 8)
            o = vec3(axis == 0 ? o.x : m.bounds.lo.x, axis == 1 ? o.y : m.bounds.hi.y, axis == 2 ? o.z : v.z);
        arbor_ray r = {o, 0.0f, d, INFINITY};
        rays[i] = r;
    }
    check_builders(&m, rays, N, 1, "axis rays");
    arbor_mesh_free(&m);
}

/* Rays with one direction component next to zero (subnormal, so that its
 * inverse is infinite; 3e-38, so that the slab distances overflow; 1e-20;
 * and 0), over a soup at x = 1000..1001: the slab test must neither lose a
 * box the ray runs through nor enter the nodes' empty slots. */
static void test_nearly_axis_rays_far_away(void)
{
    arbor_mesh m;
    arbor_mesh_init(&m);
    test_rng g;
    test_rng_seed(&g, 12);
    for (int i = 0; i < 600; i++) {
        arbor_vec3 c = vec3(1000.0f + test_rng_float(&g), test_rng_float(&g), test_rng_float(&g));
        float s = 0.01f + 0.1f * test_rng_float(&g);
        add_tri_near(&m, &g, c, s);
    }
    TEST_ASSERT_TRUE(arbor_mesh_finish(&m, NULL));
    static const float tiny[] = {1e-39f, -1e-39f, 3e-38f, -3e-38f, 1e-20f, -1e-20f, 0.0f};
    enum { N = 2100 };
    static arbor_ray rays[N];
    for (int i = 0; i < N; i++) {
        arbor_vec3 v = m.verts[test_rng_u32(&g) % m.nverts];
        arbor_vec3 d = vec3(tiny[i % 7], 0.6f, 0.8f);
        if (i & 8)
            d = vec3(tiny[i % 7], -0.8f, 0.6f);
        arbor_ray r = {vec3_sub(v, vec3_scale(d, 3.0f)), 0.0f, d, INFINITY};
        rays[i] = r;
    }
    check_builders(&m, rays, N, 1, "nearly axis rays");
    arbor_mesh_free(&m);
}

/* Rays from far away (10^4 times the soup's size, on every side) aimed
 * exactly at vertices, which are corners of the leaves' boxes, and at
 * points of edges: the slab test's rounding, which grows with the
 * distances, must never cull a box such a ray grazes. The soup sits off
 * the origin, so that its coordinates are large against its boxes. */
static void test_grazing_rays_from_afar(void)
{
    arbor_mesh m;
    arbor_mesh_init(&m);
    test_rng g;
    test_rng_seed(&g, 21);
    for (int i = 0; i < 400; i++) {
        arbor_vec3 c = vec3(300.0f + test_rng_float(&g), -200.0f + test_rng_float(&g), test_rng_float(&g));
        add_tri_near(&m, &g, c, 0.02f + 0.05f * test_rng_float(&g));
    }
    TEST_ASSERT_TRUE(arbor_mesh_finish(&m, NULL));
    enum { N = 3000 };
    static arbor_ray rays[N];
    for (int i = 0; i < N; i++) {
        uint32_t t = test_rng_u32(&g) % m.ntris;
        arbor_vec3 a = m.verts[m.tri_verts[3 * t]], b = m.verts[m.tri_verts[3 * t + 1]];
        float f = i % 3 == 0 ? 0.0f : test_rng_float(&g);
        arbor_vec3 target = vec3_add(a, vec3_scale(vec3_sub(b, a), f));
        arbor_vec3 away = vec3_scale(random_point(&g, -1.0f, 1.0f), 1e4f);
        arbor_ray r = {vec3_add(target, away), 0.0f, vec3_scale(away, -1.0f), INFINITY};
        rays[i] = r;
    }
    check_builders(&m, rays, N, 1, "grazing rays from afar");
    arbor_mesh_free(&m);
}

static void test_tiny_and_huge(void)
{
    arbor_mesh m;
    arbor_mesh_init(&m);
    test_rng g;
    test_rng_seed(&g, 10);
    for (int i = 0; i < 1500; i++) {
        arbor_vec3 c = random_point(&g, -100.0f, 100.0f);
        float s = i % 3 == 0 ? 1e3f : 1e-4f;
        add_tri_near(&m, &g, c, s);
    }
    TEST_ASSERT_TRUE(arbor_mesh_finish(&m, NULL));
    check_mesh(&m, 4000, "tiny and huge");
    arbor_mesh_free(&m);
}

/* Centroids at x = 2^-i: the spatial split peels off one triangle per level
 * and would go 200 deep; the depth limit must keep the tree under 64. */
static void test_deep_spatial_run_is_bounded(void)
{
    arbor_mesh m;
    arbor_mesh_init(&m);
    for (int i = 0; i < 200; i++) {
        float x = ldexpf(1.0f, -i / 2) * (i & 1 ? 1.0f : 1.5f);
        float s = 0.1f * x;
        add_tri(&m, vec3(x - s, 0, 0), vec3(x + s, 0, 0), vec3(x, 1, 0.1f));
    }
    TEST_ASSERT_TRUE(arbor_mesh_finish(&m, NULL));
    check_mesh(&m, 2000, "deep run");
    arbor_accel *a = build_bvh(&m, ARBOR_BUILD_SPATIAL, 1);
    arbor_tree_stats s;
    arbor_accel_stats(a, &s);
    TEST_ASSERT_TRUE(s.max_depth < 64);
    TEST_ASSERT_TRUE(s.max_depth > 20); /* the run did go deep: the limit was exercised */
    arbor_accel_free(a);
    arbor_mesh_free(&m);
}

/* Options: leaves of one triangle, a depth cap, SAH costs. */
static void test_options(void)
{
    arbor_mesh m;
    test_random_soup(&m, 1000, 11);
    arbor_ray *rays = test_random_rays(&m, 2000, 12);
    test_truth ts = truth_make(&m, rays, 2000);
    free(rays);
    for (size_t k = 0; k < NBUILDERS; k++) {
        arbor_build_opts o;
        arbor_build_opts_init(&o, ARBOR_ACCEL_BVH, builders[k]);
        o.max_leaf_tris = 1;
        arbor_accel *a = build_valid(&m, &o);
        arbor_tree_stats s;
        arbor_accel_stats(a, &s);
        TEST_ASSERT_EQUAL_UINT64(1000, s.leaves);
        TEST_ASSERT_EQUAL_UINT64(1999, s.nodes);
        check_rays(a, &m, &ts, "leaf size 1");
        arbor_accel_free(a);

        arbor_build_opts_init(&o, ARBOR_ACCEL_BVH, builders[k]);
        o.max_depth = 3;
        a = build_valid(&m, &o);
        arbor_accel_stats(a, &s);
        TEST_ASSERT_EQUAL_UINT32(3, s.max_depth);
        TEST_ASSERT_TRUE(s.leaves <= 8);
        check_rays(a, &m, &ts, "depth 3");
        arbor_accel_free(a);
    }
    /* dear triangle tests make the SAH split further: smaller leaves */
    arbor_build_opts o;
    arbor_build_opts_init(&o, ARBOR_ACCEL_BVH, ARBOR_BUILD_SAH);
    o.max_leaf_tris = 64;
    o.cost_intersect = 0.1f;
    arbor_accel *cheap = build_valid(&m, &o);
    o.cost_intersect = 10.0f;
    arbor_accel *dear = build_valid(&m, &o);
    arbor_tree_stats sc, sd;
    arbor_accel_stats(cheap, &sc);
    arbor_accel_stats(dear, &sd);
    TEST_ASSERT_TRUE(sd.mean_tris_per_leaf < sc.mean_tris_per_leaf);
    check_rays(dear, &m, &ts, "dear triangles");
    check_rays(cheap, &m, &ts, "cheap triangles");
    arbor_accel_free(cheap);
    arbor_accel_free(dear);
    test_truth_free(&ts);
    arbor_mesh_free(&m);
}

/* SAH optimises the statistic's own cost model: it beats the other three. */
static void test_sah_has_lowest_cost(void)
{
    arbor_mesh m;
    test_random_soup(&m, 5000, 13);
    double cost[NBUILDERS];
    for (size_t k = 0; k < NBUILDERS; k++) {
        arbor_accel *a = build_bvh(&m, builders[k], 1);
        arbor_tree_stats s;
        arbor_accel_stats(a, &s);
        cost[k] = s.sah_cost;
        arbor_accel_free(a);
    }
    for (size_t k = 0; k + 1 < NBUILDERS; k++)
        TEST_ASSERT_TRUE(cost[NBUILDERS - 1] < cost[k]);
    arbor_mesh_free(&m);
}

/* The triangles under binary node i. */
static uint32_t subtree_tris(const bvh_tree *t, uint32_t i)
{
    const bvh_node *n = &t->nodes[i];
    return n->count > 0 ? n->count : subtree_tris(t, i + 1) + subtree_tris(t, n->index);
}

/* The bvh_tree itself (not the arbor_accel around it) of the SAH build
 * over m on `threads`, required to be built and valid; *s its statistics. */
static bvh_tree *build_sah_tree(const arbor_mesh *m, int threads, arbor_tree_stats *s)
{
    arbor_build_opts o;
    arbor_build_opts_init(&o, ARBOR_ACCEL_BVH, ARBOR_BUILD_SAH);
    o.threads = threads;
    accel_run run;
    arbor_pool *own = accel_run_init(&run, &o);
    arbor_err e;
    bvh_tree *t = arbor_bvh_ops.build(m, &o, &run, s, &e);
    arbor_pool_destroy(own);
    TEST_ASSERT_NOT_NULL_MESSAGE(t, e.msg);
    TEST_ASSERT_TRUE_MESSAGE(arbor_bvh_ops.validate(t, m, s, &e), e.msg);
    return t;
}

/* The SAH builder leaves a node that fits one pack of the wide tree
 * unsplit when its children's areas would add up to at least its own
 * (sah_pack_stays_leaf): on bunny, every inner node of at most BVH_WIDTH
 * triangles has children smaller in sum, and the tree stays valid. Some
 * such nodes are split, so the rule does not simply stop at BVH_WIDTH. */
static void test_sah_pack_sized_splits_shrink_area(void)
{
    arbor_mesh m;
    arbor_err e;
    TEST_ASSERT_TRUE(arbor_load_model(test_shared_model("bunny.obj"), &m, &e));
    arbor_tree_stats s;
    bvh_tree *t = build_sah_tree(&m, 1, &s);
    uint32_t small_splits = 0;
    for (uint32_t i = 0; i < t->nnodes; i++) {
        const bvh_node *n = &t->nodes[i];
        if (n->count > 0 || subtree_tris(t, i) > BVH_WIDTH)
            continue;
        small_splits++;
        double children = aabb_area(bvh_node_box(&t->nodes[i + 1])) + aabb_area(bvh_node_box(&t->nodes[n->index]));
        char msg[96];
        snprintf(msg, sizeof msg, "node %u: children's areas %g, its own %g", i, children,
                 (double)aabb_area(bvh_node_box(n)));
        TEST_ASSERT_TRUE_MESSAGE(children < aabb_area(bvh_node_box(n)), msg);
    }
    TEST_ASSERT_TRUE(small_splits > 0);
    arbor_bvh_ops.destroy(t);
    arbor_mesh_free(&m);
}

/* The build on two threads makes the same tree as on one: same statistics
 * and the same hits, on a soup big enough (over 64k triangles) to fork at
 * the top levels and split the linear passes. */
static void test_parallel_build_matches_serial(void)
{
    arbor_mesh m;
    test_random_soup(&m, 70000, 14);
    arbor_ray *rays = test_random_rays(&m, 500, 15);
    test_truth ts = truth_make(&m, rays, 100);
    for (size_t k = 0; k < NBUILDERS; k++) {
        arbor_accel *one = build_bvh(&m, builders[k], 1);
        arbor_accel *two = build_bvh(&m, builders[k], 2);
        arbor_tree_stats s1, s2;
        arbor_accel_stats(one, &s1);
        arbor_accel_stats(two, &s2);
        TEST_ASSERT_EQUAL_UINT64(s1.nodes, s2.nodes);
        TEST_ASSERT_EQUAL_UINT64(s1.leaves, s2.leaves);
        TEST_ASSERT_EQUAL_UINT32(s1.max_depth, s2.max_depth);
        TEST_ASSERT_DOUBLE_WITHIN(1e-9 * s1.sah_cost, s1.sah_cost, s2.sah_cost);
        for (size_t i = 0; i < 500; i++) {
            arbor_ray r1 = rays[i], r2 = rays[i];
            arbor_hit h1, h2;
            bool f1 = arbor_accel_intersect(one, &r1, &h1);
            TEST_ASSERT_EQUAL(f1, arbor_accel_intersect(two, &r2, &h2));
            if (f1) {
                TEST_ASSERT_TRUE(h1.t == h2.t && h1.tri == h2.tri);
            }
        }
        check_rays(two, &m, &ts, "parallel");
        arbor_accel_free(one);
        arbor_accel_free(two);
    }
    free(rays);
    test_truth_free(&ts);
    arbor_mesh_free(&m);
}

/* Rays prefetch the children they enter in a wide tree of at least
 * BVH_PREFETCH_MIN_BYTES (a soup of 300k triangles), not in a smaller one
 * (bunny's), and ARBOR_PREFETCH=0 or 1 overrides the size either way.
 * (That the choice changes no hit, test_kernels checks.) */
static void test_prefetch_by_tree_size(void)
{
    arbor_mesh m[2];
    arbor_err e;
    TEST_ASSERT_TRUE(arbor_load_model(test_shared_model("bunny.obj"), &m[0], &e));
    test_random_soup(&m[1], 300000, 17);
    static const char *const forced[2] = {"1", "0"}; /* the opposite of each mesh's size */
    for (int k = 0; k < 2; k++) {
        arbor_tree_stats s;
        TEST_ASSERT_EQUAL_INT(0, unsetenv("ARBOR_PREFETCH"));
        bvh_tree *t = build_sah_tree(&m[k], 2, &s);
        TEST_ASSERT_EQUAL(k == 1, bvh_wide_bytes(t) >= BVH_PREFETCH_MIN_BYTES);
        TEST_ASSERT_EQUAL(k == 1, t->prefetch);
        arbor_bvh_ops.destroy(t);
        TEST_ASSERT_EQUAL_INT(0, setenv("ARBOR_PREFETCH", forced[k], 1));
        t = build_sah_tree(&m[k], 2, &s);
        TEST_ASSERT_EQUAL(k == 0, t->prefetch);
        arbor_bvh_ops.destroy(t);
        arbor_mesh_free(&m[k]);
    }
    TEST_ASSERT_EQUAL_INT(0, unsetenv("ARBOR_PREFETCH"));
}

/* Asserts that binary trees a and b are the same, byte for byte. */
static void assert_same_binary_tree(const bvh_tree *a, const bvh_tree *b)
{
    TEST_ASSERT_EQUAL_UINT32(a->nnodes, b->nnodes);
    TEST_ASSERT_EQUAL_MEMORY(a->nodes, b->nodes, a->nnodes * sizeof(bvh_node));
    TEST_ASSERT_EQUAL_MEMORY(a->tri_index, b->tri_index, a->ntris * sizeof(uint32_t));
}

/* The build on two threads writes the very binary tree the serial one
 * does, byte for byte, whether a fork's right subtree was built in place or
 * moved there; and the collapse on two threads (its plan cut into subtrees
 * planned at once, its packs filled in two halves) the very wide tree:
 * nodes, packs, their order and padding. */
static void test_parallel_trees_match_serial(void)
{
    arbor_mesh m;
    test_random_soup(&m, 70000, 16);
    arbor_tree_stats s;
    bvh_tree *t[2] = {build_sah_tree(&m, 1, &s), build_sah_tree(&m, 2, &s)};
    assert_same_binary_tree(t[0], t[1]);
    TEST_ASSERT_TRUE(t[0]->nwide > 1000);
    TEST_ASSERT_EQUAL_UINT32(t[0]->nwide, t[1]->nwide);
    TEST_ASSERT_EQUAL_UINT32(t[0]->npacks, t[1]->npacks);
    TEST_ASSERT_EQUAL_MEMORY(t[0]->wide, t[1]->wide, t[0]->nwide * sizeof(bvh_wide_node));
    TEST_ASSERT_EQUAL_MEMORY(t[0]->packs, t[1]->packs, t[0]->npacks * sizeof(bvh_tri_pack));
    for (int k = 0; k < 2; k++)
        arbor_bvh_ops.destroy(t[k]);
    arbor_mesh_free(&m);
}

/* Counts in larger[0] the nodes of t's top `levels` levels with at least
 * min_tris triangles whose left side is at least as large as the right,
 * in larger[1] those whose right side is larger. */
static void count_forks(const bvh_tree *t, uint32_t i, uint32_t levels, uint32_t min_tris, uint32_t larger[2])
{
    const bvh_node *n = &t->nodes[i];
    if (n->count > 0 || levels == 0 || subtree_tris(t, i) < min_tris)
        return;
    larger[subtree_tris(t, n->index) > subtree_tris(t, i + 1)]++;
    count_forks(t, i + 1, levels - 1, min_tris, larger);
    count_forks(t, n->index, levels - 1, min_tris, larger);
}

/* A build of two threads whose forks run both sides on the calling thread,
 * in order (no pool; the budget's spare thread is never taken): a fork
 * whose right side is larger builds it first, where the left's worst case
 * leaves room, and moves it next to the left afterwards; any other builds
 * the left first and the right in place after it. Either way the binary
 * tree is the serial build's, byte for byte, with no timing involved. */
static void test_fork_placement_matches_serial(void)
{
    arbor_mesh m;
    test_random_soup(&m, 70000, 16);
    arbor_tree_stats s;
    bvh_tree *serial = build_sah_tree(&m, 1, &s);
    /* both kinds of fork happen: at 2 threads the build forks nodes of at
     * least 8192 triangles in its top 4 levels (bvh_build.c) */
    uint32_t larger[2] = {0, 0};
    count_forks(serial, 0, 4, 8192, larger);
    TEST_ASSERT_TRUE(larger[0] > 0 && larger[1] > 0);
    arbor_build_opts o;
    arbor_build_opts_init(&o, ARBOR_ACCEL_BVH, ARBOR_BUILD_SAH);
    o.threads = 2;
    accel_run run = {.pool = NULL, .threads = 2, .cancel = NULL};
    arbor_pool_budget_init(&run.budget, NULL, 2);
    atomic_init(&run.stopped, false);
    arbor_err e;
    bvh_tree *forked = arbor_bvh_ops.build(&m, &o, &run, &s, &e);
    TEST_ASSERT_NOT_NULL_MESSAGE(forked, e.msg);
    TEST_ASSERT_TRUE_MESSAGE(arbor_bvh_ops.validate(forked, &m, &s, &e), e.msg);
    assert_same_binary_tree(serial, forked);
    arbor_bvh_ops.destroy(serial);
    arbor_bvh_ops.destroy(forked);
    arbor_mesh_free(&m);
}

/* One corruption of a built tree or its statistics. */
typedef void (*corruption)(bvh_tree *t, arbor_tree_stats *s);

static uint32_t first_leaf(const bvh_tree *t)
{
    uint32_t i = 0;
    while (t->nodes[i].count == 0)
        i++;
    return i;
}

static void shrink_leaf_box(bvh_tree *t, arbor_tree_stats *s)
{
    (void)s;
    bvh_node *n = &t->nodes[first_leaf(t)];
    n->bounds[3] = n->bounds[0];
}
static void grow_child_box(bvh_tree *t, arbor_tree_stats *s)
{
    (void)s;
    t->nodes[1].bounds[4] += 1.0f;
}
/* Still contains everything below it, but is no longer its children's
 * union. */
static void loosen_root_box(bvh_tree *t, arbor_tree_stats *s)
{
    (void)s;
    t->nodes[0].bounds[0] -= 1.0f;
}
static void duplicate_triangle(bvh_tree *t, arbor_tree_stats *s)
{
    (void)s;
    t->tri_index[1] = t->tri_index[0];
}
static void move_vertex_copy(bvh_tree *t, arbor_tree_stats *s)
{
    (void)s;
    t->packs[0].v[1][1][0] += 1e-3f;
}
/* The first leaf child of a wide node: its node and slot. */
static uint32_t first_wide_leaf(const bvh_tree *t, int *slot)
{
    for (uint32_t w = 0;; w++)
        for (*slot = 0; *slot < BVH_WIDTH; ++*slot)
            if (bvh_ref_is_leaf(t->wide[w].child[*slot]) && !bvh_slot_is_empty(&t->wide[w], *slot))
                return w;
}
static void shrink_wide_leaf_box(bvh_tree *t, arbor_tree_stats *s)
{
    (void)s;
    int c;
    uint32_t w = first_wide_leaf(t, &c);
    t->wide[w].box[3][c] = t->wide[w].box[0][c];
}
static void drop_wide_child(bvh_tree *t, arbor_tree_stats *s)
{
    (void)s;
    t->wide[0].child[1] = 0;
}
static void swap_pack_triangle(bvh_tree *t, arbor_tree_stats *s)
{
    (void)s;
    t->packs[0].tri[1] = t->packs[0].tri[0] & ~BVH_PACK_LAST;
}
/* The first leaf's packs run on into the next leaf's. */
static void clear_last_mark(bvh_tree *t, arbor_tree_stats *s)
{
    (void)s;
    uint32_t p = 0;
    while (!bvh_pack_is_last(&t->packs[p]))
        p++;
    t->packs[p].tri[0] &= ~BVH_PACK_LAST;
}
static void misplace_right_child(bvh_tree *t, arbor_tree_stats *s)
{
    (void)s;
    t->nodes[0].index++;
}
static void shift_leaf_range(bvh_tree *t, arbor_tree_stats *s)
{
    (void)s;
    t->nodes[first_leaf(t)].index++;
}
static void miscount_nodes(bvh_tree *t, arbor_tree_stats *s)
{
    (void)t;
    s->nodes++;
}
static void miscount_depth(bvh_tree *t, arbor_tree_stats *s)
{
    (void)t;
    s->max_depth++;
}
static void misstate_mean_leaf_depth(bvh_tree *t, arbor_tree_stats *s)
{
    (void)t;
    s->mean_leaf_depth *= 1.01;
}
static void misstate_sah_cost(bvh_tree *t, arbor_tree_stats *s)
{
    (void)t;
    s->sah_cost *= 1.00001;
}

/* The validator is only worth its checks if it catches a broken tree: each
 * corruption of a freshly built tree must make it fail, and the tree as
 * built must pass. */
static void test_validator_catches_corruption(void)
{
    static const corruption corruptions[] = {
        shrink_leaf_box,   grow_child_box,  duplicate_triangle, move_vertex_copy,         misplace_right_child,
        shift_leaf_range,  miscount_nodes,  miscount_depth,     misstate_mean_leaf_depth, misstate_sah_cost,
        shrink_wide_leaf_box, drop_wide_child, swap_pack_triangle, clear_last_mark, loosen_root_box,
    };
    arbor_mesh m;
    test_random_soup(&m, 500, 17);
    for (size_t k = 0; k < sizeof corruptions / sizeof corruptions[0]; k++) {
        arbor_tree_stats s;
        arbor_err e;
        bvh_tree *t = build_sah_tree(&m, 1, &s);
        corruptions[k](t, &s);
        char msg[64];
        snprintf(msg, sizeof msg, "corruption %zu went unnoticed", k);
        TEST_ASSERT_FALSE_MESSAGE(arbor_bvh_ops.validate(t, &m, &s, &e), msg);
        arbor_bvh_ops.destroy(t);
    }
    arbor_mesh_free(&m);
}

/* A real model: every builder valid and agreeing with brute force on a few
 * random rays; threads is the build's. */
static void check_model(const char *file, size_t nrays, int threads)
{
    arbor_mesh m;
    arbor_err e;
    const char *path = test_shared_model(file);
    if (!arbor_load_model(path, &m, &e)) {
        char msg[768];
        snprintf(msg, sizeof msg, "loading %s: %s", path, e.msg);
        TEST_FAIL_MESSAGE(msg);
    }
    arbor_ray *rays = test_random_rays(&m, nrays, 16);
    check_builders(&m, rays, nrays, threads, file);
    free(rays);
    arbor_mesh_free(&m);
}

static void test_galleon(void) { check_model("galleon.obj", 1000, 1); }
static void test_castle(void) { check_model("castle.obj", 1000, 1); }
static void test_bunny_two_threads(void) { check_model("bunny.obj", 200, 2); }

int main(void)
{
    UNITY_BEGIN();
    RUN_TEST(test_empty_mesh_misses_everything);
    RUN_TEST(test_one_triangle);
    RUN_TEST(test_stats_by_hand);
    RUN_TEST(test_random_soups);
    RUN_TEST(test_same_centroid);
    RUN_TEST(test_copies_of_one_triangle);
    RUN_TEST(test_one_plane);
    RUN_TEST(test_axis_rays_on_box_planes);
    RUN_TEST(test_nearly_axis_rays_far_away);
    RUN_TEST(test_grazing_rays_from_afar);
    RUN_TEST(test_tiny_and_huge);
    RUN_TEST(test_deep_spatial_run_is_bounded);
    RUN_TEST(test_options);
    RUN_TEST(test_sah_has_lowest_cost);
    RUN_TEST(test_sah_pack_sized_splits_shrink_area);
    RUN_TEST(test_parallel_build_matches_serial);
    RUN_TEST(test_dropped_binary_tree);
    RUN_TEST(test_validator_catches_corruption);
    RUN_TEST(test_galleon);
    RUN_TEST(test_castle);
    RUN_TEST(test_bunny_two_threads);
    RUN_TEST(test_parallel_trees_match_serial);
    RUN_TEST(test_prefetch_by_tree_size);
    RUN_TEST(test_fork_placement_matches_serial);
    return UNITY_END();
}
