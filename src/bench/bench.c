/*
 * bench.c - the benchmark (see include/arbor/bench.h): the study's measures
 * and PROTOCOL.md's ray sets for each tree over a mesh, Embree beside them,
 * and OBJ parse speed.
 *
 * Every figure is the median of o->runs repetitions through one helper,
 * median_of_runs_beside, which is also where the cancel flag is checked:
 * between measurements, never inside one, so every figure reported was
 * measured whole. With Embree, each of a tree's builds and passes over a
 * set is followed by the same of Embree's (their repetitions alternate), so
 * that a slow spell of a shared machine falls on both sides of a ratio: on
 * a VM, measuring all of a tree's repetitions and then all of Embree's gave
 * one model's primary ratio as 1.24 in one run and 0.78 in the next.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "arbor/bench.h"
#include "arbor/embree_peer.h"
#include "arbor/load.h"
#include "arbor/raysets.h"
#include "arbor/render.h"
#include "arbor/sys.h"

#define SET_MIN_MS 200.0
#define AGREE_REL 1e-3
#define DIFFUSE_SEED 20240601u

static const char *const set_names[ARBOR_SET_COUNT] = {"primary", "diffuse", "shadow"};

const char *arbor_ray_set_name(arbor_ray_set set)
{
    return (unsigned)set < ARBOR_SET_COUNT ? set_names[set] : "?";
}

void arbor_bench_opts_init(arbor_bench_opts *o)
{
    memset(o, 0, sizeof *o);
    for (int k = 0; k < ARBOR_ACCEL_KIND_COUNT; k++)
        o->kinds[k] = true;
    for (int b = 0; b < ARBOR_BUILDER_COUNT; b++)
        o->builders[b] = true;
    o->runs = 5;
    o->scale = 1.0f;
}

static size_t count_chosen(const bool *chosen, int n)
{
    size_t count = 0;
    for (int i = 0; i < n; i++)
        count += chosen[i];
    return count;
}

size_t arbor_bench_row_count(const arbor_bench_opts *o)
{
    return count_chosen(o->kinds, ARBOR_ACCEL_KIND_COUNT) * count_chosen(o->builders, ARBOR_BUILDER_COUNT) +
           (o->embree ? 1 : 0);
}

uint64_t arbor_bench_sets_bytes(void)
{
    uint64_t n = (uint64_t)ARBOR_PROTOCOL_WIDTH * ARBOR_PROTOCOL_HEIGHT;
    return ARBOR_SET_COUNT * n * sizeof(arbor_ray) + n * (sizeof(arbor_hit) + sizeof(bool));
}

bool arbor_bench_same_hits(const arbor_bench_row *a, const arbor_bench_row *b)
{
    double ha = (double)a->primary_hits, hb = (double)b->primary_hits;
    return fabs(ha - hb) <= AGREE_REL * fmax(ha, hb) &&
           fabs(a->primary_tsum - b->primary_tsum) <= AGREE_REL * fmax(fabs(a->primary_tsum), fabs(b->primary_tsum));
}

/* ---- scaling ---- */

static bool is_power_of_two(float f)
{
    int exp;
    return isfinite(f) && f > 0.0f && frexpf(f, &exp) == 0.5f;
}

bool arbor_bench_scale_mesh(arbor_mesh *m, float scale, arbor_err *e)
{
    if (!is_power_of_two(scale))
        return arbor_fail(e, ARBOR_ERR_INVALID, "scale %.9g is not a power of two", (double)scale);
    /* all checked before any is changed, so a refused scale leaves m whole */
    for (uint32_t i = 0; i < m->nverts; i++) {
        const float c[3] = {m->verts[i].x, m->verts[i].y, m->verts[i].z};
        for (int k = 0; k < 3; k++)
            if (c[k] != 0.0f && fpclassify(c[k] * scale) != FP_NORMAL)
                return arbor_fail(e, ARBOR_ERR_INVALID,
                                  "vertex %u: coordinate %.9g times scale %.9g leaves float's normal range", i + 1,
                                  (double)c[k], (double)scale);
    }
    float size = vec3_length(vec3_sub(m->bounds.hi, m->bounds.lo)) * scale;
    if (!arbor_size_traceable(size))
        return arbor_fail(e, ARBOR_ERR_INVALID,
                          "scale %.9g makes the model %.3g across, outside %.3g..%.3g where single-precision ray "
                          "tests stay exact",
                          (double)scale, (double)size, (double)ARBOR_SIZE_MIN, (double)ARBOR_SIZE_MAX);
    for (uint32_t i = 0; i < m->nverts; i++)
        m->verts[i] = vec3_scale(m->verts[i], scale);
    m->bounds.lo = vec3_scale(m->bounds.lo, scale);
    m->bounds.hi = vec3_scale(m->bounds.hi, scale);
    return true;
}

/* ---- the one timing helper ---- */

typedef bool (*measure_fn)(void *ctx, double *value, arbor_err *e);

static int compare_doubles(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static bool cancelled(const atomic_bool *cancel, arbor_err *e)
{
    if (cancel != NULL && atomic_load(cancel))
        return !arbor_fail(e, ARBOR_ERR_CANCELLED, "benchmark cancelled");
    return false;
}

/* The median of values[0, n), n >= 1; sorts them. */
static double median_of(double *values, size_t n)
{
    qsort(values, n, sizeof values[0], compare_doubles);
    return n % 2 ? values[n / 2] : 0.5 * (values[n / 2 - 1] + values[n / 2]);
}

/* Calls measure `runs` times (checking the cancel flag before each);
 * *median gets the median of the values. With a peer (not NULL), each call
 * of measure is followed by one of peer, whose values are stored at
 * peer_values[0, runs) (in no particular order) and whose median goes to
 * *peer_median (if not NULL). */
static bool median_of_runs_beside(int runs, const atomic_bool *cancel, measure_fn measure, void *ctx,
                                  measure_fn peer, void *peer_ctx, double *median, double *peer_values,
                                  double *peer_median, arbor_err *e)
{
    double values[ARBOR_BENCH_MAX_RUNS];
    for (int i = 0; i < runs; i++) {
        if (cancelled(cancel, e) || !measure(ctx, &values[i], e))
            return false;
        if (peer != NULL && (cancelled(cancel, e) || !peer(peer_ctx, &peer_values[i], e)))
            return false;
    }
    *median = median_of(values, (size_t)runs);
    if (peer != NULL && peer_median != NULL)
        *peer_median = median_of(peer_values, (size_t)runs);
    return true;
}

static bool median_of_runs(int runs, const atomic_bool *cancel, measure_fn measure, void *ctx, double *median,
                           arbor_err *e)
{
    return median_of_runs_beside(runs, cancel, measure, ctx, NULL, NULL, median, NULL, NULL, e);
}

/* ---- measures ---- */

typedef struct {
    const arbor_mesh *mesh;
    arbor_build_opts opts;
    arbor_accel *tree; /* the last one built */
} build_measure;

static bool measure_build(void *ctx, double *value, arbor_err *e)
{
    build_measure *b = ctx;
    arbor_accel_free(b->tree);
    b->tree = arbor_accel_build(b->mesh, &b->opts, e);
    if (b->tree == NULL)
        return false;
    arbor_tree_stats s;
    arbor_accel_stats(b->tree, &s);
    *value = s.build_ms;
    return true;
}

typedef struct {
    arbor_pool *pool;
    const arbor_accel *tree;
    arbor_render_params params;
} render_measure;

static bool measure_render(void *ctx, double *value, arbor_err *e)
{
    render_measure *r = ctx;
    arbor_frame *f = arbor_render(r->pool, r->tree, &r->params, e);
    if (f == NULL)
        return false;
    *value = arbor_frame_result_of(f)->render_ms;
    arbor_frame_release(f);
    return true;
}

typedef struct {
    arbor_pool *pool;
    arbor_trace_kernel kernel;
    const void *tracer;
    const arbor_ray *rays;
    size_t n;
    bool any_hit;
    int threads;
    arbor_tally tally; /* of the last run's pass */
} set_measure;

static bool measure_set(void *ctx, double *value, arbor_err *e)
{
    set_measure *s = ctx;
    arbor_set_timing t;
    if (!arbor_time_set(s->pool, s->kernel, s->tracer, s->rays, s->n, s->any_hit, s->threads, SET_MIN_MS, &t, e))
        return false;
    s->tally = t.tally;
    *value = t.mrays_per_s;
    return true;
}

typedef struct {
    const arbor_mesh *mesh;
    int threads;
    const char *max_isa;
    bool robust;
    arbor_embree_peer *peer; /* the last one built */
} embree_measure;

static bool measure_embree_build(void *ctx, double *value, arbor_err *e)
{
    embree_measure *m = ctx;
    arbor_embree_free(m->peer);
    m->peer = arbor_embree_build(m->mesh, m->threads, m->max_isa, m->robust, value, e);
    return m->peer != NULL;
}

/* ---- one mesh ---- */

/* Embree's side of a run (opts.embree): its peer, rebuilt beside every
 * tree's builds; every measurement of it, which its own row's medians are
 * of; and, per tree row, the medians of the set passes beside that row,
 * which the row's ratios are to. */
#define EMBREE_BUILD 0 /* samples[0]: build ms; samples[1 + s]: set s's Mrays/s */
typedef struct {
    embree_measure measure;
    double *samples[1 + ARBOR_SET_COUNT];
    size_t nsamples[1 + ARBOR_SET_COUNT];
    double (*beside)[ARBOR_SET_COUNT]; /* per tree row */
    arbor_tally primary;               /* of a pass over the primary set */
} embree_side;

/* What every row of one arbor_bench_mesh call shares. */
typedef struct {
    const arbor_bench_opts *o;
    const char *model;
    const arbor_mesh *mesh;
    int threads;         /* resolved: never 0 */
    arbor_pool *pool;
    arbor_raysets sets;
    arbor_bench_row *rows;
    size_t done, total;
    embree_side *embree; /* NULL without opts.embree */
} bench_run;

/* Builds run on the run's pool and threads, and stop when cancelled. */
static void build_opts(const bench_run *b, arbor_accel_kind kind, arbor_builder builder, arbor_build_opts *opts)
{
    arbor_build_opts_init(opts, kind, builder);
    opts->threads = b->threads;
    opts->pool = b->pool;
    opts->cancel = b->o->cancel;
}

/* Set s's rays, and their number in *n. */
static const arbor_ray *set_rays(const arbor_raysets *sets, int s, size_t *n)
{
    const arbor_ray *rays[ARBOR_SET_COUNT] = {sets->primary, sets->diffuse, sets->shadow};
    const size_t count[ARBOR_SET_COUNT] = {sets->nprimary, sets->ndiffuse, sets->nshadow};
    *n = count[s];
    return rays[s];
}

/* Where a run's next `runs` measurements of Embree's go: the end of the
 * samples of kind k. */
static double *embree_samples_next(embree_side *x, int k, int runs)
{
    double *at = x->samples[k] + x->nsamples[k];
    x->nsamples[k] += (size_t)runs;
    return at;
}

/* Times the three sets with the tree of row b->done, filling the row's
 * Mrays/s, hits and tsum; Embree's passes alternate with its own. */
static bool time_sets(const bench_run *b, const arbor_accel *tree, arbor_bench_row *row, arbor_err *e)
{
    embree_side *x = b->embree;
    for (int s = 0; s < ARBOR_SET_COUNT; s++) {
        size_t n;
        const arbor_ray *rays = set_rays(&b->sets, s, &n);
        bool any_hit = s == ARBOR_SET_SHADOW;
        set_measure m = {b->pool, arbor_accel_kernel, tree, rays, n, any_hit, b->threads, {0, 0.0}};
        set_measure peer = {b->pool, arbor_embree_kernel, x ? x->measure.peer : NULL, rays, n, any_hit, b->threads,
                            {0, 0.0}};
        if (n == 0) {
            row->mrays[s] = 0.0;
            if (x != NULL)
                x->beside[b->done][s] = 0.0;
            continue;
        }
        if (!median_of_runs_beside(b->o->runs, b->o->cancel, measure_set, &m, x ? measure_set : NULL, &peer,
                                   &row->mrays[s], x ? embree_samples_next(x, 1 + s, b->o->runs) : NULL,
                                   x ? &x->beside[b->done][s] : NULL, e))
            return false;
        if (s == ARBOR_SET_PRIMARY) {
            row->primary_hits = m.tally.hits;
            row->primary_tsum = m.tally.tsum;
            if (x != NULL)
                x->primary = peer.tally;
        }
    }
    return true;
}

/* One counted pass over each set: the per-ray work of the tree's queries
 * (closest hit for primary and diffuse rays, any hit for shadow rays), the
 * same work the timed passes do. */
static void count_sets(const bench_run *b, const arbor_accel *tree, arbor_bench_row *row)
{
    for (int s = 0; s < ARBOR_SET_COUNT; s++) {
        size_t n;
        const arbor_ray *rays = set_rays(&b->sets, s, &n);
        arbor_trace_counts c = {0, 0};
        for (size_t i = 0; i < n; i++) {
            arbor_ray r = rays[i];
            arbor_hit h;
            if (s == ARBOR_SET_SHADOW)
                arbor_accel_occluded_counted(tree, &r, &c);
            else
                arbor_accel_intersect_counted(tree, &r, &h, &c);
        }
        row->nodes_per_ray[s] = n > 0 ? (double)c.nodes / (double)n : 0.0;
        row->tris_per_ray[s] = n > 0 ? (double)c.tris / (double)n : 0.0;
    }
}

static void row_init(const bench_run *b, arbor_bench_row *row, const char *accel, const char *builder)
{
    memset(row, 0, sizeof *row);
    snprintf(row->model, sizeof row->model, "%s", b->model);
    row->scale = b->o->scale;
    row->triangles = b->mesh->ntris;
    row->accel = accel;
    row->builder = builder;
    row->threads = b->threads;
    row->mean_leaf_depth = row->mean_tris_per_leaf = row->sah_cost = row->render_ms = row->bytes_per_tri = NAN;
    for (int s = 0; s < ARBOR_SET_COUNT; s++)
        row->ratio[s] = row->nodes_per_ray[s] = row->tris_per_ray[s] = NAN;
}

static void row_finished(bench_run *b)
{
    b->done++;
    if (b->o->row_done != NULL)
        b->o->row_done(b->o->user, &b->rows[b->done - 1], b->done, b->total);
}

/* One tree kind and builder: build, statistics, render, ray sets. */
static bool bench_tree(bench_run *b, arbor_accel_kind kind, arbor_builder builder, arbor_err *e)
{
    arbor_bench_row *row = &b->rows[b->done];
    row_init(b, row, arbor_accel_kind_name(kind), arbor_builder_name(builder));
    row->kernel = arbor_accel_kernel_name();
    build_measure bm;
    bm.mesh = b->mesh;
    bm.tree = NULL;
    build_opts(b, kind, builder, &bm.opts);
    embree_side *x = b->embree;
    bool ok = median_of_runs_beside(b->o->runs, b->o->cancel, measure_build, &bm, x ? measure_embree_build : NULL,
                                    x ? &x->measure : NULL, &row->build_ms,
                                    x ? embree_samples_next(x, EMBREE_BUILD, b->o->runs) : NULL, NULL, e);
    if (ok) {
        arbor_tree_stats s;
        arbor_accel_stats(bm.tree, &s);
        row->mean_leaf_depth = s.mean_leaf_depth;
        row->mean_tris_per_leaf = s.mean_tris_per_leaf;
        row->sah_cost = s.sah_cost;
        if (b->mesh->ntris > 0)
            row->bytes_per_tri = (double)(s.has_wide ? s.wide.bytes : s.bytes) / (double)b->mesh->ntris;
        render_measure r;
        r.pool = b->pool;
        r.tree = bm.tree;
        arbor_render_params_init(&r.params, b->mesh, ARBOR_PROTOCOL_WIDTH, ARBOR_PROTOCOL_HEIGHT);
        ok = median_of_runs(b->o->runs, b->o->cancel, measure_render, &r, &row->render_ms, e);
    }
    ok = ok && time_sets(b, bm.tree, row, e);
    if (ok)
        count_sets(b, bm.tree, row);
    arbor_accel_free(bm.tree);
    if (ok)
        row_finished(b);
    return ok;
}

/* Embree's row, the last: the medians of all its measurements beside the
 * tree rows. */
static void embree_row(bench_run *b)
{
    const embree_side *x = b->embree;
    arbor_bench_row *row = &b->rows[b->done];
    row_init(b, row, "embree", arbor_embree_mode(x->measure.peer));
    row->kernel = b->o->embree_isa;
    row->build_ms = median_of(x->samples[EMBREE_BUILD], x->nsamples[EMBREE_BUILD]);
    if (b->mesh->ntris > 0)
        row->bytes_per_tri = (double)arbor_embree_bvh_bytes(x->measure.peer) / (double)b->mesh->ntris;
    for (int s = 0; s < ARBOR_SET_COUNT; s++) /* no samples: a set without rays */
        row->mrays[s] = x->nsamples[1 + s] > 0 ? median_of(x->samples[1 + s], x->nsamples[1 + s]) : 0.0;
    row->primary_hits = x->primary.hits;
    row->primary_tsum = x->primary.tsum;
    row_finished(b);
}

/* The ray sets: primary, then diffuse and shadow from the hits of the
 * first requested tree. */
static bool make_sets(bench_run *b, arbor_err *e)
{
    int kind = 0, builder = 0;
    while (!b->o->kinds[kind])
        kind++;
    while (!b->o->builders[builder])
        builder++;
    if (!arbor_raysets_primary(b->mesh, &b->sets, e))
        return false;
    arbor_build_opts opts;
    build_opts(b, (arbor_accel_kind)kind, (arbor_builder)builder, &opts);
    arbor_accel *ref = arbor_accel_build(b->mesh, &opts, e);
    arbor_hit *hits = malloc(b->sets.nprimary * sizeof *hits);
    bool *found = malloc(b->sets.nprimary * sizeof *found);
    bool ok = ref != NULL && hits != NULL && found != NULL;
    if (ref != NULL && !ok)
        arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory for the reference trace");
    ok = ok && arbor_accel_trace_hits(b->pool, ref, b->sets.primary, b->sets.nprimary, b->threads, hits, found, e) &&
         arbor_raysets_secondary(b->mesh, &b->sets, hits, found, DIFFUSE_SEED, e);
    free(hits);
    free(found);
    arbor_accel_free(ref);
    return ok;
}

/* Every tree row's Mrays/s over Embree's median beside it. */
static void fill_ratios(bench_run *b)
{
    for (size_t i = 0; i + 1 < b->total; i++)
        for (int s = 0; s < ARBOR_SET_COUNT; s++) {
            double peer = b->embree->beside[i][s];
            b->rows[i].ratio[s] = peer > 0.0 ? b->rows[i].mrays[s] / peer : NAN;
        }
}

static void embree_side_free(embree_side *x)
{
    if (x == NULL)
        return;
    arbor_embree_free(x->measure.peer);
    for (int k = 0; k < 1 + ARBOR_SET_COUNT; k++)
        free(x->samples[k]);
    free(x->beside);
    free(x);
}

/* Embree's side for a run of `trees` tree rows: room for `runs`
 * measurements of each kind per row. NULL when out of memory. */
static embree_side *embree_side_new(const bench_run *b, size_t trees)
{
    embree_side *x = calloc(1, sizeof *x);
    if (x == NULL)
        return NULL;
    x->measure = (embree_measure){b->mesh, b->threads, b->o->embree_isa, b->o->embree_robust, NULL};
    bool ok = (x->beside = calloc(trees, sizeof *x->beside)) != NULL;
    for (int k = 0; k < 1 + ARBOR_SET_COUNT; k++)
        ok = ok && (x->samples[k] = malloc(trees * (size_t)b->o->runs * sizeof(double))) != NULL;
    if (!ok) {
        embree_side_free(x);
        return NULL;
    }
    return x;
}

static bool check_opts(const arbor_bench_opts *o, arbor_err *e)
{
    if (o->runs < 1 || o->runs > ARBOR_BENCH_MAX_RUNS)
        return arbor_fail(e, ARBOR_ERR_INVALID, "runs must be in 1..%d, not %d", ARBOR_BENCH_MAX_RUNS, o->runs);
    if (!is_power_of_two(o->scale))
        return arbor_fail(e, ARBOR_ERR_INVALID, "scale %.9g is not a power of two", (double)o->scale);
    if (o->threads < 0)
        return arbor_fail(e, ARBOR_ERR_INVALID, "threads must be 0 (one per core) or more, not %d", o->threads);
    if (count_chosen(o->kinds, ARBOR_ACCEL_KIND_COUNT) == 0 || count_chosen(o->builders, ARBOR_BUILDER_COUNT) == 0)
        return arbor_fail(e, ARBOR_ERR_INVALID, "at least one tree kind and one builder to measure");
    if (o->embree && !arbor_embree_available())
        return arbor_fail(e, ARBOR_ERR_INVALID, "built without Embree; run `make bench-embree`");
    return true;
}

static bool bench_all(bench_run *b, arbor_err *e)
{
    const arbor_bench_opts *o = b->o;
    if (cancelled(o->cancel, e) || !make_sets(b, e))
        return false;
    if (o->embree && (b->embree = embree_side_new(b, b->total - 1)) == NULL)
        return arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory for Embree's measurements");
    for (int k = 0; k < ARBOR_ACCEL_KIND_COUNT; k++)
        for (int bl = 0; bl < ARBOR_BUILDER_COUNT; bl++)
            if (o->kinds[k] && o->builders[bl] && !bench_tree(b, (arbor_accel_kind)k, (arbor_builder)bl, e))
                return false;
    if (o->embree) {
        embree_row(b);
        fill_ratios(b);
    }
    return true;
}

/* *view: m with its own copy of the vertices, scaled; every other array is
 * m's, so only view->verts is to be freed (never arbor_mesh_free). */
static bool scaled_view(const arbor_mesh *m, float scale, arbor_mesh *view, arbor_err *e)
{
    *view = *m;
    view->verts = malloc((m->nverts ? m->nverts : 1) * sizeof *view->verts);
    if (view->verts == NULL)
        return arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory for %u scaled vertices", m->nverts);
    if (m->nverts > 0)
        memcpy(view->verts, m->verts, m->nverts * sizeof *view->verts);
    if (!arbor_bench_scale_mesh(view, scale, e)) {
        free(view->verts);
        return false;
    }
    return true;
}

bool arbor_bench_mesh(const char *model_name, const arbor_mesh *m, const arbor_bench_opts *o,
                      arbor_bench_row *rows, arbor_err *e)
{
    if (!check_opts(o, e))
        return false;
    bench_run b;
    memset(&b, 0, sizeof b);
    b.o = o;
    b.model = model_name;
    b.mesh = m;
    b.threads = o->threads > 0 ? o->threads : o->pool != NULL ? arbor_pool_threads(o->pool) : arbor_cpu_count();
    b.rows = rows;
    b.total = arbor_bench_row_count(o);
    arbor_mesh scaled;
    if (o->scale != 1.0f) {
        if (!scaled_view(m, o->scale, &scaled, e))
            return false;
        b.mesh = &scaled;
    }
    b.pool = o->pool != NULL ? o->pool : arbor_pool_create(b.threads, e);
    bool ok = b.pool != NULL && bench_all(&b, e);
    embree_side_free(b.embree);
    arbor_raysets_free(&b.sets);
    if (o->pool == NULL)
        arbor_pool_destroy(b.pool);
    if (b.mesh != m)
        free(scaled.verts);
    return ok;
}

/* ---- OBJ parse speed ---- */

typedef struct {
    const char *text, *name;
    size_t len;
    uint32_t triangles;
} parse_measure;

static bool measure_parse(void *ctx, double *value, arbor_err *e)
{
    parse_measure *p = ctx;
    arbor_mesh m;
    double t0 = arbor_now_ms();
    bool ok = arbor_load_obj_text(p->text, p->len, p->name, NULL, &m, e);
    *value = arbor_now_ms() - t0;
    p->triangles = m.ntris;
    arbor_mesh_free(&m);
    return ok;
}

bool arbor_bench_parse(const char *path, int runs, const atomic_bool *cancel, arbor_parse_timing *out,
                       arbor_err *e)
{
    if (runs < 1 || runs > ARBOR_BENCH_MAX_RUNS)
        return arbor_fail(e, ARBOR_ERR_INVALID, "runs must be in 1..%d, not %d", ARBOR_BENCH_MAX_RUNS, runs);
    char *text;
    parse_measure p = {NULL, path, 0, 0};
    if (!arbor_load_file(path, 0, &text, &p.len, e))
        return false;
    p.text = text;
    memset(out, 0, sizeof *out);
    bool ok = median_of_runs(runs, cancel, measure_parse, &p, &out->parse_ms, e);
    free(text);
    out->bytes = p.len;
    out->triangles = p.triangles;
    out->mb_per_s = out->parse_ms > 0.0 ? (double)p.len / 1e6 / (out->parse_ms / 1e3) : 0.0;
    return ok;
}

bool arbor_bench_kind_index(const char *name, int *index)
{
    arbor_accel_kind k;
    bool ok = arbor_accel_kind_parse(name, &k);
    *index = (int)k;
    return ok;
}

bool arbor_bench_builder_index(const char *name, int *index)
{
    arbor_builder b;
    bool ok = arbor_builder_parse(name, &b);
    *index = (int)b;
    return ok;
}
