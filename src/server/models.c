/*
 * models.c - /api/models/{name}: reading one, uploading (PUT of a file,
 * POST of multipart/form-data with an .obj and its .mtl files), replacing
 * and deleting; and the routes below a model (trees, boxes).
 *
 * An upload streams to a private temporary folder as it arrives (so a large
 * model never sits in memory twice), then a pool worker loads it with the
 * same loaders as the command line, adds it to the store, answers and
 * removes the folder. The folder gives .mtl files a place to resolve
 * against, and the loaders' containment check keeps them in it.
 */
#include <dirent.h>
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <unistd.h>
#include <zlib.h>

#include "arbor/load.h"
#include "http.h"

#define UPLOAD_FILES_MAX 16
#define PART_NAME_MAX 128

typedef struct upload_parts {
    char dir[64];                 /* the temporary folder */
    FILE *out;                    /* the part being written */
    char out_name[PART_NAME_MAX]; /* its file name in dir */
    char model[PART_NAME_MAX];    /* the .obj / .ply part, "" until seen */
    uint32_t nfiles;
    char error[256];              /* what went wrong while receiving, for the final answer */
} upload_parts;

/* ---- receiving ---- */

static bool parts_open_dir(http_req *r)
{
    upload_parts *u = calloc(1, sizeof *u);
    if (u == NULL)
        return false;
    snprintf(u->dir, sizeof u->dir, "/tmp/arbord-upload-XXXXXX");
    if (mkdtemp(u->dir) == NULL) {
        free(u);
        return false;
    }
    r->parts = u;
    return true;
}

void models_parts_free(http_req *r)
{
    upload_parts *u = r->parts;
    if (u == NULL)
        return;
    if (u->out != NULL)
        fclose(u->out);
    DIR *d = opendir(u->dir);
    if (d != NULL) {
        struct dirent *ent;
        char path[sizeof u->dir + 260];
        while ((ent = readdir(d)) != NULL)
            if (strcmp(ent->d_name, ".") != 0 && strcmp(ent->d_name, "..") != 0) {
                snprintf(path, sizeof path, "%s/%s", u->dir, ent->d_name);
                unlink(path);
            }
        closedir(d);
    }
    rmdir(u->dir);
    free(u);
    r->parts = NULL;
}

static bool ends_with(const char *s, const char *suffix)
{
    size_t n = strlen(s), k = strlen(suffix);
    return n >= k && strcasecmp(s + n - k, suffix) == 0;
}

static bool is_model_name(const char *f)
{
    return ends_with(f, ".obj") || ends_with(f, ".ply") || ends_with(f, ".obj.gz") || ends_with(f, ".ply.gz");
}

/* A part's file name as a safe base name: the last path component, of
 * [A-Za-z0-9._-] only and not starting with '.'; false when nothing is left. */
static bool safe_base_name(const char *filename, char *out, size_t cap)
{
    const char *base = strrchr(filename, '/');
    base = base != NULL ? base + 1 : filename;
    size_t n = 0;
    for (const char *p = base; *p != '\0' && n + 1 < cap; p++) {
        char c = *p;
        bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '.' ||
                  c == '_' || c == '-';
        out[n++] = ok ? c : '_';
    }
    out[n] = '\0';
    return n > 0 && out[0] != '.';
}

static bool part_start(upload_parts *u, const char *name)
{
    if (u->out != NULL)
        fclose(u->out);
    u->out = NULL;
    if (u->nfiles == UPLOAD_FILES_MAX) {
        snprintf(u->error, sizeof u->error, "at most %d files in one upload", UPLOAD_FILES_MAX);
        return false;
    }
    char path[256];
    snprintf(u->out_name, sizeof u->out_name, "%s", name);
    snprintf(path, sizeof path, "%s/%s", u->dir, name);
    u->out = fopen(path, "wbx");
    if (u->out == NULL) {
        snprintf(u->error, sizeof u->error, "cannot store part '%s': %s", name,
                 errno == EEXIST ? "two parts have that file name" : "write failed");
        return false;
    }
    u->nfiles++;
    if (u->model[0] == '\0' && is_model_name(name))
        snprintf(u->model, sizeof u->model, "%s", name);
    return true;
}

static bool part_write(upload_parts *u, const char *data, size_t size)
{
    if (size > 0 && fwrite(data, 1, size, u->out) != size) {
        snprintf(u->error, sizeof u->error, "cannot store part '%s': disk full or write failed", u->out_name);
        return false;
    }
    return true;
}

static enum MHD_Result on_part(void *cls, enum MHD_ValueKind kind, const char *key, const char *filename,
                               const char *content_type, const char *transfer_encoding, const char *data,
                               uint64_t off, size_t size)
{
    (void)kind;
    (void)key;
    (void)content_type;
    (void)transfer_encoding;
    upload_parts *u = cls;
    if (filename == NULL)
        return MHD_YES; /* a plain form field: not ours */
    if (off == 0) {
        char name[PART_NAME_MAX];
        if (!safe_base_name(filename, name, sizeof name)) {
            snprintf(u->error, sizeof u->error, "part file name '%.64s' is not usable", filename);
            return MHD_NO;
        }
        if (!part_start(u, name))
            return MHD_NO;
    }
    return part_write(u, data, size) ? MHD_YES : MHD_NO;
}

bool models_post_data(http_req *r, const char *data, size_t size)
{
    if (r->parts == NULL) {
        if (!parts_open_dir(r)) {
            http_reply_error(r, 507, "insufficient_memory", "cannot make a temporary folder for the upload");
            return false;
        }
        bool put = http_method_is(r, "PUT");
        if (!put) {
            r->post = MHD_create_post_processor(r->conn, 64 * 1024, on_part, r->parts);
            if (r->post == NULL) {
                http_reply_error(r, 415, "unsupported_media_type",
                                 "POST of a model takes multipart/form-data (PUT takes the file itself)");
                return false;
            }
        } else if (!part_start(r->parts, "upload.bin")) {
            http_reply_error(r, 507, "insufficient_memory", "%s", r->parts->error);
            return false;
        }
    }
    r->body_len += size;
    bool ok = r->post != NULL ? MHD_post_process(r->post, data, size) == MHD_YES : part_write(r->parts, data, size);
    if (!ok)
        http_reply_error(r, 400, "bad_request", "%s",
                         r->parts->error[0] ? r->parts->error : "malformed multipart/form-data body");
    return ok;
}

/* ---- loading, on a worker ---- */

typedef struct {
    http_req *http;
    char name[ARBOR_MODEL_NAME_MAX + 1];
    char path[256];
    bool replace;
    bool replaced;
} upload_job;

/* A PUT body's format, from its first bytes (decompressed when gzip): the
 * file name the loaders dispatch on. */
static bool name_put_body(upload_parts *u, const char *name, char *err, size_t errcap)
{
    char from[256], to[256], head[4] = {0};
    snprintf(from, sizeof from, "%s/upload.bin", u->dir);
    gzFile g = gzopen(from, "rb");
    bool gz = false;
    int got = -1;
    if (g != NULL) {
        gz = gzdirect(g) == 0;
        got = gzread(g, head, sizeof head);
        gzclose(g);
    }
    if (got < 0) {
        snprintf(err, errcap, "cannot read the uploaded file (corrupt gzip?)");
        return false;
    }
    bool ply = got == 4 && memcmp(head, "ply", 3) == 0 && (head[3] == '\n' || head[3] == '\r');
    snprintf(u->model, sizeof u->model, "%s.%s%s", name, ply ? "ply" : "obj", gz ? ".gz" : "");
    snprintf(to, sizeof to, "%s/%s", u->dir, u->model);
    if (rename(from, to) != 0) {
        snprintf(err, errcap, "cannot rename the uploaded file");
        return false;
    }
    return true;
}

/* Loader messages name the temporary path; people know the file by its
 * upload name. */
static void strip_dir(char *msg, const char *dir)
{
    size_t n = strlen(dir);
    char *at;
    while ((at = strstr(msg, dir)) != NULL) {
        size_t skip = n + (at[n] == '/' ? 1 : 0);
        memmove(at, at + skip, strlen(at + skip) + 1);
    }
}

static void upload_run(void *ctx, uint32_t task)
{
    (void)task;
    upload_job *j = ctx;
    http_req *r = j->http;
    arbor_server *s = r->srv;
    arbor_mesh mesh;
    arbor_mesh_init(&mesh);
    arbor_err err;
    arbor_err_clear(&err);
    uint64_t version = 0;
    bool ok = arbor_load_model_capped(j->path, s->config.max_upload, &mesh, &err);
    if (!ok) {
        strip_dir(err.msg, r->parts->dir);
        http_reply_error(r, 400, "bad_request", "%s", err.msg);
    } else if (!arbor_store_add_model(s->store, j->name, "(upload)", &mesh, j->replace, &version, &err)) {
        http_reply_err(r, &err);
    } else {
        arbor_model *m = arbor_store_acquire_model(s->store, j->name);
        if (m != NULL) {
            http_reply_json(r, j->replaced ? 200 : 201, model_json(s, m));
            arbor_model_release(m);
        } else {
            http_reply_error(r, 409, "conflict", "model '%s' was deleted as it was added", j->name);
        }
    }
    arbor_mesh_free(&mesh);
    models_parts_free(r);
    http_resume(r);
}

static void upload_free(void *ctx)
{
    free(ctx);
}

static bool replace_asked(http_req *r)
{
    const char *v = http_arg(r, "replace");
    return v != NULL && (strcmp(v, "1") == 0 || strcmp(v, "true") == 0);
}

static void upload(http_req *r, const char *name)
{
    upload_parts *u = r->parts;
    if (u == NULL || r->body_len == 0) {
        http_reply_error(r, 400, "bad_request", "the upload is empty");
        return;
    }
    if (u->out != NULL && fclose(u->out) != 0) {
        u->out = NULL;
        http_reply_error(r, 507, "insufficient_memory", "cannot store the upload: disk full or write failed");
        return;
    }
    u->out = NULL;
    char err[256];
    if (http_method_is(r, "PUT") && !name_put_body(u, name, err, sizeof err)) {
        http_reply_error(r, 400, "bad_request", "%s", err);
        return;
    }
    if (u->model[0] == '\0') {
        http_reply_error(r, 400, "bad_request", "the upload has no .obj, .ply, .obj.gz or .ply.gz file part");
        return;
    }
    arbor_model *old = arbor_store_acquire_model(r->srv->store, name);
    bool exists = old != NULL;
    arbor_model_release(old);
    if (exists && !replace_asked(r)) {
        http_reply_error(r, 409, "conflict", "model '%s' exists (replace it with ?replace=1)", name);
        return;
    }
    upload_job *j = calloc(1, sizeof *j);
    arbor_err e;
    arbor_job *job = j != NULL ? arbor_job_new(1, upload_run, NULL, upload_free, j, &e) : NULL;
    if (job == NULL) {
        free(j);
        http_reply_error(r, 507, "insufficient_memory", "out of memory");
        return;
    }
    j->http = r;
    snprintf(j->name, sizeof j->name, "%s", name);
    snprintf(j->path, sizeof j->path, "%s/%s", u->dir, u->model);
    j->replace = replace_asked(r);
    j->replaced = exists;
    http_suspend(r);
    if (!arbor_pool_submit(r->srv->pool, job, &e)) {
        http_reply_error(r, 503, "busy", "the daemon is shutting down");
        http_resume(r);
    }
    arbor_job_release(job);
}

/* ---- the routes ---- */

static void delete_model(http_req *r, const char *name)
{
    if (!http_may_write(r))
        return;
    arbor_err err;
    if (!arbor_store_remove_model(r->srv->store, name, &err)) {
        http_reply_err(r, &err);
        return;
    }
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "deleted", name);
    http_reply_json(r, 200, o);
}

static void get_model(http_req *r, const char *name)
{
    arbor_model *m = arbor_store_acquire_model(r->srv->store, name);
    if (m == NULL) {
        http_reply_error(r, 404, "not_found", "no model named '%s'", name);
        return;
    }
    http_reply_json(r, 200, model_json(r->srv, m));
    arbor_model_release(m);
}

/* rest is "/trees" or "/trees/{accel}/{builder}/boxes". */
static void below_model(http_req *r, const char *name, const char *rest)
{
    arbor_model *m = arbor_store_acquire_model(r->srv->store, name);
    if (m == NULL) {
        http_reply_error(r, 404, "not_found", "no model named '%s'", name);
        return;
    }
    char accel[16], builder[16];
    if (r->route == ROUTE_TREES)
        route_tree_build(r, m);
    else if (sscanf(rest, "/trees/%15[^/]/%15[^/]/boxes", accel, builder) == 2)
        route_boxes(r, m, accel, builder);
    else
        http_reply_error(r, 404, "not_found", "no such endpoint: %s", r->url);
    arbor_model_release(m);
}

void route_models(http_req *r, const char *name, const char *rest)
{
    if (rest[0] != '\0') {
        below_model(r, name, rest);
        return;
    }
    if (http_method_is(r, "GET") || http_method_is(r, "HEAD"))
        get_model(r, name);
    else if (http_method_is(r, "DELETE"))
        delete_model(r, name);
    else if (http_method_is(r, "PUT") || http_method_is(r, "POST")) {
        if (http_may_write(r))
            upload(r, name);
    } else
        http_method_not_allowed(r, "GET, HEAD, PUT, POST, DELETE");
}
