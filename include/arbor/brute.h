/*
 * brute.h - the brute-force intersector: every ray against every triangle.
 *
 * It is the ground truth that every tree is tested against, so it is kept as
 * plain as possible and shares nothing with the trees but the watertight
 * triangle test. It is O(triangles) per ray: for tests, not for rendering.
 */
#ifndef ARBOR_BRUTE_H
#define ARBOR_BRUTE_H

#include <stdbool.h>
#include <stddef.h>

#include "arbor/mesh.h"
#include "arbor/pool.h"
#include "arbor/ray.h"

/* Closest hit in (r->tmin, r->tmax); on a hit shrinks r->tmax and fills h.
 * Among hits at exactly the same t the lowest triangle index wins. */
bool arbor_brute_intersect(const arbor_mesh *m, arbor_ray *r, arbor_hit *h);

/* Any hit in (r->tmin, r->tmax). */
bool arbor_brute_occluded(const arbor_mesh *m, const arbor_ray *r);

/* Closest hits for n rays on the calling thread and up to threads - 1
 * workers of `pool` (threads 0 = as many as the pool has), or, without a
 * pool, of a pool started for the call (threads 0 = one per core): hit[i]
 * gets ray i's hit and found[i] whether there was one; rays are not
 * modified. */
void arbor_brute_intersect_many(arbor_pool *pool, const arbor_mesh *m, const arbor_ray *rays, size_t n,
                                arbor_hit *hit, bool *found, int threads);

#endif
