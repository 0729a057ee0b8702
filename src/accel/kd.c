/*
 * kd.c - the k-d tree as accel.c sees it: the arbor_kd_ops table. The tree
 * and its invariants are described in kd_internal.h; building is in
 * kd_build.c and kd_sah.c, ray queries in kd_traverse.c, checking in
 * kd_validate.c.
 */
#include "kd_internal.h"

/* kd_traverse.c is compiled once, for every kernel. */
static const accel_queries kd_queries = {kd_intersect, kd_intersect_counted, kd_occluded, kd_occluded_counted,
                                         kd_intersect_traced};

const arbor_accel_ops arbor_kd_ops = {
    kd_build, {&kd_queries, &kd_queries}, kd_walk_nodes, kd_validate, kd_destroy,
};
