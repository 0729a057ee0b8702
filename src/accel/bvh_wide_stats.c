/*
 * bvh_wide_stats.c - the statistics of the wide tree, the layout rays
 * traverse (bvh_internal.h), beside those of the binary tree the builders
 * make: nodes, leaves, depth, triangles per leaf, bytes, and its SAH cost
 * under its own cost model.
 *
 * The cost model is the traversal's: visiting a wide node is one SIMD slab
 * test of all its children's boxes, and a leaf costs one SIMD triangle test
 * per pack; each such step counts 1:
 *
 *     sah_cost = sum over wide nodes  A(node) / A(root)
 *              + sum over leaves      A(leaf) / A(root) * packs(leaf)
 *
 * where a node's area is its box's, the union of its children's boxes (the
 * root's too). It is the binary formula with packs for triangles, so the
 * two layouts' costs compare: a collapse that pays adds up to less. The
 * collapse (bvh_wide.c) plans with the same formula but a pack at 0.75,
 * which measured faster; its trees cost about 0.1% more here than those
 * planned with 1 (bunny 9.73 against 9.72).
 */
#include "bvh_internal.h"

/* What the walk adds up. */
typedef struct {
    const bvh_tree *t;
    double root_area;
    arbor_layout_stats *s;
    double leaf_depths;
} wide_sums;

/* Adds wide node w, at depth, whose box is `box`, and its subtree. */
static void add_node(wide_sums *x, uint32_t w, arbor_aabb box, uint32_t depth)
{
    arbor_layout_stats *s = x->s;
    s->nodes++;
    s->sah_cost += bvh_area_ratio(aabb_area(box), x->root_area);
    if (depth > s->max_depth)
        s->max_depth = depth;
    const bvh_wide_node *n = &x->t->wide[w];
    for (int c = 0; c < BVH_WIDTH; c++) {
        uint32_t ref = n->child[c];
        if (bvh_slot_is_empty(n, c))
            continue;
        if (!bvh_ref_is_leaf(ref)) {
            add_node(x, bvh_ref_index(ref), bvh_lane_box(n, c), depth + 1);
            continue;
        }
        uint32_t tris = bvh_leaf_tris(x->t, bvh_ref_index(ref));
        s->nodes++;
        s->leaves++;
        s->refs += tris;
        s->sah_cost += bvh_area_ratio(aabb_area(bvh_lane_box(n, c)), x->root_area) * bvh_packs_for(tris);
        x->leaf_depths += depth + 1;
        if (depth + 1 > s->max_depth)
            s->max_depth = depth + 1;
    }
}

void bvh_wide_stats(const bvh_tree *t, arbor_layout_stats *s)
{
    *s = (arbor_layout_stats){0};
    s->bytes = bvh_wide_bytes(t);
    if (t->nwide == 0)
        return;
    arbor_aabb root = bvh_wide_box(&t->wide[0]);
    wide_sums x = {t, aabb_area(root), s, 0.0};
    add_node(&x, 0, root, 0);
    s->mean_leaf_depth = s->leaves > 0 ? x.leaf_depths / (double)s->leaves : 0.0;
    s->mean_tris_per_leaf = s->leaves > 0 ? (double)s->refs / (double)s->leaves : 0.0;
}
