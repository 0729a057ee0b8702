/*
 * bvh.c - the bounding volume hierarchy as a tree kind: its arbor_accel_ops
 * table, the tree's memory and bytes, building it (the binary tree, then the
 * wide tree collapsed from it) and its validator. The layouts are described
 * in bvh_internal.h, the builders in bvh_build.c (with their splits in
 * bvh_split.c and bvh_sah.c, which only the builders call), the wide tree
 * in bvh_wide.c, its statistics in bvh_wide_stats.c and the traversal in
 * bvh_traverse.c; none of those four calls another, only this file calls
 * them.
 *
 * The validator walks the tree on its own, sharing nothing with the
 * builders but the node layout, and recounts every statistic from the walk,
 * so a builder that miscounts or misplaces anything is caught.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "bvh_internal.h"

static void bvh_tree_free(bvh_tree *t)
{
    if (t == NULL)
        return;
    free(t->nodes);
    free(t->tri_index);
    free(t->wide);
    free(t->packs);
    free(t);
}

/* The bytes both layouts hold, for arbor_tree_stats.bytes. */
static uint64_t bvh_tree_bytes(const bvh_tree *t)
{
    return (uint64_t)t->nnodes * sizeof(bvh_node) + (t->tri_index != NULL ? (uint64_t)t->ntris * sizeof(uint32_t) : 0) +
           bvh_wide_bytes(t);
}

/* Whether rays through a wide tree of that many bytes (nodes and packs)
 * prefetch the children they enter: from BVH_PREFETCH_MIN_BYTES on, unless
 * ARBOR_PREFETCH=0 or 1 in the environment says otherwise (for tests and
 * measurement; read at every build, as accel.c reads ARBOR_KERNEL). */
static bool bvh_prefetch_pick(uint64_t traversed_bytes)
{
    const char *force = getenv("ARBOR_PREFETCH");
    if (force != NULL && (strcmp(force, "0") == 0 || strcmp(force, "1") == 0))
        return force[0] == '1';
    return traversed_bytes >= BVH_PREFETCH_MIN_BYTES;
}

/* Builds the binary tree, collapses it into the wide tree rays traverse,
 * and fills the statistics of both (but build_ms). NULL when memory runs
 * out or the build is cancelled, e filled. */
static void *bvh_build(const arbor_mesh *m, const arbor_build_opts *o, accel_run *run, arbor_tree_stats *stats,
                       arbor_err *e)
{
    bvh_tree *t = calloc(1, sizeof *t);
    if (t == NULL) {
        arbor_fail(e, ARBOR_ERR_NOMEM, "bvh: out of memory");
        return NULL;
    }
    bool parallel = run->threads > 1 && m->ntris >= BVH_PARALLEL_PASS_TRIS;
    if (!bvh_build_binary(t, m, o, run, stats, e) || !bvh_wide_build(t, m, run, parallel, e)) {
        bvh_tree_free(t);
        return NULL;
    }
    t->prefetch = bvh_prefetch_pick(bvh_wide_bytes(t));
    stats->has_wide = t->nnodes > 0;
    if (stats->has_wide)
        bvh_wide_stats(t, &stats->wide);
    stats->binary_bytes = bvh_tree_bytes(t) - bvh_wide_bytes(t);
    if (o->drop_binary && t->nnodes > 0) {
        free(t->nodes);
        free(t->tri_index);
        t->nodes = NULL;
        t->tri_index = NULL;
        t->nnodes = 0;
        t->binary_dropped = true;
    }
    stats->bytes = bvh_tree_bytes(t);
    return t;
}

/* What the validating walk has seen so far. */
typedef struct {
    const bvh_tree *t;
    const arbor_mesh *m;
    arbor_err *e;
    uint8_t *seen;         /* per mesh triangle: found in a leaf */
    double root_area;
    uint32_t next_node;    /* depth-first order: the node the walk must meet next */
    uint32_t next_tri;     /* leaves cover leaf order [0, ntris) one after another */
    uint64_t inner, leaves, refs, leaf_depth_sum;
    uint32_t max_depth;
    double sah_cost;
} bvh_check;

/* Whether box is exactly the union: the builders take every box's corners
 * from its contents' by min and max, which do not round, so a box any
 * larger (still containing them) is a builder's error all the same. */
static bool box_is_union(const arbor_aabb *box, const arbor_aabb *u)
{
    return box->lo.x == u->lo.x && box->lo.y == u->lo.y && box->lo.z == u->lo.z && box->hi.x == u->hi.x &&
           box->hi.y == u->hi.y && box->hi.z == u->hi.z;
}

static bool check_leaf(bvh_check *k, uint32_t i, const bvh_node *n, const arbor_aabb *box)
{
    const bvh_tree *t = k->t;
    arbor_aabb tight = aabb_empty();
    if (n->index != k->next_tri || n->count > t->ntris - n->index)
        return arbor_fail(k->e, ARBOR_ERR_INVALID,
                          "bvh node %u: leaf triangles [%u, +%u) do not follow the previous leaf's (next is %u of %u)", i,
                          n->index, n->count, k->next_tri, t->ntris);
    k->next_tri += n->count;
    for (uint32_t j = n->index; j < n->index + n->count; j++) {
        uint32_t tri = t->tri_index[j];
        if (tri >= k->m->ntris)
            return arbor_fail(k->e, ARBOR_ERR_INVALID, "bvh node %u: triangle index %u out of range (%u triangles)", i,
                              tri, k->m->ntris);
        if (k->seen[tri])
            return arbor_fail(k->e, ARBOR_ERR_INVALID, "bvh node %u: triangle %u is in a second leaf", i, tri);
        k->seen[tri] = 1;
        arbor_aabb tri_box = arbor_mesh_tri_bounds(k->m, tri);
        if (!aabb_contains(*box, tri_box))
            return arbor_fail(k->e, ARBOR_ERR_INVALID, "bvh node %u: leaf box does not contain triangle %u", i, tri);
        tight = aabb_union(tight, tri_box);
    }
    if (n->count > 0 && !box_is_union(box, &tight))
        return arbor_fail(k->e, ARBOR_ERR_INVALID, "bvh node %u: leaf box is larger than its triangles' bounds", i);
    return true;
}

/* Checks node i at `depth` (inside `parent`, NULL for the root) and its subtree. */
static bool check_node(bvh_check *k, uint32_t i, const arbor_aabb *parent, uint32_t depth)
{
    const bvh_tree *t = k->t;
    if (i != k->next_node || i >= t->nnodes)
        return arbor_fail(k->e, ARBOR_ERR_INVALID, "bvh node %u: expected node %u of %u here in depth-first order", i,
                          k->next_node, t->nnodes);
    if (depth >= BVH_MAX_DEPTH)
        return arbor_fail(k->e, ARBOR_ERR_INVALID, "bvh node %u: depth %u exceeds the traversal stack", i, depth);
    k->next_node++;
    const bvh_node *n = &t->nodes[i];
    arbor_aabb box = bvh_node_box(n);
    if (parent != NULL && !aabb_contains(*parent, box))
        return arbor_fail(k->e, ARBOR_ERR_INVALID, "bvh node %u: box not inside its parent's", i);
    double ratio = bvh_area_ratio(aabb_area(box), k->root_area);
    if (n->count > 0) {
        k->leaves++;
        k->refs += n->count;
        k->leaf_depth_sum += depth;
        k->max_depth = depth > k->max_depth ? depth : k->max_depth;
        k->sah_cost += ratio * n->count;
        return check_leaf(k, i, n, &box);
    }
    k->inner++;
    k->sah_cost += ratio;
    if (!check_node(k, i + 1, &box, depth + 1))
        return false;
    if (n->index != k->next_node)
        return arbor_fail(k->e, ARBOR_ERR_INVALID, "bvh node %u: right child is %u, not %u right after the left subtree", i,
                          n->index, k->next_node);
    if (!check_node(k, n->index, &box, depth + 1))
        return false;
    arbor_aabb kids = aabb_union(bvh_node_box(&t->nodes[i + 1]), bvh_node_box(&t->nodes[n->index]));
    if (!box_is_union(&box, &kids))
        return arbor_fail(k->e, ARBOR_ERR_INVALID, "bvh node %u: box is larger than its children's union", i);
    return true;
}

static bool close_rel(double a, double b, double rel)
{
    return fabs(a - b) <= rel * fmax(fabs(a), fabs(b));
}

/* The statistics the walk counted against the ones the build reported. */
static bool check_stats(const bvh_check *k, const arbor_tree_stats *s, arbor_err *e)
{
    const bvh_tree *t = k->t;
    uint64_t nodes = k->inner + k->leaves;
    double mean_depth = k->leaves ? (double)k->leaf_depth_sum / (double)k->leaves : 0.0;
    double mean_tris = k->leaves ? (double)k->refs / (double)k->leaves : 0.0;
    uint64_t bytes = bvh_tree_bytes(t);
    if (s->nodes != nodes || s->leaves != k->leaves || s->empty_leaves != 0 || s->refs != k->refs)
        return arbor_fail(e, ARBOR_ERR_INVALID,
                          "bvh stats: nodes/leaves/empty/refs %llu/%llu/%llu/%llu, the walk counts %llu/%llu/0/%llu",
                          (unsigned long long)s->nodes, (unsigned long long)s->leaves,
                          (unsigned long long)s->empty_leaves, (unsigned long long)s->refs, (unsigned long long)nodes,
                          (unsigned long long)k->leaves, (unsigned long long)k->refs);
    if (s->max_depth != k->max_depth || !close_rel(s->mean_leaf_depth, mean_depth, 1e-9) ||
        !close_rel(s->mean_tris_per_leaf, mean_tris, 1e-9))
        return arbor_fail(e, ARBOR_ERR_INVALID,
                          "bvh stats: max depth %u, mean leaf depth %g, tris per leaf %g; the walk finds %u, %g, %g",
                          s->max_depth, s->mean_leaf_depth, s->mean_tris_per_leaf, k->max_depth, mean_depth, mean_tris);
    if (s->bytes != bytes || s->binary_bytes != bytes - bvh_wide_bytes(t))
        return arbor_fail(e, ARBOR_ERR_INVALID, "bvh stats: %llu bytes (%llu binary), the arrays hold %llu (%llu)",
                          (unsigned long long)s->bytes, (unsigned long long)s->binary_bytes,
                          (unsigned long long)bytes, (unsigned long long)(bytes - bvh_wide_bytes(t)));
    if (!close_rel(s->sah_cost, k->sah_cost, 1e-6))
        return arbor_fail(e, ARBOR_ERR_INVALID, "bvh stats: sah_cost %.9g, the walk finds %.9g", s->sah_cost,
                          k->sah_cost);
    return true;
}

static bool bvh_validate(const void *impl, const arbor_mesh *m, const arbor_tree_stats *s, arbor_err *e)
{
    const bvh_tree *t = impl;
    if (t->ntris != m->ntris)
        return arbor_fail(e, ARBOR_ERR_INVALID, "bvh: built over %u triangles, the mesh has %u", t->ntris, m->ntris);
    if (t->binary_dropped) /* the wide tree alone is left to check */
        return s->bytes == bvh_tree_bytes(t) ? bvh_wide_validate(t, m, e)
                                             : arbor_fail(e, ARBOR_ERR_INVALID, "bvh stats: %llu bytes, the arrays hold %llu",
                                                          (unsigned long long)s->bytes,
                                                          (unsigned long long)bvh_tree_bytes(t));
    if ((t->nnodes == 0) != (t->ntris == 0))
        return arbor_fail(e, ARBOR_ERR_INVALID, "bvh: %u nodes for %u triangles", t->nnodes, t->ntris);
    bvh_check k;
    memset(&k, 0, sizeof k);
    k.t = t;
    k.m = m;
    k.e = e;
    if (t->nnodes > 0) {
        k.seen = calloc(t->ntris, 1);
        if (k.seen == NULL)
            return arbor_fail(e, ARBOR_ERR_NOMEM, "bvh: out of memory validating");
        k.root_area = aabb_area(bvh_node_box(&t->nodes[0]));
        bool ok = check_node(&k, 0, NULL, 0);
        free(k.seen);
        if (!ok)
            return false;
        if (k.next_node != t->nnodes)
            return arbor_fail(e, ARBOR_ERR_INVALID, "bvh: the walk reaches %u of %u nodes", k.next_node, t->nnodes);
        /* each leaf triangle was new, and leaves cover all ntris slots: so every
         * mesh triangle is in exactly one leaf */
        if (k.next_tri != t->ntris)
            return arbor_fail(e, ARBOR_ERR_INVALID, "bvh: leaves hold %u of %u triangles", k.next_tri, t->ntris);
    }
    return check_stats(&k, s, e) && bvh_wide_validate(t, m, e);
}

static void bvh_destroy(void *impl)
{
    bvh_tree_free(impl);
}

/* The wide tree, the one rays traverse (its nodes are those
 * arbor_accel_intersect_traced visits), depth first, parents before
 * children, down to max_depth. A wide node's box is the union of its
 * children's; a leaf's is its lane's. */
void bvh_walk(const void *impl, uint32_t max_depth, arbor_node_fn fn, void *user)
{
    const bvh_tree *t = impl;
    if (t->nwide == 0)
        return;
    struct {
        uint32_t ref;
        arbor_aabb box;
        uint32_t depth;
    } stack[BVH_MAX_DEPTH * (BVH_WIDTH - 1) + 1];
    uint32_t sp = 0;
    stack[sp].ref = 0; /* the root */
    stack[sp].box = bvh_wide_box(&t->wide[0]);
    stack[sp++].depth = 0;
    while (sp > 0) {
        sp--;
        uint32_t ref = stack[sp].ref;
        uint32_t depth = stack[sp].depth;
        bool leaf = bvh_ref_is_leaf(ref);
        arbor_node_info info = {stack[sp].box, depth, leaf, leaf ? bvh_leaf_tris(t, bvh_ref_index(ref)) : 0, 0};
        if (!fn(user, &info))
            return;
        if (leaf || depth == max_depth)
            continue;
        /* the last child deepest, so the first comes out first */
        const bvh_wide_node *n = &t->wide[bvh_ref_index(ref)];
        for (int c = BVH_WIDTH - 1; c >= 0; c--)
            if (!bvh_slot_is_empty(n, c)) {
                stack[sp].ref = n->child[c];
                stack[sp].box = bvh_lane_box(n, c);
                stack[sp++].depth = depth + 1;
            }
    }
}

const arbor_accel_ops arbor_bvh_ops = {
    bvh_build, {&bvh_queries_sse2, &bvh_queries_avx2}, bvh_walk, bvh_validate, bvh_destroy,
};
