/*
 * kd_build.c - building k-d trees: the recursion all four builders share,
 * and the planes of the three simple ones (spatial, median, mean).
 *
 * Every builder works on the event lists of Wald and Havran, "On building
 * fast kd-Trees for Ray Tracing, and on doing that in O(N log N)" (2006):
 *
 *   1. At the root, each triangle's box gives two events per axis (start,
 *      end) or one (planar, when the box is flat there), and all events are
 *      sorted ONCE by (axis, position, type).
 *   2. A node chooses a plane (kd_choose_plane): the SAH sweep of kd_sah.c,
 *      or the spatial / median / mean plane below. No plane means a leaf.
 *   3. kd_split classifies the node's triangles as below only, above only or
 *      both (straddling) from the events on the plane's axis, and hands each
 *      child the events of its one-sided triangles in their existing order.
 *      Straddling triangles are clipped to each child's cell ("perfect
 *      splits": Sutherland-Hodgman on the triangle, then the polygon's box),
 *      and only their new events are sorted and merged in. The lists stay
 *      sorted without re-sorting, which makes the build O(N log N).
 *
 * So the tree a triangle lands in depends only on where it really is, and
 * a triangle whose box crosses a cell but which itself misses the cell is
 * never listed there.
 *
 * Nodes go to a kd_buffer in depth-first order. When a node may use
 * several threads and both its children are big, its children build as a
 * parallel pair (accel_parallel: the calling thread and an idle pool
 * worker, if the build's budget allows), the above child into a buffer of
 * its own, appended after the below subtree when both are done
 * (kd_buffer_append rebases its child indices and list offsets). The tree
 * is the same whatever the thread count.
 *
 * Cancelling: every node polls the cancel flag (accel_stop); once it is set
 * the node and every node after it frees its events and marks its buffer
 * failed, so the recursion unwinds without building anything more.
 *
 * Default options (0 or <0 in arbor_build_opts):
 *   max_depth      round(8 + 1.3 floor(log2 N)), as pbrt (<= KD_MAX_DEPTH)
 *   max_leaf_tris  4 for spatial / median / mean (on galleon and castle 4
 *                  gave spatial a lower SAH cost and faster rays than 1
 *                  or 2, and median / mean do not care); 1 for sah, whose
 *                  cost model decides the rest
 *   cost_traverse  15, cost_intersect 20, empty_bonus 0.2: the paper's
 *                  KT, KI and lambda = 1 - empty_bonus = 0.8 (kd_sah.c)
 *   threads        as accel.c resolves it (the pool's thread count, or
 *                  one per core without a pool)
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "kd_internal.h"

/* Subtrees of fewer triangles are not worth a thread. */
#define KD_FORK_MIN_TRIS 1024

/* Short lists sort faster by insertion than by radix. */
#define KD_INSERTION_SORT_MAX 48

/* ---- events ----------------------------------------------------------- */

static void kd_insertion_sort(kd_event *ev, size_t n)
{
    for (size_t i = 1; i < n; i++) {
        kd_event x = ev[i];
        size_t j = i;
        for (; j > 0 && ev[j - 1] > x; j--)
            ev[j] = ev[j - 1];
        ev[j] = x;
    }
}

/* Sorts events of one axis into (position, type) order: LSD radix sort, 8
 * bits a pass over bits 28-63 (the triangle bits below keep their input
 * order), skipping passes in which all events have the same digit. tmp
 * holds n. */
static void kd_sort_events(kd_event *ev, size_t n, kd_event *tmp)
{
    if (n <= KD_INSERTION_SORT_MAX) {
        kd_insertion_sort(ev, n);
        return;
    }
    kd_event *src = ev, *dst = tmp;
    for (int shift = 28; shift < 64; shift += 8) {
        size_t count[256] = {0};
        for (size_t i = 0; i < n; i++)
            count[(src[i] >> shift) & 255u]++;
        if (count[(src[0] >> shift) & 255u] == n)
            continue;
        size_t sum = 0;
        for (int d = 0; d < 256; d++) {
            size_t c = count[d];
            count[d] = sum;
            sum += c;
        }
        for (size_t i = 0; i < n; i++)
            dst[count[(src[i] >> shift) & 255u]++] = src[i];
        kd_event *swap = src;
        src = dst;
        dst = swap;
    }
    if (src != ev)
        memcpy(ev, src, n * sizeof *ev);
}

/* New events being gathered: one run per axis, each with room for two
 * events per triangle, so that each run is sorted on its own (three short
 * sorts instead of one long one) and the runs are then packed in axis
 * order, which is sorted order. */
typedef struct {
    kd_event *run[3];
    size_t n[3];
} kd_event_runs;

/* Runs in ev, which has room for 6 * ntris events. */
static void kd_runs_init(kd_event_runs *r, kd_event *ev, size_t ntris)
{
    for (int k = 0; k < 3; k++) {
        r->run[k] = ev + 2 * ntris * (size_t)k;
        r->n[k] = 0;
    }
}

/* Adds the events of a triangle whose (clipped) box is `box`: on each axis
 * a start and an end, or one planar event when the box is flat there. */
static void kd_runs_add(kd_event_runs *r, uint32_t tri, const arbor_aabb *box)
{
    for (int k = 0; k < 3; k++) {
        float lo = kd_lo(box, k), hi = kd_hi(box, k);
        kd_event *out = r->run[k] + r->n[k];
        if (lo == hi) {
            out[0] = kd_event_make(lo, tri, k, KD_EVENT_PLANAR);
            r->n[k] += 1;
        } else {
            out[0] = kd_event_make(lo, tri, k, KD_EVENT_START);
            out[1] = kd_event_make(hi, tri, k, KD_EVENT_END);
            r->n[k] += 2;
        }
    }
}

/* Sorts each run and packs them into one sorted list at r->run[0];
 * returns its length and sets axis_begin (if not NULL). tmp holds the
 * longest run. */
static size_t kd_runs_finish(kd_event_runs *r, kd_event *tmp, size_t axis_begin[4])
{
    size_t n = 0;
    for (int k = 0; k < 3; k++) {
        kd_sort_events(r->run[k], r->n[k], tmp);
        memmove(r->run[0] + n, r->run[k], r->n[k] * sizeof *tmp);
        if (axis_begin != NULL)
            axis_begin[k] = n;
        n += r->n[k];
    }
    if (axis_begin != NULL)
        axis_begin[3] = n;
    return n;
}

/* ---- perfect splits: a triangle clipped to a cell --------------------- */

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
static void kd_clip_split(const kd_builder *b, uint32_t tri, const arbor_aabb *cell, kd_plane pl,
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

/* ---- splitting a node's events ---------------------------------------- */

enum { KD_BELOW = 1, KD_ABOVE = 2, KD_BOTH = 3 };

/* Per-thread scratch: side[] is indexed by triangle (only the entries of
 * the node being split are meaningful); fresh[] holds a split's new events
 * (grown as needed, so small nodes never allocate); start[] and values[]
 * serve the median. */
typedef struct {
    uint8_t *side;
    kd_event *fresh;
    size_t fresh_cap;
    float *start;
    float *values;
} kd_scratch;

static bool kd_scratch_init(kd_scratch *s, const kd_builder *b)
{
    size_t n = b->mesh->ntris + 1u;
    bool median = b->builder == ARBOR_BUILD_MEDIAN;
    s->side = malloc(n);
    s->fresh = NULL;
    s->fresh_cap = 0;
    s->start = median ? calloc(n, sizeof *s->start) : NULL;
    s->values = median ? malloc(n * sizeof *s->values) : NULL;
    return s->side != NULL && (!median || (s->start != NULL && s->values != NULL));
}

static void kd_scratch_free(kd_scratch *s)
{
    free(s->side);
    free(s->fresh);
    free(s->start);
    free(s->values);
}

/* The side of pl that each triangle of t lies on, by the paper's rules on
 * the events of pl's axis: a box ending at or before the plane is below,
 * one starting at or after it above, a planar one in the plane goes to
 * pl.planar_below's side, everything else straddles. One pass suffices
 * because a triangle's start event precedes its end event. Counts the
 * one-sided triangles into *nbelow, *nabove and returns the number of
 * straddling ones. */
static size_t kd_classify(const kd_task *t, kd_plane pl, uint8_t *side, uint32_t *nbelow, uint32_t *nabove)
{
    uint32_t p = kd_float_order(pl.pos);
    size_t started_before = 0, ended_by = 0;
    *nbelow = *nabove = 0;
    for (size_t i = t->axis_begin[pl.axis]; i < t->axis_begin[pl.axis + 1]; i++) {
        kd_event e = t->events[i];
        uint32_t pos = kd_event_order(e), tri = kd_event_tri(e);
        switch (kd_event_kind(e)) {
        case KD_EVENT_START:
            side[tri] = pos >= p ? KD_ABOVE : KD_BOTH;
            *nabove += pos >= p;
            started_before += pos < p;
            break;
        case KD_EVENT_END:
            if (pos <= p) {
                side[tri] = KD_BELOW;
                ended_by++;
            }
            break;
        case KD_EVENT_PLANAR:
            side[tri] = (pos < p || (pos == p && pl.planar_below)) ? KD_BELOW : KD_ABOVE;
            *nbelow += side[tri] == KD_BELOW;
            *nabove += side[tri] == KD_ABOVE;
            break;
        }
    }
    /* a box ending by p started before it */
    *nbelow += (uint32_t)ended_by;
    return started_before - ended_by;
}

/* The first index of sorted events[0..n) on an axis >= k. */
static size_t kd_axis_start(const kd_event *events, size_t n, int k)
{
    size_t lo = 0, hi = n;
    while (lo < hi) {
        size_t mid = lo + (hi - lo) / 2;
        if (kd_event_axis(events[mid]) < k)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo;
}

/* Gives each child (0 below, 1 above) the events of t's triangles that
 * are on its side only, in their order, merged with its sorted `fresh`
 * events, so both children's lists come out sorted. After a pass that
 * counts them, one pass deals them out: before an event, the fresh events
 * of either side that sort before it are (they are few, so that test is
 * seldom true); the event itself is written to both lists and only its
 * side's count advances, which avoids a branch that would be mispredicted
 * half the time. */
static bool kd_distribute(const kd_task *t, const uint8_t *side, kd_event *const fresh[2], const size_t nfresh[2],
                          kd_task *child[2])
{
    size_t nevents = t->axis_begin[3], kept_below = 0, kept_above = 0;
    for (size_t i = 0; i < nevents; i++) {
        uint8_t s = side[kd_event_tri(t->events[i])];
        kept_below += s == KD_BELOW;
        kept_above += s == KD_ABOVE;
    }
    const size_t n[2] = {kept_below + nfresh[0], kept_above + nfresh[1]};
    for (int c = 0; c < 2; c++) {
        /* +1: the last event dealt out is also written to the other list */
        child[c]->events = malloc((n[c] + 1) * sizeof *child[c]->events);
        if (child[c]->events == NULL) {
            free(child[0]->events);
            return false;
        }
    }
    kd_event *out0 = child[0]->events, *out1 = child[1]->events;
    const kd_event *f0 = fresh[0], *f0_end = f0 + nfresh[0], *f1 = fresh[1], *f1_end = f1 + nfresh[1];
    kd_event next0 = f0 < f0_end ? *f0 : UINT64_MAX, next1 = f1 < f1_end ? *f1 : UINT64_MAX;
    size_t n0 = 0, n1 = 0;
    for (size_t i = 0; i < nevents; i++) {
        kd_event e = t->events[i];
        /* a fresh event never equals a kept one: their triangles differ */
        for (; next0 < e; next0 = f0 < f0_end ? *f0 : UINT64_MAX)
            out0[n0++] = *f0++;
        for (; next1 < e; next1 = f1 < f1_end ? *f1 : UINT64_MAX)
            out1[n1++] = *f1++;
        uint8_t s = side[kd_event_tri(e)];
        out0[n0] = e;
        out1[n1] = e;
        n0 += s == KD_BELOW;
        n1 += s == KD_ABOVE;
    }
    while (f0 < f0_end)
        out0[n0++] = *f0++;
    while (f1 < f1_end)
        out1[n1++] = *f1++;
    for (int c = 0; c < 2; c++) {
        child[c]->axis_begin[0] = 0;
        child[c]->axis_begin[1] = kd_axis_start(child[c]->events, n[c], 1);
        child[c]->axis_begin[2] = kd_axis_start(child[c]->events, n[c], 2);
        child[c]->axis_begin[3] = n[c];
    }
    return true;
}

/* Splits t at pl into the tasks below and above (their events sorted, their
 * cells the halves of t's). t's events are left for the caller to free.
 * False when memory runs out (nothing is left allocated then). */
static bool kd_split(const kd_builder *b, kd_scratch *s, const kd_task *t, kd_plane pl, kd_task *below,
                     kd_task *above)
{
    below->cell = above->cell = t->cell;
    float *below_hi = pl.axis == 0 ? &below->cell.hi.x : pl.axis == 1 ? &below->cell.hi.y : &below->cell.hi.z;
    float *above_lo = pl.axis == 0 ? &above->cell.lo.x : pl.axis == 1 ? &above->cell.lo.y : &above->cell.lo.z;
    *below_hi = *above_lo = pl.pos;
    below->depth = above->depth = t->depth + 1;
    size_t nstraddle = kd_classify(t, pl, s->side, &below->ntris, &above->ntris);

    /* Clip each straddling triangle (a start event on the plane's axis,
     * marked both) to both cells, for new events on each side. */
    size_t need = 14 * nstraddle + 1;
    if (need > s->fresh_cap) {
        kd_event *grown = realloc(s->fresh, need * sizeof *grown);
        if (grown == NULL)
            return false;
        s->fresh = grown;
        s->fresh_cap = need;
    }
    kd_event *fresh = s->fresh;
    kd_event_runs runs[2];
    kd_runs_init(&runs[0], fresh, nstraddle);
    kd_runs_init(&runs[1], fresh + 6 * nstraddle, nstraddle);
    const arbor_aabb child_cell[2] = {below->cell, above->cell};
    uint32_t *ntris[2] = {&below->ntris, &above->ntris};
    for (size_t i = t->axis_begin[pl.axis]; i < t->axis_begin[pl.axis + 1]; i++) {
        kd_event e = t->events[i];
        uint32_t tri = kd_event_tri(e);
        if (kd_event_kind(e) != KD_EVENT_START || s->side[tri] != KD_BOTH)
            continue;
        bool in[2];
        arbor_aabb box[2];
        kd_clip_split(b, tri, &t->cell, pl, child_cell, in, box);
        for (int c = 0; c < 2; c++)
            if (in[c]) {
                kd_runs_add(&runs[c], tri, &box[c]);
                (*ntris[c])++;
            }
    }
    kd_event *tmp = fresh + 12 * nstraddle;
    kd_event *const fresh_of[2] = {runs[0].run[0], runs[1].run[0]};
    const size_t nfresh[2] = {kd_runs_finish(&runs[0], tmp, NULL), kd_runs_finish(&runs[1], tmp, NULL)};
    kd_task *children[2] = {below, above};
    return kd_distribute(t, s->side, fresh_of, nfresh, children);
}

/* ---- the simple builders' planes -------------------------------------- */

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
static bool kd_simple_plane(const kd_builder *b, kd_scratch *s, const kd_task *t, kd_plane *pl)
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

/* The plane to split t at, or false for a leaf. */
static bool kd_choose_plane(const kd_builder *b, kd_scratch *s, const kd_task *t, kd_plane *pl)
{
    if (t->depth >= b->max_depth || t->ntris <= b->max_leaf_tris)
        return false;
    return b->builder == ARBOR_BUILD_SAH ? kd_sah_plane(b, t, pl) : kd_simple_plane(b, s, t, pl);
}

/* ---- node output ------------------------------------------------------ */

/* A cell's surface area in double precision, for the statistics' sums. */
static double kd_cell_area(const arbor_aabb *b)
{
    double x = (double)b->hi.x - b->lo.x, y = (double)b->hi.y - b->lo.y, z = (double)b->hi.z - b->lo.z;
    return x >= 0.0 && y >= 0.0 && z >= 0.0 ? 2.0 * (x * y + y * z + z * x) : 0.0;
}

/* The sums behind arbor_tree_stats, added up as nodes are written. */
typedef struct {
    double inner_area;      /* sum of inner nodes' cell areas */
    double leaf_area_tris;  /* sum of leaves' cell areas times their triangle counts */
    uint64_t leaves, empty_leaves, refs, depth_sum;
    uint32_t max_depth;
} kd_sums;

typedef struct {
    kd_node *nodes;
    size_t nnodes, node_cap;
    uint32_t *index;
    size_t nindex, index_cap;
    kd_sums sums;
    bool failed;  /* out of memory, more nodes than 30 bits can name, or cancelled */
} kd_buffer;

static bool kd_grow(void **array, size_t *cap, size_t need, size_t elem)
{
    if (need <= *cap)
        return true;
    size_t cap2 = *cap ? 2 * *cap : 256;
    while (cap2 < need)
        cap2 *= 2;
    void *p = realloc(*array, cap2 * elem);
    if (p == NULL)
        return false;
    *array = p;
    *cap = cap2;
    return true;
}

/* Appends a node; NULL (and out->failed) when that is not possible. */
static kd_node *kd_buffer_node(kd_buffer *out)
{
    if (out->failed || out->nnodes + 1 >= KD_MAX_NODES ||
        !kd_grow((void **)&out->nodes, &out->node_cap, out->nnodes + 1, sizeof *out->nodes)) {
        out->failed = true;
        return NULL;
    }
    return &out->nodes[out->nnodes++];
}

/* Writes t as a leaf listing its triangles (those with a start or planar
 * event on axis 0: one each). */
static void kd_emit_leaf(kd_buffer *out, const kd_task *t)
{
    uint32_t n = t->ntris;
    size_t first = out->nindex;
    if (n > 1 && (first + n > UINT32_MAX ||
                  !kd_grow((void **)&out->index, &out->index_cap, first + n, sizeof *out->index))) {
        out->failed = true;
        return;
    }
    kd_node *node = kd_buffer_node(out);
    if (node == NULL)
        return;
    node->first = (uint32_t)first;
    for (size_t i = 0; i < t->axis_begin[1]; i++) {
        kd_event e = t->events[i];
        if (kd_event_kind(e) == KD_EVENT_END)
            continue;
        if (n == 1)
            node->tri = kd_event_tri(e);
        else
            out->index[out->nindex++] = kd_event_tri(e);
    }
    node->flags = n << 2 | KD_LEAF;
    kd_sums *s = &out->sums;
    s->leaves++;
    s->empty_leaves += n == 0;
    s->refs += n;
    s->depth_sum += t->depth;
    if (t->depth > s->max_depth)
        s->max_depth = t->depth;
    s->leaf_area_tris += kd_cell_area(&t->cell) * n;
}

/* Writes t as an inner node at pl; returns its index. Its above child is
 * set by kd_set_above once known. */
static size_t kd_emit_inner(kd_buffer *out, const kd_task *t, kd_plane pl)
{
    kd_node *node = kd_buffer_node(out);
    if (node == NULL)
        return 0;
    node->split = pl.pos;
    node->flags = (uint32_t)pl.axis;
    out->sums.inner_area += kd_cell_area(&t->cell);
    return out->nnodes - 1;
}

static void kd_set_above(kd_buffer *out, size_t inner)
{
    if (!out->failed)
        out->nodes[inner].flags |= (uint32_t)out->nnodes << 2;
}

/* Appends the subtree in `from` (built with indices from 0) to `out`. */
static void kd_buffer_append(kd_buffer *out, const kd_buffer *from)
{
    size_t base = out->nnodes, first = out->nindex;
    if (out->failed || from->failed || base + from->nnodes >= KD_MAX_NODES || first + from->nindex > UINT32_MAX ||
        !kd_grow((void **)&out->nodes, &out->node_cap, base + from->nnodes, sizeof *out->nodes) ||
        !kd_grow((void **)&out->index, &out->index_cap, first + from->nindex, sizeof *out->index)) {
        out->failed = true;
        return;
    }
    for (size_t i = 0; i < from->nnodes; i++) {
        kd_node n = from->nodes[i];
        if (kd_node_kind(n) != KD_LEAF)
            n.flags += (uint32_t)base << 2;
        else if (kd_node_high(n) > 1)
            n.first += (uint32_t)first;
        out->nodes[base + i] = n;
    }
    if (from->nindex > 0) /* both lists may still be NULL */
        memcpy(out->index + first, from->index, from->nindex * sizeof *out->index);
    out->nnodes += from->nnodes;
    out->nindex += from->nindex;
    kd_sums *s = &out->sums;
    const kd_sums *f = &from->sums;
    s->inner_area += f->inner_area;
    s->leaf_area_tris += f->leaf_area_tris;
    s->leaves += f->leaves;
    s->empty_leaves += f->empty_leaves;
    s->refs += f->refs;
    s->depth_sum += f->depth_sum;
    if (f->max_depth > s->max_depth)
        s->max_depth = f->max_depth;
}

/* ---- the recursion ---------------------------------------------------- */

static void kd_build_subtree(const kd_builder *b, kd_scratch *s, kd_task *t, kd_buffer *out);

typedef struct {
    const kd_builder *b;
    kd_scratch *scratch;
    kd_task *task;
    kd_buffer *out;
} kd_job;

/* Job number `i` of the array `jobs`. */
static void kd_job_run(void *jobs, uint32_t i)
{
    kd_job *j = (kd_job *)jobs + i;
    kd_build_subtree(j->b, j->scratch, j->task, j->out);
}

/* Builds the children of the inner node `inner`: below first (it must
 * follow its parent), then above. When the node may use more than one
 * thread and both children are big enough to be worth one, the children
 * build as a parallel pair, the above one with its own scratch into its own
 * buffer, and share the node's threads; otherwise each child in turn may
 * use them all. (So an SAH split that only cuts off empty space passes the
 * threads on to the side that has the work.) */
static void kd_build_children(const kd_builder *b, kd_scratch *s, const kd_task *parent, size_t inner,
                              kd_task *below, kd_task *above, kd_buffer *out)
{
    kd_scratch s2 = {NULL, NULL, 0, NULL, NULL};
    bool fork = parent->threads > 1 && below->ntris >= KD_FORK_MIN_TRIS && above->ntris >= KD_FORK_MIN_TRIS &&
                kd_scratch_init(&s2, b);
    if (fork) {
        above->threads = parent->threads / 2;
        below->threads = parent->threads - above->threads;
        kd_buffer above_out;
        memset(&above_out, 0, sizeof above_out);
        kd_job jobs[2] = {{b, s, below, out}, {b, &s2, above, &above_out}};
        accel_parallel(b->run, 2, kd_job_run, jobs);
        kd_set_above(out, inner);
        kd_buffer_append(out, &above_out);
        free(above_out.nodes);
        free(above_out.index);
    } else {
        below->threads = above->threads = parent->threads;
        kd_build_subtree(b, s, below, out);
        kd_set_above(out, inner);
        kd_build_subtree(b, s, above, out);
    }
    kd_scratch_free(&s2);
}

/* Builds the subtree of t into out, and frees t's events. */
static void kd_build_subtree(const kd_builder *b, kd_scratch *s, kd_task *t, kd_buffer *out)
{
    if (out->failed || accel_stop(b->run)) {
        out->failed = true;
        free(t->events);
        return;
    }
    kd_plane pl;
    if (!kd_choose_plane(b, s, t, &pl)) {
        kd_emit_leaf(out, t);
        free(t->events);
        return;
    }
    kd_task below, above;
    bool ok = kd_split(b, s, t, pl, &below, &above);
    free(t->events);
    if (!ok) {
        out->failed = true;
        return;
    }
    size_t inner = kd_emit_inner(out, t, pl);
    kd_build_children(b, s, t, inner, &below, &above, out);
}

/* ---- the whole build -------------------------------------------------- */

static uint32_t kd_default_max_depth(uint32_t ntris)
{
    int log2n = 0;
    while (log2n < 31 && (ntris >> (log2n + 1)) != 0)
        log2n++;
    uint32_t d = (uint32_t)lroundf(8.0f + 1.3f * (float)log2n);
    return d < KD_MAX_DEPTH ? d : KD_MAX_DEPTH;
}

static void kd_builder_init(kd_builder *b, const arbor_mesh *m, const arbor_build_opts *o, accel_run *run,
                            arbor_aabb bounds)
{
    b->mesh = m;
    b->run = run;
    b->builder = o->builder;
    b->max_depth = o->max_depth > 0 ? (uint32_t)o->max_depth : kd_default_max_depth(m->ntris);
    b->max_leaf_tris = o->max_leaf_tris > 0 ? (uint32_t)o->max_leaf_tris : o->builder == ARBOR_BUILD_SAH ? 1u : 4u;
    b->cost_traverse = o->cost_traverse > 0.0f ? o->cost_traverse : 15.0f;
    b->cost_intersect = o->cost_intersect > 0.0f ? o->cost_intersect : 20.0f;
    b->empty_factor = 1.0f - (o->empty_bonus >= 0.0f ? o->empty_bonus : 0.2f);
    /* 2^-20 of the largest coordinate: several times the error of a clipped
     * coordinate, a + (c - a) s, whose terms are at most that large */
    float scale = fmaxf(fmaxf(fabsf(bounds.lo.x), fabsf(bounds.hi.x)),
                        fmaxf(fmaxf(fabsf(bounds.lo.y), fabsf(bounds.hi.y)),
                              fmaxf(fabsf(bounds.lo.z), fabsf(bounds.hi.z))));
    b->clip_slack = isfinite(scale) ? scale * 0x1p-20f : 0.0f;
}

/* The box of every triangle of m. */
static arbor_aabb kd_mesh_bounds(const arbor_mesh *m)
{
    arbor_aabb box = aabb_empty();
    for (uint32_t i = 0; i < m->ntris; i++)
        box = aabb_union(box, arbor_mesh_tri_bounds(m, i));
    return box;
}

/* The root task: every triangle's events, sorted once. */
static bool kd_root_task(const arbor_mesh *m, arbor_aabb bounds, uint32_t threads, kd_task *root)
{
    root->events = malloc((6 * (size_t)m->ntris + 1) * sizeof *root->events);
    kd_event *tmp = malloc((2 * (size_t)m->ntris + 1) * sizeof *tmp);
    if (root->events == NULL || tmp == NULL) {
        free(root->events);
        free(tmp);
        return false;
    }
    kd_event_runs runs;
    kd_runs_init(&runs, root->events, m->ntris);
    for (uint32_t i = 0; i < m->ntris; i++) {
        arbor_aabb box = arbor_mesh_tri_bounds(m, i);
        kd_runs_add(&runs, i, &box);
    }
    kd_runs_finish(&runs, tmp, root->axis_begin);
    free(tmp);
    root->ntris = m->ntris;
    root->depth = 0;
    root->threads = threads;
    root->cell = bounds;
    return true;
}

static void kd_fill_stats(const kd_tree *tree, const kd_sums *s, arbor_tree_stats *stats)
{
    uint64_t nonempty = s->leaves - s->empty_leaves;
    double root_area = kd_cell_area(&tree->bounds);
    stats->nodes = tree->nnodes;
    stats->leaves = s->leaves;
    stats->empty_leaves = s->empty_leaves;
    stats->max_depth = s->max_depth;
    stats->mean_leaf_depth = s->leaves ? (double)s->depth_sum / (double)s->leaves : 0.0;
    stats->mean_tris_per_leaf = nonempty ? (double)s->refs / (double)nonempty : 0.0;
    stats->refs = s->refs;
    stats->bytes = tree->nnodes * sizeof *tree->nodes + tree->nindex * sizeof *tree->tri_index;
    /* with no area at the root (all triangles on one line or point) every
     * cell counts as the root's, ratio 1, as the bvh does */
    stats->sah_cost = root_area > 0.0 ? (s->inner_area + s->leaf_area_tris) / root_area
                                      : (double)(tree->nnodes - s->leaves) + (double)s->refs;
}

void *kd_build(const arbor_mesh *m, const arbor_build_opts *o, accel_run *run, arbor_tree_stats *stats, arbor_err *e)
{
    if (m->ntris >= KD_MAX_TRIS) {
        arbor_fail(e, ARBOR_ERR_INVALID, "kd tree: %u triangles, more than the %u it can hold", m->ntris,
                   KD_MAX_TRIS - 1);
        return NULL;
    }
    kd_tree *tree = calloc(1, sizeof *tree);
    kd_builder b;
    kd_scratch s = {NULL, NULL, 0, NULL, NULL};
    kd_buffer out;
    memset(&out, 0, sizeof out);
    kd_task root;
    bool ok = tree != NULL;
    if (ok) {
        tree->mesh = m;
        tree->bounds = kd_mesh_bounds(m);
        kd_builder_init(&b, m, o, run, tree->bounds);
        tree->max_depth = b.max_depth;
        ok = kd_scratch_init(&s, &b) && kd_root_task(m, tree->bounds, run->threads, &root);
    }
    if (ok) {
        kd_build_subtree(&b, &s, &root, &out);
        ok = !out.failed;
    }
    kd_scratch_free(&s);
    bool stopped = accel_stop(run);
    if (!ok || stopped) {
        free(out.nodes);
        free(out.index);
        free(tree);
        if (!stopped)
            arbor_fail(e, ARBOR_ERR_NOMEM, "kd tree over %u triangles: out of memory (or over %u nodes)", m->ntris,
                       KD_MAX_NODES);
        return NULL;
    }
    /* give back the buffers' spare capacity */
    kd_node *nodes = realloc(out.nodes, out.nnodes * sizeof *nodes);
    uint32_t *index = out.nindex ? realloc(out.index, out.nindex * sizeof *index) : NULL;
    tree->nodes = nodes ? nodes : out.nodes;
    tree->nnodes = out.nnodes;
    if (out.nindex == 0)
        free(out.index);
    tree->tri_index = out.nindex ? (index ? index : out.index) : NULL;
    tree->nindex = out.nindex;
    kd_fill_stats(tree, &out.sums, stats);
    return tree;
}

void kd_destroy(void *impl)
{
    kd_tree *tree = impl;
    if (tree == NULL)
        return;
    free(tree->nodes);
    free(tree->tri_index);
    free(tree);
}
