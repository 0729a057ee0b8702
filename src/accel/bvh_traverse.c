/*
 * bvh_traverse.c - closest-hit and any-hit queries through a built BVH.
 *
 * One traversal (bvh_traverse) serves all three queries. It is inlined into
 * each with constant arguments: `any_hit` chooses stopping at the first hit,
 * and `counts` is a compile-time NULL in the two uncounted queries, so their
 * counting code disappears.
 *
 * At an inner node both children's boxes are tested at once (one 8-lane AVX
 * slab test, two 4-lane ones without AVX); the ray descends into the nearer
 * one it enters (any-hit: the left one) and pushes the other, with its entry
 * distance, on a small stack. A popped node whose entry lies beyond the
 * closest hit so far is skipped. Triangles are tested with the watertight
 * arbor_triangle_intersect, on the same ray values brute force uses, so the
 * trees find the same hits.
 */
#include <immintrin.h>

#include "bvh_internal.h"

_Static_assert(sizeof(arbor_vec3) == 3 * sizeof(float), "tri_verts is read as an array of floats");

/* Per-ray constants of the slab test, in SSE lanes x, y, z (lane 3 unused):
 * the origin, the inverse direction (+-inf for a zero component: see
 * bvh_box_pair) and `neg`, all ones in the lanes whose direction is negative,
 * where the ray enters a slab through its hi plane and leaves through lo. */
typedef struct {
    __m128 org, inv, neg;
    float tmin;
} bvh_ray;

/* 1 + 2 gamma(3) with gamma(n) = n u / (1 - n u), u = 2^-24: scaling exit
 * distances by it makes the slab test conservative despite rounding (Ize,
 * "Robust BVH Ray Traversal", JCGT 2013), so no box a ray touches is culled. */
#define BVH_EXIT_SCALE 1.0000003576278687f

static inline void bvh_ray_setup(bvh_ray *q, const arbor_ray *r)
{
    q->org = _mm_setr_ps(r->o.x, r->o.y, r->o.z, 0.0f);
    q->inv = _mm_div_ps(_mm_set1_ps(1.0f), _mm_setr_ps(r->d.x, r->d.y, r->d.z, 1.0f));
    q->neg = _mm_cmplt_ps(q->inv, _mm_setzero_ps());
    q->tmin = r->tmin;
}

/* A node's planes as two vectors of lanes x, y, z: lo from bounds[0..3) and
 * hi from bounds[3..6). Lane 3 holds another bound (never the index or count,
 * whose bits could be denormals, slow in arithmetic); nothing reads it. */
static inline __m128 bvh_lo(const bvh_node *n) { return _mm_loadu_ps(n->bounds); }
static inline __m128 bvh_hi(const bvh_node *n)
{
    __m128 v = _mm_loadu_ps(n->bounds + 2); /* lo z, hi x, hi y, hi z */
    return _mm_shuffle_ps(v, v, _MM_SHUFFLE(0, 3, 2, 1));
}

/* The slab test of two nodes at once, each box in one half of the lanes when
 * AVX allows 8 (the SSE2 build does it half by half). Per lane k the entry
 * and exit distances are (plane - o) / d on the near and far plane, the exit
 * scaled up by BVH_EXIT_SCALE (scaling commutes with the minimum); then
 *   entry = max(entry_k, tmin), exit = min(exit_k, tmax)
 * with max/minps, which return their second operand when the first is NaN:
 * a zero direction component with the origin on one of that axis' planes
 * gives 0 * inf = NaN, and the slab then leaves the interval as it was (the
 * ray runs inside the plane). The box is entered when the largest entry is
 * at most the smallest exit, over lanes x, y, z. Returns the entry distance
 * of each node, INFINITY for a node the ray misses within [tmin, tmax]. */
#ifdef __AVX__
static inline __m256 bvh_pair(__m128 a, __m128 b) { return _mm256_insertf128_ps(_mm256_castps128_ps256(a), b, 1); }

/* The maximum (or minimum) of lanes x, y, z of each half, in every lane. */
static inline __m256 bvh_hmax3(__m256 v)
{
    v = _mm256_max_ps(v, _mm256_permute_ps(v, _MM_SHUFFLE(3, 0, 2, 1)));
    return _mm256_max_ps(v, _mm256_permute_ps(v, _MM_SHUFFLE(3, 1, 0, 2)));
}
static inline __m256 bvh_hmin3(__m256 v)
{
    v = _mm256_min_ps(v, _mm256_permute_ps(v, _MM_SHUFFLE(3, 0, 2, 1)));
    return _mm256_min_ps(v, _mm256_permute_ps(v, _MM_SHUFFLE(3, 1, 0, 2)));
}

static inline void bvh_box_pair(const bvh_node *a, const bvh_node *b, const bvh_ray *q, float tmax, float *ta,
                                float *tb)
{
    const __m256 org = bvh_pair(q->org, q->org), inv = bvh_pair(q->inv, q->inv), neg = bvh_pair(q->neg, q->neg);
    const __m256 lo = bvh_pair(bvh_lo(a), bvh_lo(b)), hi = bvh_pair(bvh_hi(a), bvh_hi(b));
    __m256 t_in = _mm256_mul_ps(_mm256_sub_ps(_mm256_blendv_ps(lo, hi, neg), org), inv);
    __m256 t_out = _mm256_mul_ps(_mm256_sub_ps(_mm256_blendv_ps(hi, lo, neg), org), inv);
    t_out = _mm256_mul_ps(t_out, _mm256_set1_ps(BVH_EXIT_SCALE));
    t_in = bvh_hmax3(_mm256_max_ps(t_in, _mm256_set1_ps(q->tmin)));
    t_out = bvh_hmin3(_mm256_min_ps(t_out, _mm256_set1_ps(tmax)));
    __m256 entry = _mm256_blendv_ps(_mm256_set1_ps(INFINITY), t_in, _mm256_cmp_ps(t_in, t_out, _CMP_LE_OQ));
    *ta = _mm256_cvtss_f32(entry);
    *tb = _mm_cvtss_f32(_mm256_extractf128_ps(entry, 1));
}
#else
static inline float bvh_box_entry(const bvh_node *n, const bvh_ray *q, float tmax)
{
    __m128 lo = bvh_lo(n), hi = bvh_hi(n);
    __m128 near = _mm_or_ps(_mm_and_ps(q->neg, hi), _mm_andnot_ps(q->neg, lo));
    __m128 far = _mm_or_ps(_mm_and_ps(q->neg, lo), _mm_andnot_ps(q->neg, hi));
    __m128 t_in = _mm_mul_ps(_mm_sub_ps(near, q->org), q->inv);
    __m128 t_out = _mm_mul_ps(_mm_mul_ps(_mm_sub_ps(far, q->org), q->inv), _mm_set1_ps(BVH_EXIT_SCALE));
    t_in = _mm_max_ps(t_in, _mm_set1_ps(q->tmin));
    t_out = _mm_min_ps(t_out, _mm_set1_ps(tmax));
    t_in = _mm_max_ps(t_in, _mm_shuffle_ps(t_in, t_in, _MM_SHUFFLE(3, 0, 2, 1)));
    t_in = _mm_max_ps(t_in, _mm_shuffle_ps(t_in, t_in, _MM_SHUFFLE(3, 1, 0, 2)));
    t_out = _mm_min_ps(t_out, _mm_shuffle_ps(t_out, t_out, _MM_SHUFFLE(3, 0, 2, 1)));
    t_out = _mm_min_ps(t_out, _mm_shuffle_ps(t_out, t_out, _MM_SHUFFLE(3, 1, 0, 2)));
    float t0 = _mm_cvtss_f32(t_in), t1 = _mm_cvtss_f32(t_out);
    return t0 <= t1 ? t0 : INFINITY;
}

static inline void bvh_box_pair(const bvh_node *a, const bvh_node *b, const bvh_ray *q, float tmax, float *ta,
                                float *tb)
{
    *ta = bvh_box_entry(a, q, tmax);
    *tb = bvh_box_entry(b, q, tmax);
}
#endif

/* The smaller and larger of two distances as one minss / maxss: written as a
 * compare and select, the compiler may make it a branch, mispredicted when
 * the order of two children is a coin toss. */
static inline float bvh_minf(float a, float b) { return _mm_cvtss_f32(_mm_min_ss(_mm_set_ss(a), _mm_set_ss(b))); }
static inline float bvh_maxf(float a, float b) { return _mm_cvtss_f32(_mm_max_ss(_mm_set_ss(a), _mm_set_ss(b))); }

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
    /* The triangle test in the ray's own axis order: the origin and each
     * vertex are permuted to (kx, ky, kz) once, and the test then runs with
     * the constant axes (0, 1, 2), so its per-component selects fold away.
     * It does the same arithmetic on the same values, so the same hits. */
    const int kx = prep.kx, ky = prep.ky, kz = prep.kz;
    const float o[3] = {r->o.x, r->o.y, r->o.z};
    const arbor_ray rp = {vec3(o[kx], o[ky], o[kz]), r->tmin, vec3(0.0f, 0.0f, 1.0f), r->tmax};
    const arbor_ray_prep pp = {0, 1, 2, prep.sx, prep.sy, prep.sz};
    float tmax = r->tmax;
    if (counts)
        counts->nodes++;
    float t_root, t_unused;
    bvh_box_pair(&nodes[0], &nodes[0], &q, tmax, &t_root, &t_unused);
    if (t_root == INFINITY)
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
            float t_left, t_right;
            bvh_box_pair(&nodes[left], &nodes[right], &q, tmax, &t_left, &t_right);
            if (counts)
                counts->nodes += 2;
            /* Nearer child first. Any hit will do for an any-hit query, so
             * it takes the left child first whenever entered: measured, that
             * is faster than ordering (no dependent compare before descending). */
            bool swap = any_hit ? t_left == INFINITY : t_right < t_left;
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
            const float *v = (const float *)(t->tri_verts + 3 * (size_t)n->index);
            for (uint32_t i = 0; i < n->count; i++, v += 9) {
                float tt, u, w;
                if (counts)
                    counts->tris++;
                arbor_vec3 a = vec3(v[kx], v[ky], v[kz]), b = vec3(v[3 + kx], v[3 + ky], v[3 + kz]),
                           c = vec3(v[6 + kx], v[6 + ky], v[6 + kz]);
                if (arbor_triangle_intersect(&rp, &pp, a, b, c, tmax, &tt, &u, &w)) {
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
            if (any_hit || stack[sp].t <= tmax) { /* an any-hit query never lowers tmax */
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
