/*
 * store.h - the model store: loaded meshes and their built trees, kept in
 * memory for a long-running daemon, reference counted, within a memory
 * budget.
 *
 * A model is a named mesh. Each model has eight tree slots (two kinds times
 * four builders), each absent, building, ready or failed. A tree is built at
 * most once at a time however many callers ask for it: the first request
 * starts a build on the pool, later ones wait for the same build.
 *
 * Ownership. The store holds one reference to each model it lists and to each
 * ready tree. arbor_store_acquire_model and arbor_store_acquire_tree hand out
 * further references; a tree reference keeps its model (and so its mesh)
 * alive. So a frame that holds a tree can go on rendering while its model is
 * replaced, deleted or its tree evicted: memory returns when the last
 * reference goes. Release every reference with arbor_model_release /
 * arbor_tree_release, from any thread, before arbor_store_destroy.
 *
 * Memory. The bytes of every live mesh and tree, plus an estimate for each
 * tree being built, stay within max_memory: to make room the store evicts
 * ready trees that nobody but the store holds, least recently used first
 * (they go back to absent and are rebuilt on demand). What cannot fit is
 * refused with ARBOR_ERR_NOSPACE and a message saying how many bytes were
 * needed; nothing already loaded is touched.
 *
 * Threads: every function may be called from any thread. The store never
 * blocks on a build except in arbor_store_stop_builds and
 * arbor_store_destroy, which cancel them first.
 * Build callbacks run on pool workers, never under the store's lock.
 */
#ifndef ARBOR_STORE_H
#define ARBOR_STORE_H

#include <stdbool.h>
#include <stdint.h>

#include "arbor/accel.h"
#include "arbor/err.h"
#include "arbor/mesh.h"
#include "arbor/pool.h"

#define ARBOR_MODEL_NAME_MAX 64

typedef struct arbor_store arbor_store;
typedef struct arbor_model arbor_model;
typedef struct arbor_tree arbor_tree;

typedef enum { ARBOR_TREE_ABSENT, ARBOR_TREE_BUILDING, ARBOR_TREE_READY, ARBOR_TREE_FAILED } arbor_tree_state;

/* Called once a build has finished (for metrics); on a pool worker. */
typedef void (*arbor_store_build_fn)(void *user, arbor_accel_kind kind, arbor_builder builder, double ms,
                                     bool ok);

typedef struct {
    arbor_pool *pool;           /* builds run here; required */
    int build_threads;          /* thread budget of one build; 0 = the pool's */
    uint64_t max_memory;        /* bytes; 0 = unlimited */
    arbor_store_build_fn on_build;
    void *on_build_user;
} arbor_store_config;

/* A snapshot of one tree slot. */
typedef struct {
    arbor_tree_state state;
    arbor_tree_stats stats;     /* valid when state is READY */
    char error[512];            /* why the last build failed, when FAILED */
} arbor_tree_info;

typedef struct {
    uint64_t models, trees, limit;  /* bytes */
    uint64_t reserved;              /* bytes reckoned for the builds in progress */
    uint64_t held;                  /* bytes held by arbor_store_reserve */
    uint32_t nmodels, building;
} arbor_store_usage;

/* A tree is ready, or could not be had: exactly one of tree and e is set.
 * The callee owns the tree reference. Runs on a pool worker. */
typedef void (*arbor_tree_ready_fn)(void *user, arbor_tree *tree, const arbor_err *e);

typedef enum { ARBOR_ACQUIRE_READY, ARBOR_ACQUIRE_PENDING, ARBOR_ACQUIRE_FAILED } arbor_acquire;

const char *arbor_tree_state_name(arbor_tree_state s);

arbor_store *arbor_store_create(const arbor_store_config *c, arbor_err *e);
/* Cancels the builds in progress, waits for them, drops the store's
 * references. Every other reference must have been released. */
void arbor_store_destroy(arbor_store *s);

/* The rule a model name follows, in words for error messages. */
#define ARBOR_MODEL_NAME_RULE "1..64 characters of A-Z a-z 0-9 . _ -, the first not '.'"
/* True for names of 1..64 characters from [A-Za-z0-9._-] whose first is not
 * '.': a name is a file name in the models folder, where a leading dot
 * would hide it from the folder's scan (and "." and ".." are not files). */
bool arbor_model_name_valid(const char *name);
/* Whether c may be in a model name (and in a file name the folder keeps). */
bool arbor_model_name_char(char c);
/* A model file's extensions, in the order a name's files are preferred
 * (arbor_model_file_rank). */
#define ARBOR_MODEL_NEXTS 4
extern const char *const arbor_model_exts[ARBOR_MODEL_NEXTS];
/* The index in arbor_model_exts of file's extension, in any case (the
 * loader reads "BOX.OBJ" too); -1 for a file that is no model file. */
int arbor_model_ext_index(const char *file);
/* The name of the model in a file named `file`: the name less its extension
 * (.obj, .ply, .obj.gz, .ply.gz, in any case), each character a model
 * name may not hold made '_' ("rose+vase.obj" is rose_vase). False when
 * file is no model file. The name may still be no valid one (a leading '.',
 * too long: then it is ""): check it with arbor_model_name_valid. */
bool arbor_model_name_of_file(const char *file, char *name, size_t cap);
/* Which of the files that make one model name is that model's (the lowest
 * rank; among equal ranks, the first by strcmp): NAME.EXT by the order of
 * arbor_model_exts (0..3), before any file whose name was changed to make
 * it or whose extension is not in lower case (4..7). -1 for a file that is
 * no model file. The daemon's start and
 * its checks of the folder at every request both choose by it. */
int arbor_model_file_rank(const char *file);

/* How a model is added. */
enum {
    ARBOR_ADD_REPLACE = 1    /* an existing model of that name is replaced, not refused */
};

/* Adds a model made of *mesh (moved into the store on success: *mesh is left
 * empty; on failure it is untouched). `file` is where it came from. An
 * existing name fails with ARBOR_ERR_EXISTS unless flags has
 * ARBOR_ADD_REPLACE, in which case the old model is detached (frames using it
 * finish safely) and the new one takes the next version number. *version
 * (may be NULL) gets the model's version. */
bool arbor_store_add_model(arbor_store *s, const char *name, const char *file, arbor_mesh *mesh, unsigned flags,
                           uint64_t *version, arbor_err *e);
/* Detaches a model; ARBOR_ERR_NOT_FOUND when there is none of that name. */
bool arbor_store_remove_model(arbor_store *s, const char *name, arbor_err *e);
/* Detaches m (held by the caller) if it is still its name's model:
 * ARBOR_ERR_NOT_FOUND, and nothing changed, when it was removed or replaced
 * meanwhile. A check of m and a remove by name would detach a replacement
 * added between them. */
bool arbor_store_remove_this_model(arbor_store *s, const arbor_model *m, arbor_err *e);

/* A reference to the named model, or NULL. */
arbor_model *arbor_store_acquire_model(arbor_store *s, const char *name);
/* References to every model, sorted by name, in a malloc'd array (*out,
 * NULL when empty; free it after releasing each), their count in *n. False,
 * with nothing held, when out of memory: not the same as an empty store. */
bool arbor_store_list_models(arbor_store *s, arbor_model ***out, uint32_t *n, arbor_err *e);

void arbor_model_retain(arbor_model *m);
void arbor_model_release(arbor_model *m);
const char *arbor_model_name(const arbor_model *m);
const char *arbor_model_file(const arbor_model *m);
uint64_t arbor_model_version(const arbor_model *m);
/* The identity of the file the model was read from (arbor_file_stamp, taken
 * before reading it), so that a daemon sharing its models folder with others
 * sees when the file was replaced; 0 (the default) when not known. */
uint64_t arbor_model_stamp(const arbor_model *m);
void arbor_model_set_stamp(arbor_model *m, uint64_t stamp);
uint64_t arbor_model_bytes(const arbor_model *m);
const arbor_mesh *arbor_model_mesh(const arbor_model *m);
void arbor_model_tree_info(arbor_store *s, arbor_model *m, arbor_accel_kind kind, arbor_builder builder,
                           arbor_tree_info *out);

/* The model's tree of that kind and builder:
 *   READY   *out gets a reference; `ready` is not called.
 *   PENDING the tree is building (this call may have started the build);
 *           `ready` (when not NULL) will be called exactly once with the tree
 *           or the build's error.
 *   FAILED  e says why (the model was removed, the tree cannot fit in memory:
 *           ARBOR_ERR_NOSPACE, ...); `ready` is not called.
 * A tree whose last build failed is built again. */
arbor_acquire arbor_store_acquire_tree(arbor_store *s, arbor_model *m, arbor_accel_kind kind,
                                       arbor_builder builder, arbor_tree **out, arbor_tree_ready_fn ready,
                                       void *user, arbor_err *e);

void arbor_tree_retain(arbor_tree *t);
void arbor_tree_release(arbor_tree *t);
const arbor_accel *arbor_tree_accel(const arbor_tree *t);
arbor_model *arbor_tree_model(const arbor_tree *t);

void arbor_store_usage_of(arbor_store *s, arbor_store_usage *u);
/* Sets the build callback after creation (the server, made after the store,
 * counts builds for its metrics). */
void arbor_store_on_build(arbor_store *s, arbor_store_build_fn fn, void *user);

/* Asks every build in progress to stop (shutdown): their waiters are
 * called soon with ARBOR_ERR_CANCELLED. Does not wait. */
void arbor_store_cancel_builds(arbor_store *s);
/* Cancels every build and waits until each has ended: its build callback
 * and waiters have returned, so none of them runs after this (a server
 * stopping before the store calls it before it frees what they use). */
void arbor_store_stop_builds(arbor_store *s);

/* Bytes a mesh holds (its arrays). */
uint64_t arbor_mesh_bytes(const arbor_mesh *m);

/* Memory used outside the store but within its budget (a benchmark job's
 * own trees): arbor_store_reserve holds `bytes` of max_memory, evicting
 * idle trees to make room, or fails (ARBOR_ERR_NOSPACE naming `what`,
 * ARBOR_ERR_NOMEM) without holding any; arbor_store_unreserve gives back
 * what a reserve held. arbor_store_tree_estimate: the bytes a tree over
 * ntris triangles is reckoned to take, a BVH's binary tree too when
 * with_binary (the store drops it; a benchmark keeps it). */
bool arbor_store_reserve(arbor_store *s, uint64_t bytes, const char *what, arbor_err *e);
void arbor_store_unreserve(arbor_store *s, uint64_t bytes);
uint64_t arbor_store_tree_estimate(arbor_accel_kind kind, arbor_builder builder, uint32_t ntris, bool with_binary);

#endif
