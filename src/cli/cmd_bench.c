/*
 * cmd_bench.c - arbord bench: arguments and printing around the bench
 * library (include/arbor/bench.h), which measures the study's tables and
 * PROTOCOL.md's ray sets for each model, tree kind and builder, with Embree
 * beside them when asked (--embree); or, with --parse, OBJ parse speed.
 *
 * Results go to stdout as an md or csv table, or JSON lines in the one
 * encoding of include/arbor/report.h; progress and warnings to stderr.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "arbor/accel.h"
#include "arbor/bench.h"
#include "arbor/embree_peer.h"
#include "arbor/load.h"
#include "arbor/report.h"
#include "cli.h"

#define MAX_MODELS 64

typedef enum { FORMAT_MD, FORMAT_CSV, FORMAT_JSON } bench_format;

typedef struct {
    const char *models[MAX_MODELS];
    int nmodels;
    arbor_bench_opts opts;
    bench_format format;
    bool parse;
} bench_args;

static void usage(FILE *out)
{
    fprintf(out,
            "usage: arbord bench --model FILE [--model FILE ...] [options]\n"
            "  --accel LIST      tree kinds, comma-separated: bvh,kd or all (default all)\n"
            "  --builder LIST    spatial,median,mean,sah or all (default all)\n"
            "  --threads N       tracing, rendering and build threads; 0 = one per core (default 0)\n"
            "  --runs N          repetitions, 1..%d; every figure is their median (default 5)\n"
            "  --format F        md, csv or json (one object per line) (default md)\n"
            "  --embree          add Intel Embree's row and each row's ratio to it\n"
            "  --embree-isa ISA  --embree, with the best kernels Embree may use: sse2, sse4.2,\n"
            "                    avx, avx2 or avx512 (default: the best the CPU has)\n"
            "  --embree-robust   --embree, in Embree's robust mode (RTC_SCENE_FLAG_ROBUST: no\n"
            "                    box lost to rounding, no shortcut at triangle edges), the\n"
            "                    Embree nearest to arbor's exactness; its row's builder is \"robust\"\n"
            "  --scale F         measure each model scaled by F, a power of two (1024, 1/1024,\n"
            "                    0.0009765625): exact, so hits and distances (times F) stay the same;\n"
            "                    refused where the model would be over 2^40 or under 2^-40 across\n"
            "  --parse           instead: time the OBJ parser on each model's text in memory\n",
            ARBOR_BENCH_MAX_RUNS);
}

static const char *base_name(const char *path)
{
    const char *slash = strrchr(path, '/');
    return slash ? slash + 1 : path;
}

/* ---- measuring ---- */

static void report_progress(void *user, const arbor_bench_row *row, size_t done, size_t total)
{
    (void)user;
    fprintf(stderr, "bench: %s %s %s: done (%zu/%zu)\n", row->model, row->accel, row->builder, done, total);
}

/* Warns about tracers whose primary hits disagree with the first row's. */
static void check_hits(const arbor_bench_row *rows, size_t n)
{
    for (size_t i = 1; i < n; i++) {
        const arbor_bench_row *r = &rows[i];
        if (!arbor_bench_same_hits(r, &rows[0]))
            fprintf(stderr,
                    "bench: warning: %s %s %s traced different primary hits (%llu hits, tsum %.6g) than %s %s "
                    "(%llu hits, tsum %.6g)\n",
                    r->model, r->accel, r->builder, (unsigned long long)r->primary_hits, r->primary_tsum,
                    rows[0].accel, rows[0].builder, (unsigned long long)rows[0].primary_hits, rows[0].primary_tsum);
    }
}

/* Loads the model and measures it into rows (arbor_bench_row_count(o) of
 * them); says why not when it cannot. */
static bool bench_model(const arbor_bench_opts *o, const char *path, arbor_bench_row *rows)
{
    const char *model = base_name(path);
    arbor_mesh mesh;
    arbor_err e;
    fprintf(stderr, "bench: %s: load\n", model);
    if (!arbor_load_model(path, &mesh, &e)) {
        fprintf(stderr, "arbord bench: %s\n", e.msg); /* it names the file */
        return false;
    }
    fprintf(stderr, "bench: %s: %u triangles, scale %.17g, kernel %s\n", model, mesh.ntris, (double)o->scale,
            arbor_accel_kernel_name());
    bool ok = arbor_bench_mesh(model, &mesh, o, rows, &e);
    if (ok)
        check_hits(rows, arbor_bench_row_count(o));
    else
        fprintf(stderr, "arbord bench: %s: %s\n", path, e.msg);
    arbor_mesh_free(&mesh);
    return ok;
}

/* ---- output ---- */

/* Prints one cell of a table row: csv cells are comma-separated, quoted
 * when they hold a comma, a quote or a line break (RFC 4180: a quote
 * doubled); md cells framed by "| ", a '|' in them escaped. A model's file
 * name may hold any of these. */
static void put_cell(bool csv, bool first, const char *text)
{
    fputs(first ? (csv ? "" : "| ") : (csv ? "," : " | "), stdout);
    bool quote = csv && strpbrk(text, ",\"\r\n") != NULL;
    if (quote)
        putchar('"');
    for (const char *c = text; *c != '\0'; c++) {
        if ((quote && *c == '"') || (!csv && *c == '|'))
            putchar(csv ? '"' : '\\');
        putchar(*c);
    }
    if (quote)
        putchar('"');
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

static void print_table_row(const arbor_bench_row *r, bool with_ratios, bool csv)
{
    put_cell(csv, true, r->model);
    put_number(csv, "%.17g", r->scale);
    put_number(csv, "%.0f", r->triangles);
    put_cell(csv, false, r->accel);
    put_cell(csv, false, r->builder);
    put_cell(csv, false, r->kernel != NULL ? r->kernel : "-");
    put_number(csv, "%.0f", r->threads);
    put_number(csv, "%.2f", r->build_ms);
    put_number(csv, "%.2f", r->mean_leaf_depth);
    put_number(csv, "%.2f", r->mean_tris_per_leaf);
    put_number(csv, "%.2f", r->sah_cost);
    put_number(csv, "%.1f", r->bytes_per_tri);
    put_number(csv, "%.1f", r->render_ms);
    for (int s = 0; s < ARBOR_SET_COUNT; s++)
        put_number(csv, "%.2f", r->mrays[s]);
    put_number(csv, "%.0f", (double)r->primary_hits);
    put_number(csv, "%.6g", r->primary_tsum);
    for (int s = 0; s < ARBOR_SET_COUNT; s++) {
        put_number(csv, "%.2f", r->nodes_per_ray[s]);
        put_number(csv, "%.2f", r->tris_per_ray[s]);
    }
    for (int s = 0; with_ratios && s < ARBOR_SET_COUNT; s++)
        put_number(csv, "%.2f", r->ratio[s]);
    puts(csv ? "" : " |");
}

/* The table's header: the JSON keys of the first row (an arbor row, which
 * has every key, ratios included), so table and JSON never drift apart. */
static bool print_table_header(const arbor_bench_row *first, bool ratios, bool csv)
{
    cJSON *o = arbor_report_bench_row(first, ratios);
    if (o == NULL)
        return false;
    int ncols = 0;
    for (const cJSON *item = o->child; item != NULL; item = item->next, ncols++)
        put_cell(csv, ncols == 0, item->string);
    cJSON_Delete(o);
    puts(csv ? "" : " |");
    if (!csv) {
        for (int k = 0; k < ncols; k++)
            printf("|---");
        puts("|");
    }
    return true;
}

/* False when a JSON object could not be made (out of memory). */
static bool print_rows(const bench_args *a, const arbor_bench_row *rows, size_t n)
{
    bool ratios = a->opts.embree;
    if (a->format == FORMAT_JSON) {
        for (size_t i = 0; i < n; i++)
            if (!cli_print_json(arbor_report_bench_row(&rows[i], ratios)))
                return false;
        return true;
    }
    bool csv = a->format == FORMAT_CSV;
    if (n > 0 && !print_table_header(&rows[0], ratios, csv))
        return false;
    for (size_t i = 0; i < n; i++)
        print_table_row(&rows[i], ratios, csv);
    return true;
}

/* ---- --parse ---- */

static int run_parse(const bench_args *a)
{
    bool csv = a->format == FORMAT_CSV;
    if (a->format == FORMAT_MD)
        printf("| model | bytes | triangles | parse_ms | mb_per_s |\n|---|---|---|---|---|\n");
    else if (csv)
        printf("model,bytes,triangles,parse_ms,mb_per_s\n");
    for (int i = 0; i < a->nmodels; i++) {
        arbor_err err;
        arbor_parse_timing t;
        const char *name = base_name(a->models[i]);
        fprintf(stderr, "bench: %s: parse\n", name);
        if (!arbor_bench_parse(a->models[i], a->opts.runs, NULL, &t, &err)) {
            fprintf(stderr, "arbord bench: %s\n", err.msg);
            return 1;
        }
        if (a->format == FORMAT_JSON) {
            if (!cli_print_json(arbor_report_parse_timing(name, &t))) {
                fprintf(stderr, "arbord bench: out of memory\n");
                return 1;
            }
        } else {
            printf(csv ? "%s,%zu,%u,%.3f,%.1f\n" : "| %s | %zu | %u | %.3f | %.1f |\n", name, t.bytes, t.triangles,
                   t.parse_ms, t.mb_per_s);
        }
    }
    return 0;
}

/* ---- arguments ---- */

/* Marks each comma-separated name of list in `chosen` via parse, or every
 * one for "all" (as arbord stats takes it); false with a message for an
 * unknown one. */
static bool parse_list(const char *opt, const char *list, bool *chosen, int count,
                       bool (*parse)(const char *name, int *index))
{
    for (int i = 0; i < count; i++)
        chosen[i] = false;
    char buf[256];
    snprintf(buf, sizeof buf, "%s", list);
    for (char *save = NULL, *name = strtok_r(buf, ",", &save); name != NULL; name = strtok_r(NULL, ",", &save)) {
        int index;
        if (strcmp(name, "all") == 0) {
            for (int i = 0; i < count; i++)
                chosen[i] = true;
            continue;
        }
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



/* --scale: a number or a fraction (1024, 1/1024, 0.0009765625) that is a
 * power of two in float, so that scaling by it is exact. */
static bool parse_scale(const char *v, float *scale)
{
    char *end;
    double num = strtod(v, &end), den = 1.0;
    bool ok = end != v;
    if (ok && *end == '/') {
        const char *d = end + 1;
        den = strtod(d, &end);
        ok = end != d;
    }
    double f = num / den;
    int exp;
    ok = ok && *end == '\0' && f > 0.0 && (double)(float)f == f && isnormal((float)f) && frexp(f, &exp) == 0.5;
    if (!ok)
        fprintf(stderr, "arbord bench: --scale must be a power of two such as 1024, 1/1024 or 0.0009765625, not '%s'\n",
                v);
    *scale = (float)f;
    return ok;
}

/* Embree's names for its ISA levels (its max_isa setting), checked here so
 * that a misspelt one is an error rather than Embree's silent default. */
static bool parse_embree_isa(const char *v, arbor_bench_opts *o)
{
    static const char *const names[] = {"sse2", "sse4.2", "avx", "avx2", "avx512"};
    for (size_t i = 0; i < sizeof names / sizeof names[0]; i++) {
        if (strcmp(v, names[i]) == 0) {
            o->embree_isa = names[i];
            o->embree = true;
            return true;
        }
    }
    fprintf(stderr, "arbord bench: --embree-isa must be sse2, sse4.2, avx, avx2 or avx512, not '%s'\n", v);
    return false;
}

/* Returns -1 to go on, else the exit code. */
static int parse_args(int argc, char **argv, bench_args *a)
{
    cli_seen seen = {.n = 0};
    for (int i = 1; i < argc; i++) {
        const char *opt = argv[i], *v;
        bool ok = true;
        if (strcmp(opt, "--help") == 0 || strcmp(opt, "-h") == 0) {
            usage(stdout);
            return 0;
        } else if (strcmp(opt, "--model") != 0 && !cli_first("bench", &seen, opt)) {
            return 2;
        } else if (strcmp(opt, "--embree") == 0) {
            a->opts.embree = true;
        } else if (strcmp(opt, "--embree-robust") == 0) {
            a->opts.embree = a->opts.embree_robust = true;
        } else if (strcmp(opt, "--parse") == 0) {
            a->parse = true;
        } else if (strcmp(opt, "--model") == 0 || strcmp(opt, "--accel") == 0 || strcmp(opt, "--builder") == 0 ||
                   strcmp(opt, "--threads") == 0 || strcmp(opt, "--runs") == 0 || strcmp(opt, "--format") == 0 ||
                   strcmp(opt, "--scale") == 0 || strcmp(opt, "--embree-isa") == 0) {
            if ((v = cli_value("bench", argc, argv, &i)) == NULL)
                return 2;
            if (strcmp(opt, "--model") == 0) {
                if ((ok = a->nmodels < MAX_MODELS))
                    a->models[a->nmodels++] = v;
                else
                    fprintf(stderr, "arbord bench: at most %d models\n", MAX_MODELS);
            } else if (strcmp(opt, "--accel") == 0) {
                ok = parse_list(opt, v, a->opts.kinds, ARBOR_ACCEL_KIND_COUNT, arbor_bench_kind_index);
            } else if (strcmp(opt, "--builder") == 0) {
                ok = parse_list(opt, v, a->opts.builders, ARBOR_BUILDER_COUNT, arbor_bench_builder_index);
            } else if (strcmp(opt, "--threads") == 0) {
                ok = cli_int("bench", opt, v, 0, 256, &a->opts.threads);
            } else if (strcmp(opt, "--runs") == 0) {
                ok = cli_int("bench", opt, v, 1, ARBOR_BENCH_MAX_RUNS, &a->opts.runs);
            } else if (strcmp(opt, "--scale") == 0) {
                ok = parse_scale(v, &a->opts.scale);
            } else if (strcmp(opt, "--embree-isa") == 0) {
                ok = parse_embree_isa(v, &a->opts);
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
    arbor_bench_opts_init(&a.opts);
    int code = parse_args(argc, argv, &a);
    if (code >= 0)
        return code;
    if (a.opts.embree && !arbor_embree_available()) {
        fprintf(stderr, "arbord bench: built without Embree; run `make bench-embree`\n");
        return 2;
    }
    if (a.parse)
        return run_parse(&a);

    arbor_err err;
    a.opts.pool = arbor_pool_create(a.opts.threads, &err);
    if (a.opts.pool == NULL) {
        fprintf(stderr, "arbord bench: %s\n", err.msg);
        return 1;
    }
    a.opts.row_done = report_progress;
    size_t per_model = arbor_bench_row_count(&a.opts);
    arbor_bench_row *rows = calloc((size_t)a.nmodels * per_model, sizeof *rows);
    int status = 0;
    if (rows == NULL) {
        fprintf(stderr, "arbord bench: out of memory for the results\n");
        status = 1;
    }
    /* a model that fails is said and skipped: the others' rows are printed,
     * and the exit status says one failed */
    size_t measured = 0;
    for (int i = 0; i < a.nmodels && rows != NULL; i++) {
        if (bench_model(&a.opts, a.models[i], rows + measured * per_model))
            measured++;
        else
            status = 1;
    }
    if (measured > 0 && !print_rows(&a, rows, measured * per_model)) {
        fprintf(stderr, "arbord bench: out of memory\n");
        status = 1;
    }
    free(rows);
    arbor_pool_destroy(a.opts.pool);
    return status;
}
