/*
 * folder.h - what uploads write into the shared models folder, and what
 * DELETE may remove from it (folder.c). Private to src/server/; it knows
 * files, not HTTP.
 *
 * Several daemons may share the folder (docs/SCALE.md), and the operator
 * puts models there too. An upload of NAME records in ".NAME.upload" the
 * files it wrote, each with its identity (arbor_file_stamp) as written, and
 * the files already there that it uses (a material library with the same
 * bytes). DELETE removes only files the record says NAME's upload wrote and
 * that are still those files, and none that another record names: a file
 * the operator put in the folder, or replaced since, is never removed. An
 * upload's material libraries never write over a file that is not its own
 * (409); its model file is NAME.EXT, whatever was there, and the name's
 * files of the other extensions go (an upload of NAME is NAME's model).
 *
 * Every change to the folder happens under its lock (folder_lock_take), an
 * flock(2) on ".arbord.lock" in it, which serialises uploads and deletes
 * of every thread and every daemon on the machine.
 */
#ifndef ARBOR_SERVER_FOLDER_H
#define ARBOR_SERVER_FOLDER_H

#include <stdbool.h>
#include <stddef.h>

#include "arbor/store.h"

/* Whether a file name is a model file's: one of arbor_model_exts, in any
 * case. */
bool folder_is_model_file(const char *file);
/* Whether a file name is a material library's (.mtl, in any case). */
bool folder_is_material_file(const char *file);

/* How long folder_lock_take waits for a lock another holds. A daemon holds
 * it while it copies one upload into the folder or removes one model's
 * files: well under a second on a local disk. Longer means a holder that is
 * stuck (or an operator's own flock), and the request is refused rather than
 * left holding a worker the frames need. */
#define FOLDER_LOCK_WAIT_MS 5000

typedef enum { FOLDER_LOCKED, FOLDER_LOCK_BUSY, FOLDER_LOCK_FAILED } folder_lock_result;

/* Takes the folder's lock, waiting up to wait_ms for it; on FOLDER_LOCKED
 * *fd is the descriptor to give folder_lock_drop. FOLDER_LOCK_BUSY: another
 * held it all that time; FOLDER_LOCK_FAILED: the lock file cannot be opened
 * or locked. Both set err. */
folder_lock_result folder_lock_take(const char *dir, int wait_ms, int *fd, char *err, size_t errcap);
void folder_lock_drop(int fd);

typedef enum { FOLDER_SAVED, FOLDER_CONFLICT, FOLDER_REFUSED, FOLDER_FAILED } folder_result;

/* Asked once an upload is planned, before anything is written, with the
 * path its model file will have: false refuses the upload (FOLDER_REFUSED),
 * and the folder stays as it was. */
typedef bool (*folder_admit_fn)(void *ctx, const char *file);

/* Saves an upload of model `name` from stage (a folder of its parts: the
 * file `model`, then material libraries) into dir, with the lock held: the
 * model as NAME.EXT (NAME's files of the other extensions removed), each
 * material library under its own name, and the record. A material library
 * that would overwrite a file of another content that NAME's record does
 * not own is FOLDER_CONFLICT, and nothing is written; then admit decides
 * (FOLDER_REFUSED: nothing written). On FOLDER_SAVED *file is the model's
 * path. err says what went wrong on FOLDER_CONFLICT and FOLDER_FAILED (the
 * files written so far stay, named by the record: folder_remove_upload
 * removes them). */
folder_result folder_save_upload(const char *dir, const char *name, const char *stage, const char *model,
                                 folder_admit_fn admit, void *admit_ctx, char *file, size_t cap, char *err,
                                 size_t errcap);

/* Copies the file at src into dir as name, by a temporary file and a
 * rename; false (err set) when it cannot. */
bool folder_copy_file(const char *dir, const char *name, const char *src, char *err, size_t errcap);

/* Removes, with the lock held, the files an upload of `name` wrote that no
 * other record names, and its record. A model the operator put in the
 * folder has no record and keeps its files. */
void folder_remove_upload(const char *dir, const char *name);

#endif
