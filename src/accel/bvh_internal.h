/*
 * bvh_internal.h - the bounding volume hierarchy's data layout, shared by its
 * builders (bvh_build.c), its traversal (bvh_traverse.c) and its ops table
 * and validator (bvh.c). Private to src/accel.
 *
 * Layout. The nodes form one flat array in depth-first order: the root is
 * node 0, an inner node's left child is the node right after it, and only
 * the right child's index is stored. Each node is 32 bytes (two per 64-byte
 * cache line): its box and two words,
 *
 *     inner node: index = right child, count = 0
 *     leaf:       index = first triangle in leaf order, count = triangles (> 0)
 *
 * A leaf's triangles are the range [index, index + count) of two arrays kept
 * in leaf order: tri_verts (their three vertices, copied from the mesh so a
 * leaf's triangles are contiguous in memory) and tri_index (their indices in
 * the mesh, which hits report).
 *
 * Invariants (bvh.c's validator checks them all): every mesh triangle is in
 * exactly one leaf; leaves cover [0, ntris) in depth-first order; a child's
 * box lies inside its parent's; a leaf's box contains its triangles; the
 * depth of every node is below BVH_MAX_DEPTH, so a traversal stack of
 * BVH_MAX_DEPTH entries cannot overflow. A mesh without triangles has no
 * nodes at all.
 */
#ifndef ARBOR_BVH_INTERNAL_H
#define ARBOR_BVH_INTERNAL_H

#include <stdint.h>

#include "accel_impl.h"

/* Depth bound of every tree: the traversal pushes at most one node per level. */
#define BVH_MAX_DEPTH 64

typedef struct {
    float bounds[6];  /* lo x, y, z, then hi x, y, z */
    uint32_t index;   /* inner: right child; leaf: first triangle in leaf order */
    uint32_t count;   /* inner: 0; leaf: number of triangles */
} bvh_node;

_Static_assert(sizeof(bvh_node) == 32, "a node is half a cache line");

typedef struct {
    bvh_node *nodes;       /* nnodes, depth-first */
    uint32_t nnodes;
    uint32_t ntris;
    arbor_vec3 *tri_verts; /* 3 * ntris vertices, in leaf order */
    uint32_t *tri_index;   /* ntris mesh triangle indices, in leaf order */
} bvh_tree;

/* bvh_build.c: builds the tree for o->builder and fills every statistic but
 * build_ms. NULL (e filled) when memory runs out. */
void *bvh_build(const arbor_mesh *m, const arbor_build_opts *o, arbor_tree_stats *stats, arbor_err *e);

/* bvh_traverse.c: the three queries of arbor_accel_ops. */
bool bvh_intersect(const void *impl, arbor_ray *r, arbor_hit *h);
bool bvh_intersect_counted(const void *impl, arbor_ray *r, arbor_hit *h, arbor_trace_counts *c);
bool bvh_occluded(const void *impl, const arbor_ray *r);

void bvh_tree_free(bvh_tree *t);

static inline arbor_aabb bvh_node_box(const bvh_node *n)
{
    arbor_aabb b = {vec3(n->bounds[0], n->bounds[1], n->bounds[2]), vec3(n->bounds[3], n->bounds[4], n->bounds[5])};
    return b;
}

/* A(box) / A(root) in the sah_cost formula. When the root's area is zero
 * (every triangle on one line or point) every box is taken as the root's,
 * ratio 1, so that the cost still counts nodes and triangle references. */
static inline double bvh_area_ratio(double area, double root_area)
{
    return root_area > 0.0 ? area / root_area : 1.0;
}

#endif
