/*
 * bench.h - the benchmark, for the CLI and the daemon alike: the study's
 * four measures (build ms, mean leaf depth, mean triangles per leaf, render
 * ms) and sah_cost for every requested tree kind and builder over a mesh,
 * and PROTOCOL.md's ray sets (primary, diffuse, shadow) traced and timed on
 * every tree, with Intel Embree beside them when asked; and OBJ parse speed.
 *
 * Every figure is the median of `runs` repetitions of one measurement. With
 * Embree, its builds and passes over a set alternate with each tree's (a
 * tree's build, Embree's, a tree's, ...), so that a slow spell of a shared
 * machine falls on both sides of a ratio; Embree's row gives the medians of
 * all its measurements, a tree's ratios are to those taken beside it. With
 * opts.scale other than 1 the mesh is measured scaled by that power of two
 * (arbor_bench_scale_mesh, on a copy of its vertices): every ray of the sets
 * is then the unscaled one times the scale, bit for bit, so hits, triangles
 * and distances (times the scale) must come out the same. The ray sets are
 * made once per mesh: primary from the protocol camera, diffuse
 * and shadow from the primary hits of a reference trace with the first
 * requested tree; every tracer is then timed on those same rays by
 * arbor_time_set (raysets.h), so their primary hits must agree. Builds,
 * renders and traces all run on one pool, the caller's or the call's own.
 *
 * Ownership: the caller owns the mesh (unchanged during the call), the pool,
 * the cancel flag and the rows array. A row is a plain value (the model name
 * is copied into it, the accel and builder names are static strings), so
 * rows may be kept and copied after the call. Nothing here prints.
 */
#ifndef ARBOR_BENCH_H
#define ARBOR_BENCH_H

#include <stdatomic.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "arbor/accel.h"
#include "arbor/err.h"
#include "arbor/mesh.h"
#include "arbor/pool.h"

#define ARBOR_BENCH_MAX_RUNS 100
/* A file name's longest base name (NAME_MAX) and its NUL. */
#define ARBOR_BENCH_MODEL_MAX 256

/* The ray sets, in the order of a row's mrays[] and ratio[]. */
typedef enum { ARBOR_SET_PRIMARY, ARBOR_SET_DIFFUSE, ARBOR_SET_SHADOW, ARBOR_SET_COUNT } arbor_ray_set;

/* "primary", "diffuse", "shadow" */
const char *arbor_ray_set_name(arbor_ray_set set);

/* One tracer on one mesh. Tree statistics and render_ms are NAN for
 * Embree's row; ratio[] (this row's Mrays/s over Embree's, measured beside
 * it) is NAN without Embree, and in Embree's own row. */
typedef struct {
    char model[ARBOR_BENCH_MODEL_MAX];
    double scale;                 /* opts.scale: the factor the mesh was measured at */
    uint32_t triangles;
    const char *accel, *builder;  /* "bvh"/"kd" and a builder name, or "embree" and its mode
                                   * (arbor_embree_mode: "default", or "robust" with
                                   * opts.embree_robust) */
    const char *kernel;           /* the traversal kernel the tree traced with (arbor_accel_kernel_name:
                                   * "avx2", "sse2"); in Embree's row opts.embree_isa, its limit
                                   * (NULL: Embree picked the best for the CPU) */
    int threads;
    double build_ms, mean_leaf_depth, mean_tris_per_leaf, sah_cost, render_ms;
    double bytes_per_tri;         /* memory of the structure rays traverse, per triangle: the
                                   * bvh's wide tree, the kd tree, Embree's BVH (its leaves'
                                   * triangle data included; the mesh's own arrays not) */
    double mrays[ARBOR_SET_COUNT];
    double ratio[ARBOR_SET_COUNT];
    uint64_t primary_hits;  /* of one pass over the primary set */
    double primary_tsum;    /* sum of those hits' distances */
    double nodes_per_ray[ARBOR_SET_COUNT];  /* the work per ray of each set (arbor_trace_counts: */
    double tris_per_ray[ARBOR_SET_COUNT];   /* node steps, triangle tests); NAN in Embree's row */
} arbor_bench_row;

/* Called on the benchmarking thread after each row is measured: `done` of
 * `total` rows (1..total). Ratios are not filled in yet (see arbor_bench_mesh). */
typedef void (*arbor_bench_row_fn)(void *user, const arbor_bench_row *row, size_t done, size_t total);

typedef struct {
    bool kinds[ARBOR_ACCEL_KIND_COUNT];  /* the tree kinds to measure */
    bool builders[ARBOR_BUILDER_COUNT];  /* the builders, for each kind */
    int runs;                            /* 1..ARBOR_BENCH_MAX_RUNS; each figure is their median */
    int threads;                         /* build and trace threads, the caller included; 0 = as many
                                          * as the pool has, or one per core without a pool */
    bool embree;                         /* add Embree's row and every row's ratio to the Embree
                                          * passes beside it */
    const char *embree_isa;              /* NULL: Embree's kernels for the best ISA the CPU has;
                                          * else the highest it may use (arbor_embree_build) */
    bool embree_robust;                  /* with embree: Embree in its robust mode
                                          * (arbor_embree_build) */
    float scale;                         /* measure the mesh scaled by this power of two (see above) */
    arbor_pool *pool;                    /* builds, renders, traces on it; NULL: a pool of `threads`
                                          * for the call. Figures at N threads mean N threads only
                                          * on a pool nothing else is using meanwhile. */
    const atomic_bool *cancel;           /* NULL, or checked between measurements and by builds */
    arbor_bench_row_fn row_done;         /* NULL, or progress after each row */
    void *user;                          /* row_done's first argument */
} arbor_bench_opts;

/* A kind's or a builder's name as its index in opts.kinds / opts.builders,
 * for the CLI's and the daemon's lists of names; false for an unknown name. */
bool arbor_bench_kind_index(const char *name, int *index);
bool arbor_bench_builder_index(const char *name, int *index);

/* Every kind and builder, 5 runs, one thread per core, no Embree, scale 1,
 * no pool, no cancel flag, no callback. */
void arbor_bench_opts_init(arbor_bench_opts *o);

/* The rows arbor_bench_mesh fills: one per chosen kind and builder, plus
 * Embree's, in that order (kinds in enum order, builders within each). */
size_t arbor_bench_row_count(const arbor_bench_opts *o);
/* Bytes the ray sets and the primary hits they are made from take, held
 * for the whole of an arbor_bench_mesh call (besides its trees, built and
 * freed one at a time, and Embree's). */
uint64_t arbor_bench_sets_bytes(void);

/* Measures the mesh; rows must hold arbor_bench_row_count(o) rows.
 * model_name is the name the rows carry (cut to ARBOR_BENCH_MODEL_MAX - 1
 * bytes). Ratios to Embree are filled in once its row (the last) is done.
 * Fails with ARBOR_ERR_INVALID on bad options (or Embree asked of a build
 * without it), ARBOR_ERR_CANCELLED when *o->cancel was set, and whatever a
 * build, render or trace failed with; the rows reported done stay valid. */
bool arbor_bench_mesh(const char *model_name, const arbor_mesh *m, const arbor_bench_opts *o,
                      arbor_bench_row *rows, arbor_err *e);

/* Multiplies every vertex of m, and its bounds, by scale, a power of two,
 * so exactly: no coordinate rounds. Fails with ARBOR_ERR_INVALID, leaving m
 * unchanged, when scale is not a power of two or a non-zero coordinate
 * would leave float's normal range (become subnormal, zero or infinite). */
bool arbor_bench_scale_mesh(arbor_mesh *m, float scale, arbor_err *e);

/* True when two rows traced the same primary hits (counts and distance sums
 * within 1e-3 relative): every tracer should, on the same rays. */
bool arbor_bench_same_hits(const arbor_bench_row *a, const arbor_bench_row *b);

/* OBJ parse speed: the file read into memory (gunzipped when .gz) once,
 * then parsed `runs` times; parse_ms is the median. */
typedef struct {
    size_t bytes;        /* of OBJ text */
    uint32_t triangles;
    double parse_ms;
    double mb_per_s;     /* bytes / 1e6 per second of parse_ms */
} arbor_parse_timing;

bool arbor_bench_parse(const char *path, int runs, const atomic_bool *cancel, arbor_parse_timing *out,
                       arbor_err *e);

#endif
