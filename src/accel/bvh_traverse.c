/*
 * bvh_traverse.c - closest-hit and any-hit queries through the wide tree
 * (bvh_internal.h, bvh_wide.c).
 *
 * One traversal (bvh_traverse) serves all three queries. It is inlined into
 * each with constant arguments: `any_hit` chooses stopping at the first hit,
 * and `counts` is a compile-time NULL in the two uncounted queries, so their
 * counting code disappears. The two uncounted queries, the hot ones, hold
 * two instances of it, with and without prefetching the children a ray
 * enters, and take the one the tree chose when it was built (bvh.c,
 * bvh_prefetch_pick), so that no node step tests the choice.
 *
 * This file is a traversal kernel (accel_impl.h): the Makefile compiles it
 * once per instruction set, and what it exports is named by
 * ACCEL_KERNEL_SYM. Its vectors are BVH_WIDTH lanes wide whatever the
 * instruction set (simd.h): the layout is the same for every kernel.
 *
 * At a wide node one BVH_WIDTH-lane slab test checks every child's box. The
 * ray goes on into the nearest child it enters and pushes the others,
 * farthest first, with their entry distances, on a stack; a popped entry
 * whose distance lies beyond the closest hit so far is skipped. An any-hit
 * query needs no order and takes the children as they come. A leaf's packs
 * are tested BVH_WIDTH triangles per step (tri_pack.h), with the arithmetic
 * of arbor_triangle_intersect lane by lane, so each triangle gives exactly
 * the t, u, v brute force computes for it.
 *
 * Ties. Among hits at exactly the same t the lowest triangle index wins, as
 * in brute force and the k-d tree, whatever leaf or lane finds them: once
 * there is a hit the triangle tests accept t up to the next float above
 * it, so an equal t reaches the index comparison, and boxes are culled
 * (and popped entries skipped) only when their entry distance is beyond
 * the hit grown by a margin for rounding (box_bound): an entry at t, or
 * rounded just past it, may hold a tie.
 */
#include "bvh_internal.h"

#define SIMD_LANES BVH_WIDTH
#include "tri_pack.h"

#ifndef ACCEL_KERNEL
#error "bvh_traverse.c is a traversal kernel: the Makefile compiles it with -DACCEL_KERNEL=<name>"
#endif

/* 1 + 6u, u = 2^-24, about 1 + 2 gamma(3) (Ize, "Robust BVH Ray
 * Traversal", JCGT 2013): exit distances computed with an inverse
 * direction scaled by it are never below the true ones, so no box a ray
 * touches is culled. An exit carries four roundings (the division, the
 * scaling, the subtraction, the product), each a factor of at least
 * 1 - u, and (1 - u)^4 (1 + 6u) > 1. */
#define BVH_EXIT_SCALE 1.0000003576278687f

/* The helpers below must be inlined into the traversal: a call per node or
 * per ray costs as much as the work (measured on sponza, whose rays mostly
 * leave the model after a few nodes). */
#define BVH_INLINE SIMD_INLINE

/* Per-ray constants of the box test, each broadcast to all lanes: the
 * origin, the inverse direction (+-inf for a zero component) and, for exit
 * distances, that inverse scaled up by BVH_EXIT_SCALE; per axis the row of
 * a node's boxes the ray enters through (lo, or hi when the direction is
 * negative) and the row it leaves through. */
typedef struct {
    vfloat org[3], inv[3], inv_exit[3];
    int near[3], far[3];
    vfloat tmin;
} box_ray;

BVH_INLINE void box_ray_setup(box_ray *q, const arbor_ray *r)
{
    typedef float float4 __attribute__((vector_size(16)));
    const float o[3] = {r->o.x, r->o.y, r->o.z};
    /* one division for the three axes: the divisions would otherwise queue
     * one behind another at the start of every ray */
    const float4 inv = (float4){1.0f, 1.0f, 1.0f, 1.0f} / (float4){r->d.x, r->d.y, r->d.z, 1.0f};
    /* unrolled, so that every field's index is a constant and the
     * constants can stay in registers; as a loop GCC stored them through
     * the array indices and read them back (docs/BENCH.md: sponza's shadow
     * rays, one or two nodes each, 11-33% faster unrolled) */
#pragma GCC unroll 3
    for (int a = 0; a < 3; a++) {
        int is_neg = inv[a] < 0.0f;
        q->org[a] = vset1(o[a]);
        q->inv[a] = vset1(inv[a]);
        q->inv_exit[a] = vset1(inv[a] * BVH_EXIT_SCALE);
        q->near[a] = a + 3 * is_neg;
        q->far[a] = a + 3 - 3 * is_neg;
    }
    q->tmin = vset1(r->tmin);
}

/* The bound boxes are tested against for hits up to tmax: tmax grown by
 * 2^-20 relative. A box holding a triangle whose computed t is tmax (a tie,
 * or the hit an any-hit query with tmax just past it looks for) may have an
 * entry distance that rounds above tmax: the entry carries three roundings
 * and the triangle's t its own few ulps from the true distance. 2^-20
 * covers both with room (kd_traverse.c's margin); culling a little less
 * near the hit costs next to nothing. */
#define BVH_TIE_SCALE (1.0f + 0x1p-20f)

BVH_INLINE float box_bound(float tmax)
{
    return tmax > 0.0f ? tmax * BVH_TIE_SCALE : tmax;
}

/* The slab test of a node's children. Per axis the entry and exit distances
 * are (plane - o) / d on the near and far plane, the exit's by the scaled
 * inverse; then entry = max(entries, tmin), exit = min(exits, tmax),
 * folded with vmax / vmin, which return their second operand when the first
 * is NaN: a zero direction component with the origin on one of that axis'
 * planes gives 0 * inf = NaN, and the slab then leaves the interval as it
 * was (the ray runs inside the plane). Returns the mask of children entered,
 * entry <= exit, and each one's entry distance in *entry. Empty slots
 * (lo +inf, hi -inf) give entry +inf and exit -inf on every axis, for a
 * ray with a finite origin and direction (bvh_internal.h says what becomes
 * of the others). */
BVH_INLINE int wide_boxes(const bvh_wide_node *n, const box_ray *q, vfloat tmax, vfloat *entry)
{
    vfloat t_in = q->tmin, t_out = tmax;
#pragma GCC unroll 3
    for (int a = 0; a < 3; a++) {
        vfloat near = (vload(n->box[q->near[a]]) - q->org[a]) * q->inv[a];
        vfloat far = (vload(n->box[q->far[a]]) - q->org[a]) * q->inv_exit[a];
        t_in = vmax(near, t_in);
        t_out = vmin(far, t_out);
    }
    *entry = t_in;
    return vmask(vle(t_in, t_out));
}

typedef struct {
    uint32_t ref;
    float t;
} stack_entry;

/* Starts loading every entered child, a wide node's four lines or its
 * leaf's first pack's first four, before they are ordered. The child the
 * ray goes into next is otherwise known only after the order's branches,
 * and its loads, issued behind them, start over whenever one mispredicts;
 * on a tree larger than the caches a diffuse ray spends more than half its
 * time waiting for memory (docs/BENCH.md, "Entered children prefetched").
 * On a tree the caches hold, the dozen instructions per child only cost,
 * so only trees of BVH_PREFETCH_MIN_BYTES or more do it (bvh_internal.h). */
BVH_INLINE void prefetch_entered(const bvh_tree *t, const bvh_wide_node *n, int mask)
{
    for (; mask != 0; mask &= mask - 1) {
        uint32_t ref = n->child[__builtin_ctz(mask)];
        const char *p = bvh_ref_is_leaf(ref) ? (const char *)&t->packs[bvh_ref_index(ref)]
                                             : (const char *)&t->wide[bvh_ref_index(ref)];
        for (int line = 0; line < 4; line++)
            __builtin_prefetch(p + 64 * line);
    }
}

/* Where the traversal is, for a visitor: the box it entered the node by and
 * the node's depth in the wide tree. */
typedef struct {
    arbor_aabb box;
    uint32_t depth;
} visit_place;

static void visit_node(arbor_node_fn visit, void *user, const visit_place *at, bool leaf, uint32_t tris,
                       uint32_t tests)
{
    arbor_node_info info = {at->box, at->depth, leaf, tris, tests};
    visit(user, &info);
}

/* The closest hit (any_hit false) or the first found (any_hit true) in
 * (r->tmin, r->tmax); fills *h on a hit unless h is NULL. prefetch: whether
 * each node's entered children are prefetched (prefetch_entered); it
 * changes no answer. counts, when not
 * NULL, gets the nodes visited (wide nodes and leaves: one step each, as a
 * k-d node is) and the triangles tested; visit, when not
 * NULL, each node visited (the inspector's ray path). counts and visit are
 * compile-time NULL in the plain queries, which lose their code. */
BVH_INLINE bool bvh_traverse(const bvh_tree *t, const arbor_ray *r, bool any_hit, bool prefetch, arbor_hit *h,
                             arbor_trace_counts *counts, arbor_node_fn visit, void *user)
{
    if (t->nwide == 0)
        return false;
    visit_place at = {{vec3(0, 0, 0), vec3(0, 0, 0)}, 0};
    visit_place places[BVH_MAX_DEPTH * (BVH_WIDTH - 1)]; /* the stack's places; untouched without visit */
    if (visit)
        at.box = bvh_wide_box(&t->wide[0]);
    box_ray q;
    box_ray_setup(&q, r);
    tri_ray tq;
    bool tq_ready = false;
    /* tmax: the closest hit so far; limit: the triangle tests' bound, just
     * above tmax once there is a hit, so that a tie reaches the index rule */
    float tmax = r->tmax, limit = r->tmax, box_tmax = box_bound(r->tmax);
    stack_entry stack[BVH_MAX_DEPTH * (BVH_WIDTH - 1)];
    uint32_t sp = 0;
    uint32_t ref = 0; /* the root */
    float hit_u = 0.0f, hit_v = 0.0f;
    uint32_t hit_tri = UINT32_MAX; /* UINT32_MAX: no hit yet */
    for (;;) {
        if (!bvh_ref_is_leaf(ref)) {
            const bvh_wide_node *n = &t->wide[bvh_ref_index(ref)];
            vfloat entry;
            int mask = wide_boxes(n, &q, vset1(box_tmax), &entry);
            if (counts)
                counts->nodes++;
            if (visit)
                visit_node(visit, user, &at, false, 0, 1);
            if (prefetch)
                prefetch_entered(t, n, mask);
            if (mask != 0) {
                int c = __builtin_ctz(mask);
                mask &= mask - 1;
                uint32_t near = n->child[c];
                float t_near = entry[c];
                int near_lane = c;
                const uint32_t base = sp;
                /* push the rest; for a closest hit keep the nearest to go
                 * into and push in order, farthest deepest */
                while (mask != 0) {
                    c = __builtin_ctz(mask);
                    mask &= mask - 1;
                    uint32_t other = n->child[c];
                    float t_other = entry[c];
                    int other_lane = c;
                    if (!any_hit && t_other < t_near) {
                        uint32_t r0 = near;
                        float t0 = t_near;
                        int l0 = near_lane;
                        near = other, t_near = t_other, near_lane = other_lane;
                        other = r0, t_other = t0, other_lane = l0;
                    }
                    uint32_t i = sp++;
                    if (!any_hit)
                        for (; i > base && stack[i - 1].t < t_other; i--) {
                            stack[i] = stack[i - 1];
                            if (visit)
                                places[i] = places[i - 1];
                        }
                    stack[i].ref = other;
                    stack[i].t = t_other;
                    if (visit)
                        places[i] = (visit_place){bvh_lane_box(n, other_lane), at.depth + 1};
                }
                ref = near;
                if (visit)
                    at = (visit_place){bvh_lane_box(n, near_lane), at.depth + 1};
                continue;
            }
        } else {
            const bvh_tri_pack *pack = &t->packs[bvh_ref_index(ref)];
            if (counts || visit) {
                uint32_t tris = bvh_leaf_tris(t, bvh_ref_index(ref));
                if (counts) {
                    counts->nodes++;
                    counts->tris += tris;
                }
                if (visit)
                    visit_node(visit, user, &at, true, tris, 1);
            }
            if (!tq_ready) {
                tri_ray_setup(&tq, r);
                tq_ready = true;
            }
            for (;; pack++) {
                tri_pack_hits ph;
                int hits = tri_pack_test(&pack->v[0][0][0], &tq, vset1(limit), &ph);
                if (any_hit && hits != 0)
                    return true;
                /* rare (at most a few packs a ray), and GCC allocates
                 * registers for the loop around it when told so */
                if (__builtin_expect(hits != 0, 0)) {
                    /* the nearest lane, the lowest triangle index on a tie;
                     * a lane at t == tmax wins only with a lower index than
                     * the best's (the test admits t up to limit for that) */
                    tri_pack_lanes lanes;
                    tri_pack_lanes_of(&ph, &lanes);
                    for (; hits != 0; hits &= hits - 1) {
                        int l = __builtin_ctz(hits);
                        float tl = lanes.t[l];
                        uint32_t tri = pack->tri[l] & ~BVH_PACK_LAST;
                        if (tl < tmax || (tl == tmax && tri < hit_tri)) {
                            tmax = tl;
                            hit_tri = tri;
                            hit_u = lanes.v[l] * lanes.inv[l];
                            hit_v = lanes.w[l] * lanes.inv[l];
                        }
                    }
                    limit = tri_pack_next_up(tmax);
                    box_tmax = box_bound(tmax);
                }
                if (bvh_pack_is_last(pack))
                    break;
            }
        }
        /* next: the most recently pushed entry that may still hold a closer hit */
        for (;;) {
            if (sp == 0)
                goto done;
            sp--;
            if (any_hit || stack[sp].t <= box_tmax) { /* an any-hit query never lowers it */
                ref = stack[sp].ref;
                if (visit)
                    at = places[sp];
                break;
            }
        }
    }
done:
    if (hit_tri != UINT32_MAX && h != NULL) {
        h->t = tmax;
        h->u = hit_u;
        h->v = hit_v;
        h->tri = hit_tri;
    }
    return hit_tri != UINT32_MAX;
}

static bool bvh_intersect(const void *impl, arbor_ray *r, arbor_hit *h)
{
    const bvh_tree *t = impl;
    if (!(t->prefetch ? bvh_traverse(t, r, false, true, h, NULL, NULL, NULL)
                      : bvh_traverse(t, r, false, false, h, NULL, NULL, NULL)))
        return false;
    r->tmax = h->t;
    return true;
}

static bool bvh_intersect_counted(const void *impl, arbor_ray *r, arbor_hit *h, arbor_trace_counts *c)
{
    const bvh_tree *t = impl;
    if (!bvh_traverse(t, r, false, t->prefetch, h, c, NULL, NULL))
        return false;
    r->tmax = h->t;
    return true;
}

static bool bvh_intersect_traced(const void *impl, arbor_ray *r, arbor_hit *h, arbor_trace_counts *c, arbor_node_fn visit,
                          void *user)
{
    const bvh_tree *t = impl;
    if (!bvh_traverse(t, r, false, t->prefetch, h, c, visit, user))
        return false;
    r->tmax = h->t;
    return true;
}

static bool bvh_occluded(const void *impl, const arbor_ray *r)
{
    const bvh_tree *t = impl;
    return t->prefetch ? bvh_traverse(t, r, true, true, NULL, NULL, NULL, NULL)
                       : bvh_traverse(t, r, true, false, NULL, NULL, NULL, NULL);
}

static bool bvh_occluded_counted(const void *impl, const arbor_ray *r, arbor_trace_counts *c)
{
    const bvh_tree *t = impl;
    return bvh_traverse(t, r, true, t->prefetch, NULL, c, NULL, NULL);
}

const accel_queries ACCEL_KERNEL_SYM(bvh_queries) = {bvh_intersect, bvh_intersect_counted, bvh_occluded,
                                                     bvh_occluded_counted, bvh_intersect_traced};
