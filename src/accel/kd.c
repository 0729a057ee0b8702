/*
 * kd.c - the k-d tree as accel.c sees it: the arbor_kd_ops table. The tree
 * and its invariants are described in kd_internal.h; building is in
 * kd_build.c and kd_sah.c, ray queries in kd_traverse.c (a traversal
 * kernel), checking in kd_validate.c; the walk over the nodes is here.
 */
#include "kd_internal.h"

/* Every node down to max_depth, depth first, with its cell. */
static void kd_walk_nodes(const void *impl, uint32_t max_depth, arbor_node_fn fn, void *user)
{
    const kd_tree *tree = impl;
    if (tree->nodes == NULL)
        return;
    struct {
        uint32_t node;
        kd_place place;
    } stack[KD_MAX_DEPTH + 2];
    int sp = 0;
    stack[sp].node = 0;
    stack[sp++].place = (kd_place){tree->bounds, 0};
    while (sp > 0) {
        sp--;
        uint32_t at = stack[sp].node;
        kd_place p = stack[sp].place;
        const kd_node *n = &tree->nodes[at];
        uint32_t axis = kd_node_kind(*n);
        arbor_node_info info = {p.cell, p.depth, axis == KD_LEAF, axis == KD_LEAF ? kd_node_high(*n) : 0, 0};
        if (!fn(user, &info))
            return;
        if (axis == KD_LEAF || p.depth == max_depth)
            continue;
        kd_place below, above;
        kd_child_cells(&p, axis, n->split, &below, &above);
        stack[sp].node = kd_node_high(*n);
        stack[sp++].place = above;
        stack[sp].node = at + 1;
        stack[sp++].place = below;
    }
}

const arbor_accel_ops arbor_kd_ops = {
    kd_build, {&kd_queries_sse2, &kd_queries_avx2}, kd_walk_nodes, kd_validate, kd_destroy,
};
