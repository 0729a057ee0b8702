/*
 * http.c - what every route uses to answer: JSON that notes its failed
 * allocations, stored replies, suspension and resumption of a request and
 * its hand-over to a pool worker, query parameters, methods, the write
 * token, JSON bodies, and the readiness gate of frames (see http.h).
 *
 * It knows the server's records (http.h) but no route: the routes and
 * server.c, which dispatches to them, sit above it.
 */
#include <assert.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "arbor/sys.h"
#include "http.h"

/* ---- JSON ---- */

static _Thread_local bool json_oom;

void *json_malloc(size_t n)
{
    void *p = malloc(n);
    if (p == NULL)
        json_oom = true;
    return p;
}

void json_oom_clear(void)
{
    json_oom = false;
}

void json_put(cJSON *object, const char *key, cJSON *item)
{
    if (!cJSON_AddItemToObject(object, key, item)) {
        json_oom = true;
        cJSON_Delete(item);
    }
}

void json_push(cJSON *array, cJSON *item)
{
    if (!cJSON_AddItemToArray(array, item)) {
        json_oom = true;
        cJSON_Delete(item);
    }
}

/* ---- replies ---- */


void http_reply_response(http_req *r, unsigned status, struct MHD_Response *resp, uint64_t bytes)
{
    if (r->response != NULL)
        MHD_destroy_response(r->response);
    r->response = resp;
    r->status = status;
    r->bytes = bytes;
}

void http_reply_buffer(http_req *r, unsigned status, const char *content_type, void *data, size_t len)
{
    struct MHD_Response *resp = MHD_create_response_from_buffer(len, data, MHD_RESPMEM_MUST_FREE);
    if (resp == NULL) {
        /* No response: queue_reply sends the server's 507. */
        free(data);
        http_reply_response(r, MHD_HTTP_INSUFFICIENT_STORAGE, NULL, sizeof OOM_BODY - 1);
        return;
    }
    MHD_add_response_header(resp, MHD_HTTP_HEADER_CONTENT_TYPE, content_type);
    http_reply_response(r, status, resp, len);
}

void http_reply_json(http_req *r, unsigned status, cJSON *body)
{
    char *text = body != NULL && !json_oom ? cJSON_PrintUnformatted(body) : NULL;
    cJSON_Delete(body);
    bool failed = json_oom;
    json_oom = false;
    if (text == NULL || failed) {
        free(text);
        /* Out of memory making the body (or the body's JSON was never
         * built, for the same reason): the server's 507. */
        http_reply_response(r, MHD_HTTP_INSUFFICIENT_STORAGE, NULL, sizeof OOM_BODY - 1);
        return;
    }
    size_t len = strlen(text);
    arbor_utf8_repair(text, len); /* a URL's %ff, a material name in Latin-1 */
    /* A newline ends the body, so curl's output ends a line. */
    char *line = realloc(text, len + 2);
    if (line != NULL) {
        text = line;
        text[len++] = '\n';
        text[len] = '\0';
    }
    http_reply_buffer(r, status, "application/json", text, len);
}

void http_reply_error(http_req *r, unsigned status, const char *code, const char *fmt, ...)
{
    char msg[1024];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    cJSON *o = cJSON_CreateObject(), *err = cJSON_AddObjectToObject(o, "error");
    cJSON_AddStringToObject(err, "code", code);
    cJSON_AddStringToObject(err, "message", msg);
    http_reply_json(r, status, o);
}

void http_reply_err(http_req *r, const arbor_err *e)
{
    switch (e->status) {
    case ARBOR_ERR_NOT_FOUND: http_reply_error(r, 404, "not_found", "%s", e->msg); break;
    case ARBOR_ERR_EXISTS: http_reply_error(r, 409, "conflict", "%s", e->msg); break;
    case ARBOR_ERR_NOSPACE: http_reply_error(r, 507, "insufficient_memory", "%s", e->msg); break;
    case ARBOR_ERR_NOMEM: http_reply_error(r, 507, "insufficient_memory", "%s", e->msg); break;
    case ARBOR_ERR_CANCELLED: http_reply_error(r, 503, "busy", "%s", e->msg); break;
    case ARBOR_ERR_PARSE:
    case ARBOR_ERR_INVALID: http_reply_error(r, 400, "bad_request", "%s", e->msg); break;
    default: http_reply_error(r, 500, "internal", "%s", e->msg); break;
    }
}

void http_reply_header(http_req *r, const char *name, const char *value)
{
    if (r->response != NULL)
        MHD_add_response_header(r->response, name, value);
}

/* ---- request records ---- */

void http_req_release(http_req *r)
{
    if (r == NULL || atomic_fetch_sub(&r->refs, 1) != 1)
        return;
    if (r->response != NULL)
        MHD_destroy_response(r->response);
    free(r->body);
    free(r->url);
    free(r);
}

void http_suspend(http_req *r)
{
    arbor_server *s = r->srv;
    atomic_fetch_add(&r->refs, 1);
    pthread_mutex_lock(&s->lock);
    s->inflight++;
    pthread_mutex_unlock(&s->lock);
    r->suspended = true;
    MHD_suspend_connection(r->conn);
}

void http_resume(http_req *r)
{
    arbor_server *s = r->srv;
    MHD_resume_connection(r->conn);
    pthread_mutex_lock(&s->lock);
    if (--s->inflight == 0)
        pthread_cond_broadcast(&s->idle);
    pthread_mutex_unlock(&s->lock);
    http_req_release(r);
}

void http_queue(http_req *r, void (*run)(void *ctx, uint32_t task), void (*release)(void *ctx), void *ctx)
{
    arbor_err e;
    arbor_job *job = arbor_job_new(1, run, NULL, release, ctx, &e);
    if (job == NULL) {
        release(ctx);
        http_reply_error(r, 507, "insufficient_memory", "out of memory");
        http_resume(r);
        return;
    }
    if (!arbor_pool_submit(r->srv->pool, job, &e)) {
        arbor_job_release(job); /* releases ctx: before r is resumed, which may let the server go */
        http_reply_stopping(r);
        http_resume(r);
        return;
    }
    arbor_job_release(job);
}

const char *http_arg(http_req *r, const char *key)
{
    return MHD_lookup_connection_value(r->conn, MHD_GET_ARGUMENT_KIND, key);
}

#define ARGS_KNOWN_MAX 8

typedef struct {
    const char *known;
    const char *unknown;                 /* the first key not in known */
    const char *twice;                   /* the first key given twice */
    const char *bare;                    /* the first key given without '=' and a value */
    const char *seen[ARGS_KNOWN_MAX];    /* the keys so far, each once */
    uint32_t nseen;
} args_check;

static enum MHD_Result arg_known(void *cls, enum MHD_ValueKind kind, const char *key, const char *value)
{
    (void)kind;
    args_check *c = cls;
    size_t n = strlen(key);
    bool plain = n > 0 && strcspn(key, ", ") == n; /* a key holding a separator would match across two */
    const char *at = c->known;
    while (plain && (at = strstr(at, key)) != NULL && !((at == c->known || at[-1] == ' ') &&
                                                         (at[n] == ',' || at[n] == '\0')))
        at += n;
    if (!plain || at == NULL) {
        c->unknown = key;
        return MHD_NO;
    }
    for (uint32_t i = 0; i < c->nseen; i++)
        if (strcmp(c->seen[i], key) == 0) {
            c->twice = key; /* the route would read the first and drop the other */
            return MHD_NO;
        }
    assert(c->nseen < ARGS_KNOWN_MAX); /* known names fewer keys, each seen once */
    c->seen[c->nseen++] = key;
    if (value == NULL) {
        c->bare = key; /* "?replace" would read as absent: false, not the true it looks like */
        return MHD_NO;
    }
    return MHD_YES;
}

bool http_args_known(http_req *r, const char *known)
{
    args_check c = {.known = known};
    MHD_get_connection_values(r->conn, MHD_GET_ARGUMENT_KIND, arg_known, &c);
    if (c.unknown != NULL && known[0] == '\0')
        http_reply_error(r, 400, "bad_request", "unknown query parameter '%s': %s %.*s takes none", c.unknown,
                         r->method, (int)strcspn(r->url, "?"), r->url); /* the path: r->url keeps the query */
    else if (c.unknown != NULL)
        http_reply_error(r, 400, "bad_request", "unknown query parameter '%s' (%s)", c.unknown, known);
    else if (c.twice != NULL)
        http_reply_error(r, 400, "bad_request", "%s is given twice", c.twice);
    else if (c.bare != NULL)
        http_reply_error(r, 400, "bad_request", "%s needs a value (%s=...)", c.bare, c.bare);
    return c.unknown == NULL && c.twice == NULL && c.bare == NULL;
}

bool http_arg_flag(http_req *r, const char *key, bool *ok)
{
    const char *v = http_arg(r, key);
    if (v == NULL || strcmp(v, "0") == 0 || strcmp(v, "false") == 0)
        return false;
    if (strcmp(v, "1") == 0 || strcmp(v, "true") == 0)
        return true;
    http_reply_error(r, 400, "bad_request", "%s must be 1, true, 0 or false, not '%s'", key, v);
    *ok = false;
    return false;
}

bool http_method_is(http_req *r, const char *m)
{
    return strcmp(r->method, m) == 0;
}

void http_method_not_allowed(http_req *r, const char *allow)
{
    http_reply_error(r, 405, "method_not_allowed", "%s is not allowed on %.*s (allowed: %s)", r->method,
                     (int)strcspn(r->url, "?"), r->url, allow);
    http_reply_header(r, MHD_HTTP_HEADER_ALLOW, allow);
}

/* Compares in time independent of where the strings differ. */
static bool same_secret(const char *a, const char *b)
{
    size_t la = strlen(a), lb = strlen(b);
    unsigned char diff = (unsigned char)(la != lb);
    for (size_t i = 0; i < la; i++)
        diff |= (unsigned char)(a[i] ^ b[i % (lb ? lb : 1)]);
    return diff == 0;
}

bool http_may_write(http_req *r)
{
    arbor_server *s = r->srv;
    if (s->token == NULL) {
        if (s->loopback)
            return true;
        http_reply_error(r, 403, "forbidden",
                         "changes are refused on a non-loopback address without --token-file");
        return false;
    }
    const char *auth = MHD_lookup_connection_value(r->conn, MHD_HEADER_KIND, MHD_HTTP_HEADER_AUTHORIZATION);
    if (auth != NULL && strncasecmp(auth, "Bearer ", 7) == 0 && same_secret(auth + 7, s->token))
        return true;
    http_reply_error(r, 401, "unauthorized", "this request changes state: send Authorization: Bearer <token>");
    http_reply_header(r, MHD_HTTP_HEADER_WWW_AUTHENTICATE, "Bearer");
    return false;
}

/* Keys an object of a body may have: the API's have fewer than 32, and the
 * check for a key given twice is quadratic in them. */
#define JSON_KEYS_MAX 64

/* Whether every object in j, at any depth, has at most JSON_KEYS_MAX keys,
 * none of them twice (cJSON keeps every copy, and a route would read one of
 * them silently); else why, in err. */
static bool json_keys_once(const cJSON *j, char *err, size_t cap)
{
    uint32_t n = 0;
    for (const cJSON *v = j->child; v != NULL; v = v->next, n++) {
        if (cJSON_IsObject(j)) {
            if (n == JSON_KEYS_MAX) {
                snprintf(err, cap, "an object has more than %d keys", JSON_KEYS_MAX);
                return false;
            }
            for (const cJSON *w = j->child; w != v; w = w->next)
                if (strcmp(w->string, v->string) == 0) {
                    snprintf(err, cap, "%.64s is given twice", v->string);
                    return false;
                }
        }
        if (!json_keys_once(v, err, cap))
            return false;
    }
    return true;
}

cJSON *http_body_json(http_req *r)
{
    if (r->body_len == 0) {
        http_reply_error(r, 400, "bad_request", "a JSON object body is required");
        return NULL;
    }
    const char *nul = memchr(r->body, '\0', r->body_len);
    if (nul != NULL) { /* JSON has no raw NUL; cJSON would end a string at it */
        http_reply_error(r, 400, "bad_request", "malformed JSON body: a NUL byte at byte %zu", (size_t)(nul - r->body));
        return NULL;
    }
    const char *end = NULL;
    cJSON *j = cJSON_ParseWithLengthOpts(r->body, r->body_len, &end, false);
    /* cJSON stops after the first value; anything but white space after it
     * is as malformed as a broken value. */
    while (j != NULL && end < r->body + r->body_len && (*end == ' ' || *end == '\n' || *end == '\r' || *end == '\t'))
        end++;
    if (j != NULL && end != r->body + r->body_len) {
        cJSON_Delete(j);
        http_reply_error(r, 400, "bad_request", "malformed JSON body: trailing data at byte %zu",
                         (size_t)(end - r->body));
        return NULL;
    }
    if (j == NULL) {
        size_t at = end != NULL && end >= r->body ? (size_t)(end - r->body) : 0;
        http_reply_error(r, 400, "bad_request", "malformed JSON body near byte %zu", at);
        return NULL;
    }
    char why[128];
    if (!cJSON_IsObject(j)) {
        cJSON_Delete(j);
        http_reply_error(r, 400, "bad_request", "the JSON body must be an object");
        return NULL;
    }
    if (!json_keys_once(j, why, sizeof why)) {
        cJSON_Delete(j);
        http_reply_error(r, 400, "bad_request", "%s", why);
        return NULL;
    }
    return j;
}

/* Ready: every model loaded and every prebuilt tree built. Lock held. */
bool server_ready_locked(const arbor_server *s)
{
    return s->loaded && s->npending == 0 && !s->stopping;
}

void http_reply_stopping(http_req *r)
{
    http_reply_error(r, 503, "busy", "the daemon is shutting down");
}

bool http_ready_for_frames(http_req *r)
{
    arbor_server *s = r->srv;
    pthread_mutex_lock(&s->lock);
    bool ready = server_ready_locked(s);
    uint32_t pending = s->npending;
    pthread_mutex_unlock(&s->lock);
    if (!ready) {
        http_reply_error(r, 503, "busy", "the daemon is %s (%u models or trees pending; /readyz says when it is ready)",
                         atomic_load(&s->closing) ? "shutting down" : "loading", (unsigned)pending);
        http_reply_header(r, "Retry-After", "1");
    }
    return ready;
}

