/*
 * kd_internal.h - the k-d tree's private types (private to src/accel/kd*.c).
 *
 *   kd.c           the arbor_kd_ops table: what accel.c calls
 *   kd_build.c     the recursion every builder shares (events, perfect
 *                  splits, node output, parallel parts, cancelling) and the
 *                  spatial / median / mean planes
 *   kd_sah.c       the SAH plane of Wald and Havran (2006) by event sweep
 *   kd_traverse.c  closest-hit and any-hit ray queries
 *   kd_validate.c  the invariant checker behind arbor_accel_validate
 *
 * THE TREE. nodes[] holds 8-byte nodes in depth-first order, as pbrt's
 * KdAccelNode: an inner node's below child (coordinates < split) is the next
 * node and its above child is at the index stored in the node. A leaf with
 * one triangle stores that triangle's index; a leaf with more stores the
 * offset of its list in tri_index[]. Triangle indices are always the mesh's.
 * A leaf's cell is not stored: it follows from the root box and the planes.
 *
 * Invariants (kd_validate.c checks them):
 *   - every split lies strictly inside its node's cell, so both children
 *     have cells of positive extent along the split axis;
 *   - a triangle is listed in every leaf whose cell it enters and in no leaf
 *     it does not touch (up to rounding at the cells' faces; the builder
 *     rounds outwards, so at worst a triangle is listed once too often);
 *   - no leaf is deeper than max_depth (<= KD_MAX_DEPTH).
 */
#ifndef ARBOR_KD_INTERNAL_H
#define ARBOR_KD_INTERNAL_H

#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "accel_impl.h"

/* The deepest tree accel.c's option check lets through; also the size of
 * the traversal stack, which holds at most one entry per level. */
#define KD_MAX_DEPTH 64

/* The low two bits of kd_node.flags: 0, 1, 2 = the split axis, 3 = leaf. */
#define KD_LEAF 3u

/* Child indices and leaf sizes have the upper 30 bits of flags. */
#define KD_MAX_NODES (1u << 30)

typedef struct {
    union {
        float split;     /* inner: the plane's coordinate on its axis */
        uint32_t tri;    /* leaf of one triangle: its index */
        uint32_t first;  /* leaf of several: where its list starts in tri_index */
    };
    uint32_t flags;      /* axis or KD_LEAF | above-child index or triangle count << 2 */
} kd_node;

_Static_assert(sizeof(kd_node) == 8, "kd nodes are 8 bytes");

static inline uint32_t kd_node_kind(kd_node n) { return n.flags & 3u; }
static inline uint32_t kd_node_high(kd_node n) { return n.flags >> 2; }

/* A leaf's triangles: its own one, or its run of tri_index. An empty leaf
 * has none, and no address: a tree whose leaves all hold at most one
 * triangle has no tri_index at all (NULL, and NULL + 0 is undefined). */
static inline const uint32_t *kd_leaf_tris(const kd_node *n, const uint32_t *tri_index)
{
    uint32_t count = kd_node_high(*n);
    return count == 1 ? &n->tri : count == 0 ? NULL : tri_index + n->first;
}

typedef struct {
    const arbor_mesh *mesh;
    kd_node *nodes;
    uint32_t *tri_index;
    size_t nnodes, nindex;
    arbor_aabb bounds;   /* the root's cell: the box of all triangles */
    uint32_t max_depth;  /* the limit the build obeyed */
} kd_tree;

/* ---- building (kd_build.c, kd_sah.c) ---------------------------------- */

/* Events of Wald and Havran: where a triangle's box (clipped to the node's
 * cell) starts and ends along an axis, or lies when it is flat there. At one
 * position ends sort before planars before starts, which is the order the
 * sweep needs. */
typedef enum { KD_EVENT_END = 0, KD_EVENT_PLANAR = 1, KD_EVENT_START = 2 } kd_event_type;

/* The largest triangle count events can name (28 bits). */
#define KD_MAX_TRIS (1u << 28)

/* An event packed in 64 bits so that integer order is the order the
 * algorithm needs, (axis, position, type), then triangle:
 *     axis:2 | position:32 | type:2 | triangle:28
 * The position is the float's bits mapped to an unsigned integer of the
 * same order (kd_float_order), so that sorting, merging and comparing with
 * a plane are integer operations. */
typedef uint64_t kd_event;

static inline uint32_t kd_float_order(float x)
{
    uint32_t u;
    x += 0.0f;  /* -0 becomes +0: equal positions get equal bits */
    memcpy(&u, &x, sizeof u);
    return u ^ ((u >> 31) ? 0xffffffffu : 0x80000000u);
}

static inline float kd_order_float(uint32_t u)
{
    u ^= (u >> 31) ? 0x80000000u : 0xffffffffu;
    float x;
    memcpy(&x, &u, sizeof x);
    return x;
}

static inline kd_event kd_event_make(float pos, uint32_t tri, int axis, kd_event_type type)
{
    return (uint64_t)axis << 62 | (uint64_t)kd_float_order(pos) << 30 | (uint64_t)type << 28 | tri;
}

static inline uint32_t kd_event_tri(kd_event e) { return (uint32_t)e & (KD_MAX_TRIS - 1u); }
static inline kd_event_type kd_event_kind(kd_event e) { return (kd_event_type)((e >> 28) & 3u); }
static inline int kd_event_axis(kd_event e) { return (int)(e >> 62); }
static inline uint32_t kd_event_order(kd_event e) { return (uint32_t)(e >> 30); }
static inline float kd_event_pos(kd_event e) { return kd_order_float(kd_event_order(e)); }

/* One node to build. Its events are sorted by (axis, position, type), so
 * axis k's events are the block events[axis_begin[k] .. axis_begin[k + 1]).
 * Every triangle in the node has exactly one start or planar event on each
 * axis, so ntris is the count of those on any one axis. */
typedef struct {
    kd_event *events;  /* owned; freed once the node is split or made a leaf */
    size_t axis_begin[4];
    uint32_t ntris;
    uint32_t depth;
    uint32_t threads;  /* how many threads the subtree may build on at once */
    arbor_aabb cell;
} kd_task;

/* A split: the plane, and the side that triangles lying in it go to. */
typedef struct {
    int axis;
    float pos;
    bool planar_below;
} kd_plane;

/* The resolved build options, shared read-only by every build thread. */
typedef struct {
    const arbor_mesh *mesh;
    accel_run *run;        /* threads and cancel flag (not read-only: accel_stop records a cancel) */
    arbor_builder builder;
    uint32_t max_depth;
    uint32_t max_leaf_tris;
    float cost_traverse;   /* KT */
    float cost_intersect;  /* KI */
    float empty_factor;    /* lambda: a split's cost is multiplied by it when one side is empty */
    float clip_slack;      /* outward rounding of computed clip coordinates (see kd_build.c) */
} kd_builder;

/* The SAH plane for t (kd_sah.c): false when no plane is cheaper than a
 * leaf, i.e. when t should be a leaf. */
bool kd_sah_plane(const kd_builder *b, const kd_task *t, kd_plane *plane);

/* The entry points behind arbor_kd_ops (kd.c); see accel_impl.h. */
void *kd_build(const arbor_mesh *m, const arbor_build_opts *o, accel_run *run, arbor_tree_stats *stats, arbor_err *e);
void kd_destroy(void *impl);
bool kd_intersect(const void *impl, arbor_ray *r, arbor_hit *h);
bool kd_intersect_counted(const void *impl, arbor_ray *r, arbor_hit *h, arbor_trace_counts *c);
bool kd_occluded(const void *impl, const arbor_ray *r);
bool kd_intersect_traced(const void *impl, arbor_ray *r, arbor_hit *h, arbor_trace_counts *c, arbor_node_fn visit,
                         void *user);
void kd_walk_nodes(const void *impl, uint32_t max_depth, arbor_node_fn fn, void *user);
bool kd_validate(const void *impl, const arbor_mesh *m, const arbor_tree_stats *stats, arbor_err *e);

/* Cell box accessors: component k of a box's lo / hi corner. */
static inline float kd_lo(const arbor_aabb *b, int k) { return k == 0 ? b->lo.x : k == 1 ? b->lo.y : b->lo.z; }
static inline float kd_hi(const arbor_aabb *b, int k) { return k == 0 ? b->hi.x : k == 1 ? b->hi.y : b->hi.z; }

#endif
