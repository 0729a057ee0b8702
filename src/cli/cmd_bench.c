/*
 * cmd_bench.c - arbord bench: the study's four measures (build ms, mean leaf
 * depth, mean triangles per leaf, render ms) plus sah_cost for each model,
 * tree kind and builder, and PROTOCOL.md's ray sets traced and timed, with
 * Embree beside them when asked (--embree); or, with --parse, OBJ parse speed.
 *
 * Every figure is the median of --runs repetitions through one helper,
 * median_of_runs. The ray sets are made once per model: primary from the
 * camera, diffuse and shadow from the primary hits of a reference trace with
 * the first requested tree; every tracer is then timed on those same rays by
 * the library's arbor_time_set. Progress goes to stderr, results to stdout.
 */
#include <cjson/cJSON.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <zlib.h>

#include "arbor/accel.h"
#include "arbor/load.h"
#include "arbor/raysets.h"
#include "arbor/render.h"
#include "arbor/sys.h"
#include "cli.h"
#include "embree_peer.h"

#define MAX_MODELS 64
#define SET_MIN_MS 200.0
#define AGREE_REL 1e-3
#define DIFFUSE_SEED 20240601u

typedef enum { FORMAT_MD, FORMAT_CSV, FORMAT_JSON } bench_format;
enum { SET_PRIMARY, SET_DIFFUSE, SET_SHADOW, SET_COUNT };
static const char *const set_names[SET_COUNT] = {"primary", "diffuse", "shadow"};

typedef struct {
    const char *models[MAX_MODELS];
    int nmodels;
    bool kinds[ARBOR_ACCEL_KIND_COUNT];
    bool builders[ARBOR_BUILDER_COUNT];
    int threads, runs;
    bench_format format;
    bool embree, parse;
} bench_args;

/* One line of the results. Tree statistics and render_ms are NAN for Embree,
 * ratios NAN without it. */
typedef struct {
    const char *model;
    uint32_t triangles;
    const char *accel, *builder;
    int threads;
    double build_ms, mean_leaf_depth, mean_tris_per_leaf, sah_cost, render_ms;
    double mrays[SET_COUNT];
    double ratio[SET_COUNT];
    uint64_t primary_hits;
    double primary_tsum;
} bench_row;

typedef struct {
    bench_row *rows;
    size_t n, cap;
} row_list;

static void usage(FILE *out)
{
    fprintf(out,
            "usage: arbord bench --model FILE [--model FILE ...] [options]\n"
            "  --accel LIST      tree kinds, comma-separated: bvh,kd (default both)\n"
            "  --builder LIST    spatial,median,mean,sah (default all)\n"
            "  --threads N       tracing, rendering and build threads (default: one per core)\n"
            "  --runs N          repetitions; every figure is their median (default 5)\n"
            "  --format F        md, csv or json (one object per line) (default md)\n"
            "  --embree          add Intel Embree's row and each row's ratio to it\n"
            "  --parse           instead: time the OBJ parser on each model's text in memory\n");
}

/* ---- the one timing helper ---- */

typedef bool (*measure_fn)(void *ctx, double *value, arbor_err *e);

static int compare_doubles(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* Calls measure `runs` times; *median gets the median of the values. */
static bool median_of_runs(int runs, measure_fn measure, void *ctx, double *median, arbor_err *e)
{
    double values[100];
    for (int i = 0; i < runs; i++)
        if (!measure(ctx, &values[i], e))
            return false;
    qsort(values, (size_t)runs, sizeof values[0], compare_doubles);
    *median = runs % 2 ? values[runs / 2] : 0.5 * (values[runs / 2 - 1] + values[runs / 2]);
    return true;
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
    if (!arbor_time_set(NULL, s->kernel, s->tracer, s->rays, s->n, s->any_hit, s->threads, SET_MIN_MS, &t, e))
        return false;
    s->tally = t.tally;
    *value = t.mrays_per_s;
    return true;
}

typedef struct {
    const arbor_mesh *mesh;
    int threads;
    embree_peer *peer; /* the last one built */
} embree_measure;

static bool measure_embree_build(void *ctx, double *value, arbor_err *e)
{
    embree_measure *m = ctx;
    embree_peer_free(m->peer);
    m->peer = embree_peer_build(m->mesh, m->threads, value, e);
    return m->peer != NULL;
}

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

/* ---- the ray sets of one model, on every tracer ---- */

/* Times the three sets with one tracer, filling the row's Mrays/s, hits, tsum. */
static bool time_sets(const bench_args *a, const arbor_raysets *sets, arbor_trace_kernel kernel, const void *tracer,
                      bench_row *row, arbor_err *e)
{
    const arbor_ray *rays[SET_COUNT] = {sets->primary, sets->diffuse, sets->shadow};
    size_t n[SET_COUNT] = {sets->nprimary, sets->ndiffuse, sets->nshadow};
    for (int s = 0; s < SET_COUNT; s++) {
        set_measure m = {kernel, tracer, rays[s], n[s], s == SET_SHADOW, a->threads, {0, 0.0}};
        if (n[s] == 0) {
            row->mrays[s] = 0.0;
            continue;
        }
        if (!median_of_runs(a->runs, measure_set, &m, &row->mrays[s], e))
            return false;
        if (s == SET_PRIMARY) {
            row->primary_hits = m.tally.hits;
            row->primary_tsum = m.tally.tsum;
        }
    }
    return true;
}

static void row_init(bench_row *row, const char *model, const arbor_mesh *m, const char *accel, const char *builder,
                     int threads)
{
    memset(row, 0, sizeof *row);
    row->model = model;
    row->triangles = m->ntris;
    row->accel = accel;
    row->builder = builder;
    row->threads = threads;
    row->mean_leaf_depth = row->mean_tris_per_leaf = row->sah_cost = row->render_ms = NAN;
    for (int s = 0; s < SET_COUNT; s++)
        row->ratio[s] = NAN;
}

static bool row_push(row_list *l, const bench_row *row, arbor_err *e)
{
    if (l->n == l->cap) {
        size_t cap = l->cap ? 2 * l->cap : 16;
        bench_row *grown = realloc(l->rows, cap * sizeof *grown);
        if (grown == NULL)
            return arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory for the results");
        l->rows = grown;
        l->cap = cap;
    }
    l->rows[l->n++] = *row;
    return true;
}

/* One tree kind and builder: build, statistics, render, ray sets. */
static bool bench_tree(const bench_args *a, const char *model, const arbor_mesh *mesh, const arbor_raysets *sets,
                       arbor_pool *pool, arbor_accel_kind kind, arbor_builder builder, bench_row *row, arbor_err *e)
{
    row_init(row, model, mesh, arbor_accel_kind_name(kind), arbor_builder_name(builder), a->threads);
    fprintf(stderr, "bench: %s %s %s: build\n", model, row->accel, row->builder);
    build_measure b;
    b.mesh = mesh;
    b.tree = NULL;
    arbor_build_opts_init(&b.opts, kind, builder);
    b.opts.threads = a->threads;
    bool ok = median_of_runs(a->runs, measure_build, &b, &row->build_ms, e);
    if (ok) {
        arbor_tree_stats s;
        arbor_accel_stats(b.tree, &s);
        row->mean_leaf_depth = s.mean_leaf_depth;
        row->mean_tris_per_leaf = s.mean_tris_per_leaf;
        row->sah_cost = s.sah_cost;
        fprintf(stderr, "bench: %s %s %s: render\n", model, row->accel, row->builder);
        render_measure r;
        r.pool = pool;
        r.tree = b.tree;
        arbor_render_params_init(&r.params, mesh, ARBOR_PROTOCOL_WIDTH, ARBOR_PROTOCOL_HEIGHT);
        ok = median_of_runs(a->runs, measure_render, &r, &row->render_ms, e);
    }
    if (ok) {
        fprintf(stderr, "bench: %s %s %s: ray sets\n", model, row->accel, row->builder);
        ok = time_sets(a, sets, arbor_accel_kernel, b.tree, row, e);
    }
    arbor_accel_free(b.tree);
    return ok;
}

static bool bench_embree(const bench_args *a, const char *model, const arbor_mesh *mesh, const arbor_raysets *sets,
                         bench_row *row, arbor_err *e)
{
    row_init(row, model, mesh, "embree", "default", a->threads);
    fprintf(stderr, "bench: %s embree: build\n", model);
    embree_measure m = {mesh, a->threads, NULL};
    bool ok = median_of_runs(a->runs, measure_embree_build, &m, &row->build_ms, e);
    if (ok) {
        fprintf(stderr, "bench: %s embree: ray sets\n", model);
        ok = time_sets(a, sets, embree_peer_kernel, m.peer, row, e);
    }
    embree_peer_free(m.peer);
    return ok;
}

/* The ray sets: primary, then diffuse and shadow from the hits of the
 * first requested tree. */
static bool make_sets(const bench_args *a, const arbor_mesh *mesh, arbor_raysets *sets, arbor_err *e)
{
    int kind = 0, builder = 0;
    while (!a->kinds[kind])
        kind++;
    while (!a->builders[builder])
        builder++;
    if (!arbor_raysets_primary(mesh, sets, e))
        return false;
    arbor_build_opts opts;
    arbor_build_opts_init(&opts, (arbor_accel_kind)kind, (arbor_builder)builder);
    opts.threads = a->threads;
    arbor_accel *ref = arbor_accel_build(mesh, &opts, e);
    arbor_hit *hits = malloc(sets->nprimary * sizeof *hits);
    bool *found = malloc(sets->nprimary * sizeof *found);
    bool ok = ref != NULL && hits != NULL && found != NULL;
    if (ref != NULL && !ok)
        arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory for the reference trace");
    ok = ok && arbor_accel_trace_hits(NULL, ref, sets->primary, sets->nprimary, a->threads, hits, found, e) &&
         arbor_raysets_secondary(mesh, sets, hits, found, DIFFUSE_SEED, e);
    free(hits);
    free(found);
    arbor_accel_free(ref);
    return ok;
}

static bool agree(double a, double b)
{
    return fabs(a - b) <= AGREE_REL * fmax(fabs(a), fabs(b));
}

/* Warns about tracers whose primary hits disagree with the first row's, and
 * fills every arbor row's ratios to the Embree row (if any). */
static void compare_rows(bench_row *rows, size_t n)
{
    const bench_row *peer = NULL;
    for (size_t i = 0; i < n; i++)
        if (strcmp(rows[i].accel, "embree") == 0)
            peer = &rows[i];
    for (size_t i = 0; i < n; i++) {
        bench_row *r = &rows[i];
        if (!agree((double)r->primary_hits, (double)rows[0].primary_hits) || !agree(r->primary_tsum, rows[0].primary_tsum))
            fprintf(stderr,
                    "bench: warning: %s %s %s traced different primary hits (%llu hits, tsum %.6g) than %s %s "
                    "(%llu hits, tsum %.6g)\n",
                    r->model, r->accel, r->builder, (unsigned long long)r->primary_hits, r->primary_tsum,
                    rows[0].accel, rows[0].builder, (unsigned long long)rows[0].primary_hits, rows[0].primary_tsum);
        if (peer != NULL && r != peer)
            for (int s = 0; s < SET_COUNT; s++)
                r->ratio[s] = peer->mrays[s] > 0.0 ? r->mrays[s] / peer->mrays[s] : NAN;
    }
}

static const char *base_name(const char *path)
{
    const char *slash = strrchr(path, '/');
    return slash ? slash + 1 : path;
}

static bool bench_model(const bench_args *a, const char *path, arbor_pool *pool, row_list *out, arbor_err *e)
{
    const char *model = base_name(path);
    arbor_mesh mesh;
    fprintf(stderr, "bench: %s: load\n", model);
    if (!arbor_load_model(path, &mesh, e))
        return false;
    arbor_raysets sets;
    fprintf(stderr, "bench: %s: %u triangles; ray sets\n", model, mesh.ntris);
    bool ok = make_sets(a, &mesh, &sets, e);
    size_t first = out->n;
    bench_row row;
    for (int k = 0; ok && k < ARBOR_ACCEL_KIND_COUNT; k++)
        for (int b = 0; ok && b < ARBOR_BUILDER_COUNT; b++)
            if (a->kinds[k] && a->builders[b])
                ok = bench_tree(a, model, &mesh, &sets, pool, (arbor_accel_kind)k, (arbor_builder)b, &row, e) &&
                     row_push(out, &row, e);
    if (ok && a->embree)
        ok = bench_embree(a, model, &mesh, &sets, &row, e) && row_push(out, &row, e);
    if (ok)
        compare_rows(out->rows + first, out->n - first);
    arbor_raysets_free(&sets);
    arbor_mesh_free(&mesh);
    return ok;
}

/* ---- output ---- */

static const char *const json_keys[] = {"model", "triangles", "accel", "builder", "threads", "build_ms",
                                        "mean_leaf_depth", "mean_tris_per_leaf", "sah_cost", "render_ms",
                                        "primary_mrays", "diffuse_mrays", "shadow_mrays", "primary_hits",
                                        "primary_tsum"};
#define NKEYS (sizeof json_keys / sizeof json_keys[0])

/* Prints o on one line and frees it. */
static void print_json_object(cJSON *o)
{
    char *text = cJSON_PrintUnformatted(o);
    if (text != NULL)
        puts(text);
    free(text);
    cJSON_Delete(o);
}

static void add_number(cJSON *o, const char *key, double v)
{
    if (isnan(v))
        cJSON_AddNullToObject(o, key);
    else
        cJSON_AddNumberToObject(o, key, v);
}

static void print_json_row(const bench_row *r, bool with_ratios)
{
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "model", r->model);
    cJSON_AddNumberToObject(o, "triangles", r->triangles);
    cJSON_AddStringToObject(o, "accel", r->accel);
    cJSON_AddStringToObject(o, "builder", r->builder);
    cJSON_AddNumberToObject(o, "threads", r->threads);
    add_number(o, "build_ms", r->build_ms);
    add_number(o, "mean_leaf_depth", r->mean_leaf_depth);
    add_number(o, "mean_tris_per_leaf", r->mean_tris_per_leaf);
    add_number(o, "sah_cost", r->sah_cost);
    add_number(o, "render_ms", r->render_ms);
    for (int s = 0; s < SET_COUNT; s++) {
        char key[32];
        snprintf(key, sizeof key, "%s_mrays", set_names[s]);
        add_number(o, key, r->mrays[s]);
    }
    cJSON_AddNumberToObject(o, "primary_hits", (double)r->primary_hits);
    cJSON_AddNumberToObject(o, "primary_tsum", r->primary_tsum);
    for (int s = 0; with_ratios && s < SET_COUNT; s++) {
        if (isnan(r->ratio[s]))
            continue; /* the Embree row itself */
        char key[32];
        snprintf(key, sizeof key, "%s_ratio", set_names[s]);
        cJSON_AddNumberToObject(o, key, r->ratio[s]);
    }
    print_json_object(o);
}

/* Prints one cell of a table row: csv cells are comma-separated, md cells
 * framed by "| ". */
static void put_cell(bool csv, bool first, const char *text)
{
    printf("%s%s", first ? (csv ? "" : "| ") : (csv ? "," : " | "), text);
}

/* A number cell, "-" when not applicable. */
static void put_number(bool csv, const char *fmt, double v)
{
    char buf[64];
    if (isnan(v))
        snprintf(buf, sizeof buf, "-");
    else
        snprintf(buf, sizeof buf, fmt, v);
    put_cell(csv, false, buf);
}

static void print_table_row(const bench_row *r, bool with_ratios, bool csv)
{
    put_cell(csv, true, r->model);
    put_number(csv, "%.0f", r->triangles);
    put_cell(csv, false, r->accel);
    put_cell(csv, false, r->builder);
    put_number(csv, "%.0f", r->threads);
    put_number(csv, "%.2f", r->build_ms);
    put_number(csv, "%.2f", r->mean_leaf_depth);
    put_number(csv, "%.2f", r->mean_tris_per_leaf);
    put_number(csv, "%.2f", r->sah_cost);
    put_number(csv, "%.1f", r->render_ms);
    for (int s = 0; s < SET_COUNT; s++)
        put_number(csv, "%.2f", r->mrays[s]);
    put_number(csv, "%.0f", (double)r->primary_hits);
    put_number(csv, "%.6g", r->primary_tsum);
    for (int s = 0; with_ratios && s < SET_COUNT; s++)
        put_number(csv, "%.2f", r->ratio[s]);
    puts(csv ? "" : " |");
}

static void print_rows(const bench_args *a, const row_list *rows)
{
    bool ratios = a->embree;
    if (a->format == FORMAT_JSON) {
        for (size_t i = 0; i < rows->n; i++)
            print_json_row(&rows->rows[i], ratios);
        return;
    }
    bool csv = a->format == FORMAT_CSV;
    for (size_t k = 0; k < NKEYS; k++)
        put_cell(csv, k == 0, json_keys[k]);
    for (int s = 0; ratios && s < SET_COUNT; s++) {
        char key[32];
        snprintf(key, sizeof key, "%s_ratio", set_names[s]);
        put_cell(csv, false, key);
    }
    puts(csv ? "" : " |");
    if (!csv) {
        for (size_t k = 0; k < NKEYS + (ratios ? SET_COUNT : 0); k++)
            printf("|---");
        puts("|");
    }
    for (size_t i = 0; i < rows->n; i++)
        print_table_row(&rows->rows[i], ratios, csv);
}

/* ---- --parse ---- */

/* The whole file, decompressed when it is gzip (zlib reads plain files as they are). */
static char *read_model_text(const char *path, size_t *len, arbor_err *e)
{
    gzFile gz = gzopen(path, "rb");
    if (gz == NULL) {
        arbor_fail(e, ARBOR_ERR_IO, "%s: cannot open", path);
        return NULL;
    }
    size_t cap = 1 << 20, n = 0;
    char *text = malloc(cap);
    int got = 0;
    /* gzread takes an unsigned count and returns an int: read at most 1 GiB at a time */
    while (text != NULL && (got = gzread(gz, text + n, (unsigned)(cap - n < (1u << 30) ? cap - n : (1u << 30)))) > 0) {
        n += (size_t)got;
        if (n == cap) {
            char *grown = realloc(text, cap *= 2);
            if (grown == NULL)
                free(text);
            text = grown;
        }
    }
    gzclose(gz);
    if (text == NULL || got < 0) {
        free(text);
        arbor_fail(e, text == NULL ? ARBOR_ERR_NOMEM : ARBOR_ERR_IO, "%s: cannot read", path);
        return NULL;
    }
    *len = n;
    return text;
}

static void print_json_parse(const char *model, size_t bytes, uint32_t triangles, double ms, double mbps)
{
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "model", model);
    cJSON_AddNumberToObject(o, "bytes", (double)bytes);
    cJSON_AddNumberToObject(o, "triangles", triangles);
    cJSON_AddNumberToObject(o, "parse_ms", ms);
    cJSON_AddNumberToObject(o, "mb_per_s", mbps);
    print_json_object(o);
}

static int run_parse(const bench_args *a)
{
    bool csv = a->format == FORMAT_CSV;
    if (a->format == FORMAT_MD)
        printf("| model | bytes | triangles | parse_ms | mb_per_s |\n|---|---|---|---|---|\n");
    else if (csv)
        printf("model,bytes,triangles,parse_ms,mb_per_s\n");
    for (int i = 0; i < a->nmodels; i++) {
        arbor_err err;
        parse_measure p = {NULL, a->models[i], 0, 0};
        double ms = 0.0;
        char *text = read_model_text(a->models[i], &p.len, &err);
        p.text = text;
        fprintf(stderr, "bench: %s: parse\n", base_name(a->models[i]));
        bool ok = text != NULL && median_of_runs(a->runs, measure_parse, &p, &ms, &err);
        free(text);
        if (!ok) {
            fprintf(stderr, "arbord bench: %s\n", err.msg);
            return 1;
        }
        double mbps = ms > 0.0 ? (double)p.len / 1e6 / (ms / 1e3) : 0.0;
        const char *name = base_name(a->models[i]);
        if (a->format == FORMAT_JSON)
            print_json_parse(name, p.len, p.triangles, ms, mbps);
        else
            printf(csv ? "%s,%zu,%u,%.3f,%.1f\n" : "| %s | %zu | %u | %.3f | %.1f |\n", name, p.len, p.triangles,
                   ms, mbps);
    }
    return 0;
}

/* ---- arguments ---- */

/* Marks each comma-separated name of list in `chosen` via parse; false with a message for an unknown one. */
static bool parse_list(const char *opt, const char *list, bool *chosen, int count,
                       bool (*parse)(const char *name, int *index))
{
    for (int i = 0; i < count; i++)
        chosen[i] = false;
    char buf[256];
    snprintf(buf, sizeof buf, "%s", list);
    for (char *save = NULL, *name = strtok_r(buf, ",", &save); name != NULL; name = strtok_r(NULL, ",", &save)) {
        int index;
        if (!parse(name, &index)) {
            fprintf(stderr, "arbord bench: %s: unknown name '%s'\n", opt, name);
            return false;
        }
        chosen[index] = true;
    }
    for (int i = 0; i < count; i++)
        if (chosen[i])
            return true;
    fprintf(stderr, "arbord bench: %s needs at least one name\n", opt);
    return false;
}

static bool parse_kind(const char *name, int *index)
{
    arbor_accel_kind k;
    bool ok = arbor_accel_kind_parse(name, &k);
    *index = (int)k;
    return ok;
}

static bool parse_builder(const char *name, int *index)
{
    arbor_builder b;
    bool ok = arbor_builder_parse(name, &b);
    *index = (int)b;
    return ok;
}

/* Returns -1 to go on, else the exit code. */
static int parse_args(int argc, char **argv, bench_args *a)
{
    for (int i = 1; i < argc; i++) {
        const char *opt = argv[i], *v;
        bool ok = true;
        if (strcmp(opt, "--help") == 0 || strcmp(opt, "-h") == 0) {
            usage(stdout);
            return 0;
        } else if (strcmp(opt, "--embree") == 0) {
            a->embree = true;
        } else if (strcmp(opt, "--parse") == 0) {
            a->parse = true;
        } else if (strcmp(opt, "--model") == 0 || strcmp(opt, "--accel") == 0 || strcmp(opt, "--builder") == 0 ||
                   strcmp(opt, "--threads") == 0 || strcmp(opt, "--runs") == 0 || strcmp(opt, "--format") == 0) {
            if ((v = cli_value("bench", argc, argv, &i)) == NULL)
                return 2;
            if (strcmp(opt, "--model") == 0) {
                if ((ok = a->nmodels < MAX_MODELS))
                    a->models[a->nmodels++] = v;
                else
                    fprintf(stderr, "arbord bench: at most %d models\n", MAX_MODELS);
            } else if (strcmp(opt, "--accel") == 0) {
                ok = parse_list(opt, v, a->kinds, ARBOR_ACCEL_KIND_COUNT, parse_kind);
            } else if (strcmp(opt, "--builder") == 0) {
                ok = parse_list(opt, v, a->builders, ARBOR_BUILDER_COUNT, parse_builder);
            } else if (strcmp(opt, "--threads") == 0) {
                ok = cli_int("bench", opt, v, 0, 256, &a->threads);
            } else if (strcmp(opt, "--runs") == 0) {
                ok = cli_int("bench", opt, v, 1, 100, &a->runs);
            } else if (strcmp(v, "md") == 0 || strcmp(v, "csv") == 0 || strcmp(v, "json") == 0) {
                a->format = v[0] == 'm' ? FORMAT_MD : v[0] == 'c' ? FORMAT_CSV : FORMAT_JSON;
            } else {
                fprintf(stderr, "arbord bench: --format must be md, csv or json, not '%s'\n", v);
                ok = false;
            }
        } else {
            fprintf(stderr, "arbord bench: unknown option '%s'\n", opt);
            usage(stderr);
            return 2;
        }
        if (!ok)
            return 2;
    }
    if (a->nmodels == 0) {
        fprintf(stderr, "arbord bench: at least one --model FILE is required\n");
        usage(stderr);
        return 2;
    }
    return -1;
}

int cmd_bench(int argc, char **argv)
{
    bench_args a;
    memset(&a, 0, sizeof a);
    for (int k = 0; k < ARBOR_ACCEL_KIND_COUNT; k++)
        a.kinds[k] = true;
    for (int b = 0; b < ARBOR_BUILDER_COUNT; b++)
        a.builders[b] = true;
    a.runs = 5;
    int code = parse_args(argc, argv, &a);
    if (code >= 0)
        return code;
    if (a.embree && !embree_peer_available()) {
        fprintf(stderr, "arbord bench: built without Embree; run `make bench-embree`\n");
        return 2;
    }
    if (a.threads == 0)
        a.threads = arbor_cpu_count();
    if (a.parse)
        return run_parse(&a);

    arbor_err err;
    arbor_pool *pool = arbor_pool_create(a.threads, &err);
    if (pool == NULL) {
        fprintf(stderr, "arbord bench: %s\n", err.msg);
        return 1;
    }
    row_list rows = {NULL, 0, 0};
    int status = 0;
    for (int i = 0; i < a.nmodels && status == 0; i++)
        if (!bench_model(&a, a.models[i], pool, &rows, &err)) {
            fprintf(stderr, "arbord bench: %s: %s\n", a.models[i], err.msg);
            status = 1;
        }
    if (status == 0)
        print_rows(&a, &rows);
    free(rows.rows);
    arbor_pool_destroy(pool);
    return status;
}
