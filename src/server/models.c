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
#define _XOPEN_SOURCE 700 /* realpath, beyond the build's _POSIX_C_SOURCE */
#include <dirent.h>
#include <limits.h>
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>
#include <unistd.h>
#include <zlib.h>

#include "arbor/load.h"
#include "arbor/sys.h"
#include "folder.h"
#include "http.h"

#define UPLOAD_FILES_MAX 16
#define PART_NAME_MAX 128

typedef struct upload_parts {
    char dir[PATH_MAX / 2];       /* the temporary folder */
    DIR *listing;                 /* dir, opened with it (models_parts_free) */
    FILE *out;                    /* the part being written */
    char out_name[PART_NAME_MAX]; /* its file name in dir */
    uint64_t out_bytes;           /* written of it so far */
    char model[PART_NAME_MAX];    /* the .obj / .ply part, "" until seen */
    uint32_t nfiles;
    char error[256];              /* what went wrong while receiving, for the final answer */
    bool full;                    /* error is the temporary folder's disk being full */
} upload_parts;

/* ---- receiving ---- */

/* The parts are received into a temporary folder of their own, in TMPDIR
 * as other programs' temporary files are (/tmp without it). */
static bool parts_open_dir(http_req *r)
{
    upload_parts *u = calloc(1, sizeof *u);
    if (u == NULL)
        return false;
    const char *tmp = getenv("TMPDIR");
    if (tmp == NULL || tmp[0] != '/')
        tmp = "/tmp";
    int n = snprintf(u->dir, sizeof u->dir, "%s/arbord-upload-XXXXXX", tmp);
    bool fits = n >= 0 && (size_t)n < sizeof u->dir;
    if (!fits || mkdtemp(u->dir) == NULL) {
        int why = fits ? errno : ENAMETOOLONG; /* for the caller's message, past free */
        free(u);
        errno = why;
        return false;
    }
    u->listing = opendir(u->dir);
    if (u->listing == NULL) {
        int why = errno;
        rmdir(u->dir);
        free(u);
        errno = why;
        return false;
    }
    r->parts = u;
    return true;
}

/* Closes the part being written; false (u->error set) when what was
 * buffered of it cannot be written. */
static bool part_close(upload_parts *u)
{
    bool ok = u->out == NULL || fclose(u->out) == 0;
    if (!ok) {
        u->full = true;
        snprintf(u->error, sizeof u->error, "cannot store part '%s' in the temporary folder: %s", u->out_name,
                 strerror(errno));
    }
    u->out = NULL;
    return ok;
}

void models_parts_free(http_req *r)
{
    if (r->post != NULL) { /* it writes into the parts */
        MHD_destroy_post_processor(r->post);
        r->post = NULL;
    }
    upload_parts *u = r->parts;
    if (u == NULL)
        return;
    part_close(u);
    /* The listing was opened with the folder: reading it again allocates
     * nothing, so the upload's files go even when memory has run out (an
     * opendir here failed then, and left them in TMPDIR: test_alloc_fail). */
    rewinddir(u->listing);
    struct dirent *ent;
    char path[sizeof u->dir + 260];
    while ((ent = readdir(u->listing)) != NULL)
        if (strcmp(ent->d_name, ".") != 0 && strcmp(ent->d_name, "..") != 0) {
            snprintf(path, sizeof path, "%s/%s", u->dir, ent->d_name);
            unlink(path);
        }
    closedir(u->listing);
    rmdir(u->dir);
    free(u);
    r->parts = NULL;
}

/* A part's file name as a safe base name: the last path component, of
 * [A-Za-z0-9._-] only and not starting with '.'; false when nothing is left. */
static bool safe_base_name(const char *filename, char *out, size_t cap)
{
    const char *base = strrchr(filename, '/');
    base = base != NULL ? base + 1 : filename;
    size_t n = 0;
    for (const char *p = base; *p != '\0' && n + 1 < cap; p++) {
        out[n++] = arbor_model_name_char(*p) ? *p : '_';
    }
    out[n] = '\0';
    return n > 0 && out[0] != '.';
}

static bool part_start(upload_parts *u, const char *name)
{
    if (!part_close(u))
        return false;
    if (u->nfiles == UPLOAD_FILES_MAX) {
        snprintf(u->error, sizeof u->error, "at most %d files in one upload", UPLOAD_FILES_MAX);
        return false;
    }
    if (u->model[0] != '\0' && folder_is_model_file(name)) {
        /* it would become a model of the folder, past the checks a model's name gets */
        snprintf(u->error, sizeof u->error, "an upload holds one model file: '%s' is a second, after '%s'", name,
                 u->model);
        return false;
    }
    char path[sizeof u->dir + PART_NAME_MAX + 2];
    snprintf(u->out_name, sizeof u->out_name, "%s", name);
    u->out_bytes = 0;
    snprintf(path, sizeof path, "%s/%s", u->dir, name);
    u->out = fopen(path, "wbx");
    if (u->out == NULL) {
        u->full = errno != EEXIST;
        snprintf(u->error, sizeof u->error, "cannot store part '%s': %s", name,
                 errno == EEXIST ? "two parts have that file name" : strerror(errno));
        return false;
    }
    u->nfiles++;
    if (u->model[0] == '\0' && folder_is_model_file(name))
        snprintf(u->model, sizeof u->model, "%s", name);
    return true;
}

static bool part_write(upload_parts *u, const char *data, size_t size)
{
    u->out_bytes += size;
    if (size > 0 && fwrite(data, 1, size, u->out) != size) {
        u->full = true;
        snprintf(u->error, sizeof u->error, "cannot store part '%s' in the temporary folder: %s", u->out_name,
                 strerror(errno));
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
        if (!folder_is_model_file(name) && !folder_is_material_file(name)) {
            /* it would be written into the models folder, for no model */
            snprintf(u->error, sizeof u->error,
                     "part '%s' is neither a model file (.obj, .ply, either .gz) nor a material library (.mtl)",
                     name);
            return MHD_NO;
        }
        /* libmicrohttpd calls with offset 0 twice for one part when the
         * first read after its headers holds only a few bytes of it (the
         * first call then has none): that part goes on */
        bool same = u->out != NULL && u->out_bytes == 0 && strcmp(u->out_name, name) == 0;
        if (!same && !part_start(u, name))
            return MHD_NO;
    }
    return part_write(u, data, size) ? MHD_YES : MHD_NO;
}

bool models_post_data(http_req *r, const char *data, size_t size)
{
    if (r->parts == NULL) {
        if (!parts_open_dir(r)) {
            http_reply_error(r, 507, "insufficient_storage", "cannot make a temporary folder for the upload: %s",
                             strerror(errno));
            return false;
        }
        bool put = http_method_is(r, "PUT");
        const char *type = MHD_lookup_connection_value(r->conn, MHD_HEADER_KIND, MHD_HTTP_HEADER_CONTENT_TYPE);
        bool multipart = type != NULL && strncasecmp(type, "multipart/form-data", 19) == 0;
        if (put && multipart) {
            /* it would be saved as the model, boundaries and part headers in its text */
            http_reply_error(r, 415, "unsupported_media_type",
                             "PUT takes the model file itself: POST a multipart/form-data body");
            return false;
        }
        if (!put) {
            /* libmicrohttpd would read a form (curl -d's default type) too */
            r->post = multipart ? MHD_create_post_processor(r->conn, 64 * 1024, on_part, r->parts) : NULL;
            if (r->post == NULL) {
                http_reply_error(r, 415, "unsupported_media_type",
                                 "POST of a model takes multipart/form-data (PUT takes the file itself)");
                return false;
            }
        } else if (!part_start(r->parts, "upload.bin")) {
            http_reply_error(r, 507, "insufficient_storage", "%s", r->parts->error);
            return false;
        }
    }
    r->body_len += size;
    bool ok = r->post != NULL ? MHD_post_process(r->post, data, size) == MHD_YES : part_write(r->parts, data, size);
    if (!ok && r->parts->full)
        http_reply_error(r, 507, "insufficient_storage", "%s", r->parts->error);
    else if (!ok)
        http_reply_error(r, 400, "bad_request", "%s",
                         r->parts->error[0] ? r->parts->error : "malformed multipart/form-data body");
    return ok;
}

/* ---- loading, on a worker ---- */

/* A change of the models folder: an upload or a DELETE of model `name`.
 * They run one at a time, in the order they arrived (folder_line). */
struct folder_task {
    arbor_server *srv;
    http_req *http;
    void (*run)(folder_task *t); /* the change: answers t->http, which task_run then resumes */
    char name[ARBOR_MODEL_NAME_MAX + 1];
    bool replace;                /* an upload's ?replace */
    bool ran;                    /* task_run has handed the line on */
    folder_task *next;           /* in srv->folder_waiting */
};

/* The path of the upload's model part. */
static const char *path_of_part(const upload_parts *u, char *path, size_t cap)
{
    snprintf(path, cap, "%s/%s", u->dir, u->model);
    return path;
}

/* What a model file holds, read through gzip when it is compressed:
 * whether it is PLY, and whether it is text at all (an OBJ has no NUL in
 * its first bytes, a PLY starts "ply"). Its decompressed size is counted up
 * to max + 1, so a small .gz that inflates past the limit is caught here,
 * before any parsing. Replies and returns false when the file is unusable. */
static bool sniff_model(http_req *r, const char *path, uint64_t max, bool *ply, bool *gz)
{
    gzFile g = gzopen(path, "rb");
    if (g == NULL) {
        http_reply_error(r, 507, "insufficient_storage", "cannot read the stored upload: %s", strerror(errno));
        return false;
    }
    *gz = gzdirect(g) == 0;
    char buf[65536];
    uint64_t total = 0;
    int got;
    bool text = true;
    *ply = false;
    while ((got = gzread(g, buf, sizeof buf)) > 0 && total <= max) {
        if (total == 0) {
            *ply = got >= 4 && memcmp(buf, "ply", 3) == 0 && (buf[3] == '\n' || buf[3] == '\r');
            text = *ply || memchr(buf, '\0', (size_t)(got < 512 ? got : 512)) == NULL;
        }
        total += (uint64_t)got;
    }
    int zerr = Z_OK;
    gzerror(g, &zerr);
    bool broken = got < 0;
    gzclose(g);
    if (broken && zerr == Z_MEM_ERROR) {
        http_reply_error(r, 507, "insufficient_memory", "out of memory reading the upload");
        return false;
    }
    if (broken) {
        http_reply_error(r, 400, "bad_request", "the upload is not valid gzip data");
        return false;
    }
    if (total > max) {
        http_reply_error(r, 413, "too_large", "the upload decompresses to more than the limit of %llu bytes",
                         (unsigned long long)max);
        return false;
    }
    if (!text) {
        http_reply_error(r, 415, "unsupported_media_type", "the upload is neither OBJ nor PLY (nor gzip of one)");
        return false;
    }
    return true;
}

/* Names a PUT body by its format, the name the loaders dispatch on. */
static bool name_put_body(http_req *r, const char *name)
{
    upload_parts *u = r->parts;
    char from[sizeof u->dir + 16], to[sizeof u->dir + PART_NAME_MAX + 2];
    snprintf(from, sizeof from, "%s/upload.bin", u->dir);
    bool ply, gz;
    if (!sniff_model(r, from, r->srv->config.max_upload, &ply, &gz))
        return false;
    snprintf(u->model, sizeof u->model, "%s.%s%s", name, ply ? "ply" : "obj", gz ? ".gz" : "");
    snprintf(to, sizeof to, "%s/%s", u->dir, u->model);
    if (rename(from, to) != 0) {
        http_reply_error(r, 507, "insufficient_storage", "cannot rename the stored upload: %s", strerror(errno));
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

/* The store takes an upload's model once the folder's plan holds and
 * before any file is written (folder.h): a model the store has no room for
 * (507) leaves the folder as it was, the files of the model it would have
 * replaced included. */
typedef struct {
    arbor_store *store;
    const char *name;
    arbor_mesh *mesh;
    bool admitted;
    uint64_t version;
    arbor_err err;
} upload_admit;

static bool admit_upload(void *ctx, const char *file)
{
    upload_admit *a = ctx;
    a->admitted = arbor_store_add_model(a->store, a->name, file, a->mesh, ARBOR_ADD_REPLACE, &a->version, &a->err);
    return a->admitted;
}

/* Saves the loaded upload into the folder and adds it to the store, with
 * the folder's lock held: an upload or DELETE of the same name, through
 * this daemon or another, comes wholly before or after. Replies. */
static void upload_publish(folder_task *j, arbor_mesh *mesh)
{
    http_req *r = j->http;
    arbor_server *s = r->srv;
    const char *dir = s->config.upload_dir;
    char file[PATH_MAX], why[PATH_MAX + 256];
    bool exists = sync_exists(s, j->name), filed = false;
    upload_admit a = {.store = s->store, .name = j->name, .mesh = mesh};
    folder_result saved = FOLDER_FAILED;
    uint64_t stamp = 0;
    if (exists && !j->replace) {
        http_reply_error(r, 409, "conflict", "model '%s' exists (replace it with ?replace=1)", j->name);
    } else if ((saved = folder_save_upload(dir, j->name, r->parts->dir, r->parts->model, admit_upload, &a, file,
                                           sizeof file, why, sizeof why)) == FOLDER_REFUSED) {
        http_reply_err(r, &a.err);
    } else if (saved != FOLDER_SAVED) {
        http_reply_error(r, saved == FOLDER_CONFLICT ? 409 : 507,
                         saved == FOLDER_CONFLICT ? "conflict" : "insufficient_storage", "%s", why);
    } else if ((stamp = arbor_file_stamp(file)) == 0) { /* taken at once: what sync.c compares */
        http_reply_error(r, 409, "conflict", "model '%s' was removed from the folder as it was added", j->name);
    } else {
        arbor_model *m = arbor_store_acquire_model(s->store, j->name);
        if (m != NULL && arbor_model_version(m) == a.version)
            arbor_model_set_stamp(m, stamp);
        if (m != NULL)
            http_reply_json(r, exists ? 200 : 201, model_json(s, m));
        else
            http_reply_error(r, 409, "conflict", "model '%s' was deleted as it was added", j->name);
        arbor_model_release(m);
        filed = true;
    }
    if (a.admitted && !filed) {
        /* The store holds a model whose file is not in the folder: it goes,
         * and the next request for the name loads what the folder has. */
        arbor_err gone;
        arbor_store_remove_model(s->store, j->name, &gone);
    }
    if (saved == FOLDER_FAILED && !exists)
        folder_remove_upload(dir, j->name); /* what was written of it */
}

/* The answer to a change of the folder whose lock was not had: 503 while
 * another holds it (worth a retry), 507 when it cannot be had at all. */
static void folder_lock_refused(http_req *r, folder_lock_result why_not, const char *why)
{
    if (why_not == FOLDER_LOCK_BUSY) {
        http_reply_error(r, 503, "busy", "%s", why);
        http_reply_header(r, "Retry-After", "1");
    } else {
        http_reply_error(r, 507, "insufficient_storage", "%s", why);
    }
}

/* Copies into the upload's temporary folder the material libraries its
 * model names and did not send that the models folder has, so that it loads
 * with the materials every daemon finds beside it in the folder, and its
 * save records them as used (folder.h: no DELETE of another model then
 * removes them). Returns how many it copied. */
static uint32_t stage_folder_libraries(upload_parts *u, const char *dir, const arbor_mesh *m)
{
    uint32_t copied = 0;
    char src[PATH_MAX], why[PATH_MAX + 128];
    char *real_dir = dir != NULL && m->nmissing_libraries > 0 ? realpath(dir, NULL) : NULL;
    struct stat st;
    for (uint32_t i = 0; real_dir != NULL && i < m->nmissing_libraries; i++) {
        const char *lib = m->missing_libraries[i];
        snprintf(src, sizeof src, "%s/%s", dir, lib);
        /* the loader's rule: a library is read only where its real path,
         * links resolved, lies inside the model's folder */
        char *real = lib[0] != '.' && folder_is_material_file(lib) ? realpath(src, NULL) : NULL;
        if (real != NULL && arbor_real_path_inside(real, real_dir) && stat(real, &st) == 0 &&
            S_ISREG(st.st_mode) && u->nfiles < UPLOAD_FILES_MAX && folder_copy_file(u->dir, lib, real, why, sizeof why)) {
            u->nfiles++;
            copied++;
        }
        free(real);
    }
    free(real_dir);
    return copied;
}

/* Loads the upload's model from its temporary folder, with the libraries
 * stage_folder_libraries adds when it adds any. */
static bool load_staged(upload_parts *u, const char *path, const arbor_server *s, arbor_mesh *mesh, arbor_err *err)
{
    if (!arbor_load_model_capped(path, s->config.max_upload, mesh, err))
        return false;
    if (stage_folder_libraries(u, s->config.upload_dir, mesh) == 0)
        return true;
    arbor_mesh_free(mesh);
    return arbor_load_model_capped(path, s->config.max_upload, mesh, err);
}

static void upload_run(folder_task *j)
{
    http_req *r = j->http;
    arbor_server *s = r->srv;
    upload_parts *u = r->parts;
    arbor_mesh mesh;
    arbor_mesh_init(&mesh);
    arbor_err err;
    arbor_err_clear(&err);
    char path[sizeof u->dir + PART_NAME_MAX + 2], why[PATH_MAX + 128];
    bool ply, gz;
    int lock;
    folder_lock_result locked;
    if (http_method_is(r, "PUT") ? !name_put_body(r, j->name) : !sniff_model(r, path_of_part(u, path, sizeof path),
                                                                           s->config.max_upload, &ply, &gz)) {
        /* answered */
    } else if (!load_staged(u, path_of_part(u, path, sizeof path), s, &mesh, &err)) {
        strip_dir(err.msg, u->dir);
        if (err.status == ARBOR_ERR_NOMEM)
            http_reply_err(r, &err);
        else
            http_reply_error(r, 400, "bad_request", "%s", err.msg);
    } else if ((locked = folder_lock_take(s->config.upload_dir, FOLDER_LOCK_WAIT_MS, &lock, why, sizeof why)) !=
               FOLDER_LOCKED) {
        folder_lock_refused(r, locked, why);
    } else {
        for (uint32_t i = 0; i < mesh.nwarnings; i++)
            strip_dir(mesh.warnings[i], u->dir);
        upload_publish(j, &mesh);
        folder_lock_drop(lock);
    }
    arbor_mesh_free(&mesh);
    models_parts_free(r);
}

/* The changes of the folder run one at a time, in the order they arrived:
 * an upload parses its whole file into memory (eight at once took 1.4 GB
 * of a hostile gzip's faces), and each change takes a worker from the
 * frames, for as long as FOLDER_LOCK_WAIT_MS when another holds the
 * folder's lock. folder_line queues a task, or starts it when none runs;
 * line_next starts the next, from the end of task_run, or from the release
 * of a task that never ran (http_queue releases it before it resumes the
 * request). */
static void line_next(arbor_server *s);

static void task_run(void *ctx, uint32_t task)
{
    (void)task;
    folder_task *t = ctx;
    http_req *r = t->http;
    t->run(t);
    /* the next starts while r still holds the server up: once r is
     * resumed, a stopping daemon may free it */
    t->ran = true;
    line_next(t->srv);
    http_resume(r);
}

static void task_free(void *ctx)
{
    folder_task *t = ctx;
    arbor_server *s = t->srv;
    bool ran = t->ran;
    free(t);
    if (!ran)
        line_next(s);
}

static void line_next(arbor_server *s)
{
    pthread_mutex_lock(&s->lock);
    folder_task *next = s->folder_waiting;
    if (next != NULL)
        s->folder_waiting = next->next;
    else
        s->folder_busy = false;
    pthread_mutex_unlock(&s->lock);
    if (next != NULL)
        http_queue(next->http, task_run, task_free, next);
}

/* Suspends r and runs run for it in the line; 507 when out of memory. */
static void folder_line(http_req *r, void (*run)(folder_task *t), const char *name, bool replace)
{
    arbor_server *s = r->srv;
    folder_task *t = calloc(1, sizeof *t);
    if (t == NULL) {
        http_reply_error(r, 507, "insufficient_memory", "out of memory");
        return;
    }
    t->srv = s;
    t->http = r;
    t->run = run;
    snprintf(t->name, sizeof t->name, "%s", name);
    t->replace = replace;
    http_suspend(r);
    pthread_mutex_lock(&s->lock);
    bool now = !s->folder_busy;
    if (now) {
        s->folder_busy = true;
    } else {
        folder_task **end = &s->folder_waiting;
        while (*end != NULL)
            end = &(*end)->next;
        *end = t;
    }
    pthread_mutex_unlock(&s->lock);
    if (now)
        http_queue(r, task_run, task_free, t);
}

static void upload(http_req *r, const char *name)
{
    upload_parts *u = r->parts;
    bool ok = true;
    bool replace = http_arg_flag(r, "replace", &ok);
    if (!ok)
        return;
    if (u == NULL || r->body_len == 0) {
        http_reply_error(r, 400, "bad_request", "the upload is empty");
        return;
    }
    if (r->post != NULL) {
        /* MHD_NO: the body ended inside a part (no closing boundary), which
         * may be cut anywhere */
        bool whole = MHD_destroy_post_processor(r->post) == MHD_YES;
        r->post = NULL;
        if (!whole) {
            http_reply_error(r, 400, "bad_request", "the multipart body ends inside a part (no closing boundary)");
            return;
        }
    }
    if (!part_close(u)) {
        http_reply_error(r, 507, "insufficient_storage", "%s", u->error);
        return;
    }
    if (http_method_is(r, "POST") && u->model[0] == '\0') {
        http_reply_error(r, 400, "bad_request", "the upload has no .obj, .ply, .obj.gz or .ply.gz file part");
        return;
    }
    folder_line(r, upload_run, name, replace);
}

/* ---- the routes ---- */

/* Unloads the model and removes what its upload wrote, with the folder's
 * lock held (folder.h). A read-only folder holds no upload's files to
 * remove, and its models are only unloaded. In a folder that can be
 * written, a lock that cannot be taken is a 507 and the model stays: the
 * files left behind would load it again at the next request. A model of
 * the folder this daemon has not loaded (or cannot load) goes all the same. */
static void delete_run(folder_task *j)
{
    http_req *r = j->http;
    const char *dir = r->srv->config.upload_dir;
    char why[PATH_MAX + 128];
    arbor_err err;
    int lock = -1;
    folder_lock_result taken = dir != NULL ? folder_lock_take(dir, FOLDER_LOCK_WAIT_MS, &lock, why, sizeof why)
                                           : FOLDER_LOCK_FAILED;
    bool locked = taken == FOLDER_LOCKED;
    bool exists = sync_exists(r->srv, j->name); /* under the lock: as other daemons left it */
    if (taken == FOLDER_LOCK_BUSY || (dir != NULL && !locked && access(dir, W_OK) == 0)) {
        folder_lock_refused(r, taken, why);
    } else if (!arbor_store_remove_model(r->srv->store, j->name, &err) &&
               (err.status != ARBOR_ERR_NOT_FOUND || !exists)) {
        http_reply_err(r, &err);
    } else {
        /* An uploaded model's files go with it, or the next start would load
         * it again, and so would the other daemons sharing the folder
         * (sync.c); a model the operator put in the folder keeps its file
         * (and is loaded again by the next request for it). */
        if (locked)
            folder_remove_upload(dir, j->name);
        cJSON *o = cJSON_CreateObject();
        cJSON_AddStringToObject(o, "deleted", j->name);
        http_reply_json(r, 200, o);
    }
    if (locked)
        folder_lock_drop(lock);
}

static void delete_model(http_req *r, const char *name)
{
    if (!http_may_write(r))
        return;
    /* Not sync_model: a model this daemon cannot load (a broken file, or
     * one over its memory budget) is still deleted through it. */
    if (!sync_exists(r->srv, name)) {
        http_reply_error(r, 404, "not_found", "no model named '%s'", name);
        return;
    }
    folder_line(r, delete_run, name, false);
}

static void get_model(http_req *r, const char *name)
{
    arbor_model *m = sync_model(r, name);
    if (m == NULL)
        return;
    http_reply_json(r, 200, model_json(r->srv, m));
    arbor_model_release(m);
}

/* rest is "/trees" or "/trees/{accel}/{builder}/boxes". */
static void below_model(http_req *r, const char *name, const char *rest)
{
    arbor_model *m = sync_model(r, name);
    if (m == NULL)
        return;
    char accel[16], builder[16];
    int end = 0; /* where the match ended: sscanf's count ignores the literal after the last field */
    if (r->route == ROUTE_TREES && strcmp(rest, "/trees") == 0) /* classify saw only the path's end */
        route_tree_build(r, m);
    else if (sscanf(rest, "/trees/%15[^/]/%15[^/]/boxes%n", accel, builder, &end) == 2 && end > 0 &&
             rest[end] == '\0')
        route_boxes(r, m, accel, builder);
    else
        http_reply_error(r, 404, "not_found", "no such endpoint: %s", r->url);
    arbor_model_release(m);
}

void route_models(http_req *r, const char *name, const char *rest)
{
    /* the boxes read their own parameters; an upload takes ?replace */
    bool uploading = http_method_is(r, "PUT") || http_method_is(r, "POST");
    bool allowed = r->route == ROUTE_TREES ? http_method_is(r, "POST")
                                           : uploading || http_method_is(r, "GET") || http_method_is(r, "HEAD") ||
                                                 http_method_is(r, "DELETE"); /* else a 405 below */
    if (allowed && r->route != ROUTE_BOXES && !http_args_known(r, uploading && rest[0] == '\0' ? "replace" : ""))
        return;
    if (rest[0] != '\0') {
        below_model(r, name, rest);
        return;
    }
    if (http_method_is(r, "GET") || http_method_is(r, "HEAD"))
        get_model(r, name);
    else if (http_method_is(r, "DELETE"))
        delete_model(r, name);
    else if (uploading) {
        if (http_may_write(r))
            upload(r, name);
    } else
        http_method_not_allowed(r, "GET, HEAD, PUT, POST, DELETE");
}
