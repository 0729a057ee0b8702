/*
 * bvh_builder.h - what the binary BVH builders share (bvh_build.c, the
 * recursion; bvh_split.c, partitions and the simple splits; bvh_sah.c, the
 * SAH's splits): the triangle references they partition, the boxes they
 * keep in SSE registers, the builder's settings, and the splits each file
 * offers the recursion. Private to src/accel.
 *
 * A split function reorders the references of a node, prims[b, e), so that
 * its left child's come first, and sets both children's boxes (range_box);
 * it returns where the right child's start (or, for the SAH's, whether to
 * split at all). Every split is a function of the references alone, so the
 * tree does not depend on the threads that build it.
 */
#ifndef ARBOR_BVH_BUILDER_H
#define ARBOR_BVH_BUILDER_H

#include <emmintrin.h>
#include <math.h>
#include <stdbool.h>
#include <stdint.h>

#include "accel_impl.h"
#include "bvh_internal.h"

/* Nodes of at most this many triangles take the exact SAH (bvh_sah.c). */
#define BVH_SAH_EXACT_TRIS 16

/* A triangle reference: the triangle's box, with its mesh index in the
 * fourth lane of lo, where a 4-wide load of lo finds it and box arithmetic
 * ignores it (see centroid2). */
typedef struct {
    float lo[3];
    uint32_t tri;
    float hi[3];
    float zero; /* 0 */
} bvh_prim;

_Static_assert(sizeof(bvh_prim) == 32, "a reference is half a cache line");

/* A box as the builder keeps it, one SSE register per corner; the fourth
 * lane means nothing. */
typedef struct {
    __m128 lo, hi;
} build_box;

/* What a node's parent tells it about its range of references: the box of
 * their triangles and the box of their doubled centroids. */
typedef struct {
    build_box box, cbox;
} range_box;

typedef struct {
    arbor_builder builder;
    uint32_t max_leaf;       /* a node with more triangles is always split */
    uint32_t max_depth;      /* a node at this depth is always a leaf */
    uint32_t fork_depth;     /* nodes above this depth may fork */
    float cost_traverse, cost_intersect;
    bvh_prim *prims;         /* the triangle references; each task owns a range */
    uint32_t *tri_index;     /* leaf order, written by the leaves */
    bvh_node *nodes;         /* each task owns a range of slots */
    accel_run *run;          /* threads and cancel flag */
} bvh_builder;

static inline build_box box_empty(void)
{
    build_box b = {_mm_set1_ps(INFINITY), _mm_set1_ps(-INFINITY)};
    return b;
}

/* The box in the first operand, so that a NaN corner spreads (minps returns
 * its second operand when either is NaN), as arbor_minf does. */
static inline void box_grow(build_box *b, __m128 lo, __m128 hi)
{
    b->lo = _mm_min_ps(b->lo, lo);
    b->hi = _mm_max_ps(b->hi, hi);
}

static inline void box_merge(build_box *b, const build_box *with)
{
    box_grow(b, with->lo, with->hi);
}

/* Surface area of a non-empty box, 2 ((x y + y z) + z x) as aabb_area
 * computes it, in registers: the SAH sweeps call this for every bin. */
static inline float box_area(const build_box *b)
{
    __m128 d = _mm_sub_ps(b->hi, b->lo);
    __m128 p = _mm_mul_ps(d, _mm_shuffle_ps(d, d, _MM_SHUFFLE(3, 0, 2, 1))); /* x y, y z, z x */
    __m128 sum = _mm_add_ss(_mm_add_ss(p, _mm_shuffle_ps(p, p, _MM_SHUFFLE(1, 1, 1, 1))),
                            _mm_shuffle_ps(p, p, _MM_SHUFFLE(2, 2, 2, 2)));
    return 2.0f * _mm_cvtss_f32(sum);
}

static inline __m128 prim_lo(const bvh_prim *p)
{
    return _mm_loadu_ps(p->lo);
}

static inline __m128 prim_hi(const bvh_prim *p)
{
    return _mm_loadu_ps(p->hi);
}

/* lo + hi: twice the centroid, with 0 in the fourth lane (lo's lane holds
 * the triangle index's bits, which as a float may be a denormal or NaN). */
static inline __m128 centroid2(__m128 lo, __m128 hi)
{
    const __m128 xyz = _mm_castsi128_ps(_mm_setr_epi32(-1, -1, -1, 0));
    return _mm_add_ps(_mm_and_ps(lo, xyz), hi);
}

static inline float centroid_axis(const bvh_builder *B, uint32_t i, int axis)
{
    return B->prims[i].lo[axis] + B->prims[i].hi[axis];
}

static inline void prim_swap(bvh_prim *p, uint32_t i, uint32_t j)
{
    bvh_prim t = p[i];
    p[i] = p[j];
    p[j] = t;
}

/* The bins of a node: nbins bins per axis over its centroid box, bin
 * (c - lo) * scale clamped to [0, nbins - 1]. */
typedef struct {
    __m128 lo, scale, last;
    uint32_t nbins;
} bin_grid;

/* The bins of centroid c on the three axes (lane 3 meaningless), without
 * branches; maxps returns 0 for a NaN, which lands in bin 0. The binning and
 * the partition both use this, so they agree on every triangle's side. */
static inline __m128i bin_of(const bin_grid *g, __m128 c)
{
    __m128 f = _mm_mul_ps(_mm_sub_ps(c, g->lo), g->scale);
    return _mm_cvttps_epi32(_mm_min_ps(_mm_max_ps(f, _mm_setzero_ps()), g->last));
}

/* A split to partition by: a side per triangle, either by the bin of its
 * centroid on axis (left: bins below limit_bin, which is the costed plane
 * + 1) or by its position (left: below limit_pos), both in every lane. */
typedef struct {
    int axis;
    bool by_bin;
    const bin_grid *grid;
    __m128i limit_bin;
    __m128 limit_pos;
} split_rule;

/* The boxes of prims[b, e). */
void bvh_range_bounds(const bvh_builder *B, uint32_t b, uint32_t e, range_box *r);
/* Splits prims[b, e) at m as they lie and measures both halves. */
uint32_t bvh_split_at(const bvh_builder *B, uint32_t b, uint32_t m, uint32_t e, range_box kids[2]);
/* The object median split on axis: both halves non-empty for e - b >= 2. */
uint32_t bvh_split_median(const bvh_builder *B, uint32_t b, uint32_t e, int axis, range_box kids[2]);
/* The mean of the (doubled) centroids of prims[b, e) on axis. */
float bvh_centroid_mean(const bvh_builder *B, uint32_t b, uint32_t e, int axis);
/* Partitions prims[b, e) by rule, the left side first, measuring both
 * sides' boxes; returns where the right side starts (b or e when one side
 * is empty: kids are then meaningless). bvh_partition_centroids measures
 * only the centroid boxes, leaving kids' boxes empty for the caller. */
uint32_t bvh_partition(const bvh_builder *B, uint32_t b, uint32_t e, const split_rule *rule, range_box kids[2]);
uint32_t bvh_partition_centroids(const bvh_builder *B, uint32_t b, uint32_t e, const split_rule *rule,
                                 range_box kids[2]);

/* The SAH's splits (bvh_sah.c): binned for large nodes, exact for nodes of
 * at most BVH_SAH_EXACT_TRIS, decided directly for two triangles. */
bool bvh_sah_split(const bvh_builder *B, uint32_t b, uint32_t e, uint32_t depth, float area, const build_box *cbox,
                   range_box kids[2], uint32_t *m);
bool bvh_sah_split_small(const bvh_builder *B, uint32_t b, uint32_t e, float area, int only_axis, range_box kids[2],
                         uint32_t *m);
uint32_t bvh_sah_split_pair(const bvh_builder *B, uint32_t b, float area, const build_box *cbox, range_box kids[2]);
/* Whether a node of at most one pack, which the SAH would split into kids,
 * stays a leaf for the wide tree's sake (bvh_sah.c). */
bool bvh_sah_pack_stays_leaf(const bvh_builder *B, float area, uint32_t n, const range_box kids[2]);

#endif
