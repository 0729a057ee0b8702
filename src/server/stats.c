/*
 * stats.c - what the daemon reports about its models and trees: the MODEL
 * object of /api/models, /api/stats, and tree builds asked for over
 * POST /api/models/{name}/trees. Tree statistics are encoded by report.c,
 * the same code `arbord stats --json` prints with.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "arbor/embree_peer.h"
#include "arbor/report.h"
#include "arbor/sys.h"
#include "http.h"

bool parse_tree_names(http_req *r, const char *accel, const char *builder, arbor_accel_kind *k, arbor_builder *b)
{
    if (!arbor_accel_kind_parse(accel, k)) {
        http_reply_error(r, 400, "bad_request", "unknown accel '%s' (" ARBOR_ACCEL_KIND_NAMES ")", accel);
        return false;
    }
    if (!arbor_builder_parse(builder, b)) {
        http_reply_error(r, 400, "bad_request", "unknown builder '%s' (" ARBOR_BUILDER_NAMES ")", builder);
        return false;
    }
    return true;
}

static cJSON *vec3_json(arbor_vec3 v)
{
    const float f[3] = {v.x, v.y, v.z};
    return cJSON_CreateFloatArray(f, 3);
}

static cJSON *tree_json(arbor_server *s, arbor_model *m, arbor_accel_kind k, arbor_builder b)
{
    arbor_tree_info info;
    arbor_model_tree_info(s->store, m, k, b, &info);
    cJSON *t = cJSON_CreateObject();
    cJSON_AddStringToObject(t, "accel", arbor_accel_kind_name(k));
    cJSON_AddStringToObject(t, "builder", arbor_builder_name(b));
    cJSON_AddStringToObject(t, "state", arbor_tree_state_name(info.state));
    bool ready = info.state == ARBOR_TREE_READY;
    json_put(t, "build_ms", ready ? cJSON_CreateNumber(info.stats.build_ms) : cJSON_CreateNull());
    json_put(t, "bytes", ready ? cJSON_CreateNumber((double)info.stats.bytes) : cJSON_CreateNull());
    if (info.state == ARBOR_TREE_FAILED)
        cJSON_AddStringToObject(t, "error", info.error);
    return t;
}

cJSON *model_json(arbor_server *s, arbor_model *m)
{
    const arbor_mesh *mesh = arbor_model_mesh(m);
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "name", arbor_model_name(m));
    cJSON_AddStringToObject(o, "file", arbor_model_file(m));
    cJSON_AddNumberToObject(o, "triangles", mesh->ntris);
    cJSON_AddNumberToObject(o, "vertices", mesh->nverts);
    cJSON *bounds = cJSON_AddObjectToObject(o, "bounds");
    json_put(bounds, "min", vec3_json(mesh->bounds.lo));
    json_put(bounds, "max", vec3_json(mesh->bounds.hi));
    cJSON *mats = cJSON_AddArrayToObject(o, "materials");
    for (uint32_t i = 0; i < mesh->nmats; i++)
        json_push(mats, cJSON_CreateString(mesh->mats[i].name));
    cJSON *warnings = cJSON_AddArrayToObject(o, "warnings");
    for (uint32_t i = 0; i < mesh->nwarnings; i++)
        json_push(warnings, cJSON_CreateString(mesh->warnings[i]));
    cJSON_AddNumberToObject(o, "bytes", (double)arbor_model_bytes(m));
    cJSON_AddNumberToObject(o, "version", (double)arbor_model_version(m));
    cJSON *trees = cJSON_AddArrayToObject(o, "trees");
    for (int k = 0; k < ARBOR_ACCEL_KIND_COUNT; k++)
        for (int b = 0; b < ARBOR_BUILDER_COUNT; b++)
            json_push(trees, tree_json(s, m, (arbor_accel_kind)k, (arbor_builder)b));
    return o;
}

/* A tree's statistics: its binary tree's (the study's measures), and the
 * bvh's wide tree, which its rays traverse, as the object "wide". */
static cJSON *stats_json(arbor_model *m, arbor_accel_kind k, arbor_builder b, const arbor_tree_stats *st)
{
    const char *name = arbor_model_name(m);
    uint32_t ntris = arbor_model_mesh(m)->ntris;
    cJSON *o = arbor_report_tree_stats(name, ntris, k, b, st, ARBOR_LAYOUT_BINARY);
    if (o != NULL && st->has_wide)
        json_put(o, "wide", arbor_report_tree_stats(name, ntris, k, b, st, ARBOR_LAYOUT_WIDE));
    return o;
}

/* ---- waiting for a tree ---- */

typedef struct {
    http_req *http;
    arbor_accel_kind kind;
    arbor_builder builder;
    bool with_daemon;   /* answer as /api/stats does, else the tree's statistics alone */
} tree_wait;

static cJSON *daemon_json(arbor_server *s);

static void reply_tree(http_req *r, arbor_tree *tree, const tree_wait *w)
{
    arbor_tree_stats st;
    arbor_accel_stats(arbor_tree_accel(tree), &st);
    cJSON *stats = stats_json(arbor_tree_model(tree), w->kind, w->builder, &st);
    if (!w->with_daemon) {
        http_reply_json(r, 200, stats);
        return;
    }
    cJSON *o = cJSON_CreateObject();
    json_put(o, "daemon", daemon_json(r->srv));
    json_push(cJSON_AddArrayToObject(o, "trees"), stats);
    http_reply_json(r, 200, o);
}

static void on_tree(void *user, arbor_tree *tree, const arbor_err *e)
{
    tree_wait *w = user;
    if (tree != NULL)
        reply_tree(w->http, tree, w);
    else
        http_reply_err(w->http, e);
    arbor_tree_release(tree);
    http_resume(w->http);
    free(w);
}

/* Answers with the tree's statistics once it is built (suspending while it
 * builds), or, with wait false, 202 and its state at once. */
static void answer_tree(http_req *r, arbor_model *m, arbor_accel_kind k, arbor_builder b, bool wait,
                        bool with_daemon)
{
    tree_wait *w = calloc(1, sizeof *w);
    if (w == NULL) {
        http_reply_error(r, 507, "insufficient_memory", "out of memory");
        return;
    }
    *w = (tree_wait){r, k, b, with_daemon};
    arbor_tree *tree = NULL;
    arbor_err err;
    arbor_err_clear(&err);
    if (wait)
        http_suspend(r);
    arbor_acquire got = arbor_store_acquire_tree(r->srv->store, m, k, b, &tree, wait ? on_tree : NULL, w, &err);
    if (got == ARBOR_ACQUIRE_PENDING && wait)
        return;
    if (got == ARBOR_ACQUIRE_READY) {
        reply_tree(r, tree, w);
        arbor_tree_release(tree);
    } else if (got == ARBOR_ACQUIRE_FAILED) {
        http_reply_err(r, &err);
    } else {
        cJSON *o = cJSON_CreateObject();
        cJSON_AddStringToObject(o, "model", arbor_model_name(m));
        cJSON_AddStringToObject(o, "accel", arbor_accel_kind_name(k));
        cJSON_AddStringToObject(o, "builder", arbor_builder_name(b));
        cJSON_AddStringToObject(o, "state", "building");
        http_reply_json(r, 202, o);
    }
    free(w);
    if (wait)
        http_resume(r);
}

void route_tree_build(http_req *r, arbor_model *m)
{
    if (!http_method_is(r, "POST")) {
        http_method_not_allowed(r, "POST");
        return;
    }
    if (!http_may_write(r))
        return;
    cJSON *body = http_body_json(r);
    if (body == NULL)
        return;
    const char *accel = "bvh", *builder = "sah";
    bool wait = true, ok = true;
    for (const cJSON *v = body->child; v != NULL && ok; v = v->next) {
        if (strcmp(v->string, "accel") == 0 || strcmp(v->string, "builder") == 0) {
            ok = cJSON_IsString(v);
            if (!ok)
                http_reply_error(r, 400, "bad_request", "%s must be a string", v->string);
            else if (strcmp(v->string, "accel") == 0)
                accel = v->valuestring;
            else
                builder = v->valuestring;
        } else if (strcmp(v->string, "wait") == 0) {
            ok = cJSON_IsBool(v);
            if (!ok)
                http_reply_error(r, 400, "bad_request", "wait must be true or false");
            wait = cJSON_IsTrue(v);
        } else {
            ok = false;
            http_reply_error(r, 400, "bad_request", "unknown field '%s' (accel, builder, wait)", v->string);
        }
    }
    arbor_accel_kind k;
    arbor_builder b;
    if (ok && parse_tree_names(r, accel, builder, &k, &b))
        answer_tree(r, m, k, b, wait, false);
    cJSON_Delete(body);
}

/* ---- /api/stats ---- */

static uint64_t rss_bytes(void)
{
    FILE *f = fopen("/proc/self/statm", "r");
    unsigned long long pages = 0, resident = 0;
    if (f != NULL) {
        if (fscanf(f, "%llu %llu", &pages, &resident) != 2)
            resident = 0;
        fclose(f);
    }
    return resident * (uint64_t)sysconf(_SC_PAGESIZE);
}

static cJSON *daemon_json(arbor_server *s)
{
    uint64_t frames, rays;
    double mean_ms, p99_ms;
    metrics_frame_summary(&s->metrics, &frames, &rays, &mean_ms, &p99_ms);
    uint32_t waiting, rendering;
    pthread_mutex_lock(&s->lock);
    frames_count(s, &waiting, &rendering);
    pthread_mutex_unlock(&s->lock);
    arbor_store_usage u;
    arbor_store_usage_of(s->store, &u);

    cJSON *d = cJSON_CreateObject();
    cJSON_AddNumberToObject(d, "uptime_s", (arbor_now_ms() - s->start_ms) / 1e3);
    cJSON_AddNumberToObject(d, "frames", (double)frames);
    cJSON_AddNumberToObject(d, "rays", (double)rays);
    cJSON_AddNumberToObject(d, "frame_ms_mean", mean_ms);
    cJSON_AddNumberToObject(d, "frame_ms_p99", p99_ms);
    cJSON *q = cJSON_AddObjectToObject(d, "queue");
    cJSON_AddNumberToObject(q, "waiting", waiting);
    cJSON_AddNumberToObject(q, "rendering", rendering);
    cJSON_AddNumberToObject(q, "limit", s->config.queue);
    /* frames rendered at once (one per worker): a client splitting a frame
     * gains nothing by asking for more strips at a time */
    cJSON_AddNumberToObject(q, "threads", s->config.threads);
    cJSON *mem = cJSON_AddObjectToObject(d, "memory");
    cJSON_AddNumberToObject(mem, "models", (double)u.models);
    cJSON_AddNumberToObject(mem, "trees", (double)u.trees);
    cJSON_AddNumberToObject(mem, "building", (double)u.reserved);
    cJSON_AddNumberToObject(mem, "benchmarks", (double)u.held); /* the running bench job's reckoning */
    cJSON_AddNumberToObject(mem, "limit", (double)u.limit);
    cJSON_AddNumberToObject(mem, "rss", (double)rss_bytes());
    /* what one request may ask, so that a client (the viewer) splits its
     * frames by them rather than by a refusal's words */
    cJSON *lim = cJSON_AddObjectToObject(d, "limits");
    cJSON_AddNumberToObject(lim, "max_pixels", (double)s->config.max_pixels);
    cJSON_AddNumberToObject(lim, "max_body", (double)s->config.max_body);
    cJSON_AddNumberToObject(lim, "max_upload", (double)s->config.max_upload);
    /* whether a bench job may ask for Embree beside the trees */
    cJSON_AddBoolToObject(d, "embree", arbor_embree_available());
    return d;
}

static void add_ready_trees(arbor_server *s, arbor_model *m, cJSON *trees)
{
    for (int k = 0; k < ARBOR_ACCEL_KIND_COUNT; k++)
        for (int b = 0; b < ARBOR_BUILDER_COUNT; b++) {
            arbor_tree_info info;
            arbor_model_tree_info(s->store, m, (arbor_accel_kind)k, (arbor_builder)b, &info);
            if (info.state == ARBOR_TREE_READY)
                json_push(trees, stats_json(m, (arbor_accel_kind)k, (arbor_builder)b, &info.stats));
        }
}

void route_stats(http_req *r)
{
    arbor_server *s = r->srv;
    if (!http_args_known(r, "model, accel, builder"))
        return;
    const char *model = http_arg(r, "model"), *accel = http_arg(r, "accel"), *builder = http_arg(r, "builder");
    arbor_model *one = NULL;
    if (model != NULL && (one = sync_model(r, model)) == NULL)
        return;
    if (accel != NULL || builder != NULL) {
        arbor_accel_kind k;
        arbor_builder b;
        if (one == NULL)
            http_reply_error(r, 400, "bad_request", "accel and builder narrow to one model's tree: give model too");
        else if (parse_tree_names(r, accel ? accel : "bvh", builder ? builder : "sah", &k, &b))
            answer_tree(r, one, k, b, true, true);
        arbor_model_release(one);
        return;
    }
    arbor_model **models = NULL;
    uint32_t n = 0;
    arbor_err e;
    if (one == NULL && !arbor_store_list_models(s->store, &models, &n, &e)) {
        http_reply_err(r, &e);
        return;
    }
    cJSON *o = cJSON_CreateObject();
    json_put(o, "daemon", daemon_json(s));
    cJSON *trees = cJSON_AddArrayToObject(o, "trees");
    if (one != NULL) {
        add_ready_trees(s, one, trees);
        arbor_model_release(one);
    } else {
        for (uint32_t i = 0; i < n; i++) {
            add_ready_trees(s, models[i], trees);
            arbor_model_release(models[i]);
        }
        free(models);
    }
    http_reply_json(r, 200, o);
}
