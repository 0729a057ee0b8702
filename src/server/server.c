/*
 * server.c - the libmicrohttpd daemon: request records, routing, the
 * access log, readiness, the frame-timeout reaper and shutdown (see
 * include/arbor/server.h and http.h). The replies, suspension and helpers
 * every route uses are http.c's, below the routes this file dispatches to.
 *
 * libmicrohttpd calls on_request several times per request on its one
 * polling thread: once with the headers, once per piece of body, once with
 * no data left (dispatch), and once more after a suspended connection is
 * resumed. Nothing here blocks: a handler replies at once or hands the
 * request to a worker, which replies and resumes.
 */
#include <arpa/inet.h>
#include <errno.h>
#include <inttypes.h>
#include <math.h>
#include <netinet/in.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include "arbor/sys.h"
#include "http.h"

#define REAPER_PERIOD_MS 100
/* Bytes of a body over its limit read and dropped before the 413 is sent
 * and the connection closed. */
#define BODY_DRAIN_MAX (16u << 20)
#define DRAIN_MS 3000

/* ---- readiness, health, metrics ---- */

void arbor_server_pending(arbor_server *s, const char *what)
{
    char *copy = strdup(what);
    pthread_mutex_lock(&s->lock);
    char **grown = copy != NULL ? realloc(s->pending, (s->npending + 1) * sizeof *grown) : NULL;
    if (grown != NULL) {
        s->pending = grown;
        s->pending[s->npending++] = copy;
        copy = NULL;
    }
    pthread_mutex_unlock(&s->lock);
    free(copy);
}

void arbor_server_pending_done(arbor_server *s, const char *what)
{
    pthread_mutex_lock(&s->lock);
    for (uint32_t i = 0; i < s->npending; i++)
        if (strcmp(s->pending[i], what) == 0) {
            free(s->pending[i]);
            s->pending[i] = s->pending[--s->npending];
            break;
        }
    pthread_mutex_unlock(&s->lock);
}

void arbor_server_loaded(arbor_server *s)
{
    pthread_mutex_lock(&s->lock);
    s->loaded = true;
    pthread_mutex_unlock(&s->lock);
}

static void route_readyz(http_req *r)
{
    arbor_server *s = r->srv;
    cJSON *o = cJSON_CreateObject();
    pthread_mutex_lock(&s->lock);
    bool ready = server_ready_locked(s);
    cJSON_AddStringToObject(o, "status", s->stopping ? "stopping" : ready ? "ready" : "loading");
    if (!s->stopping && !ready) {
        cJSON *p = cJSON_AddArrayToObject(o, "pending");
        for (uint32_t i = 0; i < s->npending; i++)
            json_push(p, cJSON_CreateString(s->pending[i]));
    }
    pthread_mutex_unlock(&s->lock);
    http_reply_json(r, ready ? 200 : 503, o);
}

static void route_metrics(http_req *r)
{
    arbor_server *s = r->srv;
    metrics_gauges g = {0};
    arbor_store_usage u;
    arbor_store_usage_of(s->store, &u);
    g.uptime_s = (arbor_now_ms() - s->start_ms) / 1e3;
    g.model_bytes = u.models;
    g.tree_bytes = u.trees;
    g.models = u.nmodels;
    pthread_mutex_lock(&s->lock);
    frames_count(s, &g.frames_waiting, &g.frames_rendering);
    pthread_mutex_unlock(&s->lock);
    size_t len = 0;
    char *text = metrics_expose(&s->metrics, &g, &len);
    if (text == NULL) {
        http_reply_error(r, 507, "insufficient_memory", "out of memory writing the metrics");
        return;
    }
    http_reply_buffer(r, 200, "text/plain; version=0.0.4; charset=utf-8", text, len);
}

static void on_build(void *user, arbor_accel_kind kind, arbor_builder builder, double ms, bool ok)
{
    arbor_server *s = user;
    metrics_build(&s->metrics, kind, builder, ms, ok);
}

/* ---- routing ---- */

/* Copies the next path segment of *p (after a '/') into seg; false when
 * there is none or it is too long. */
static bool next_segment(const char **p, char *seg, size_t cap)
{
    if (**p != '/')
        return false;
    const char *start = *p + 1, *end = strchr(start, '/');
    size_t n = end != NULL ? (size_t)(end - start) : strlen(start);
    if (n == 0 || n >= cap)
        return false;
    memcpy(seg, start, n);
    seg[n] = '\0';
    *p = start + n;
    return true;
}

static http_route classify(const char *path)
{
    if (strcmp(path, "/healthz") == 0) return ROUTE_HEALTHZ;
    if (strcmp(path, "/readyz") == 0) return ROUTE_READYZ;
    if (strcmp(path, "/metrics") == 0) return ROUTE_METRICS;
    if (strcmp(path, "/api/models") == 0) return ROUTE_MODELS;
    if (strcmp(path, "/api/stats") == 0) return ROUTE_STATS;
    if (strcmp(path, "/api/render") == 0) return ROUTE_RENDER;
    if (strcmp(path, "/api/ray") == 0) return ROUTE_RAY;
    if (strcmp(path, "/api/bench") == 0) return ROUTE_BENCH;
    if (strncmp(path, "/api/jobs/", 10) == 0) return ROUTE_JOBS;
    if (strncmp(path, "/api/models/", 12) == 0) {
        const char *boxes = strstr(path + 12, "/boxes"); /* after the name: a model may be called boxes */
        if (boxes != NULL && boxes[6] == '\0') return ROUTE_BOXES;
        const char *trees = strstr(path + 12, "/trees");
        return trees != NULL && trees[6] == '\0' ? ROUTE_TREES : ROUTE_MODEL;
    }
    if (strncmp(path, "/api/", 5) == 0 || strcmp(path, "/api") == 0) return ROUTE_UNKNOWN;
    return ROUTE_STATIC;
}

/* A route of one method (GET also serving HEAD) whose query parameters are
 * `known` (http_args_known), or NULL when the handler checks them itself. */
static void only(http_req *r, const char *method, const char *known, void (*handler)(http_req *))
{
    if (!http_method_is(r, method) && !(strcmp(method, "GET") == 0 && http_method_is(r, "HEAD")))
        http_method_not_allowed(r, strcmp(method, "GET") == 0 ? "GET, HEAD" : method);
    else if (known == NULL || http_args_known(r, known))
        handler(r);
}

static void route_healthz(http_req *r)
{
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "status", "ok");
    http_reply_json(r, 200, o);
}

static void list_models(http_req *r)
{
    if (!sync_models(r))
        return;
    arbor_model **models;
    uint32_t n;
    arbor_err e;
    if (!arbor_store_list_models(r->srv->store, &models, &n, &e)) {
        http_reply_err(r, &e);
        return;
    }
    cJSON *o = cJSON_CreateObject(), *a = cJSON_AddArrayToObject(o, "models");
    for (uint32_t i = 0; i < n; i++) {
        json_push(a, model_json(r->srv, models[i]));
        arbor_model_release(models[i]);
    }
    free(models);
    http_reply_json(r, 200, o);
}

static void dispatch(http_req *r, const char *path)
{
    switch (r->route) {
    case ROUTE_HEALTHZ: only(r, "GET", "", route_healthz); return;
    case ROUTE_READYZ: only(r, "GET", "", route_readyz); return;
    case ROUTE_METRICS: only(r, "GET", "", route_metrics); return;
    case ROUTE_MODELS: only(r, "GET", "", list_models); return;
    case ROUTE_STATS: only(r, "GET", NULL, route_stats); return;
    case ROUTE_RAY: only(r, "POST", "", route_ray); return;
    case ROUTE_BENCH: only(r, "POST", "", route_bench); return;
    case ROUTE_RENDER:
        if (http_method_is(r, "GET") || http_method_is(r, "HEAD")) /* its query is the request */
            route_render(r);
        else if (http_method_is(r, "POST")) /* its body is */
            only(r, "POST", "", route_render);
        else
            http_method_not_allowed(r, "GET, HEAD, POST");
        return;
    case ROUTE_JOBS: route_job(r, path + 10); return;
    case ROUTE_MODEL:
    case ROUTE_TREES:
    case ROUTE_BOXES: {
        char name[ARBOR_MODEL_NAME_MAX + 2];
        const char *p = path + 11;
        if (!next_segment(&p, name, sizeof name) || !arbor_model_name_valid(name)) {
            int len = (int)strcspn(path + 12, "/"); /* the name's segment, not the path after it */
            if (r->upload)
                http_reply_error(r, 400, "bad_request",
                                 "'%.*s' is no model name: names are " ARBOR_MODEL_NAME_RULE, len, path + 12);
            else
                http_reply_error(r, 404, "not_found", "no model named '%.*s'", len, path + 12);
            return;
        }
        route_models(r, name, p);
        return;
    }
    case ROUTE_STATIC:
        if (http_method_is(r, "GET") || http_method_is(r, "HEAD"))
            route_static(r, path);
        else
            http_method_not_allowed(r, "GET, HEAD");
        return;
    default: http_reply_error(r, 404, "not_found", "no such endpoint: %s", path); return;
    }
}

/* ---- the access log ---- */

/* A request's own bytes (method, path) in the text log, control bytes and
 * the backslash as \xNN: a client must not write terminal escapes or
 * forged lines into the operator's log. */
static void log_text_field(const char *text)
{
    for (const unsigned char *p = (const unsigned char *)text; *p != '\0'; p++) {
        if (*p < 0x20 || *p == 0x7f || *p == '\\')
            fprintf(stderr, "\\x%02x", *p);
        else
            fputc(*p, stderr);
    }
}

static void log_request(const arbor_server *s, const http_req *r, double ms)
{
    char when[32];
    time_t now = time(NULL);
    struct tm tm;
    gmtime_r(&now, &tm);
    strftime(when, sizeof when, "%Y-%m-%dT%H:%M:%SZ", &tm);
    if (s->config.log_json) {
        cJSON *o = cJSON_CreateObject();
        cJSON_AddStringToObject(o, "time", when);
        cJSON_AddStringToObject(o, "id", r->id);
        cJSON_AddStringToObject(o, "method", r->method);
        cJSON_AddStringToObject(o, "path", r->url != NULL ? r->url : "");
        cJSON_AddNumberToObject(o, "status", r->status);
        cJSON_AddNumberToObject(o, "bytes", (double)r->bytes);
        cJSON_AddNumberToObject(o, "ms", round(ms * 1000.0) / 1000.0);
        char *line = cJSON_PrintUnformatted(o);
        if (line != NULL) {
            arbor_utf8_repair(line, strlen(line)); /* the path's bytes, as in answers */
            fprintf(stderr, "%s\n", line);
        }
        free(line);
        cJSON_Delete(o);
        json_oom_clear(); /* the log's own failure; no answer is missing a part */
    } else {
        flockfile(stderr); /* one line, whichever threads log at once */
        fprintf(stderr, "%s %s ", when, r->id);
        log_text_field(r->method);
        fputc(' ', stderr);
        log_text_field(r->url != NULL ? r->url : "");
        fprintf(stderr, " %u %" PRIu64 "B %.1fms\n", r->status, r->bytes, ms);
        funlockfile(stderr);
    }
}

/* ---- libmicrohttpd callbacks ---- */

/* What the server keeps per connection: the record on_uri made for the
 * request being read, until the access handler takes it. libmicrohttpd
 * calls the completion callback only for requests that reached the
 * handler, so the record of one it refused itself (a request line or
 * headers over its limits) is freed here: at the connection's next request,
 * or when it closes. Polling thread only. */
typedef struct {
    http_req *unclaimed;
} conn_ctx;

static void on_connection(void *cls, struct MHD_Connection *conn, void **socket_context,
                          enum MHD_ConnectionNotificationCode code)
{
    (void)cls;
    (void)conn;
    if (code == MHD_CONNECTION_NOTIFY_STARTED) {
        *socket_context = calloc(1, sizeof(conn_ctx));
        return;
    }
    conn_ctx *c = *socket_context;
    if (c != NULL)
        http_req_release(c->unclaimed);
    free(c);
    *socket_context = NULL;
}

static conn_ctx *conn_ctx_of(struct MHD_Connection *conn)
{
    const union MHD_ConnectionInfo *ci = MHD_get_connection_info(conn, MHD_CONNECTION_INFO_SOCKET_CONTEXT);
    return ci != NULL ? ci->socket_context : NULL;
}

/* The first thing libmicrohttpd knows of a request: its raw URI (query
 * string included, for the log). Creates the record. */
static void *on_uri(void *cls, const char *uri, struct MHD_Connection *conn)
{
    arbor_server *s = cls;
    conn_ctx *c = conn_ctx_of(conn);
    if (c != NULL) {
        http_req_release(c->unclaimed);
        c->unclaimed = NULL;
    }
    http_req *r = calloc(1, sizeof *r);
    char *url = strdup(uri);
    if (r == NULL || url == NULL) {
        /* on_request answers a request without a record with the 507. */
        free(r);
        free(url);
        return NULL;
    }
    r->srv = s;
    atomic_init(&r->refs, 1);
    r->url = url;
    r->start_ms = arbor_now_ms();
    pthread_mutex_lock(&s->lock);
    uint64_t id = ++s->next_request_id;
    pthread_mutex_unlock(&s->lock);
    snprintf(r->id, sizeof r->id, "%" PRIx64 "-%" PRIu64, (uint64_t)s->start_ms & 0xffff, id);
    if (c != NULL)
        c->unclaimed = r;
    return r;
}

static void on_completed(void *cls, struct MHD_Connection *conn, void **con_cls,
                         enum MHD_RequestTerminationCode toe)
{
    (void)toe;
    arbor_server *s = cls;
    http_req *r = *con_cls;
    if (r == NULL)
        return;
    /* libmicrohttpd also completes some requests that never reached the
     * handler (a connection timed out while its headers came in): this
     * callback's release is then the only one. */
    conn_ctx *c = conn_ctx_of(conn);
    if (c != NULL && c->unclaimed == r)
        c->unclaimed = NULL;
    double ms = arbor_now_ms() - r->start_ms;
    if (r->status != 0) {
        metrics_request(&s->metrics, r->route, r->status, ms / 1e3);
        log_request(s, r, ms);
    }
    *con_cls = NULL;
    /* An upload that ended before its answer (the client went) leaves its
     * temporary files: no worker has them, as none runs for a request
     * libmicrohttpd completes (it completes none while suspended). */
    models_parts_free(r);
    http_req_release(r);
}

static enum MHD_Result queue_reply(http_req *r)
{
    /* An upload's temporary files go before its answer does: a client that
     * has its answer may look, and the daemon holds nothing it no longer needs. */
    models_parts_free(r);
    if (r->response == NULL && r->status == 0)
        http_reply_error(r, 500, "internal", "no answer was made");
    if (r->response == NULL) {
        /* The answer could not be made for want of memory. */
        r->status = MHD_HTTP_INSUFFICIENT_STORAGE;
        return MHD_queue_response(r->conn, r->status, r->srv->oom);
    }
    MHD_add_response_header(r->response, "X-Request-Id", r->id);
    /* While stopping, connections close after their answer, so that the
     * daemon can wait for every answer to leave before it stops. */
    if (atomic_load(&r->srv->closing))
        MHD_add_response_header(r->response, MHD_HTTP_HEADER_CONNECTION, "close");
    enum MHD_Result ok = MHD_queue_response(r->conn, r->status, r->response);
    MHD_destroy_response(r->response);
    r->response = NULL;
    return ok;
}

/* Headers have arrived: what the body may be, and whether to refuse it now. */
static bool on_headers(http_req *r, const char *method)
{
    snprintf(r->method, sizeof r->method, "%s", method);
    const char *path = r->url;
    char *q = strchr(r->url, '?');
    if (q != NULL)
        *q = '\0';
    r->route = classify(path);
    if (q != NULL)
        *q = '?';
    r->upload = r->route == ROUTE_MODEL && (http_method_is(r, "PUT") || http_method_is(r, "POST"));
    r->limit = r->upload ? r->srv->config.max_upload : r->srv->config.max_body;
    /* Refuse an unauthorised upload before its body, not after storing it. */
    if (r->upload && !http_may_write(r))
        return false;
    /* Bodies are read as they come: only a PUT of a model may be gzip (known
     * by its magic bytes); any other coding would be parsed as the body. */
    bool body = http_method_is(r, "POST") || http_method_is(r, "PUT");
    bool put_model = r->upload && http_method_is(r, "PUT");
    const char *coding =
        body ? MHD_lookup_connection_value(r->conn, MHD_HEADER_KIND, MHD_HTTP_HEADER_CONTENT_ENCODING) : NULL;
    if (coding != NULL && strcasecmp(coding, "identity") != 0 &&
        !(put_model && (strcasecmp(coding, "gzip") == 0 || strcasecmp(coding, "x-gzip") == 0))) {
        http_reply_error(r, 415, "unsupported_media_type", "Content-Encoding '%s' is not read here%s", coding,
                         put_model ? " (gzip is)" : " (only a PUT of a model may be gzip)");
        return false;
    }
    const char *length = MHD_lookup_connection_value(r->conn, MHD_HEADER_KIND, MHD_HTTP_HEADER_CONTENT_LENGTH);
    if (length != NULL && strtoull(length, NULL, 10) > r->limit) {
        http_reply_error(r, 413, "too_large", "the body of %s bytes is over the limit of %zu bytes", length,
                         r->limit);
        return false;
    }
    return true;
}

static void on_body(http_req *r, const char *data, size_t size)
{
    if (r->too_large || r->response != NULL)
        return;
    if (size > r->limit - r->body_len) {
        r->too_large = true;
        return;
    }
    if (r->upload) {
        if (!models_post_data(r, data, size))
            r->too_large = r->response == NULL;
        return;
    }
    if (r->body_len + size > r->body_cap) {
        size_t cap = r->body_cap ? r->body_cap : 4096;
        while (cap < r->body_len + size)
            cap *= 2;
        char *b = realloc(r->body, cap);
        if (b == NULL) {
            http_reply_error(r, 507, "insufficient_memory", "out of memory reading the body");
            return;
        }
        r->body = b;
        r->body_cap = cap;
    }
    memcpy(r->body + r->body_len, data, size);
    r->body_len += size;
}

/* Runs r's route unless the server is stopping. The stop waits once for
 * `inflight` to fall to 0, and libmicrohttpd aborts on a connection
 * suspended after that: so a route counts as in flight while it runs, and
 * none that may suspend starts once `stopping` is set (the probes never
 * suspend, and /readyz says "stopping"). */
static void dispatch_unless_stopping(http_req *r, const char *url)
{
    arbor_server *s = r->srv;
    bool probe = r->route == ROUTE_HEALTHZ || r->route == ROUTE_READYZ || r->route == ROUTE_METRICS;
    pthread_mutex_lock(&s->lock);
    bool refuse = s->stopping && !probe;
    if (!refuse)
        s->inflight++;
    pthread_mutex_unlock(&s->lock);
    if (refuse) {
        http_reply_stopping(r);
        return;
    }
    dispatch(r, url);
    pthread_mutex_lock(&s->lock);
    if (--s->inflight == 0)
        pthread_cond_broadcast(&s->idle);
    pthread_mutex_unlock(&s->lock);
}

static enum MHD_Result on_request(void *cls, struct MHD_Connection *conn, const char *url, const char *method,
                                  const char *version, const char *upload_data, size_t *upload_data_size,
                                  void **con_cls)
{
    (void)version;
    http_req *r = *con_cls;
    if (r == NULL) {
        /* on_uri had no memory for the request's record. */
        arbor_server *s = cls;
        return MHD_queue_response(conn, MHD_HTTP_INSUFFICIENT_STORAGE, s->oom);
    }
    if (r->conn == NULL) {
        r->conn = conn;
        conn_ctx *c = conn_ctx_of(conn);
        if (c != NULL && c->unclaimed == r)
            c->unclaimed = NULL; /* the completion callback frees it now */
        json_oom_clear(); /* a mark left by what came before is not this request's */
        if (!on_headers(r, method))
            return queue_reply(r);
        return MHD_YES;
    }
    if (*upload_data_size > 0) {
        on_body(r, upload_data, *upload_data_size);
        r->body_seen += *upload_data_size;
        *upload_data_size = 0;
        if (r->body_seen <= (uint64_t)r->limit + BODY_DRAIN_MAX)
            return MHD_YES;
        /* Past the limit (or an answer made mid-body) the body is read and
         * dropped, so that the client, done sending, reads the answer. Past
         * the drain the connection is closed unanswered (libmicrohttpd
         * queues no answer while a body still comes in), or an endless
         * chunked body would hold it for ever; the access log has the 413
         * it earned. */
        if (r->response == NULL)
            http_reply_error(r, 413, "too_large", "the body is over the limit of %zu bytes", r->limit);
        return MHD_NO;
    }
    if (r->suspended) {
        /* Resumed: a worker has replied, or sync.c has loaded the model the
         * route needs and it runs again. */
        r->suspended = false;
        if (r->redispatch) {
            r->redispatch = false;
            dispatch_unless_stopping(r, url);
            if (r->suspended)
                return MHD_YES;
        }
        return queue_reply(r);
    }
    if (r->response == NULL) {
        if (r->too_large)
            http_reply_error(r, 413, "too_large", "the body is over the limit of %zu bytes", r->limit);
        else
            dispatch_unless_stopping(r, url);
    }
    if (r->suspended)
        return MHD_YES;
    return queue_reply(r);
}

/* Decodes %XX in place, as libmicrohttpd's own unescaper does, except that a
 * %00 leaves the whole string undecoded: a NUL would cut the path short and
 * make a different file out of it. */
static size_t unescape(void *cls, struct MHD_Connection *conn, char *s)
{
    (void)cls;
    (void)conn;
    if (strstr(s, "%00") != NULL)
        return strlen(s);
    return MHD_http_unescape(s);
}

/* ---- the frame-timeout reaper ---- */

static void *reaper_run(void *arg)
{
    arbor_server *s = arg;
    pthread_mutex_lock(&s->lock);
    while (!s->stopping) {
        struct timespec until;
        clock_gettime(CLOCK_MONOTONIC, &until);
        until.tv_nsec += REAPER_PERIOD_MS * 1000000L;
        if (until.tv_nsec >= 1000000000L) {
            until.tv_sec++;
            until.tv_nsec -= 1000000000L;
        }
        pthread_cond_timedwait(&s->reaper_wake, &s->lock, &until);
        if (!s->stopping) {
            pthread_mutex_unlock(&s->lock);
            frames_reap(s, arbor_now_ms());
            pthread_mutex_lock(&s->lock);
        }
    }
    pthread_mutex_unlock(&s->lock);
    return NULL;
}

/* ---- start and stop ---- */

static bool bind_address(const char *bind, int port, struct sockaddr_storage *ss, bool *loopback, arbor_err *e)
{
    memset(ss, 0, sizeof *ss);
    struct sockaddr_in *v4 = (struct sockaddr_in *)ss;
    struct sockaddr_in6 *v6 = (struct sockaddr_in6 *)ss;
    if (inet_pton(AF_INET, bind, &v4->sin_addr) == 1) {
        v4->sin_family = AF_INET;
        v4->sin_port = htons((uint16_t)port);
        *loopback = (ntohl(v4->sin_addr.s_addr) >> 24) == 127;
        return true;
    }
    if (inet_pton(AF_INET6, bind, &v6->sin6_addr) == 1) {
        v6->sin6_family = AF_INET6;
        v6->sin6_port = htons((uint16_t)port);
        *loopback = IN6_IS_ADDR_LOOPBACK(&v6->sin6_addr);
        return true;
    }
    return arbor_fail(e, ARBOR_ERR_INVALID, "--bind '%s' is not an IPv4 or IPv6 address", bind);
}

/* libmicrohttpd's own messages would go to stderr unasked; the server's
 * errors come back through arbor_err instead. */
static void mhd_quiet(void *cls, const char *fmt, va_list ap)
{
    (void)cls;
    (void)fmt;
    (void)ap;
}

/* Whether a port can be bound, to tell "in use" from other failures. */
static void explain_bind_failure(const struct sockaddr_storage *ss, const char *addr, int port, arbor_err *e)
{
    int fd = socket(ss->ss_family, SOCK_STREAM, 0);
    int err = 0;
    if (fd >= 0) {
        int one = 1;
        setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
        socklen_t len = ss->ss_family == AF_INET ? sizeof(struct sockaddr_in) : sizeof(struct sockaddr_in6);
        if (bind(fd, (const struct sockaddr *)ss, len) != 0)
            err = errno;
        close(fd);
    }
    char why[128] = "cannot listen";
    if (err != 0)
        strerror_r(err, why, sizeof why);
    arbor_fail(e, ARBOR_ERR_IO, "cannot listen on %s port %d: %s", addr, port, why);
}

static bool start_mhd(arbor_server *s, arbor_err *e)
{
    const arbor_server_config *c = &s->config;
    struct sockaddr_storage ss;
    if (!bind_address(c->bind, c->port, &ss, &s->loopback, e))
        return false;
    unsigned flags = MHD_USE_EPOLL_INTERNAL_THREAD | MHD_ALLOW_SUSPEND_RESUME;
    if (ss.ss_family == AF_INET6)
        flags |= MHD_USE_IPv6;
    s->mhd = MHD_start_daemon(
        flags, (uint16_t)c->port, NULL, NULL, on_request, s, MHD_OPTION_SOCK_ADDR, (struct sockaddr *)&ss,
        MHD_OPTION_URI_LOG_CALLBACK, on_uri, s, MHD_OPTION_NOTIFY_COMPLETED, on_completed, s,
        MHD_OPTION_NOTIFY_CONNECTION, on_connection, s,
        MHD_OPTION_UNESCAPE_CALLBACK, unescape, NULL, MHD_OPTION_EXTERNAL_LOGGER, mhd_quiet, NULL,
        MHD_OPTION_CONNECTION_TIMEOUT, (unsigned)c->connection_timeout_s, MHD_OPTION_CONNECTION_LIMIT,
        (unsigned)c->connection_limit, MHD_OPTION_PER_IP_CONNECTION_LIMIT, (unsigned)c->per_ip_limit,
        MHD_OPTION_CONNECTION_MEMORY_LIMIT, (size_t)64 * 1024, MHD_OPTION_END);
    if (s->mhd == NULL) {
        explain_bind_failure(&ss, c->bind, c->port, e);
        return false;
    }
    const union MHD_DaemonInfo *info = MHD_get_daemon_info(s->mhd, MHD_DAEMON_INFO_BIND_PORT);
    s->port = info != NULL && info->port != 0 ? info->port : c->port;
    return true;
}

static bool config_check(const arbor_server_config *c, arbor_err *e)
{
    if (c->port < 0 || c->port > 65535)
        return arbor_fail(e, ARBOR_ERR_INVALID, "port must be in 0..65535, not %d", c->port);
    if (c->threads < 1 || c->queue < 0)
        return arbor_fail(e, ARBOR_ERR_INVALID, "threads must be >= 1 and queue >= 0");
    if (c->max_body < 1 || c->max_upload < 1 || c->max_pixels < 1)
        return arbor_fail(e, ARBOR_ERR_INVALID, "limits must be positive");
    if (c->connection_limit < 1 || c->per_ip_limit < 1 || c->connection_timeout_s < 1)
        return arbor_fail(e, ARBOR_ERR_INVALID, "connection limits and timeout must be positive");
    return true;
}

arbor_server *arbor_server_start(const arbor_server_config *c, arbor_store *store, arbor_pool *pool,
                                 arbor_err *e)
{
    if (!config_check(c, e))
        return NULL;
    arbor_server *s = calloc(1, sizeof *s);
    if (s == NULL) {
        arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory starting the server");
        return NULL;
    }
    s->config = *c;
    s->store = store;
    s->pool = pool;
    s->start_ms = arbor_now_ms();
    s->token = c->token != NULL ? strdup(c->token) : NULL;
    s->config.token = NULL;
    metrics_init(&s->metrics);
    pthread_mutex_init(&s->lock, NULL);
    pthread_cond_init(&s->idle, NULL);
    /* the reaper's waits by the monotonic clock: a step of the wall clock
     * must not hold frame timeouts off */
    pthread_condattr_t monotonic;
    pthread_condattr_init(&monotonic);
    pthread_condattr_setclock(&monotonic, CLOCK_MONOTONIC);
    pthread_cond_init(&s->reaper_wake, &monotonic);
    pthread_condattr_destroy(&monotonic);
    /* cJSON allocates through json_malloc, which notes failures (see http.h). */
    cJSON_Hooks hooks = {json_malloc, free};
    cJSON_InitHooks(&hooks);
    s->jobs = jobs_create(pool, store);
    s->oom = MHD_create_response_from_buffer(sizeof OOM_BODY - 1, (void *)OOM_BODY, MHD_RESPMEM_PERSISTENT);
    if (s->oom != NULL)
        MHD_add_response_header(s->oom, MHD_HTTP_HEADER_CONTENT_TYPE, "application/json");
    arbor_store_on_build(store, on_build, s);
    bool ok = (c->token == NULL || s->token != NULL) && s->jobs != NULL && s->oom != NULL;
    if (!ok)
        arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory starting the server");
    if (ok)
        ok = start_mhd(s, e);
    if (ok && pthread_create(&s->reaper, NULL, reaper_run, s) != 0)
        ok = arbor_fail(e, ARBOR_ERR_NOMEM, "cannot start the frame-timeout thread");
    s->reaper_started = ok;
    if (!ok) {
        arbor_server_stop(s);
        return NULL;
    }
    return s;
}

int arbor_server_port(const arbor_server *s)
{
    return s->port;
}

bool arbor_server_writes_forbidden(const arbor_server *s)
{
    return s->token == NULL && !s->loopback;
}

/* Gives the answers already queued time to reach their clients: until no
 * connection is left open (they close after answering while stopping) or
 * DRAIN_MS have passed, whichever is first. */
static void drain(arbor_server *s)
{
    double until = arbor_now_ms() + DRAIN_MS;
    while (s->mhd != NULL && arbor_now_ms() < until) {
        const union MHD_DaemonInfo *info = MHD_get_daemon_info(s->mhd, MHD_DAEMON_INFO_CURRENT_CONNECTIONS);
        if (info == NULL || info->num_connections == 0)
            return;
        struct timespec pause = {0, 10 * 1000000L};
        nanosleep(&pause, NULL);
    }
}

void arbor_server_stop(arbor_server *s)
{
    if (s == NULL)
        return;
    /* The listening socket is ours once quiesced, but the polling thread may
     * still look at its descriptor until it stops: closed after that
     * (TSan saw the close race the thread). */
    MHD_socket listen = s->mhd != NULL ? MHD_quiesce_daemon(s->mhd) : MHD_INVALID_SOCKET;
    atomic_store(&s->closing, true);
    pthread_mutex_lock(&s->lock);
    s->stopping = true;
    pthread_cond_broadcast(&s->reaper_wake);
    pthread_mutex_unlock(&s->lock);
    frames_cancel_all(s);
    if (s->jobs != NULL)
        jobs_cancel_all(s->jobs);
    /* A build's callback and waiters (frames waiting for a tree, start-up's
     * prebuild) reach this server: they must all have run before it goes. */
    arbor_store_stop_builds(s->store);
    arbor_store_on_build(s->store, NULL, NULL);
    if (s->reaper_started)
        pthread_join(s->reaper, NULL);
    /* Cancelled frames and builds answer from the workers; wait for every
     * suspended connection to be resumed, as libmicrohttpd requires before
     * it stops. */
    pthread_mutex_lock(&s->lock);
    while (s->inflight > 0)
        pthread_cond_wait(&s->idle, &s->lock);
    pthread_mutex_unlock(&s->lock);
    drain(s);
    if (s->mhd != NULL)
        MHD_stop_daemon(s->mhd);
    if (listen != MHD_INVALID_SOCKET)
        close(listen);
    if (s->oom != NULL)
        MHD_destroy_response(s->oom);
    jobs_destroy(s->jobs);
    for (uint32_t i = 0; i < s->npending; i++)
        free(s->pending[i]);
    free(s->pending);
    free(s->token);
    sync_forget(s);
    pthread_cond_destroy(&s->reaper_wake);
    pthread_cond_destroy(&s->idle);
    pthread_mutex_destroy(&s->lock);
    metrics_destroy(&s->metrics);
    free(s);
}
