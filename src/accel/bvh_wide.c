/*
 * bvh_wide.c - the wide tree rays traverse, collapsed from the binary tree
 * the builders make (layouts in bvh_internal.h), and its validator.
 *
 * Collapsing is driven by the SAH of the wide tree, under the cost model of
 * bvh_wide_stats.c: a wide node's visit costs COLLAPSE_NODE_COST times its
 * area, a leaf COLLAPSE_PACK_COST times its area per pack. One pass over the
 * binary nodes bottom up (children come after their parent in depth-first
 * order, so a reverse scan meets them first) plans, for each node and each
 * number of slots k = 1 .. BVH_WIDTH of a wide node its subtree may fill,
 * the least cost and how it is reached (the dynamic programme of Ylitie et
 * al., "Efficient Incoherent Ray Traversal on GPUs Through Compressed Wide
 * BVHs", 2017): in one slot, the cheaper of its subtree as one leaf and a
 * wide node whose BVH_WIDTH slots its two children share; in k slots, the
 * best share of k between the children, unless one slot costs less. Only
 * subtrees of at most COLLAPSE_MAX_LEAF_TRIS triangles may become a leaf, so
 * leaves stay a few packs long (a binary leaf stays a leaf whatever its
 * size). Filling then reads the plan top down: a lookup per slot, no search.
 * A subtree's triangles are contiguous in leaf order, so a leaf is a range
 * of tri_index whatever binary leaves it merges.
 *
 * Planning runs in parallel when the build has threads: the binary tree is
 * cut a few levels down, the subtrees below the cut are planned at once and
 * the nodes above it after them. Every node gets the plan a serial scan
 * gives it, so the tree does not depend on the threads. A node's costs are
 * needed only by its parent, so they live on a stack during the scan, and
 * the plan keeps 16 bytes per binary node while the collapse runs.
 *
 * One pass, depth first, then writes the wide nodes and a record per pack
 * (its range of leaf order) into arrays sized for the worst case, which are
 * then shrunk to fit (a counting pass first cost more than it saved: the
 * walk's cache misses on a large binary tree dominate). A linear pass turns
 * the records into packs, in two parallel halves for large meshes: it is
 * the first to write the packs' memory, most of the tree's, whose page
 * faults would otherwise all fall to the serial walk. The recursion is at
 * most as deep as the binary tree, and so is the wide tree. The collapse
 * is short next to the binary build, so it is not cancellable: the cancel
 * flag is polled before it.
 */
#include <assert.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "arbor/sys.h"
#include "bvh_internal.h"

/* The cost model's steps. bvh_wide_stats.c counts both as 1; a pack at
 * 0.75 made fuller leaves (bunny 5.22 -> 5.66 triangles per leaf, 5% fewer
 * bytes) and measured faster primary rays on all of bunny, castle, galleon,
 * sponza and dragon (+2-5% of Embree's rate, 6 interleaved rounds, 1
 * thread), diffuse and shadow rays within noise. */
#define COLLAPSE_NODE_COST 1.0f
#define COLLAPSE_PACK_COST 0.75f
/* The largest leaf the SAH may choose: four packs keep a leaf's tests short
 * however flat the cost curve is. */
#define COLLAPSE_MAX_LEAF_PACKS 4
#define COLLAPSE_MAX_LEAF_TRIS (COLLAPSE_MAX_LEAF_PACKS * BVH_WIDTH)

/* The collapse's decisions for one binary node, for every number of slots
 * k = 1 .. BVH_WIDTH of a wide node its subtree may fill. */
typedef struct {
    uint8_t split[BVH_WIDTH];   /* [k - 1]: 0 = one slot, else the slots given to the left child */
    uint8_t node_split;         /* as a wide node: the slots given to the left child */
    bool leaf;                  /* as one slot: a leaf, else a wide node */
    uint32_t tris;              /* triangles in the subtree */
} collapse_plan;
_Static_assert(BVH_WIDTH < 256, "a number of slots fits a byte");

/* A subtree's least SAH costs (area x steps) in at most k = 1 .. BVH_WIDTH
 * slots, [k - 1]. Only a node's parent reads them, so they are not kept
 * per node but on a stack (see plan_node). */
typedef struct {
    float cost[BVH_WIDTH];
} slot_costs;

/* The costs of the subtrees planned and not yet taken by their parents: at
 * most one per level of the binary tree, and one more. */
typedef struct {
    slot_costs at[BVH_MAX_DEPTH + 1];
    uint32_t n;
} cost_stack;

typedef struct {
    uint32_t first, count;  /* a range of leaf order */
} tri_range;

/* What fill_leaf decides for one pack: lanes [0, lanes) hold the
 * triangles of leaf order [first, first + lanes); last marks a leaf's last
 * pack. */
typedef struct {
    uint32_t first;
    uint8_t lanes;
    bool last;
} pack_record;

/* What planning and filling share: the tree, the plan per binary node, the
 * record per pack, the next wide node and pack. */
typedef struct {
    bvh_tree *t;
    collapse_plan *plan;
    pack_record *records;
    uint32_t next_wide, next_pack;
} wide_ctx;

/* The range of leaf order the subtree of binary node i covers: it starts at
 * its leftmost leaf, the first leaf from i in depth-first order. */
static tri_range subtree_range(const wide_ctx *x, uint32_t i)
{
    const bvh_node *n = x->t->nodes;
    uint32_t j = i;
    while (n[j].count == 0)
        j++;
    tri_range r = {n[j].index, x->plan[i].tris};
    return r;
}

/* Plans binary leaf n: one wide leaf, whatever the slots. */
static void plan_binary_leaf(collapse_plan *p, const bvh_node *n, slot_costs *c)
{
    p->tris = n->count;
    p->leaf = true;
    p->node_split = 0;
    float cost = aabb_area(bvh_node_box(n)) * COLLAPSE_PACK_COST * (float)bvh_packs_for(n->count);
    for (int k = 0; k < BVH_WIDTH; k++) {
        c->cost[k] = cost;
        p->split[k] = 0;
    }
}

/* Plans binary inner node n, with l and r its children's plans and costs:
 * in k >= 2 slots, the best share of them between the children, unless one
 * slot costs less; in one slot, the cheaper of a leaf (if small enough) and
 * a wide node whose BVH_WIDTH slots the children share. Sets c to n's
 * costs. */
static void plan_inner(collapse_plan *p, const bvh_node *n, const collapse_plan *l, const slot_costs *lc,
                       const collapse_plan *r, const slot_costs *rc, slot_costs *c)
{
    float shared[BVH_WIDTH + 1];
    uint8_t left_slots[BVH_WIDTH + 1];
    for (int k = 2; k <= BVH_WIDTH; k++) {
        shared[k] = INFINITY;
        left_slots[k] = 1;
        for (int j = 1; j < k; j++)
            if (lc->cost[j - 1] + rc->cost[k - j - 1] < shared[k]) {
                shared[k] = lc->cost[j - 1] + rc->cost[k - j - 1];
                left_slots[k] = (uint8_t)j;
            }
    }
    float area = aabb_area(bvh_node_box(n));
    p->tris = l->tris + r->tris;
    float as_leaf = p->tris <= COLLAPSE_MAX_LEAF_TRIS
                        ? area * COLLAPSE_PACK_COST * (float)bvh_packs_for(p->tris)
                        : INFINITY;
    float as_node = area * COLLAPSE_NODE_COST + shared[BVH_WIDTH];
    p->leaf = as_leaf <= as_node;
    p->node_split = left_slots[BVH_WIDTH];
    float one = p->leaf ? as_leaf : as_node;
    c->cost[0] = one;
    p->split[0] = 0;
    for (int k = 2; k <= BVH_WIDTH; k++) {
        bool share = shared[k] < one;
        c->cost[k - 1] = share ? shared[k] : one;
        p->split[k - 1] = share ? left_slots[k] : 0;
    }
}

/* Plans binary node i, whose children (if any) are planned and their costs
 * on top of s, the left child's topmost; leaves i's costs there instead.
 * Nodes taken in reverse depth-first order meet the stack this way: the
 * reverse of "i, left subtree, right subtree" finishes the right child,
 * then the left, then comes to i. */
static void plan_node(wide_ctx *x, uint32_t i, cost_stack *s)
{
    const bvh_node *n = &x->t->nodes[i];
    if (n->count > 0) {
        assert(s->n <= BVH_MAX_DEPTH);
        plan_binary_leaf(&x->plan[i], n, &s->at[s->n++]);
        return;
    }
    assert(s->n >= 2);
    slot_costs c;
    plan_inner(&x->plan[i], n, &x->plan[i + 1], &s->at[s->n - 1], &x->plan[n->index], &s->at[s->n - 2], &c);
    s->at[s->n - 2] = c;
    s->n--;
}

/* One past the last node of binary node i's subtree: its rightmost leaf
 * is its last node in depth-first order. */
static uint32_t subtree_end(const bvh_node *nodes, uint32_t i)
{
    while (nodes[i].count == 0)
        i = nodes[i].index;
    return i + 1;
}

/* The subtree of one binary node, planned on its own: nodes [b, e) and
 * their costs. */
typedef struct {
    wide_ctx *x;
    uint32_t b, e;
    slot_costs cost;
} plan_part;

/* Part number `i` of the array `parts`. */
static void plan_part_run(void *parts, uint32_t i)
{
    plan_part *p = (plan_part *)parts + i;
    cost_stack s;
    s.n = 0;
    for (uint32_t j = p->e; j-- > p->b;)
        plan_node(p->x, j, &s);
    assert(s.n == 1);
    p->cost = s.at[0];
}

/* A parallel plan cuts the binary tree at this depth: the subtrees below
 * (at most 2^depth, enough to even out the threads' shares) are planned at
 * once, then the few nodes above. */
#define COLLAPSE_PLAN_CUT_DEPTH 4
#define COLLAPSE_PLAN_CUT_MAX (1u << COLLAPSE_PLAN_CUT_DEPTH)

/* The nodes above the cut, depth first, and the subtrees hanging from it. */
typedef struct {
    uint32_t node[2 * COLLAPSE_PLAN_CUT_MAX - 1];
    int8_t part[2 * COLLAPSE_PLAN_CUT_MAX - 1]; /* the subtree node[j] roots, -1 for a node above */
    uint32_t n;
    plan_part parts[COLLAPSE_PLAN_CUT_MAX];
    uint32_t nparts;
} plan_cut;

static void cut_at(plan_cut *c, wide_ctx *x, uint32_t i, uint32_t depth)
{
    const bvh_node *nodes = x->t->nodes;
    uint32_t j = c->n++;
    c->node[j] = i;
    if (depth == 0 || nodes[i].count > 0) {
        c->part[j] = (int8_t)c->nparts;
        c->parts[c->nparts++] = (plan_part){x, i, subtree_end(nodes, i), {{0}}};
        return;
    }
    c->part[j] = -1;
    cut_at(c, x, i + 1, depth - 1);
    cut_at(c, x, nodes[i].index, depth - 1);
}

/* Plans every binary node: the subtrees below the cut in parallel (when
 * parallel; the whole tree as one otherwise), then the nodes above it,
 * each subtree's costs standing in for it on the stack. */
static void plan_collapse(wide_ctx *x, accel_run *run, bool parallel)
{
    plan_cut c;
    c.n = c.nparts = 0;
    cut_at(&c, x, 0, parallel ? COLLAPSE_PLAN_CUT_DEPTH : 0);
    accel_parallel(run, c.nparts, plan_part_run, c.parts);
    cost_stack s;
    s.n = 0;
    for (uint32_t j = c.n; j-- > 0;) {
        if (c.part[j] >= 0)
            s.at[s.n++] = c.parts[c.part[j]].cost;
        else
            plan_node(x, c.node[j], &s);
    }
    assert(s.n == 1);
}

/* Appends to out[n ..] the binary nodes that fill the at most k slots
 * planned for the subtree of binary node i; returns the new count. */
static int planned_slots(const wide_ctx *x, uint32_t i, int k, uint32_t *out, int n)
{
    assert(k >= 1 && n + k <= BVH_WIDTH);
    int left = x->plan[i].split[k - 1];
    assert(left < k);
    if (left == 0) {
        out[n] = i;
        return n + 1;
    }
    n = planned_slots(x, i + 1, left, out, n);
    return planned_slots(x, x->t->nodes[i].index, k - left, out, n);
}

/* The binary nodes that become the children of the wide node made from
 * binary inner node i; returns how many. */
static int wide_children(const wide_ctx *x, uint32_t i, uint32_t out[BVH_WIDTH])
{
    int left = x->plan[i].node_split;
    int n = planned_slots(x, i + 1, left, out, 0);
    return planned_slots(x, x->t->nodes[i].index, BVH_WIDTH - left, out, n);
}

/* The children of the root wide node. The root is always a wide node, so
 * traversal always starts at one: a binary tree planned as one leaf gets a
 * root with that leaf as its only child. */
static int root_children(const wide_ctx *x, uint32_t out[BVH_WIDTH])
{
    if (!x->plan[0].leaf)
        return wide_children(x, 0, out);
    out[0] = 0;
    return 1;
}

/* Assigns a leaf its packs: their records, which fill_packs turns into
 * the packs afterwards. */
static uint32_t fill_leaf(wide_ctx *x, tri_range r)
{
    uint32_t pack0 = x->next_pack, npacks = bvh_packs_for(r.count);
    x->next_pack += npacks;
    for (uint32_t j = 0; j < npacks; j++) {
        uint32_t left = r.count - j * BVH_WIDTH;
        x->records[pack0 + j] = (pack_record){r.first + j * BVH_WIDTH, (uint8_t)(left < BVH_WIDTH ? left : BVH_WIDTH),
                                              j + 1 == npacks};
    }
    return BVH_REF_LEAF | pack0;
}

/* Packs [b, e) from their records: each lane's triangle index and
 * vertices, from tri_index and the mesh (BVH_LANE_UNUSED and NaN in unused
 * lanes), BVH_PACK_LAST on the last pack's lane 0. This pass is the first
 * to write the packs' memory (most of the tree's), so it maps its part in
 * one call first (dragon, 1 thread: the pass 35.5-36.7 -> 31.5-32.3 ms, 3
 * runs each), and runs in parallel halves for large meshes, which splits
 * the mapping too. */
typedef struct {
    bvh_tree *t;
    const arbor_mesh *m;
    const pack_record *records;
    uint32_t b, e;
} pack_pass;

/* How far ahead of the pack being filled its sources are prefetched: a
 * lane's vertices are two loads away from tri_index (its triangle's corner
 * indices, then the corners), at places leaf order makes random in the
 * mesh's arrays. The corner indices are fetched PACK_AHEAD_INDICES packs
 * ahead, the corners, through indices by then in cache,
 * PACK_AHEAD_VERTICES ahead (1 thread, the pass's median over 20 builds:
 * bunny 3.0 -> 2.1 ms, sponza 1.6 -> 1.3; over 5: dragon 38 -> 29; the
 * stalls on those loads were most of its time outside the kernel). The
 * first packs of a pass go unprefetched, which costs only their stalls. */
#define PACK_AHEAD_INDICES 8
#define PACK_AHEAD_VERTICES 4

/* Prefetches the corner indices (corners false) or the corners of the
 * triangles of pack p, if the pass has it. */
static void prefetch_pack_sources(const pack_pass *pp, uint32_t p, bool corners)
{
    if (p >= pp->e)
        return;
    const pack_record *rec = &pp->records[p];
    for (uint32_t lane = 0; lane < rec->lanes; lane++) {
        const uint32_t *iv = pp->m->tri_verts + 3 * (size_t)pp->t->tri_index[rec->first + lane];
        if (!corners) {
            __builtin_prefetch(iv);
            continue;
        }
        for (int k = 0; k < 3; k++)
            __builtin_prefetch(&pp->m->verts[iv[k]]);
    }
}

/* Pass number `i` of the array `passes`. */
static void fill_packs(void *passes, uint32_t i)
{
    const pack_pass *pp = (const pack_pass *)passes + i;
    arbor_prefault(&pp->t->packs[pp->b], (size_t)(pp->e - pp->b) * sizeof(bvh_tri_pack));
    for (uint32_t p = pp->b; p < pp->e; p++) {
        prefetch_pack_sources(pp, p + PACK_AHEAD_INDICES, false);
        prefetch_pack_sources(pp, p + PACK_AHEAD_VERTICES, true);
        const pack_record *rec = &pp->records[p];
        bvh_tri_pack *pack = &pp->t->packs[p];
        for (int lane = 0; lane < BVH_WIDTH; lane++) {
            arbor_vec3 v[3] = {{NAN, NAN, NAN}, {NAN, NAN, NAN}, {NAN, NAN, NAN}};
            uint32_t tri = BVH_LANE_UNUSED;
            if (lane < rec->lanes) {
                tri = pp->t->tri_index[rec->first + (uint32_t)lane];
                arbor_mesh_tri(pp->m, tri, &v[0], &v[1], &v[2]);
            }
            pack->tri[lane] = tri;
            for (int k = 0; k < 3; k++) {
                pack->v[k][0][lane] = v[k].x;
                pack->v[k][1][lane] = v[k].y;
                pack->v[k][2][lane] = v[k].z;
            }
        }
        if (rec->last)
            pack->tri[0] |= BVH_PACK_LAST;
    }
}

static uint32_t fill_subtree(wide_ctx *x, uint32_t i);

/* Writes a wide node whose children are binary nodes kids[0, n), then their
 * subtrees; returns its reference. */
static uint32_t fill_node(wide_ctx *x, const uint32_t *kids, int n)
{
    uint32_t w = x->next_wide++;
    bvh_wide_node *node = &x->t->wide[w];
    for (int c = 0; c < BVH_WIDTH; c++) {
        const bvh_node *k = c < n ? &x->t->nodes[kids[c]] : NULL;
        for (int row = 0; row < 3; row++) {
            node->box[row][c] = k ? k->bounds[row] : INFINITY;
            node->box[row + 3][c] = k ? k->bounds[row + 3] : -INFINITY;
        }
        node->child[c] = BVH_REF_EMPTY;
        node->unused[c] = 0;
    }
    for (int c = 0; c < n; c++)
        node->child[c] = fill_subtree(x, kids[c]);
    return w;
}

/* Writes the subtree of binary node i; returns the reference to it. */
static uint32_t fill_subtree(wide_ctx *x, uint32_t i)
{
    if (x->plan[i].leaf)
        return fill_leaf(x, subtree_range(x, i));
    uint32_t kids[BVH_WIDTH];
    int n = wide_children(x, i, kids);
    return fill_node(x, kids, n);
}

bool bvh_wide_build(bvh_tree *t, const arbor_mesh *m, accel_run *run, bool parallel, arbor_err *e)
{
    if (t->nnodes == 0)
        return true;
    /* the references' and packs' flag bits (bvh_internal.h) */
    assert(t->ntris <= (uint32_t)1 << 31);
    /* Worst cases: a wide node per binary inner node (at least the root),
     * and per wide leaf one pack more than its triangles fill, where wide
     * leaves are at most the binary leaves. */
    uint32_t leaves = (t->nnodes + 1) / 2;
    size_t max_wide = leaves > 1 ? leaves - 1 : 1, max_packs = leaves + t->ntris / BVH_WIDTH;
    wide_ctx x = {t, malloc(t->nnodes * sizeof *x.plan), malloc(max_packs * sizeof *x.records), 0, 0};
    t->wide = bvh_alloc_aligned(max_wide * sizeof *t->wide);
    t->packs = bvh_alloc_aligned(max_packs * sizeof *t->packs);
    bool ok = x.plan != NULL && x.records != NULL && t->wide != NULL && t->packs != NULL;
    if (ok) {
        plan_collapse(&x, run, parallel);
        uint32_t kids[BVH_WIDTH];
        fill_node(&x, kids, root_children(&x, kids));
        t->nwide = x.next_wide;
        t->npacks = x.next_pack;
        t->wide = bvh_shrink_aligned(t->wide, t->nwide * sizeof *t->wide);
        t->packs = bvh_shrink_aligned(t->packs, t->npacks * sizeof *t->packs);
        ok = t->wide != NULL && t->packs != NULL;
    }
    if (ok) {
        pack_pass halves[2] = {{t, m, x.records, 0, t->npacks / 2}, {t, m, x.records, t->npacks / 2, t->npacks}};
        pack_pass whole = {t, m, x.records, 0, t->npacks};
        accel_parallel(run, parallel ? 2 : 1, fill_packs, parallel ? halves : &whole);
    }
    free(x.plan);
    free(x.records);
    if (!ok)
        return arbor_fail(e, ARBOR_ERR_NOMEM, "bvh: out of memory for the wide tree of %u triangles", t->ntris);
    return true;
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

static bool check_pack_lane(wide_check *k, uint32_t p, int lane, bool used, const arbor_aabb *box)
{
    const bvh_tri_pack *pack = &k->t->packs[p];
    uint32_t tri = bvh_lane_tri(pack, lane);
    arbor_vec3 v[3];
    for (int j = 0; j < 3; j++)
        v[j] = vec3(pack->v[j][0][lane], pack->v[j][1][lane], pack->v[j][2][lane]);
    if (!used) {
        for (int j = 0; j < 3; j++)
            if (!isnan(v[j].x) || !isnan(v[j].y) || !isnan(v[j].z) || tri != BVH_LANE_UNUSED)
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

/* A leaf's packs: from its first, the next in depth-first order, up to the
 * one marked last; every pack but the last full, lane 0 always used, the
 * used lanes first. */
static bool check_wide_leaf(wide_check *k, uint32_t ref, const arbor_aabb *box)
{
    uint32_t pack0 = bvh_ref_index(ref);
    if (pack0 != k->next_pack)
        return arbor_fail(k->e, ARBOR_ERR_INVALID, "bvh wide leaf: first pack %u, expected %u of %u", pack0,
                          k->next_pack, k->t->npacks);
    for (uint32_t p = pack0;; p++) {
        if (p >= k->t->npacks)
            return arbor_fail(k->e, ARBOR_ERR_INVALID, "bvh wide leaf from pack %u: no last pack before the end (%u)",
                              pack0, k->t->npacks);
        const bvh_tri_pack *pack = &k->t->packs[p];
        bool last = bvh_pack_is_last(pack);
        int used = 0;
        while (used < BVH_WIDTH && pack->tri[used] != BVH_LANE_UNUSED)
            used++;
        if (used == 0 || (used < BVH_WIDTH && !last))
            return arbor_fail(k->e, ARBOR_ERR_INVALID, "bvh pack %u: %d lanes used in a leaf's %s pack", p, used,
                              last ? "last" : "inner");
        for (int lane = 0; lane < BVH_WIDTH; lane++) {
            if (lane > 0 && pack->tri[lane] != BVH_LANE_UNUSED && (pack->tri[lane] & BVH_PACK_LAST))
                return arbor_fail(k->e, ARBOR_ERR_INVALID, "bvh pack %u lane %d: the last mark off lane 0", p, lane);
            if (!check_pack_lane(k, p, lane, lane < used, box))
                return false;
        }
        if (last) {
            k->next_pack = p + 1;
            return true;
        }
    }
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
        arbor_aabb box = bvh_lane_box(n, c);
        uint32_t ref = n->child[c];
        if (box.lo.x == INFINITY) {
            if (ref != BVH_REF_EMPTY)
                return arbor_fail(k->e, ARBOR_ERR_INVALID, "bvh wide node %u: empty slot %d has child %#x", w, c, ref);
            if (box.lo.y != INFINITY || box.lo.z != INFINITY || box.hi.x != -INFINITY || box.hi.y != -INFINITY ||
                box.hi.z != -INFINITY)
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
    if (t->ntris == 0) {
        if (t->nwide != 0 || t->npacks != 0)
            return arbor_fail(e, ARBOR_ERR_INVALID, "bvh: an empty tree with %u wide nodes", t->nwide);
        return true;
    }
    wide_check k = {t, m, e, calloc(m->ntris, 1), 0, 0};
    if (k.seen == NULL)
        return arbor_fail(e, ARBOR_ERR_NOMEM, "bvh: out of memory validating");
    /* the root's children lie in the binary root's box, or, that dropped,
     * in their own union */
    arbor_aabb root = t->binary_dropped ? bvh_wide_box(&t->wide[0]) : bvh_node_box(&t->nodes[0]);
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
