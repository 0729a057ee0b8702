/*
 * test_kd.c - the k-d tree, every builder, on random soups and on the cases
 * that break k-d trees: everything in one plane, triangles lying in (or
 * touching) candidate split planes, huge and tiny triangles together, many
 * copies of one triangle, a flat heightfield, a closed room whose walls are
 * the root box's faces, a fan of triangles around one vertex, and 0 and 1
 * triangles. For each: the build ends within the depth limit, validate
 * passes, and closest hit and any hit equal brute force exactly (same t,
 * same triangle, same barycentrics) on random rays, axis-parallel rays and
 * rays that start on candidate split planes, with varied [tmin, tmax].
 * (tests/unit/test_accel.c runs the heavy cross-kind comparison.)
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "arbor/accel.h"
#include "arbor/brute.h"
#include "arbor/load.h"
#include "arbor/pool.h"
#include "support.h"
#include "unity.h"

#define RANDOM_RAYS 20000
#define SPECIAL_RAYS 4000

/* Brute force runs on it; created in main. */
static arbor_pool *pool;

void setUp(void) {}
void tearDown(void) {}

/* ---- meshes ----------------------------------------------------------- */

static void add_tri(arbor_mesh *m, arbor_vec3 a, arbor_vec3 b, arbor_vec3 c)
{
    uint32_t base = m->nverts;
    TEST_ASSERT_TRUE(arbor_mesh_add_vert(m, a, NULL));
    TEST_ASSERT_TRUE(arbor_mesh_add_vert(m, b, NULL));
    TEST_ASSERT_TRUE(arbor_mesh_add_vert(m, c, NULL));
    TEST_ASSERT_TRUE(arbor_mesh_add_tri(m, base, base + 1, base + 2, 0, NULL));
}

static arbor_vec3 rand_point(test_rng *g, float lo, float hi)
{
    return vec3(lo + (hi - lo) * test_rng_float(g), lo + (hi - lo) * test_rng_float(g),
                lo + (hi - lo) * test_rng_float(g));
}

/* Sets coordinate k of p. */
static arbor_vec3 with_axis(arbor_vec3 p, int k, float x)
{
    if (k == 0)
        p.x = x;
    else if (k == 1)
        p.y = x;
    else
        p.z = x;
    return p;
}

static void finish(arbor_mesh *m)
{
    TEST_ASSERT_TRUE(arbor_mesh_finish(m, NULL));
}

/* n random triangles in the plane z = 0.25. */
static void mesh_one_plane(arbor_mesh *m, uint32_t n)
{
    test_rng g;
    test_rng_seed(&g, 11);
    arbor_mesh_init(m);
    for (uint32_t i = 0; i < n; i++) {
        arbor_vec3 c = rand_point(&g, 0.0f, 1.0f);
        float s = 0.01f + 0.1f * test_rng_float(&g);
        arbor_vec3 p[3];
        for (int j = 0; j < 3; j++)
            p[j] = with_axis(vec3_add(c, vec3_scale(rand_point(&g, -1.0f, 1.0f), s)), 2, 0.25f);
        add_tri(m, p[0], p[1], p[2]);
    }
    finish(m);
}

/* The box [0,1]^3 spanned by two big triangles, and, in each of the planes
 * x = 0.5, y = 0.5, z = 0.5, x = 0.25, x = 0.75 (the spatial builder's
 * first planes; any planar triangle's plane is an SAH candidate too):
 * triangles lying in it, triangles with an edge in it, triangles with a
 * vertex in it, on either side; and a soup around them. */
static void mesh_on_planes(arbor_mesh *m)
{
    const int axis[5] = {0, 1, 2, 0, 0};
    const float pos[5] = {0.5f, 0.5f, 0.5f, 0.25f, 0.75f};
    test_rng g;
    test_rng_seed(&g, 12);
    arbor_mesh_init(m);
    add_tri(m, vec3(0, 0, 0), vec3(1, 1, 0), vec3(1, 0, 1));
    add_tri(m, vec3(1, 1, 1), vec3(0, 1, 0), vec3(0, 0, 1));
    for (int q = 0; q < 5; q++)
        for (int i = 0; i < 180; i++) {
            arbor_vec3 c = rand_point(&g, 0.1f, 0.9f), p[3];
            float s = 0.02f + 0.1f * test_rng_float(&g), side = (i & 1) ? 1.0f : -1.0f;
            for (int j = 0; j < 3; j++)
                p[j] = vec3_add(c, vec3_scale(rand_point(&g, -1.0f, 1.0f), s));
            int in_plane = i % 6 < 2 ? 3 : i % 6 < 4 ? 2 : 1;  /* lying, edge, vertex */
            for (int j = 0; j < 3; j++) {
                float off = fabsf(vec3_axis(p[j], axis[q]) - vec3_axis(c, axis[q]));
                p[j] = with_axis(p[j], axis[q], j < in_plane ? pos[q] : pos[q] + side * (off + 0.01f));
            }
            add_tri(m, p[0], p[1], p[2]);
        }
    for (int i = 0; i < 300; i++) {
        arbor_vec3 c = rand_point(&g, 0.05f, 0.95f);
        float s = 0.01f + 0.05f * test_rng_float(&g);
        add_tri(m, vec3_add(c, vec3_scale(rand_point(&g, -1, 1), s)), vec3_add(c, vec3_scale(rand_point(&g, -1, 1), s)),
                vec3_add(c, vec3_scale(rand_point(&g, -1, 1), s)));
    }
    finish(m);
}

/* A few triangles a thousand units across and many a thousandth of a unit
 * across, inside the big ones' span. */
static void mesh_huge_and_tiny(arbor_mesh *m)
{
    test_rng g;
    test_rng_seed(&g, 13);
    arbor_mesh_init(m);
    for (int i = 0; i < 8; i++)
        add_tri(m, rand_point(&g, -1000.0f, 1000.0f), rand_point(&g, -1000.0f, 1000.0f),
                rand_point(&g, -1000.0f, 1000.0f));
    for (int i = 0; i < 800; i++) {
        arbor_vec3 c = rand_point(&g, -10.0f, 10.0f);
        add_tri(m, vec3_add(c, vec3_scale(rand_point(&g, -1, 1), 1e-3f)),
                vec3_add(c, vec3_scale(rand_point(&g, -1, 1), 1e-3f)),
                vec3_add(c, vec3_scale(rand_point(&g, -1, 1), 1e-3f)));
    }
    finish(m);
}

/* 200 copies each of two triangles (one of them flat in y), in a soup. */
static void mesh_copies(arbor_mesh *m)
{
    test_rng g;
    test_rng_seed(&g, 14);
    arbor_mesh_init(m);
    for (int i = 0; i < 200; i++) {
        add_tri(m, vec3(0.2f, 0.3f, 0.1f), vec3(0.7f, 0.4f, 0.8f), vec3(0.3f, 0.9f, 0.5f));
        add_tri(m, vec3(0.1f, 0.6f, 0.1f), vec3(0.9f, 0.6f, 0.2f), vec3(0.4f, 0.6f, 0.9f));
    }
    for (int i = 0; i < 200; i++) {
        arbor_vec3 c = rand_point(&g, 0.0f, 1.0f);
        add_tri(m, vec3_add(c, vec3_scale(rand_point(&g, -1, 1), 0.05f)),
                vec3_add(c, vec3_scale(rand_point(&g, -1, 1), 0.05f)),
                vec3_add(c, vec3_scale(rand_point(&g, -1, 1), 0.05f)));
    }
    finish(m);
}

/* A 25 x 25 grid of quads (two triangles each, sharing vertices) in y = 0
 * with heights of up to 1e-3. */
static void mesh_heightfield(arbor_mesh *m)
{
    const uint32_t n = 25;
    test_rng g;
    test_rng_seed(&g, 15);
    arbor_mesh_init(m);
    for (uint32_t z = 0; z <= n; z++)
        for (uint32_t x = 0; x <= n; x++)
            TEST_ASSERT_TRUE(arbor_mesh_add_vert(m, vec3((float)x / n, 1e-3f * test_rng_float(&g), (float)z / n), NULL));
    for (uint32_t z = 0; z < n; z++)
        for (uint32_t x = 0; x < n; x++) {
            uint32_t v = z * (n + 1) + x;
            TEST_ASSERT_TRUE(arbor_mesh_add_tri(m, v, v + 1, v + n + 1, 0, NULL));
            TEST_ASSERT_TRUE(arbor_mesh_add_tri(m, v + 1, v + n + 2, v + n + 1, 0, NULL));
        }
    finish(m);
}

/* The six walls of [0,2] x [0,1] x [0,1] (two triangles each: the root
 * box's faces, where most centroids lie) around a small soup. */
static void mesh_room(arbor_mesh *m)
{
    test_rng g;
    test_rng_seed(&g, 16);
    arbor_mesh_init(m);
    arbor_vec3 c[8];
    for (int i = 0; i < 8; i++)
        c[i] = vec3((i & 1) ? 2.0f : 0.0f, (i & 2) ? 1.0f : 0.0f, (i & 4) ? 1.0f : 0.0f);
    const int quads[6][4] = {{0, 1, 3, 2}, {4, 5, 7, 6}, {0, 1, 5, 4}, {2, 3, 7, 6}, {0, 2, 6, 4}, {1, 3, 7, 5}};
    for (int q = 0; q < 6; q++) {
        add_tri(m, c[quads[q][0]], c[quads[q][1]], c[quads[q][2]]);
        add_tri(m, c[quads[q][0]], c[quads[q][2]], c[quads[q][3]]);
    }
    for (int i = 0; i < 40; i++) {
        arbor_vec3 p = vec3(0.2f + 1.6f * test_rng_float(&g), 0.2f + 0.6f * test_rng_float(&g),
                            0.2f + 0.6f * test_rng_float(&g));
        add_tri(m, p, vec3_add(p, vec3_scale(rand_point(&g, -1, 1), 0.1f)),
                vec3_add(p, vec3_scale(rand_point(&g, -1, 1), 0.1f)));
    }
    finish(m);
}

/* 400 thin triangles around the vertex (0.5, 0.5, 0.5): every plane
 * through the middle cuts them all. */
static void mesh_fan(arbor_mesh *m)
{
    test_rng g;
    test_rng_seed(&g, 17);
    arbor_mesh_init(m);
    arbor_vec3 centre = vec3(0.5f, 0.5f, 0.5f);
    for (int i = 0; i < 400; i++) {
        arbor_vec3 a = rand_point(&g, 0.0f, 1.0f);
        arbor_vec3 b = vec3_add(a, vec3_scale(rand_point(&g, -1, 1), 0.05f));
        add_tri(m, centre, a, b);
    }
    finish(m);
}

/* ---- rays and the truth ----------------------------------------------- */

/* Rays meant to hit the corner cases: origins with coordinates set to a
 * vertex's (the planes SAH splits at), to a triangle's box centre (where
 * median and mean split), or to a dyadic fraction of the box (the spatial
 * builder's planes), or left random; directions along an axis, toward a
 * triangle, or toward one with a component zeroed (+0 or -0). */
static arbor_ray *special_rays(const arbor_mesh *m, size_t n, uint64_t seed)
{
    test_rng g;
    test_rng_seed(&g, seed);
    arbor_ray *rays = malloc(n * sizeof *rays);
    TEST_ASSERT_NOT_NULL(rays);
    arbor_vec3 lo = m->bounds.lo, ext = aabb_extent(m->bounds);
    for (size_t i = 0; i < n; i++) {
        arbor_vec3 o = vec3(lo.x + ext.x * (1.5f * test_rng_float(&g) - 0.25f),
                            lo.y + ext.y * (1.5f * test_rng_float(&g) - 0.25f),
                            lo.z + ext.z * (1.5f * test_rng_float(&g) - 0.25f));
        uint32_t tri = m->ntris ? test_rng_u32(&g) % m->ntris : 0;
        for (int k = 0; k < 3; k++) {
            uint32_t pick = test_rng_u32(&g) % 4;
            if (pick == 0 && m->nverts) {
                o = with_axis(o, k, vec3_axis(m->verts[test_rng_u32(&g) % m->nverts], k));
            } else if (pick == 1 && m->ntris) {
                arbor_aabb box = arbor_mesh_tri_bounds(m, test_rng_u32(&g) % m->ntris);
                o = with_axis(o, k, vec3_axis(aabb_center(box), k));
            } else if (pick == 2) {
                /* the middle, a quarter, an eighth, ... of the box */
                int level = 1 + (int)(test_rng_u32(&g) % 5);
                float frac = (float)(2 * (test_rng_u32(&g) % (1u << (level - 1))) + 1) / (float)(1u << level);
                o = with_axis(o, k, vec3_axis(lo, k) + vec3_axis(ext, k) * frac);
            }
        }
        arbor_vec3 d = vec3(0, 0, 0);
        int k = (int)(test_rng_u32(&g) % 3);
        if (i % 3 == 0 || m->ntris == 0) {
            d = with_axis(d, k, (test_rng_u32(&g) & 1) ? 1.0f : -1.0f);
        } else {
            arbor_vec3 a, b, c;
            arbor_mesh_tri(m, tri, &a, &b, &c);
            d = vec3_sub(vec3_scale(vec3_add(vec3_add(a, b), c), 1.0f / 3.0f), o);
            if (i % 3 == 2)
                d = with_axis(d, k, (test_rng_u32(&g) & 1) ? 0.0f : -0.0f);
            if (vec3_length(d) == 0.0f)
                d = vec3(0, 1, 0);
            d = vec3_normalize(d);
        }
        arbor_ray r = {o, 0.0f, d, INFINITY};
        rays[i] = r;
    }
    return rays;
}

/* One ray set with brute force's answers. A third of the rays get a
 * positive tmin and a third a finite tmax, so the interval is tested too. */
typedef struct {
    arbor_ray *rays;
    size_t n;
    arbor_hit *hit;
    bool *found;
    bool *occluded;
    size_t hits;
} truth;

/* arbor_brute_occluded over the rays, one ray per parallel loop index. */
typedef struct {
    const arbor_mesh *m;
    const arbor_ray *rays;
    bool *occluded;
} occluded_job;

static void occluded_run(void *ctx, uint32_t i)
{
    occluded_job *j = ctx;
    j->occluded[i] = arbor_brute_occluded(j->m, &j->rays[i]);
}

static void truth_compute(truth *ts, const arbor_mesh *m)
{
    arbor_ray *random = test_random_rays(m, RANDOM_RAYS, 5);
    arbor_ray *special = special_rays(m, SPECIAL_RAYS, 6);
    TEST_ASSERT_NOT_NULL(random);
    ts->n = RANDOM_RAYS + SPECIAL_RAYS;
    ts->rays = malloc(ts->n * sizeof *ts->rays);
    ts->hit = malloc(ts->n * sizeof *ts->hit);
    ts->found = malloc(ts->n * sizeof *ts->found);
    ts->occluded = malloc(ts->n * sizeof *ts->occluded);
    TEST_ASSERT_TRUE(ts->rays && ts->hit && ts->found && ts->occluded);
    memcpy(ts->rays, random, RANDOM_RAYS * sizeof *random);
    memcpy(ts->rays + RANDOM_RAYS, special, SPECIAL_RAYS * sizeof *special);
    free(random);
    free(special);
    float diag = vec3_length(aabb_extent(m->bounds));
    test_rng g;
    test_rng_seed(&g, 8);
    for (size_t i = 0; i < ts->n; i++) {
        if (i % 3 == 1)
            ts->rays[i].tmin = 0.5f * diag * test_rng_float(&g);
        else if (i % 3 == 2)
            ts->rays[i].tmax = 1.5f * diag * test_rng_float(&g);
    }
    arbor_brute_intersect_many(pool, m, ts->rays, ts->n, ts->hit, ts->found, 0);
    occluded_job job = {m, ts->rays, ts->occluded};
    arbor_pool_parallel(pool, (uint32_t)ts->n, 0, occluded_run, &job);
    ts->hits = 0;
    for (size_t i = 0; i < ts->n; i++)
        ts->hits += ts->found[i];
}

static void truth_free(truth *ts)
{
    free(ts->rays);
    free(ts->hit);
    free(ts->found);
    free(ts->occluded);
}

/* ---- checks ----------------------------------------------------------- */

static arbor_accel *build_checked(const arbor_mesh *m, const arbor_build_opts *o, const char *what)
{
    arbor_err e;
    char msg[1024];
    arbor_accel *tree = arbor_accel_build(m, o, &e);
    if (tree == NULL) {
        snprintf(msg, sizeof msg, "%s: build failed: %s", what, e.msg);
        TEST_FAIL_MESSAGE(msg);
    }
    if (!arbor_accel_validate(tree, &e)) {
        snprintf(msg, sizeof msg, "%s: validate: %s", what, e.msg);
        TEST_FAIL_MESSAGE(msg);
    }
    return tree;
}

/* pbrt's default depth limit, round(8 + 1.3 floor(log2 N)). */
static uint32_t default_depth_limit(uint32_t ntris)
{
    int log2n = 0;
    while (ntris >> (log2n + 1))
        log2n++;
    return (uint32_t)lround(8.0 + 1.3 * log2n);
}

/* Closest and any hit of tree on every ray of ts equal brute force's. */
static void check_rays(const arbor_accel *tree, const truth *ts, const char *what)
{
    char msg[1024];
    for (size_t i = 0; i < ts->n; i++) {
        arbor_ray r = ts->rays[i];
        arbor_hit h = {0, 0, 0, 0};
        bool found = arbor_accel_intersect(tree, &r, &h);
        const arbor_hit *b = &ts->hit[i];
        bool ok = found == ts->found[i] &&
                  (found ? h.t == b->t && h.tri == b->tri && h.u == b->u && h.v == b->v && r.tmax == h.t
                         : r.tmax == ts->rays[i].tmax);
        if (!ok) {
            const arbor_ray *q = &ts->rays[i];
            snprintf(msg, sizeof msg,
                     "%s: ray %zu o=(%.9g %.9g %.9g) d=(%.9g %.9g %.9g) [%g, %g]: tree %s t=%.9g tri=%u, brute %s "
                     "t=%.9g tri=%u",
                     what, i, q->o.x, q->o.y, q->o.z, q->d.x, q->d.y, q->d.z, q->tmin, q->tmax,
                     found ? "hit" : "miss", h.t, h.tri, ts->found[i] ? "hit" : "miss", b->t, b->tri);
            TEST_FAIL_MESSAGE(msg);
        }
        if (arbor_accel_occluded(tree, &ts->rays[i]) != ts->occluded[i]) {
            snprintf(msg, sizeof msg, "%s: ray %zu: occluded should be %d", what, i, ts->occluded[i]);
            TEST_FAIL_MESSAGE(msg);
        }
    }
}

/* Every builder over m (default options): builds, validates, stays within
 * the depth limit and answers every ray as brute force does. */
static void check_mesh(const char *name, const arbor_mesh *m)
{
    truth ts;
    truth_compute(&ts, m);
    /* a ray set that misses everything (or hits everything) proves little */
    if (m->ntris > 1) {
        TEST_ASSERT_TRUE_MESSAGE(ts.hits > ts.n / 20 && ts.hits < ts.n, "ray set hits too little or everything");
    }
    for (int b = 0; b < ARBOR_BUILDER_COUNT; b++) {
        char what[128];
        snprintf(what, sizeof what, "%s kd %s", name, arbor_builder_name((arbor_builder)b));
        arbor_build_opts o;
        arbor_build_opts_init(&o, ARBOR_ACCEL_KD, (arbor_builder)b);
        arbor_accel *tree = build_checked(m, &o, what);
        arbor_tree_stats s;
        arbor_accel_stats(tree, &s);
        TEST_ASSERT_LESS_OR_EQUAL_UINT32_MESSAGE(default_depth_limit(m->ntris), s.max_depth, what);
        TEST_ASSERT_EQUAL_UINT64_MESSAGE(2 * s.leaves - 1, s.nodes, what);
        TEST_ASSERT_TRUE_MESSAGE(s.refs >= m->ntris, what);
        check_rays(tree, &ts, what);
        arbor_accel_free(tree);
    }
    truth_free(&ts);
}

/* ---- the tests -------------------------------------------------------- */

static void test_random_soup_every_builder(void)
{
    arbor_mesh m;
    test_random_soup(&m, 1200, 1);
    check_mesh("soup", &m);
    arbor_mesh_free(&m);
}

static void test_all_in_one_plane(void)
{
    arbor_mesh m;
    mesh_one_plane(&m, 600);
    check_mesh("one plane", &m);
    arbor_mesh_free(&m);
}

static void test_triangles_on_split_planes(void)
{
    arbor_mesh m;
    mesh_on_planes(&m);
    check_mesh("on planes", &m);
    arbor_mesh_free(&m);
}

static void test_huge_and_tiny(void)
{
    arbor_mesh m;
    mesh_huge_and_tiny(&m);
    check_mesh("huge and tiny", &m);
    arbor_mesh_free(&m);
}

static void test_many_copies(void)
{
    arbor_mesh m;
    mesh_copies(&m);
    check_mesh("copies", &m);
    arbor_mesh_free(&m);
}

static void test_flat_heightfield(void)
{
    arbor_mesh m;
    mesh_heightfield(&m);
    check_mesh("heightfield", &m);
    arbor_mesh_free(&m);
}

static void test_room_walls_on_root_faces(void)
{
    arbor_mesh m;
    mesh_room(&m);
    check_mesh("room", &m);
    arbor_mesh_free(&m);
}

static void test_fan_around_one_vertex(void)
{
    arbor_mesh m;
    mesh_fan(&m);
    check_mesh("fan", &m);
    arbor_mesh_free(&m);
}

static void test_no_triangles(void)
{
    arbor_mesh m;
    arbor_mesh_init(&m);
    finish(&m);
    arbor_ray r = {vec3(0, 0, 0), 0.0f, vec3(0, 0, 1), INFINITY};
    for (int b = 0; b < ARBOR_BUILDER_COUNT; b++) {
        arbor_build_opts o;
        arbor_build_opts_init(&o, ARBOR_ACCEL_KD, (arbor_builder)b);
        arbor_accel *tree = build_checked(&m, &o, "no triangles");
        arbor_tree_stats s;
        arbor_accel_stats(tree, &s);
        TEST_ASSERT_EQUAL_UINT64(1, s.nodes);
        TEST_ASSERT_EQUAL_UINT64(1, s.empty_leaves);
        TEST_ASSERT_EQUAL_UINT64(0, s.refs);
        arbor_ray q = r;
        arbor_hit h;
        TEST_ASSERT_FALSE(arbor_accel_intersect(tree, &q, &h));
        TEST_ASSERT_FALSE(arbor_accel_occluded(tree, &r));
        arbor_accel_free(tree);
    }
    arbor_mesh_free(&m);
}

static void test_one_triangle(void)
{
    arbor_mesh m;
    arbor_mesh_init(&m);
    add_tri(&m, vec3(0, 0, 0), vec3(1, 0, 0), vec3(0, 1, 0.5f));
    finish(&m);
    for (int b = 0; b < ARBOR_BUILDER_COUNT; b++) {
        arbor_build_opts o;
        arbor_build_opts_init(&o, ARBOR_ACCEL_KD, (arbor_builder)b);
        arbor_accel *tree = build_checked(&m, &o, "one triangle");
        arbor_tree_stats s;
        arbor_accel_stats(tree, &s);
        /* a lone triangle is a leaf: the cost is the root's area times 1 */
        TEST_ASSERT_EQUAL_UINT64(1, s.nodes);
        TEST_ASSERT_EQUAL_UINT64(1, s.refs);
        TEST_ASSERT_EQUAL_DOUBLE(1.0, s.sah_cost);
        arbor_accel_free(tree);
    }
    check_mesh("one triangle", &m);
    arbor_mesh_free(&m);
}

/* max_depth and max_leaf_tris are obeyed, and a shallow tree is still exact. */
static void test_depth_and_leaf_options(void)
{
    arbor_mesh m;
    test_random_soup(&m, 1000, 2);
    truth ts;
    truth_compute(&ts, &m);
    for (int b = 0; b < ARBOR_BUILDER_COUNT; b++) {
        arbor_build_opts o;
        arbor_build_opts_init(&o, ARBOR_ACCEL_KD, (arbor_builder)b);
        o.max_depth = 3;
        arbor_accel *tree = build_checked(&m, &o, "max_depth 3");
        arbor_tree_stats s;
        arbor_accel_stats(tree, &s);
        TEST_ASSERT_LESS_OR_EQUAL_UINT32(3, s.max_depth);
        check_rays(tree, &ts, "max_depth 3");
        arbor_accel_free(tree);

        arbor_build_opts_init(&o, ARBOR_ACCEL_KD, (arbor_builder)b);
        o.max_leaf_tris = 1000;
        tree = build_checked(&m, &o, "max_leaf_tris 1000");
        arbor_accel_stats(tree, &s);
        TEST_ASSERT_EQUAL_UINT64(1, s.nodes);
        TEST_ASSERT_EQUAL_UINT64(1000, s.refs);
        arbor_accel_free(tree);
    }
    truth_free(&ts);
    arbor_mesh_free(&m);
}

/* The SAH's options steer it: traversal too dear for any split gives a
 * single leaf; a larger empty-space bonus cuts off more empty cells. */
static void test_sah_cost_options(void)
{
    arbor_mesh m;
    test_random_soup(&m, 2000, 3);
    arbor_build_opts o;
    arbor_build_opts_init(&o, ARBOR_ACCEL_KD, ARBOR_BUILD_SAH);
    o.cost_traverse = 1e9f;
    arbor_accel *tree = build_checked(&m, &o, "sah KT 1e9");
    arbor_tree_stats s;
    arbor_accel_stats(tree, &s);
    TEST_ASSERT_EQUAL_UINT64(1, s.nodes);
    arbor_accel_free(tree);

    arbor_tree_stats none, big;
    arbor_build_opts_init(&o, ARBOR_ACCEL_KD, ARBOR_BUILD_SAH);
    o.empty_bonus = 0.0f;
    tree = build_checked(&m, &o, "sah no bonus");
    arbor_accel_stats(tree, &none);
    arbor_accel_free(tree);
    o.empty_bonus = 0.6f;
    tree = build_checked(&m, &o, "sah bonus 0.6");
    arbor_accel_stats(tree, &big);
    arbor_accel_free(tree);
    TEST_ASSERT_GREATER_THAN_UINT64(none.empty_leaves, big.empty_leaves);
    arbor_mesh_free(&m);
}

/* The SAH tree has a lower SAH cost than the spatial-median one: the
 * builder optimises what it claims to. sah_cost weighs a node and a
 * triangle test alike, so the SAH build is given those weights (its
 * defaults weigh packed triangle tests below a step). */
static void test_sah_cost_below_spatial(void)
{
    arbor_mesh m;
    test_random_soup(&m, 5000, 4);
    arbor_tree_stats s[2];
    const arbor_builder builders[2] = {ARBOR_BUILD_SPATIAL, ARBOR_BUILD_SAH};
    for (int i = 0; i < 2; i++) {
        arbor_build_opts o;
        arbor_build_opts_init(&o, ARBOR_ACCEL_KD, builders[i]);
        o.cost_traverse = o.cost_intersect = 1.0f;
        arbor_accel *tree = build_checked(&m, &o, arbor_builder_name(builders[i]));
        arbor_accel_stats(tree, &s[i]);
        arbor_accel_free(tree);
    }
    TEST_ASSERT_TRUE(s[1].sah_cost < s[0].sah_cost);
    arbor_mesh_free(&m);
}

/* Building on several threads gives the very same tree as on one. */
static void test_threads_build_the_same_tree(void)
{
    arbor_mesh m;
    test_random_soup(&m, 4000, 5);
    for (int b = 0; b < ARBOR_BUILDER_COUNT; b++) {
        arbor_tree_stats s[2];
        const int threads[2] = {1, 8};
        for (int i = 0; i < 2; i++) {
            arbor_build_opts o;
            arbor_build_opts_init(&o, ARBOR_ACCEL_KD, (arbor_builder)b);
            o.threads = threads[i];
            arbor_accel *tree = build_checked(&m, &o, "threads");
            arbor_accel_stats(tree, &s[i]);
            arbor_accel_free(tree);
        }
        TEST_ASSERT_EQUAL_UINT64(s[0].nodes, s[1].nodes);
        TEST_ASSERT_EQUAL_UINT64(s[0].refs, s[1].refs);
        TEST_ASSERT_EQUAL_UINT64(s[0].empty_leaves, s[1].empty_leaves);
        TEST_ASSERT_EQUAL_UINT32(s[0].max_depth, s[1].max_depth);
        TEST_ASSERT_DOUBLE_WITHIN(1e-9 * s[0].sah_cost, s[0].sah_cost, s[1].sah_cost);
    }
    arbor_mesh_free(&m);
}

/* The counted query finds the same hits and counts real work: a node or
 * more per ray that meets the box, a test per hit, and far fewer tests than
 * brute force's one per triangle. */
static void test_counted_traversal(void)
{
    arbor_mesh m;
    test_random_soup(&m, 4000, 6);
    arbor_ray *rays = test_random_rays(&m, 4000, 9);
    for (int b = 0; b < ARBOR_BUILDER_COUNT; b++) {
        arbor_build_opts o;
        arbor_build_opts_init(&o, ARBOR_ACCEL_KD, (arbor_builder)b);
        arbor_accel *tree = build_checked(&m, &o, "counted");
        arbor_trace_counts total = {0, 0};
        for (size_t i = 0; i < 4000; i++) {
            arbor_ray r1 = rays[i], r2 = rays[i];
            arbor_hit h1, h2;
            arbor_trace_counts c = {0, 0};
            bool f1 = arbor_accel_intersect(tree, &r1, &h1);
            bool f2 = arbor_accel_intersect_counted(tree, &r2, &h2, &c);
            TEST_ASSERT_EQUAL(f1, f2);
            if (f1) {
                TEST_ASSERT_EQUAL_UINT32(h1.tri, h2.tri);
                TEST_ASSERT_TRUE(c.nodes >= 1 && c.tris >= 1);
            }
            total.nodes += c.nodes;
            total.tris += c.tris;
        }
        TEST_ASSERT_TRUE(total.tris < 4000ull * 4000ull / 20);
        arbor_accel_free(tree);
    }
    free(rays);
    arbor_mesh_free(&m);
}

/* Real models validate for every builder (skipped until they can be read). */
static void check_shared_model(const char *file)
{
    arbor_mesh m;
    arbor_err e;
    char msg[768];
    if (!arbor_load_model(test_shared_model(file), &m, &e)) {
        snprintf(msg, sizeof msg, "cannot read %s: %s", file, e.msg);
        TEST_IGNORE_MESSAGE(msg);
    }
    for (int b = 0; b < ARBOR_BUILDER_COUNT; b++) {
        char what[128];
        snprintf(what, sizeof what, "%s kd %s", file, arbor_builder_name((arbor_builder)b));
        arbor_build_opts o;
        arbor_build_opts_init(&o, ARBOR_ACCEL_KD, (arbor_builder)b);
        arbor_accel_free(build_checked(&m, &o, what));
    }
    arbor_mesh_free(&m);
}

static void test_galleon_validates(void) { check_shared_model("galleon.obj"); }
static void test_castle_validates(void) { check_shared_model("castle.obj"); }
static void test_bunny_validates(void) { check_shared_model("bunny.obj"); }

int main(void)
{
    arbor_err e;
    pool = arbor_pool_create(0, &e);
    TEST_ASSERT_NOT_NULL(pool);
    UNITY_BEGIN();
    RUN_TEST(test_random_soup_every_builder);
    RUN_TEST(test_all_in_one_plane);
    RUN_TEST(test_triangles_on_split_planes);
    RUN_TEST(test_huge_and_tiny);
    RUN_TEST(test_many_copies);
    RUN_TEST(test_flat_heightfield);
    RUN_TEST(test_room_walls_on_root_faces);
    RUN_TEST(test_fan_around_one_vertex);
    RUN_TEST(test_no_triangles);
    RUN_TEST(test_one_triangle);
    RUN_TEST(test_depth_and_leaf_options);
    RUN_TEST(test_sah_cost_options);
    RUN_TEST(test_sah_cost_below_spatial);
    RUN_TEST(test_threads_build_the_same_tree);
    RUN_TEST(test_counted_traversal);
    RUN_TEST(test_galleon_validates);
    RUN_TEST(test_castle_validates);
    RUN_TEST(test_bunny_validates);
    int failures = UNITY_END();
    arbor_pool_destroy(pool);
    return failures;
}
