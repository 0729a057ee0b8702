/*
 * support.h - helpers shared by the unit tests: where the real models are,
 * a fixed-seed random generator, random rays and triangle soups, and the
 * PROTOCOL.md primary rays.
 */
#ifndef ARBOR_TEST_SUPPORT_H
#define ARBOR_TEST_SUPPORT_H

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

/* |a - b| <= rel * max(|a|, |b|) */
int test_close(float a, float b, float rel);

#endif
