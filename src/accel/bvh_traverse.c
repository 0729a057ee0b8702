/*
 * bvh_traverse.c - closest-hit and any-hit queries through a built BVH.
 *
 * One traversal (bvh_traverse) serves all three queries. It is inlined into
 * each with constant arguments: `any_hit` chooses stopping at the first hit,
 * and `counts` is a compile-time NULL in the two uncounted queries, so their
 * counting code disappears.
 *
 * At an inner node both children's boxes are tested; the ray descends into
 * the nearer one it enters and pushes the other, with its entry distance, on
 * a small stack. A popped node whose entry lies beyond the closest hit so far
 * is skipped. Triangles are tested with the watertight arbor_triangle_intersect,
 * on the same ray values brute force uses, so the trees find the same hits.
 */
#include "bvh_internal.h"

/* Per-ray constants of the slab test. near[k] and far[k] index the node's
 * bounds[]: the plane of axis k the ray enters through and the one it leaves
 * through (lo and hi when the direction is positive, swapped when negative),
 * so the test needs no min/max per axis. */
typedef struct {
    float org[3], inv[3];
    uint32_t near[3], far[3];
    float tmin;
} bvh_ray;

/* 1 + 2 gamma(3) with gamma(n) = n u / (1 - n u), u = 2^-24: scaling exit
 * distances by it makes the slab test conservative despite rounding (Ize,
 * "Robust BVH Ray Traversal", JCGT 2013), so no box a ray touches is culled. */
#define BVH_EXIT_SCALE 1.0000003576278687f

static inline void bvh_ray_setup(bvh_ray *q, const arbor_ray *r)
{
    const float o[3] = {r->o.x, r->o.y, r->o.z};
    const float d[3] = {r->d.x, r->d.y, r->d.z};
    for (uint32_t k = 0; k < 3; k++) {
        q->org[k] = o[k];
        q->inv[k] = 1.0f / d[k]; /* +-inf for a zero component: see bvh_box_entry */
        q->near[k] = q->inv[k] < 0.0f ? k + 3 : k;
        q->far[k] = q->inv[k] < 0.0f ? k : k + 3;
    }
    q->tmin = r->tmin;
}

/* One slab: the distances to the near and far plane of axis k. */
static inline void bvh_slab(const float *bounds, const bvh_ray *q, int k, float *t_near, float *t_far)
{
    *t_near = (bounds[q->near[k]] - q->org[k]) * q->inv[k];
    *t_far = (bounds[q->far[k]] - q->org[k]) * q->inv[k];
}

/* The larger and smaller of a distance and a bound, keeping the bound when
 * the distance is NaN (the comparison is false). */
static inline float bvh_raise(float t, float bound) { return t > bound ? t : bound; }
static inline float bvh_lower(float t, float bound) { return t < bound ? t : bound; }

/* Where the ray enters the node's box within [tmin, tmax], or INFINITY if it
 * does not. With a zero direction component, inv is +-inf and a plane through
 * the origin gives 0 * inf = NaN: bvh_raise and bvh_lower then keep the
 * interval as it was (the ray runs inside that plane). The exit distance is
 * scaled once after the minimum, which scaling by a positive factor commutes
 * with. Written out per axis: this is the traversal's inner loop. */
static inline float bvh_box_entry(const bvh_node *n, const bvh_ray *q, float tmax)
{
    float nx, fx, ny, fy, nz, fz;
    bvh_slab(n->bounds, q, 0, &nx, &fx);
    bvh_slab(n->bounds, q, 1, &ny, &fy);
    bvh_slab(n->bounds, q, 2, &nz, &fz);
    float t0 = bvh_raise(nz, bvh_raise(ny, bvh_raise(nx, q->tmin)));
    float t1 = bvh_lower(fz, bvh_lower(fy, bvh_lower(fx, INFINITY))) * BVH_EXIT_SCALE;
    t1 = bvh_lower(t1, tmax);
    return t0 <= t1 ? t0 : INFINITY;
}

/* The closest hit (any_hit false) or the first found (any_hit true) in
 * (r->tmin, r->tmax); fills *h on a hit unless h is NULL. counts, when not
 * NULL, gets the node boxes tested and the triangles tested. */
static inline __attribute__((always_inline)) bool bvh_traverse(const bvh_tree *t, const arbor_ray *r, bool any_hit,
                                                                arbor_hit *h, arbor_trace_counts *counts)
{
    if (t->nnodes == 0)
        return false;
    const bvh_node *nodes = t->nodes;
    bvh_ray q;
    bvh_ray_setup(&q, r);
    arbor_ray_prep prep;
    arbor_ray_prepare(r, &prep);
    float tmax = r->tmax;
    if (counts)
        counts->nodes++;
    if (bvh_box_entry(&nodes[0], &q, tmax) == INFINITY)
        return false;

    struct {
        uint32_t node;
        float t;
    } stack[BVH_MAX_DEPTH];
    uint32_t sp = 0;
    uint32_t ni = 0;
    bool found = false;
    float hit_u = 0.0f, hit_v = 0.0f;
    uint32_t hit_slot = 0;
    for (;;) {
        const bvh_node *n = &nodes[ni];
        if (n->count == 0) {
            uint32_t left = ni + 1, right = n->index;
            float t_left = bvh_box_entry(&nodes[left], &q, tmax);
            float t_right = bvh_box_entry(&nodes[right], &q, tmax);
            if (counts)
                counts->nodes += 2;
            /* nearer child first; selects rather than a branch, which would
             * be mispredicted about half the time */
            bool swap = t_right < t_left;
            uint32_t near = swap ? right : left, far = swap ? left : right;
            float t_near = swap ? t_right : t_left, t_far = swap ? t_left : t_right;
            if (t_near != INFINITY) {
                if (t_far != INFINITY) {
                    stack[sp].node = far;
                    stack[sp].t = t_far;
                    sp++;
                }
                ni = near;
                continue;
            }
        } else {
            const arbor_vec3 *v = t->tri_verts + 3 * (size_t)n->index;
            for (uint32_t i = 0; i < n->count; i++, v += 3) {
                float tt, u, w;
                if (counts)
                    counts->tris++;
                if (arbor_triangle_intersect(r, &prep, v[0], v[1], v[2], tmax, &tt, &u, &w)) {
                    if (any_hit)
                        return true;
                    found = true;
                    tmax = tt;
                    hit_u = u;
                    hit_v = w;
                    hit_slot = n->index + i;
                }
            }
        }
        /* next: the most recently pushed node that may still hold a closer hit */
        for (;;) {
            if (sp == 0)
                goto done;
            sp--;
            if (stack[sp].t <= tmax) {
                ni = stack[sp].node;
                break;
            }
        }
    }
done:
    if (found && h != NULL) {
        h->t = tmax;
        h->u = hit_u;
        h->v = hit_v;
        h->tri = t->tri_index[hit_slot];
    }
    return found;
}

bool bvh_intersect(const void *impl, arbor_ray *r, arbor_hit *h)
{
    if (!bvh_traverse(impl, r, false, h, NULL))
        return false;
    r->tmax = h->t;
    return true;
}

bool bvh_intersect_counted(const void *impl, arbor_ray *r, arbor_hit *h, arbor_trace_counts *c)
{
    if (!bvh_traverse(impl, r, false, h, c))
        return false;
    r->tmax = h->t;
    return true;
}

bool bvh_occluded(const void *impl, const arbor_ray *r)
{
    return bvh_traverse(impl, r, true, NULL, NULL);
}
