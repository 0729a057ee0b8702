/*
 * test_bench.c - the bench library (include/arbor/bench.h) and its JSON
 * encoding (include/arbor/report.h): a one-run benchmark of every tree on a
 * small Cornell box fills the rows it promised and reports each as it
 * finishes; every tree traced the primary hits brute force finds on the same
 * rays; a cancel flag, set before or during the run, stops it with
 * ARBOR_ERR_CANCELLED; with Embree, its row is last and each tree's
 * ratios are to the Embree passes beside it; a mesh measured scaled by a
 * power of two traces the same hits at distances summing to the unscaled
 * sum times the scale; bad options are refused; the JSON keys are the ones
 * scripts/bench_tables.py reads, NAN written as null; parse timing counts
 * the file's bytes and triangles.
 */
#include <cjson/cJSON.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "arbor/bench.h"
#include "arbor/brute.h"
#include "arbor/embree_peer.h"
#include "arbor/procgen.h"
#include "arbor/raysets.h"
#include "arbor/report.h"
#include "support.h"
#include "unity.h"

static arbor_mesh mesh;

void setUp(void)
{
    arbor_err e;
    /* 4 x 4 quads: small enough for brute force over all 786,432 primary rays */
    TEST_ASSERT_TRUE_MESSAGE(arbor_gen_cornell(&mesh, 4, &e), e.msg);
}

void tearDown(void)
{
    arbor_mesh_free(&mesh);
}

/* What row_done saw. */
typedef struct {
    size_t calls, done[16], total[16];
    char names[16][32];
    atomic_bool *cancel_after_first; /* set after the first row, when not NULL */
} progress_log;

static void log_row(void *user, const arbor_bench_row *row, size_t done, size_t total)
{
    progress_log *log = user;
    if (log->calls < 16) {
        log->done[log->calls] = done;
        log->total[log->calls] = total;
        snprintf(log->names[log->calls], sizeof log->names[0], "%s %s", row->accel, row->builder);
    }
    log->calls++;
    if (log->cancel_after_first != NULL)
        atomic_store(log->cancel_after_first, true);
}

static void one_run_opts(arbor_bench_opts *o, progress_log *log)
{
    arbor_bench_opts_init(o);
    o->runs = 1;
    o->threads = 2;
    o->row_done = log_row;
    o->user = log;
}

/* Primary hits of PROTOCOL.md's rays by brute force: the independent truth. */
static uint64_t brute_primary_hits(void)
{
    arbor_raysets sets;
    arbor_err e;
    TEST_ASSERT_TRUE(arbor_raysets_primary(&mesh, &sets, &e));
    arbor_hit *hit = malloc(sets.nprimary * sizeof *hit);
    bool *found = malloc(sets.nprimary * sizeof *found);
    arbor_brute_intersect_many(NULL, &mesh, sets.primary, sets.nprimary, hit, found, 0);
    uint64_t hits = 0;
    for (size_t i = 0; i < sets.nprimary; i++)
        hits += found[i];
    free(hit);
    free(found);
    arbor_raysets_free(&sets);
    return hits;
}

static void test_every_tree_gets_its_row_and_the_same_hits_as_brute_force(void)
{
    progress_log log;
    memset(&log, 0, sizeof log);
    arbor_bench_opts o;
    one_run_opts(&o, &log);
    size_t total = arbor_bench_row_count(&o);
    TEST_ASSERT_EQUAL_UINT64(ARBOR_ACCEL_KIND_COUNT * ARBOR_BUILDER_COUNT, total);
    arbor_bench_row rows[ARBOR_ACCEL_KIND_COUNT * ARBOR_BUILDER_COUNT];
    arbor_err e;
    TEST_ASSERT_TRUE_MESSAGE(arbor_bench_mesh("cornell4", &mesh, &o, rows, &e), e.msg);

    TEST_ASSERT_EQUAL_UINT64(total, log.calls);
    for (size_t i = 0; i < total; i++) {
        TEST_ASSERT_EQUAL_UINT64(i + 1, log.done[i]);
        TEST_ASSERT_EQUAL_UINT64(total, log.total[i]);
        char want[32];
        snprintf(want, sizeof want, "%s %s", rows[i].accel, rows[i].builder);
        TEST_ASSERT_EQUAL_STRING(want, log.names[i]);
    }
    uint64_t truth = brute_primary_hits();
    TEST_ASSERT_TRUE(truth > 0 && truth < (uint64_t)ARBOR_PROTOCOL_WIDTH * ARBOR_PROTOCOL_HEIGHT);
    for (size_t i = 0; i < total; i++) {
        const arbor_bench_row *r = &rows[i];
        TEST_ASSERT_EQUAL_STRING("cornell4", r->model);
        TEST_ASSERT_EQUAL_STRING(arbor_accel_kind_name((arbor_accel_kind)(i / ARBOR_BUILDER_COUNT)), r->accel);
        TEST_ASSERT_EQUAL_STRING(arbor_builder_name((arbor_builder)(i % ARBOR_BUILDER_COUNT)), r->builder);
        TEST_ASSERT_EQUAL_UINT32(mesh.ntris, r->triangles);
        TEST_ASSERT_EQUAL_INT(2, r->threads);
        TEST_ASSERT_EQUAL_STRING(arbor_accel_kernel_name(), r->kernel);
        TEST_ASSERT_EQUAL_UINT64_MESSAGE(truth, r->primary_hits, r->builder);
        TEST_ASSERT_TRUE(arbor_bench_same_hits(r, &rows[0]));
        TEST_ASSERT_TRUE(r->build_ms >= 0.0 && r->render_ms > 0.0 && r->sah_cost > 0.0);
        TEST_ASSERT_TRUE(r->mean_leaf_depth >= 0.0 && r->mean_tris_per_leaf > 0.0);
        /* a leaf lists each triangle at least once: a 4-byte index or more */
        TEST_ASSERT_TRUE(r->bytes_per_tri >= 4.0);
        for (int s = 0; s < ARBOR_SET_COUNT; s++) {
            TEST_ASSERT_TRUE(r->mrays[s] > 0.0);
            TEST_ASSERT_TRUE(isnan(r->ratio[s])); /* no Embree */
            TEST_ASSERT_TRUE(r->nodes_per_ray[s] > 0.0 && r->tris_per_ray[s] > 0.0);
        }
        /* every hit took a triangle test at least */
        double hits_per_ray = (double)truth / (ARBOR_PROTOCOL_WIDTH * ARBOR_PROTOCOL_HEIGHT);
        TEST_ASSERT_TRUE_MESSAGE(r->tris_per_ray[ARBOR_SET_PRIMARY] >= hits_per_ray, r->builder);
    }
}

/* With Embree, its row comes last and traced the same primary hits as the
 * trees (to AGREE_REL: Embree's test is not the watertight one); each tree
 * row has ratios, and with one tree row they are exactly the tree's Mrays/s
 * over Embree's row's, whose passes were all made beside it. That the
 * passes alternate is not visible in the rows; with two tree rows this
 * checks only that each row's ratios were filled from passes of its own.
 * The run of two trees puts Embree in its robust mode (opts.embree_robust),
 * which its row's builder names as Embree reports it (arbor_embree_mode).
 * Skipped where arbord is built without Embree (make bench-embree). */
static void test_embree_row_and_ratios_to_the_passes_beside_each_tree(void)
{
    if (!arbor_embree_available())
        TEST_IGNORE_MESSAGE("built without Embree");
    for (int trees = 1; trees <= 2; trees++) {
        arbor_bench_opts o;
        arbor_bench_opts_init(&o);
        o.runs = 3;
        o.threads = 2;
        o.embree = true;
        o.embree_robust = trees == 2;
        o.kinds[ARBOR_ACCEL_KD] = false;
        for (int b = 0; b < ARBOR_BUILDER_COUNT; b++)
            o.builders[b] = b == ARBOR_BUILD_SAH || (trees == 2 && b == ARBOR_BUILD_MEDIAN);
        arbor_bench_row rows[3];
        arbor_err e;
        TEST_ASSERT_EQUAL_UINT64((size_t)trees + 1, arbor_bench_row_count(&o));
        TEST_ASSERT_TRUE_MESSAGE(arbor_bench_mesh("cornell4", &mesh, &o, rows, &e), e.msg);
        const arbor_bench_row *peer = &rows[trees];
        TEST_ASSERT_EQUAL_STRING("embree", peer->accel);
        TEST_ASSERT_EQUAL_STRING(o.embree_robust ? "robust" : "default", peer->builder);
        TEST_ASSERT_TRUE(peer->primary_hits > 0);
        TEST_ASSERT_TRUE(peer->build_ms > 0.0 && peer->bytes_per_tri > 0.0 && isnan(peer->render_ms));
        for (int s = 0; s < ARBOR_SET_COUNT; s++) {
            TEST_ASSERT_TRUE(peer->mrays[s] > 0.0 && isnan(peer->ratio[s]));
            for (int t = 0; t < trees; t++) {
                TEST_ASSERT_TRUE(arbor_bench_same_hits(&rows[t], peer));
                TEST_ASSERT_TRUE(rows[t].ratio[s] > 0.0 && isfinite(rows[t].ratio[s]));
            }
            if (trees == 1)
                TEST_ASSERT_EQUAL_DOUBLE(rows[0].mrays[s] / peer->mrays[s], rows[0].ratio[s]);
        }
    }
}

/* At scale 1024 and 1/1024 every tree traces the same primary hits, at
 * distances summing to the unscaled sum times the scale exactly (each
 * distance is scaled exactly, and so is their sum); the caller's mesh is
 * left as it was. */
static void test_a_scaled_mesh_gives_the_same_hits_at_scaled_distances(void)
{
    const float scales[] = {1.0f, 1024.0f, 1.0f / 1024.0f};
    arbor_bench_row rows[3][ARBOR_ACCEL_KIND_COUNT];
    const arbor_vec3 first = mesh.verts[1];
    for (int i = 0; i < 3; i++) {
        progress_log log;
        memset(&log, 0, sizeof log);
        arbor_bench_opts o;
        one_run_opts(&o, &log);
        for (int b = 0; b < ARBOR_BUILDER_COUNT; b++)
            o.builders[b] = b == ARBOR_BUILD_SAH;
        o.scale = scales[i];
        arbor_err e;
        TEST_ASSERT_TRUE_MESSAGE(arbor_bench_mesh("cornell4", &mesh, &o, rows[i], &e), e.msg);
        TEST_ASSERT_TRUE(mesh.verts[1].x == first.x && mesh.verts[1].y == first.y && mesh.verts[1].z == first.z);
    }
    for (int i = 0; i < 3; i++)
        for (int k = 0; k < ARBOR_ACCEL_KIND_COUNT; k++) {
            const arbor_bench_row *r = &rows[i][k];
            TEST_ASSERT_EQUAL_DOUBLE(scales[i], r->scale);
            TEST_ASSERT_TRUE(r->primary_hits > 0);
            TEST_ASSERT_EQUAL_UINT64(rows[0][0].primary_hits, r->primary_hits);
            TEST_ASSERT_TRUE_MESSAGE(r->primary_tsum == rows[0][0].primary_tsum * scales[i], r->accel);
        }
}

static void test_a_cancel_flag_set_before_stops_before_any_row(void)
{
    progress_log log;
    memset(&log, 0, sizeof log);
    arbor_bench_opts o;
    one_run_opts(&o, &log);
    atomic_bool cancel = true;
    o.cancel = &cancel;
    arbor_bench_row rows[ARBOR_ACCEL_KIND_COUNT * ARBOR_BUILDER_COUNT];
    arbor_err e;
    TEST_ASSERT_FALSE(arbor_bench_mesh("cornell4", &mesh, &o, rows, &e));
    TEST_ASSERT_EQUAL_INT(ARBOR_ERR_CANCELLED, e.status);
    TEST_ASSERT_EQUAL_UINT64(0, log.calls);

    arbor_parse_timing t;
    TEST_ASSERT_FALSE(arbor_bench_parse(test_repo_model("cornell.obj"), 1, &cancel, &t, &e));
    TEST_ASSERT_EQUAL_INT(ARBOR_ERR_CANCELLED, e.status);
}

static void test_a_cancel_flag_set_during_the_run_stops_it_between_measurements(void)
{
    atomic_bool cancel = false;
    progress_log log;
    memset(&log, 0, sizeof log);
    log.cancel_after_first = &cancel;
    arbor_bench_opts o;
    one_run_opts(&o, &log);
    o.cancel = &cancel;
    arbor_bench_row rows[ARBOR_ACCEL_KIND_COUNT * ARBOR_BUILDER_COUNT];
    arbor_err e;
    TEST_ASSERT_FALSE(arbor_bench_mesh("cornell4", &mesh, &o, rows, &e));
    TEST_ASSERT_EQUAL_INT(ARBOR_ERR_CANCELLED, e.status);
    TEST_ASSERT_EQUAL_UINT64(1, log.calls);
    TEST_ASSERT_EQUAL_STRING("bvh spatial", log.names[0]);
}

static void test_bad_options_are_refused(void)
{
    arbor_bench_opts o;
    arbor_bench_row rows[ARBOR_ACCEL_KIND_COUNT * ARBOR_BUILDER_COUNT + 1];
    arbor_err e;
    arbor_bench_opts_init(&o);
    o.runs = 0;
    TEST_ASSERT_FALSE(arbor_bench_mesh("m", &mesh, &o, rows, &e));
    TEST_ASSERT_EQUAL_INT(ARBOR_ERR_INVALID, e.status);
    TEST_ASSERT_NOT_NULL(strstr(e.msg, "runs"));

    arbor_bench_opts_init(&o);
    for (int b = 0; b < ARBOR_BUILDER_COUNT; b++)
        o.builders[b] = false;
    TEST_ASSERT_EQUAL_UINT64(0, arbor_bench_row_count(&o));
    TEST_ASSERT_FALSE(arbor_bench_mesh("m", &mesh, &o, rows, &e));
    TEST_ASSERT_EQUAL_INT(ARBOR_ERR_INVALID, e.status);

    /* not powers of two; powers of two that take the mesh where every ray
     * would miss */
    const struct {
        float scale;
        const char *why;
    } bad_scales[] = {{0.0f, "power of two"},   {3.0f, "power of two"},      {-2.0f, "power of two"},
                      {NAN, "power of two"},    {0x1p50f, "single-precision"}, {0x1p-50f, "single-precision"}};
    for (size_t i = 0; i < sizeof bad_scales / sizeof bad_scales[0]; i++) {
        arbor_bench_opts_init(&o);
        o.scale = bad_scales[i].scale;
        TEST_ASSERT_FALSE(arbor_bench_mesh("m", &mesh, &o, rows, &e));
        TEST_ASSERT_EQUAL_INT(ARBOR_ERR_INVALID, e.status);
        TEST_ASSERT_NOT_NULL_MESSAGE(strstr(e.msg, bad_scales[i].why), e.msg);
    }

    arbor_bench_opts_init(&o);
    o.embree = true;
    o.kinds[ARBOR_ACCEL_KD] = false;
    TEST_ASSERT_EQUAL_UINT64(ARBOR_BUILDER_COUNT + 1, arbor_bench_row_count(&o));
    if (!arbor_embree_available()) {
        TEST_ASSERT_FALSE(arbor_bench_mesh("m", &mesh, &o, rows, &e));
        TEST_ASSERT_EQUAL_INT(ARBOR_ERR_INVALID, e.status);
        TEST_ASSERT_NOT_NULL(strstr(e.msg, "make bench-embree"));
    }
}

/* The keys of o, comma-separated, into buf. */
static void keys_of(const cJSON *o, char *buf, size_t size)
{
    size_t n = 0;
    buf[0] = '\0';
    for (const cJSON *item = o->child; item != NULL; item = item->next)
        n += (size_t)snprintf(buf + n, size - n, "%s%s", n ? "," : "", item->string);
}

static void test_json_keys_and_null_for_what_does_not_apply(void)
{
    arbor_bench_row row;
    memset(&row, 0, sizeof row);
    snprintf(row.model, sizeof row.model, "castle.obj");
    row.accel = "embree";
    row.builder = "default";
    row.mean_leaf_depth = row.mean_tris_per_leaf = row.sah_cost = row.render_ms = row.bytes_per_tri = NAN;
    for (int s = 0; s < ARBOR_SET_COUNT; s++) {
        row.mrays[s] = 1.5;
        row.ratio[s] = row.nodes_per_ray[s] = row.tris_per_ray[s] = NAN;
    }
    char keys[768];
    const char *row_keys = "model,scale,triangles,accel,builder,kernel,threads,build_ms,mean_leaf_depth,mean_tris_per_leaf,"
                           "sah_cost,bytes_per_tri,render_ms,primary_mrays,diffuse_mrays,shadow_mrays,primary_hits,primary_tsum,"
                           "primary_nodes_per_ray,primary_tris_per_ray,diffuse_nodes_per_ray,diffuse_tris_per_ray,"
                           "shadow_nodes_per_ray,shadow_tris_per_ray";
    cJSON *o = arbor_report_bench_row(&row, true);
    TEST_ASSERT_NOT_NULL(o);
    keys_of(o, keys, sizeof keys);
    TEST_ASSERT_EQUAL_STRING(row_keys, keys); /* Embree's own row: no ratios */
    TEST_ASSERT_TRUE(cJSON_IsNull(cJSON_GetObjectItem(o, "sah_cost")));
    TEST_ASSERT_TRUE(cJSON_IsNull(cJSON_GetObjectItem(o, "render_ms")));
    TEST_ASSERT_TRUE(cJSON_IsNull(cJSON_GetObjectItem(o, "kernel")));
    TEST_ASSERT_TRUE(cJSON_IsNull(cJSON_GetObjectItem(o, "shadow_tris_per_ray")));
    cJSON_Delete(o);

    row.accel = "bvh";
    row.builder = "sah";
    for (int s = 0; s < ARBOR_SET_COUNT; s++)
        row.ratio[s] = 0.5;
    o = arbor_report_bench_row(&row, true);
    keys_of(o, keys, sizeof keys);
    char with_ratios[900];
    snprintf(with_ratios, sizeof with_ratios, "%s,primary_ratio,diffuse_ratio,shadow_ratio", row_keys);
    TEST_ASSERT_EQUAL_STRING(with_ratios, keys);
    TEST_ASSERT_EQUAL_DOUBLE(0.5, cJSON_GetObjectItem(o, "shadow_ratio")->valuedouble);
    cJSON_Delete(o);
    o = arbor_report_bench_row(&row, false);
    keys_of(o, keys, sizeof keys);
    TEST_ASSERT_EQUAL_STRING(row_keys, keys);
    cJSON_Delete(o);

    arbor_tree_stats s;
    memset(&s, 0, sizeof s);
    s.nodes = 7;
    s.sah_cost = NAN;
    s.bytes = 1000;
    s.binary_bytes = 1000;
    o = arbor_report_tree_stats("m.obj", 12, ARBOR_ACCEL_KD, ARBOR_BUILD_MEAN, &s, ARBOR_LAYOUT_BINARY);
    keys_of(o, keys, sizeof keys);
    TEST_ASSERT_EQUAL_STRING("model,triangles,accel,builder,layout,build_ms,nodes,leaves,empty_leaves,max_depth,"
                             "mean_leaf_depth,mean_tris_per_leaf,refs,bytes,sah_cost",
                             keys);
    TEST_ASSERT_EQUAL_STRING("kd", cJSON_GetObjectItem(o, "accel")->valuestring);
    TEST_ASSERT_EQUAL_STRING("mean", cJSON_GetObjectItem(o, "builder")->valuestring);
    TEST_ASSERT_EQUAL_STRING("binary", cJSON_GetObjectItem(o, "layout")->valuestring);
    TEST_ASSERT_EQUAL_DOUBLE(7.0, cJSON_GetObjectItem(o, "nodes")->valuedouble);
    TEST_ASSERT_EQUAL_DOUBLE(1000.0, cJSON_GetObjectItem(o, "bytes")->valuedouble);
    TEST_ASSERT_TRUE(cJSON_IsNull(cJSON_GetObjectItem(o, "sah_cost")));
    cJSON_Delete(o);
    arbor_layout_stats l;
    TEST_ASSERT_FALSE(arbor_tree_layout_stats(&s, ARBOR_LAYOUT_WIDE, &l));

    /* a tree with a wide layout: its own numbers, and the binary tree's
     * bytes as built (here 600 of the 1000 the tree holds) */
    s.has_wide = true;
    s.binary_bytes = 600;
    s.wide.nodes = 3;
    s.wide.bytes = 400;
    s.wide.sah_cost = 2.5;
    o = arbor_report_tree_stats("m.obj", 12, ARBOR_ACCEL_BVH, ARBOR_BUILD_SAH, &s, ARBOR_LAYOUT_WIDE);
    TEST_ASSERT_EQUAL_STRING("wide", cJSON_GetObjectItem(o, "layout")->valuestring);
    TEST_ASSERT_EQUAL_DOUBLE(3.0, cJSON_GetObjectItem(o, "nodes")->valuedouble);
    TEST_ASSERT_EQUAL_DOUBLE(2.5, cJSON_GetObjectItem(o, "sah_cost")->valuedouble);
    cJSON_Delete(o);
    o = arbor_report_tree_stats("m.obj", 12, ARBOR_ACCEL_BVH, ARBOR_BUILD_SAH, &s, ARBOR_LAYOUT_BINARY);
    TEST_ASSERT_EQUAL_DOUBLE(600.0, cJSON_GetObjectItem(o, "bytes")->valuedouble);
    cJSON_Delete(o);
}

static void test_parse_timing_counts_the_files_bytes_and_triangles(void)
{
    char dir[] = "/tmp/arbor_test_bench_XXXXXX", path[64];
    TEST_ASSERT_NOT_NULL(mkdtemp(dir));
    snprintf(path, sizeof path, "%s/m.obj", dir);
    const char *text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 2 4 3\n";
    FILE *f = fopen(path, "w");
    TEST_ASSERT_NOT_NULL(f);
    TEST_ASSERT_EQUAL_INT((int)strlen(text), (int)fwrite(text, 1, strlen(text), f));
    TEST_ASSERT_EQUAL_INT(0, fclose(f));
    arbor_parse_timing t;
    arbor_err e;
    TEST_ASSERT_TRUE_MESSAGE(arbor_bench_parse(path, 3, NULL, &t, &e), e.msg);
    TEST_ASSERT_EQUAL_UINT64(strlen(text), t.bytes);
    TEST_ASSERT_EQUAL_UINT32(2, t.triangles);
    TEST_ASSERT_TRUE(t.parse_ms >= 0.0);
    cJSON *o = arbor_report_parse_timing("x.obj", &t);
    char keys[128];
    keys_of(o, keys, sizeof keys);
    TEST_ASSERT_EQUAL_STRING("model,bytes,triangles,parse_ms,mb_per_s", keys);
    cJSON_Delete(o);
    unlink(path);
    rmdir(dir);
}

int main(void)
{
    UNITY_BEGIN();
    RUN_TEST(test_every_tree_gets_its_row_and_the_same_hits_as_brute_force);
    RUN_TEST(test_embree_row_and_ratios_to_the_passes_beside_each_tree);
    RUN_TEST(test_a_scaled_mesh_gives_the_same_hits_at_scaled_distances);
    RUN_TEST(test_a_cancel_flag_set_before_stops_before_any_row);
    RUN_TEST(test_a_cancel_flag_set_during_the_run_stops_it_between_measurements);
    RUN_TEST(test_bad_options_are_refused);
    RUN_TEST(test_json_keys_and_null_for_what_does_not_apply);
    RUN_TEST(test_parse_timing_counts_the_files_bytes_and_triangles);
    return UNITY_END();
}
