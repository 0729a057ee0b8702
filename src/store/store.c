/*
 * store.c - models and their trees, reference counted, built once on the
 * pool, kept within a memory budget (see include/arbor/store.h).
 *
 * One mutex, s->lock, guards the model table and every tree slot. Reference
 * counts are atomics so that releasing never needs the lock, except for the
 * last release of a model or tree, which frees memory and so updates the
 * byte counters (atomics too). A slot's tree reference is handed out only
 * under the lock, so a ready tree whose count is 1 is held by the store
 * alone and may be evicted.
 *
 * A build is a one-task job on the pool. It holds a reference to its model;
 * the slot points at the build while it runs. When it ends the worker takes
 * the lock, files the tree (or the error) in the slot unless the model was
 * detached meanwhile, takes the waiters, unlocks, and calls them.
 */
#include <assert.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "arbor/store.h"

typedef struct waiter {
    arbor_tree_ready_fn fn;
    void *user;
    struct waiter *next;
} waiter;

typedef struct build build;

/* One of a model's eight trees; protected by the store's lock. */
typedef struct {
    arbor_tree_state state;
    arbor_tree *tree;     /* the store's reference, when READY */
    build *build;         /* when BUILDING */
    uint64_t last_used;   /* store tick of the last acquire, for LRU eviction */
    char error[sizeof(((arbor_err *)0)->msg)]; /* when FAILED */
} tree_slot;

struct arbor_model {
    arbor_store *store;
    atomic_int refs;
    char name[ARBOR_MODEL_NAME_MAX + 1];
    char *file;
    uint64_t version;
    uint64_t bytes;
    atomic_uint_fast64_t stamp; /* the identity of the file it was read from, 0 when not known */
    arbor_mesh mesh;
    /* protected by store->lock */
    bool detached;        /* removed or replaced: no longer listed, no new builds */
    tree_slot slots[ARBOR_ACCEL_KIND_COUNT][ARBOR_BUILDER_COUNT];
};

struct arbor_tree {
    arbor_model *model;   /* a reference: the mesh outlives the tree */
    arbor_accel *accel;
    atomic_int refs;
    uint64_t bytes;
};

struct build {
    arbor_store *store;
    arbor_model *model;   /* a reference */
    arbor_accel_kind kind;
    arbor_builder builder;
    uint64_t reserved;    /* estimate counted in s->reserved while building */
    atomic_bool cancel;
    waiter *waiters;      /* protected by store->lock */
    arbor_job *job;
};

struct arbor_store {
    arbor_store_config config;
    pthread_mutex_t lock;
    pthread_cond_t builds_done;  /* signalled when `building` drops to 0 */
    /* protected by lock */
    arbor_model **models;        /* listed models, sorted by name */
    uint32_t nmodels, cap;
    uint64_t tick;
    uint64_t reserved;           /* estimates of trees being built */
    uint64_t held;               /* arbor_store_reserve's: work outside the store */
    char held_for[64];           /* what the last reserve was for, for messages */
    uint32_t building;
    uint64_t next_version;
    /* updated without the lock, when memory is really allocated and freed */
    atomic_uint_fast64_t model_bytes, tree_bytes;
};

static const char *const state_names[] = {"absent", "building", "ready", "failed"};

const char *arbor_tree_state_name(arbor_tree_state s)
{
    return (unsigned)s < 4 ? state_names[s] : "?";
}

/* Bytes per triangle a built tree takes, about the largest of the trees of
 * ../shared/models (arbord stats --accel all --builder all): the bvh's
 * wide tree alone (the store drops the binary one), 60-81, and its binary
 * tree 17-26 more where it is kept (bunny, castle, galleon); the kd
 * tree's nodes, leaf lists and leaf packs, which copy every listed
 * triangle's corners, 287-429 for sah, up to 1,631 for the simple builders,
 * which split triangles far more often. So that a build that cannot fit is
 * refused before it starts rather than after. */
uint64_t arbor_store_tree_estimate(arbor_accel_kind kind, arbor_builder builder, uint32_t ntris, bool with_binary)
{
    uint64_t per_tri = kind == ARBOR_ACCEL_BVH ? (with_binary ? 110 : 84) : builder == ARBOR_BUILD_SAH ? 450 : 1700;
    return per_tri * ntris + 4096;
}

uint64_t arbor_mesh_bytes(const arbor_mesh *m)
{
    uint64_t b = (uint64_t)m->nverts * sizeof *m->verts + (uint64_t)m->ntris * (3 + 1) * sizeof(uint32_t) +
                 (uint64_t)m->nmats * sizeof *m->mats + (uint64_t)m->nnormals * sizeof *m->normals +
                 (m->tri_normals != NULL ? (uint64_t)m->ntris * 3 * sizeof(uint32_t) : 0);
    for (uint32_t i = 0; i < m->nwarnings; i++)
        b += strlen(m->warnings[i]) + 1;
    for (uint32_t i = 0; i < m->nmissing_libraries; i++)
        b += strlen(m->missing_libraries[i]) + 1;
    return b;
}

bool arbor_model_name_char(char c)
{
    return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '.' || c == '_' ||
           c == '-';
}

bool arbor_model_name_valid(const char *name)
{
    size_t n = strlen(name);
    if (n < 1 || n > ARBOR_MODEL_NAME_MAX || name[0] == '.')
        return false;
    for (size_t i = 0; i < n; i++)
        if (!arbor_model_name_char(name[i]))
            return false;
    return true;
}

const char *const arbor_model_exts[ARBOR_MODEL_NEXTS] = {".obj", ".ply", ".obj.gz", ".ply.gz"};

/* The compressed extensions are tried first: "a.obj.gz" is a, not "a.obj". */
int arbor_model_ext_index(const char *file)
{
    size_t n = strlen(file);
    for (int i = ARBOR_MODEL_NEXTS; i-- > 0;) {
        size_t k = strlen(arbor_model_exts[i]);
        if (n > k && strcasecmp(file + n - k, arbor_model_exts[i]) == 0)
            return i;
    }
    return -1;
}

bool arbor_model_name_of_file(const char *file, char *name, size_t cap)
{
    int ext = arbor_model_ext_index(file);
    if (ext < 0)
        return false;
    size_t stem = strlen(file) - strlen(arbor_model_exts[ext]), len = stem < cap ? stem : 0;
    for (size_t j = 0; j < len; j++)
        name[j] = arbor_model_name_char(file[j]) ? file[j] : '_';
    name[len] = '\0';
    return true;
}

int arbor_model_file_rank(const char *file)
{
    int ext = arbor_model_ext_index(file);
    if (ext < 0)
        return -1;
    size_t stem = strlen(file) - strlen(arbor_model_exts[ext]);
    if (strcmp(file + stem, arbor_model_exts[ext]) != 0)
        return ext + ARBOR_MODEL_NEXTS; /* NAME.OBJ is not the file NAME.obj */
    for (size_t j = 0; j < stem; j++)
        if (!arbor_model_name_char(file[j]))
            return ext + ARBOR_MODEL_NEXTS;
    return ext;
}

arbor_store *arbor_store_create(const arbor_store_config *c, arbor_err *e)
{
    if (c->pool == NULL) {
        arbor_fail(e, ARBOR_ERR_INVALID, "the store needs a pool to build on");
        return NULL;
    }
    arbor_store *s = calloc(1, sizeof *s);
    if (s == NULL) {
        arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory creating the store");
        return NULL;
    }
    s->config = *c;
    s->next_version = 1;
    atomic_init(&s->model_bytes, 0);
    atomic_init(&s->tree_bytes, 0);
    pthread_mutex_init(&s->lock, NULL);
    pthread_cond_init(&s->builds_done, NULL);
    return s;
}

/* ---- references ---- */

void arbor_model_retain(arbor_model *m)
{
    atomic_fetch_add_explicit(&m->refs, 1, memory_order_relaxed);
}

void arbor_model_release(arbor_model *m)
{
    if (m == NULL || atomic_fetch_sub_explicit(&m->refs, 1, memory_order_acq_rel) != 1)
        return;
    /* Only detached models can die: the store holds a reference to each listed one. */
    atomic_fetch_sub(&m->store->model_bytes, m->bytes);
    arbor_mesh_free(&m->mesh);
    free(m->file);
    free(m);
}

void arbor_tree_retain(arbor_tree *t)
{
    atomic_fetch_add_explicit(&t->refs, 1, memory_order_relaxed);
}

void arbor_tree_release(arbor_tree *t)
{
    if (t == NULL || atomic_fetch_sub_explicit(&t->refs, 1, memory_order_acq_rel) != 1)
        return;
    arbor_model *m = t->model;
    atomic_fetch_sub(&m->store->tree_bytes, t->bytes);
    arbor_accel_free(t->accel);
    free(t);
    arbor_model_release(m);
}

const char *arbor_model_name(const arbor_model *m) { return m->name; }
const char *arbor_model_file(const arbor_model *m) { return m->file; }
uint64_t arbor_model_version(const arbor_model *m) { return m->version; }
uint64_t arbor_model_bytes(const arbor_model *m) { return m->bytes; }
uint64_t arbor_model_stamp(const arbor_model *m) { return atomic_load(&((arbor_model *)m)->stamp); }
void arbor_model_set_stamp(arbor_model *m, uint64_t stamp) { atomic_store(&m->stamp, stamp); }
const arbor_mesh *arbor_model_mesh(const arbor_model *m) { return &m->mesh; }
const arbor_accel *arbor_tree_accel(const arbor_tree *t) { return t->accel; }
arbor_model *arbor_tree_model(const arbor_tree *t) { return t->model; }

/* ---- the model table (lock held) ---- */

/* Index of name in the sorted table, or where it would go (*found false). */
static uint32_t table_find(const arbor_store *s, const char *name, bool *found)
{
    uint32_t lo = 0, hi = s->nmodels;
    while (lo < hi) {
        uint32_t mid = lo + (hi - lo) / 2;
        int c = strcmp(s->models[mid]->name, name);
        if (c == 0) {
            *found = true;
            return mid;
        }
        if (c < 0)
            lo = mid + 1;
        else
            hi = mid;
    }
    *found = false;
    return lo;
}

static bool table_grow(arbor_store *s, arbor_err *e)
{
    if (s->nmodels < s->cap)
        return true;
    uint32_t cap = s->cap ? 2 * s->cap : 16;
    arbor_model **m = realloc(s->models, cap * sizeof *m);
    if (m == NULL)
        return arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory growing the model table");
    s->models = m;
    s->cap = cap;
    return true;
}

static uint64_t used_bytes(arbor_store *s)
{
    return atomic_load(&s->model_bytes) + atomic_load(&s->tree_bytes) + s->reserved + s->held;
}


/* What a change under the lock lets go of: released after unlocking, since
 * freeing a big tree takes milliseconds nobody should wait for. */
typedef struct {
    arbor_tree **trees;
    uint32_t ntrees, cap;
    arbor_model *model;
} dropped;

static bool dropped_init(arbor_store *s, dropped *d, arbor_err *e)
{
    d->cap = (s->nmodels + 1) * ARBOR_ACCEL_KIND_COUNT * ARBOR_BUILDER_COUNT;
    d->ntrees = 0;
    d->model = NULL;
    d->trees = malloc(d->cap * sizeof *d->trees);
    return d->trees != NULL || arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory");
}

static void dropped_release(dropped *d)
{
    for (uint32_t i = 0; i < d->ntrees; i++)
        arbor_tree_release(d->trees[i]);
    free(d->trees);
    arbor_model_release(d->model);
}

/* Detaches the model at index: no longer listed, its ready trees and the
 * store's reference to it go to *d, its builds are asked to stop. Lock held. */
static void model_detach(arbor_store *s, uint32_t index, dropped *d)
{
    arbor_model *m = s->models[index];
    m->detached = true;
    for (int k = 0; k < ARBOR_ACCEL_KIND_COUNT; k++)
        for (int b = 0; b < ARBOR_BUILDER_COUNT; b++) {
            tree_slot *slot = &m->slots[k][b];
            if (slot->state == ARBOR_TREE_READY) {
                d->trees[d->ntrees++] = slot->tree;
                slot->state = ARBOR_TREE_ABSENT;
            } else if (slot->state == ARBOR_TREE_BUILDING) {
                atomic_store(&slot->build->cancel, true);
            }
            slot->tree = NULL;
        }
    memmove(&s->models[index], &s->models[index + 1], (s->nmodels - index - 1) * sizeof *s->models);
    s->nmodels--;
    d->model = m;
}

static bool evictable(const tree_slot *slot)
{
    return slot->state == ARBOR_TREE_READY && atomic_load(&slot->tree->refs) == 1;
}

static int by_last_used(const void *a, const void *b)
{
    const tree_slot *x = *(tree_slot *const *)a, *y = *(tree_slot *const *)b;
    return (x->last_used > y->last_used) - (x->last_used < y->last_used);
}

/* Says why `need` bytes cannot fit: more than the whole budget (freeing
 * would never help), or what is in use that cannot be freed. Lock held. */
static void fail_nospace(arbor_store *s, uint64_t need, const char *what, arbor_err *e)
{
    uint64_t used = used_bytes(s), limit = s->config.max_memory;
    if (need > limit) {
        arbor_fail(e, ARBOR_ERR_NOSPACE, "%s needs %llu bytes, more than the whole memory budget of %llu bytes", what,
                   (unsigned long long)need, (unsigned long long)limit);
        return;
    }
    char held[128] = "";
    if (s->held > 0)
        snprintf(held, sizeof held, "; %llu of them held for %s", (unsigned long long)s->held, s->held_for);
    arbor_fail(e, ARBOR_ERR_NOSPACE,
               "%s needs %llu bytes; %llu of the %llu-byte memory budget are in use and cannot be freed "
               "(trees being rendered are never evicted%s)",
               what, (unsigned long long)need, (unsigned long long)(used < limit ? used : limit),
               (unsigned long long)limit, held);
}

/* Makes room for `need` more bytes by evicting ready trees that only the
 * store holds, least recently used first, into *d (their bytes come back
 * when d is released; `pending` counts them meanwhile). Evicts nothing when
 * even all of them would not make enough room: false, e saying so of
 * `what` (of `need_named` bytes), or that memory ran out. `spare` is a model
 * whose trees are about to go anyway (a replaced one), or NULL. Lock held. */
static bool make_room(arbor_store *s, uint64_t need, const arbor_model *spare, dropped *d, uint64_t *pending,
                      const char *what, uint64_t need_named, arbor_err *e)
{
    uint64_t limit = s->config.max_memory, used = used_bytes(s) - *pending;
    if (limit == 0 || used + need <= limit)
        return true;
    tree_slot **cand = malloc(d->cap * sizeof *cand);
    if (cand == NULL)
        return arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory making room for %s", what);
    uint32_t n = 0;
    uint64_t can_free = 0;
    for (uint32_t i = 0; i < s->nmodels; i++)
        for (int k = 0; k < ARBOR_ACCEL_KIND_COUNT; k++)
            for (int b = 0; b < ARBOR_BUILDER_COUNT; b++) {
                tree_slot *slot = &s->models[i]->slots[k][b];
                if (s->models[i] != spare && evictable(slot)) {
                    cand[n++] = slot;
                    can_free += slot->tree->bytes;
                }
            }
    bool ok = used - (can_free < used ? can_free : used) + need <= limit;
    if (ok) {
        qsort(cand, n, sizeof *cand, by_last_used);
        for (uint32_t i = 0; i < n && used + need > limit; i++) {
            used -= cand[i]->tree->bytes;
            *pending += cand[i]->tree->bytes;
            d->trees[d->ntrees++] = cand[i]->tree;
            cand[i]->tree = NULL;
            cand[i]->state = ARBOR_TREE_ABSENT;
        }
    } else {
        fail_nospace(s, need_named, what, e);
    }
    free(cand);
    return ok;
}

/* Bytes a replaced model would give back at once: its own, if no frame
 * holds it, and those of its trees no frame holds. Lock held. */
static uint64_t bytes_freed_by_detach(const arbor_model *m)
{
    uint64_t b = 0;
    int idle_trees = 0;
    for (int k = 0; k < ARBOR_ACCEL_KIND_COUNT; k++)
        for (int j = 0; j < ARBOR_BUILDER_COUNT; j++)
            if (evictable(&m->slots[k][j])) {
                b += m->slots[k][j].tree->bytes;
                idle_trees++;
            }
    /* Each idle tree holds the model too; beyond those and the store's own,
     * a reference is a frame or a request still using the mesh. */
    if (atomic_load(&m->refs) == 1 + idle_trees)
        b += m->bytes;
    return b;
}

static arbor_model *model_new(const char *name, const char *file, const arbor_mesh *mesh, arbor_store *s,
                              arbor_err *e)
{
    arbor_model *m = calloc(1, sizeof *m);
    char *copy = strdup(file);
    if (m == NULL || copy == NULL) {
        free(m);
        free(copy);
        arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory adding model '%s'", name);
        return NULL;
    }
    m->store = s;
    atomic_init(&m->refs, 1);
    atomic_init(&m->stamp, 0);
    snprintf(m->name, sizeof m->name, "%s", name);
    m->file = copy;
    m->bytes = arbor_mesh_bytes(mesh) + sizeof *m;
    return m;
}

bool arbor_store_add_model(arbor_store *s, const char *name, const char *file, arbor_mesh *mesh, unsigned flags,
                           uint64_t *version, arbor_err *e)
{
    if (!arbor_model_name_valid(name))
        return arbor_fail(e, ARBOR_ERR_INVALID, "model name '%s' must be " ARBOR_MODEL_NAME_RULE, name);
    arbor_model *m = model_new(name, file, mesh, s, e);
    if (m == NULL)
        return false;
    dropped d;
    pthread_mutex_lock(&s->lock);
    bool found, ok = dropped_init(s, &d, e) && table_grow(s, e);
    uint32_t at = table_find(s, name, &found);
    if (ok && found && !(flags & ARBOR_ADD_REPLACE))
        ok = arbor_fail(e, ARBOR_ERR_EXISTS, "model '%s' exists", name);
    if (ok) {
        arbor_model *old = found ? s->models[at] : NULL;
        uint64_t pending = old != NULL ? bytes_freed_by_detach(old) : 0;
        ok = make_room(s, m->bytes, old, &d, &pending, "the model", m->bytes, e);
    }
    if (ok) {
        if (found)
            model_detach(s, at, &d);
        memmove(&s->models[at + 1], &s->models[at], (s->nmodels - at) * sizeof *s->models);
        s->models[at] = m;
        s->nmodels++;
        m->version = s->next_version++;
        m->mesh = *mesh;
        arbor_mesh_init(mesh);
        atomic_fetch_add(&s->model_bytes, m->bytes);
        if (version != NULL)
            *version = m->version;
    }
    pthread_mutex_unlock(&s->lock);
    if (d.trees != NULL)
        dropped_release(&d);
    if (!ok) {
        free(m->file);
        free(m);
    }
    return ok;
}

bool arbor_store_reserve(arbor_store *s, uint64_t bytes, const char *what, arbor_err *e)
{
    dropped d;
    uint64_t pending = 0;
    pthread_mutex_lock(&s->lock);
    bool ok = dropped_init(s, &d, e) && make_room(s, bytes, NULL, &d, &pending, what, bytes, e);
    if (ok) {
        s->held += bytes;
        snprintf(s->held_for, sizeof s->held_for, "%s", what);
    }
    pthread_mutex_unlock(&s->lock);
    if (d.trees != NULL)
        dropped_release(&d);
    return ok;
}

void arbor_store_unreserve(arbor_store *s, uint64_t bytes)
{
    pthread_mutex_lock(&s->lock);
    assert(s->held >= bytes);
    s->held -= bytes;
    pthread_mutex_unlock(&s->lock);
}

/* Detaches model `name`, if it is `only` when that is not NULL. */
static bool remove_model(arbor_store *s, const char *name, const arbor_model *only, arbor_err *e)
{
    dropped d;
    pthread_mutex_lock(&s->lock);
    bool found, ok = dropped_init(s, &d, e);
    uint32_t at = table_find(s, name, &found);
    if (ok && !found)
        ok = arbor_fail(e, ARBOR_ERR_NOT_FOUND, "no model named '%s'", name);
    if (ok && only != NULL && s->models[at] != only)
        ok = arbor_fail(e, ARBOR_ERR_NOT_FOUND, "model '%s' was replaced", name);
    if (ok)
        model_detach(s, at, &d);
    pthread_mutex_unlock(&s->lock);
    if (d.trees != NULL)
        dropped_release(&d);
    return ok;
}

bool arbor_store_remove_model(arbor_store *s, const char *name, arbor_err *e)
{
    return remove_model(s, name, NULL, e);
}

bool arbor_store_remove_this_model(arbor_store *s, const arbor_model *m, arbor_err *e)
{
    return remove_model(s, arbor_model_name(m), m, e);
}

arbor_model *arbor_store_acquire_model(arbor_store *s, const char *name)
{
    pthread_mutex_lock(&s->lock);
    bool found;
    uint32_t at = table_find(s, name, &found);
    arbor_model *m = found ? s->models[at] : NULL;
    if (m != NULL)
        arbor_model_retain(m);
    pthread_mutex_unlock(&s->lock);
    return m;
}

bool arbor_store_list_models(arbor_store *s, arbor_model ***out, uint32_t *n, arbor_err *e)
{
    pthread_mutex_lock(&s->lock);
    *n = s->nmodels;
    *out = *n > 0 ? malloc(*n * sizeof **out) : NULL;
    bool ok = *n == 0 || *out != NULL;
    for (uint32_t i = 0; ok && i < *n; i++) {
        (*out)[i] = s->models[i];
        arbor_model_retain(s->models[i]);
    }
    pthread_mutex_unlock(&s->lock);
    if (!ok) {
        *n = 0;
        return arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory listing the models");
    }
    return true;
}

void arbor_model_tree_info(arbor_store *s, arbor_model *m, arbor_accel_kind kind, arbor_builder builder,
                           arbor_tree_info *out)
{
    memset(out, 0, sizeof *out);
    pthread_mutex_lock(&s->lock);
    const tree_slot *slot = &m->slots[kind][builder];
    out->state = slot->state;
    if (slot->state == ARBOR_TREE_READY)
        arbor_accel_stats(slot->tree->accel, &out->stats);
    if (slot->state == ARBOR_TREE_FAILED)
        snprintf(out->error, sizeof out->error, "%s", slot->error);
    pthread_mutex_unlock(&s->lock);
}

void arbor_store_on_build(arbor_store *s, arbor_store_build_fn fn, void *user)
{
    pthread_mutex_lock(&s->lock);
    s->config.on_build = fn;
    s->config.on_build_user = user;
    pthread_mutex_unlock(&s->lock);
}

void arbor_store_usage_of(arbor_store *s, arbor_store_usage *u)
{
    pthread_mutex_lock(&s->lock);
    u->models = atomic_load(&s->model_bytes);
    u->trees = atomic_load(&s->tree_bytes);
    u->reserved = s->reserved;
    u->held = s->held;
    u->limit = s->config.max_memory;
    u->nmodels = s->nmodels;
    u->building = s->building;
    pthread_mutex_unlock(&s->lock);
}

/* ---- builds ---- */

/* Builds b's tree, outside the store's lock, as a tree not yet filed (its
 * bytes counted, one reference held); NULL with *err set when the build
 * fails, is cancelled or the tree cannot be had. */
static arbor_tree *build_tree(build *b, arbor_tree_stats *st, arbor_err *err)
{
    arbor_store *s = b->store;
    arbor_build_opts opts;
    arbor_build_opts_init(&opts, b->kind, b->builder);
    /* The build takes its threads from the pool it runs on (this task is on
     * one of its workers) and stops when the model goes or the store shuts
     * down. */
    opts.threads = s->config.build_threads;
    opts.pool = s->config.pool;
    opts.cancel = &b->cancel;
    opts.drop_binary = true; /* rays, boxes and ray paths all use the wide tree */
    arbor_err_clear(err);
    arbor_accel *accel = atomic_load(&b->cancel) ? NULL : arbor_accel_build(&b->model->mesh, &opts, err);
    if (accel == NULL) {
        if (err->status == ARBOR_OK)
            arbor_fail(err, ARBOR_ERR_CANCELLED, "build cancelled");
        return NULL;
    }
    arbor_accel_stats(accel, st);
    arbor_tree *t = calloc(1, sizeof *t);
    if (t == NULL) {
        arbor_accel_free(accel);
        arbor_fail(err, ARBOR_ERR_NOMEM, "out of memory filing the tree");
        return NULL;
    }
    t->accel = accel;
    t->bytes = st->bytes;
    t->model = b->model;
    arbor_model_retain(b->model);
    atomic_init(&t->refs, 1);
    atomic_fetch_add(&s->tree_bytes, t->bytes);
    return t;
}

/* Files the tree in its slot (or the failure), then tells the waiters. */
static void build_run(void *ctx, uint32_t task)
{
    (void)task;
    build *b = ctx;
    arbor_store *s = b->store;
    arbor_err err;
    arbor_tree_stats st = {0};
    arbor_tree *t = build_tree(b, &st, &err);

    dropped d = {0};
    pthread_mutex_lock(&s->lock);
    tree_slot *slot = &b->model->slots[b->kind][b->builder];
    assert(slot->build == b && slot->state == ARBOR_TREE_BUILDING);
    s->reserved -= b->reserved;
    if (b->model->detached) {
        /* Cancelled or not, the tree is of a model that is gone. */
        arbor_fail(&err, ARBOR_ERR_NOT_FOUND, "model '%s' was removed or replaced while its tree was built",
                   b->model->name);
    } else if (t != NULL) {
        /* The estimate may have been low: make room now or give the tree up. */
        uint64_t pending = 0;
        if (dropped_init(s, &d, &err))
            make_room(s, 0, NULL, &d, &pending, "the tree", t->bytes, &err);
    }
    bool filed = t != NULL && err.status == ARBOR_OK;
    if (b->model->detached) {
        slot->state = ARBOR_TREE_ABSENT;
    } else if (filed) {
        slot->state = ARBOR_TREE_READY;
        slot->tree = t;
        slot->last_used = ++s->tick;
    } else {
        slot->state = ARBOR_TREE_FAILED;
        snprintf(slot->error, sizeof slot->error, "%s", err.msg);
    }
    slot->build = NULL;
    waiter *w = b->waiters;
    b->waiters = NULL;
    uint32_t nwaiters = 0;
    for (waiter *x = w; x != NULL; x = x->next)
        nwaiters++;
    if (filed)
        atomic_fetch_add(&t->refs, (int)nwaiters);
    arbor_store_build_fn on_build = s->config.on_build;
    void *on_build_user = s->config.on_build_user;
    pthread_mutex_unlock(&s->lock);

    if (d.trees != NULL)
        dropped_release(&d);
    if (!filed)
        arbor_tree_release(t);
    if (on_build != NULL)
        on_build(on_build_user, b->kind, b->builder, st.build_ms, filed);
    /* The build's hold on the model ends before anyone hears of the tree, so
     * that a waiter that lets go of the tree and replaces the model finds it
     * held by the store alone. */
    arbor_model_release(b->model);
    b->model = NULL;
    while (w != NULL) {
        waiter *next = w->next;
        w->fn(w->user, filed ? t : NULL, filed ? NULL : &err);
        free(w);
        w = next;
    }
}

/* The job is over (run or cancelled before it ran): the build goes. */
static void build_done(void *ctx, bool cancelled)
{
    build *b = ctx;
    arbor_store *s = b->store;
    if (cancelled) {
        /* Never ran: fail its waiters as build_run would have. */
        arbor_err err;
        arbor_fail(&err, ARBOR_ERR_CANCELLED, "build of %s %s cancelled", arbor_accel_kind_name(b->kind),
                   arbor_builder_name(b->builder));
        pthread_mutex_lock(&s->lock);
        if (b->model->detached)
            arbor_fail(&err, ARBOR_ERR_NOT_FOUND, "model '%s' was removed or replaced while its tree was built",
                       b->model->name);
        tree_slot *slot = &b->model->slots[b->kind][b->builder];
        s->reserved -= b->reserved;
        slot->state = ARBOR_TREE_ABSENT;
        slot->build = NULL;
        waiter *w = b->waiters;
        b->waiters = NULL;
        pthread_mutex_unlock(&s->lock);
        while (w != NULL) {
            waiter *next = w->next;
            w->fn(w->user, NULL, &err);
            free(w);
            w = next;
        }
    }
    /* The model goes before `building` drops: once it is 0, destroy expects
     * no reference but its own. */
    arbor_model_release(b->model);
    b->model = NULL;
    pthread_mutex_lock(&s->lock);
    if (--s->building == 0)
        pthread_cond_broadcast(&s->builds_done);
    pthread_mutex_unlock(&s->lock);
}

/* The pool let go of the job; done has run (and released the model) unless
 * the job was never submitted. */
static void build_free(void *ctx)
{
    build *b = ctx;
    arbor_model_release(b->model);
    free(b);
}

/* Whether `need` more bytes could fit if every tree nobody renders with were
 * evicted. Lock held. */
static bool could_fit(arbor_store *s, uint64_t need)
{
    uint64_t limit = s->config.max_memory;
    if (limit == 0)
        return true;
    uint64_t fixed = used_bytes(s);
    for (uint32_t i = 0; i < s->nmodels; i++)
        for (int k = 0; k < ARBOR_ACCEL_KIND_COUNT; k++)
            for (int b = 0; b < ARBOR_BUILDER_COUNT; b++)
                if (evictable(&s->models[i]->slots[k][b]))
                    fixed -= s->models[i]->slots[k][b].tree->bytes;
    return fixed + need <= limit;
}

/* Starts a build for an absent or failed slot. A build that could not fit
 * even with every idle tree evicted is refused now; otherwise nothing is
 * evicted yet: the tree's real size, known when it is built, decides what
 * goes (build_run). Lock held. */
static bool build_start(arbor_store *s, arbor_model *m, arbor_accel_kind kind, arbor_builder builder,
                        arbor_err *e)
{
    uint64_t need = arbor_store_tree_estimate(kind, builder, m->mesh.ntris, false);
    bool ok = could_fit(s, need);
    if (!ok)
        fail_nospace(s, need, "building the tree", e);
    build *b = ok ? calloc(1, sizeof *b) : NULL;
    if (ok && b == NULL)
        ok = arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory starting a build");
    if (ok) {
        b->store = s;
        b->model = m;
        arbor_model_retain(m);
        b->kind = kind;
        b->builder = builder;
        b->reserved = need;
        atomic_init(&b->cancel, false);
        b->job = arbor_job_new(1, build_run, build_done, build_free, b, e);
        if (b->job == NULL) {
            build_free(b);
            ok = false;
        }
    }
    if (ok && !arbor_pool_submit(s->config.pool, b->job, e)) {
        arbor_job_release(b->job);
        ok = false;
    }
    /* The pool's reference keeps the job alive while the slot says BUILDING,
     * which is the only time b->job is used (to cancel it). */
    if (ok)
        arbor_job_release(b->job);
    if (ok) {
        tree_slot *slot = &m->slots[kind][builder];
        slot->state = ARBOR_TREE_BUILDING;
        slot->build = b;
        s->reserved += need;
        s->building++;
    }
    return ok;
}

arbor_acquire arbor_store_acquire_tree(arbor_store *s, arbor_model *m, arbor_accel_kind kind,
                                       arbor_builder builder, arbor_tree **out, arbor_tree_ready_fn ready,
                                       void *user, arbor_err *e)
{
    *out = NULL;
    waiter *w = NULL;
    if (ready != NULL && (w = malloc(sizeof *w)) == NULL) {
        arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory waiting for a tree");
        return ARBOR_ACQUIRE_FAILED;
    }
    arbor_acquire r = ARBOR_ACQUIRE_PENDING;
    pthread_mutex_lock(&s->lock);
    tree_slot *slot = &m->slots[kind][builder];
    if (m->detached) {
        arbor_fail(e, ARBOR_ERR_NOT_FOUND, "model '%s' was removed", m->name);
        r = ARBOR_ACQUIRE_FAILED;
    } else if (slot->state == ARBOR_TREE_READY) {
        slot->last_used = ++s->tick;
        arbor_tree_retain(slot->tree);
        *out = slot->tree;
        r = ARBOR_ACQUIRE_READY;
    } else if (slot->state != ARBOR_TREE_BUILDING && !build_start(s, m, kind, builder, e)) {
        r = ARBOR_ACQUIRE_FAILED;
    }
    if (r == ARBOR_ACQUIRE_PENDING && w != NULL) {
        w->fn = ready;
        w->user = user;
        w->next = slot->build->waiters;
        slot->build->waiters = w;
        w = NULL;
    }
    pthread_mutex_unlock(&s->lock);
    free(w);
    return r;
}

void arbor_store_cancel_builds(arbor_store *s)
{
    pthread_mutex_lock(&s->lock);
    for (uint32_t i = 0; i < s->nmodels; i++)
        for (int k = 0; k < ARBOR_ACCEL_KIND_COUNT; k++)
            for (int b = 0; b < ARBOR_BUILDER_COUNT; b++)
                if (s->models[i]->slots[k][b].state == ARBOR_TREE_BUILDING) {
                    atomic_store(&s->models[i]->slots[k][b].build->cancel, true);
                    arbor_job_cancel(s->models[i]->slots[k][b].build->job);
                }
    pthread_mutex_unlock(&s->lock);
}

void arbor_store_stop_builds(arbor_store *s)
{
    arbor_store_cancel_builds(s);
    pthread_mutex_lock(&s->lock);
    while (s->building > 0)
        pthread_cond_wait(&s->builds_done, &s->lock);
    pthread_mutex_unlock(&s->lock);
}

void arbor_store_destroy(arbor_store *s)
{
    if (s == NULL)
        return;
    arbor_store_stop_builds(s);
    while (s->nmodels > 0) {
        dropped d;
        if (!dropped_init(s, &d, NULL))
            break;
        model_detach(s, s->nmodels - 1, &d);
        dropped_release(&d);
    }
    assert(atomic_load(&s->model_bytes) == 0 && atomic_load(&s->tree_bytes) == 0);
    free(s->models);
    pthread_cond_destroy(&s->builds_done);
    pthread_mutex_destroy(&s->lock);
    free(s);
}
