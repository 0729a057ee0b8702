/*
 * kd_split.c - splitting a node at its plane: each triangle classified as
 * below, above or both from the events on the plane's axis, the straddling
 * ones clipped to both children (kd_clip.c) for new events, and the
 * node's events dealt out to its children with the new ones merged in, so
 * that both children's lists come out sorted without sorting them again:
 * this is what makes the build O(N log N) (Wald and Havran, section 5).
 */
#include <stdlib.h>

#include "kd_internal.h"

enum { KD_BELOW = 1, KD_ABOVE = 2, KD_BOTH = 3 };

bool kd_scratch_init(kd_scratch *s, const kd_builder *b)
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

void kd_scratch_free(kd_scratch *s)
{
    free(s->side);
    free(s->fresh);
    free(s->start);
    free(s->values);
}

/* How a split lays out its new events in the scratch's fresh[], for n
 * straddling triangles: each child's runs (kd_event_runs), then the radix
 * sort's spare room, which holds one run. */
typedef struct {
    kd_event *runs[2];    /* below, above: KD_RUNS_ROOM * n events each */
    kd_event *sort_spare; /* KD_RUN_ROOM * n events */
} kd_fresh_layout;

/* Lays out s->fresh for n straddling triangles, growing it if need be;
 * false when memory runs out. */
static bool kd_fresh_layout_get(kd_scratch *s, size_t n, kd_fresh_layout *l)
{
    size_t need = (2 * KD_RUNS_ROOM + KD_RUN_ROOM) * n + 1;  /* + 1: never malloc(0) */
    if (need > s->fresh_cap) {
        kd_event *grown = realloc(s->fresh, need * sizeof *grown);
        if (grown == NULL)
            return false;
        s->fresh = grown;
        s->fresh_cap = need;
    }
    l->runs[0] = s->fresh;
    l->runs[1] = l->runs[0] + KD_RUNS_ROOM * n;
    l->sort_spare = l->runs[1] + KD_RUNS_ROOM * n;
    return true;
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

bool kd_split(const kd_builder *b, kd_scratch *s, const kd_task *t, kd_plane pl, kd_task *below, kd_task *above)
{
    below->cell = above->cell = t->cell;
    float *below_hi = pl.axis == 0 ? &below->cell.hi.x : pl.axis == 1 ? &below->cell.hi.y : &below->cell.hi.z;
    float *above_lo = pl.axis == 0 ? &above->cell.lo.x : pl.axis == 1 ? &above->cell.lo.y : &above->cell.lo.z;
    *below_hi = *above_lo = pl.pos;
    below->depth = above->depth = t->depth + 1;
    size_t nstraddle = kd_classify(t, pl, s->side, &below->ntris, &above->ntris);

    /* Clip each straddling triangle (a start event on the plane's axis,
     * marked both) to both cells, for new events on each side. */
    kd_fresh_layout fresh;
    if (!kd_fresh_layout_get(s, nstraddle, &fresh))
        return false;
    kd_event_runs runs[2];
    for (int c = 0; c < 2; c++)
        kd_runs_init(&runs[c], fresh.runs[c], nstraddle);
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
    kd_event *const fresh_of[2] = {runs[0].run[0], runs[1].run[0]};
    const size_t nfresh[2] = {kd_runs_finish(&runs[0], fresh.sort_spare, NULL),
                              kd_runs_finish(&runs[1], fresh.sort_spare, NULL)};
    kd_task *children[2] = {below, above};
    return kd_distribute(t, s->side, fresh_of, nfresh, children);
}

