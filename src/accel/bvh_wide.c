/*
 * bvh_wide.c - the wide tree rays traverse, collapsed from the binary tree
 * the builders make (layouts in bvh_internal.h), and its validator.
 *
 * Collapsing. Every binary subtree of at most BVH_WIDE_LEAF_TRIS triangles
 * becomes one leaf: one pack, tested in one SIMD step, costs about what a
 * single triangle does, so a split below that size only adds box tests. Any
 * other binary inner node becomes a wide node whose children are found by
 * opening, among its current children that are not leaves, the one with the
 * largest surface area (the one rays are likeliest to enter), until there are
 * BVH_WIDTH (the rule of Wald et al., "Getting Rid of Packets", 2008, and
 * Embree's BVH4). A subtree's triangles are contiguous in leaf order, so a
 * leaf is a range of tri_index whatever binary leaves it merges.
 *
 * Two passes over the same child choice: one counts wide nodes and packs so
 * that each array is allocated once, aligned, at its final size; the second
 * fills them depth first. Both recurse at most as deep as the binary tree.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "bvh_internal.h"

#define BVH_WIDE_LEAF_TRIS BVH_WIDTH

/* The range [*first, *first + count) of leaf order that binary node i covers:
 * from its leftmost leaf to its rightmost. */
static uint32_t subtree_tris(const bvh_tree *t, uint32_t i, uint32_t *first)
{
    uint32_t lo = i, hi = i;
    while (t->nodes[lo].count == 0)
        lo++;
    while (t->nodes[hi].count == 0)
        hi = t->nodes[hi].index;
    *first = t->nodes[lo].index;
    return t->nodes[hi].index + t->nodes[hi].count - *first;
}

static bool becomes_leaf(const bvh_tree *t, uint32_t i)
{
    uint32_t first;
    return t->nodes[i].count > 0 || subtree_tris(t, i, &first) <= BVH_WIDE_LEAF_TRIS;
}

static float node_area(const bvh_node *n)
{
    return aabb_area(bvh_node_box(n));
}

/* The binary nodes that become the children of the wide node made from
 * binary inner node i (which does not become a leaf); returns how many. */
static int wide_children(const bvh_tree *t, uint32_t i, uint32_t out[BVH_WIDTH])
{
    int n = 2;
    out[0] = i + 1;
    out[1] = t->nodes[i].index;
    while (n < BVH_WIDTH) {
        int open = -1;
        float best = -1.0f;
        for (int c = 0; c < n; c++) {
            float area = node_area(&t->nodes[out[c]]);
            if (!becomes_leaf(t, out[c]) && area > best) {
                best = area;
                open = c;
            }
        }
        if (open < 0)
            break;
        uint32_t inner = out[open];
        out[open] = inner + 1;
        out[n++] = t->nodes[inner].index;
    }
    return n;
}

static uint32_t packs_for(uint32_t tris)
{
    return (tris + BVH_WIDTH - 1) / BVH_WIDTH;
}

/* Counts the wide nodes and packs the subtree of binary node i becomes. */
static void count_subtree(const bvh_tree *t, uint32_t i, uint32_t *nwide, uint32_t *npacks)
{
    uint32_t first;
    if (becomes_leaf(t, i)) {
        *npacks += packs_for(subtree_tris(t, i, &first));
        return;
    }
    uint32_t kids[BVH_WIDTH];
    int n = wide_children(t, i, kids);
    ++*nwide;
    for (int c = 0; c < n; c++)
        count_subtree(t, kids[c], nwide, npacks);
}

typedef struct {
    bvh_tree *t;
    const arbor_mesh *m;
    uint32_t next_wide, next_pack;
} wide_fill;

static uint64_t fill_leaf(wide_fill *f, uint32_t i)
{
    bvh_tree *t = f->t;
    uint32_t first;
    uint32_t count = subtree_tris(t, i, &first);
    uint32_t pack0 = f->next_pack;
    f->next_pack += packs_for(count);
    for (uint32_t p = pack0; p < f->next_pack; p++) {
        bvh_tri_pack *pack = &t->packs[p];
        for (int lane = 0; lane < BVH_WIDTH; lane++) {
            uint32_t slot = first + (p - pack0) * BVH_WIDTH + (uint32_t)lane;
            arbor_vec3 v[3] = {{NAN, NAN, NAN}, {NAN, NAN, NAN}, {NAN, NAN, NAN}};
            uint32_t tri = UINT32_MAX;
            if (slot < first + count) {
                tri = t->tri_index[slot];
                arbor_mesh_tri(f->m, tri, &v[0], &v[1], &v[2]);
            }
            for (int k = 0; k < 3; k++) {
                pack->v[k][0][lane] = v[k].x;
                pack->v[k][1][lane] = v[k].y;
                pack->v[k][2][lane] = v[k].z;
            }
            t->pack_tri[BVH_WIDTH * (size_t)p + (size_t)lane] = tri;
        }
    }
    return BVH_REF_LEAF | (uint64_t)count << 32 | pack0;
}

/* Writes the subtree of binary node i; returns the reference to it. */
static uint64_t fill_subtree(wide_fill *f, uint32_t i)
{
    const bvh_tree *t = f->t;
    if (becomes_leaf(t, i))
        return fill_leaf(f, i);
    uint32_t kids[BVH_WIDTH];
    int n = wide_children(t, i, kids);
    uint32_t w = f->next_wide++;
    for (int c = 0; c < BVH_WIDTH; c++) {
        const bvh_node *k = c < n ? &t->nodes[kids[c]] : NULL;
        for (int row = 0; row < 3; row++) {
            f->t->wide[w].box[row][c] = k ? k->bounds[row] : INFINITY;
            f->t->wide[w].box[row + 3][c] = k ? k->bounds[row + 3] : -INFINITY;
        }
        f->t->wide[w].child[c] = 0;
    }
    for (int c = 0; c < n; c++)
        f->t->wide[w].child[c] = fill_subtree(f, kids[c]);
    return w;
}

static void *alloc_aligned(size_t count, size_t size)
{
    size_t bytes = (count * size + 63) & ~(size_t)63;
    return aligned_alloc(64, bytes > 0 ? bytes : 64);
}

bool bvh_wide_build(bvh_tree *t, const arbor_mesh *m, arbor_err *e)
{
    if (t->nnodes == 0)
        return true;
    /* The root is always a wide node, so traversal always starts at one: a
     * binary tree small enough to be one leaf gets a root with that leaf. */
    bool root_leaf = becomes_leaf(t, 0);
    uint32_t nwide = 1, npacks = 0, first;
    if (root_leaf) {
        npacks = packs_for(subtree_tris(t, 0, &first));
    } else {
        nwide = 0;
        count_subtree(t, 0, &nwide, &npacks);
    }
    t->wide = alloc_aligned(nwide, sizeof *t->wide);
    t->packs = alloc_aligned(npacks, sizeof *t->packs);
    t->pack_tri = malloc(BVH_WIDTH * (size_t)npacks * sizeof *t->pack_tri);
    if (t->wide == NULL || t->packs == NULL || t->pack_tri == NULL)
        return arbor_fail(e, ARBOR_ERR_NOMEM, "bvh: out of memory for the wide tree (%u nodes, %u packs)", nwide,
                          npacks);
    t->nwide = nwide;
    t->npacks = npacks;
    wide_fill f = {t, m, 0, 0};
    if (root_leaf) {
        f.next_wide = 1;
        for (int c = 0; c < BVH_WIDTH; c++)
            for (int row = 0; row < 3; row++) {
                t->wide[0].box[row][c] = c == 0 ? t->nodes[0].bounds[row] : INFINITY;
                t->wide[0].box[row + 3][c] = c == 0 ? t->nodes[0].bounds[row + 3] : -INFINITY;
            }
        memset(t->wide[0].child, 0, sizeof t->wide[0].child);
        t->wide[0].child[0] = fill_leaf(&f, 0);
    } else {
        fill_subtree(&f, 0);
    }
    return true;
}

uint64_t bvh_tree_bytes(const bvh_tree *t)
{
    return (uint64_t)t->nnodes * sizeof(bvh_node) + (uint64_t)t->ntris * sizeof(uint32_t) +
           (uint64_t)t->nwide * sizeof(bvh_wide_node) +
           (uint64_t)t->npacks * (sizeof(bvh_tri_pack) + BVH_WIDTH * sizeof(uint32_t));
}

/* What the validating walk of the wide tree has seen so far. */
typedef struct {
    const bvh_tree *t;
    const arbor_mesh *m;
    arbor_err *e;
    uint8_t *seen;        /* per mesh triangle: found in a pack */
    uint32_t next_wide;   /* depth-first order: the node the walk must meet next */
    uint32_t next_pack;   /* and the pack */
} wide_check;

static arbor_aabb lane_box(const bvh_wide_node *n, int c)
{
    arbor_aabb b = {vec3(n->box[0][c], n->box[1][c], n->box[2][c]), vec3(n->box[3][c], n->box[4][c], n->box[5][c])};
    return b;
}

static bool check_pack_lane(wide_check *k, uint32_t p, int lane, bool used, const arbor_aabb *box)
{
    const bvh_tri_pack *pack = &k->t->packs[p];
    uint32_t tri = k->t->pack_tri[BVH_WIDTH * (size_t)p + (size_t)lane];
    arbor_vec3 v[3];
    for (int j = 0; j < 3; j++)
        v[j] = vec3(pack->v[j][0][lane], pack->v[j][1][lane], pack->v[j][2][lane]);
    if (!used) {
        for (int j = 0; j < 3; j++)
            if (!isnan(v[j].x) || !isnan(v[j].y) || !isnan(v[j].z) || tri != UINT32_MAX)
                return arbor_fail(k->e, ARBOR_ERR_INVALID, "bvh pack %u lane %d: an unused lane is not NaN padding",
                                  p, lane);
        return true;
    }
    if (tri >= k->m->ntris)
        return arbor_fail(k->e, ARBOR_ERR_INVALID, "bvh pack %u lane %d: triangle index %u out of range (%u triangles)",
                          p, lane, tri, k->m->ntris);
    if (k->seen[tri])
        return arbor_fail(k->e, ARBOR_ERR_INVALID, "bvh pack %u lane %d: triangle %u is in a second pack", p, lane, tri);
    k->seen[tri] = 1;
    arbor_vec3 w[3];
    arbor_mesh_tri(k->m, tri, &w[0], &w[1], &w[2]);
    if (memcmp(v, w, sizeof v) != 0)
        return arbor_fail(k->e, ARBOR_ERR_INVALID, "bvh pack %u lane %d: vertices of triangle %u differ from the mesh's",
                          p, lane, tri);
    if (!aabb_contains(*box, arbor_mesh_tri_bounds(k->m, tri)))
        return arbor_fail(k->e, ARBOR_ERR_INVALID, "bvh pack %u lane %d: leaf box does not contain triangle %u", p,
                          lane, tri);
    return true;
}

static bool check_wide_leaf(wide_check *k, uint64_t ref, const arbor_aabb *box)
{
    uint32_t tris = bvh_ref_tris(ref), pack0 = bvh_ref_index(ref);
    if (tris == 0 || pack0 != k->next_pack || packs_for(tris) > k->t->npacks - pack0)
        return arbor_fail(k->e, ARBOR_ERR_INVALID, "bvh wide leaf: %u triangles from pack %u (next is %u of %u)", tris,
                          pack0, k->next_pack, k->t->npacks);
    k->next_pack += packs_for(tris);
    for (uint32_t p = pack0; p < k->next_pack; p++)
        for (int lane = 0; lane < BVH_WIDTH; lane++)
            if (!check_pack_lane(k, p, lane, (p - pack0) * BVH_WIDTH + (uint32_t)lane < tris, box))
                return false;
    return true;
}

/* Checks wide node w at depth, inside `parent`, and its subtree. */
static bool check_wide_node(wide_check *k, uint32_t w, const arbor_aabb *parent, uint32_t depth)
{
    if (w != k->next_wide || w >= k->t->nwide)
        return arbor_fail(k->e, ARBOR_ERR_INVALID, "bvh wide node %u: expected node %u of %u in depth-first order", w,
                          k->next_wide, k->t->nwide);
    if (depth >= BVH_MAX_DEPTH)
        return arbor_fail(k->e, ARBOR_ERR_INVALID, "bvh wide node %u: depth %u exceeds the traversal stack", w, depth);
    k->next_wide++;
    const bvh_wide_node *n = &k->t->wide[w];
    for (int c = 0; c < BVH_WIDTH; c++) {
        arbor_aabb box = lane_box(n, c);
        uint64_t ref = n->child[c];
        if (ref == 0) {
            if (box.lo.x != INFINITY || box.lo.y != INFINITY || box.lo.z != INFINITY || box.hi.x != -INFINITY ||
                box.hi.y != -INFINITY || box.hi.z != -INFINITY)
                return arbor_fail(k->e, ARBOR_ERR_INVALID, "bvh wide node %u: empty slot %d has a non-empty box", w, c);
            continue;
        }
        if (!aabb_contains(*parent, box))
            return arbor_fail(k->e, ARBOR_ERR_INVALID, "bvh wide node %u: child %d's box is not inside its parent's", w,
                              c);
        bool ok = bvh_ref_is_leaf(ref) ? check_wide_leaf(k, ref, &box)
                                       : check_wide_node(k, bvh_ref_index(ref), &box, depth + 1);
        if (!ok)
            return false;
    }
    return true;
}

bool bvh_wide_validate(const bvh_tree *t, const arbor_mesh *m, arbor_err *e)
{
    if (t->nnodes == 0) {
        if (t->nwide != 0 || t->npacks != 0)
            return arbor_fail(e, ARBOR_ERR_INVALID, "bvh: an empty tree with %u wide nodes", t->nwide);
        return true;
    }
    wide_check k = {t, m, e, calloc(m->ntris, 1), 0, 0};
    if (k.seen == NULL)
        return arbor_fail(e, ARBOR_ERR_NOMEM, "bvh: out of memory validating");
    arbor_aabb root = bvh_node_box(&t->nodes[0]);
    bool ok = check_wide_node(&k, 0, &root, 0);
    if (ok && (k.next_wide != t->nwide || k.next_pack != t->npacks))
        ok = arbor_fail(e, ARBOR_ERR_INVALID, "bvh: the walk reaches %u of %u wide nodes and %u of %u packs",
                        k.next_wide, t->nwide, k.next_pack, t->npacks);
    for (uint32_t i = 0; ok && i < m->ntris; i++)
        if (!k.seen[i])
            ok = arbor_fail(e, ARBOR_ERR_INVALID, "bvh: triangle %u is in no pack", i);
    free(k.seen);
    return ok;
}
