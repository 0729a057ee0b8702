/*
 * kd_sah.c - the surface area heuristic plane of Wald and Havran, "On
 * building fast kd-Trees for Ray Tracing, and on doing that in O(N log N)"
 * (2006), section 4 (FindPlane and the SAH with planar triangles).
 *
 * The cost of splitting a node (cell V, N triangles) at plane p into cells
 * V_L, V_R holding N_L, N_R triangles is
 *
 *     C(p) = lambda(p) * (KT + KI * (SA(V_L)/SA(V) * N_L + SA(V_R)/SA(V) * N_R))
 *
 * with lambda(p) = empty_factor (the paper's 0.8, i.e. 1 - empty_bonus)
 * when N_L = 0 or N_R = 0, which favours cutting off empty space, and 1
 * otherwise. Triangles lying in p go to whichever side gives the lower
 * cost. A leaf costs KI * N; the node is split only if some C(p) is lower.
 *
 * The candidate planes are the event positions. With the node's events
 * sorted by (axis, position, type), one sweep per axis knows at each
 * position how many triangles end there (p-), lie in it (p|) and start
 * there (p+); N_L counts the triangles started before p and N_R those not
 * yet ended, so each candidate costs O(1) and the sweep O(events).
 *
 * Planes on the cell's faces are skipped: they cannot separate anything
 * and would give an empty child of no volume.
 */
#include "kd_internal.h"

/* C(p) for children with area fractions pb, pa and nb, na triangles. */
static float kd_split_cost(const kd_builder *b, float pb, float pa, uint32_t nb, uint32_t na)
{
    float cost = b->cost_traverse + b->cost_intersect * (pb * (float)nb + pa * (float)na);
    return (nb == 0 || na == 0) ? b->empty_factor * cost : cost;
}

/* Sweeps axis k of t, lowering *best (and filling pl) at every plane
 * cheaper than it. */
static void kd_sah_sweep(const kd_builder *b, const kd_task *t, int k, float *best, kd_plane *pl, bool *found)
{
    arbor_vec3 ext = aabb_extent(t->cell);
    float ek = vec3_axis(ext, k), e1 = vec3_axis(ext, (k + 1) % 3), e2 = vec3_axis(ext, (k + 2) % 3);
    float lo = kd_lo(&t->cell, k), hi = kd_hi(&t->cell, k);
    /* a child of extent x along k has area 2 (e1 e2 + x (e1 + e2)) */
    float inv_area = 1.0f / (2.0f * (e1 * e2 + ek * (e1 + e2)));
    uint32_t nl = 0, nr = t->ntris;
    const kd_event *e = t->events + t->axis_begin[k], *end = t->events + t->axis_begin[k + 1];
    while (e < end) {
        /* the events at one position: ends, then planars, then starts */
        uint32_t at = kd_event_order(*e), ending = 0, planar = 0, starting = 0;
        for (; e < end && kd_event_order(*e) == at; e++) {
            kd_event_type type = kd_event_kind(*e);
            ending += type == KD_EVENT_END;
            planar += type == KD_EVENT_PLANAR;
            starting += type == KD_EVENT_START;
        }
        /* now nl counts the triangles that start before p and nr those that
         * end after p or lie after it; the `planar` ones lie in p */
        nr -= planar + ending;
        float p = kd_order_float(at);
        if (p > lo && p < hi) {
            float pb = 2.0f * (e1 * e2 + (p - lo) * (e1 + e2)) * inv_area;
            float pa = 2.0f * (e1 * e2 + (hi - p) * (e1 + e2)) * inv_area;
            /* with no triangle in the plane both sides cost the same */
            float cost_below = kd_split_cost(b, pb, pa, nl + planar, nr);
            float cost_above = planar ? kd_split_cost(b, pb, pa, nl, nr + planar) : cost_below;
            float cost = cost_below < cost_above ? cost_below : cost_above;
            if (cost < *best) {
                *best = cost;
                pl->axis = k;
                pl->pos = p;
                pl->planar_below = cost_below < cost_above;
                *found = true;
            }
        }
        nl += starting + planar;
    }
}

bool kd_sah_plane(const kd_builder *b, const kd_task *t, kd_plane *pl)
{
    /* a cell without area (a segment or a point) gives no probabilities */
    if (!(aabb_area(t->cell) > 0.0f))
        return false;
    float best = b->cost_intersect * (float)t->ntris;
    bool found = false;
    for (int k = 0; k < 3; k++)
        kd_sah_sweep(b, t, k, &best, pl, &found);
    return found;
}
