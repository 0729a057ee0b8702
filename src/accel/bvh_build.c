/*
 * bvh_build.c - the BVH builders: spatial median, object median, object mean
 * and binned SAH, one top-down recursion that differs only in where it
 * splits a node (choose_split). The splits themselves are bvh_split.c's
 * (partitions, the simple builders' planes) and bvh_sah.c's (the SAH's);
 * what the three files share is bvh_builder.h.
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
 *            (bvh_sah_pack_stays_leaf). The partition then sends each triangle to
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
#include <stdlib.h>
#include <string.h>

#include "arbor/sys.h"
#include "bvh_builder.h"

/* Defaults (arbor_build_opts fields that are 0). The simple builders split
 * down to BVH_SIMPLE_LEAF triangles; the SAH builder decides by cost but
 * never leaves more than BVH_SAH_LEAF in a leaf. Unit costs for traversal
 * and intersection are what the sah_cost statistic uses too. */
#define BVH_SIMPLE_LEAF 4
#define BVH_SAH_LEAF 8
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

/* What a subtree's build adds to the statistics; parallel tasks each keep
 * their own and the parent adds them up after the join. */
typedef struct {
    uint64_t inner, leaves, refs, leaf_depth_sum;
    uint32_t max_depth;
    double inner_area, leaf_area;  /* sum of A(n) over inner nodes; of A(l) N(l) over leaves */
} bvh_tally;

static uint32_t ceil_log2(uint32_t n)
{
    uint32_t k = 0;
    while (k < 32 && ((uint64_t)1 << k) < n)
        k++;
    return k;
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
        return n > B->max_leaf ? bvh_split_at(B, b, b + n / 2, e, kids) : 0;
    int axis = vec3_max_axis(ext);
    split_rule rule = {axis, false, NULL, _mm_setzero_si128(), _mm_set1_ps(0.5f * (lo[axis] + hi[axis]))};
    /* Past this depth only median splits are sure to end by BVH_MAX_DEPTH - 1:
     * each halves the count, so n triangles need ceil(log2 n) more levels. */
    if (depth + 1 + ceil_log2(n) > BVH_MAX_DEPTH - 1)
        return bvh_split_median(B, b, e, axis, kids);
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
            m = bvh_sah_split_pair(B, b, area, &r->cbox, kids);
        else if (!(n <= BVH_SAH_EXACT_TRIS
                       ? bvh_sah_split_small(B, b, e, area, n <= BVH_WIDTH ? axis : -1, kids, &m)
                       : bvh_sah_split(B, b, e, depth, area, &r->cbox, kids, &m)))
            return 0;
        if (m == 0 || (m != b && m != e && bvh_sah_pack_stays_leaf(B, area, n, kids)))
            return 0;
        break;
    case ARBOR_BUILD_SPATIAL:
        if (n <= B->max_leaf)
            return 0;
        m = bvh_partition(B, b, e, &rule, kids);
        break;
    case ARBOR_BUILD_MEAN:
        if (n <= B->max_leaf)
            return 0;
        rule.limit_pos = _mm_set1_ps(bvh_centroid_mean(B, b, e, axis));
        m = bvh_partition(B, b, e, &rule, kids);
        break;
    case ARBOR_BUILD_MEDIAN:
    default:
        if (n <= B->max_leaf)
            return 0;
        return bvh_split_median(B, b, e, axis, kids);
    }
    /* a plane with every centroid on one side (a mean that rounds to the
     * smallest value, or bins of one axis only): fall back to the median */
    if (m == b || m == e)
        m = bvh_split_median(B, b, e, axis, kids);
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
