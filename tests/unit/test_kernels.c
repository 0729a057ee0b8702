/*
 * test_kernels.c - every traversal kernel (accel_impl.h) gives brute
 * force's hits. A BVH and a k-d tree are built once per kernel
 * (ARBOR_KERNEL=sse2 picks the SSE2 one, none the best the CPU has), the
 * BVH once with and once without its rays prefetching the children they
 * enter (ARBOR_PREFETCH: two instances of its traversal loop), over a
 * real model, a random soup and a mesh of ties (coincident triangles: equal
 * t, the lowest index must win), and each kernel's closest hits (t, u, v,
 * triangle) and any-hit answers must equal brute force's bit for bit, for
 * random rays and PROTOCOL.md's primary rays.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "arbor/accel.h"
#include "arbor/brute.h"
#include "arbor/load.h"
#include "support.h"
#include "unity.h"

void setUp(void) {}
void tearDown(void) {}

/* Builds the sah tree of that kind over m with the kernel `name` ("sse2"),
 * or the CPU's best (NULL), and ARBOR_PREFETCH=prefetch ("0", "1"; the
 * k-d tree ignores it), and checks the kernel name reported. */
static arbor_accel *build_with(const arbor_mesh *m, arbor_accel_kind kind, const char *name, const char *prefetch)
{
    TEST_ASSERT_EQUAL_INT(0, setenv("ARBOR_PREFETCH", prefetch, 1));
    if (name != NULL)
        TEST_ASSERT_EQUAL_INT(0, setenv("ARBOR_KERNEL", name, 1));
    else
        TEST_ASSERT_EQUAL_INT(0, unsetenv("ARBOR_KERNEL"));
    if (name != NULL)
        TEST_ASSERT_EQUAL_STRING(name, arbor_accel_kernel_name());
    arbor_build_opts o;
    arbor_build_opts_init(&o, kind, ARBOR_BUILD_SAH);
    o.threads = 1;
    arbor_err e;
    arbor_accel *a = arbor_accel_build(m, &o, &e);
    TEST_ASSERT_NOT_NULL_MESSAGE(a, e.msg);
    TEST_ASSERT_TRUE_MESSAGE(arbor_accel_validate(a, &e), e.msg);
    return a;
}

/* Tree a (kind `kind`) against brute force's truth and found on n rays;
 * returns the rays that hit. */
static size_t check_tree(const arbor_accel *a, arbor_accel_kind kind, const arbor_ray *rays, size_t n,
                         const arbor_hit *truth, const bool *found, const char *what)
{
    const char *kernel = arbor_accel_kernel_name();
    const char *prefetch = getenv("ARBOR_PREFETCH");
    size_t hits = 0;
    for (size_t i = 0; i < n; i++) {
        arbor_ray r = rays[i];
        arbor_hit h;
        char msg[160];
        snprintf(msg, sizeof msg, "%s, %s, kernel %s, prefetch %s, ray %zu", what, arbor_accel_kind_name(kind),
                 kernel, prefetch, i);
        bool got = arbor_accel_intersect(a, &r, &h);
        TEST_ASSERT_EQUAL_MESSAGE(found[i], got, msg);
        TEST_ASSERT_EQUAL_MESSAGE(found[i], arbor_accel_occluded(a, &rays[i]), msg);
        if (!got)
            continue;
        hits++;
        TEST_ASSERT_EQUAL_UINT32_MESSAGE(truth[i].tri, h.tri, msg);
        TEST_ASSERT_TRUE_MESSAGE(memcmp(&truth[i].t, &h.t, sizeof h.t) == 0, msg);
        TEST_ASSERT_TRUE_MESSAGE(memcmp(&truth[i].u, &h.u, sizeof h.u) == 0, msg);
        TEST_ASSERT_TRUE_MESSAGE(memcmp(&truth[i].v, &h.v, sizeof h.v) == 0, msg);
    }
    return hits;
}

/* Each kind under each kernel against brute force on n rays. */
static void check_rays(const arbor_mesh *m, const arbor_ray *rays, size_t n, const char *what)
{
    arbor_hit *truth = malloc(n * sizeof *truth);
    bool *found = malloc(n * sizeof *found);
    TEST_ASSERT_NOT_NULL(truth);
    TEST_ASSERT_NOT_NULL(found);
    arbor_brute_intersect_many(NULL, m, rays, n, truth, found, 0);
    static const char *const kernels[] = {"sse2", NULL};
    static const char *const prefetch[] = {"0", "1"};
    size_t hits = 0;
    for (int kind = 0; kind < ARBOR_ACCEL_KIND_COUNT; kind++)
        for (size_t k = 0; k < sizeof kernels / sizeof kernels[0]; k++)
            for (size_t p = 0; p < (kind == ARBOR_ACCEL_BVH ? 2u : 1u); p++) {
                arbor_accel *a = build_with(m, (arbor_accel_kind)kind, kernels[k], prefetch[p]);
                hits += check_tree(a, (arbor_accel_kind)kind, rays, n, truth, found, what);
                arbor_accel_free(a);
            }
    TEST_ASSERT_TRUE_MESSAGE(hits > 0, "no ray hit: the comparison proved nothing");
    unsetenv("ARBOR_KERNEL");
    unsetenv("ARBOR_PREFETCH");
    free(truth);
    free(found);
}

static void check_mesh(const arbor_mesh *m, const char *what)
{
    arbor_ray *rays = test_random_rays(m, 20000, 7);
    check_rays(m, rays, 20000, what);
    free(rays);
    size_t n;
    rays = test_protocol_rays(m, 4, &n);
    check_rays(m, rays, n, what);
    free(rays);
}

static void test_kernel_names(void)
{
    TEST_ASSERT_EQUAL_INT(0, setenv("ARBOR_KERNEL", "sse2", 1));
    TEST_ASSERT_EQUAL_STRING("sse2", arbor_accel_kernel_name());
    TEST_ASSERT_EQUAL_INT(0, unsetenv("ARBOR_KERNEL"));
    __builtin_cpu_init();
    bool avx2 = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
    TEST_ASSERT_EQUAL_STRING(avx2 ? "avx2" : "sse2", arbor_accel_kernel_name());
}

static void test_bunny(void)
{
    arbor_mesh m;
    arbor_err e;
    TEST_ASSERT_TRUE_MESSAGE(arbor_load_model(test_shared_model("bunny.obj"), &m, &e), e.msg);
    check_mesh(&m, "bunny");
    arbor_mesh_free(&m);
}

static void test_soup(void)
{
    arbor_mesh m;
    test_random_soup(&m, 3000, 11);
    check_mesh(&m, "soup");
    arbor_mesh_free(&m);
}

/* Every triangle of a soup three times, the copies at the end of the mesh
 * in reverse order: every hit is a three-way tie at one t, which the
 * lowest index must win whatever leaf and lane each copy lands in. */
static void test_coincident_triangles(void)
{
    arbor_mesh soup;
    test_random_soup(&soup, 600, 5);
    arbor_mesh m;
    arbor_mesh_init(&m);
    arbor_err e;
    for (uint32_t copy = 0; copy < 3; copy++) {
        for (uint32_t v = 0; v < soup.nverts; v++)
            TEST_ASSERT_TRUE(arbor_mesh_add_vert(&m, soup.verts[v], &e));
        for (uint32_t i = 0; i < soup.ntris; i++) {
            const uint32_t *src = soup.tri_verts + 3 * (copy == 0 ? i : soup.ntris - 1 - i);
            uint32_t base = copy * soup.nverts;
            TEST_ASSERT_TRUE(arbor_mesh_add_tri(&m, src[0] + base, src[1] + base, src[2] + base, 0, &e));
        }
    }
    TEST_ASSERT_TRUE_MESSAGE(arbor_mesh_finish(&m, &e), e.msg);
    check_mesh(&m, "coincident soup");
    arbor_mesh_free(&m);
    arbor_mesh_free(&soup);
}

int main(void)
{
    UNITY_BEGIN();
    RUN_TEST(test_kernel_names);
    RUN_TEST(test_bunny);
    RUN_TEST(test_soup);
    RUN_TEST(test_coincident_triangles);
    return UNITY_END();
}
