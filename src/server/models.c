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
    if (u->model[0] != '\0' && is_model_name(name)) {
        /* it would become a model of the folder, past the checks a model's name gets */
        snprintf(u->error, sizeof u->error, "an upload holds one model file: '%s' is a second, after '%s'", name,
                 u->model);
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
    char path[PATH_MAX];
    bool replace;
    bool replaced;
} upload_job;

/* What a model file holds, read through gzip when it is compressed:
 * whether it is PLY, and whether it is text at all (an OBJ has no NUL in
 * its first bytes, a PLY starts "ply"). Its decompressed size is counted up
 * to max + 1, so a small .gz that inflates past the limit is caught here,
 * before any parsing. Replies and returns false when the file is unusable. */
static bool sniff_model(http_req *r, const char *path, uint64_t max, bool *ply, bool *gz)
{
    gzFile g = gzopen(path, "rb");
    if (g == NULL) {
        http_reply_error(r, 507, "insufficient_memory", "cannot read the stored upload");
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
        http_reply_error(r, 507, "insufficient_memory", "cannot rename the stored upload");
        return false;
    }
    return true;
}

/* ---- saving into the models folder ---- */

/* Copies src to dir/name through a temporary file and a rename, so that a
 * daemon reading the folder never sees half a file. */
static bool save_file(const char *src, const char *dir, const char *name, char *err, size_t errcap)
{
    char tmp[PATH_MAX], dst[PATH_MAX];
    snprintf(tmp, sizeof tmp, "%s/.%s.XXXXXX", dir, name);
    snprintf(dst, sizeof dst, "%s/%s", dir, name);
    int fd = mkstemp(tmp);
    FILE *in = fopen(src, "rb"), *out = fd >= 0 ? fdopen(fd, "wb") : NULL;
    bool ok = in != NULL && out != NULL;
    char buf[65536];
    size_t n;
    while (ok && (n = fread(buf, 1, sizeof buf, in)) > 0)
        ok = fwrite(buf, 1, n, out) == n;
    ok = ok && !ferror(in);
    if (in != NULL)
        fclose(in);
    if (out != NULL)
        ok = (fclose(out) == 0) && ok;
    else if (fd >= 0)
        close(fd);
    ok = ok && rename(tmp, dst) == 0;
    if (!ok) {
        int errnum = errno;
        if (fd >= 0)
            unlink(tmp);
        char why[128] = "write failed";
        strerror_r(errnum, why, sizeof why);
        snprintf(err, errcap, "cannot save %s in %s: %s", name, dir, why);
    }
    return ok;
}

static const char *const model_exts[] = {".obj", ".ply", ".obj.gz", ".ply.gz"};

/* The model's extension, from the stored part's name. */
static const char *model_ext(const char *file)
{
    for (int i = 3; i >= 0; i--)
        if (ends_with(file, model_exts[i]))
            return model_exts[i];
    return ".obj";
}

/* ---- what an upload owns in the folder ----
 *
 * An upload of NAME records the files it wrote into the folder in
 * ".NAME.upload" (a dot file: the folder's scan skips it, sync.c), one file
 * name a line: the model file and the material libraries that came with it.
 * DELETE removes the files the record names and the record, through any
 * daemon sharing the folder, so a file the operator put there is never
 * removed. An upload writes no file of the folder that its name's record
 * does not hold: a material library already there with other bytes is a
 * conflict (another model's, or the operator's), and one with the same
 * bytes is left as it is and not taken over. The record is written before
 * the files it names, so a DELETE that comes between finds them all. */

#define OWNED_MAX (UPLOAD_FILES_MAX + 1)

typedef struct {
    char file[OWNED_MAX][NAME_MAX + 1];
    uint32_t n;
} owned_files;

static void record_path(const char *dir, const char *name, char *path, size_t cap)
{
    snprintf(path, cap, "%s/.%s.upload", dir, name);
}

static bool owned_has(const owned_files *o, const char *file)
{
    for (uint32_t i = 0; i < o->n; i++)
        if (strcmp(o->file[i], file) == 0)
            return true;
    return false;
}

/* The record of name's upload, empty when there is none; lines that are no
 * plain file name of the folder are ignored (the record is ours, but the
 * folder is shared). */
static void owned_read(const char *dir, const char *name, owned_files *o)
{
    char path[PATH_MAX], line[NAME_MAX + 2];
    record_path(dir, name, path, sizeof path);
    o->n = 0;
    FILE *f = fopen(path, "r");
    while (f != NULL && o->n < OWNED_MAX && fgets(line, sizeof line, f) != NULL) {
        size_t len = strcspn(line, "\n");
        if (len > 0 && len <= NAME_MAX && line[0] != '.' && memchr(line, '/', len) == NULL) {
            memcpy(o->file[o->n], line, len);
            o->file[o->n++][len] = '\0';
        }
    }
    if (f != NULL)
        fclose(f);
}

/* Removes from dir the files of o that keep (may be NULL) does not have. */
static void owned_unlink(const char *dir, const owned_files *o, const owned_files *keep)
{
    char path[PATH_MAX];
    for (uint32_t i = 0; i < o->n; i++)
        if (keep == NULL || !owned_has(keep, o->file[i])) {
            snprintf(path, sizeof path, "%s/%s", dir, o->file[i]);
            unlink(path);
        }
}

/* Removes the files of name's upload and its record: a model the operator
 * put in the folder has none, and keeps its file. */
static void owned_remove(const char *dir, const char *name)
{
    owned_files o;
    char path[PATH_MAX];
    owned_read(dir, name, &o);
    owned_unlink(dir, &o, NULL);
    record_path(dir, name, path, sizeof path);
    unlink(path);
}

/* Writes o as name's upload record in dir, through stage (a folder of
 * ours) and save_file. */
static bool owned_write(const char *dir, const char *name, const owned_files *o, const char *stage, char *err,
                        size_t errcap)
{
    char tmp[PATH_MAX], record[PART_NAME_MAX + 16];
    snprintf(tmp, sizeof tmp, "%s/.upload", stage);
    snprintf(record, sizeof record, ".%s.upload", name);
    FILE *f = fopen(tmp, "w");
    bool ok = f != NULL;
    for (uint32_t i = 0; ok && i < o->n; i++)
        ok = fprintf(f, "%s\n", o->file[i]) > 0;
    ok = (f != NULL && fclose(f) == 0) && ok;
    if (!ok) {
        snprintf(err, errcap, "cannot store the upload's record");
        return false;
    }
    return save_file(tmp, dir, record, err, errcap);
}

/* Whether files a and b hold the same bytes. */
static bool same_bytes(const char *a, const char *b)
{
    FILE *fa = fopen(a, "rb"), *fb = fopen(b, "rb");
    bool same = fa != NULL && fb != NULL;
    char ba[8192], bb[8192];
    while (same) {
        size_t na = fread(ba, 1, sizeof ba, fa), nb = fread(bb, 1, sizeof bb, fb);
        same = na == nb && memcmp(ba, bb, na) == 0;
        if (na < sizeof ba)
            break;
    }
    if (fa != NULL)
        fclose(fa);
    if (fb != NULL)
        fclose(fb);
    return same;
}

/* Saves the upload into dir: the model as NAME.EXT (the other extensions of
 * NAME removed, so the folder holds one file of that name), the material
 * libraries under their own names, and the record of what it wrote (the
 * files an earlier upload of NAME wrote and this one does not are
 * removed). *conflict is set, and nothing written, when a material library
 * would overwrite a file that is not NAME's. */
static bool save_upload(const upload_parts *u, const char *dir, const char *name, char *file, size_t cap,
                        bool *conflict, char *err, size_t errcap)
{
    char src[PATH_MAX], dst[PATH_MAX], final[PART_NAME_MAX + 16];
    const char *ext = model_ext(u->model);
    snprintf(final, sizeof final, "%s%s", name, ext);
    owned_files before, now = {.n = 0};
    owned_read(dir, name, &before);
    snprintf(now.file[now.n++], sizeof now.file[0], "%s", final);
    /* which parts to write, before writing any */
    DIR *d = opendir(u->dir);
    struct dirent *ent;
    *conflict = false;
    while (d != NULL && !*conflict && (ent = readdir(d)) != NULL) {
        if (ent->d_name[0] == '.' || strcmp(ent->d_name, u->model) == 0)
            continue;
        snprintf(src, sizeof src, "%s/%s", u->dir, ent->d_name);
        snprintf(dst, sizeof dst, "%s/%s", dir, ent->d_name);
        struct stat st;
        bool taken = lstat(dst, &st) == 0 && !owned_has(&before, ent->d_name);
        if (taken && !same_bytes(src, dst)) {
            *conflict = true;
            snprintf(err, errcap,
                     "'%s' is in the models folder already, with other contents, and no upload of '%s' wrote "
                     "it: give the file another name (and the .obj's mtllib line) and upload again",
                     ent->d_name, name);
        } else if (!taken && now.n < OWNED_MAX) {
            snprintf(now.file[now.n++], sizeof now.file[0], "%s", ent->d_name);
        }
    }
    if (d != NULL)
        closedir(d);
    if (d == NULL || *conflict) {
        if (d == NULL)
            snprintf(err, errcap, "cannot read the stored upload");
        return false;
    }
    bool ok = owned_write(dir, name, &now, u->dir, err, errcap);
    /* the material libraries, then the model: a daemon that loads the model
     * finds its materials */
    for (uint32_t i = now.n; ok && i-- > 0;) {
        snprintf(src, sizeof src, "%s/%s", u->dir, i == 0 ? u->model : now.file[i]);
        ok = save_file(src, dir, now.file[i], err, errcap);
    }
    if (ok) {
        owned_unlink(dir, &before, &now);
        for (int i = 0; i < 4; i++)
            if (strcmp(model_exts[i], ext) != 0) {
                snprintf(src, sizeof src, "%s/%s%s", dir, name, model_exts[i]);
                unlink(src);
            }
    }
    snprintf(file, cap, "%s/%s", dir, final);
    return ok;
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
    char file[PATH_MAX], why[PATH_MAX + 128];
    uint64_t version = 0, stamp = 0;
    unsigned flags = j->replace ? ARBOR_ADD_REPLACE : 0;
    bool conflict = false;
    bool loaded = arbor_load_model_capped(j->path, s->config.max_upload, &mesh, &err);
    for (uint32_t i = 0; i < mesh.nwarnings; i++)
        strip_dir(mesh.warnings[i], r->parts->dir);
    if (!loaded) {
        strip_dir(err.msg, r->parts->dir);
        if (err.status == ARBOR_ERR_NOMEM)
            http_reply_err(r, &err);
        else
            http_reply_error(r, 400, "bad_request", "%s", err.msg);
    } else if (!save_upload(r->parts, s->config.upload_dir, j->name, file, sizeof file, &conflict, why,
                            sizeof why)) {
        if (!conflict && !j->replaced)
            owned_remove(s->config.upload_dir, j->name); /* what was written of it */
        http_reply_error(r, conflict ? 409 : 507, conflict ? "conflict" : "insufficient_storage", "%s", why);
    } else if ((stamp = arbor_file_stamp(file)) == 0) { /* taken at once: what sync.c compares */
        /* A DELETE of the name came between the rename and now: it is the
         * later change, and this upload is gone with it. */
        http_reply_error(r, 409, "conflict", "model '%s' was deleted as it was added", j->name);
    } else if (!arbor_store_add_model(s->store, j->name, file, &mesh, flags, &version, &err)) {
        /* A new model refused (no room) leaves no file: the daemons sharing
         * the folder would load it, and a restart too. */
        if (!j->replaced)
            owned_remove(s->config.upload_dir, j->name);
        http_reply_err(r, &err);
    } else {
        arbor_model *m = arbor_store_acquire_model(s->store, j->name);
        if (m != NULL && arbor_model_version(m) == version)
            arbor_model_set_stamp(m, stamp);
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
    if (http_method_is(r, "PUT") && !name_put_body(r, name))
        return;
    if (u->model[0] == '\0') {
        http_reply_error(r, 400, "bad_request", "the upload has no .obj, .ply, .obj.gz or .ply.gz file part");
        return;
    }
    char part[sizeof u->dir + PART_NAME_MAX + 2];
    snprintf(part, sizeof part, "%s/%s", u->dir, u->model);
    bool ply, gz;
    if (http_method_is(r, "POST") && !sniff_model(r, part, r->srv->config.max_upload, &ply, &gz))
        return;
    /* It exists when this daemon has it or the shared folder does (uploaded
     * through another daemon). */
    arbor_model *old = arbor_store_acquire_model(r->srv->store, name);
    bool exists = old != NULL || sync_in_folder(r->srv, name);
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
    arbor_model *m = sync_model(r, name);
    if (m == NULL)
        return;
    arbor_model_release(m);
    arbor_err err;
    if (!arbor_store_remove_model(r->srv->store, name, &err)) {
        http_reply_err(r, &err);
        return;
    }
    /* An uploaded model's files go with it, or the next start would load it
     * again, and so would the other daemons sharing the folder (sync.c); a
     * model the operator put in the folder keeps its file (and is loaded
     * again by the next request for it). */
    if (r->srv->config.upload_dir != NULL)
        owned_remove(r->srv->config.upload_dir, name);
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "deleted", name);
    http_reply_json(r, 200, o);
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
    if (r->route == ROUTE_TREES)
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
