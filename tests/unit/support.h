/*
 * support.h - helpers shared by the unit tests: where the real models are,
 * a fixed-seed random generator, random rays and triangle soups, rays aimed
 * through a mesh's vertices and edges, the PROTOCOL.md primary rays, and
 * brute force's answers for a ray set.
 */
#ifndef ARBOR_TEST_SUPPORT_H
#define ARBOR_TEST_SUPPORT_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "arbor/mesh.h"
#include "arbor/ray.h"

/* Path of a model in ../shared/models (ARBOR_SHARED_MODELS overrides);
 * returns a static buffer, valid until the next call. */
const char *test_shared_model(const char *file);

/* Path of a model in the repository's models/ folder (static buffer). */
const char *test_repo_model(const char *file);

/* PCG32: a small fixed-seed generator so every run sees the same numbers. */
typedef struct { uint64_t state, inc; } test_rng;
void test_rng_seed(test_rng *g, uint64_t seed);
uint32_t test_rng_u32(test_rng *g);
float test_rng_float(test_rng *g); /* [0, 1) */

/* n rays with origins uniform in the mesh's bounds grown by half its
 * diagonal, and uniform directions; t in (0, inf). Caller frees. */
arbor_ray *test_random_rays(const arbor_mesh *m, size_t n, uint64_t seed);

/* A soup of n random triangles of varied size in the unit cube. */
void test_random_soup(arbor_mesh *m, uint32_t n, uint64_t seed);

/* PROTOCOL.md's primary rays for the mesh, every `stride`-th pixel in x and
 * y (stride 1 = all 1024 x 768); *n gets the count. Caller frees. */
arbor_ray *test_protocol_rays(const arbor_mesh *m, int stride, size_t *n);

/* Every vertex of m and the midpoint of every edge; in a closed mesh wound
 * consistently, each edge once (taken where it runs from the lower to the
 * higher vertex index, which is in exactly one of its two triangles), so
 * *n = nverts + 3 ntris / 2. Caller frees. */
arbor_vec3 *test_vertices_and_edge_midpoints(const arbor_mesh *m, size_t *n);

/* A ray from each origin exactly through each target (direction target - o,
 * passing it at t = 1), origins major; t in (0, inf). Caller frees. */
arbor_ray *test_aimed_rays(const arbor_vec3 *origins, size_t norigins, const arbor_vec3 *targets, size_t ntargets);

/* |a - b| <= rel * max(|a|, |b|) */
int test_close(float a, float b, float rel);

/* A ray set and brute force's closest hit of each ray, the independent
 * truth the trees are held to (for an occlusion set, found[i] is whether
 * ray i is occluded: a closest hit in (tmin, tmax) exists exactly when some
 * hit does). */
typedef struct {
    arbor_ray *rays;
    size_t n;
    arbor_hit *hit;
    bool *found;
} test_truth;

/* Brute force over rays[0, n) on all cores; takes ownership of rays. */
void test_truth_compute(test_truth *ts, const arbor_mesh *m, arbor_ray *rays, size_t n);
/* How many rays hit. */
size_t test_truth_hits(const test_truth *ts);
void test_truth_free(test_truth *ts);

#endif
