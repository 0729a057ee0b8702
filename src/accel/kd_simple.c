/*
 * kd_simple.c - the planes of the three simple k-d builders: spatial (the
 * middle of the cell), median and mean (the median or mean centre of the
 * node's triangles' boxes clipped to the cell), each on the cell's longest
 * axis that makes progress. The SAH builder's plane is kd_sah.c's.
 */
#include "kd_internal.h"

/* The k-th smallest of v[0..n) (quickselect with a three-way partition,
 * so that runs of equal values, common in meshes, end it at once;
 * reorders v). */
static float kd_select(float *v, size_t n, size_t k)
{
    size_t lo = 0, hi = n;
    while (hi - lo > 1) {
        float pivot = v[lo + (hi - lo) / 2];
        /* [lo, lt) < pivot, [lt, i) == pivot, [gt, hi) > pivot */
        size_t lt = lo, i = lo, gt = hi;
        while (i < gt) {
            float x = v[i];
            if (x < pivot) {
                v[i++] = v[lt];
                v[lt++] = x;
            } else if (x > pivot) {
                v[i] = v[--gt];
                v[gt] = x;
            } else {
                i++;
            }
        }
        if (k < lt)
            hi = lt;
        else if (k >= gt)
            lo = gt;
        else
            return pivot;
    }
    return v[k];
}

/* Median or mean, along axis k, of the centres of t's triangles' boxes
 * clipped to the cell. Clipped boxes keep the centres inside the cell, so
 * straddling triangles cannot drag the plane outside it. */
static float kd_centroid_plane(const kd_builder *b, kd_scratch *s, const kd_task *t, int k)
{
    const kd_event *begin = t->events + t->axis_begin[k], *end = t->events + t->axis_begin[k + 1];
    if (b->builder == ARBOR_BUILD_MEAN) {
        double sum = 0.0;
        for (const kd_event *e = begin; e < end; e++)
            sum += kd_event_kind(*e) == KD_EVENT_PLANAR ? kd_event_pos(*e) : 0.5 * kd_event_pos(*e);
        return (float)(sum / t->ntris);
    }
    /* events are sorted by position, so a triangle's start precedes its end */
    size_t n = 0;
    for (const kd_event *e = begin; e < end; e++) {
        uint32_t tri = kd_event_tri(*e);
        switch (kd_event_kind(*e)) {
        case KD_EVENT_START:
            s->start[tri] = kd_event_pos(*e);
            break;
        case KD_EVENT_END:
            s->values[n++] = 0.5f * s->start[tri] + 0.5f * kd_event_pos(*e);
            break;
        case KD_EVENT_PLANAR:
            s->values[n++] = kd_event_pos(*e);
            break;
        }
    }
    return kd_select(s->values, n, n / 2);
}

/* The plane of spatial, median or mean on axis k: the middle of the cell,
 * or the median / mean clipped centre. A median or mean that is not
 * strictly inside the cell (the centres all lie on a face) falls back to
 * the middle. False when the cell is too thin to halve, or when the split
 * would make no progress: for spatial, when every triangle would go to
 * both sides; for median and mean, when either side would get every
 * triangle (an object split that separates none of them). */
static bool kd_simple_plane_on(const kd_builder *b, kd_scratch *s, const kd_task *t, int k, kd_plane *pl)
{
    float lo = kd_lo(&t->cell, k), hi = kd_hi(&t->cell, k);
    float mid = 0.5f * lo + 0.5f * hi;
    float p = b->builder == ARBOR_BUILD_SPATIAL ? mid : kd_centroid_plane(b, s, t, k);
    if (!(p > lo && p < hi))
        p = mid;
    if (!(p > lo && p < hi))
        return false;
    uint32_t nbelow = 0, nabove = 0, order = kd_float_order(p);
    for (size_t i = t->axis_begin[k]; i < t->axis_begin[k + 1]; i++) {
        kd_event e = t->events[i];
        kd_event_type type = kd_event_kind(e);
        uint32_t pos = kd_event_order(e);
        nbelow += (type == KD_EVENT_START && pos < order) || (type == KD_EVENT_PLANAR && pos <= order);
        nabove += (type == KD_EVENT_END && pos > order) || (type == KD_EVENT_PLANAR && pos > order);
    }
    bool all_below = nbelow == t->ntris, all_above = nabove == t->ntris;
    if (b->builder == ARBOR_BUILD_SPATIAL ? all_below && all_above : all_below || all_above)
        return false;
    pl->axis = k;
    pl->pos = p;
    pl->planar_below = true;
    return true;
}

/* The plane of spatial, median or mean: on the cell's longest axis, or,
 * when that makes no progress, on the next longest that does. */
bool kd_simple_plane(const kd_builder *b, kd_scratch *s, const kd_task *t, kd_plane *pl)
{
    arbor_vec3 ext = aabb_extent(t->cell);
    int k0 = vec3_max_axis(ext), k1 = (k0 + 1) % 3, k2 = (k0 + 2) % 3;
    if (vec3_axis(ext, k2) > vec3_axis(ext, k1)) {
        int swap = k1;
        k1 = k2;
        k2 = swap;
    }
    return kd_simple_plane_on(b, s, t, k0, pl) || kd_simple_plane_on(b, s, t, k1, pl) ||
           kd_simple_plane_on(b, s, t, k2, pl);
}
