/*
 * kd_events.c - the k-d builder's event lists (see kd_internal.h for the
 * event encoding): sorting them, and gathering new ones in per-axis runs.
 *
 * The root's events are sorted once; after that only the few events of
 * clipped (straddling) triangles are new at each split, gathered in runs
 * and sorted here before kd_split.c merges them into the kept ones.
 */
#include <string.h>

#include "kd_internal.h"

/* Short lists sort faster by insertion than by radix. */
#define KD_INSERTION_SORT_MAX 48

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
void kd_sort_events(kd_event *ev, size_t n, kd_event *tmp)
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

void kd_runs_init(kd_event_runs *r, kd_event *ev, size_t ntris)
{
    for (int k = 0; k < 3; k++) {
        r->run[k] = ev + KD_RUN_ROOM * ntris * (size_t)k;
        r->n[k] = 0;
    }
}

size_t kd_runs_finish(kd_event_runs *r, kd_event *tmp, size_t axis_begin[4])
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
