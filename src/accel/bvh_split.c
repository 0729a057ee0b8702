/*
 * bvh_split.c - partitions of a node's triangle references and the simple
 * builders' splits: spatial median and object mean (a plane, bvh_partition),
 * object median (quickselect), halving by count (bvh_split_at). The SAH's
 * splits (bvh_sah.c) partition by the bin each centroid fell in, through
 * the same loop (bvh_partition_centroids). See bvh_builder.h.
 */
#ifdef __SSE4_1__
#include <smmintrin.h>
#endif

#include "bvh_builder.h"

/* The boxes of prims[b, e): for the splits that do not compute them as they
 * partition (median, halving by count). */
void bvh_range_bounds(const bvh_builder *B, uint32_t b, uint32_t e, range_box *r)
{
    r->box = r->cbox = box_empty();
    for (uint32_t i = b; i < e; i++) {
        __m128 lo = prim_lo(&B->prims[i]), hi = prim_hi(&B->prims[i]), c = centroid2(lo, hi);
        box_grow(&r->box, lo, hi);
        box_grow(&r->cbox, c, c);
    }
}

/* Moves the references of prims[b, e) whose centroid lies below pos on axis
 * to the front and returns where the others start: quickselect's partition. */
static uint32_t partition_below(const bvh_builder *B, uint32_t b, uint32_t e, int axis, float pos)
{
    uint32_t m = b;
    /* invariant: prims[b, m) below pos, prims[m, i) not below. Every element
     * is swapped and m advances by the comparison's value: no branch on it,
     * which would be mispredicted half the time near the root. */
    for (uint32_t i = b; i < e; i++) {
        uint32_t below = centroid_axis(B, i, axis) < pos;
        prim_swap(B->prims, i, m);
        m += below;
    }
    return m;
}

static float median_of_three(float a, float b, float c)
{
    return arbor_maxf(arbor_minf(a, b), arbor_minf(arbor_maxf(a, b), c));
}

/* Quickselect (Hoare's FIND): reorders prims[b, e) so that the reference
 * with the k-th smallest centroid on axis is at k, none larger before it and
 * none smaller after it. Expected O(e - b). Each round splits the range
 * three ways (below, equal to, above the pivot), so equal centroids cannot
 * stall it. */
static void select_nth(const bvh_builder *B, uint32_t b, uint32_t e, uint32_t k, int axis)
{
    while (e - b > 1) {
        float pivot = median_of_three(centroid_axis(B, b, axis), centroid_axis(B, b + (e - b) / 2, axis),
                                      centroid_axis(B, e - 1, axis));
        uint32_t lt = partition_below(B, b, e, axis, pivot);
        uint32_t le = partition_below(B, lt, e, axis, nextafterf(pivot, INFINITY));
        if (k < lt)
            e = lt;
        else if (k >= le)
            b = le;
        else
            return;
        if (lt == le)
            return; /* the pivot was NaN (a NaN vertex): no order to find */
    }
}

/* Splits prims[b, e) at m and measures both halves. */
uint32_t bvh_split_at(const bvh_builder *B, uint32_t b, uint32_t m, uint32_t e, range_box kids[2])
{
    bvh_range_bounds(B, b, m, &kids[0]);
    bvh_range_bounds(B, m, e, &kids[1]);
    return m;
}

/* The object median split on axis: both halves non-empty for e - b >= 2. */
uint32_t bvh_split_median(const bvh_builder *B, uint32_t b, uint32_t e, int axis, range_box kids[2])
{
    uint32_t m = b + (e - b) / 2;
    select_nth(B, b, e, m, axis);
    return bvh_split_at(B, b, m, e, kids);
}

float bvh_centroid_mean(const bvh_builder *B, uint32_t b, uint32_t e, int axis)
{
    double sum = 0.0;
    for (uint32_t i = b; i < e; i++)
        sum += centroid_axis(B, i, axis);
    return (float)(sum / (double)(e - b));
}

static inline uint32_t goes_left(const split_rule *r, __m128 c)
{
    __m128 below = r->by_bin ? _mm_castsi128_ps(_mm_cmplt_epi32(bin_of(r->grid, c), r->limit_bin))
                             : _mm_cmplt_ps(c, r->limit_pos);
    return (uint32_t)_mm_movemask_ps(below) >> r->axis & 1;
}

/* mask ? a : b, lane by lane (mask lanes all ones or all zeros). */
static inline __m128 select4(__m128 mask, __m128 a, __m128 b)
{
#ifdef __SSE4_1__
    return _mm_blendv_ps(b, a, mask);
#else
    return _mm_or_ps(_mm_and_ps(mask, a), _mm_andnot_ps(mask, b));
#endif
}

/* Grows the side the mask selects by a reference's centroid and, when
 * `boxes`, its box: the other side grows by an empty box, so neither needs
 * a branch. */
static inline void side_grow(range_box *r, __m128 mask, __m128 lo, __m128 hi, __m128 c, bool boxes)
{
    const __m128 inf = _mm_set1_ps(INFINITY), ninf = _mm_set1_ps(-INFINITY);
    if (boxes)
        box_grow(&r->box, select4(mask, lo, inf), select4(mask, hi, ninf));
    box_grow(&r->cbox, select4(mask, c, inf), select4(mask, c, ninf));
}

/* Moves the references of prims[b, e) that go left by rule to the front,
 * computing both sides' centroid boxes on the way and, when `boxes`, their
 * boxes (else left empty); returns where the right side starts (b or e
 * when one side is empty; kids are then meaningless). Inlined with a
 * constant `boxes` into its two callers. */
static inline uint32_t partition_sides(const bvh_builder *B, uint32_t b, uint32_t e, const split_rule *rule,
                                       range_box kids[2], bool boxes)
{
    bvh_prim *p = B->prims;
    range_box left = {box_empty(), box_empty()}, right = left;
    uint32_t m = b;
    /* invariant: prims[b, m) go left, prims[m, i) go right. Every element
     * is swapped and m advances by the side, without a branch on it (see
     * partition_below); the swap moves the registers already loaded, whole
     * 16-byte halves, which later loads can take straight from the stores. */
    for (uint32_t i = b; i < e; i++) {
        __m128 lo = prim_lo(&p[i]), hi = prim_hi(&p[i]), c = centroid2(lo, hi);
        uint32_t goes = goes_left(rule, c);
        __m128 mask = _mm_castsi128_ps(_mm_set1_epi32(-(int32_t)goes));
        side_grow(&left, mask, lo, hi, c, boxes);
        side_grow(&right, _mm_xor_ps(mask, _mm_castsi128_ps(_mm_set1_epi32(-1))), lo, hi, c, boxes);
        __m128 mlo = prim_lo(&p[m]), mhi = prim_hi(&p[m]);
        _mm_storeu_ps(p[m].lo, lo);
        _mm_storeu_ps(p[m].hi, hi);
        _mm_storeu_ps(p[i].lo, mlo);
        _mm_storeu_ps(p[i].hi, mhi);
        m += goes;
    }
    kids[0] = left;
    kids[1] = right;
    return m;
}

uint32_t bvh_partition(const bvh_builder *B, uint32_t b, uint32_t e, const split_rule *rule, range_box kids[2])
{
    return partition_sides(B, b, e, rule, kids, true);
}

uint32_t bvh_partition_centroids(const bvh_builder *B, uint32_t b, uint32_t e, const split_rule *rule,
                                 range_box kids[2])
{
    return partition_sides(B, b, e, rule, kids, false);
}
