/*
 * accel.c - the common acceleration-structure interface: option defaults,
 * names, and dispatch to the kind that built a tree (include/arbor/accel.h).
 */
#include <stdlib.h>
#include <string.h>

#include "accel_impl.h"
#include "arbor/sys.h"

struct arbor_accel {
    const arbor_accel_ops *ops;
    const accel_queries *queries; /* ops' queries in the kernel picked at build */
    void *impl;
    const arbor_mesh *mesh;
    arbor_build_opts opts;
    arbor_tree_stats stats;
};

static const char *const kind_names[ARBOR_ACCEL_KIND_COUNT] = {"bvh", "kd"};
static const char *const builder_names[ARBOR_BUILDER_COUNT] = {"spatial", "median", "mean", "sah"};
static const char *const layout_names[ARBOR_LAYOUT_COUNT] = {"binary", "wide"};
static const char *const kernel_names[ACCEL_KERNEL_COUNT] = {"sse2", "avx2"};

/* The traversal kernel of the trees built now: AVX2 where the CPU has both
 * AVX2 and FMA, SSE2 (every x86-64 has it) otherwise, or SSE2 when the
 * environment says ARBOR_KERNEL=sse2 (other values are ignored: AVX2 cannot
 * be forced onto a CPU without it). Read at every build, so that a test can
 * build one tree per kernel; getenv is cheap next to any build. */
static accel_kernel kernel_pick(void)
{
    const char *want = getenv("ARBOR_KERNEL");
    if (want != NULL && strcmp(want, "sse2") == 0)
        return ACCEL_KERNEL_SSE2;
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma") ? ACCEL_KERNEL_AVX2 : ACCEL_KERNEL_SSE2;
}

const char *arbor_accel_kernel_name(void)
{
    return kernel_names[kernel_pick()];
}

void arbor_build_opts_init(arbor_build_opts *o, arbor_accel_kind kind, arbor_builder builder)
{
    memset(o, 0, sizeof *o);
    o->kind = kind;
    o->builder = builder;
    o->empty_bonus = -1.0f;
}

const char *arbor_accel_kind_name(arbor_accel_kind kind)
{
    return (unsigned)kind < ARBOR_ACCEL_KIND_COUNT ? kind_names[kind] : "?";
}

const char *arbor_builder_name(arbor_builder builder)
{
    return (unsigned)builder < ARBOR_BUILDER_COUNT ? builder_names[builder] : "?";
}

const char *arbor_layout_name(arbor_layout layout)
{
    return (unsigned)layout < ARBOR_LAYOUT_COUNT ? layout_names[layout] : "?";
}

bool arbor_tree_layout_stats(const arbor_tree_stats *s, arbor_layout layout, arbor_layout_stats *out)
{
    if (layout == ARBOR_LAYOUT_WIDE) {
        *out = s->wide;
        return s->has_wide;
    }
    if (layout != ARBOR_LAYOUT_BINARY)
        return false;
    *out = (arbor_layout_stats){s->nodes,  s->leaves, s->empty_leaves, s->max_depth, s->mean_leaf_depth,
                                s->mean_tris_per_leaf, s->refs, s->binary_bytes,
                                s->sah_cost};
    return true;
}

bool arbor_accel_kind_parse(const char *name, arbor_accel_kind *kind)
{
    for (int i = 0; i < ARBOR_ACCEL_KIND_COUNT; i++)
        if (strcmp(name, kind_names[i]) == 0) {
            *kind = (arbor_accel_kind)i;
            return true;
        }
    return false;
}

bool arbor_builder_parse(const char *name, arbor_builder *builder)
{
    for (int i = 0; i < ARBOR_BUILDER_COUNT; i++)
        if (strcmp(name, builder_names[i]) == 0) {
            *builder = (arbor_builder)i;
            return true;
        }
    return false;
}

static bool opts_validate(const arbor_build_opts *o, arbor_err *e)
{
    if ((unsigned)o->kind >= ARBOR_ACCEL_KIND_COUNT)
        return arbor_fail(e, ARBOR_ERR_INVALID, "unknown accel kind %d", (int)o->kind);
    if ((unsigned)o->builder >= ARBOR_BUILDER_COUNT)
        return arbor_fail(e, ARBOR_ERR_INVALID, "unknown builder %d", (int)o->builder);
    if (o->threads < 0)
        return arbor_fail(e, ARBOR_ERR_INVALID, "threads must be >= 0, not %d", o->threads);
    if (o->max_leaf_tris < 0)
        return arbor_fail(e, ARBOR_ERR_INVALID, "max_leaf_tris must be >= 0, not %d", o->max_leaf_tris);
    if (o->max_depth < 0 || o->max_depth > 64)
        return arbor_fail(e, ARBOR_ERR_INVALID, "max_depth must be in 0..64, not %d", o->max_depth);
    if (o->cost_traverse < 0.0f || o->cost_intersect < 0.0f)
        return arbor_fail(e, ARBOR_ERR_INVALID, "SAH costs must be >= 0");
    if (o->empty_bonus >= 1.0f)
        return arbor_fail(e, ARBOR_ERR_INVALID, "empty_bonus must be < 1, not %g", (double)o->empty_bonus);
    return true;
}

arbor_pool *accel_run_init(accel_run *run, const arbor_build_opts *o)
{
    uint32_t threads = o->threads > 0 ? (uint32_t)o->threads
                       : o->pool != NULL ? (uint32_t)arbor_pool_threads(o->pool)
                                         : (uint32_t)arbor_cpu_count();
    arbor_pool *own = o->pool == NULL && threads > 1 ? arbor_pool_create((int)threads - 1, NULL) : NULL;
    run->pool = o->pool != NULL ? o->pool : own;
    run->threads = threads;
    arbor_pool_budget_init(&run->budget, run->pool, threads);
    run->cancel = o->cancel;
    atomic_init(&run->stopped, false);
    return own;
}

static void *cancelled(arbor_err *e)
{
    arbor_fail(e, ARBOR_ERR_CANCELLED, "build cancelled");
    return NULL;
}

arbor_accel *arbor_accel_build(const arbor_mesh *m, const arbor_build_opts *o, arbor_err *e)
{
    if (!opts_validate(o, e))
        return NULL;
    if (o->cancel != NULL && atomic_load(o->cancel))
        return cancelled(e);
    arbor_accel *a = calloc(1, sizeof *a);
    if (a == NULL) {
        arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory allocating a tree");
        return NULL;
    }
    a->ops = o->kind == ARBOR_ACCEL_BVH ? &arbor_bvh_ops : &arbor_kd_ops;
    a->queries = a->ops->queries[kernel_pick()];
    a->mesh = m;
    a->opts = *o;
    accel_run run;
    arbor_pool *own = accel_run_init(&run, o);
    double t0 = arbor_now_ms();
    a->impl = a->ops->build(m, o, &run, &a->stats, e);
    a->stats.build_ms = arbor_now_ms() - t0;
    arbor_pool_destroy(own);
    if (a->impl == NULL) {
        free(a);
        return atomic_load(&run.stopped) ? cancelled(e) : NULL;
    }
    return a;
}

bool arbor_accel_intersect(const arbor_accel *a, arbor_ray *r, arbor_hit *h)
{
    return a->queries->intersect(a->impl, r, h);
}

bool arbor_accel_intersect_counted(const arbor_accel *a, arbor_ray *r, arbor_hit *h, arbor_trace_counts *c)
{
    return a->queries->intersect_counted(a->impl, r, h, c);
}

bool arbor_accel_intersect_traced(const arbor_accel *a, arbor_ray *r, arbor_hit *h, arbor_trace_counts *c,
                                  arbor_node_fn visit, void *user)
{
    return a->queries->intersect_traced(a->impl, r, h, c, visit, user);
}

void arbor_accel_walk(const arbor_accel *a, uint32_t max_depth, arbor_node_fn fn, void *user)
{
    a->ops->walk(a->impl, max_depth, fn, user);
}

bool arbor_accel_occluded(const arbor_accel *a, const arbor_ray *r)
{
    return a->queries->occluded(a->impl, r);
}

bool arbor_accel_occluded_counted(const arbor_accel *a, const arbor_ray *r, arbor_trace_counts *c)
{
    return a->queries->occluded_counted(a->impl, r, c);
}

void arbor_accel_stats(const arbor_accel *a, arbor_tree_stats *s)
{
    *s = a->stats;
}

bool arbor_accel_validate(const arbor_accel *a, arbor_err *e)
{
    return a->ops->validate(a->impl, a->mesh, &a->stats, e);
}

const arbor_mesh *arbor_accel_mesh(const arbor_accel *a)
{
    return a->mesh;
}

const arbor_build_opts *arbor_accel_opts(const arbor_accel *a)
{
    return &a->opts;
}

void arbor_accel_free(arbor_accel *a)
{
    if (a == NULL)
        return;
    a->ops->destroy(a->impl);
    free(a);
}
