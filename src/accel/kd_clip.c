/*
 * kd_clip.c - perfect splits: a triangle that straddles a split plane is
 * clipped to its node's cell (Sutherland-Hodgman), and the polygon left is
 * cut by the plane, so that each child gets the box of the part of the
 * triangle really inside its cell rather than the triangle's whole box.
 * kd_split.c turns those boxes into the children's new events.
 */
#include <math.h>

#include "kd_internal.h"

/* A vertex of a clipped polygon. Bit k of `exact` says coordinate k carries
 * no rounding error: it is a mesh vertex's, or the clipping plane's, or both
 * ends of the clipped edge had it exactly. */
typedef struct {
    float v[3];
    unsigned exact;
} kd_clip_vertex;

/* A triangle clipped by six planes has at most 3 + 6 vertices (and one
 * more plane, the split, may add a tenth). */
#define KD_CLIP_MAX 10

/* Sutherland-Hodgman with one plane, both ways at once: the part of
 * polygon in (n vertices) with coordinate k <= bound goes to below, the
 * part with coordinate k >= bound to above (either may be NULL; counts in
 * *nb, *na). Vertices on the plane go to both sides, and an edge crossing
 * it strictly adds its crossing point to both. */
static void kd_cut(const kd_clip_vertex *in, int n, int k, float bound, kd_clip_vertex *below, int *nb,
                   kd_clip_vertex *above, int *na)
{
    int where[KD_CLIP_MAX];  /* -1 below the plane, 0 on it, 1 above */
    for (int i = 0; i < n; i++)
        where[i] = (in[i].v[k] > bound) - (in[i].v[k] < bound);
    int nbelow = 0, nabove = 0;
    for (int i = 0; i < n; i++) {
        int j = i + 1 == n ? 0 : i + 1;
        const kd_clip_vertex *a = &in[i], *c = &in[j];
        if (below != NULL && where[i] <= 0)
            below[nbelow++] = *a;
        if (above != NULL && where[i] >= 0)
            above[nabove++] = *a;
        if (where[i] * where[j] < 0) {
            /* built in registers and stored field by field: a vertex
             * built on the stack and copied whole stalls store forwarding */
            float s = (bound - a->v[k]) / (c->v[k] - a->v[k]);
            float x0 = k == 0 ? bound : a->v[0] + (c->v[0] - a->v[0]) * s;
            float x1 = k == 1 ? bound : a->v[1] + (c->v[1] - a->v[1]) * s;
            float x2 = k == 2 ? bound : a->v[2] + (c->v[2] - a->v[2]) * s;
            unsigned same = (a->v[0] == c->v[0]) | (a->v[1] == c->v[1]) << 1 | (a->v[2] == c->v[2]) << 2;
            unsigned exact = 1u << k | (a->exact & c->exact & same);
            kd_clip_vertex *out[2] = {below ? &below[nbelow++] : NULL, above ? &above[nabove++] : NULL};
            for (int o = 0; o < 2; o++)
                if (out[o] != NULL) {
                    out[o]->v[0] = x0;
                    out[o]->v[1] = x1;
                    out[o]->v[2] = x2;
                    out[o]->exact = exact;
                }
        }
    }
    if (nb != NULL)
        *nb = nbelow;
    if (na != NULL)
        *na = nabove;
}

/* Whether some vertex of poly lies beyond bound on axis k: below it when
 * keep_above, above it otherwise. */
static bool kd_sticks_out(const kd_clip_vertex *poly, int n, int k, float bound, bool keep_above)
{
    for (int i = 0; i < n; i++)
        if (keep_above ? poly[i].v[k] < bound : poly[i].v[k] > bound)
            return true;
    return false;
}

/* The box of polygon poly (n > 0 vertices) within cell. Coordinates that
 * clipping computed are rounded outwards by `slack` (more than their
 * rounding error), so the box never misses a part of the triangle; exact
 * ones stay exact, so a triangle flat on an axis stays planar there. */
static arbor_aabb kd_polygon_box(const kd_clip_vertex *poly, int n, float slack, const arbor_aabb *cell)
{
    float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (int i = 0; i < n; i++)
        for (int k = 0; k < 3; k++) {
            float v = poly[i].v[k];
            float d = (poly[i].exact & (1u << k)) ? 0.0f : slack;
            lo[k] = v - d < lo[k] ? v - d : lo[k];
            hi[k] = v + d > hi[k] ? v + d : hi[k];
        }
    for (int k = 0; k < 3; k++) {
        lo[k] = lo[k] > kd_lo(cell, k) ? lo[k] : kd_lo(cell, k);
        hi[k] = hi[k] < kd_hi(cell, k) ? hi[k] : kd_hi(cell, k);
    }
    arbor_aabb box = {vec3(lo[0], lo[1], lo[2]), vec3(hi[0], hi[1], hi[2])};
    return box;
}

/* Perfect split of a straddling triangle: triangle tri clipped to the cell
 * (Sutherland-Hodgman), then that polygon cut by the plane into the parts
 * in the below and above cells. in[c] says whether part c (0 below, 1
 * above) is non-empty, and box[c] is then its box. */
void kd_clip_split(const kd_builder *b, uint32_t tri, const arbor_aabb *cell, kd_plane pl,
                   const arbor_aabb child_cell[2], bool in[2], arbor_aabb box[2])
{
    kd_clip_vertex buf[2][KD_CLIP_MAX], *poly = buf[0], *spare = buf[1];
    arbor_vec3 p[3];
    arbor_mesh_tri(b->mesh, tri, &p[0], &p[1], &p[2]);
    for (int i = 0; i < 3; i++) {
        kd_clip_vertex v = {{p[i].x, p[i].y, p[i].z}, 7u};
        poly[i] = v;
    }
    int n = 3;
    /* the cell's six faces: lo on each axis keeps what is above it, hi
     * what is below; faces the polygon does not cross cost no copy */
    for (int face = 0; face < 6 && n > 0; face++) {
        int k = face >> 1;
        bool keep_above = (face & 1) == 0;
        float bound = keep_above ? kd_lo(cell, k) : kd_hi(cell, k);
        if (!kd_sticks_out(poly, n, k, bound, keep_above))
            continue;
        if (keep_above)
            kd_cut(poly, n, k, bound, NULL, NULL, spare, &n);
        else
            kd_cut(poly, n, k, bound, spare, &n, NULL, NULL);
        kd_clip_vertex *swap = poly;
        poly = spare;
        spare = swap;
    }
    kd_clip_vertex part[2][KD_CLIP_MAX];
    int count[2] = {0, 0};
    if (n > 0)
        kd_cut(poly, n, pl.axis, pl.pos, part[0], &count[0], part[1], &count[1]);
    for (int c = 0; c < 2; c++) {
        in[c] = count[c] > 0;
        if (in[c])
            box[c] = kd_polygon_box(part[c], count[c], b->clip_slack, &child_cell[c]);
    }
}
