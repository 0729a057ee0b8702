/*
 * sync.c - models in a folder that several daemons share (docs/SCALE.md).
 *
 * Every daemon of a cluster serves the same first --models folder, and an
 * upload through any of them is written there atomically (models.c). The
 * files are the truth, and a file's version is its identity
 * (arbor_file_stamp: inode, size, modification time; a rename gives
 * each upload a new inode). Before a route uses a model it asks sync_model,
 * which compares the store's model with the folder:
 *   - a model the store does not know, or whose file is not the one it was
 *     read from, is loaded from the folder on the pool while the request is
 *     suspended; the request is then dispatched again and finds it;
 *   - a model whose file is gone (deleted through another daemon) is
 *     unloaded and answered 404.
 * However many requests wait for one name, it is loaded once.
 *
 * A file that fails to load is remembered with its stamp (a sync_bad) and
 * not read again until it changes: GET /api/models lists the others, and a
 * request for that name is answered the load's error (a model the store had
 * under that name, from an older file, is unloaded: the daemons sharing the
 * folder must not answer two versions). A load that failed for another
 * reason than the file's contents (memory, a read error) is tried again
 * after SYNC_RETRY_MS, since its cause may have passed meanwhile.
 *
 * The checks are stat(2) calls on the polling thread (metadata only: no
 * file is read there; a name without NAME.EXT, which may be a renamed
 * file's, also stats the folder, whose entries are read again only when it
 * has changed: sync_odd); reading and parsing happen on the pool. GET
 * /api/models alone reads the folder's entries each time, to find the
 * files other daemons added: one readdir and a stat per model.
 */
#include <dirent.h>
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>

#include "arbor/load.h"
#include "arbor/sys.h"
#include "folder.h"
#include "http.h"

/* Loads one request may wait for: GET /api/models loads new models one per
 * round, and a file rewritten while it loads costs another round. Past
 * this the request takes the store as it is. */
#define SYNC_ROUNDS_MAX 32

typedef struct waiter {
    http_req *r;
    struct waiter *next;
} waiter;

struct sync_load {
    arbor_server *srv;
    char name[ARBOR_MODEL_NAME_MAX + 1];
    char path[PATH_MAX];
    uint64_t stamp;           /* of path, taken before reading it */
    waiter *waiters;          /* protected by srv->lock */
    struct sync_load *next;   /* srv->loads, protected by srv->lock */
};

/* How long a load that failed for memory or I/O stands before it is tried
 * again. */
#define SYNC_RETRY_MS 5000.0

struct sync_bad {
    char name[ARBOR_MODEL_NAME_MAX + 1];
    uint64_t stamp;           /* of its file when it failed */
    double retry_ms;          /* arbor_now_ms() from which it is read again */
    arbor_err err;
    struct sync_bad *next;    /* srv->bad, protected by srv->lock */
};

/* SYNC_BAD: the folder's file failed to load and has not changed since. */
typedef enum { SYNC_CURRENT, SYNC_LOAD, SYNC_GONE, SYNC_BAD } sync_state;


/* Whether a folder entry is a model file, and its model's name. */
static bool entry_name(const char *file, char *name, size_t cap)
{
    return file[0] != '.' && arbor_model_name_of_file(file, name, cap) && arbor_model_name_valid(name);
}

static int64_t ns_of(struct timespec t)
{
    return (int64_t)t.tv_sec * 1000000000 + t.tv_nsec;
}

/* The folder's renamed files now into *o: false when it cannot be read or
 * memory runs out (the caller then finds none). A folder without renamed
 * files allocates nothing. */
static bool odd_read(const char *dir, int64_t mtime_ns, sync_odd *o)
{
    memset(o, 0, sizeof *o);
    DIR *d = opendir(dir);
    struct timespec now;
    clock_gettime(CLOCK_REALTIME, &now);
    struct dirent *ent;
    char name[ARBOR_MODEL_NAME_MAX + 1];
    uint32_t cap = 0;
    bool ok = d != NULL;
    while (ok && (ent = readdir(d)) != NULL) {
        if (arbor_model_file_rank(ent->d_name) < ARBOR_MODEL_NEXTS || !entry_name(ent->d_name, name, sizeof name))
            continue;
        if (o->n == cap) {
            cap = cap ? 2 * cap : 16;
            void *grown = realloc(o->files, cap * sizeof *o->files);
            ok = grown != NULL;
            if (ok)
                o->files = grown;
        }
        if (ok) {
            snprintf(o->files[o->n].file, sizeof o->files[0].file, "%s", ent->d_name);
            snprintf(o->files[o->n++].name, sizeof o->files[0].name, "%s", name);
        }
    }
    if (d != NULL)
        closedir(d);
    if (!ok) {
        free(o->files);
        memset(o, 0, sizeof *o);
        return false;
    }
    o->read = true;
    o->mtime_ns = mtime_ns;
    o->read_ns = ns_of(now);
    return true;
}

/* The renamed file of model `name` (the lowest arbor_model_file_rank, then
 * the first by name) into first; false when there is none. */
static bool odd_file(arbor_server *s, const char *dir, const char *name, char *first, size_t cap)
{
    struct stat st;
    if (stat(dir, &st) != 0)
        return false;
    int64_t mtime = ns_of(st.st_mtim);
    pthread_mutex_lock(&s->lock);
    /* a read within a second of the folder's last change may have missed
     * an entry made in the same tick of a coarse clock: read again */
    bool current = s->odd.read && s->odd.mtime_ns == mtime && s->odd.read_ns - mtime > 1000000000;
    pthread_mutex_unlock(&s->lock);
    if (!current) {
        sync_odd fresh;
        odd_read(dir, mtime, &fresh);
        pthread_mutex_lock(&s->lock);
        free(s->odd.files);
        s->odd = fresh;
        pthread_mutex_unlock(&s->lock);
    }
    int best = -1;
    first[0] = '\0';
    pthread_mutex_lock(&s->lock);
    for (uint32_t i = 0; i < s->odd.n; i++) {
        const char *file = s->odd.files[i].file;
        int rank = arbor_model_file_rank(file);
        if (strcmp(s->odd.files[i].name, name) == 0 &&
            (best < 0 || rank < best || (rank == best && strcmp(file, first) < 0))) {
            best = rank;
            snprintf(first, cap, "%s", file);
        }
    }
    pthread_mutex_unlock(&s->lock);
    return best >= 0;
}

/* The file of model `name` in the shared folder and its stamp, if any:
 * NAME.EXT, by the order of arbor_model_exts, or else the file whose name
 * was changed to make that name or whose extension is in upper case, as the
 * daemon chose at start (arbor_model_file_rank: "rose+vase.obj" for
 * rose_vase, "Box.OBJ" for Box), from the cached read of the folder. */
static bool folder_file(arbor_server *s, const char *name, char *path, size_t cap, uint64_t *stamp)
{
    const char *dir = s->config.upload_dir;
    for (size_t i = 0; dir != NULL && i < ARBOR_MODEL_NEXTS; i++) {
        snprintf(path, cap, "%s/%s%s", dir, name, arbor_model_exts[i]);
        if ((*stamp = arbor_file_stamp(path)) != 0)
            return true;
    }
    char first[NAME_MAX + 1];
    if (dir == NULL || !odd_file(s, dir, name, first, sizeof first))
        return false;
    snprintf(path, cap, "%s/%s", dir, first);
    return (*stamp = arbor_file_stamp(path)) != 0;
}

/* What the folder says of `name`, whose model in the store is m (NULL:
 * none). For SYNC_LOAD, path and *stamp are the file to read. The shared
 * folder's file comes first; a model read from another --models folder is
 * compared with its own file. */
static sync_state compare(arbor_server *s, const char *name, arbor_model *m, char *path, size_t cap,
                          uint64_t *stamp)
{
    uint64_t known = m != NULL ? arbor_model_stamp(m) : 0;
    if (m != NULL && known == 0)
        return SYNC_CURRENT; /* not read from a file this daemon tracks */
    if (folder_file(s, name, path, cap, stamp))
        return known == *stamp ? SYNC_CURRENT : SYNC_LOAD;
    if (m == NULL || (*stamp = arbor_file_stamp(arbor_model_file(m))) == 0)
        return SYNC_GONE;
    snprintf(path, cap, "%s", arbor_model_file(m));
    return known == *stamp ? SYNC_CURRENT : SYNC_LOAD;
}

bool sync_exists(arbor_server *s, const char *name)
{
    char path[PATH_MAX];
    uint64_t stamp;
    arbor_model *m = arbor_store_acquire_model(s->store, name);
    bool exists = compare(s, name, m, path, sizeof path, &stamp) != SYNC_GONE;
    arbor_model_release(m);
    return exists;
}

/* ---- files that failed to load ---- */

/* The link to name's record in s->bad, or to the list's end (lock held). */
static sync_bad **bad_find(arbor_server *s, const char *name)
{
    sync_bad **p = &s->bad;
    while (*p != NULL && strcmp((*p)->name, name) != 0)
        p = &(*p)->next;
    return p;
}

/* Remembers that l's file failed with e, in place of what was known of its
 * name; false when that cannot be had (out of memory). */
static bool bad_remember(const sync_load *l, const arbor_err *e)
{
    arbor_server *s = l->srv;
    sync_bad *b = calloc(1, sizeof *b);
    if (b == NULL)
        return false;
    snprintf(b->name, sizeof b->name, "%s", l->name);
    b->stamp = l->stamp;
    /* what the file holds fails until it changes; anything else (memory,
     * a read error, a permission the operator then mends) may pass later */
    bool lasting = e->status == ARBOR_ERR_PARSE || e->status == ARBOR_ERR_INVALID;
    b->retry_ms = lasting ? INFINITY : arbor_now_ms() + SYNC_RETRY_MS;
    b->err = *e;
    pthread_mutex_lock(&s->lock);
    sync_bad **p = bad_find(s, l->name), *old = *p;
    if (old != NULL) {
        *p = old->next;
        free(old);
    }
    b->next = s->bad;
    s->bad = b;
    pthread_mutex_unlock(&s->lock);
    return true;
}

/* Whether name's file at stamp is known to fail (its error in *e); a
 * record of another stamp, or past its retry time, is dropped. */
static bool bad_known(arbor_server *s, const char *name, uint64_t stamp, arbor_err *e)
{
    pthread_mutex_lock(&s->lock);
    sync_bad **p = bad_find(s, name), *b = *p;
    bool known = b != NULL && b->stamp == stamp && arbor_now_ms() < b->retry_ms;
    if (known) {
        *e = b->err;
    } else if (b != NULL) {
        *p = b->next;
        free(b);
    }
    pthread_mutex_unlock(&s->lock);
    return known;
}

void sync_forget(arbor_server *s)
{
    free(s->odd.files);
    memset(&s->odd, 0, sizeof s->odd);
    while (s->bad != NULL) {
        sync_bad *b = s->bad;
        s->bad = b->next;
        free(b);
    }
}

/* Answers r with the error its model's file failed to load with. */
static void bad_reply(http_req *r, const char *name, const char *path, const arbor_err *e)
{
    if (e->status == ARBOR_ERR_NOSPACE || e->status == ARBOR_ERR_NOMEM)
        http_reply_err(r, e);
    else
        http_reply_error(r, 500, "bad_model_file", "model '%s' cannot be loaded from %s: %s", name, path, e->msg);
}

/* ---- loading, on a worker ---- */

static void load_answer(sync_load *l, bool ok, const arbor_err *e)
{
    arbor_server *s = l->srv;
    /* A file replaced or deleted while it was read (another request, or
     * another daemon, changed the folder) is no fault of the file: the
     * waiters look again and find what is there now. A file that fails is
     * remembered, and the waiters look again too: a listing then passes it
     * by, and a request for it gets its error (settle). Remembered before
     * the load leaves s->loads, so that no request between starts it again. */
    bool changed = !ok && arbor_file_stamp(l->path) != l->stamp;
    bool remembered = !ok && !changed && e->status != ARBOR_ERR_CANCELLED && bad_remember(l, e);
    pthread_mutex_lock(&s->lock);
    for (sync_load **p = &s->loads; *p != NULL; p = &(*p)->next)
        if (*p == l) {
            *p = l->next;
            break;
        }
    waiter *w = l->waiters;
    l->waiters = NULL;
    pthread_mutex_unlock(&s->lock);
    while (w != NULL) {
        waiter *next = w->next;
        if (ok || changed || remembered)
            w->r->redispatch = true;
        else if (e->status == ARBOR_ERR_CANCELLED)
            http_reply_err(w->r, e);
        else
            bad_reply(w->r, l->name, l->path, e);
        http_resume(w->r);
        free(w);
        w = next;
    }
}

static void load_run(void *ctx, uint32_t task)
{
    (void)task;
    sync_load *l = ctx;
    arbor_server *s = l->srv;
    arbor_mesh mesh;
    arbor_mesh_init(&mesh);
    arbor_err err;
    arbor_err_clear(&err);
    uint64_t version = 0;
    size_t cap = s->config.max_upload > ARBOR_LOAD_MAX_BYTES ? (size_t)s->config.max_upload : ARBOR_LOAD_MAX_BYTES;
    bool ok = arbor_load_model_capped(l->path, cap, &mesh, &err) &&
              arbor_store_add_model(s->store, l->name, l->path, &mesh, ARBOR_ADD_REPLACE,
                                    &version, &err);
    arbor_mesh_free(&mesh);
    arbor_model *m = ok ? arbor_store_acquire_model(s->store, l->name) : NULL;
    if (m != NULL && arbor_model_version(m) == version)
        arbor_model_set_stamp(m, l->stamp);
    arbor_model_release(m);
    load_answer(l, ok, &err);
}

static void load_free(void *ctx)
{
    free(ctx);
}

/* Suspends r until `name` is loaded from path (started here unless a load
 * of that name is already on its way). */
static void load_async(http_req *r, const char *name, const char *path, uint64_t stamp)
{
    arbor_server *s = r->srv;
    waiter *w = malloc(sizeof *w);
    sync_load *fresh = calloc(1, sizeof *fresh);
    arbor_err e;
    arbor_job *job = fresh != NULL ? arbor_job_new(1, load_run, NULL, load_free, fresh, &e) : NULL;
    if (w == NULL || job == NULL) {
        free(w);
        if (job == NULL)
            free(fresh);
        arbor_job_release(job);
        http_reply_error(r, 507, "insufficient_memory", "out of memory loading model '%s'", name);
        return;
    }
    fresh->srv = s;
    snprintf(fresh->name, sizeof fresh->name, "%s", name);
    snprintf(fresh->path, sizeof fresh->path, "%s", path);
    fresh->stamp = stamp;
    r->sync_rounds++;
    http_suspend(r);
    w->r = r;
    pthread_mutex_lock(&s->lock);
    sync_load *l = s->loads;
    while (l != NULL && strcmp(l->name, name) != 0)
        l = l->next;
    bool start = l == NULL;
    if (start) {
        l = fresh;
        l->next = s->loads;
        s->loads = l;
    }
    w->next = l->waiters;
    l->waiters = w;
    pthread_mutex_unlock(&s->lock);
    if (start && !arbor_pool_submit(s->pool, job, &e)) {
        arbor_err busy;
        arbor_fail(&busy, ARBOR_ERR_CANCELLED, "the daemon is shutting down");
        load_answer(l, false, &busy);
    }
    arbor_job_release(job); /* frees `fresh` when it was not needed */
}

/* ---- the lookups ---- */

static void unload(arbor_server *s, arbor_model *m)
{
    arbor_err err;
    /* Only the model that was checked: one added meanwhile (an upload here)
     * has a file, and the next request sees it. */
    arbor_store_remove_this_model(s->store, m, &err);
}

/* Acts on compare's verdict for one name whose model in the store is m:
 * SYNC_CURRENT (m is what the folder holds), SYNC_GONE (there is no such
 * model now; m, if any, was unloaded), SYNC_LOAD (r is suspended for the
 * load, or answered when it could not start) or SYNC_BAD (the folder's file
 * is known to fail: its error in *bad, its path in bad_path; m, if any, was
 * unloaded). */
static sync_state settle(http_req *r, const char *name, arbor_model *m, arbor_err *bad, char *bad_path, size_t cap)
{
    char path[PATH_MAX];
    uint64_t stamp = 0;
    sync_state st = compare(r->srv, name, m, path, sizeof path, &stamp);
    if (st == SYNC_LOAD && bad_known(r->srv, name, stamp, bad)) {
        snprintf(bad_path, cap, "%s", path);
        /* what this daemon had loaded is not what the folder holds now: the
         * others answer the new file, so this one cannot answer the old */
        if (m != NULL)
            unload(r->srv, m);
        st = SYNC_BAD;
    }
    if (st == SYNC_LOAD && r->sync_rounds >= SYNC_ROUNDS_MAX)
        st = m != NULL ? SYNC_CURRENT : SYNC_GONE; /* the folder keeps changing: take what is here */
    if (st == SYNC_LOAD)
        load_async(r, name, path, stamp);
    else if (st == SYNC_GONE && m != NULL)
        unload(r->srv, m);
    return st;
}

bool sync_name_valid(http_req *r, const char *name)
{
    if (arbor_model_name_valid(name))
        return true;
    http_reply_error(r, 400, "bad_request", "'%s' is no model name: names are " ARBOR_MODEL_NAME_RULE, name);
    return false;
}

arbor_model *sync_model(http_req *r, const char *name)
{
    /* The name makes a path in the folder: "../x" would read files outside it. */
    if (!sync_name_valid(r, name))
        return NULL;
    arbor_model *m = arbor_store_acquire_model(r->srv->store, name);
    arbor_err bad;
    char path[PATH_MAX];
    sync_state st = settle(r, name, m, &bad, path, sizeof path);
    if (st == SYNC_CURRENT && m != NULL)
        return m;
    arbor_model_release(m);
    if (st == SYNC_BAD)
        bad_reply(r, name, path, &bad);
    else if (st != SYNC_LOAD)
        http_reply_error(r, 404, "not_found", "no model named '%s'", name);
    return NULL;
}

bool sync_models(http_req *r)
{
    arbor_server *s = r->srv;
    arbor_model **models;
    uint32_t n;
    arbor_err bad; /* a file that fails to load is left out of the listing */
    if (!arbor_store_list_models(s->store, &models, &n, &bad)) {
        http_reply_err(r, &bad);
        return false;
    }
    bool current = true;
    char path[PATH_MAX];
    for (uint32_t i = 0; i < n; i++) {
        current = current && settle(r, arbor_model_name(models[i]), models[i], &bad, path, sizeof path) != SYNC_LOAD;
        arbor_model_release(models[i]);
    }
    free(models);
    DIR *d = current && s->config.upload_dir != NULL ? opendir(s->config.upload_dir) : NULL;
    struct dirent *ent;
    char name[ARBOR_MODEL_NAME_MAX + 1];
    while (d != NULL && current && (ent = readdir(d)) != NULL) {
        if (!entry_name(ent->d_name, name, sizeof name))
            continue;
        arbor_model *m = arbor_store_acquire_model(s->store, name);
        if (m == NULL)
            current = settle(r, name, NULL, &bad, path, sizeof path) != SYNC_LOAD;
        arbor_model_release(m);
    }
    if (d != NULL)
        closedir(d);
    return current;
}
