/*
 * kd_build.c - building k-d trees: the recursion all four builders share,
 * its threads, and the build from options to finished tree.
 *
 * Every builder works on the event lists of Wald and Havran, "On building
 * fast kd-Trees for Ray Tracing, and on doing that in O(N log N)" (2006):
 *
 *   1. At the root, each triangle's box gives two events per axis (start,
 *      end) or one (planar, when the box is flat there), and all events are
 *      sorted ONCE by (axis, position, type).
 *   2. A node chooses a plane (kd_choose_plane): the SAH sweep of kd_sah.c,
 *      or the spatial / median / mean plane of kd_simple.c. No plane means
 *      a leaf.
 *   3. kd_split (kd_split.c) classifies the node's triangles as below
 *      only, above only or both (straddling) from the events on the plane's
 *      axis, and hands each child the events of its one-sided triangles in
 *      their existing order. Straddling triangles are clipped to each
 *      child's cell ("perfect splits", kd_clip.c), and only their new
 *      events are sorted (kd_events.c) and merged in. The lists stay sorted
 *      without re-sorting, which makes the build O(N log N).
 *
 * So the tree a triangle lands in depends only on where it really is, and
 * a triangle whose box crosses a cell but which itself misses the cell is
 * never listed there.
 *
 * Nodes go to a kd_buffer (kd_buffer.c) in depth-first order. When a node
 * may use several threads and both its children are big, its children
 * build as a parallel pair (accel_parallel: the calling thread and an idle
 * pool worker, if the build's budget allows), the above child into a buffer
 * of its own, appended after the below subtree when both are done
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
 *                  or 2, and median / mean do not care); none for sah
 *                  (0: only empty nodes are leaves before the SAH is
 *                  asked), whose cost alone ends the recursion, as the
 *                  paper's; a cap of 1 made every single triangle a leaf
 *                  in a cell the SAH would still have cut empty space off
 *   cost_traverse  15, cost_intersect 2.5, empty_bonus 0.2: the paper's
 *                  KT and lambda = 1 - empty_bonus = 0.8 (kd_sah.c), and
 *                  its KI of 20 over the KD_PACK_LANES (8) triangles a
 *                  leaf tests at once: its triangles cost about an eighth
 *                  of a scalar test each. Leaves grow to 13-15 triangles,
 *                  rays take 13-36% fewer steps and the tree has 15 times
 *                  fewer nodes (docs/BENCH.md, "k-d tree")
 *   threads        as accel.c resolves it (the pool's thread count, or
 *                  one per core without a pool)
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "kd_internal.h"

/* Subtrees of fewer triangles are not worth a thread. */
#define KD_FORK_MIN_TRIS 1024

/* The plane to split t at, or false for a leaf. */
static bool kd_choose_plane(const kd_builder *b, kd_scratch *s, const kd_task *t, kd_plane *pl)
{
    if (t->depth >= b->max_depth || t->ntris <= b->max_leaf_tris)
        return false;
    return b->builder == ARBOR_BUILD_SAH ? kd_sah_plane(b, t, pl) : kd_simple_plane(b, s, t, pl);
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
    kd_scratch s2 = KD_SCRATCH_NONE;
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
    b->max_leaf_tris = o->max_leaf_tris > 0 ? (uint32_t)o->max_leaf_tris : o->builder == ARBOR_BUILD_SAH ? 0u : 4u;
    b->cost_traverse = o->cost_traverse > 0.0f ? o->cost_traverse : 15.0f;
    b->cost_intersect = o->cost_intersect > 0.0f ? o->cost_intersect : 20.0f / KD_PACK_LANES;
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
    root->events = malloc((KD_RUNS_ROOM * (size_t)m->ntris + 1) * sizeof *root->events);
    kd_event *tmp = malloc((KD_RUN_ROOM * (size_t)m->ntris + 1) * sizeof *tmp);
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

void *kd_build(const arbor_mesh *m, const arbor_build_opts *o, accel_run *run, arbor_tree_stats *stats, arbor_err *e)
{
    if (m->ntris >= KD_MAX_TRIS) {
        arbor_fail(e, ARBOR_ERR_INVALID, "kd tree: %u triangles, more than the %u it can hold", m->ntris,
                   KD_MAX_TRIS - 1);
        return NULL;
    }
    kd_tree *tree = calloc(1, sizeof *tree);
    kd_builder b;
    kd_scratch s = KD_SCRATCH_NONE;
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
    if (!kd_pack_leaves(tree)) {
        kd_destroy(tree);
        arbor_fail(e, ARBOR_ERR_NOMEM, "kd tree over %u triangles: out of memory for its leaf packs", m->ntris);
        return NULL;
    }
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
    free(tree->packs);
    free(tree);
}
