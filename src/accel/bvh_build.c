/*
 * bvh_build.c - the BVH builders: spatial median, object median, object mean
 * and binned SAH, one top-down recursion that differs only in where it
 * splits a node (choose_split).
 *
 * The build works on an array of triangle references (bvh_prim: a
 * triangle's box and its index, 32 bytes) that it partitions in place, so a
 * node always owns a contiguous range prims[begin, end) and every pass over
 * a node reads memory in order, with no gather through an index array. The
 * references are made once up front. A node's box and the box of its
 * triangles' centroids (the centres of their boxes) come from its parent's
 * partition, which computes both for each side as it moves the references,
 * so a node costs two passes: binning and partitioning. Centroids are kept
 * doubled (lo + hi, not halved): comparisons among them are the same and
 * each costs one add less. The node array is allocated once for the worst
 * case, 2N - 1 nodes (every leaf holding one triangle), and nodes are written
 * straight into their depth-first slots; a leaf writes its triangles' mesh
 * indices into tri_index, so no allocation happens per node.
 *
 * Splits (all on the centroids, so every triangle goes to exactly one side):
 *   spatial  the middle of the node's centroid bounds on their longest axis;
 *   median   the median centroid on that axis, found by quickselect;
 *   mean     the mean centroid on that axis;
 *   sah      binned SAH (Wald, "On fast Construction of SAH-based Bounding
 *            Volume Hierarchies", 2007): centroids fall into BVH_SAH_BINS
 *            bins per axis (fewer for small nodes, but at least 8), the
 *            cost of each plane between bins is evaluated from prefix and
 *            suffix sums of the bins, and the cheapest plane wins (nodes of
 *            two triangles are decided directly, and nodes of at most
 *            BVH_SAH_EXACT_TRIS try every plane between their centroids
 *            in sorted order, the exact object SAH); the node stays a leaf
 *            when splitting costs more than intersecting its triangles (and
 *            it is small enough), or when it fits one pack of the wide tree
 *            and its children would not make that tree cheaper
 *            (sah_pack_stays_leaf). The partition then sends each triangle to
 *            the side of its bin, computed as the binning computed it, so the
 *            split made is exactly the one costed (a plane position derived
 *            from the bin edge could round a centroid into the other side).
 * When a split would leave one side empty (rounding, or everything on one
 * side of the plane) the node splits at the object median instead, which
 * always gives two non-empty halves; when all centroids coincide the range is
 * halved by count. The same median split takes over near BVH_MAX_DEPTH so
 * that no tree is deeper than the traversal stack.
 *
 * Parallel build: the top levels of the recursion build their two children
 * as a parallel loop of two (accel_parallel: the calling thread and an idle
 * pool worker, if the build's budget allows), and bin their triangles in
 * parallel parts whose bins are merged in a fixed order (merging boxes and
 * counts is exact, so the bins are those of a serial pass). The left child
 * is built into slot s + 1 as always; the right child, when the left is
 * finished before it starts, next to the left subtree; otherwise it cannot
 * know how many nodes the left will use, so it is built into the slot the
 * left's worst case would leave free, s + 2 n_left, and moved down next to
 * the left subtree after both finish. Which levels fork depends only on the
 * build's thread count, never on which threads turn up, and every node ends
 * in the same slot either way, so neither do the tree and its sums.
 *
 * Cancelling: every node polls the cancel flag (accel_stop); once it is set
 * each node still to be built becomes a leaf, so the recursion unwinds in
 * one pass over the triangles left, and the build then fails.
 */
#include <assert.h>
#include <emmintrin.h>
#ifdef __SSE4_1__
#include <smmintrin.h>
#endif
#include <stdlib.h>
#include <string.h>

#include "arbor/sys.h"
#include "bvh_internal.h"

/* Defaults (arbor_build_opts fields that are 0). The simple builders split
 * down to BVH_SIMPLE_LEAF triangles; the SAH builder decides by cost but
 * never leaves more than BVH_SAH_LEAF in a leaf. Unit costs for traversal
 * and intersection are what the sah_cost statistic uses too. */
#define BVH_SIMPLE_LEAF 4
#define BVH_SAH_LEAF 8
#define BVH_SAH_BINS 32
#define BVH_SAH_MIN_BINS 8
/* A bin per 4 triangles, against the rule before (a bin per triangle, at
 * least 16 and at most 32, so nodes of 17 to 127 triangles now have fewer):
 * at 1 thread, medians of 11 builds (dragon 5) of arbor_accel_build in a
 * loop, two rounds alternating with the parent, bunny 24.4 and 27.8 -> 22.2
 * and 21.8 ms, dragon 373 and 411 -> 330 and 330; the wide trees' SAH cost
 * 0.05-0.8% more (castle 10.31 -> 10.39, sponza 18.67 -> 18.80, dragon
 * 15.011 -> 15.020), their rays within the VM's noise (docs/BENCH.md). */
#define BVH_SAH_TRIS_PER_BIN 4
#define BVH_SAH_EXACT_TRIS 16
#define BVH_COST_TRAVERSE 1.0f
#define BVH_COST_INTERSECT 1.0f
/* A node forks into a parallel pair only if it has this many triangles, and
 * only in the top levels: enough levels that uneven splits still leave work
 * for every thread (about eight parts per thread), no more, since a fork
 * costs a loop on the pool and may move its right subtree. Median of 9
 * builds at 2 threads, when every fork moved it: 2 -> 3 levels, dragon 209
 * -> 199-203 ms, sponza and bunny unchanged; 4 levels, sponza 3% slower.
 * Since forks mostly build in place (862024e), 4 and 5 levels measured
 * within noise of 3 on bunny and sponza. */
#define BVH_FORK_MIN_TRIS 8192
#define BVH_FORK_EXTRA_LEVELS 3
/* Top-level nodes of at least BVH_PARALLEL_PASS_TRIS (bvh_internal.h) bin
 * in at most this many parallel parts. */
#define BVH_BIN_PARTS 8
/* Nodes of at least this many triangles bin into two sets (bins_fill): in
 * smaller ones clearing and merging the second set would cost more than the
 * shorter chains save. 64 and 1024 measured the same as 256. */
#define BVH_BIN_PAIR_TRIS 256

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

/* What a subtree's build adds to the statistics; parallel tasks each keep
 * their own and the parent adds them up after the join. */
typedef struct {
    uint64_t inner, leaves, refs, leaf_depth_sum;
    uint32_t max_depth;
    double inner_area, leaf_area;  /* sum of A(n) over inner nodes; of A(l) N(l) over leaves */
} bvh_tally;

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

static uint32_t ceil_log2(uint32_t n)
{
    uint32_t k = 0;
    while (k < 32 && ((uint64_t)1 << k) < n)
        k++;
    return k;
}

/* The boxes of prims[b, e): for the splits that do not compute them as they
 * partition (median, halving by count). */
static void range_bounds(const bvh_builder *B, uint32_t b, uint32_t e, range_box *r)
{
    r->box = r->cbox = box_empty();
    for (uint32_t i = b; i < e; i++) {
        __m128 lo = prim_lo(&B->prims[i]), hi = prim_hi(&B->prims[i]), c = centroid2(lo, hi);
        box_grow(&r->box, lo, hi);
        box_grow(&r->cbox, c, c);
    }
}

static inline void prim_swap(bvh_prim *p, uint32_t i, uint32_t j)
{
    bvh_prim t = p[i];
    p[i] = p[j];
    p[j] = t;
}

/* Moves the references of prims[b, e) whose centroid lies below pos on axis
 * to the front and returns where the others start: quickselect's partition. */
static uint32_t partition_below(const bvh_builder *B, uint32_t b, uint32_t e, int axis, float pos)
{
    uint32_t m = b;
    /* invariant: prims[b, m) below pos, prims[m, i) not below. Every element
     * is swapped and m advances by the comparison's value: no branch on it,
     * which would be mispredicted half the time near the root. */
    for (uint32_t i = b; i < e; i++) {
        uint32_t below = centroid_axis(B, i, axis) < pos;
        prim_swap(B->prims, i, m);
        m += below;
    }
    return m;
}

static float median_of_three(float a, float b, float c)
{
    return arbor_maxf(arbor_minf(a, b), arbor_minf(arbor_maxf(a, b), c));
}

/* Quickselect (Hoare's FIND): reorders prims[b, e) so that the reference
 * with the k-th smallest centroid on axis is at k, none larger before it and
 * none smaller after it. Expected O(e - b). Each round splits the range
 * three ways (below, equal to, above the pivot), so equal centroids cannot
 * stall it. */
static void select_nth(const bvh_builder *B, uint32_t b, uint32_t e, uint32_t k, int axis)
{
    while (e - b > 1) {
        float pivot = median_of_three(centroid_axis(B, b, axis), centroid_axis(B, b + (e - b) / 2, axis),
                                      centroid_axis(B, e - 1, axis));
        uint32_t lt = partition_below(B, b, e, axis, pivot);
        uint32_t le = partition_below(B, lt, e, axis, nextafterf(pivot, INFINITY));
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

/* Splits prims[b, e) at m and measures both halves. */
static uint32_t split_at(const bvh_builder *B, uint32_t b, uint32_t m, uint32_t e, range_box kids[2])
{
    range_bounds(B, b, m, &kids[0]);
    range_bounds(B, m, e, &kids[1]);
    return m;
}

/* The object median split on axis: both halves non-empty for e - b >= 2. */
static uint32_t split_median(const bvh_builder *B, uint32_t b, uint32_t e, int axis, range_box kids[2])
{
    uint32_t m = b + (e - b) / 2;
    select_nth(B, b, e, m, axis);
    return split_at(B, b, m, e, kids);
}

static float centroid_mean(const bvh_builder *B, uint32_t b, uint32_t e, int axis)
{
    double sum = 0.0;
    for (uint32_t i = b; i < e; i++)
        sum += centroid_axis(B, i, axis);
    return (float)(sum / (double)(e - b));
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

static inline uint32_t goes_left(const split_rule *r, __m128 c)
{
    __m128 below = r->by_bin ? _mm_castsi128_ps(_mm_cmplt_epi32(bin_of(r->grid, c), r->limit_bin))
                             : _mm_cmplt_ps(c, r->limit_pos);
    return (uint32_t)_mm_movemask_ps(below) >> r->axis & 1;
}

/* mask ? a : b, lane by lane (mask lanes all ones or all zeros). */
static inline __m128 select4(__m128 mask, __m128 a, __m128 b)
{
#ifdef __SSE4_1__
    return _mm_blendv_ps(b, a, mask);
#else
    return _mm_or_ps(_mm_and_ps(mask, a), _mm_andnot_ps(mask, b));
#endif
}

/* Grows the side the mask selects by a reference's centroid and, when
 * `boxes`, its box: the other side grows by an empty box, so neither needs
 * a branch. */
static inline void side_grow(range_box *r, __m128 mask, __m128 lo, __m128 hi, __m128 c, bool boxes)
{
    const __m128 inf = _mm_set1_ps(INFINITY), ninf = _mm_set1_ps(-INFINITY);
    if (boxes)
        box_grow(&r->box, select4(mask, lo, inf), select4(mask, hi, ninf));
    box_grow(&r->cbox, select4(mask, c, inf), select4(mask, c, ninf));
}

/* Moves the references of prims[b, e) that go left by rule to the front,
 * computing both sides' centroid boxes on the way and, when `boxes`, their
 * boxes (else left empty); returns where the right side starts (b or e
 * when one side is empty; kids are then meaningless). Inlined with a
 * constant `boxes` into its two callers. */
static inline uint32_t partition_sides(const bvh_builder *B, uint32_t b, uint32_t e, const split_rule *rule,
                                       range_box kids[2], bool boxes)
{
    bvh_prim *p = B->prims;
    range_box left = {box_empty(), box_empty()}, right = left;
    uint32_t m = b;
    /* invariant: prims[b, m) go left, prims[m, i) go right. Every element
     * is swapped and m advances by the side, without a branch on it (see
     * partition_below); the swap moves the registers already loaded, whole
     * 16-byte halves, which later loads can take straight from the stores. */
    for (uint32_t i = b; i < e; i++) {
        __m128 lo = prim_lo(&p[i]), hi = prim_hi(&p[i]), c = centroid2(lo, hi);
        uint32_t goes = goes_left(rule, c);
        __m128 mask = _mm_castsi128_ps(_mm_set1_epi32(-(int32_t)goes));
        side_grow(&left, mask, lo, hi, c, boxes);
        side_grow(&right, _mm_xor_ps(mask, _mm_castsi128_ps(_mm_set1_epi32(-1))), lo, hi, c, boxes);
        __m128 mlo = prim_lo(&p[m]), mhi = prim_hi(&p[m]);
        _mm_storeu_ps(p[m].lo, lo);
        _mm_storeu_ps(p[m].hi, hi);
        _mm_storeu_ps(p[i].lo, mlo);
        _mm_storeu_ps(p[i].hi, mhi);
        m += goes;
    }
    kids[0] = left;
    kids[1] = right;
    return m;
}

/* The partition of the splits that know nothing of the sides' boxes. */
static uint32_t partition(const bvh_builder *B, uint32_t b, uint32_t e, const split_rule *rule, range_box kids[2])
{
    return partition_sides(B, b, e, rule, kids, true);
}

/* The bins of the three axes: boxes and triangle counts. */
typedef struct {
    build_box box[3][BVH_SAH_BINS];
    uint32_t count[3][BVH_SAH_BINS];
} sah_bins;

static void bins_clear(sah_bins *s, uint32_t nbins)
{
    for (int k = 0; k < 3; k++)
        for (uint32_t j = 0; j < nbins; j++)
            s->box[k][j] = box_empty();
    memset(s->count, 0, sizeof s->count);
}

static void bins_merge(sah_bins *to, const sah_bins *from, uint32_t nbins)
{
    for (int k = 0; k < 3; k++)
        for (uint32_t j = 0; j < nbins; j++) {
            box_merge(&to->box[k][j], &from->box[k][j]);
            to->count[k][j] += from->count[k][j];
        }
}

static inline void bin_grow(sah_bins *s, int axis, uint32_t j, __m128 lo, __m128 hi)
{
    box_grow(&s->box[axis][j], lo, hi);
    s->count[axis][j]++;
}

static inline void bin_prim(sah_bins *s, const bin_grid *g, const bvh_prim *p)
{
    __m128 lo = prim_lo(p), hi = prim_hi(p);
    __m128i j = bin_of(g, centroid2(lo, hi));
    /* the three axes written out, their bins taken from the register */
    bin_grow(s, 0, (uint32_t)_mm_cvtsi128_si32(j), lo, hi);
    bin_grow(s, 1, (uint32_t)_mm_cvtsi128_si32(_mm_shuffle_epi32(j, _MM_SHUFFLE(1, 1, 1, 1))), lo, hi);
    bin_grow(s, 2, (uint32_t)_mm_cvtsi128_si32(_mm_shuffle_epi32(j, _MM_SHUFFLE(2, 2, 2, 2))), lo, hi);
}

/* Bins prims[b, e) into s, cleared: the build's hottest loop. The three
 * axes' bins come from one SSE computation and the reference is loaded once
 * for the three bins it grows. A node of BVH_BIN_PAIR_TRIS or more bins
 * alternate references into two sets, merged at the end (the same bins:
 * min, max and counts do not depend on the order). Each update of a bin
 * reads what the one before wrote, so references that fall in one bin wait
 * on each other; they do that on a wall's or floor's triangles, whose
 * centroids share a coordinate, and on the mesh's runs of neighbours. Two
 * sets halve those chains. 1 thread, median of 15 builds pinned to a core,
 * four rounds alternating with the parent: sponza 21.5-24.3 -> 19.0-21.8 ms,
 * bunny 21.8-24.7 -> 20.8-24.1, dragon (three rounds of 5) 373-377 -> 325-351.
 * Written as a loop over an array of sets (four, or two), it measured
 * slower than the parent; written out, as here, faster. */
static void bins_fill(sah_bins *s, const bin_grid *g, const bvh_prim *p, uint32_t b, uint32_t e)
{
    bins_clear(s, g->nbins);
    if (e - b < BVH_BIN_PAIR_TRIS) {
        for (uint32_t i = b; i < e; i++)
            bin_prim(s, g, &p[i]);
        return;
    }
    sah_bins other;
    bins_clear(&other, g->nbins);
    uint32_t i = b;
    for (; i + 1 < e; i += 2) {
        bin_prim(s, g, &p[i]);
        bin_prim(&other, g, &p[i + 1]);
    }
    if (i < e)
        bin_prim(s, g, &p[i]);
    bins_merge(s, &other, g->nbins);
}

/* One part of a parallel binning: prims[b, e) into its own bins. */
typedef struct {
    const bvh_builder *B;
    const bin_grid *grid;
    uint32_t b, e;
    sah_bins bins;
} bin_part;

/* Part number `i` of the array `parts`. */
static void bin_part_run(void *parts, uint32_t i)
{
    bin_part *p = (bin_part *)parts + i;
    bins_fill(&p->bins, p->grid, p->B->prims, p->b, p->e);
}

/* Bins prims[b, e) into s. A large node at the top levels bins in parallel
 * parts, merged in order: the same bins as one pass would fill (serially
 * when the parts' memory cannot be had). */
static void bins_build(const bvh_builder *B, uint32_t b, uint32_t e, uint32_t depth, const bin_grid *g, sah_bins *s)
{
    uint32_t nparts = B->run->threads < BVH_BIN_PARTS ? B->run->threads : BVH_BIN_PARTS;
    bin_part *parts = NULL;
    if (nparts > 1 && depth < B->fork_depth && e - b >= BVH_PARALLEL_PASS_TRIS)
        parts = malloc(nparts * sizeof *parts);
    if (parts == NULL) {
        bins_fill(s, g, B->prims, b, e);
        return;
    }
    for (uint32_t i = 0; i < nparts; i++) {
        parts[i].B = B;
        parts[i].grid = g;
        parts[i].b = b + (uint32_t)((uint64_t)(e - b) * i / nparts);
        parts[i].e = b + (uint32_t)((uint64_t)(e - b) * (i + 1) / nparts);
    }
    accel_parallel(B->run, nparts, bin_part_run, parts);
    *s = parts[0].bins;
    for (uint32_t i = 1; i < nparts; i++)
        bins_merge(s, &parts[i].bins, g->nbins);
    free(parts);
}

/* The cheapest plane of one axis' bins by the sum A(l) N(l) + A(r) N(r):
 * sets *plane (the plane after bin *plane) and returns the sum, or INFINITY
 * if no plane has triangles on both sides. Planes after an empty bin split
 * the triangles like the plane before it, so only the others are tried. */
static float sah_sweep(const build_box *box, const uint32_t *count, uint32_t nbins, uint32_t *plane)
{
    /* right[j], right_count[j]: A N and N of the bins after plane j */
    float right[BVH_SAH_BINS];
    uint32_t right_count[BVH_SAH_BINS];
    build_box acc = box_empty();
    uint32_t n = 0;
    float an = 0.0f;
    for (uint32_t j = nbins - 1; j > 0; j--) {
        if (count[j] > 0) {
            box_merge(&acc, &box[j]);
            n += count[j];
            an = box_area(&acc) * (float)n;
        }
        right[j - 1] = an;
        right_count[j - 1] = n;
    }
    float best = INFINITY;
    acc = box_empty();
    n = 0;
    for (uint32_t j = 0; j + 1 < nbins; j++) {
        if (count[j] == 0)
            continue;
        box_merge(&acc, &box[j]);
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

/* Whether a node of n triangles and surface `area` stays a leaf: its best
 * split, whose children's A N add up to `split_an`, costs no less than
 * testing all its triangles, and it is small enough to be a leaf. */
static bool sah_stays_leaf(const bvh_builder *B, float area, double split_an, uint32_t n)
{
    double split_cost = (double)B->cost_traverse * area + (double)B->cost_intersect * split_an;
    double leaf_cost = (double)B->cost_intersect * area * (double)n;
    return !(split_cost < leaf_cost) && n <= B->max_leaf;
}

/* Binned SAH over the three axes of prims[b, e), whose box has area `area`
 * and whose centroids span cbox (not a single point). Returns whether
 * splitting at the cheapest plane beats a leaf, by the cost model
 * Ct A(n) + Ci (A(l) N(l) + A(r) N(r)) against Ci A(n) N(n) (the usual one
 * multiplied through by A(n), so flat nodes need no division), and if so
 * partitions there (*m: where the right side starts; b or e when no plane
 * has triangles on both sides). A node gets a bin per BVH_SAH_TRIS_PER_BIN
 * triangles, between BVH_SAH_MIN_BINS and BVH_SAH_BINS: clearing and
 * sweeping a bin costs about as much as binning a few triangles, so small
 * nodes given a bin per triangle spent most of their time on empty bins. */
static bool sah_split(const bvh_builder *B, uint32_t b, uint32_t e, uint32_t depth, float area,
                      const build_box *cbox, range_box kids[2], uint32_t *m)
{
    uint32_t n = e - b;
    bin_grid g;
    uint32_t nbins = n / BVH_SAH_TRIS_PER_BIN;
    g.nbins = nbins < BVH_SAH_MIN_BINS ? BVH_SAH_MIN_BINS : nbins > BVH_SAH_BINS ? BVH_SAH_BINS : nbins;
    float lo[4], hi[4], scale[4] = {0.0f, 0.0f, 0.0f, 0.0f};
    _mm_storeu_ps(lo, cbox->lo);
    _mm_storeu_ps(hi, cbox->hi);
    for (int k = 0; k < 3; k++) {
        float ext = hi[k] - lo[k];
        scale[k] = ext > 0.0f ? (float)g.nbins / ext : 0.0f;
    }
    g.lo = cbox->lo;
    g.scale = _mm_loadu_ps(scale);
    g.last = _mm_set1_ps((float)(g.nbins - 1));
    sah_bins bins;
    bins_build(B, b, e, depth, &g, &bins);
    float best = INFINITY;
    split_rule rule = {0, true, &g, _mm_setzero_si128(), _mm_setzero_ps()};
    uint32_t best_plane = 0;
    for (int k = 0; k < 3; k++) {
        uint32_t plane = 0;
        float cost = scale[k] > 0.0f ? sah_sweep(bins.box[k], bins.count[k], g.nbins, &plane) : INFINITY;
        if (cost < best) {
            best = cost;
            best_plane = plane;
            rule.axis = k;
            rule.limit_bin = _mm_set1_epi32((int)plane + 1);
        }
    }
    if (sah_stays_leaf(B, area, best, n))
        return false;
    if (best == INFINITY) {
        *m = b;
        return true;
    }
    /* The sides are the bins' on either side of the plane, so their boxes
     * are the unions of those bins' boxes, to the bit (min and max do not
     * round): the partition computes only the centroid boxes, which the
     * bins do not keep (dragon, 1 thread: 357-368 -> 348 ms a build, 3 runs). */
    *m = partition_sides(B, b, e, &rule, kids, false);
    uint32_t costed_left = 0;
    for (uint32_t j = 0; j < g.nbins; j++) {
        box_merge(&kids[j > best_plane].box, &bins.box[rule.axis][j]);
        costed_left += j <= best_plane ? bins.count[rule.axis][j] : 0;
    }
    /* the split made is the one costed: as many go left as the bins counted */
    assert(*m - b == costed_left);
    (void)costed_left;
    return true;
}

/* A float's bits as an integer that orders as the float does (a negative
 * float's magnitude bits flipped), NaNs included in some fixed place, so
 * that sorting by it is a total order whatever the input. */
static inline int32_t float_order_key(float f)
{
    uint32_t u;
    memcpy(&u, &f, sizeof u);
    u ^= ((uint32_t)0 - (u >> 31)) >> 1; /* a negative float: its magnitude bits flipped */
    int32_t key;
    memcpy(&key, &u, sizeof key);
    return key;
}

/* order[0, n): 0 .. n - 1 by key, ties by place (n <= BVH_SAH_EXACT_TRIS,
 * key padded to a multiple of 4). Each one's place in the order is the
 * number of keys below its own plus the equal ones before it, counted four
 * at a time: no branch on the data, where an insertion sort's mispredicted
 * branches took a third of sah_split_small's time. */
static void small_order(const int32_t *key, uint32_t n, uint8_t *order)
{
    __m128i k4[BVH_SAH_EXACT_TRIS / 4];
    uint32_t quads = (n + 3) / 4, live = ((uint32_t)1 << n) - 1; /* the padding is not counted */
    for (uint32_t q = 0; q < quads; q++)
        k4[q] = _mm_loadu_si128((const __m128i *)(const void *)(key + 4 * q));
    for (uint32_t i = 0; i < n; i++) {
        __m128i ki = _mm_set1_epi32(key[i]);
        uint32_t below = 0, equal = 0;
        for (uint32_t q = 0; q < quads; q++) {
            below |= (uint32_t)_mm_movemask_ps(_mm_castsi128_ps(_mm_cmplt_epi32(k4[q], ki))) << (4 * q);
            equal |= (uint32_t)_mm_movemask_ps(_mm_castsi128_ps(_mm_cmpeq_epi32(k4[q], ki))) << (4 * q);
        }
        uint32_t before = ((uint32_t)1 << i) - 1;
        order[__builtin_popcount(below & live) + __builtin_popcount(equal & before)] = (uint8_t)i;
    }
}

/* The SAH for a node of at most BVH_SAH_EXACT_TRIS triangles: every plane
 * between two neighbours in centroid order on each axis (the full object
 * SAH, which bins only approximate), by the same cost model as sah_split's,
 * and partitioning there (*m: where the right side starts, b when no plane
 * has a finite cost). Near the leaves, where most nodes are, this costs less
 * than clearing and sweeping bins, and finds planes at least as cheap.
 * only_axis >= 0 limits the search to that axis (see choose_split). */
static bool sah_split_small(const bvh_builder *B, uint32_t b, uint32_t e, float area, int only_axis,
                            range_box kids[2], uint32_t *m)
{
    uint32_t n = e - b;
    bvh_prim *p = B->prims + b;
    assert(n <= BVH_SAH_EXACT_TRIS);
    /* order[k]: the node's references by centroid on axis k, ties by place */
    uint8_t order[3][BVH_SAH_EXACT_TRIS];
    int32_t key[BVH_SAH_EXACT_TRIS] = {0};
    float right[BVH_SAH_EXACT_TRIS];
    float best = INFINITY;
    int best_axis = 0;
    uint32_t best_count = 0;
    int first_axis = only_axis >= 0 ? only_axis : 0, end_axis = only_axis >= 0 ? only_axis + 1 : 3;
    for (int k = first_axis; k < end_axis; k++) {
        for (uint32_t i = 0; i < n; i++)
            key[i] = float_order_key(p[i].lo[k] + p[i].hi[k]);
        small_order(key, n, order[k]);
        /* right[i]: A N of the references from the i-th on */
        build_box acc = box_empty();
        for (uint32_t i = n - 1; i > 0; i--) {
            box_grow(&acc, prim_lo(&p[order[k][i]]), prim_hi(&p[order[k][i]]));
            right[i] = box_area(&acc) * (float)(n - i);
        }
        acc = box_empty();
        for (uint32_t i = 1; i < n; i++) {
            box_grow(&acc, prim_lo(&p[order[k][i - 1]]), prim_hi(&p[order[k][i - 1]]));
            float cost = box_area(&acc) * (float)i + right[i];
            if (cost < best) {
                best = cost;
                best_axis = k;
                best_count = i;
            }
        }
    }
    if (sah_stays_leaf(B, area, best, n))
        return false;
    if (best == INFINITY) {
        *m = b;
        return true;
    }
    bvh_prim sorted[BVH_SAH_EXACT_TRIS];
    for (uint32_t i = 0; i < n; i++)
        sorted[i] = p[order[best_axis][i]];
    memcpy(p, sorted, n * sizeof *p);
    *m = split_at(B, b, b + best_count, e, kids);
    return true;
}

/* The SAH decision for a node of two triangles whose centroids differ: the
 * only split puts one on each side, which binning on any axis where they
 * differ finds too; it is taken by the same cost model as sah_split's.
 * Returns the split index (b + 1, the triangle with the smaller centroid on
 * the first such axis first) or 0 for a leaf. Two triangles is the commonest
 * node size near the leaves, and clearing and sweeping bins for them cost
 * more than their binning. */
static uint32_t sah_split_pair(const bvh_builder *B, uint32_t b, float area, const build_box *cbox,
                               range_box kids[2])
{
    range_bounds(B, b, b + 1, &kids[0]);
    range_bounds(B, b + 1, b + 2, &kids[1]);
    if (sah_stays_leaf(B, area, (double)box_area(&kids[0].box) + (double)box_area(&kids[1].box), 2))
        return 0;
    float lo[4], hi[4];
    _mm_storeu_ps(lo, cbox->lo);
    _mm_storeu_ps(hi, cbox->hi);
    int axis = hi[0] > lo[0] ? 0 : hi[1] > lo[1] ? 1 : 2;
    if (centroid_axis(B, b + 1, axis) < centroid_axis(B, b, axis)) {
        prim_swap(B->prims, b, b + 1);
        range_box t = kids[0];
        kids[0] = kids[1];
        kids[1] = t;
    }
    return b + 1;
}

/* Whether a node of at most one pack of triangles and surface `area`,
 * which the SAH would split into kids, stays a leaf all the same, for the
 * wide tree rays traverse (bvh_wide.c): its whole leaf costs one pack test
 * over its area, two leaf children a pack test each over their areas, so
 * when these add up to at least its own the collapse merges the children
 * back (it could keep them only if splitting them further cost less,
 * which measured never: the wide trees' SAH costs are unchanged to four
 * digits on bunny, castle, sponza and dragon). The levels below are then
 * not built only to be undone: 12-16% of the SAH build's time. */
static bool sah_pack_stays_leaf(const bvh_builder *B, float area, uint32_t n, const range_box kids[2])
{
    return n <= BVH_WIDTH && n <= B->max_leaf && box_area(&kids[0].box) + box_area(&kids[1].box) >= area;
}

/* Where the node over prims[b, e) at depth `depth`, with boxes r, splits:
 * the index in (b, e) where its right child's references start, or 0 (never
 * such an index) for a leaf. Reorders prims[b, e) to match and sets the
 * children's boxes. */
static uint32_t choose_split(const bvh_builder *B, uint32_t b, uint32_t e, uint32_t depth, float area,
                             const range_box *r, range_box kids[2])
{
    uint32_t n = e - b;
    float lo[4], hi[4];
    _mm_storeu_ps(lo, r->cbox.lo);
    _mm_storeu_ps(hi, r->cbox.hi);
    arbor_vec3 ext = vec3(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]);
    if (ext.x <= 0.0f && ext.y <= 0.0f && ext.z <= 0.0f) /* one centroid: any halving is as good */
        return n > B->max_leaf ? split_at(B, b, b + n / 2, e, kids) : 0;
    int axis = vec3_max_axis(ext);
    split_rule rule = {axis, false, NULL, _mm_setzero_si128(), _mm_set1_ps(0.5f * (lo[axis] + hi[axis]))};
    /* Past this depth only median splits are sure to end by BVH_MAX_DEPTH - 1:
     * each halves the count, so n triangles need ceil(log2 n) more levels. */
    if (depth + 1 + ceil_log2(n) > BVH_MAX_DEPTH - 1)
        return split_median(B, b, e, axis, kids);
    uint32_t m;
    switch (B->builder) {
    case ARBOR_BUILD_SAH:
        /* A node of at most one pack searches only the longest axis of its
         * centroids: in the wide tree it becomes one pack or two slots of
         * a wide node, whose cost hardly depends on the plane, and one
         * axis is a third of the work. Against all three, `arbord stats
         * --accel bvh --builder sah --threads 1`: the wide trees' SAH cost
         * the same to four digits on bunny, dragon, castle, galleon and
         * f-16 (sponza 18.66 -> 18.67), builds 8-12% faster (dragon 376 ->
         * 345 ms, bunny 22.6 -> 20.0); the binary tree's 0.2-0.9% dearer.
         * Extending it to 16 triangles made the wide trees up to 1.6%
         * dearer. */
        if (n == 2)
            m = sah_split_pair(B, b, area, &r->cbox, kids);
        else if (!(n <= BVH_SAH_EXACT_TRIS
                       ? sah_split_small(B, b, e, area, n <= BVH_WIDTH ? axis : -1, kids, &m)
                       : sah_split(B, b, e, depth, area, &r->cbox, kids, &m)))
            return 0;
        if (m == 0 || (m != b && m != e && sah_pack_stays_leaf(B, area, n, kids)))
            return 0;
        break;
    case ARBOR_BUILD_SPATIAL:
        if (n <= B->max_leaf)
            return 0;
        m = partition(B, b, e, &rule, kids);
        break;
    case ARBOR_BUILD_MEAN:
        if (n <= B->max_leaf)
            return 0;
        rule.limit_pos = _mm_set1_ps(centroid_mean(B, b, e, axis));
        m = partition(B, b, e, &rule, kids);
        break;
    case ARBOR_BUILD_MEDIAN:
    default:
        if (n <= B->max_leaf)
            return 0;
        return split_median(B, b, e, axis, kids);
    }
    /* a plane with every centroid on one side (a mean that rounds to the
     * smallest value, or bins of one axis only): fall back to the median */
    if (m == b || m == e)
        m = split_median(B, b, e, axis, kids);
    return m;
}

static uint32_t build_subtree(const bvh_builder *B, uint32_t s, uint32_t b, uint32_t e, uint32_t depth,
                              const range_box *r, bvh_tally *tally);

typedef struct {
    const bvh_builder *B;
    uint32_t slot, begin, end, depth;
    range_box bounds;
    bvh_tally tally;
    uint32_t used;
} build_task;

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

/* The two children of a forking node: side[0] the left, side[1] the
 * right; the loop's index i (indices are claimed in ascending order) builds
 * side[i ^ right_first]. The right side's slot is chosen when it is
 * claimed: next to the left subtree if that is finished, else the slot the
 * left's worst case leaves free. left_nodes: the left subtree's node count,
 * released by its task once built (0 before: a subtree has a node at
 * least); acquired by the right's, which may then reuse slots the left's
 * own forks wrote before they compacted. */
typedef struct {
    build_task side[2];
    int right_first;
    atomic_uint left_nodes;
} fork_pair;

/* Index `i` of the fork_pair `pair`. */
static void fork_pair_run(void *pair, uint32_t i)
{
    fork_pair *f = pair;
    build_task *t = &f->side[i ^ (uint32_t)f->right_first];
    bool left = t == &f->side[0];
    uint32_t left_nodes = left ? 0 : atomic_load_explicit(&f->left_nodes, memory_order_acquire);
    if (left_nodes > 0)
        t->slot = f->side[0].slot + left_nodes;
    t->used = build_subtree(t->B, t->slot, t->begin, t->end, t->depth, &t->bounds, &t->tally);
    if (left)
        atomic_store_explicit(&f->left_nodes, t->used, memory_order_release);
}

/* Builds the children of inner node s over prims[b, m) and prims[m, e), with
 * boxes kids, as a parallel pair; returns the nodes they used. */
static uint32_t build_children_parallel(const bvh_builder *B, uint32_t s, uint32_t b, uint32_t m, uint32_t e,
                                        uint32_t depth, const range_box kids[2], bvh_tally *tally)
{
    /* The left subtree uses at most 2 (m - b) - 1 slots. When the budget
     * has a thread spare, the larger side is claimed first, normally by the
     * calling thread: it then waits at the join only for the smaller, whose
     * helper goes back to the pool when done, free to take the larger
     * side's own forks (a caller done first would wait idle instead).
     * Median of 5 builds at 2 threads: sponza 14.4 -> 13.3 ms, bunny 15.3
     * -> 15.0, dragon 220 -> 218. When it has none, the caller most likely
     * builds both, so the left goes first and the right is then built in
     * place. (A right subtree built before the left is finished is moved
     * next to it afterwards; before 862024e every fork's was, at 2 threads
     * 1.6 times the tree's nodes, mostly onto fresh pages: 7% of bunny's
     * build, 6.5% of dragon's.) The hint counts the build's threads, not
     * the pool's idle workers: on a pool busy with other work a larger
     * right side may still go first on one thread, and be moved. */
    bool spare = arbor_pool_budget_spare(&B->run->budget) > 0;
    fork_pair f;
    f.side[0] = (build_task){B, s + 1, b, m, depth + 1, kids[0], {0}, 0};
    f.side[1] = (build_task){B, s + 2 * (m - b), m, e, depth + 1, kids[1], {0}, 0};
    f.right_first = spare && e - m > m - b;
    atomic_init(&f.left_nodes, 0);
    accel_parallel(B->run, 2, fork_pair_run, &f);
    const build_task *left = &f.side[0], *right = &f.side[1];
    uint32_t right_slot = s + 1 + left->used;
    if (right_slot != right->slot)
        move_subtree(B->nodes, right->slot, right_slot, right->used);
    B->nodes[s].index = right_slot;
    tally_add(tally, &left->tally);
    tally_add(tally, &right->tally);
    return left->used + right->used;
}

/* Builds the subtree over prims[b, e), whose boxes are r, with its root in
 * slot s at `depth`, in depth-first order from s; returns the number of
 * nodes it used (at most 2 (e - b) - 1). */
static uint32_t build_subtree(const bvh_builder *B, uint32_t s, uint32_t b, uint32_t e, uint32_t depth,
                              const range_box *r, bvh_tally *tally)
{
    bvh_node *node = &B->nodes[s];
    float lo[4], hi[4];
    _mm_storeu_ps(lo, r->box.lo);
    _mm_storeu_ps(hi, r->box.hi);
    for (int a = 0; a < 3; a++) {
        node->bounds[a] = lo[a];
        node->bounds[3 + a] = hi[a];
    }
    float area = box_area(&r->box);
    range_box kids[2];
    uint32_t m = e - b > 1 && depth < B->max_depth && !accel_stop(B->run)
                     ? choose_split(B, b, e, depth, area, r, kids)
                     : 0;
    if (m == 0) {
        node->index = b;
        node->count = e - b;
        for (uint32_t i = b; i < e; i++)
            B->tri_index[i] = B->prims[i].tri;
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
        return 1 + build_children_parallel(B, s, b, m, e, depth, kids, tally);
    uint32_t left = build_subtree(B, s + 1, b, m, depth + 1, &kids[0], tally);
    node->index = s + 1 + left;
    return 1 + left + build_subtree(B, s + 1 + left, m, e, depth + 1, &kids[1], tally);
}

static void tally_to_stats(const bvh_tally *t, double root_area, arbor_tree_stats *s)
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
    s->sah_cost = root_area > 0.0 ? (t->inner_area + t->leaf_area) / root_area : (double)(t->inner + t->refs);
}

/* The references of mesh triangles [b, e) and their boxes: a linear pass,
 * which large meshes split in two parallel halves. */
typedef struct {
    const arbor_mesh *m;
    bvh_prim *prims;
    uint32_t b, e;
    range_box bounds;
} prim_pass;

/* Pass number `half` of the array `passes`. */
static void make_prims(void *passes, uint32_t half)
{
    prim_pass *p = (prim_pass *)passes + half;
    arbor_prefault(&p->prims[p->b], (size_t)(p->e - p->b) * sizeof *p->prims); /* fresh memory (bvh_wide.c, fill_packs) */
    p->bounds.box = p->bounds.cbox = box_empty();
    for (uint32_t t = p->b; t < p->e; t++) {
        arbor_vec3 v[3];
        arbor_mesh_tri(p->m, t, &v[0], &v[1], &v[2]);
        bvh_prim *prim = &p->prims[t];
        prim->lo[0] = arbor_minf(arbor_minf(v[0].x, v[1].x), v[2].x);
        prim->lo[1] = arbor_minf(arbor_minf(v[0].y, v[1].y), v[2].y);
        prim->lo[2] = arbor_minf(arbor_minf(v[0].z, v[1].z), v[2].z);
        prim->hi[0] = arbor_maxf(arbor_maxf(v[0].x, v[1].x), v[2].x);
        prim->hi[1] = arbor_maxf(arbor_maxf(v[0].y, v[1].y), v[2].y);
        prim->hi[2] = arbor_maxf(arbor_maxf(v[0].z, v[1].z), v[2].z);
        prim->tri = t;
        prim->zero = 0.0f;
        __m128 lo = prim_lo(prim), hi = prim_hi(prim), c = centroid2(lo, hi);
        box_grow(&p->bounds.box, lo, hi);
        box_grow(&p->bounds.cbox, c, c);
    }
}

/* Makes every reference, in two parallel halves when parallel; returns the
 * root's boxes. */
static range_box prims_make(accel_run *run, const arbor_mesh *m, bvh_prim *prims, bool parallel)
{
    prim_pass halves[2] = {{.m = m, .prims = prims, .b = 0, .e = m->ntris / 2},
                           {.m = m, .prims = prims, .b = m->ntris / 2, .e = m->ntris}};
    prim_pass whole = {.m = m, .prims = prims, .b = 0, .e = m->ntris};
    accel_parallel(run, parallel ? 2 : 1, make_prims, parallel ? halves : &whole);
    if (!parallel)
        return whole.bounds;
    box_merge(&halves[0].bounds.box, &halves[1].bounds.box);
    box_merge(&halves[0].bounds.cbox, &halves[1].bounds.cbox);
    return halves[0].bounds;
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

bool bvh_build_binary(bvh_tree *tree, const arbor_mesh *m, const arbor_build_opts *o, accel_run *run,
                      arbor_tree_stats *stats, arbor_err *e)
{
    uint32_t n = m->ntris;
    if (n > UINT32_MAX / 2)
        return arbor_fail(e, ARBOR_ERR_INVALID, "bvh: %u triangles is more than node indices can address", n);
    tree->ntris = n;
    if (n == 0) {
        bvh_tally none = {0};
        tally_to_stats(&none, 0.0, stats);
        return true;
    }
    bvh_builder B;
    builder_init(&B, o, run);
    bvh_prim *prims = bvh_alloc_aligned(n * sizeof *prims);
    bvh_node *scratch = bvh_alloc_aligned((2 * (size_t)n - 1) * sizeof(bvh_node));
    tree->tri_index = malloc(n * sizeof *tree->tri_index);
    if (prims == NULL || scratch == NULL || tree->tri_index == NULL)
        goto nomem;
    bool parallel = B.fork_depth > 0 && n >= BVH_PARALLEL_PASS_TRIS;
    range_box root = prims_make(run, m, prims, parallel);
    B.prims = prims;
    B.tri_index = tree->tri_index;
    B.nodes = scratch;
    bvh_tally tally = {0};
    tree->nnodes = build_subtree(&B, 0, 0, n, 0, &root, &tally);
    free(prims);
    prims = NULL;
    if (accel_stop(run))
        goto fail; /* the tree was cut short */
    tree->nodes = bvh_shrink_aligned(scratch, tree->nnodes * sizeof(bvh_node));
    scratch = NULL;
    if (tree->nodes == NULL)
        goto nomem;
    tally_to_stats(&tally, aabb_area(bvh_node_box(&tree->nodes[0])), stats);
    return true;
nomem:
    arbor_fail(e, ARBOR_ERR_NOMEM, "bvh: out of memory building over %u triangles", n);
fail:
    free(prims);
    free(scratch);
    return false;
}
