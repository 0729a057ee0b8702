/*
 * accel_impl.h - what a tree kind provides to accel.c (private to src/accel).
 *
 * Each kind (bvh.c, kd.c) exports one arbor_accel_ops table. accel.c owns the
 * arbor_accel wrapper, times the build and dispatches through the table, so a
 * kind only builds, traverses and describes itself. `impl` is the kind's own
 * tree, created by build and released by destroy.
 */
#ifndef ARBOR_ACCEL_IMPL_H
#define ARBOR_ACCEL_IMPL_H

#include "arbor/accel.h"

typedef struct {
    /* Builds a tree over m with validated options; fills every field of
     * *stats except build_ms. NULL (and e filled) on failure. */
    void *(*build)(const arbor_mesh *m, const arbor_build_opts *o, arbor_tree_stats *stats, arbor_err *e);
    bool (*intersect)(const void *impl, arbor_ray *r, arbor_hit *h);
    bool (*intersect_counted)(const void *impl, arbor_ray *r, arbor_hit *h, arbor_trace_counts *c);
    bool (*occluded)(const void *impl, const arbor_ray *r);
    /* See arbor_accel_validate; stats are the ones build filled. */
    bool (*validate)(const void *impl, const arbor_mesh *m, const arbor_tree_stats *stats, arbor_err *e);
    void (*destroy)(void *impl);
} arbor_accel_ops;

extern const arbor_accel_ops arbor_bvh_ops;
extern const arbor_accel_ops arbor_kd_ops;

#endif
