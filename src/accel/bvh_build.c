/*
 * bvh_build.c - the BVH builders: spatial median, object median, object mean
 * and binned SAH, one top-down recursion that differs only in where it
 * splits a node (choose_split).
 *
 * The build works on an array idx of triangle indices that it partitions in
 * place, so a node always owns a contiguous range idx[begin, end). Each
 * triangle's box and centroid (the centre of its box) are computed once up
 * front. The node array is allocated once for the worst case, 2N - 1 nodes
 * (every leaf holding one triangle), and nodes are written straight into
 * their depth-first slots, so no allocation happens per node.
 *
 * Splits (all on the centroids, so every triangle goes to exactly one side):
 *   spatial  the middle of the node's centroid bounds on their longest axis;
 *   median   the median centroid on that axis, found by quickselect;
 *   mean     the mean centroid on that axis;
 *   sah      binned SAH (Wald, "On fast Construction of SAH-based Bounding
 *            Volume Hierarchies", 2007): centroids fall into BVH_SAH_BINS
 *            bins per axis (fewer for small nodes, but at least 16), the
 *            cost of each plane between bins is evaluated from prefix and
 *            suffix sums of the bins, and the cheapest plane wins (nodes of
 *            two triangles are decided directly); the node stays a leaf
 *            when splitting costs more than intersecting its triangles (and
 *            it is small enough).
 * When a split would leave one side empty (rounding, or everything on one
 * side of the plane) the node splits at the object median instead, which
 * always gives two non-empty halves; when all centroids coincide the range is
 * halved by count. The same median split takes over near BVH_MAX_DEPTH so
 * that no tree is deeper than the traversal stack.
 *
 * Parallel build: the top levels of the recursion build their two children
 * as a parallel loop of two (accel_parallel: the calling thread and an idle
 * pool worker, if the build's budget allows). The left child is built into
 * slot s + 1 as always; the right child cannot know how many nodes the left
 * will use, so it is built into the slot its worst case would leave free,
 * s + 2 n_left, and moved down next to the left subtree after both finish.
 * Which levels fork depends only on the build's thread count, never on
 * which threads turn up, so neither do the tree and its sums.
 *
 * Cancelling: every node polls the cancel flag (accel_stop); once it is set
 * each node still to be built becomes a leaf, so the recursion unwinds in
 * one pass over the triangles left, and the build then fails.
 */
#include <emmintrin.h>
#include <stdlib.h>
#include <string.h>

#include "bvh_internal.h"

/* Defaults (arbor_build_opts fields that are 0). The simple builders split
 * down to BVH_SIMPLE_LEAF triangles; the SAH builder decides by cost but
 * never leaves more than BVH_SAH_LEAF in a leaf. Unit costs for traversal
 * and intersection are what the sah_cost statistic uses too. */
#define BVH_SIMPLE_LEAF 4
#define BVH_SAH_LEAF 8
#define BVH_SAH_BINS 32
#define BVH_SAH_MIN_BINS 16
#define BVH_COST_TRAVERSE 1.0f
#define BVH_COST_INTERSECT 1.0f
/* A node forks into a parallel pair only if it has this many triangles, and
 * only in the top levels: enough levels that uneven splits still leave work
 * for every thread (a few parts per thread), no more. */
#define BVH_FORK_MIN_TRIS 8192
#define BVH_FORK_EXTRA_LEVELS 2
/* Meshes this large also split the linear passes over all triangles. */
#define BVH_PARALLEL_PASS_TRIS 65536

/* A box as the builder keeps it: four lanes per corner, the fourth always 0,
 * so that growing a box is one 4-wide min and max that the compiler can
 * vectorise (binning, the inner loop of the SAH build, is mostly that). */
typedef struct {
    float lo[4], hi[4];
} build_box;

typedef struct {
    arbor_builder builder;
    uint32_t max_leaf;       /* a node with more triangles is always split */
    uint32_t max_depth;      /* a node at this depth is always a leaf */
    uint32_t fork_depth;     /* nodes above this depth may fork */
    float cost_traverse, cost_intersect;
    const build_box *tri_box;   /* per mesh triangle */
    const float *centroid;      /* per mesh triangle: x, y, z of its box centre, 0 */
    uint32_t *idx;              /* triangle indices; each task owns a range */
    bvh_node *nodes;            /* each task owns a range of slots */
    accel_run *run;             /* threads and cancel flag */
} bvh_builder;

/* What a subtree's build adds to the statistics; parallel tasks each keep
 * their own and the parent adds them up after the join. */
typedef struct {
    uint64_t inner, leaves, refs, leaf_depth_sum;
    uint32_t max_depth;
    double inner_area, leaf_area;  /* sum of A(n) over inner nodes; of A(l) N(l) over leaves */
} bvh_tally;

static inline void box_empty(build_box *b)
{
    for (int a = 0; a < 3; a++) {
        b->lo[a] = INFINITY;
        b->hi[a] = -INFINITY;
    }
    b->lo[3] = b->hi[3] = 0.0f;
}

static inline void box_add(build_box *b, const build_box *t)
{
    for (int a = 0; a < 4; a++) {
        b->lo[a] = arbor_minf(b->lo[a], t->lo[a]);
        b->hi[a] = arbor_maxf(b->hi[a], t->hi[a]);
    }
}

/* p: four floats, the fourth 0 */
static inline void box_add_point(build_box *b, const float *p)
{
    for (int a = 0; a < 4; a++) {
        b->lo[a] = arbor_minf(b->lo[a], p[a]);
        b->hi[a] = arbor_maxf(b->hi[a], p[a]);
    }
}

/* Surface area of a non-empty box, computed as aabb_area does. */
static inline float box_area(const build_box *b)
{
    float x = b->hi[0] - b->lo[0], y = b->hi[1] - b->lo[1], z = b->hi[2] - b->lo[2];
    return 2.0f * (x * y + y * z + z * x);
}

static uint32_t ceil_log2(uint32_t n)
{
    uint32_t k = 0;
    while (k < 32 && ((uint64_t)1 << k) < n)
        k++;
    return k;
}

static inline float centroid_axis(const bvh_builder *B, uint32_t tri, int axis)
{
    return B->centroid[4 * (size_t)tri + (size_t)axis];
}

/* The box of the triangles in idx[b, e) and the box of their centroids. */
static void range_bounds(const bvh_builder *B, uint32_t b, uint32_t e, build_box *box, build_box *cbox)
{
    box_empty(box);
    box_empty(cbox);
    for (uint32_t i = b; i < e; i++) {
        uint32_t t = B->idx[i];
        box_add(box, &B->tri_box[t]);
        box_add_point(cbox, &B->centroid[4 * (size_t)t]);
    }
}

/* Moves the triangles of idx[b, e) whose centroid lies below pos on axis to
 * the front and returns where the others start. The one partition of every
 * builder (and of the quickselect below). */
static uint32_t partition(const bvh_builder *B, uint32_t b, uint32_t e, int axis, float pos)
{
    uint32_t *idx = B->idx;
    uint32_t m = b;
    /* invariant: idx[b, m) below pos, idx[m, i) not below. Every element is
     * swapped and m advances by the comparison's value: no branch on it,
     * which would be mispredicted half the time near the root. */
    for (uint32_t i = b; i < e; i++) {
        uint32_t t = idx[i];
        uint32_t below = centroid_axis(B, t, axis) < pos;
        idx[i] = idx[m];
        idx[m] = t;
        m += below;
    }
    return m;
}

static float median_of_three(float a, float b, float c)
{
    return arbor_maxf(arbor_minf(a, b), arbor_minf(arbor_maxf(a, b), c));
}

/* Quickselect (Hoare's FIND): reorders idx[b, e) so that the triangle with
 * the k-th smallest centroid on axis is at k, none larger before it and none
 * smaller after it. Expected O(e - b). Each round splits the range three
 * ways (below, equal to, above the pivot), so equal centroids cannot stall it. */
static void select_nth(const bvh_builder *B, uint32_t b, uint32_t e, uint32_t k, int axis)
{
    while (e - b > 1) {
        float pivot = median_of_three(centroid_axis(B, B->idx[b], axis), centroid_axis(B, B->idx[b + (e - b) / 2], axis),
                                      centroid_axis(B, B->idx[e - 1], axis));
        uint32_t lt = partition(B, b, e, axis, pivot);
        uint32_t le = partition(B, lt, e, axis, nextafterf(pivot, INFINITY));
        if (k < lt)
            e = lt;
        else if (k >= le)
            b = le;
        else
            return;
        if (lt == le)
            return; /* the pivot was NaN (a NaN vertex): no order to find */
    }
}

/* The object median split on axis: both halves non-empty for e - b >= 2. */
static uint32_t split_median(const bvh_builder *B, uint32_t b, uint32_t e, int axis)
{
    uint32_t m = b + (e - b) / 2;
    select_nth(B, b, e, m, axis);
    return m;
}

static float centroid_mean(const bvh_builder *B, uint32_t b, uint32_t e, int axis)
{
    double sum = 0.0;
    for (uint32_t i = b; i < e; i++)
        sum += centroid_axis(B, B->idx[i], axis);
    return (float)(sum / (double)(e - b));
}

/* The bins of the three axes: boxes (32 bytes, so aligned ones never straddle
 * a cache line) and triangle counts. */
typedef struct {
    _Alignas(64) build_box box[3][BVH_SAH_BINS];
    uint32_t count[3][BVH_SAH_BINS];
} sah_bins;

/* The cheapest plane of one axis' bins by the sum A(l) N(l) + A(r) N(r):
 * sets *plane (the plane after bin *plane) and returns the sum, or INFINITY
 * if no plane has triangles on both sides. Planes after an empty bin split
 * the triangles like the plane before it, so only the others are tried. */
static float sah_sweep(const build_box *box, const uint32_t *count, uint32_t nbins, uint32_t *plane)
{
    /* right[j], right_count[j]: A N and N of the bins after plane j */
    float right[BVH_SAH_BINS];
    uint32_t right_count[BVH_SAH_BINS];
    build_box acc;
    box_empty(&acc);
    uint32_t n = 0;
    float an = 0.0f;
    for (uint32_t j = nbins - 1; j > 0; j--) {
        if (count[j] > 0) {
            box_add(&acc, &box[j]);
            n += count[j];
            an = box_area(&acc) * (float)n;
        }
        right[j - 1] = an;
        right_count[j - 1] = n;
    }
    float best = INFINITY;
    box_empty(&acc);
    n = 0;
    for (uint32_t j = 0; j + 1 < nbins; j++) {
        if (count[j] == 0)
            continue;
        box_add(&acc, &box[j]);
        n += count[j];
        if (right_count[j] == 0)
            break;
        float cost = box_area(&acc) * (float)n + right[j];
        if (cost < best) {
            best = cost;
            *plane = j;
        }
    }
    return best;
}

/* Binned SAH over the three axes of idx[b, e), whose box has area `area` and
 * whose centroids span cbox (not a single point). Sets *axis and *pos to the
 * cheapest plane and returns whether splitting there beats a leaf, by the
 * cost model Ct A(n) + Ci (A(l) N(l) + A(r) N(r)) against Ci A(n) N(n)
 * (the usual one multiplied through by A(n), so flat nodes need no division).
 * *axis and *pos stay as they came if no plane has triangles on both sides.
 * Nodes of fewer than BVH_SAH_BINS triangles use as many bins as they have
 * triangles, but at least BVH_SAH_MIN_BINS: more would be mostly empty. */
static bool sah_choose(const bvh_builder *B, uint32_t b, uint32_t e, float area, const build_box *cbox, int *axis,
                       float *pos)
{
    uint32_t n = e - b;
    uint32_t nbins = n < BVH_SAH_BINS ? (n > BVH_SAH_MIN_BINS ? n : BVH_SAH_MIN_BINS) : BVH_SAH_BINS;
    sah_bins bins;
    const float *lo = cbox->lo;
    float scale[3];
    for (int k = 0; k < 3; k++) {
        float ext = cbox->hi[k] - lo[k];
        scale[k] = ext > 0.0f ? (float)nbins / ext : 0.0f;
        for (uint32_t j = 0; j < nbins; j++) {
            box_empty(&bins.box[k][j]);
            bins.count[k][j] = 0;
        }
    }
    /* The binning loop, the build's hottest: the three axes' bin indices in
     * one SSE computation, (c - lo) * scale clamped to [0, nbins - 1] without
     * branches (maxps returns 0 for a NaN, which lands in bin 0), and the
     * triangle's box loaded once for the three bins it grows. */
    const __m128 lo4 = _mm_loadu_ps(lo), scale4 = _mm_setr_ps(scale[0], scale[1], scale[2], 0.0f);
    const __m128 last4 = _mm_set1_ps((float)(nbins - 1));
    for (uint32_t i = b; i < e; i++) {
        uint32_t t = B->idx[i];
        __m128 f = _mm_mul_ps(_mm_sub_ps(_mm_loadu_ps(&B->centroid[4 * (size_t)t]), lo4), scale4);
        f = _mm_min_ps(_mm_max_ps(f, _mm_setzero_ps()), last4);
        uint32_t j[4];
        _mm_storeu_si128((__m128i *)j, _mm_cvttps_epi32(f));
        const __m128 tlo = _mm_loadu_ps(B->tri_box[t].lo), thi = _mm_loadu_ps(B->tri_box[t].hi);
        for (int k = 0; k < 3; k++) {
            build_box *bin = &bins.box[k][j[k]];
            bins.count[k][j[k]]++;
            _mm_storeu_ps(bin->lo, _mm_min_ps(_mm_loadu_ps(bin->lo), tlo));
            _mm_storeu_ps(bin->hi, _mm_max_ps(_mm_loadu_ps(bin->hi), thi));
        }
    }
    float best = INFINITY;
    for (int k = 0; k < 3; k++) {
        uint32_t plane = 0;
        float cost = scale[k] > 0.0f ? sah_sweep(bins.box[k], bins.count[k], nbins, &plane) : INFINITY;
        if (cost < best) {
            best = cost;
            *axis = k;
            *pos = lo[k] + (float)(plane + 1) / scale[k];
        }
    }
    double split_cost = (double)B->cost_traverse * area + (double)B->cost_intersect * best;
    double leaf_cost = (double)B->cost_intersect * area * (double)(e - b);
    return split_cost < leaf_cost || e - b > B->max_leaf;
}

/* The SAH decision for a node of two triangles whose centroids differ: the
 * only split puts one on each side, which binning on any axis where they
 * differ finds too; it is taken by the same cost model as sah_choose's.
 * Returns the split index (b + 1, the triangle with the smaller centroid on
 * the first such axis first) or 0 for a leaf. Two triangles is the commonest
 * node size near the leaves, and clearing and sweeping bins for them cost
 * more than their binning. */
static uint32_t sah_split_pair(const bvh_builder *B, uint32_t b, float area, const build_box *cbox)
{
    uint32_t *idx = B->idx;
    double split_cost = (double)B->cost_traverse * area +
                        (double)B->cost_intersect * ((double)box_area(&B->tri_box[idx[b]]) +
                                                     (double)box_area(&B->tri_box[idx[b + 1]]));
    double leaf_cost = (double)B->cost_intersect * area * 2.0;
    if (!(split_cost < leaf_cost) && B->max_leaf >= 2)
        return 0;
    int axis = cbox->hi[0] > cbox->lo[0] ? 0 : cbox->hi[1] > cbox->lo[1] ? 1 : 2;
    if (centroid_axis(B, idx[b + 1], axis) < centroid_axis(B, idx[b], axis)) {
        uint32_t t = idx[b];
        idx[b] = idx[b + 1];
        idx[b + 1] = t;
    }
    return b + 1;
}

/* Where the node over idx[b, e) at depth `depth` splits: the index in (b, e)
 * where its right child's triangles start, or 0 (never such an index) for a
 * leaf. Reorders idx[b, e) to match. */
static uint32_t choose_split(const bvh_builder *B, uint32_t b, uint32_t e, uint32_t depth, float area,
                             const build_box *cbox)
{
    uint32_t n = e - b;
    arbor_vec3 ext = vec3(cbox->hi[0] - cbox->lo[0], cbox->hi[1] - cbox->lo[1], cbox->hi[2] - cbox->lo[2]);
    if (ext.x <= 0.0f && ext.y <= 0.0f && ext.z <= 0.0f)
        return n > B->max_leaf ? b + n / 2 : 0; /* one centroid: any halving is as good */
    int axis = vec3_max_axis(ext);
    float pos = 0.5f * (cbox->lo[axis] + cbox->hi[axis]);
    /* Past this depth only median splits are sure to end by BVH_MAX_DEPTH - 1:
     * each halves the count, so n triangles need ceil(log2 n) more levels. */
    if (depth + 1 + ceil_log2(n) > BVH_MAX_DEPTH - 1)
        return split_median(B, b, e, axis);
    uint32_t m;
    switch (B->builder) {
    case ARBOR_BUILD_SAH:
        if (n == 2)
            return sah_split_pair(B, b, area, cbox);
        if (!sah_choose(B, b, e, area, cbox, &axis, &pos))
            return 0;
        m = partition(B, b, e, axis, pos);
        break;
    case ARBOR_BUILD_SPATIAL:
        if (n <= B->max_leaf)
            return 0;
        m = partition(B, b, e, axis, pos);
        break;
    case ARBOR_BUILD_MEAN:
        if (n <= B->max_leaf)
            return 0;
        m = partition(B, b, e, axis, centroid_mean(B, b, e, axis));
        break;
    case ARBOR_BUILD_MEDIAN:
    default:
        if (n <= B->max_leaf)
            return 0;
        return split_median(B, b, e, axis);
    }
    /* a plane with every centroid on one side (rounding at a bin edge or a
     * mean that rounds to the smallest value): fall back to the median */
    if (m == b || m == e)
        m = split_median(B, b, e, axis);
    return m;
}

static uint32_t build_subtree(const bvh_builder *B, uint32_t s, uint32_t b, uint32_t e, uint32_t depth,
                              bvh_tally *tally);

typedef struct {
    const bvh_builder *B;
    uint32_t slot, begin, end, depth;
    bvh_tally tally;
    uint32_t used;
} build_task;

/* Task number `i` of the array `tasks`. */
static void build_task_run(void *tasks, uint32_t i)
{
    build_task *t = (build_task *)tasks + i;
    t->used = build_subtree(t->B, t->slot, t->begin, t->end, t->depth, &t->tally);
}

static void tally_add(bvh_tally *to, const bvh_tally *from)
{
    to->inner += from->inner;
    to->leaves += from->leaves;
    to->refs += from->refs;
    to->leaf_depth_sum += from->leaf_depth_sum;
    to->max_depth = to->max_depth > from->max_depth ? to->max_depth : from->max_depth;
    to->inner_area += from->inner_area;
    to->leaf_area += from->leaf_area;
}

/* Moves the subtree of `count` nodes at slot `from` down to slot `to`; the
 * right-child indices inside it move with it. */
static void move_subtree(bvh_node *nodes, uint32_t from, uint32_t to, uint32_t count)
{
    memmove(nodes + to, nodes + from, count * sizeof *nodes);
    for (uint32_t i = to; i < to + count; i++)
        if (nodes[i].count == 0)
            nodes[i].index -= from - to;
}

/* Builds the children of inner node s over idx[b, m) and idx[m, e) as a
 * parallel pair; returns the nodes they used. */
static uint32_t build_children_parallel(const bvh_builder *B, uint32_t s, uint32_t b, uint32_t m, uint32_t e,
                                        uint32_t depth, bvh_tally *tally)
{
    /* the left subtree uses at most 2 (m - b) - 1 slots */
    build_task kids[2] = {{B, s + 1, b, m, depth + 1, {0}, 0}, {B, s + 2 * (m - b), m, e, depth + 1, {0}, 0}};
    accel_parallel(B->run, 2, build_task_run, kids);
    const build_task *left = &kids[0], *right = &kids[1];
    uint32_t right_slot = s + 1 + left->used;
    if (right_slot != right->slot)
        move_subtree(B->nodes, right->slot, right_slot, right->used);
    B->nodes[s].index = right_slot;
    tally_add(tally, &left->tally);
    tally_add(tally, &right->tally);
    return left->used + right->used;
}

/* Builds the subtree over idx[b, e) with its root in slot s at `depth`, in
 * depth-first order from s; returns the number of nodes it used (at most
 * 2 (e - b) - 1). */
static uint32_t build_subtree(const bvh_builder *B, uint32_t s, uint32_t b, uint32_t e, uint32_t depth,
                              bvh_tally *tally)
{
    build_box box, cbox;
    range_bounds(B, b, e, &box, &cbox);
    bvh_node *node = &B->nodes[s];
    for (int a = 0; a < 3; a++) {
        node->bounds[a] = box.lo[a];
        node->bounds[3 + a] = box.hi[a];
    }
    float area = box_area(&box);
    uint32_t m = e - b > 1 && depth < B->max_depth && !accel_stop(B->run) ? choose_split(B, b, e, depth, area, &cbox)
                                                                          : 0;
    if (m == 0) {
        node->index = b;
        node->count = e - b;
        tally->leaves++;
        tally->refs += e - b;
        tally->leaf_depth_sum += depth;
        tally->max_depth = depth > tally->max_depth ? depth : tally->max_depth;
        tally->leaf_area += (double)area * (e - b);
        return 1;
    }
    node->count = 0;
    tally->inner++;
    tally->inner_area += area;
    if (depth < B->fork_depth && e - b >= BVH_FORK_MIN_TRIS)
        return 1 + build_children_parallel(B, s, b, m, e, depth, tally);
    uint32_t left = build_subtree(B, s + 1, b, m, depth + 1, tally);
    node->index = s + 1 + left;
    return 1 + left + build_subtree(B, s + 1 + left, m, e, depth + 1, tally);
}

static void tally_to_stats(const bvh_tally *t, const bvh_tree *tree, double root_area, arbor_tree_stats *s)
{
    memset(s, 0, sizeof *s);
    s->nodes = t->inner + t->leaves;
    s->leaves = t->leaves;
    s->empty_leaves = 0;
    s->max_depth = t->max_depth;
    s->refs = t->refs;
    if (t->leaves > 0) {
        s->mean_leaf_depth = (double)t->leaf_depth_sum / (double)t->leaves;
        s->mean_tris_per_leaf = (double)t->refs / (double)t->leaves;
    }
    s->bytes = bvh_tree_bytes(tree);
    s->sah_cost = root_area > 0.0 ? (t->inner_area + t->leaf_area) / root_area : (double)(t->inner + t->refs);
}

void bvh_tree_free(bvh_tree *t)
{
    if (t == NULL)
        return;
    free(t->nodes);
    free(t->tri_index);
    free(t->wide);
    free(t->packs);
    free(t->pack_tri);
    free(t);
}

/* A linear pass over mesh triangles [b, e), which large meshes split in two
 * parallel halves. */
typedef struct {
    const arbor_mesh *m;
    build_box *tri_box;
    float *centroid;
    bvh_tree *tree;
    uint32_t b, e;
} tri_pass;

/* Each triangle's box and centroid, once for the whole build: pass number
 * `half` of the array `passes`. */
static void precompute_triangles(void *passes, uint32_t half)
{
    const tri_pass *p = (const tri_pass *)passes + half;
    for (uint32_t t = p->b; t < p->e; t++) {
        arbor_vec3 v[3];
        arbor_mesh_tri(p->m, t, &v[0], &v[1], &v[2]);
        build_box *box = &p->tri_box[t];
        box_empty(box);
        for (int k = 0; k < 3; k++) {
            const float q[4] = {v[k].x, v[k].y, v[k].z, 0.0f};
            box_add_point(box, q);
        }
        for (int a = 0; a < 4; a++)
            p->centroid[4 * (size_t)t + a] = 0.5f * (box->lo[a] + box->hi[a]);
        p->tree->tri_index[t] = t;
    }
}

/* Runs pass over all triangles, in two parallel halves when parallel. */
static void tri_pass_run(accel_run *run, void (*pass)(void *passes, uint32_t half), tri_pass whole, bool parallel)
{
    tri_pass halves[2] = {whole, whole};
    halves[0].e = halves[1].b = whole.e / 2;
    accel_parallel(run, parallel ? 2 : 1, pass, parallel ? halves : &whole);
}

static void builder_init(bvh_builder *B, const arbor_build_opts *o, accel_run *run)
{
    memset(B, 0, sizeof *B);
    B->builder = o->builder;
    B->max_leaf = o->max_leaf_tris > 0 ? (uint32_t)o->max_leaf_tris
                  : o->builder == ARBOR_BUILD_SAH ? BVH_SAH_LEAF : BVH_SIMPLE_LEAF;
    B->max_depth = o->max_depth > 0 && o->max_depth < BVH_MAX_DEPTH ? (uint32_t)o->max_depth : BVH_MAX_DEPTH - 1;
    B->fork_depth = run->threads > 1 ? ceil_log2(run->threads) + BVH_FORK_EXTRA_LEVELS : 0;
    B->run = run;
    B->cost_traverse = o->cost_traverse > 0.0f ? o->cost_traverse : BVH_COST_TRAVERSE;
    B->cost_intersect = o->cost_intersect > 0.0f ? o->cost_intersect : BVH_COST_INTERSECT;
}

void *bvh_alloc_aligned(size_t bytes)
{
    return aligned_alloc(64, bytes > 0 ? (bytes + 63) & ~(size_t)63 : 64);
}

/* In place when realloc allows (it usually does when shrinking), through an
 * aligned copy when it moved the array to a less aligned place. */
void *bvh_shrink_aligned(void *p, size_t used)
{
    size_t bytes = used > 0 ? (used + 63) & ~(size_t)63 : 64;
    void *shrunk = realloc(p, bytes);
    if (shrunk == NULL || ((uintptr_t)shrunk & 63) == 0)
        return shrunk != NULL ? shrunk : p;
    void *out = aligned_alloc(64, bytes);
    if (out != NULL)
        memcpy(out, shrunk, used);
    free(shrunk);
    return out;
}

void *bvh_build(const arbor_mesh *m, const arbor_build_opts *o, accel_run *run, arbor_tree_stats *stats,
                arbor_err *e)
{
    uint32_t n = m->ntris;
    if (n > UINT32_MAX / 2) {
        arbor_fail(e, ARBOR_ERR_INVALID, "bvh: %u triangles is more than node indices can address", n);
        return NULL;
    }
    bvh_tree *tree = calloc(1, sizeof *tree);
    if (tree == NULL) {
        arbor_fail(e, ARBOR_ERR_NOMEM, "bvh: out of memory");
        return NULL;
    }
    tree->ntris = n;
    if (n == 0) {
        bvh_tally none = {0};
        tally_to_stats(&none, tree, 0.0, stats);
        return tree;
    }
    bvh_builder B;
    builder_init(&B, o, run);
    build_box *tri_box = malloc(n * sizeof *tri_box);
    float *centroid = malloc(4 * (size_t)n * sizeof *centroid);
    bvh_node *scratch = bvh_alloc_aligned((2 * (size_t)n - 1) * sizeof(bvh_node));
    tree->tri_index = malloc(n * sizeof *tree->tri_index);
    if (tri_box == NULL || centroid == NULL || scratch == NULL || tree->tri_index == NULL)
        goto nomem;
    bool parallel = B.fork_depth > 0 && n >= BVH_PARALLEL_PASS_TRIS;
    tri_pass pass = {m, tri_box, centroid, tree, 0, n};
    tri_pass_run(run, precompute_triangles, pass, parallel);
    B.tri_box = tri_box;
    B.centroid = centroid;
    B.idx = tree->tri_index;
    B.nodes = scratch;
    bvh_tally tally = {0};
    tree->nnodes = build_subtree(&B, 0, 0, n, 0, &tally);
    if (accel_stop(run))
        goto fail; /* the tree was cut short */
    tree->nodes = bvh_shrink_aligned(scratch, tree->nnodes * sizeof(bvh_node));
    scratch = NULL;
    if (tree->nodes == NULL)
        goto nomem;
    free(tri_box);
    free(centroid);
    if (!bvh_wide_build(tree, m, run, parallel, e)) {
        bvh_tree_free(tree);
        return NULL;
    }
    tally_to_stats(&tally, tree, aabb_area(bvh_node_box(&tree->nodes[0])), stats);
    stats->has_wide = true;
    bvh_wide_stats(tree, &stats->wide);
    return tree;
nomem:
    arbor_fail(e, ARBOR_ERR_NOMEM, "bvh: out of memory building over %u triangles", n);
fail:
    free(tri_box);
    free(centroid);
    free(scratch);
    bvh_tree_free(tree);
    return NULL;
}
