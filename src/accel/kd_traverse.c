/*
 * kd_traverse.c - ray queries on a k-d tree: closest hit (plain and with
 * work counters) and any hit, all through one inline traversal.
 *
 * The traversal is Havran's recursive ray traversal done with an explicit
 * stack (as pbrt's KdTreeAccel::Intersect): the ray, clipped to the root
 * cell as the parametric interval [tnear, tfar], meets each inner node's
 * plane at tsplit; the child on the ray's near side is visited with
 * [tnear, tsplit] and the far one is pushed with [tsplit, tfar], or only one
 * child is visited when tsplit lies outside the interval. Leaves are thus
 * reached front to back, and the todo stack holds at most one entry per
 * level (KD_MAX_DEPTH).
 *
 * Exactness. A hit is kept wherever it is found, even slightly outside the
 * current leaf's interval: every hit a triangle test reports is a real hit
 * of the ray, so keeping it can only be right, while rejecting it would
 * lose hits whose t and the cell's t round differently (a triangle lying in
 * a split plane, for instance). Pending children that start beyond the best
 * hit, or before any hit beyond tmax (with a margin of 2^-20 relative for
 * that rounding in both cases), are skipped, and the search ends when none
 * is left: the first hit along the ray lies in a leaf the ray reaches
 * before any such child, and that leaf lists the triangle. They are skipped one by one, not all at once, because a ray
 * lying in a plane pushes a child with the whole interval, so the stack is
 * not always ordered by tnear.
 * A ray through a point where split planes meet (perfect splits put planes
 * through vertices) touches some cells around it over an interval of zero
 * length, which the rounding of tsplit can put just outside [tnear, tfar];
 * a triangle listed only in such a cell would be lost (rays aimed through a
 * sphere's vertices were). So a node sends the ray to both children unless
 * tsplit lies outside the interval by more than KD_SPLIT_MARGIN.
 * Among hits at exactly the same t the lowest triangle index wins, as in
 * brute force, whatever order the leaves list them in.
 *
 * Leaves. A leaf of one triangle runs the scalar watertight test; a leaf
 * of more tests its packs (kd_pack.c), KD_PACK_LANES triangles at once, by
 * tri_pack.h, whose lanes compute exactly what the scalar test computes, so
 * t, u and v are brute force's. Counted rays count triangles, not lanes.
 *
 * This file is a traversal kernel (accel_impl.h), as bvh_traverse.c is:
 * compiled once per instruction set, so that a pack's eight lanes are one
 * AVX register wherever the CPU has AVX2, even in a portable build; what it
 * exports is named by ACCEL_KERNEL_SYM.
 *
 * Planes parallel to the ray: a zero direction component is made +0, so its
 * reciprocal is +inf and tsplit is +inf or -inf (one child, the one the
 * origin is in) or NaN when the origin lies in the plane: then both
 * children are visited with the whole interval (the NaN-ignoring min / max
 * below). A ray starting on a plane gets tsplit = 0 and visits the side it
 * moves into (and the other with an empty interval when tnear is 0).
 */
#include "kd_internal.h"

#define SIMD_LANES KD_PACK_LANES
#include "tri_pack.h"

#ifndef ACCEL_KERNEL
#error "kd_traverse.c is a traversal kernel: the Makefile compiles it with -DACCEL_KERNEL=<name>"
#endif

/* Relative margin for the rounding of cell intervals and hit distances. */
#define KD_SPLIT_MARGIN 0x1p-20f

typedef struct {
    uint32_t node;
    float tnear, tfar;
} kd_todo;

/* Clips the ray to the tree's box: [*tnear, *tfar] within [tmin, tmax];
 * false when it misses. The box's interval is widened by pbrt's 2 gamma(3)
 * (relative) so that rounding cannot cut off a ray that grazes the box or
 * meets a flat one. A ray parallel to a slab (infinite reciprocal) is in it
 * or misses, decided here, because (lo - o) * inv is NaN when o = lo. */
static inline bool kd_clip_root(const kd_tree *tree, const arbor_ray *r, const float o[3], const float inv[3],
                                float *tnear, float *tfar)
{
    const float widen = 2.0f * (3.0f * 0x1p-24f) / (1.0f - 3.0f * 0x1p-24f);
    float t0 = -INFINITY, t1 = INFINITY;
    for (int k = 0; k < 3; k++) {
        float lo = kd_lo(&tree->bounds, k), hi = kd_hi(&tree->bounds, k);
        if (isinf(inv[k])) {
            if (!(o[k] >= lo && o[k] <= hi))
                return false;
            continue;
        }
        float a = (lo - o[k]) * inv[k], b = (hi - o[k]) * inv[k];
        float n = a < b ? a : b, f = a < b ? b : a;
        t0 = n > t0 ? n : t0;
        t1 = f < t1 ? f : t1;
    }
    t0 = t0 > 0.0f ? t0 * (1.0f - widen) : t0 * (1.0f + widen);
    t1 = t1 > 0.0f ? t1 * (1.0f + widen) : t1 * (1.0f - widen);
    *tnear = t0 > r->tmin ? t0 : r->tmin;
    *tfar = t1 < r->tmax ? t1 : r->tmax;
    return *tnear <= *tfar;
}

static void kd_visit(arbor_node_fn visit, void *user, const kd_place *p, bool leaf, uint32_t tris)
{
    arbor_node_info info = {p->cell, p->depth, leaf, tris, 1};
    visit(user, &info);
}

/* A hit at t below the limit (so t <= *best): it becomes the best unless it
 * ties the best at a higher triangle index. */
static inline void kd_keep_hit(uint32_t tri, float t, float u, float v, float *best, float *best_u, float *best_v,
                               uint32_t *best_tri, float *limit, float *stop)
{
    if (t < *best || tri < *best_tri) {
        *best = t;
        *best_u = u;
        *best_v = v;
        *best_tri = tri;
        *limit = tri_pack_next_up(t);
        *stop = t + fabsf(t) * KD_SPLIT_MARGIN;
    }
}

/* The one traversal. count == NULL, visit == NULL and any_hit are
 * compile-time constants at every call, so each query gets its own copy
 * without the code it does not use. */
static inline __attribute__((always_inline)) bool kd_trace(const kd_tree *tree, arbor_ray *r, arbor_hit *h,
                                                           arbor_trace_counts *count, bool any_hit,
                                                           arbor_node_fn visit, void *user)
{
    const float o[3] = {r->o.x, r->o.y, r->o.z};
    const float d[3] = {r->d.x + 0.0f, r->d.y + 0.0f, r->d.z + 0.0f};  /* -0 becomes +0 */
    const float inv[3] = {1.0f / d[0], 1.0f / d[1], 1.0f / d[2]};
    /* which child the ray meets first: below when moving up the axis, and
     * (d = +0) below when parallel, matching tsplit = +inf / -inf above */
    const bool below_first[3] = {d[0] >= 0.0f, d[1] >= 0.0f, d[2] >= 0.0f};
    float tnear, tfar;
    if (!kd_clip_root(tree, r, o, inv, &tnear, &tfar))
        return false;
    arbor_ray_prep prep;
    arbor_ray_prepare(r, &prep);
    tri_ray tq = {{0, 0, 0}, {0, 0, 0}, {0, 0, 0}, 0.0f};  /* set up at the first leaf of several triangles */
    bool tq_ready = false;
    const kd_node *nodes = tree->nodes;
    const arbor_mesh *mesh = tree->mesh;
    kd_todo todo[KD_MAX_DEPTH];
    kd_place place = {tree->bounds, 0}, places[KD_MAX_DEPTH]; /* untouched without visit */
    int ntodo = 0;
    uint32_t at = 0;
    /* limit: the triangle tests' bound, just above best once there is a hit
     * so that a tie can reach the index comparison; stop: best + margin, and
     * tmax + margin before any hit, so that a cell whose entry rounds just
     * past tmax still gets its hits below tmax tested */
    float best = r->tmax, limit = r->tmax, stop = r->tmax + fabsf(r->tmax) * KD_SPLIT_MARGIN;
    float best_u = 0.0f, best_v = 0.0f;
    uint32_t best_tri = UINT32_MAX;
    for (;;) {
        const kd_node *n = &nodes[at];
        if (count)
            count->nodes++;
        uint32_t axis = kd_node_kind(*n);
        if (visit)
            kd_visit(visit, user, &place, axis == KD_LEAF, axis == KD_LEAF ? kd_node_high(*n) : 0);
        if (axis != KD_LEAF) {
            float tsplit = (n->split - o[axis]) * inv[axis];
            uint32_t below = at + 1, above = kd_node_high(*n);
            uint32_t near = below_first[axis] ? below : above, far = below_first[axis] ? above : below;
            kd_place near_place, far_place;
            if (visit) {
                kd_child_cells(&place, axis, n->split, &near_place, &far_place);
                if (!below_first[axis]) {
                    kd_place swap = near_place;
                    near_place = far_place;
                    far_place = swap;
                }
            }
            if (tsplit > tfar + fabsf(tfar) * KD_SPLIT_MARGIN) {
                at = near;
                if (visit)
                    place = near_place;
            } else if (tsplit < tnear - fabsf(tnear) * KD_SPLIT_MARGIN) {
                at = far;
                if (visit)
                    place = far_place;
            } else {
                todo[ntodo].node = far;
                todo[ntodo].tnear = tsplit > tnear ? tsplit : tnear;
                todo[ntodo].tfar = tfar;
                if (visit) {
                    places[ntodo] = far_place;
                    place = near_place;
                }
                ntodo++;
                at = near;
                tfar = tsplit < tfar ? tsplit : tfar;
            }
            continue;
        }
        uint32_t ntris = kd_node_high(*n);
        if (count)
            count->tris += ntris;
        if (ntris == 1) {
            arbor_vec3 a, b, c;
            float t, u, v;
            arbor_mesh_tri(mesh, n->tri, &a, &b, &c);
            if (arbor_triangle_intersect(r, &prep, a, b, c, limit, &t, &u, &v)) {
                if (any_hit)
                    return true;
                kd_keep_hit(n->tri, t, u, v, &best, &best_u, &best_v, &best_tri, &limit, &stop);
            }
        } else if (ntris > 1) {
            /* packs of KD_PACK_LANES; a hit at t < limit has t <= best, and
             * the lanes are taken in list order against the limit each
             * one leaves, so the nearest wins, the lowest index on a tie */
            const uint32_t *tris = tree->tri_index + n->first;
            const kd_pack *pack = tree->packs + n->first / KD_PACK_LANES;
            if (!tq_ready) {
                tri_ray_setup(&tq, r);
                tq_ready = true;
            }
            for (uint32_t i = 0; i < ntris; i += KD_PACK_LANES, pack++) {
                tri_pack_hits ph;
                int hits = tri_pack_test(&pack->v[0][0][0], &tq, vset1(limit), &ph);
                if (hits == 0)
                    continue;
                if (any_hit)
                    return true;
                tri_pack_lanes lanes;
                tri_pack_lanes_of(&ph, &lanes);
                for (; hits != 0; hits &= hits - 1) {
                    int l = __builtin_ctz((unsigned)hits);
                    if (lanes.t[l] < limit)
                        kd_keep_hit(tris[i + (uint32_t)l], lanes.t[l], lanes.v[l] * lanes.inv[l],
                                    lanes.w[l] * lanes.inv[l], &best, &best_u, &best_v, &best_tri, &limit, &stop);
                }
            }
        }
        /* next: the nearest pending child that can still hold a closer hit */
        do {
            if (ntodo == 0)
                goto done;
            ntodo--;
            at = todo[ntodo].node;
            if (visit)
                place = places[ntodo];
            tnear = todo[ntodo].tnear;
            tfar = todo[ntodo].tfar;
        } while (tnear > stop);
    }
done:
    if (any_hit || best_tri == UINT32_MAX)
        return false;
    r->tmax = best;
    h->t = best;
    h->u = best_u;
    h->v = best_v;
    h->tri = best_tri;
    return true;
}

static bool kd_intersect(const void *impl, arbor_ray *r, arbor_hit *h)
{
    return kd_trace(impl, r, h, NULL, false, NULL, NULL);
}

static bool kd_intersect_counted(const void *impl, arbor_ray *r, arbor_hit *h, arbor_trace_counts *c)
{
    return kd_trace(impl, r, h, c, false, NULL, NULL);
}

static bool kd_intersect_traced(const void *impl, arbor_ray *r, arbor_hit *h, arbor_trace_counts *c,
                                arbor_node_fn visit, void *user)
{
    return kd_trace(impl, r, h, c, false, visit, user);
}

static bool kd_occluded(const void *impl, const arbor_ray *r)
{
    arbor_ray copy = *r;
    return kd_trace(impl, &copy, NULL, NULL, true, NULL, NULL);
}

static bool kd_occluded_counted(const void *impl, const arbor_ray *r, arbor_trace_counts *c)
{
    arbor_ray copy = *r;
    return kd_trace(impl, &copy, NULL, c, true, NULL, NULL);
}

const accel_queries ACCEL_KERNEL_SYM(kd_queries) = {kd_intersect, kd_intersect_counted, kd_occluded,
                                                    kd_occluded_counted, kd_intersect_traced};
