/*
 * test_ray.c - the watertight ray/triangle test: hits, misses, barycentrics,
 * the (tmin, tmax) interval, and rays through shared edges and vertices.
 */
#include <math.h>

#include "arbor/ray.h"
#include "support.h"
#include "unity.h"

void setUp(void) {}
void tearDown(void) {}

static bool hit_tri(arbor_ray r, arbor_vec3 a, arbor_vec3 b, arbor_vec3 c, float *t, float *u, float *v)
{
    arbor_ray_prep p;
    arbor_ray_prepare(&r, &p);
    return arbor_triangle_intersect(&r, &p, a, b, c, r.tmax, t, u, v);
}

static arbor_ray ray(arbor_vec3 o, arbor_vec3 d)
{
    arbor_ray r = {o, 0.0f, d, INFINITY};
    return r;
}

static void test_hit_distance_and_barycentrics(void)
{
    arbor_vec3 a = vec3(0, 0, 0), b = vec3(4, 0, 0), c = vec3(0, 4, 0);
    float t, u, v;
    TEST_ASSERT_TRUE(hit_tri(ray(vec3(1, 2, 5), vec3(0, 0, -1)), a, b, c, &t, &u, &v));
    TEST_ASSERT_FLOAT_WITHIN(1e-6f, 5.0f, t);
    TEST_ASSERT_FLOAT_WITHIN(1e-6f, 0.25f, u); /* weight of b: x / 4 */
    TEST_ASSERT_FLOAT_WITHIN(1e-6f, 0.5f, v);  /* weight of c: y / 4 */
    /* the same triangle seen from behind is hit too (two-sided) */
    TEST_ASSERT_TRUE(hit_tri(ray(vec3(1, 2, -3), vec3(0, 0, 1)), a, b, c, &t, &u, &v));
    TEST_ASSERT_FLOAT_WITHIN(1e-6f, 3.0f, t);
}

static void test_misses(void)
{
    arbor_vec3 a = vec3(0, 0, 0), b = vec3(4, 0, 0), c = vec3(0, 4, 0);
    float t, u, v;
    TEST_ASSERT_FALSE(hit_tri(ray(vec3(3, 3, 5), vec3(0, 0, -1)), a, b, c, &t, &u, &v));  /* outside */
    TEST_ASSERT_FALSE(hit_tri(ray(vec3(1, 1, 5), vec3(0, 0, 1)), a, b, c, &t, &u, &v));   /* behind */
    TEST_ASSERT_FALSE(hit_tri(ray(vec3(-1, 1, 0), vec3(1, 0, 0)), a, b, c, &t, &u, &v));  /* in plane */
    TEST_ASSERT_FALSE(hit_tri(ray(vec3(1, 1, 5), vec3(1, 0, 0)), a, b, c, &t, &u, &v));   /* parallel */
    /* a degenerate (zero-area) triangle is never hit */
    TEST_ASSERT_FALSE(hit_tri(ray(vec3(1, 0, 5), vec3(0, 0, -1)), a, b, vec3(2, 0, 0), &t, &u, &v));
}

static void test_interval(void)
{
    arbor_vec3 a = vec3(0, 0, 0), b = vec3(4, 0, 0), c = vec3(0, 4, 0);
    float t, u, v;
    arbor_ray r = ray(vec3(1, 1, 5), vec3(0, 0, -1));
    r.tmax = 4.999f;
    TEST_ASSERT_FALSE(hit_tri(r, a, b, c, &t, &u, &v));
    r.tmax = 5.001f;
    TEST_ASSERT_TRUE(hit_tri(r, a, b, c, &t, &u, &v));
    r.tmin = 5.0001f;
    TEST_ASSERT_FALSE(hit_tri(r, a, b, c, &t, &u, &v));
}

/* Random rays aimed at points of the shared diagonal of a split square (and
 * at its centre vertex, shared by a fan) must hit one of the triangles: no
 * ray slips through the crack between neighbours. */
static void test_shared_edge_and_vertex(void)
{
    test_rng g;
    test_rng_seed(&g, 3);
    /* a fan of 8 triangles around (0.3, 0.7, 0.2), slightly tilted */
    arbor_vec3 centre = vec3(0.3f, 0.7f, 0.2f), rim[8];
    for (int k = 0; k < 8; k++) {
        float ang = 0.785398f * (float)k + 0.1f;
        rim[k] = vec3(0.3f + cosf(ang), 0.7f + sinf(ang), 0.2f + 0.3f * cosf(2.0f * ang));
    }
    int misses = 0;
    for (int i = 0; i < 20000; i++) {
        arbor_vec3 o = vec3(4.0f * test_rng_float(&g) - 2.0f, 4.0f * test_rng_float(&g) - 2.0f,
                            2.0f + 3.0f * test_rng_float(&g));
        /* aim at the vertex, or at a point of a random spoke (an edge shared by two triangles) */
        int spoke = (int)(test_rng_u32(&g) % 8);
        float s = (i % 4 == 0) ? 0.0f : test_rng_float(&g);
        arbor_vec3 target = vec3_add(centre, vec3_scale(vec3_sub(rim[spoke], centre), s));
        arbor_ray r = ray(o, vec3_normalize(vec3_sub(target, o)));
        bool hit = false;
        for (int k = 0; k < 8 && !hit; k++) {
            float t, u, v;
            hit = hit_tri(r, centre, rim[k], rim[(k + 1) % 8], &t, &u, &v);
        }
        misses += !hit;
    }
    TEST_ASSERT_EQUAL_INT(0, misses);
}

/* A vector normalises to the same bits at every power-of-two scale, far
 * past where its squared length leaves float's range (the normals of a
 * model 1e13 or 1e-13 across); the model sizes the test is exact for are
 * the documented ones. */
static void test_normalize_at_every_scale(void)
{
    arbor_vec3 unit = vec3_normalize(vec3(3.0f, -4.0f, 12.0f));
    TEST_ASSERT_FLOAT_WITHIN(1e-7f, 3.0f / 13.0f, unit.x);
    for (int e = -100; e <= 100; e += 5) {
        arbor_vec3 n = vec3_normalize(vec3(ldexpf(3.0f, e), ldexpf(-4.0f, e), ldexpf(12.0f, e)));
        TEST_ASSERT_EQUAL_MEMORY_MESSAGE(&unit, &n, sizeof n, "scale 2^e");
    }
    TEST_ASSERT_TRUE(arbor_size_traceable(1.0f) && arbor_size_traceable(ARBOR_SIZE_MAX) &&
                     arbor_size_traceable(ARBOR_SIZE_MIN));
    TEST_ASSERT_FALSE(arbor_size_traceable(ARBOR_SIZE_MAX * 2.0f) || arbor_size_traceable(ARBOR_SIZE_MIN / 2.0f) ||
                      arbor_size_traceable(INFINITY));
}

int main(void)
{
    UNITY_BEGIN();
    RUN_TEST(test_hit_distance_and_barycentrics);
    RUN_TEST(test_misses);
    RUN_TEST(test_interval);
    RUN_TEST(test_shared_edge_and_vertex);
    RUN_TEST(test_normalize_at_every_scale);
    return UNITY_END();
}
