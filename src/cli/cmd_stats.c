/*
 * cmd_stats.c - arbord stats: build trees over a model and print their
 * statistics, one row (or one JSON object per line) per kind, builder and
 * layout: the binary tree the builders make, and the bvh's wide tree that
 * its rays traverse.
 */
#include <stdio.h>
#include <string.h>

#include "arbor/accel.h"
#include "arbor/load.h"
#include "arbor/report.h"
#include "cli.h"

static void usage(FILE *out)
{
    fprintf(out,
            "usage: arbord stats --model FILE [--accel bvh|kd|all] [--builder NAME|all] [--threads N] [--json]\n"
            "  --accel     bvh, kd or all (default bvh)\n"
            "  --builder   spatial, median, mean, sah or all (default all)\n"
            "  --threads N build threads; 0 = one per core (default 0)\n"
            "  --json      one JSON object per line instead of a table\n"
            "Each tree has a row per layout: binary (as built; what the study measured) and,\n"
            "for the bvh, wide (the collapsed tree its rays traverse).\n");
}

static void print_header(void)
{
    printf("%-5s %-8s %-6s %10s %9s %9s %7s %6s %10s %9s %10s %11s %10s\n", "accel", "builder", "layout", "build_ms",
           "nodes", "leaves", "empty", "depth", "leaf_depth", "tris/leaf", "refs", "bytes", "sah_cost");
}

/* One row per layout the tree has: the binary tree, and the bvh's wide tree. */
static void print_rows(arbor_accel_kind kind, arbor_builder b, const arbor_tree_stats *s)
{
    arbor_layout_stats l;
    for (int layout = 0; layout < ARBOR_LAYOUT_COUNT; layout++)
        if (arbor_tree_layout_stats(s, (arbor_layout)layout, &l))
            printf("%-5s %-8s %-6s %10.2f %9llu %9llu %7llu %6u %10.2f %9.2f %10llu %11llu %10.2f\n",
                   arbor_accel_kind_name(kind), arbor_builder_name(b), arbor_layout_name((arbor_layout)layout),
                   s->build_ms, (unsigned long long)l.nodes, (unsigned long long)l.leaves,
                   (unsigned long long)l.empty_leaves, l.max_depth, l.mean_leaf_depth, l.mean_tris_per_leaf,
                   (unsigned long long)l.refs, (unsigned long long)l.bytes, l.sah_cost);
}

/* One JSON object per line and layout; false when out of memory. */
static bool print_json(const char *model, uint32_t ntris, arbor_accel_kind kind, arbor_builder b,
                       const arbor_tree_stats *s)
{
    arbor_layout_stats l;
    for (int layout = 0; layout < ARBOR_LAYOUT_COUNT; layout++)
        if (arbor_tree_layout_stats(s, (arbor_layout)layout, &l) &&
            !cli_print_json(arbor_report_tree_stats(model, ntris, kind, b, s, (arbor_layout)layout)))
            return false;
    return true;
}

typedef struct {
    const char *model;
    bool json;
    int threads;
    bool all_kinds, all_builders;
    arbor_accel_kind kind;
    arbor_builder builder;
} stats_args;

/* Fills *a from the command line; returns -1 to go on, else the exit
 * status (0 after --help, 2 for a usage error). */
static int parse_args(int argc, char **argv, stats_args *a)
{
    const char *accel = "bvh", *builder = "all";
    *a = (stats_args){.model = NULL, .kind = ARBOR_ACCEL_BVH, .builder = ARBOR_BUILD_SAH};
    cli_seen seen = {.n = 0};
    for (int i = 1; i < argc; i++) {
        const char *opt = argv[i];
        if (strcmp(opt, "--help") == 0 || strcmp(opt, "-h") == 0) {
            usage(stdout);
            return 0;
        } else if (!cli_first("stats", &seen, opt)) {
            return 2;
        } else if (strcmp(opt, "--json") == 0) {
            a->json = true;
        } else if (strcmp(opt, "--model") == 0) {
            if ((a->model = cli_value("stats", argc, argv, &i)) == NULL) return 2;
        } else if (strcmp(opt, "--accel") == 0) {
            if ((accel = cli_value("stats", argc, argv, &i)) == NULL) return 2;
        } else if (strcmp(opt, "--builder") == 0) {
            if ((builder = cli_value("stats", argc, argv, &i)) == NULL) return 2;
        } else if (strcmp(opt, "--threads") == 0) {
            const char *v = cli_value("stats", argc, argv, &i);
            if (v == NULL || !cli_int("stats", "--threads", v, 0, 1024, &a->threads)) return 2;
        } else {
            fprintf(stderr, "arbord stats: unknown option '%s'\n", opt);
            usage(stderr);
            return 2;
        }
    }
    if (a->model == NULL) {
        fprintf(stderr, "arbord stats: --model FILE is required\n");
        usage(stderr);
        return 2;
    }
    a->all_kinds = strcmp(accel, "all") == 0;
    a->all_builders = strcmp(builder, "all") == 0;
    if (!a->all_kinds && !arbor_accel_kind_parse(accel, &a->kind)) {
        fprintf(stderr, "arbord stats: unknown accel '%s' (bvh, kd, all)\n", accel);
        return 2;
    }
    if (!a->all_builders && !arbor_builder_parse(builder, &a->builder)) {
        fprintf(stderr, "arbord stats: unknown builder '%s' (spatial, median, mean, sah, all)\n", builder);
        return 2;
    }
    return -1;
}

/* Builds one tree on the pool and prints its rows; false (said on stderr)
 * when the build fails or the output runs out of memory. */
static bool stats_one(const stats_args *a, const arbor_mesh *mesh, arbor_pool *pool, arbor_accel_kind kind,
                      arbor_builder b)
{
    arbor_build_opts opts;
    arbor_build_opts_init(&opts, kind, b);
    opts.threads = a->threads;
    opts.pool = pool;
    arbor_err err;
    arbor_accel *tree = arbor_accel_build(mesh, &opts, &err);
    if (tree == NULL) {
        fprintf(stderr, "arbord stats: %s %s: %s\n", arbor_accel_kind_name(kind), arbor_builder_name(b), err.msg);
        return false;
    }
    arbor_tree_stats s;
    arbor_accel_stats(tree, &s);
    bool ok = true;
    if (!a->json)
        print_rows(kind, b, &s);
    else
        ok = print_json(a->model, mesh->ntris, kind, b, &s);
    arbor_accel_free(tree);
    if (!ok)
        fprintf(stderr, "arbord stats: out of memory\n");
    return ok;
}

int cmd_stats(int argc, char **argv)
{
    stats_args a;
    int code = parse_args(argc, argv, &a);
    if (code >= 0)
        return code;
    arbor_mesh mesh;
    arbor_err err;
    if (!arbor_load_model(a.model, &mesh, &err)) {
        fprintf(stderr, "arbord stats: %s\n", err.msg);
        return 1;
    }
    for (uint32_t w = 0; w < mesh.nwarnings; w++)
        fprintf(stderr, "arbord stats: warning: %s\n", mesh.warnings[w]);
    if (!a.json) {
        printf("model %s: %u triangles, %u vertices\n", a.model, mesh.ntris, mesh.nverts);
        print_header();
    }
    /* one pool for every build of the command */
    arbor_pool *pool = arbor_pool_create(a.threads, &err);
    if (pool == NULL) {
        fprintf(stderr, "arbord stats: %s\n", err.msg);
        arbor_mesh_free(&mesh);
        return 1;
    }
    bool ok = true;
    for (int k = 0; k < ARBOR_ACCEL_KIND_COUNT && ok; k++)
        for (int b = 0; b < ARBOR_BUILDER_COUNT && ok; b++)
            if ((a.all_kinds || k == (int)a.kind) && (a.all_builders || b == (int)a.builder))
                ok = stats_one(&a, &mesh, pool, (arbor_accel_kind)k, (arbor_builder)b);
    arbor_pool_destroy(pool);
    arbor_mesh_free(&mesh);
    return ok ? 0 : 1;
}
