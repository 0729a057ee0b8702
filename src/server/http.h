/*
 * http.h - what the server's modules share: the server and request records,
 * replies, suspension, and each module's entry points. Private to
 * src/server/; the public face is include/arbor/server.h.
 *
 * A request (http_req) is reference counted: libmicrohttpd's connection holds
 * one reference until the request is completed, and asynchronous work (a
 * frame, a build, an upload, a bench job) holds one until it has replied.
 * Replying from a worker is `http_reply_*` then `http_resume`; the polling
 * thread then queues the stored response. A route handler either replies at
 * once or calls http_suspend before handing the request to a worker.
 */
#ifndef ARBOR_SERVER_HTTP_H
#define ARBOR_SERVER_HTTP_H

#include <cjson/cJSON.h>
#include <limits.h>
#include <microhttpd.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdbool.h>
#include <stdint.h>

#include "arbor/server.h"
#include "metrics.h"
#include "render_request.h"

typedef struct http_req http_req;
typedef struct render_req render_req;
typedef struct job_table job_table;
typedef struct sync_load sync_load;
typedef struct sync_bad sync_bad;
typedef struct folder_task folder_task;

/* The shared folder's files whose names were changed to make model names
 * ("rose+vase.obj", "Box.OBJ"), as read at one version of the folder (its
 * mtime): read again only when the folder has changed, so that a request
 * for a name with no NAME.EXT costs a stat of the folder, not a read of all
 * its entries (sync.c). */
typedef struct {
    bool read;                /* false: never read, or the last read failed */
    int64_t mtime_ns;         /* the folder's when read */
    int64_t read_ns;          /* the clock's when read (CLOCK_REALTIME, as mtime) */
    uint32_t n;
    struct {
        char file[NAME_MAX + 1];
        char name[ARBOR_MODEL_NAME_MAX + 1]; /* the model name it makes */
    } *files;                 /* n, malloc'd; NULL when none */
} sync_odd;


struct arbor_server {
    arbor_server_config config;
    char *token;                    /* owned copy of config.token */
    arbor_store *store;
    arbor_pool *pool;
    struct MHD_Daemon *mhd;
    struct MHD_Response *oom;       /* 507, made at start: the answer when no other can be made */
    int port;
    bool loopback;                  /* bound to a loopback address */
    double start_ms;
    http_metrics metrics;
    job_table *jobs;
    atomic_bool closing;            /* stopping, for the polling thread's answers (no lock there) */

    pthread_mutex_t lock;           /* guards everything below, down to `next_request_id` */
    pthread_cond_t idle;            /* signalled when `inflight` drops to 0 */
    char **pending;                 /* readiness: what is still loading */
    uint32_t npending;
    bool loaded, stopping;
    render_req *frames;             /* frames admitted and not yet answered (list) */
    uint32_t nframes;               /* its length: admission counts it */
    uint32_t inflight;              /* requests suspended, waiting for a worker, or in their route */
    sync_load *loads;               /* models being loaded from the shared folder (sync.c) */
    sync_bad *bad;                  /* folder files that failed to load (sync.c) */
    sync_odd odd;                   /* the folder's files whose names were changed into model names (sync.c) */
    folder_task *folder_waiting;    /* uploads and DELETEs queued behind the one running (models.c) */
    bool folder_busy;               /* one is running */
    uint64_t next_request_id;

    pthread_t reaper;               /* cancels frames past --frame-timeout */
    pthread_cond_t reaper_wake;
    bool reaper_started;
};

struct http_req {
    arbor_server *srv;
    struct MHD_Connection *conn;
    atomic_int refs;
    char id[24];
    char method[16];
    char *url;
    http_route route;
    double start_ms;

    /* the body, up to `limit` bytes */
    char *body;
    size_t body_len, body_cap, limit;
    uint64_t body_seen;              /* every body byte read, kept or not */
    bool too_large;
    bool upload;                     /* a PUT or POST of a model: the body goes to models.c */
    struct MHD_PostProcessor *post;
    struct upload_parts *parts;      /* multipart uploads (models.c) */

    /* the answer: set once, by the handler or by a worker */
    struct MHD_Response *response;
    unsigned status;
    uint64_t bytes;
    bool suspended;                  /* polling thread only */
    bool redispatch;                 /* resumed to run its route again (sync.c loaded its model) */
    uint8_t sync_rounds;             /* models loaded for it so far (sync.c) */
};

/* ---- JSON (http.c) ----
 * cJSON's AddItemToObject and AddItemToArray leave the item to the caller
 * when it cannot be added (no memory for the key, or no parent because
 * making the parent failed); these free it. Every cJSON allocation that
 * fails also marks the thread, as SQLite's mallocFailed does, so that an
 * answer missing a part is never sent: http_reply_json answers 507 instead
 * (and clears the mark). json_malloc is cJSON's allocator (the server
 * installs it); json_oom_clear drops a mark that no answer owns. */
void json_put(cJSON *object, const char *key, cJSON *item);
void json_push(cJSON *array, cJSON *item);
void *json_malloc(size_t n);
void json_oom_clear(void);

/* ---- replies (http.c) ---- */
/* The body of the server's ready-made 507 (arbor_server.oom). */
#define OOM_BODY "{\"error\":{\"code\":\"insufficient_memory\",\"message\":\"out of memory\"}}\n"
/* Stores a JSON answer (takes ownership of body). */
void http_reply_json(http_req *r, unsigned status, cJSON *body);
/* Stores {"error":{"code","message"}}. */
void http_reply_error(http_req *r, unsigned status, const char *code, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));
/* Stores the error an arbor_err maps to (404 not found, 507 no space, ...). */
void http_reply_err(http_req *r, const arbor_err *e);
/* Stores resp (taken; NULL: the server's 507 is sent) as the answer, of
 * `bytes` bytes for the access log, in place of any stored before. */
void http_reply_response(http_req *r, unsigned status, struct MHD_Response *resp, uint64_t bytes);
/* Stores a body the response frees with free(). */
void http_reply_buffer(http_req *r, unsigned status, const char *content_type, void *data, size_t len);
/* Adds a header to the stored response. */
void http_reply_header(http_req *r, const char *name, const char *value);

/* ---- suspension (http.c) ---- */
/* The handler hands r to a worker: suspends the connection and takes a
 * reference for the worker. */
void http_suspend(http_req *r);
/* The worker has replied: resumes the connection and drops its reference. */
void http_resume(http_req *r);
void http_req_release(http_req *r);
/* Hands r, already suspended (http_suspend), to a pool worker: queues a job
 * of one task, run(ctx, 0), which must reply and resume r; release(ctx)
 * frees ctx once the job is over. When the job cannot be queued r is
 * answered (507 out of memory, 503 shutting down) and resumed, and ctx
 * released. */
void http_queue(http_req *r, void (*run)(void *ctx, uint32_t task), void (*release)(void *ctx), void *ctx);

/* ---- helpers (http.c) ---- */
const char *http_arg(http_req *r, const char *key);
/* Whether every query parameter is one of `known` ("a, b, c"; "" for a
 * route that takes none), each given once; replies 400 naming the first
 * that is not. */
bool http_args_known(http_req *r, const char *known);
/* A flag parameter: absent is false, "1" and "true" true, "0" and "false"
 * false; anything else replies 400 and returns false with *ok false. */
bool http_arg_flag(http_req *r, const char *key, bool *ok);
bool http_may_write(http_req *r);   /* replies 401/403 when not */
bool http_method_is(http_req *r, const char *m);
void http_method_not_allowed(http_req *r, const char *allow);
/* The body as JSON: an object (replies 400 and returns NULL otherwise). */
cJSON *http_body_json(http_req *r);

/* ---- routes ---- */
void route_models(http_req *r, const char *name, const char *rest);  /* models.c */
void route_render(http_req *r);                                        /* render_route.c */
void route_ray(http_req *r);                                           /* inspect.c */
void route_stats(http_req *r);                                         /* stats.c */
void route_tree_build(http_req *r, arbor_model *m);                    /* stats.c */
void route_boxes(http_req *r, arbor_model *m, const char *accel, const char *builder); /* inspect.c */
void route_bench(http_req *r);                                         /* jobs.c */
void route_job(http_req *r, const char *id);                           /* jobs.c */
void route_static(http_req *r, const char *path);                      /* static.c */

/* models.c: the body of an upload, from the polling thread. */
bool models_post_data(http_req *r, const char *data, size_t size);
void models_parts_free(http_req *r);

/* render_route.c: frames in flight. frames_count wants s->lock held; the
 * others take it. */
void frames_cancel_all(arbor_server *s);
void frames_reap(arbor_server *s, double now_ms);
void frames_count(arbor_server *s, uint32_t *waiting, uint32_t *rendering);
/* Reads a render or ray request and the model it names (a reference);
 * false with the reply made, or r suspended while sync.c loads the model. */
bool render_read_request(http_req *r, bool ray, render_spec *spec, arbor_render_params *params,
                         arbor_model **model);

/* sync.c: models as the shared models folder has them. sync_model returns
 * a reference to the model `name`, or NULL when r has been answered (400:
 * no model name; 404: no such model, here or in the folder) or suspended while the model is
 * loaded from the folder, after which r's route runs again. sync_models
 * does the same for every model (GET /api/models): false when r was
 * answered or suspended. sync_exists: whether model `name` exists as the
 * folders have it: a file in the shared folder, or a model in the store
 * whose file is still there (or that came from none); a model another
 * daemon deleted does not, though this one has not unloaded it yet. */
arbor_model *sync_model(http_req *r, const char *name);
/* Whether a model name from a body or a query is one (false: 400 made). */
bool sync_name_valid(http_req *r, const char *name);
bool sync_models(http_req *r);
bool sync_exists(arbor_server *s, const char *name);
void sync_forget(arbor_server *s); /* frees the records of failed and of renamed files */

/* http.c: frames and rays are refused (503) until the daemon is ready,
 * so that a load balancer passes them to a node that is; false with the
 * answer made. server_ready_locked: ready, with s->lock held. */
bool http_ready_for_frames(http_req *r);
/* The 503 of a request the stopping daemon will not start (a new frame, job or route). */
void http_reply_stopping(http_req *r);
bool server_ready_locked(const arbor_server *s);

/* jobs.c */
job_table *jobs_create(arbor_pool *pool, arbor_store *store);
void jobs_cancel_all(job_table *t);
void jobs_destroy(job_table *t);

/* stats.c: one model as JSON (the MODEL of docs/API.md). */
cJSON *model_json(arbor_server *s, arbor_model *m);
/* Parses "bvh"/"kd" and a builder name; replies 400 when unknown. */
bool parse_tree_names(http_req *r, const char *accel, const char *builder, arbor_accel_kind *k, arbor_builder *b);

#endif
