/*
 * bvh_internal.h - the bounding volume hierarchy's data layout, shared by its
 * builders (bvh_build.c, with bvh_builder.h), its traversal
 * (bvh_traverse.c) and its ops table and validator (bvh.c). Private to
 * src/accel.
 *
 * The tree is kept twice, in two layouts with different jobs.
 *
 * The binary tree (bvh_node) is what the builders make and what the
 * statistics and the validator describe: the study's measures are of this
 * tree. Its nodes form one flat array in depth-first order: the root is
 * node 0, an inner node's left child is the node right after it, and only
 * the right child's index is stored. Each node is 32 bytes: its box and two
 * words,
 *
 *     inner node: index = right child, count = 0
 *     leaf:       index = first triangle in leaf order, count = triangles (> 0)
 *
 * A leaf's triangles are the range [index, index + count) of tri_index, the
 * mesh indices of the triangles in leaf order.
 *
 * The wide tree (bvh_wide.c) is what rays traverse: the binary tree
 * collapsed into nodes of up to BVH_WIDTH children whose boxes one SIMD slab
 * test checks at once, with leaf triangles in packs of BVH_WIDTH that one
 * SIMD triangle test checks at once. A wide node is 32 BVH_WIDTH bytes
 * (BVH_WIDTH / 2 cache lines): its children's boxes as six rows of
 * BVH_WIDTH lanes, a 32-bit reference per child,
 *
 *     inner child: the wide node's index (never 0, the root)
 *     leaf child:  BVH_REF_LEAF | first pack
 *     empty slot:  BVH_REF_EMPTY, with an empty box (lo +inf, hi -inf)
 *
 * and 32 bytes unused, which keep a node whole cache lines. (A visiting
 * order per ray octant there measured slower than sorting the children
 * entered by distance: docs/BENCH.md.)
 *
 * No ray with a finite origin and direction enters an empty box. One with
 * NaN or infinite components may: its slab distances can be NaN on every
 * axis, which the slab test ignores, so it enters every box. Such a ray
 * hits nothing, and then tests the first leaf in vain (BVH_REF_EMPTY is a
 * leaf reference to pack 0) rather than go back to the root forever.
 *
 * A pack is BVH_WIDTH triangles' vertices and their mesh indices, 5 cache
 * lines. A leaf's triangles fill its packs in order; the last pack's unused
 * lanes hold NaN vertices (no ray hits them) and the index BVH_LANE_UNUSED,
 * and lane 0's index carries BVH_PACK_LAST in the leaf's last pack (lane 0
 * is never unused, and mesh.c stops a mesh at 2^31 triangles, so indices
 * leave that bit free). Wide node 0 is the root; wide nodes and packs are
 * in depth-first order.
 *
 * Invariants (bvh.c's validator checks them all): every mesh triangle is in
 * exactly one leaf of each layout; binary leaves cover [0, ntris) in
 * depth-first order; a child's box lies inside its parent's; a leaf's box
 * contains its triangles; the depth of every node is below BVH_MAX_DEPTH,
 * so a traversal stack of BVH_MAX_DEPTH entries per pushed sibling cannot
 * overflow. A mesh without triangles has no nodes at all.
 */
#ifndef ARBOR_BVH_INTERNAL_H
#define ARBOR_BVH_INTERNAL_H

#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "accel_impl.h"

/* Depth bound of every tree: the traversal pushes at most one node per level. */
#define BVH_MAX_DEPTH 64

typedef struct {
    float bounds[6];  /* lo x, y, z, then hi x, y, z */
    uint32_t index;   /* inner: right child; leaf: first triangle in leaf order */
    uint32_t count;   /* inner: 0; leaf: number of triangles */
} bvh_node;

_Static_assert(sizeof(bvh_node) == 32, "a node is half a cache line");

#define BVH_WIDTH 8
#define BVH_REF_LEAF ((uint32_t)1 << 31)
#define BVH_REF_EMPTY BVH_REF_LEAF
#define BVH_PACK_LAST ((uint32_t)1 << 31)
#define BVH_LANE_UNUSED UINT32_MAX

typedef struct {
    float box[6][BVH_WIDTH];      /* rows lo x, y, z, hi x, y, z; lane c is child c */
    uint32_t child[BVH_WIDTH];    /* references, as above */
    uint32_t unused[BVH_WIDTH];
} bvh_wide_node;

_Static_assert(sizeof(bvh_wide_node) == 32 * BVH_WIDTH, "a wide node is whole cache lines");

typedef struct {
    float v[3][3][BVH_WIDTH];     /* vertex a, b, c; axis x, y, z; lane = triangle */
    uint32_t tri[BVH_WIDTH];      /* mesh triangle per lane; see above */
} bvh_tri_pack;

_Static_assert(sizeof(bvh_tri_pack) % 64 == 0, "a pack is whole cache lines");

typedef struct {
    bvh_node *nodes;          /* nnodes, depth-first; NULL once dropped */
    uint32_t nnodes;          /* 0 once dropped */
    bool binary_dropped;      /* opts.drop_binary: nodes and tri_index freed after the collapse */
    uint32_t ntris;
    uint32_t *tri_index;      /* ntris mesh triangle indices, in leaf order */
    bvh_wide_node *wide;      /* nwide, depth-first, 64-byte aligned */
    uint32_t nwide;
    uint32_t npacks;
    bvh_tri_pack *packs;      /* npacks, 64-byte aligned */
    bool prefetch;            /* rays prefetch the children they enter (bvh_prefetch_pick) */
} bvh_tree;

/* Wide trees of at least this many bytes (nodes and packs) have their rays
 * prefetch the children they enter (bvh_traverse.c; bvh.c's
 * bvh_prefetch_pick decides at the build). The prefetch pays where a ray's
 * next node would come from memory, and costs its dozen instructions per
 * child entered where that node is in a cache anyway. Tracing one tree
 * with and without it in alternating passes (1 thread, the AVX2-only AMD
 * EPYC VM of docs/BENCH.md): dragon (59 MB) 10-13% faster primary and
 * diffuse rays with it, 3-7% faster shadow rays; sponza (4.4 MB) 4-8%
 * slower on every set, bunny (4.5 MB) within 2%; castle and galleon (under
 * 1 MB) primary rays 5-7% slower. So the line is about a core's share of a
 * last-level cache, and a constant: glibc's sysconf reports that VM's L3
 * as the socket's 256 MB, not the 32 MB its cores share. */
#define BVH_PREFETCH_MIN_BYTES (16u << 20)

/* The bytes of the layout rays traverse: wide nodes and packs. */
static inline uint64_t bvh_wide_bytes(const bvh_tree *t)
{
    return (uint64_t)t->nwide * sizeof(bvh_wide_node) + (uint64_t)t->npacks * sizeof(bvh_tri_pack);
}
static inline bool bvh_ref_is_leaf(uint32_t ref) { return (ref & BVH_REF_LEAF) != 0; }
static inline uint32_t bvh_ref_index(uint32_t ref) { return ref & ~BVH_REF_LEAF; }
/* The packs a leaf of that many triangles fills. */
static inline uint32_t bvh_packs_for(uint32_t tris) { return (tris + BVH_WIDTH - 1) / BVH_WIDTH; }
/* Lane l's mesh triangle, or BVH_LANE_UNUSED. */
static inline uint32_t bvh_lane_tri(const bvh_tri_pack *p, int l)
{
    return p->tri[l] == BVH_LANE_UNUSED ? BVH_LANE_UNUSED : p->tri[l] & ~BVH_PACK_LAST;
}
static inline bool bvh_pack_is_last(const bvh_tri_pack *p) { return (p->tri[0] & BVH_PACK_LAST) != 0; }
/* The triangles of the leaf whose first pack is p0. */
static inline uint32_t bvh_leaf_tris(const bvh_tree *t, uint32_t p0)
{
    uint32_t tris = 0;
    for (uint32_t p = p0;; p++) {
        for (int l = 0; l < BVH_WIDTH; l++)
            tris += t->packs[p].tri[l] != BVH_LANE_UNUSED;
        if (bvh_pack_is_last(&t->packs[p]))
            return tris;
    }
}

/* Linear passes over all triangles of a mesh this large (making the
 * references, copying the packs' vertices) split into two parallel halves
 * when the build has threads. */
#define BVH_PARALLEL_PASS_TRIS 65536

/* bvh_build.c: builds t's binary tree (nodes, nnodes, ntris, tri_index)
 * for o->builder on run's threads and fills its statistics but build_ms
 * and bytes. False when memory runs out or the build is cancelled (e
 * filled; see accel_impl.h); t's arrays are then the caller's to free.
 * bvh.c builds a tree by this, then bvh_wide_build. */
bool bvh_build_binary(bvh_tree *t, const arbor_mesh *m, const arbor_build_opts *o, accel_run *run,
                      arbor_tree_stats *stats, arbor_err *e);

/* bvh_traverse.c, one copy per traversal kernel (accel_impl.h). */
extern const accel_queries bvh_queries_sse2, bvh_queries_avx2;
void bvh_walk(const void *impl, uint32_t max_depth, arbor_node_fn fn, void *user);

/* Arrays of nodes and packs are 64-byte aligned, so that no node straddles
 * more cache lines than it must. Both builds allocate them for the worst
 * case, write them once, then shrink them to the part used, keeping the
 * alignment: p itself when realloc cannot shrink it, NULL (p freed) only
 * when an aligned copy was needed and memory ran out. Inline here, so that
 * the builds and bvh.c, which frees the arrays, share them without calling
 * each other. */
static inline void *bvh_alloc_aligned(size_t bytes)
{
    return aligned_alloc(64, bytes > 0 ? (bytes + 63) & ~(size_t)63 : 64);
}

static inline void *bvh_shrink_aligned(void *p, size_t used)
{
    size_t bytes = used > 0 ? (used + 63) & ~(size_t)63 : 64;
    void *shrunk = realloc(p, bytes);
    if (shrunk == NULL || ((uintptr_t)shrunk & 63) == 0)
        return shrunk != NULL ? shrunk : p;
    void *out = aligned_alloc(64, bytes); /* realloc moved it to a less aligned place */
    if (out != NULL)
        memcpy(out, shrunk, used);
    free(shrunk);
    return out;
}

/* bvh_wide.c: builds t's wide tree from its binary tree, its linear pass in
 * two parallel halves when parallel (false, e filled, when memory runs
 * out), and checks it against the mesh. */
bool bvh_wide_build(bvh_tree *t, const arbor_mesh *m, accel_run *run, bool parallel, arbor_err *e);
bool bvh_wide_validate(const bvh_tree *t, const arbor_mesh *m, arbor_err *e);
/* bvh_wide_stats.c: the wide tree's statistics (nodes, leaves, depths,
 * bytes, sah_cost under its own cost model). */
void bvh_wide_stats(const bvh_tree *t, arbor_layout_stats *s);

/* Whether slot c of wide node n is empty (no child). BVH_REF_EMPTY is
 * also the first leaf's reference; only an empty slot has lo +inf. */
static inline bool bvh_slot_is_empty(const bvh_wide_node *n, int c)
{
    return n->child[c] == BVH_REF_EMPTY && n->box[0][c] == INFINITY;
}

/* Child c's box in wide node n. */
static inline arbor_aabb bvh_lane_box(const bvh_wide_node *n, int c)
{
    arbor_aabb b = {vec3(n->box[0][c], n->box[1][c], n->box[2][c]), vec3(n->box[3][c], n->box[4][c], n->box[5][c])};
    return b;
}

/* Wide node n's box: the union of its children's (the root's has no lane
 * of its own to be read from). */
static inline arbor_aabb bvh_wide_box(const bvh_wide_node *n)
{
    arbor_aabb b = {vec3(INFINITY, INFINITY, INFINITY), vec3(-INFINITY, -INFINITY, -INFINITY)};
    for (int c = 0; c < BVH_WIDTH; c++)
        if (!bvh_slot_is_empty(n, c)) {
            arbor_aabb l = bvh_lane_box(n, c);
            b.lo = vec3_min(b.lo, l.lo);
            b.hi = vec3_max(b.hi, l.hi);
        }
    return b;
}

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
