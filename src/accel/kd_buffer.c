/*
 * kd_buffer.c - the node buffer the k-d recursion writes: nodes in
 * depth-first order, the leaves' triangle lists, and the sums behind the
 * tree's statistics, added up as nodes are written. A subtree built on
 * another thread goes to a buffer of its own, appended afterwards with its
 * child indices and list offsets rebased.
 */
#include <stdlib.h>
#include <string.h>

#include "kd_internal.h"

/* A cell's surface area in double precision, for the statistics' sums. */
static double kd_cell_area(const arbor_aabb *b)
{
    double x = (double)b->hi.x - b->lo.x, y = (double)b->hi.y - b->lo.y, z = (double)b->hi.z - b->lo.z;
    return x >= 0.0 && y >= 0.0 && z >= 0.0 ? 2.0 * (x * y + y * z + z * x) : 0.0;
}

/* Grows *array (of *cap elements of elem bytes) to hold need, doubling. */
static bool kd_grow(void **array, size_t *cap, size_t need, size_t elem)
{
    if (need <= *cap)
        return true;
    size_t cap2 = *cap ? 2 * *cap : 256;
    while (cap2 < need)
        cap2 *= 2;
    void *p = realloc(*array, cap2 * elem);
    if (p == NULL)
        return false;
    *array = p;
    *cap = cap2;
    return true;
}

/* Appends a node; NULL (and out->failed) when that is not possible. */
static kd_node *kd_buffer_node(kd_buffer *out)
{
    if (out->failed || out->nnodes + 1 >= KD_MAX_NODES ||
        !kd_grow((void **)&out->nodes, &out->node_cap, out->nnodes + 1, sizeof *out->nodes)) {
        out->failed = true;
        return NULL;
    }
    return &out->nodes[out->nnodes++];
}

/* Writes t as a leaf listing its triangles (those with a start or planar
 * event on axis 0: one each). */
void kd_emit_leaf(kd_buffer *out, const kd_task *t)
{
    uint32_t n = t->ntris;
    size_t first = out->nindex;
    if (n > 1 && (first + n > UINT32_MAX ||
                  !kd_grow((void **)&out->index, &out->index_cap, first + n, sizeof *out->index))) {
        out->failed = true;
        return;
    }
    kd_node *node = kd_buffer_node(out);
    if (node == NULL)
        return;
    node->first = (uint32_t)first;
    for (size_t i = 0; i < t->axis_begin[1]; i++) {
        kd_event e = t->events[i];
        if (kd_event_kind(e) == KD_EVENT_END)
            continue;
        if (n == 1)
            node->tri = kd_event_tri(e);
        else
            out->index[out->nindex++] = kd_event_tri(e);
    }
    node->flags = kd_node_flags(KD_LEAF, n);
    kd_sums *s = &out->sums;
    s->leaves++;
    s->empty_leaves += n == 0;
    s->refs += n;
    s->depth_sum += t->depth;
    if (t->depth > s->max_depth)
        s->max_depth = t->depth;
    s->leaf_area_tris += kd_cell_area(&t->cell) * n;
}

size_t kd_emit_inner(kd_buffer *out, const kd_task *t, kd_plane pl)
{
    kd_node *node = kd_buffer_node(out);
    if (node == NULL)
        return 0;
    node->split = pl.pos;
    node->flags = kd_node_flags((uint32_t)pl.axis, 0);
    out->sums.inner_area += kd_cell_area(&t->cell);
    return out->nnodes - 1;
}

void kd_set_above(kd_buffer *out, size_t inner)
{
    if (!out->failed)
        out->nodes[inner].flags |= kd_node_flags(0, (uint32_t)out->nnodes);
}

void kd_buffer_append(kd_buffer *out, const kd_buffer *from)
{
    size_t base = out->nnodes, first = out->nindex;
    if (out->failed || from->failed || base + from->nnodes >= KD_MAX_NODES || first + from->nindex > UINT32_MAX ||
        !kd_grow((void **)&out->nodes, &out->node_cap, base + from->nnodes, sizeof *out->nodes) ||
        !kd_grow((void **)&out->index, &out->index_cap, first + from->nindex, sizeof *out->index)) {
        out->failed = true;
        return;
    }
    for (size_t i = 0; i < from->nnodes; i++) {
        kd_node n = from->nodes[i];
        if (kd_node_kind(n) != KD_LEAF)
            n.flags += kd_node_flags(0, (uint32_t)base);
        else if (kd_node_high(n) > 1)
            n.first += (uint32_t)first;
        out->nodes[base + i] = n;
    }
    if (from->nindex > 0) /* both lists may still be NULL */
        memcpy(out->index + first, from->index, from->nindex * sizeof *out->index);
    out->nnodes += from->nnodes;
    out->nindex += from->nindex;
    kd_sums *s = &out->sums;
    const kd_sums *f = &from->sums;
    s->inner_area += f->inner_area;
    s->leaf_area_tris += f->leaf_area_tris;
    s->leaves += f->leaves;
    s->empty_leaves += f->empty_leaves;
    s->refs += f->refs;
    s->depth_sum += f->depth_sum;
    if (f->max_depth > s->max_depth)
        s->max_depth = f->max_depth;
}

void kd_fill_stats(const kd_tree *tree, const kd_sums *s, arbor_tree_stats *stats)
{
    uint64_t nonempty = s->leaves - s->empty_leaves;
    double root_area = kd_cell_area(&tree->bounds);
    stats->nodes = tree->nnodes;
    stats->leaves = s->leaves;
    stats->empty_leaves = s->empty_leaves;
    stats->max_depth = s->max_depth;
    stats->mean_leaf_depth = s->leaves ? (double)s->depth_sum / (double)s->leaves : 0.0;
    stats->mean_tris_per_leaf = nonempty ? (double)s->refs / (double)nonempty : 0.0;
    stats->refs = s->refs;
    stats->bytes = kd_tree_bytes(tree);
    stats->binary_bytes = stats->bytes;
    /* with no area at the root (all triangles on one line or point) every
     * cell counts as the root's, ratio 1, as the bvh does */
    stats->sah_cost = root_area > 0.0 ? (s->inner_area + s->leaf_area_tris) / root_area
                                      : (double)(tree->nnodes - s->leaves) + (double)s->refs;
}
