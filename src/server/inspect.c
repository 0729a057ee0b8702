/*
 * inspect.c - seeing inside a tree: its boxes down to a depth
 * (GET /api/models/{name}/trees/{accel}/{builder}/boxes) and one primary
 * ray's path through it (POST /api/ray), both from the accel layer's walk
 * and traced traversal, so what the viewer draws is what the tracer does.
 *
 * Both need a built tree; one that is absent is built first, the request
 * suspended meanwhile, as a frame's is.
 */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "http.h"

#define BOXES_MAX 20000
#define RAY_STEPS_MAX 100000

typedef enum { INSPECT_BOXES, INSPECT_RAY } inspect_kind;

typedef struct {
    http_req *http;
    inspect_kind kind;
    /* boxes */
    uint32_t depth;
    bool leaves_only, all_levels;
    /* ray */
    render_spec spec;
    arbor_render_params params;
    arbor_tree *ready; /* the tree, when it was ready at once (ready_run) */
} inspect_req;

static cJSON *box_json(arbor_aabb b)
{
    const float lo[3] = {b.lo.x, b.lo.y, b.lo.z}, hi[3] = {b.hi.x, b.hi.y, b.hi.z};
    cJSON *o = cJSON_CreateObject();
    json_put(o, "min", cJSON_CreateFloatArray(lo, 3));
    json_put(o, "max", cJSON_CreateFloatArray(hi, 3));
    return o;
}

static cJSON *vec_json(arbor_vec3 v)
{
    const float f[3] = {v.x, v.y, v.z};
    return cJSON_CreateFloatArray(f, 3);
}

/* A node as JSON: a box of the overlay is {min, max, depth, leaf, tris}; a
 * step of a ray's path nests its box and adds the tests made there. */
static cJSON *node_json(const arbor_node_info *n, bool step)
{
    cJSON *o = step ? cJSON_CreateObject() : box_json(n->box);
    if (step)
        json_put(o, "box", box_json(n->box));
    cJSON_AddNumberToObject(o, "depth", n->depth);
    cJSON_AddBoolToObject(o, "leaf", n->leaf);
    if (step)
        cJSON_AddNumberToObject(o, "tests", n->tests);
    cJSON_AddNumberToObject(o, "tris", n->tris);
    return o;
}

/* ---- boxes ---- */

/* A walk over the nodes the request wants: the first counts them (boxes
 * NULL), the second sends them, or past BOXES_MAX an even sample of them
 * in tree order, so that the boxes drawn cover the whole tree rather than
 * the corner its first BOXES_MAX nodes fill. */
typedef struct {
    const inspect_req *q;
    cJSON *boxes;
    uint64_t total;   /* what the first walk counted */
    uint64_t seen;
} box_walk;

static bool on_node(void *user, const arbor_node_info *n)
{
    box_walk *w = user;
    const inspect_req *q = w->q;
    bool want = q->leaves_only ? n->leaf && n->depth <= q->depth
                               : q->all_levels ? n->depth <= q->depth : n->depth == q->depth;
    if (!want)
        return true;
    uint64_t i = w->seen++;
    /* floor(i * BOXES_MAX / total) steps up BOXES_MAX times as i goes
     * from 0 to total, at every i when total is at most BOXES_MAX */
    if (w->boxes != NULL && (i + 1) * BOXES_MAX / w->total != i * BOXES_MAX / w->total)
        json_push(w->boxes, node_json(n, false));
    return true;
}

static void answer_boxes(const inspect_req *q, const arbor_accel *a)
{
    box_walk w = {q, NULL, 0, 0};
    arbor_accel_walk(a, q->depth, on_node, &w);
    w.total = w.seen;
    w.seen = 0;
    w.boxes = cJSON_CreateArray();
    arbor_accel_walk(a, q->depth, on_node, &w);
    cJSON *o = cJSON_CreateObject();
    cJSON_AddNumberToObject(o, "depth", q->depth);
    cJSON_AddNumberToObject(o, "count", (double)w.total);
    cJSON_AddBoolToObject(o, "truncated", w.total > BOXES_MAX);
    cJSON_AddNumberToObject(o, "max_boxes", BOXES_MAX);
    json_put(o, "boxes", w.boxes);
    http_reply_json(q->http, 200, o);
}

/* ---- a ray's path ---- */

typedef struct {
    cJSON *steps;
    uint32_t count;
    bool truncated;
} ray_walk;

static bool on_step(void *user, const arbor_node_info *n)
{
    ray_walk *w = user;
    if (w->count == RAY_STEPS_MAX) {
        w->truncated = true;
        return true; /* keep tracing: the counts must stay whole */
    }
    json_push(w->steps, node_json(n, true));
    w->count++;
    return true;
}

static void answer_ray(const inspect_req *q, const arbor_accel *a)
{
    const arbor_camera *c = &q->params.camera;
    arbor_ray ray = arbor_camera_ray(c, (float)q->spec.x + 0.5f, (float)q->spec.y + 0.5f);
    arbor_ray traced = ray;
    arbor_hit hit;
    arbor_trace_counts counts = {0, 0};
    ray_walk w = {cJSON_CreateArray(), 0, false};
    bool found = arbor_accel_intersect_traced(a, &traced, &hit, &counts, on_step, &w);

    cJSON *o = cJSON_CreateObject();
    cJSON *r = cJSON_AddObjectToObject(o, "ray");
    json_put(r, "origin", vec_json(ray.o));
    json_put(r, "dir", vec_json(ray.d));
    cJSON_AddNumberToObject(o, "x", q->spec.x);
    cJSON_AddNumberToObject(o, "y", q->spec.y);
    if (found) {
        cJSON *h = cJSON_AddObjectToObject(o, "hit");
        cJSON_AddNumberToObject(h, "t", hit.t);
        cJSON_AddNumberToObject(h, "triangle", hit.tri);
        json_put(h, "point", vec_json(vec3_add(ray.o, vec3_scale(ray.d, hit.t))));
        const arbor_mesh *m = arbor_accel_mesh(a);
        json_put(h, "normal", vec_json(vec3_normalize(arbor_mesh_tri_normal(m, hit.tri))));
    } else {
        cJSON_AddNullToObject(o, "hit");
    }
    cJSON *cnt = cJSON_AddObjectToObject(o, "counts");
    cJSON_AddNumberToObject(cnt, "nodes", (double)counts.nodes);
    cJSON_AddNumberToObject(cnt, "tris", (double)counts.tris);
    cJSON_AddBoolToObject(o, "truncated", w.truncated);
    json_put(o, "steps", w.steps);
    http_reply_json(q->http, 200, o);
}

/* ---- both: a tree, then the answer ---- */

static void answer(inspect_req *q, arbor_tree *tree)
{
    if (q->kind == INSPECT_BOXES)
        answer_boxes(q, arbor_tree_accel(tree));
    else
        answer_ray(q, arbor_tree_accel(tree));
}

static void on_tree(void *user, arbor_tree *tree, const arbor_err *e)
{
    inspect_req *q = user;
    if (tree != NULL)
        answer(q, tree);
    else
        http_reply_err(q->http, e);
    arbor_tree_release(tree);
    http_resume(q->http);
    free(q);
}

/* The answer with a tree that was ready, on a worker: the box walk may
 * visit every node of a large tree. */
static void ready_run(void *ctx, uint32_t task)
{
    (void)task;
    inspect_req *q = ctx;
    answer(q, q->ready);
    /* The tree goes before the connection resumes: the last resume lets
     * shutdown destroy the store, which expects no tree held. */
    arbor_tree_release(q->ready);
    q->ready = NULL;
    http_resume(q->http);
}

static void ready_free(void *ctx)
{
    inspect_req *q = ctx;
    arbor_tree_release(q->ready);
    free(q);
}

/* Answers q with the tree, now or once built. Takes q. */
static void with_tree(inspect_req *q, arbor_model *m, arbor_accel_kind k, arbor_builder b)
{
    http_req *r = q->http;
    arbor_tree *tree = NULL;
    arbor_err err;
    arbor_err_clear(&err);
    http_suspend(r);
    arbor_acquire got = arbor_store_acquire_tree(r->srv->store, m, k, b, &tree, on_tree, q, &err);
    if (got == ARBOR_ACQUIRE_PENDING)
        return;
    if (got == ARBOR_ACQUIRE_READY) {
        q->ready = tree;
        http_queue(r, ready_run, ready_free, q);
        return;
    }
    http_reply_err(r, &err);
    free(q);
    http_resume(r);
}

void route_boxes(http_req *r, arbor_model *m, const char *accel, const char *builder)
{
    if (!http_method_is(r, "GET") && !http_method_is(r, "HEAD")) {
        http_method_not_allowed(r, "GET, HEAD");
        return;
    }
    arbor_accel_kind k;
    arbor_builder b;
    if (!parse_tree_names(r, accel, builder, &k, &b) || !http_args_known(r, "depth, leaves, all"))
        return;
    bool ok = true;
    bool leaves_only = http_arg_flag(r, "leaves", &ok);
    bool all_levels = ok && http_arg_flag(r, "all", &ok);
    if (!ok)
        return;
    const char *d = http_arg(r, "depth");
    char *end = NULL;
    errno = 0;
    long depth = d != NULL ? strtol(d, &end, 10) : 0;
    if (d != NULL && (end == d || *end != '\0' || errno != 0 || depth < 0 || depth > 255)) {
        http_reply_error(r, 400, "bad_request", "depth must be a whole number in 0..255, not '%s'", d);
        return;
    }
    inspect_req *q = calloc(1, sizeof *q);
    if (q == NULL) {
        http_reply_error(r, 507, "insufficient_memory", "out of memory");
        return;
    }
    q->http = r;
    q->kind = INSPECT_BOXES;
    q->depth = (uint32_t)depth;
    q->leaves_only = leaves_only;
    q->all_levels = all_levels;
    with_tree(q, m, k, b);
}

void route_ray(http_req *r)
{
    inspect_req *q = calloc(1, sizeof *q);
    if (q == NULL) {
        http_reply_error(r, 507, "insufficient_memory", "out of memory");
        return;
    }
    q->http = r;
    q->kind = INSPECT_RAY;
    arbor_model *m = NULL;
    if (!render_read_request(r, true, &q->spec, &q->params, &m)) {
        free(q);
        return;
    }
    with_tree(q, m, q->spec.kind, q->spec.builder);
    arbor_model_release(m);
}
