/*
 * kd_internal.h - the k-d tree's private types (private to src/accel/kd*.c).
 *
 *   kd.c           the arbor_kd_ops table: what accel.c calls
 *   kd_build.c     the recursion every builder shares: options, the root,
 *                  parallel children, cancelling, the finished tree
 *   kd_events.c    event lists: the radix sort, runs of new events
 *   kd_clip.c      perfect splits: a straddling triangle clipped to a cell
 *   kd_split.c     a node's events classified by a plane and dealt out to
 *                  its children, with the clipped triangles' events spliced in
 *   kd_simple.c    the planes of the spatial, median and mean builders
 *   kd_sah.c       the SAH plane of Wald and Havran (2006) by event sweep
 *   kd_buffer.c    the node buffer the recursion writes, and its statistics
 *   kd_pack.c      the leaves' triangles in packs for the SIMD test
 *   kd_traverse.c  closest-hit and any-hit ray queries
 *   kd_validate.c  the invariant checker behind arbor_accel_validate
 *
 * THE TREE. nodes[] holds 8-byte nodes in depth-first order, as pbrt's
 * KdAccelNode: an inner node's below child (coordinates < split) is the next
 * node and its above child is at the index stored in the node. A leaf with
 * one triangle stores that triangle's index; a leaf with more stores the
 * offset of its list in tri_index[], a multiple of KD_PACK_LANES, and its
 * triangles' corners are in packs[offset / KD_PACK_LANES] on, in the list's
 * order, for the SIMD test (kd_pack.c). Triangle indices are always the
 * mesh's.
 * A leaf's cell is not stored: it follows from the root box and the planes.
 *
 * Invariants (kd_validate.c checks them):
 *   - every split lies within its node's cell, which has positive extent
 *     along the split axis; strictly inside it but for the SAH's splits on
 *     a face, whose flat child (no extent along the axis) takes the
 *     triangles lying in that face (kd_sah.c);
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

/* Child indices and leaf sizes have the upper 30 bits of flags, above the
 * KD_KIND_BITS of the axis or KD_LEAF. */
#define KD_KIND_BITS 2
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

static inline uint32_t kd_node_kind(kd_node n) { return n.flags & ((1u << KD_KIND_BITS) - 1u); }
static inline uint32_t kd_node_high(kd_node n) { return n.flags >> KD_KIND_BITS; }
static inline uint32_t kd_node_flags(uint32_t kind, uint32_t high) { return high << KD_KIND_BITS | kind; }

/* A leaf's triangles: its own one, or its run of tri_index. An empty leaf
 * has none, and no address: a tree whose leaves all hold at most one
 * triangle has no tri_index at all (NULL, and NULL + 0 is undefined). */
static inline const uint32_t *kd_leaf_tris(const kd_node *n, const uint32_t *tri_index)
{
    uint32_t count = kd_node_high(*n);
    return count == 1 ? &n->tri : count == 0 ? NULL : tri_index + n->first;
}

/* Triangles a leaf's pack holds: 8, as in the BVH's packs, one AVX
 * register a row (two SSE halves without AVX). With packed tests costed as
 * such (kd_build.c's KI) the SAH makes leaves of 13-15 triangles on the
 * study's models, and packs of 8 traced 6-13% more rays a second than packs
 * of 4 on castle and bunny. */
#define KD_PACK_LANES 8

/* The corners of KD_PACK_LANES triangles as tri_pack.h reads them:
 * v[corner][axis][lane]. */
typedef struct {
    _Alignas(4 * KD_PACK_LANES) float v[3][3][KD_PACK_LANES];
} kd_pack;

typedef struct {
    const arbor_mesh *mesh;
    kd_node *nodes;
    uint32_t *tri_index;
    kd_pack *packs;
    size_t nnodes, nindex, npacks;
    arbor_aabb bounds;   /* the root's cell: the box of all triangles */
    uint32_t max_depth;  /* the limit the build obeyed */
} kd_tree;

/* Cell box accessors: component k of a box's lo / hi corner. */
static inline float kd_lo(const arbor_aabb *b, int k) { return k == 0 ? b->lo.x : k == 1 ? b->lo.y : b->lo.z; }
static inline float kd_hi(const arbor_aabb *b, int k) { return k == 0 ? b->hi.x : k == 1 ? b->hi.y : b->hi.z; }

/* ---- building (kd_build.c and the files it calls) --------------------- */

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

/* ---- event lists (kd_events.c) ---- */

/* Room for new events, per triangle: one axis's run holds at most two
 * (start and end), the three axes' runs together six. */
#define KD_RUN_ROOM 2u
#define KD_RUNS_ROOM (3u * KD_RUN_ROOM)

/* Sorts events of one axis into (position, type) order; tmp holds n. */
void kd_sort_events(kd_event *ev, size_t n, kd_event *tmp);

/* New events being gathered: one run per axis, each with room for
 * KD_RUN_ROOM events per triangle, so that each run is sorted on its own
 * (three short sorts instead of one long one) and the runs are then packed
 * in axis order, which is sorted order. */
typedef struct {
    kd_event *run[3];
    size_t n[3];
} kd_event_runs;

/* Runs in ev, which has room for KD_RUNS_ROOM * ntris events. */
void kd_runs_init(kd_event_runs *r, kd_event *ev, size_t ntris);

/* Adds the events of a triangle whose (clipped) box is `box`: on each axis
 * a start and an end, or one planar event when the box is flat there. */
static inline void kd_runs_add(kd_event_runs *r, uint32_t tri, const arbor_aabb *box)
{
    for (int k = 0; k < 3; k++) {
        float lo = kd_lo(box, k), hi = kd_hi(box, k);
        kd_event *out = r->run[k] + r->n[k];
        if (lo == hi) {
            out[0] = kd_event_make(lo, tri, k, KD_EVENT_PLANAR);
            r->n[k] += 1;
        } else {
            out[0] = kd_event_make(lo, tri, k, KD_EVENT_START);
            out[1] = kd_event_make(hi, tri, k, KD_EVENT_END);
            r->n[k] += 2;
        }
    }
}

/* Sorts each run and packs them into one sorted list at r->run[0];
 * returns its length and sets axis_begin (if not NULL). tmp holds the
 * longest run (KD_RUN_ROOM * ntris). */
size_t kd_runs_finish(kd_event_runs *r, kd_event *tmp, size_t axis_begin[4]);

/* ---- perfect splits (kd_clip.c) ---- */

/* Triangle tri clipped to cell, then cut by pl into the parts in the below
 * and above cells (child_cell[0], [1]). in[c] says whether part c is
 * non-empty, and box[c] is then its box, rounded outwards by b->clip_slack
 * where clipping computed a coordinate. */
void kd_clip_split(const kd_builder *b, uint32_t tri, const arbor_aabb *cell, kd_plane pl,
                   const arbor_aabb child_cell[2], bool in[2], arbor_aabb box[2]);

/* ---- splitting a node (kd_split.c) ---- */

/* Per-thread scratch: side[] is indexed by triangle (only the entries of
 * the node being split are meaningful); fresh[] holds a split's new events
 * (grown as needed, so small nodes never allocate); start[] and values[]
 * serve the median. */
typedef struct {
    uint8_t *side;
    kd_event *fresh;
    size_t fresh_cap;
    float *start;
    float *values;
} kd_scratch;

/* An empty scratch, safe to free. */
#define KD_SCRATCH_NONE ((kd_scratch){NULL, NULL, 0, NULL, NULL})

bool kd_scratch_init(kd_scratch *s, const kd_builder *b);
void kd_scratch_free(kd_scratch *s);

/* Splits t at pl into the tasks below and above (their events sorted, their
 * cells the halves of t's). t's events are left for the caller to free.
 * False when memory runs out (nothing is left allocated then). */
bool kd_split(const kd_builder *b, kd_scratch *s, const kd_task *t, kd_plane pl, kd_task *below, kd_task *above);

/* ---- choosing planes (kd_simple.c, kd_sah.c) ---- */

/* The plane of spatial, median or mean (kd_simple.c); false when no plane
 * makes progress. */
bool kd_simple_plane(const kd_builder *b, kd_scratch *s, const kd_task *t, kd_plane *pl);

/* The SAH plane for t (kd_sah.c): false when no plane is cheaper than a
 * leaf, i.e. when t should be a leaf. */
bool kd_sah_plane(const kd_builder *b, const kd_task *t, kd_plane *plane);

/* The SAH's parts (kd_sah.c; exposed for the test of the sweep): the areas
 * of the children of cell split at p on axis k as fractions of the cell's
 * (pb below, pa above), and the cost of a split whose children hold nb and
 * na triangles. */
void kd_sah_fractions(const arbor_aabb *cell, int k, float p, double *pb, double *pa);
double kd_sah_cost(const kd_builder *b, double pb, double pa, uint32_t nb, uint32_t na);

/* ---- the node buffer (kd_buffer.c) ---- */

/* The sums behind arbor_tree_stats, added up as nodes are written. */
typedef struct {
    double inner_area;      /* sum of inner nodes' cell areas */
    double leaf_area_tris;  /* sum of leaves' cell areas times their triangle counts */
    uint64_t leaves, empty_leaves, refs, depth_sum;
    uint32_t max_depth;
} kd_sums;

/* Nodes in depth-first order and the leaves' triangle lists, as they are
 * written; a subtree built on another thread has one of its own, with
 * indices from 0, until kd_buffer_append moves it after its sibling. */
typedef struct {
    kd_node *nodes;
    size_t nnodes, node_cap;
    uint32_t *index;
    size_t nindex, index_cap;
    kd_sums sums;
    bool failed;  /* out of memory, more nodes than 30 bits can name, or cancelled */
} kd_buffer;

/* Writes t as a leaf listing its triangles. */
void kd_emit_leaf(kd_buffer *out, const kd_task *t);

/* Writes t as an inner node at pl; returns its index. Its above child is
 * set by kd_set_above once known. */
size_t kd_emit_inner(kd_buffer *out, const kd_task *t, kd_plane pl);

/* The above child of inner node `inner` is the next node written. */
void kd_set_above(kd_buffer *out, size_t inner);

/* Appends the subtree in `from` (built with indices from 0) to `out`. */
void kd_buffer_append(kd_buffer *out, const kd_buffer *from);

/* Lays the finished tree's leaves out in packs (kd_pack.c); false when
 * memory runs out (the tree is then unchanged). */
bool kd_pack_leaves(kd_tree *tree);

/* The bytes a tree holds: nodes, triangle lists and packs. */
static inline uint64_t kd_tree_bytes(const kd_tree *t)
{
    return t->nnodes * sizeof *t->nodes + t->nindex * sizeof *t->tri_index + t->npacks * sizeof *t->packs;
}

/* A node's cell and depth, for a visitor (kd_traverse.c) or a walk (kd.c). */
typedef struct {
    arbor_aabb cell;
    uint32_t depth;
} kd_place;

/* The cells of an inner node's children: below and above its plane. */
static inline void kd_child_cells(const kd_place *p, uint32_t axis, float split, kd_place *below, kd_place *above)
{
    *below = *above = (kd_place){p->cell, p->depth + 1};
    float *hi = axis == 0 ? &below->cell.hi.x : axis == 1 ? &below->cell.hi.y : &below->cell.hi.z;
    float *lo = axis == 0 ? &above->cell.lo.x : axis == 1 ? &above->cell.lo.y : &above->cell.lo.z;
    *hi = split;
    *lo = split;
}

/* Fills stats from the finished tree and its buffer's sums. */
void kd_fill_stats(const kd_tree *tree, const kd_sums *s, arbor_tree_stats *stats);

/* The entry points behind arbor_kd_ops (kd.c); see accel_impl.h. */
void *kd_build(const arbor_mesh *m, const arbor_build_opts *o, accel_run *run, arbor_tree_stats *stats, arbor_err *e);
void kd_destroy(void *impl);
/* kd_traverse.c, one copy per traversal kernel (accel_impl.h). */
extern const accel_queries kd_queries_sse2, kd_queries_avx2;
bool kd_validate(const void *impl, const arbor_mesh *m, const arbor_tree_stats *stats, arbor_err *e);

#endif
