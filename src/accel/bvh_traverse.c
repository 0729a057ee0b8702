/*
 * bvh_traverse.c - closest-hit and any-hit queries through the wide tree
 * (bvh_internal.h, bvh_wide.c).
 *
 * One traversal (bvh_traverse) serves all three queries. It is inlined into
 * each with constant arguments: `any_hit` chooses stopping at the first hit,
 * and `counts` is a compile-time NULL in the two uncounted queries, so their
 * counting code disappears.
 *
 * At a wide node one 4-lane slab test checks every child's box. The ray goes
 * on into the nearest child it enters and pushes the others, farthest first,
 * with their entry distances, on a stack; a popped entry whose distance lies
 * beyond the closest hit so far is skipped. An any-hit query needs no order
 * and takes the children as they come. A leaf's packs are tested four
 * triangles per step (pack_test), with the arithmetic of
 * arbor_triangle_intersect lane by lane, so each triangle gives exactly the
 * t, u, v brute force computes for it.
 *
 * Ties. Among hits at exactly the same t the lowest triangle index wins, as
 * in brute force and the k-d tree, whatever leaf or lane finds them: once
 * there is a hit the triangle tests accept t up to the next float above
 * it, so an equal t reaches the index comparison, and popped entries are
 * skipped only when their entry distance is beyond the hit (entry <= t is
 * still visited: such a box may hold a tie).
 */
#include <immintrin.h>

#include "bvh_internal.h"

/* 1 + 2 gamma(3) with gamma(n) = n u / (1 - n u), u = 2^-24: scaling exit
 * distances by it makes the slab test conservative despite rounding (Ize,
 * "Robust BVH Ray Traversal", JCGT 2013), so no box a ray touches is culled. */
#define BVH_EXIT_SCALE 1.0000003576278687f

/* The helpers below must be inlined into the traversal: a call per node or
 * per ray costs as much as the work (measured on sponza, whose rays mostly
 * leave the model after a few nodes). */
#define BVH_INLINE static inline __attribute__((always_inline))

/* Per-ray constants of the box test, each broadcast to all lanes: the
 * origin, the inverse direction (+-inf for a zero component), and per axis
 * the row of a node's boxes the ray enters through (lo, or hi when the
 * direction is negative) and the row it leaves through. */
typedef struct {
    __m128 org[3], inv[3];
    int near[3], far[3];
    __m128 tmin;
} box_ray;

BVH_INLINE void box_ray_setup(box_ray *q, const arbor_ray *r)
{
    /* one divps for the three axes: the divisions would otherwise queue
     * one behind another at the start of every ray */
    const __m128 o = _mm_setr_ps(r->o.x, r->o.y, r->o.z, 0.0f);
    const __m128 inv = _mm_div_ps(_mm_set1_ps(1.0f), _mm_setr_ps(r->d.x, r->d.y, r->d.z, 1.0f));
    const int neg = _mm_movemask_ps(_mm_cmplt_ps(inv, _mm_setzero_ps()));
    q->org[0] = _mm_shuffle_ps(o, o, _MM_SHUFFLE(0, 0, 0, 0));
    q->org[1] = _mm_shuffle_ps(o, o, _MM_SHUFFLE(1, 1, 1, 1));
    q->org[2] = _mm_shuffle_ps(o, o, _MM_SHUFFLE(2, 2, 2, 2));
    q->inv[0] = _mm_shuffle_ps(inv, inv, _MM_SHUFFLE(0, 0, 0, 0));
    q->inv[1] = _mm_shuffle_ps(inv, inv, _MM_SHUFFLE(1, 1, 1, 1));
    q->inv[2] = _mm_shuffle_ps(inv, inv, _MM_SHUFFLE(2, 2, 2, 2));
    for (int a = 0; a < 3; a++) {
        int is_neg = (neg >> a) & 1;
        q->near[a] = a + 3 * is_neg;
        q->far[a] = a + 3 - 3 * is_neg;
    }
    q->tmin = _mm_set1_ps(r->tmin);
}

/* Per-ray constants of the triangle test (the watertight test's, ray.h):
 * the axis permutation k, the origin in that order, the shear constants.
 * Set up at the first leaf a ray reaches: many rays never reach one. */
typedef struct {
    int k[3];
    __m128 org[3], shear[3], tmin;
} tri_ray;

BVH_INLINE void tri_ray_setup(tri_ray *q, const arbor_ray *r)
{
    const float o[3] = {r->o.x, r->o.y, r->o.z};
    arbor_ray_prep p;
    arbor_ray_prepare(r, &p);
    q->k[0] = p.kx;
    q->k[1] = p.ky;
    q->k[2] = p.kz;
    for (int a = 0; a < 3; a++)
        q->org[a] = _mm_set1_ps(o[q->k[a]]);
    q->shear[0] = _mm_set1_ps(p.sx);
    q->shear[1] = _mm_set1_ps(p.sy);
    q->shear[2] = _mm_set1_ps(p.sz);
    q->tmin = _mm_set1_ps(r->tmin);
}

/* The slab test of a node's children. Per axis the entry and exit distances
 * are (plane - o) / d on the near and far plane, the exit scaled up by
 * BVH_EXIT_SCALE; then entry = max(entries, tmin), exit = min(exits, tmax),
 * folded with max/minps, which return their second operand when the first
 * is NaN: a zero direction component with the origin on one of that axis'
 * planes gives 0 * inf = NaN, and the slab then leaves the interval as it
 * was (the ray runs inside the plane). Returns the mask of children entered,
 * entry <= exit, and each one's entry distance in *entry. Empty slots
 * (lo +inf, hi -inf) give entry +inf and exit -inf on every axis. */
BVH_INLINE int wide_boxes(const bvh_wide_node *n, const box_ray *q, __m128 tmax, __m128 *entry)
{
    const __m128 scale = _mm_set1_ps(BVH_EXIT_SCALE);
    __m128 t_in = q->tmin, t_out = tmax;
    for (int a = 2; a >= 0; a--) {
        __m128 near = _mm_mul_ps(_mm_sub_ps(_mm_load_ps(n->box[q->near[a]]), q->org[a]), q->inv[a]);
        __m128 far = _mm_mul_ps(_mm_sub_ps(_mm_load_ps(n->box[q->far[a]]), q->org[a]), q->inv[a]);
        t_in = _mm_max_ps(near, t_in);
        t_out = _mm_min_ps(_mm_mul_ps(far, scale), t_out);
    }
    *entry = t_in;
    return _mm_movemask_ps(_mm_cmple_ps(t_in, t_out));
}

/* The watertight test (arbor_triangle_intersect) of four triangles, the same
 * operations in the same order on each lane, so the same results. Returns
 * the mask of lanes hit in (tmin, tmax), with their distances in *t and
 * their U, V, W and 1 / det in the rest for the barycentrics. Unused lanes
 * hold NaN vertices, which make every comparison false: never a hit. */
typedef struct {
    __m128 hit, t, v, w, inv;
} pack_hits;

BVH_INLINE int pack_test(const bvh_tri_pack *p, const tri_ray *q, __m128 tmax, pack_hits *out)
{
    const int kx = q->k[0], ky = q->k[1], kz = q->k[2];
    __m128 az = _mm_sub_ps(_mm_load_ps(p->v[0][kz]), q->org[2]);
    __m128 bz = _mm_sub_ps(_mm_load_ps(p->v[1][kz]), q->org[2]);
    __m128 cz = _mm_sub_ps(_mm_load_ps(p->v[2][kz]), q->org[2]);
    __m128 ax = _mm_sub_ps(_mm_sub_ps(_mm_load_ps(p->v[0][kx]), q->org[0]), _mm_mul_ps(q->shear[0], az));
    __m128 ay = _mm_sub_ps(_mm_sub_ps(_mm_load_ps(p->v[0][ky]), q->org[1]), _mm_mul_ps(q->shear[1], az));
    __m128 bx = _mm_sub_ps(_mm_sub_ps(_mm_load_ps(p->v[1][kx]), q->org[0]), _mm_mul_ps(q->shear[0], bz));
    __m128 by = _mm_sub_ps(_mm_sub_ps(_mm_load_ps(p->v[1][ky]), q->org[1]), _mm_mul_ps(q->shear[1], bz));
    __m128 cx = _mm_sub_ps(_mm_sub_ps(_mm_load_ps(p->v[2][kx]), q->org[0]), _mm_mul_ps(q->shear[0], cz));
    __m128 cy = _mm_sub_ps(_mm_sub_ps(_mm_load_ps(p->v[2][ky]), q->org[1]), _mm_mul_ps(q->shear[1], cz));
    __m128 u = _mm_sub_ps(_mm_mul_ps(cx, by), _mm_mul_ps(cy, bx));
    __m128 v = _mm_sub_ps(_mm_mul_ps(ax, cy), _mm_mul_ps(ay, cx));
    __m128 w = _mm_sub_ps(_mm_mul_ps(bx, ay), _mm_mul_ps(by, ax));
    const __m128 zero = _mm_setzero_ps();
    int on_edge = _mm_movemask_ps(
        _mm_or_ps(_mm_or_ps(_mm_cmpeq_ps(u, zero), _mm_cmpeq_ps(v, zero)), _mm_cmpeq_ps(w, zero)));
    if (__builtin_expect(on_edge != 0, 0)) {
        /* on an edge in single precision: decide those lanes exactly in double */
        float Ax[4], Ay[4], Bx[4], By[4], Cx[4], Cy[4], U[4], V[4], W[4];
        _mm_storeu_ps(Ax, ax), _mm_storeu_ps(Ay, ay), _mm_storeu_ps(Bx, bx), _mm_storeu_ps(By, by);
        _mm_storeu_ps(Cx, cx), _mm_storeu_ps(Cy, cy);
        _mm_storeu_ps(U, u), _mm_storeu_ps(V, v), _mm_storeu_ps(W, w);
        for (int l = 0; l < 4; l++)
            if (on_edge & (1 << l))
                arbor_edge_functions_exact(Ax[l], Ay[l], Bx[l], By[l], Cx[l], Cy[l], &U[l], &V[l], &W[l]);
        u = _mm_loadu_ps(U), v = _mm_loadu_ps(V), w = _mm_loadu_ps(W);
    }
    __m128 some_neg = _mm_or_ps(_mm_or_ps(_mm_cmplt_ps(u, zero), _mm_cmplt_ps(v, zero)), _mm_cmplt_ps(w, zero));
    __m128 some_pos = _mm_or_ps(_mm_or_ps(_mm_cmpgt_ps(u, zero), _mm_cmpgt_ps(v, zero)), _mm_cmpgt_ps(w, zero));
    __m128 det = _mm_add_ps(_mm_add_ps(u, v), w);
    __m128 sz = q->shear[2];
    __m128 T = _mm_add_ps(_mm_add_ps(_mm_mul_ps(_mm_mul_ps(u, sz), az), _mm_mul_ps(_mm_mul_ps(v, sz), bz)),
                          _mm_mul_ps(_mm_mul_ps(w, sz), cz));
    __m128 inv = _mm_div_ps(_mm_set1_ps(1.0f), det);
    __m128 t = _mm_mul_ps(T, inv);
    /* det == 0 needs no test of its own: then inv is infinite and t is
     * NaN or infinite, outside (tmin, tmax) */
    __m128 hit = _mm_andnot_ps(_mm_and_ps(some_neg, some_pos),
                               _mm_and_ps(_mm_cmpgt_ps(t, q->tmin), _mm_cmplt_ps(t, tmax)));
    out->hit = hit;
    out->t = t;
    out->v = v;
    out->w = w;
    out->inv = inv;
    return _mm_movemask_ps(hit);
}

BVH_INLINE float lane(__m128 v, int l)
{
    float f[4];
    _mm_storeu_ps(f, v);
    return f[l];
}

typedef struct {
    uint64_t ref;
    float t;
} stack_entry;

/* Where the traversal is, for a visitor: the box it entered the node by and
 * the node's depth in the wide tree. */
typedef struct {
    arbor_aabb box;
    uint32_t depth;
} visit_place;

static arbor_aabb lane_box(const bvh_wide_node *n, int c)
{
    arbor_aabb b = {vec3(n->box[0][c], n->box[1][c], n->box[2][c]), vec3(n->box[3][c], n->box[4][c], n->box[5][c])};
    return b;
}

/* The root's box: the union of its children's. */
static arbor_aabb root_box(const bvh_tree *t)
{
    arbor_aabb b = {vec3(INFINITY, INFINITY, INFINITY), vec3(-INFINITY, -INFINITY, -INFINITY)};
    for (int c = 0; c < BVH_WIDTH; c++)
        if (t->wide[0].child[c] != 0) {
            arbor_aabb l = lane_box(&t->wide[0], c);
            b.lo = vec3_min(b.lo, l.lo);
            b.hi = vec3_max(b.hi, l.hi);
        }
    return b;
}

static void visit_node(arbor_node_fn visit, void *user, const visit_place *at, bool leaf, uint32_t tris,
                       uint32_t tests)
{
    arbor_node_info info = {at->box, at->depth, leaf, tris, tests};
    visit(user, &info);
}

/* The closest hit (any_hit false) or the first found (any_hit true) in
 * (r->tmin, r->tmax); fills *h on a hit unless h is NULL. counts, when not
 * NULL, gets the child boxes and the triangles tested; visit, when not
 * NULL, each node visited (the inspector's ray path). counts and visit are
 * compile-time NULL in the plain queries, which lose their code. */
BVH_INLINE bool bvh_traverse(const bvh_tree *t, const arbor_ray *r, bool any_hit, arbor_hit *h,
                             arbor_trace_counts *counts, arbor_node_fn visit, void *user)
{
    if (t->nwide == 0)
        return false;
    visit_place at = {{vec3(0, 0, 0), vec3(0, 0, 0)}, 0};
    visit_place places[BVH_MAX_DEPTH * (BVH_WIDTH - 1)]; /* the stack's places; untouched without visit */
    if (visit)
        at.box = root_box(t);
    box_ray q;
    box_ray_setup(&q, r);
    tri_ray tq;
    bool tq_ready = false;
    /* tmax: the closest hit so far; limit: the triangle tests' bound, just
     * above tmax once there is a hit, so that a tie reaches the index rule */
    float tmax = r->tmax, limit = r->tmax;
    stack_entry stack[BVH_MAX_DEPTH * (BVH_WIDTH - 1)];
    uint32_t sp = 0;
    uint64_t ref = 0; /* the root */
    bool found = false;
    float hit_u = 0.0f, hit_v = 0.0f;
    uint32_t hit_slot = 0;
    for (;;) {
        if (!bvh_ref_is_leaf(ref)) {
            const bvh_wide_node *n = &t->wide[bvh_ref_index(ref)];
            __m128 entry;
            int mask = wide_boxes(n, &q, _mm_set1_ps(tmax), &entry);
            if (counts)
                for (int c = 0; c < BVH_WIDTH; c++)
                    counts->nodes += n->child[c] != 0;
            if (visit) {
                uint32_t tested = 0;
                for (int c = 0; c < BVH_WIDTH; c++)
                    tested += n->child[c] != 0;
                visit_node(visit, user, &at, false, 0, tested);
            }
            if (mask != 0) {
                float te[4];
                _mm_storeu_ps(te, entry);
                int c = __builtin_ctz(mask);
                mask &= mask - 1;
                uint64_t near = n->child[c];
                float t_near = te[c];
                int near_lane = c;
                const uint32_t base = sp;
                /* push the rest; for a closest hit keep the nearest to go
                 * into and push in order, farthest deepest */
                while (mask != 0) {
                    c = __builtin_ctz(mask);
                    mask &= mask - 1;
                    uint64_t other = n->child[c];
                    float t_other = te[c];
                    int other_lane = c;
                    if (!any_hit && t_other < t_near) {
                        uint64_t r0 = near;
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
                        places[i] = (visit_place){lane_box(n, other_lane), at.depth + 1};
                }
                ref = near;
                if (visit)
                    at = (visit_place){lane_box(n, near_lane), at.depth + 1};
                continue;
            }
        } else {
            uint32_t tris = bvh_ref_tris(ref), p0 = bvh_ref_index(ref);
            if (counts)
                counts->tris += tris;
            if (visit)
                visit_node(visit, user, &at, true, tris, 0);
            if (!tq_ready) {
                tri_ray_setup(&tq, r);
                tq_ready = true;
            }
            for (uint32_t p = p0; p < p0 + bvh_packs_for(tris); p++) {
                pack_hits ph;
                int hits = pack_test(&t->packs[p], &tq, _mm_set1_ps(limit), &ph);
                if (hits == 0)
                    continue;
                if (any_hit)
                    return true;
                /* the nearest lane hit; among lanes at that t the lowest
                 * triangle index, and against the best so far the same */
                __m128 th = _mm_or_ps(_mm_and_ps(ph.hit, ph.t), _mm_andnot_ps(ph.hit, _mm_set1_ps(INFINITY)));
                __m128 m = _mm_min_ps(th, _mm_shuffle_ps(th, th, _MM_SHUFFLE(2, 3, 0, 1)));
                m = _mm_min_ps(m, _mm_shuffle_ps(m, m, _MM_SHUFFLE(1, 0, 3, 2)));
                int nearest = _mm_movemask_ps(_mm_cmpeq_ps(th, m)) & hits;
                int l = __builtin_ctz(nearest);
                for (int o = nearest & (nearest - 1); o != 0; o &= o - 1)
                    if (t->pack_tri[BVH_WIDTH * p + (uint32_t)__builtin_ctz(o)] < t->pack_tri[BVH_WIDTH * p + (uint32_t)l])
                        l = __builtin_ctz(o);
                float tl = lane(ph.t, l);
                uint32_t slot = BVH_WIDTH * p + (uint32_t)l;
                if (found && tl == tmax && t->pack_tri[slot] > t->pack_tri[hit_slot])
                    continue;
                found = true;
                tmax = tl;
                limit = nextafterf(tl, INFINITY);
                hit_u = lane(ph.v, l) * lane(ph.inv, l);
                hit_v = lane(ph.w, l) * lane(ph.inv, l);
                hit_slot = slot;
            }
        }
        /* next: the most recently pushed entry that may still hold a closer hit */
        for (;;) {
            if (sp == 0)
                goto done;
            sp--;
            if (any_hit || stack[sp].t <= tmax) { /* an any-hit query never lowers tmax */
                ref = stack[sp].ref;
                if (visit)
                    at = places[sp];
                break;
            }
        }
    }
done:
    if (found && h != NULL) {
        h->t = tmax;
        h->u = hit_u;
        h->v = hit_v;
        h->tri = t->pack_tri[hit_slot];
    }
    return found;
}

bool bvh_intersect(const void *impl, arbor_ray *r, arbor_hit *h)
{
    if (!bvh_traverse(impl, r, false, h, NULL, NULL, NULL))
        return false;
    r->tmax = h->t;
    return true;
}

bool bvh_intersect_counted(const void *impl, arbor_ray *r, arbor_hit *h, arbor_trace_counts *c)
{
    if (!bvh_traverse(impl, r, false, h, c, NULL, NULL))
        return false;
    r->tmax = h->t;
    return true;
}

bool bvh_intersect_traced(const void *impl, arbor_ray *r, arbor_hit *h, arbor_trace_counts *c, arbor_node_fn visit,
                          void *user)
{
    if (!bvh_traverse(impl, r, false, h, c, visit, user))
        return false;
    r->tmax = h->t;
    return true;
}

bool bvh_occluded(const void *impl, const arbor_ray *r)
{
    return bvh_traverse(impl, r, true, NULL, NULL, NULL, NULL);
}
