/*
 * accel.h - the acceleration-structure interface: one small API over every
 * tree kind (bvh, kd) and builder (spatial, median, mean, sah).
 *
 * The tracer, the statistics and the server hold an opaque arbor_accel and
 * never know which kind it is. arbor_accel_build returns a tree the caller
 * owns and releases with arbor_accel_free; the tree keeps a pointer to the
 * mesh, which must outlive it and stay unchanged. A built tree is immutable:
 * any number of threads may trace through it at once without locks.
 *
 * Names ("bvh", "kd", "spatial", "median", "mean", "sah") are the same
 * strings in the CLI, the JSON API and the viewer.
 *
 * Threads. A build runs on the calling thread and idle workers of
 * opts.pool, never on threads of its own: a daemon gives every build the
 * one pool its other work uses, so concurrent builds share the cores.
 * opts.threads caps the threads working on one build at once (the calling
 * thread counts as one). It also fixes where the recursion splits into
 * parallel parts, and the statistics are summed part by part, so the last
 * digits of sah_cost may differ between thread counts; for a given
 * opts.threads the tree and every statistic are the same whatever the pool
 * and however its threads are busy. Without a pool, a build with threads
 * other than 1 starts a pool of threads - 1 workers for its own duration
 * (the command line's way; a server passes its pool).
 *
 * Cancelling. A build polls *opts.cancel at every node; once it sees it set
 * it stops and fails with ARBOR_ERR_CANCELLED, having freed everything; it
 * never returns a tree cut short. A cancel that comes as the build ends may
 * find nothing left to stop: the build then returns its complete tree.
 */
#ifndef ARBOR_ACCEL_H
#define ARBOR_ACCEL_H

#include <stdatomic.h>
#include <stdbool.h>
#include <stdint.h>

#include "arbor/err.h"
#include "arbor/mesh.h"
#include "arbor/pool.h"
#include "arbor/ray.h"

typedef enum { ARBOR_ACCEL_BVH, ARBOR_ACCEL_KD, ARBOR_ACCEL_KIND_COUNT } arbor_accel_kind;

typedef enum {
    ARBOR_BUILD_SPATIAL,  /* middle of the node's (centroid) bounds, longest axis */
    ARBOR_BUILD_MEDIAN,   /* median centroid along the longest axis */
    ARBOR_BUILD_MEAN,     /* mean centroid along the longest axis */
    ARBOR_BUILD_SAH,      /* surface area heuristic */
    ARBOR_BUILDER_COUNT
} arbor_builder;

typedef struct {
    arbor_accel_kind kind;
    arbor_builder builder;
    int threads;          /* at most this many threads on the build at once (see above); 0 = as many
                           * as the pool has, or one per core without a pool */
    arbor_pool *pool;     /* workers that help the calling thread; NULL: see above */
    const atomic_bool *cancel; /* the build stops when it is set; NULL: never cancelled */
    int max_leaf_tris;    /* leaf size limit; 0 = the kind's default */
    int max_depth;        /* 0 = the kind's default (kd: 8 + 1.3 log2 N) */
    float cost_traverse;  /* SAH cost of visiting an inner node; 0 = default */
    float cost_intersect; /* SAH cost of one triangle test; 0 = default */
    float empty_bonus;    /* kd SAH: fraction of cost saved for an empty side; <0 = default */
    bool drop_binary;     /* bvh: free the binary tree once it is collapsed into the wide tree
                           * rays traverse (a daemon's memory); its statistics stay, and
                           * arbor_accel_validate then checks the wide tree alone */
} arbor_build_opts;

/* A tree's two layouts. The builders of both kinds make a binary tree,
 * which the study's measures describe and the k-d tree's rays traverse; the
 * bvh collapses its binary tree into a wide one (nodes of several children,
 * leaves of triangle packs), and its rays traverse that. */
typedef enum { ARBOR_LAYOUT_BINARY, ARBOR_LAYOUT_WIDE, ARBOR_LAYOUT_COUNT } arbor_layout;

/* The shape of one layout. For the binary tree sah_cost is
 * sum over inner nodes A(n)/A(root) + sum over leaves A(l)/A(root) * N(l);
 * the wide tree's is the same sum with a leaf's packs for its triangles
 * (src/accel/bvh_wide_stats.c says why). nodes counts leaves too. */
typedef struct {
    uint64_t nodes, leaves, empty_leaves;
    uint32_t max_depth;
    double mean_leaf_depth;     /* over all leaves; the root is depth 0 */
    double mean_tris_per_leaf;  /* over non-empty leaves */
    uint64_t refs;              /* triangle references in leaves */
    uint64_t bytes;             /* memory this layout's arrays hold */
    double sah_cost;
} arbor_layout_stats;

/* Statistics of a built tree (DESIGN.md): those of its binary tree, inline
 * (as the study's tables have them), and of its wide tree when it has one. */
typedef struct {
    double build_ms;
    uint64_t nodes, leaves, empty_leaves;
    uint32_t max_depth;
    double mean_leaf_depth;     /* over all leaves; the root is depth 0 */
    double mean_tris_per_leaf;  /* over non-empty leaves */
    uint64_t refs;              /* triangle references in leaves */
    uint64_t bytes;             /* memory the tree holds: all its arrays (bvh: both layouts) */
    uint64_t binary_bytes;      /* the binary tree's arrays as built, also once a bvh has freed them
                                 * (drop_binary): the binary layout's bytes */
    double sah_cost;
    bool has_wide;              /* the bvh: rays traverse the wide tree below */
    arbor_layout_stats wide;
} arbor_tree_stats;

const char *arbor_layout_name(arbor_layout layout);
/* One layout's statistics from s: false when the tree has no such layout. */
bool arbor_tree_layout_stats(const arbor_tree_stats *s, arbor_layout layout, arbor_layout_stats *out);

/* Work done by one traced ray, for the heat mode and per-ray statistics. */
typedef struct {
    uint64_t nodes;  /* node steps: nodes visited, inner and leaf, in the tree rays traverse
                      * (a kd node; a bvh wide node, whose children's boxes one SIMD test
                      * checks, or leaf), so both kinds' counts and heat maps compare */
    uint64_t tris;   /* triangle tests */
} arbor_trace_counts;

typedef struct arbor_accel arbor_accel;

/* Defaults for a kind and builder. */
void arbor_build_opts_init(arbor_build_opts *o, arbor_accel_kind kind, arbor_builder builder);

const char *arbor_accel_kind_name(arbor_accel_kind kind);
const char *arbor_builder_name(arbor_builder builder);
/* Parse a name; false for an unknown one. The names, for messages: */
#define ARBOR_ACCEL_KIND_NAMES "bvh, kd"
#define ARBOR_BUILDER_NAMES "spatial, median, mean, sah"
bool arbor_accel_kind_parse(const char *name, arbor_accel_kind *kind);
bool arbor_builder_parse(const char *name, arbor_builder *builder);

/* The traversal kernel trees built now trace with: "avx2" where the CPU has
 * AVX2 and FMA, "sse2" otherwise, whatever the build's -march; the
 * environment variable ARBOR_KERNEL=sse2 makes it "sse2" everywhere. Every
 * kernel returns the same hits. A tree keeps the kernel it was built with. */
const char *arbor_accel_kernel_name(void);

/* Builds a tree over m. NULL on failure (invalid options, no memory,
 * ARBOR_ERR_CANCELLED when cancelled). opts.pool and opts.cancel are used
 * only while the build runs. */
arbor_accel *arbor_accel_build(const arbor_mesh *m, const arbor_build_opts *o, arbor_err *e);

/* Closest hit in (r->tmin, r->tmax); on a hit shrinks r->tmax and fills h.
 * Every query takes any ray: one with a NaN or infinite component, or a
 * zero direction, hits what brute force says (nothing, for the former). */
bool arbor_accel_intersect(const arbor_accel *a, arbor_ray *r, arbor_hit *h);
/* The same, also adding the work done to *c. */
bool arbor_accel_intersect_counted(const arbor_accel *a, arbor_ray *r, arbor_hit *h, arbor_trace_counts *c);
/* One node of a tree as the inspectors see it (the viewer's box overlay and
 * ray path). box: a bvh node's bounds, a kd node's cell; depth: the root
 * is 0; tris: a leaf's triangles (walk) or those a ray tested there
 * (traced); tests: the node steps a ray made there (traced: 1 at every
 * node visited; 0 in a walk). */
typedef struct {
    arbor_aabb box;
    uint32_t depth;
    bool leaf;
    uint32_t tris, tests;
} arbor_node_info;

/* Called per node; a walk stops when it returns false (a trace does not). */
typedef bool (*arbor_node_fn)(void *user, const arbor_node_info *n);

/* Every node down to max_depth, depth first, parents before children, of
 * the tree rays traverse: the bvh's wide tree (the nodes
 * arbor_accel_intersect_traced visits; arbor_accel_stats' "wide" layout),
 * the kd tree's cells. */
void arbor_accel_walk(const arbor_accel *a, uint32_t max_depth, arbor_node_fn fn, void *user);

/* arbor_accel_intersect_counted, also calling visit at every node the
 * traversal visits, in visiting order (the bvh: nodes of the wide tree that
 * rays traverse). The sums of the visited nodes' tests and tris equal *c's
 * nodes and tris. The same traversal as the plain query, with the visitor
 * compiled out there. */
bool arbor_accel_intersect_traced(const arbor_accel *a, arbor_ray *r, arbor_hit *h, arbor_trace_counts *c,
                                  arbor_node_fn visit, void *user);

/* Any hit in (r->tmin, r->tmax). */
bool arbor_accel_occluded(const arbor_accel *a, const arbor_ray *r);
/* The same, adding the work it did to *c (arbor_accel_intersect_counted). */
bool arbor_accel_occluded_counted(const arbor_accel *a, const arbor_ray *r, arbor_trace_counts *c);

void arbor_accel_stats(const arbor_accel *a, arbor_tree_stats *s);

/* Walks the built tree and checks its invariants independently of the
 * builder: every triangle referenced where it must be (bvh: in exactly one
 * leaf; kd: in every leaf whose cell its clipped box overlaps, and nowhere it
 * does not touch), child bounds inside the parent's, and the statistics
 * (nodes, leaves, empty leaves, refs, depths, sah_cost) equal to what the walk
 * counts. False with the first violation in e. For tests and debugging. */
bool arbor_accel_validate(const arbor_accel *a, arbor_err *e);
const arbor_mesh *arbor_accel_mesh(const arbor_accel *a);
const arbor_build_opts *arbor_accel_opts(const arbor_accel *a);
void arbor_accel_free(arbor_accel *a);

#endif
