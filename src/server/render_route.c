/*
 * render_route.c - /api/render: admission, stream keys, the frame's life
 * from tree to PNG, the frame-timeout reaper and shutdown's cancellation.
 *
 * A frame admitted is on the server's list (s->frames, under s->lock) until
 * it is answered; the list's length is what admission compares with
 * threads + queue. Its request is suspended. The frame first needs its tree:
 * ready at once, or after a build, whose callback arrives on a pool worker.
 * Then it renders on the pool, and frame_done (a worker) encodes the PNG,
 * replies and resumes.
 *
 * Cancellation (a newer frame of the same stream, the timeout, shutdown)
 * happens under s->lock: a rendering frame is cancelled in the pool and
 * frame_done answers it; a frame still waiting for its tree is answered at
 * once, and the build's later callback only lets go of the tree. Each
 * render_req is answered exactly once: `answered` is set under the lock by
 * whoever answers.
 */
#include <assert.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>

#include "arbor/png.h"
#include "arbor/sys.h"
#include "http.h"
#include "render_request.h"

typedef enum { RR_WAITING_TREE, RR_RENDERING } rr_state;

struct render_req {
    arbor_server *srv;
    http_req *http;               /* a reference, while suspended */
    render_spec spec;
    arbor_render_params params;
    arbor_model *model;
    arbor_tree *tree;
    arbor_frame *frame;
    atomic_int refs;              /* the answer path, route_render while it runs, a pending build's callback */
    double admitted_ms, tree_ms, submitted_ms;
    int fd;                       /* the client's socket, open while rr is suspended; -1: unknown */
    /* protected by srv->lock */
    rr_state state;
    bool answered;
    bool cancelled;
    cancel_reason reason;
    render_req *prev, *next;
};

static void rr_release(render_req *rr)
{
    if (atomic_fetch_sub(&rr->refs, 1) != 1)
        return;
    arbor_tree_release(rr->tree);
    arbor_model_release(rr->model);
    if (rr->frame != NULL)
        arbor_frame_release(rr->frame);
    free(rr);
}

/* ---- the list (lock held) ---- */

static void list_add(arbor_server *s, render_req *rr)
{
    rr->prev = NULL;
    rr->next = s->frames;
    if (s->frames != NULL)
        s->frames->prev = rr;
    s->frames = rr;
    s->nframes++;
}

static void list_remove(arbor_server *s, render_req *rr)
{
    if (rr->prev != NULL)
        rr->prev->next = rr->next;
    else
        s->frames = rr->next;
    if (rr->next != NULL)
        rr->next->prev = rr->prev;
    rr->prev = rr->next = NULL;
    s->nframes--;
}

/* The pool shares its workers among every frame submitted, so "rendering"
 * is as many of them as there are workers, and the rest wait: the same
 * count admission uses (threads + queue). */
void frames_count(arbor_server *s, uint32_t *waiting, uint32_t *rendering)
{
    uint32_t submitted = 0;
    for (render_req *rr = s->frames; rr != NULL; rr = rr->next)
        submitted += rr->state == RR_RENDERING;
    *rendering = submitted < (uint32_t)s->config.threads ? submitted : (uint32_t)s->config.threads;
    *waiting = s->nframes - *rendering;
}

/* ---- answering ---- */

static void reply_cancelled(render_req *rr)
{
    http_req *r = rr->http;
    switch (rr->reason) {
    case CANCEL_SUPERSEDED:
        http_reply_error(r, 409, "superseded", "frame cancelled: a newer frame of stream '%s' replaced it",
                         rr->spec.stream);
        break;
    case CANCEL_TIMEOUT:
        http_reply_error(r, 503, "timeout", "frame cancelled after %g s (--frame-timeout)",
                         rr->srv->config.frame_timeout_s);
        break;
    case CANCEL_CLIENT_GONE: /* for the access log: no one reads it */
        http_reply_error(r, 503, "client_gone", "frame cancelled: the client closed its connection");
        break;
    default: http_reply_error(r, 503, "busy", "frame cancelled: the daemon is shutting down"); break;
    }
    metrics_frame_cancelled(&rr->srv->metrics, rr->reason);
}

/* Hands the answer back to the polling thread and lets go. The caller has
 * set `answered` and taken rr off the list. */
static void rr_finish(render_req *rr)
{
    /* The model and tree go before the connection is resumed: once every
     * connection is resumed, shutdown destroys the store, which must find
     * no reference left. */
    pthread_mutex_lock(&rr->srv->lock);
    arbor_tree *tree = rr->tree;
    arbor_model *model = rr->model;
    rr->tree = NULL;
    rr->model = NULL;
    pthread_mutex_unlock(&rr->srv->lock);
    arbor_tree_release(tree);
    arbor_model_release(model);
    http_resume(rr->http);
    rr->http = NULL;
    rr_release(rr);
}

/* Claims the right to answer rr: false when someone already has. */
static bool rr_claim(render_req *rr)
{
    arbor_server *s = rr->srv;
    pthread_mutex_lock(&s->lock);
    bool mine = !rr->answered;
    if (mine) {
        rr->answered = true;
        list_remove(s, rr);
    }
    pthread_mutex_unlock(&s->lock);
    return mine;
}

static void reply_frame_json(render_req *rr, const arbor_frame_result *res, double queue_ms)
{
    const render_spec *sp = &rr->spec;
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "model", sp->model);
    cJSON_AddStringToObject(o, "accel", arbor_accel_kind_name(sp->kind));
    cJSON_AddStringToObject(o, "builder", arbor_builder_name(sp->builder));
    cJSON_AddStringToObject(o, "mode", arbor_render_mode_name(sp->mode));
    cJSON_AddNumberToObject(o, "width", res->width);
    cJSON_AddNumberToObject(o, "height", res->height);
    cJSON_AddNumberToObject(o, "spp", sp->spp);
    cJSON_AddNumberToObject(o, "render_ms", res->render_ms);
    cJSON_AddNumberToObject(o, "rays", (double)res->rays);
    cJSON_AddNumberToObject(o, "mrays_per_s", res->mrays_per_s);
    cJSON_AddNumberToObject(o, "queue_ms", queue_ms);
    cJSON_AddNumberToObject(o, "build_ms", rr->tree_ms - rr->admitted_ms);
    bool heat = sp->mode == ARBOR_MODE_HEAT;
    json_put(o, "heat_scale", heat ? cJSON_CreateNumber(res->heat_scale) : cJSON_CreateNull());
    json_put(o, "heat_max", heat ? cJSON_CreateNumber(res->heat_max) : cJSON_CreateNull());
    json_put(o, "heat_mean", heat ? cJSON_CreateNumber(res->heat_mean) : cJSON_CreateNull());
    json_put(o, "mean_nodes", res->counted ? cJSON_CreateNumber(res->mean_nodes) : cJSON_CreateNull());
    json_put(o, "mean_tris", res->counted ? cJSON_CreateNumber(res->mean_tris) : cJSON_CreateNull());
    http_reply_json(rr->http, 200, o);
}

/* Heat mode's costs as the bytes of little-endian float32s, whatever the
 * host's byte order: a browser reads them with a DataView. */
static void reply_frame_costs(render_req *rr, const arbor_frame_result *res)
{
    const float *costs = arbor_frame_heat_costs(rr->frame);
    assert(costs != NULL); /* format costs is refused outside heat mode */
    size_t n = (size_t)res->width * (size_t)res->height;
    uint8_t *bytes = malloc(n * 4);
    if (bytes == NULL) {
        arbor_err err;
        arbor_fail(&err, ARBOR_ERR_NOMEM, "out of memory for the %zu costs of a %dx%d frame", n, res->width,
                   res->height);
        http_reply_err(rr->http, &err);
        return;
    }
    for (size_t i = 0; i < n; i++) {
        uint32_t u;
        memcpy(&u, &costs[i], sizeof u);
        for (int b = 0; b < 4; b++)
            bytes[4 * i + (size_t)b] = (uint8_t)(u >> (8 * b));
    }
    http_reply_buffer(rr->http, 200, "application/octet-stream", bytes, n * 4);
    http_reply_header(rr->http, "Cache-Control", "no-store");
}

static void add_number_header(http_req *r, const char *name, const char *fmt, double v)
{
    char text[64];
    snprintf(text, sizeof text, fmt, v);
    http_reply_header(r, name, text);
}

static void reply_frame(render_req *rr, const arbor_frame_result *res)
{
    http_req *r = rr->http;
    double done_ms = arbor_now_ms();
    double queue_ms = done_ms - rr->submitted_ms - res->render_ms;
    double encode_ms = 0.0;
    if (queue_ms < 0.0)
        queue_ms = 0.0;
    if (rr->spec.format == RENDER_JSON) {
        reply_frame_json(rr, res, queue_ms);
    } else if (rr->spec.format == RENDER_COSTS) {
        reply_frame_costs(rr, res);
    } else {
        uint8_t *png = NULL;
        size_t len = 0;
        arbor_err err;
        if (!arbor_png_encode(res->rgb, res->width, res->height, &png, &len, &err)) {
            http_reply_err(r, &err);
            return;
        }
        encode_ms = arbor_now_ms() - done_ms;
        http_reply_buffer(r, 200, "image/png", png, len);
        http_reply_header(r, "Cache-Control", "no-store");
    }
    add_number_header(r, "X-Render-Ms", "%.3f", res->render_ms);
    add_number_header(r, "X-Rays", "%.0f", (double)res->rays);
    add_number_header(r, "X-Mrays-Per-S", "%.3f", res->mrays_per_s);
    if (rr->spec.mode == ARBOR_MODE_HEAT)
        add_number_header(r, "X-Heat-Scale", "%.17g", res->heat_scale); /* exact: strips take it as it is */
    char timing[160];
    snprintf(timing, sizeof timing, "queue;dur=%.3f, build;dur=%.3f, render;dur=%.3f, encode;dur=%.3f", queue_ms,
             rr->tree_ms - rr->admitted_ms, res->render_ms, encode_ms);
    http_reply_header(r, "Server-Timing", timing);
}

static void frame_done(arbor_frame *f, void *user)
{
    render_req *rr = user;
    const arbor_frame_result *res = arbor_frame_result_of(f);
    if (!rr_claim(rr))
        return;
    if (res->cancelled) {
        reply_cancelled(rr);
    } else {
        metrics_frame(&rr->srv->metrics, rr->spec.mode, res->rays, res->render_ms);
        reply_frame(rr, res);
    }
    rr_finish(rr);
}

/* The tree is here: render, unless the frame was answered meanwhile. */
static void start_frame(render_req *rr, arbor_tree *tree)
{
    arbor_server *s = rr->srv;
    arbor_err err;
    arbor_err_clear(&err);
    pthread_mutex_lock(&s->lock);
    bool go = !rr->answered, submitted = false;
    if (go) {
        rr->tree = tree;
        rr->tree_ms = arbor_now_ms();
        rr->submitted_ms = arbor_now_ms();
        rr->frame = arbor_render_submit(s->pool, arbor_tree_accel(tree), &rr->params, frame_done, rr, &err);
        submitted = rr->frame != NULL;
        /* Only a frame that exists is RENDERING: cancel_locked cancels it. */
        if (submitted)
            rr->state = RR_RENDERING;
    }
    pthread_mutex_unlock(&s->lock);
    if (!go)
        arbor_tree_release(tree);
    /* Once submitted, rr belongs to frame_done, which may already have freed it. */
    if (go && !submitted && rr_claim(rr)) {
        http_reply_err(rr->http, &err);
        rr_finish(rr);
    }
}

static void on_tree(void *user, arbor_tree *tree, const arbor_err *e)
{
    render_req *rr = user;
    if (tree != NULL) {
        start_frame(rr, tree);
    } else if (rr_claim(rr)) {
        http_reply_err(rr->http, e);
        rr_finish(rr);
    }
    rr_release(rr);  /* the callback's reference */
}

/* ---- cancellation ---- */

/* Cancels rr for `why` (lock held). A frame waiting for its tree is taken
 * off the list and returned, for the caller to answer after unlocking. */
static render_req *cancel_locked(arbor_server *s, render_req *rr, cancel_reason why)
{
    if (rr->cancelled)
        return NULL;
    rr->cancelled = true;
    rr->reason = why;
    if (rr->state == RR_RENDERING) {
        arbor_frame_cancel(rr->frame);
        return NULL;
    }
    rr->answered = true;
    list_remove(s, rr);
    return rr;
}

static void answer_cancelled(render_req **list, uint32_t n)
{
    for (uint32_t i = 0; i < n; i++) {
        reply_cancelled(list[i]);
        rr_finish(list[i]);
    }
}

/* Cancels every frame matching `pick` (all when NULL). */
static void cancel_where(arbor_server *s, bool (*pick)(const render_req *, const void *), const void *arg,
                         cancel_reason why)
{
    pthread_mutex_lock(&s->lock);
    uint32_t cap = s->nframes, n = 0;
    render_req **now = cap > 0 ? malloc(cap * sizeof *now) : NULL;
    render_req *rr = s->frames;
    while (rr != NULL) {
        render_req *next = rr->next;
        /* Without room to list them, frames waiting for a tree are left to
         * be answered when it comes (a cancelled build answers too): one
         * taken off the list here and not answered would never resume. */
        bool answerable = now != NULL || rr->state == RR_RENDERING;
        if (answerable && (pick == NULL || pick(rr, arg))) {
            render_req *c = cancel_locked(s, rr, why);
            if (c != NULL)
                now[n++] = c;
        }
        rr = next;
    }
    pthread_mutex_unlock(&s->lock);
    answer_cancelled(now, n);
    free(now);
}

static bool past_deadline(const render_req *rr, const void *arg)
{
    double now = *(const double *)arg, limit = rr->srv->config.frame_timeout_s * 1e3;
    return !rr->cancelled && now - rr->admitted_ms > limit;
}

/* Whether rr's client has closed its connection (or its sending side):
 * libmicrohttpd watches no suspended connection, so without this a frame
 * nobody waits for would hold its worker and its queue slot to the end. */
static bool client_gone(const render_req *rr, const void *arg)
{
    (void)arg;
    if (rr->cancelled || rr->fd < 0)
        return false;
    char c;
    ssize_t n = recv(rr->fd, &c, 1, MSG_PEEK | MSG_DONTWAIT); /* 0: the end of its stream */
    return n == 0 || (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR);
}

void frames_reap(arbor_server *s, double now_ms)
{
    cancel_where(s, client_gone, NULL, CANCEL_CLIENT_GONE);
    if (s->config.frame_timeout_s > 0.0)
        cancel_where(s, past_deadline, &now_ms, CANCEL_TIMEOUT);
}

void frames_cancel_all(arbor_server *s)
{
    cancel_where(s, NULL, NULL, CANCEL_SHUTDOWN);
}

/* ---- the request ---- */

typedef struct {
    cJSON *obj;
    arbor_err *e;
    bool ok;
} query_ctx;

static enum MHD_Result query_arg(void *cls, enum MHD_ValueKind kind, const char *key, const char *value)
{
    (void)kind;
    query_ctx *q = cls;
    if (q->ok)
        q->ok = render_query_add(q->obj, key, value, q->e);
    return q->ok ? MHD_YES : MHD_NO;
}

/* The request's fields as JSON, from the body (POST) or the query. */
static cJSON *request_fields(http_req *r)
{
    if (http_method_is(r, "POST"))
        return http_body_json(r);
    arbor_err err;
    arbor_err_clear(&err);
    query_ctx q = {cJSON_CreateObject(), &err, true};
    if (q.obj == NULL) {
        http_reply_error(r, 507, "insufficient_memory", "out of memory");
        return NULL;
    }
    MHD_get_connection_values(r->conn, MHD_GET_ARGUMENT_KIND, query_arg, &q);
    if (!q.ok) {
        cJSON_Delete(q.obj);
        http_reply_err(r, &err);
        return NULL;
    }
    return q.obj;
}

/* Reads and checks the request into *spec and *params, and the model it
 * names into *model (a reference): true, or false with the reply made or r
 * suspended while the model loads (http.h). */
bool render_read_request(http_req *r, bool ray, render_spec *spec, arbor_render_params *params,
                         arbor_model **model)
{
    if (!http_ready_for_frames(r))
        return false;
    cJSON *fields = request_fields(r);
    if (fields == NULL)
        return false;
    arbor_err err;
    arbor_err_clear(&err);
    bool ok = render_spec_from_json(fields, ray, spec, &err);
    cJSON_Delete(fields);
    if (!ok) {
        http_reply_err(r, &err);
        return false;
    }
    if ((*model = sync_model(r, spec->model)) == NULL)
        return false;
    if (!render_spec_params(spec, arbor_model_mesh(*model), r->srv->config.max_pixels, params, &err)) {
        arbor_model_release(*model);
        http_reply_err(r, &err);
        return false;
    }
    return true;
}

static bool same_stream(const render_req *rr, const void *arg)
{
    return !rr->cancelled && strcmp(rr->spec.stream, (const char *)arg) == 0;
}

/* Puts rr on the list, or refuses it when the queue is full. */
static bool admit(arbor_server *s, render_req *rr)
{
    if (rr->spec.stream[0] != '\0')
        cancel_where(s, same_stream, rr->spec.stream, CANCEL_SUPERSEDED);
    pthread_mutex_lock(&s->lock);
    /* A cancelled frame stays listed until its tiles stop, soon: it holds
     * no place, or a frame that superseded one on its stream would find
     * the place still taken and be refused too. */
    uint32_t live = 0;
    for (const render_req *q = s->frames; q != NULL; q = q->next)
        live += !q->cancelled;
    bool ok = !s->stopping && live < (uint32_t)(s->config.threads + s->config.queue);
    if (ok)
        list_add(s, rr);
    pthread_mutex_unlock(&s->lock);
    return ok;
}

void route_render(http_req *r)
{
    arbor_server *s = r->srv;
    render_req *rr = calloc(1, sizeof *rr);
    if (rr == NULL) {
        http_reply_error(r, 507, "insufficient_memory", "out of memory");
        return;
    }
    rr->srv = s;
    /* The answer path's reference and this handler's: a cancel from another
     * thread may answer rr before this function is done with it. */
    atomic_init(&rr->refs, 2);
    if (!render_read_request(r, false, &rr->spec, &rr->params, &rr->model)) {
        free(rr);
        return;
    }
    rr->admitted_ms = arbor_now_ms();
    rr->http = r;
    const union MHD_ConnectionInfo *ci = MHD_get_connection_info(r->conn, MHD_CONNECTION_INFO_CONNECTION_FD);
    rr->fd = ci != NULL ? ci->connect_fd : -1;
    /* Suspended before anyone else can see rr, so that no resume comes first. */
    http_suspend(r);
    if (!admit(s, rr)) {
        metrics_frame_rejected(&s->metrics);
        if (atomic_load(&s->closing)) { /* the stop began after http_ready_for_frames */
            http_reply_stopping(r);
        } else {
            http_reply_error(r, 503, "busy", "all %u frame slots (--threads + --queue) are taken; try again",
                             (unsigned)(s->config.threads + s->config.queue));
            http_reply_header(r, "Retry-After", "1");
        }
        rr->answered = true;
        rr_finish(rr);
        rr_release(rr);
        return;
    }
    arbor_tree *tree = NULL;
    arbor_err err;
    arbor_err_clear(&err);
    atomic_fetch_add(&rr->refs, 1);  /* for on_tree, should the tree be pending */
    arbor_acquire got = arbor_store_acquire_tree(s->store, rr->model, rr->spec.kind, rr->spec.builder, &tree,
                                                 on_tree, rr, &err);
    if (got != ARBOR_ACQUIRE_PENDING)
        rr_release(rr);
    if (got == ARBOR_ACQUIRE_READY) {
        start_frame(rr, tree);
    } else if (got == ARBOR_ACQUIRE_FAILED && rr_claim(rr)) {
        http_reply_err(r, &err);
        rr_finish(rr);
    }
    rr_release(rr);
}
