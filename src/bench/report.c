/*
 * report.c - measurements as JSON objects (see include/arbor/report.h).
 *
 * Each object is built through a small writer that remembers whether any
 * addition failed, so an object is either complete or NULL, never missing
 * a key silently.
 */
#include <assert.h>
#include <math.h>
#include <stdio.h>

#include "arbor/report.h"

typedef struct {
    cJSON *o;
    bool ok;
} json_writer;

static json_writer writer_new(void)
{
    json_writer w = {cJSON_CreateObject(), true};
    w.ok = w.o != NULL;
    return w;
}

/* NULL (not applicable) becomes null. */
static void put_string(json_writer *w, const char *key, const char *v)
{
    if (!w->ok)
        return;
    w->ok = (v == NULL ? cJSON_AddNullToObject(w->o, key) : cJSON_AddStringToObject(w->o, key, v)) != NULL;
}

/* NAN (not applicable) becomes null. */
static void put_number(json_writer *w, const char *key, double v)
{
    if (!w->ok)
        return;
    w->ok = (isnan(v) ? cJSON_AddNullToObject(w->o, key) : cJSON_AddNumberToObject(w->o, key, v)) != NULL;
}

/* The object, or NULL (and nothing leaked) when an addition failed. */
static cJSON *writer_end(json_writer *w)
{
    if (w->ok)
        return w->o;
    cJSON_Delete(w->o);
    return NULL;
}

cJSON *arbor_report_tree_stats(const char *model, uint32_t triangles, arbor_accel_kind kind, arbor_builder builder,
                               const arbor_tree_stats *s, arbor_layout layout)
{
    arbor_layout_stats l;
    bool has = arbor_tree_layout_stats(s, layout, &l);
    assert(has && "the layout is one the tree has");
    (void)has;
    json_writer w = writer_new();
    put_string(&w, "model", model);
    put_number(&w, "triangles", triangles);
    put_string(&w, "accel", arbor_accel_kind_name(kind));
    put_string(&w, "builder", arbor_builder_name(builder));
    put_string(&w, "layout", arbor_layout_name(layout));
    put_number(&w, "build_ms", s->build_ms);
    put_number(&w, "nodes", (double)l.nodes);
    put_number(&w, "leaves", (double)l.leaves);
    put_number(&w, "empty_leaves", (double)l.empty_leaves);
    put_number(&w, "max_depth", l.max_depth);
    put_number(&w, "mean_leaf_depth", l.mean_leaf_depth);
    put_number(&w, "mean_tris_per_leaf", l.mean_tris_per_leaf);
    put_number(&w, "refs", (double)l.refs);
    put_number(&w, "bytes", (double)l.bytes);
    put_number(&w, "sah_cost", l.sah_cost);
    return writer_end(&w);
}

cJSON *arbor_report_bench_row(const arbor_bench_row *r, bool with_ratios)
{
    json_writer w = writer_new();
    put_string(&w, "model", r->model);
    put_number(&w, "scale", r->scale);
    put_number(&w, "triangles", r->triangles);
    put_string(&w, "accel", r->accel);
    put_string(&w, "builder", r->builder);
    put_string(&w, "kernel", r->kernel);
    put_number(&w, "threads", r->threads);
    put_number(&w, "build_ms", r->build_ms);
    put_number(&w, "mean_leaf_depth", r->mean_leaf_depth);
    put_number(&w, "mean_tris_per_leaf", r->mean_tris_per_leaf);
    put_number(&w, "sah_cost", r->sah_cost);
    put_number(&w, "bytes_per_tri", r->bytes_per_tri);
    put_number(&w, "render_ms", r->render_ms);
    for (int s = 0; s < ARBOR_SET_COUNT; s++) {
        char key[32];
        snprintf(key, sizeof key, "%s_mrays", arbor_ray_set_name((arbor_ray_set)s));
        put_number(&w, key, r->mrays[s]);
    }
    put_number(&w, "primary_hits", (double)r->primary_hits);
    put_number(&w, "primary_tsum", r->primary_tsum);
    for (int s = 0; s < ARBOR_SET_COUNT; s++) {
        char key[48];
        snprintf(key, sizeof key, "%s_nodes_per_ray", arbor_ray_set_name((arbor_ray_set)s));
        put_number(&w, key, r->nodes_per_ray[s]);
        snprintf(key, sizeof key, "%s_tris_per_ray", arbor_ray_set_name((arbor_ray_set)s));
        put_number(&w, key, r->tris_per_ray[s]);
    }
    for (int s = 0; with_ratios && s < ARBOR_SET_COUNT; s++) {
        if (isnan(r->ratio[s]))
            continue; /* the Embree row itself */
        char key[32];
        snprintf(key, sizeof key, "%s_ratio", arbor_ray_set_name((arbor_ray_set)s));
        put_number(&w, key, r->ratio[s]);
    }
    return writer_end(&w);
}

cJSON *arbor_report_parse_timing(const char *model, const arbor_parse_timing *t)
{
    json_writer w = writer_new();
    put_string(&w, "model", model);
    put_number(&w, "bytes", (double)t->bytes);
    put_number(&w, "triangles", t->triangles);
    put_number(&w, "parse_ms", t->parse_ms);
    put_number(&w, "mb_per_s", t->mb_per_s);
    return writer_end(&w);
}
