/*
 * bvh_sah.c - the SAH's splits of a BVH node (bvh_builder.h): binned SAH
 * (Wald, "On fast Construction of SAH-based Bounding Volume Hierarchies",
 * 2007) for large nodes, the exact object SAH for nodes of at most
 * BVH_SAH_EXACT_TRIS triangles, two triangles decided directly, and the
 * rule that keeps a node of one pack a leaf for the wide tree. A split
 * partitions by the bin it costed (bvh_split.c), so the split made is the
 * one costed. The cost model is sah_stays_leaf's, with the builder's weights
 * (B->cost_traverse, B->cost_intersect: bvh_build.c sets their defaults).
 */
#include <assert.h>
#include <stdlib.h>
#include <string.h>

#include "bvh_builder.h"

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
/* Top-level nodes of at least BVH_PARALLEL_PASS_TRIS (bvh_internal.h) bin
 * in at most this many parallel parts. */
#define BVH_BIN_PARTS 8
/* Nodes of at least this many triangles bin into two sets (bins_fill): in
 * smaller ones clearing and merging the second set would cost more than the
 * shorter chains save. 64 and 1024 measured the same as 256. */
#define BVH_BIN_PAIR_TRIS 256

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
bool bvh_sah_split(const bvh_builder *B, uint32_t b, uint32_t e, uint32_t depth, float area,
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
    *m = bvh_partition_centroids(B, b, e, &rule, kids);
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
 * branches took a third of bvh_sah_split_small's time. */
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
 * SAH, which bins only approximate), by the same cost model as bvh_sah_split's,
 * and partitioning there (*m: where the right side starts, b when no plane
 * has a finite cost). Near the leaves, where most nodes are, this costs less
 * than clearing and sweeping bins, and finds planes at least as cheap.
 * only_axis >= 0 limits the search to that axis (see choose_split in
 * bvh_build.c). */
bool bvh_sah_split_small(const bvh_builder *B, uint32_t b, uint32_t e, float area, int only_axis,
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
    *m = bvh_split_at(B, b, b + best_count, e, kids);
    return true;
}

/* The SAH decision for a node of two triangles whose centroids differ: the
 * only split puts one on each side, which binning on any axis where they
 * differ finds too; it is taken by the same cost model as bvh_sah_split's.
 * Returns the split index (b + 1, the triangle with the smaller centroid on
 * the first such axis first) or 0 for a leaf. Two triangles is the commonest
 * node size near the leaves, and clearing and sweeping bins for them cost
 * more than their binning. */
uint32_t bvh_sah_split_pair(const bvh_builder *B, uint32_t b, float area, const build_box *cbox,
                            range_box kids[2])
{
    bvh_range_bounds(B, b, b + 1, &kids[0]);
    bvh_range_bounds(B, b + 1, b + 2, &kids[1]);
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
bool bvh_sah_pack_stays_leaf(const bvh_builder *B, float area, uint32_t n, const range_box kids[2])
{
    return n <= BVH_WIDTH && n <= B->max_leaf && box_area(&kids[0].box) + box_area(&kids[1].box) >= area;
}
