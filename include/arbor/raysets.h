/*
 * raysets.h - PROTOCOL.md's ray sets (primary, diffuse, shadow) and the one
 * timed loop every tracer (ours, a peer's) is measured with.
 *
 * arbor_raysets_primary makes the primary set from the mesh alone;
 * arbor_raysets_secondary makes the diffuse and shadow sets from the primary
 * rays' hits in a reference trace, so every tracer is timed on the same
 * rays. The sets own their arrays; arbor_raysets_free releases them.
 *
 * A tracer is measured through an arbor_trace_kernel: a tight loop over a
 * slice of a set, called once per chunk of ARBOR_TRACE_CHUNK rays (never per
 * ray). arbor_trace_set runs a set on the calling thread and up to
 * threads - 1 workers of `pool`, each claiming the next chunk not yet
 * traced. Without a pool (NULL) it starts a pool of threads - 1 workers for
 * the call, so a benchmark measuring N threads gets N threads of its own.
 * arbor_time_set repeats whole passes until min_ms have passed, on one such
 * pool for all of them.
 */
#ifndef ARBOR_RAYSETS_H
#define ARBOR_RAYSETS_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "arbor/accel.h"
#include "arbor/err.h"
#include "arbor/mesh.h"
#include "arbor/pool.h"
#include "arbor/ray.h"

#define ARBOR_PROTOCOL_WIDTH 1024
#define ARBOR_PROTOCOL_HEIGHT 768
#define ARBOR_TRACE_CHUNK 1024

typedef struct {
    arbor_ray *primary, *diffuse, *shadow;
    size_t nprimary, ndiffuse, nshadow;
    arbor_vec3 light;  /* e + 0.5 d u */
    float size;        /* d, the model's diagonal */
} arbor_raysets;

/* The primary set (1024 x 768 rays, row by row from the top-left). Other
 * fields zeroed; light and size set. False when out of memory. */
bool arbor_raysets_primary(const arbor_mesh *m, arbor_raysets *s, arbor_err *e);

/* Diffuse and shadow sets from the primary hits: hits[i], found[i] are
 * primary ray i's closest hit. Directions of diffuse rays come from a
 * generator seeded with (seed, i). */
bool arbor_raysets_secondary(const arbor_mesh *m, arbor_raysets *s, const arbor_hit *hits, const bool *found,
                             uint64_t seed, arbor_err *e);

void arbor_raysets_free(arbor_raysets *s);

/* Hits of a pass: for closest-hit sets the hit count and the sum of hit
 * distances; for occlusion sets the occluded count (tsum 0). */
typedef struct {
    uint64_t hits;
    double tsum;
} arbor_tally;

/* Traces rays[0..n) as closest-hit (any_hit false) or occlusion queries,
 * adding to *t. Called from several threads at once on disjoint slices. */
typedef void (*arbor_trace_kernel)(const void *tracer, const arbor_ray *rays, size_t n, bool any_hit,
                                   arbor_tally *t);

/* Our tracer's kernel; `tracer` is an arbor_accel. */
void arbor_accel_kernel(const void *tracer, const arbor_ray *rays, size_t n, bool any_hit, arbor_tally *t);

/* One pass over the set on at most `threads` threads, the caller included
 * (0 = as many as the pool has; one per core without a pool). The tally is
 * summed chunk by chunk in order, so it does not depend on threads. False
 * when out of memory or when the threads of its own cannot be started. */
bool arbor_trace_set(arbor_pool *pool, arbor_trace_kernel kernel, const void *tracer, const arbor_ray *rays, size_t n,
                     bool any_hit, int threads, arbor_tally *tally, arbor_err *e);

typedef struct {
    double mrays_per_s;  /* rays of all passes / wall time of all passes */
    int passes;
    double ms;           /* wall time of all passes */
    arbor_tally tally;   /* of one pass */
} arbor_set_timing;

/* Whole passes until at least min_ms have passed. */
bool arbor_time_set(arbor_pool *pool, arbor_trace_kernel kernel, const void *tracer, const arbor_ray *rays, size_t n,
                    bool any_hit, int threads, double min_ms, arbor_set_timing *out, arbor_err *e);

/* Closest hits of every ray with our tracer, on threads as arbor_trace_set:
 * hits[i] and found[i] for ray i (the reference trace for
 * arbor_raysets_secondary). */
bool arbor_accel_trace_hits(arbor_pool *pool, const arbor_accel *a, const arbor_ray *rays, size_t n, int threads,
                            arbor_hit *hits, bool *found, arbor_err *e);

#endif
