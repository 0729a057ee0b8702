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
 * cost (above on a tie, as in the paper). A leaf costs KI * N; the node is split only if
 * some C(p) is lower: that is the only test that ends the recursion (with
 * the depth limit as a safety net; kd_build.c sets no leaf-size cap for
 * sah). Costs are computed and compared in double, so that the sum of
 * areas times counts does not round differently from plane to plane.
 *
 * The candidate planes are the event positions. With the node's events
 * sorted by (axis, position, type), one sweep per axis knows at each
 * position how many triangles end there (p-), lie in it (p|) and start
 * there (p+); N_L counts the triangles started before p and N_R those not
 * yet ended, so each candidate costs O(1) and the sweep O(events).
 *
 * Planes on the cell's faces: as in the paper, a plane on a face is a
 * candidate when triangles lie in it and go to the flat side, the child of
 * no extent along the axis (below at the low face, above at the high one):
 * this cuts a layer of planar triangles (a floor, a wall) off into a flat
 * cell that rays only reach where they cross it. Both sides then make
 * progress: the flat child has a smaller cell, the other fewer triangles.
 * A face plane with no triangle in it, or with its planar triangles on the
 * full side, separates nothing and is never a candidate, and neither is
 * any plane of a cell that is already flat along the axis.
 */
#include <math.h>

#include "kd_internal.h"

double kd_sah_cost(const kd_builder *b, double pb, double pa, uint32_t nb, uint32_t na)
{
    double cost = (double)b->cost_traverse + (double)b->cost_intersect * (pb * (double)nb + pa * (double)na);
    return (nb == 0 || na == 0) ? (double)b->empty_factor * cost : cost;
}

void kd_sah_fractions(const arbor_aabb *cell, int k, float p, double *pb, double *pa)
{
    double lo = kd_lo(cell, k), hi = kd_hi(cell, k);
    double e1 = (double)kd_hi(cell, (k + 1) % 3) - kd_lo(cell, (k + 1) % 3);
    double e2 = (double)kd_hi(cell, (k + 2) % 3) - kd_lo(cell, (k + 2) % 3);
    /* a cell of extent x along k has area 2 (e1 e2 + x (e1 + e2)) */
    double cap = e1 * e2, rim = e1 + e2, area = cap + (hi - lo) * rim;
    *pb = (cap + ((double)p - lo) * rim) / area;
    *pa = (cap + (hi - (double)p) * rim) / area;
}

/* Sweeps axis k of t, lowering *best (and filling pl) at every plane
 * cheaper than it. */
static void kd_sah_sweep(const kd_builder *b, const kd_task *t, int k, double *best, kd_plane *pl, bool *found)
{
    float lo = kd_lo(&t->cell, k), hi = kd_hi(&t->cell, k);
    if (!(lo < hi))
        return;
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
        /* the sides the planar triangles may take: either inside the cell,
         * only the flat one on a face */
        bool inside = p > lo && p < hi;
        bool may_below = inside || (p == lo && planar > 0);
        bool may_above = inside || (p == hi && planar > 0);
        if (may_below || may_above) {
            double pb, pa;
            kd_sah_fractions(&t->cell, k, p, &pb, &pa);
            double cost_below = may_below ? kd_sah_cost(b, pb, pa, nl + planar, nr) : INFINITY;
            double cost_above = may_above ? kd_sah_cost(b, pb, pa, nl, nr + planar) : INFINITY;
            bool below = cost_below < cost_above;
            double cost = below ? cost_below : cost_above;
            if (cost < *best) {
                *best = cost;
                pl->axis = k;
                pl->pos = p;
                pl->planar_below = below;
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
    double best = (double)b->cost_intersect * (double)t->ntris;
    bool found = false;
    for (int k = 0; k < 3; k++)
        kd_sah_sweep(b, t, k, &best, pl, &found);
    return found;
}
