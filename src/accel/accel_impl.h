/*
 * accel_impl.h - what a tree kind provides to accel.c (private to src/accel).
 *
 * Each kind (bvh.c, kd.c) exports one arbor_accel_ops table. accel.c owns the
 * arbor_accel wrapper, times the build and dispatches through the table, so a
 * kind only builds, traverses and describes itself. `impl` is the kind's own
 * tree, created by build and released by destroy.
 */
#ifndef ARBOR_ACCEL_IMPL_H
#define ARBOR_ACCEL_IMPL_H

#include "arbor/accel.h"

/* What a build runs on, resolved by accel.c from the options: the pool its
 * parallel parts use (NULL: the calling thread alone), the budget holding
 * the whole build to `threads` threads, and the cancel flag. */
typedef struct {
    arbor_pool *pool;
    arbor_pool_budget budget;
    uint32_t threads;          /* >= 1: where the recursion splits into parallel parts depends on it */
    const atomic_bool *cancel; /* NULL: never cancelled */
    atomic_bool stopped;       /* some check saw *cancel set: the build must fail */
} accel_run;

/* Resolves o's threads, pool and cancel flag into run. Without a pool, a
 * build of more than one thread starts one of its own, returned for the
 * caller to destroy after the build; when that fails the build runs on the
 * calling thread alone, which is slower but builds the same tree (the tree
 * depends on run->threads only). accel.c. */
arbor_pool *accel_run_init(accel_run *run, const arbor_build_opts *o);

/* Whether the build must stop, remembering a cancel once seen (so that
 * clearing the flag later cannot pass off a cut-short tree as built). Two
 * relaxed loads: cheap enough to call at every node. */
static inline bool accel_stop(accel_run *r)
{
    if (r->cancel == NULL)
        return false;
    if (atomic_load_explicit(r->cancel, memory_order_relaxed)) {
        atomic_store_explicit(&r->stopped, true, memory_order_relaxed);
        return true;
    }
    return atomic_load_explicit(&r->stopped, memory_order_relaxed);
}

/* Runs fn(ctx, i) for every i in [0, n) on the build's threads. */
static inline void accel_parallel(accel_run *r, uint32_t n, void (*fn)(void *ctx, uint32_t i), void *ctx)
{
    arbor_pool_parallel_within(r->pool, &r->budget, n, fn, ctx);
}

/* The ray queries of a tree kind, as one traversal kernel compiles them. */
typedef struct {
    bool (*intersect)(const void *impl, arbor_ray *r, arbor_hit *h);
    bool (*intersect_counted)(const void *impl, arbor_ray *r, arbor_hit *h, arbor_trace_counts *c);
    bool (*occluded)(const void *impl, const arbor_ray *r);
    bool (*occluded_counted)(const void *impl, const arbor_ray *r, arbor_trace_counts *c);
    bool (*intersect_traced)(const void *impl, arbor_ray *r, arbor_hit *h, arbor_trace_counts *c,
                             arbor_node_fn visit, void *user);
} accel_queries;

/* Traversal kernels. The Makefile compiles each source of its KERNEL_SRC
 * list once per kernel, with that kernel's instruction set and
 * -DACCEL_KERNEL=<name>, so one binary holds them all; accel.c picks one
 * per build (arbor_accel_kernel_name). ACCEL_KERNEL_SYM(x) is x_<name>: a
 * kernel source names what it exports with it, so the copies do not clash.
 * Every kernel gives the same hits (the tests run each): they differ only
 * in how many lanes an instruction holds. */
typedef enum { ACCEL_KERNEL_SSE2, ACCEL_KERNEL_AVX2, ACCEL_KERNEL_COUNT } accel_kernel;

#define ACCEL_KERNEL_CAT2(x, k) x##_##k
#define ACCEL_KERNEL_CAT(x, k) ACCEL_KERNEL_CAT2(x, k)
#define ACCEL_KERNEL_SYM(x) ACCEL_KERNEL_CAT(x, ACCEL_KERNEL)

typedef struct {
    /* Builds a tree over m with validated options on run's threads; fills
     * every field of *stats except build_ms. NULL on failure: e filled, or,
     * when accel_stop(run) has returned true, e untouched (accel.c reports
     * the cancel). Never a tree once accel_stop has returned true. */
    void *(*build)(const arbor_mesh *m, const arbor_build_opts *o, accel_run *run, arbor_tree_stats *stats,
                   arbor_err *e);
    /* The queries per kernel; a kind without kernels of its own gives the
     * same table for each. */
    const accel_queries *queries[ACCEL_KERNEL_COUNT];
    void (*walk)(const void *impl, uint32_t max_depth, arbor_node_fn fn, void *user);
    /* See arbor_accel_validate; stats are the ones build filled. */
    bool (*validate)(const void *impl, const arbor_mesh *m, const arbor_tree_stats *stats, arbor_err *e);
    void (*destroy)(void *impl);
} arbor_accel_ops;

extern const arbor_accel_ops arbor_bvh_ops;
extern const arbor_accel_ops arbor_kd_ops;

#endif
