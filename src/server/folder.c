/*
 * folder.c - what uploads write into the shared models folder and what
 * DELETE removes from it: the folder's lock, the uploads' records, and
 * publishing files by a temporary name and a rename (folder.h).
 *
 * A record, ".NAME.upload", is a line per file: "own STAMP FILE" for a file
 * the upload wrote (STAMP, in hex, its arbor_file_stamp once written; 0
 * while it is being written) and "use FILE" for one that was there with the
 * same bytes. A save writes the record twice: before the files, naming
 * every file it is about to write besides the earlier upload's, so that
 * whatever it leaves behind if it stops half way is on record; and after,
 * naming what it wrote, with their stamps.
 */
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <inttypes.h>
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "arbor/sys.h"
#include "folder.h"

/* Entries a record holds: an upload's parts (at most 16, models.c) and,
 * while a save runs, the earlier upload's files besides. */
#define RECORD_MAX 40

typedef struct {
    char file[NAME_MAX + 1];
    bool own;
    uint64_t stamp; /* own: the file as written, 0 while it is written */
} record_entry;

typedef struct {
    record_entry e[RECORD_MAX];
    uint32_t n;
} record;

static bool ends_with(const char *s, const char *suffix)
{
    size_t n = strlen(s), k = strlen(suffix);
    return n >= k && strcasecmp(s + n - k, suffix) == 0;
}

bool folder_is_model_file(const char *file)
{
    return arbor_model_ext_index(file) >= 0;
}

bool folder_is_material_file(const char *file)
{
    return ends_with(file, ".mtl");
}

folder_lock_result folder_lock_take(const char *dir, int wait_ms, int *fd, char *err, size_t errcap)
{
    char path[PATH_MAX];
    snprintf(path, sizeof path, "%s/.arbord.lock", dir);
    *fd = open(path, O_RDWR | O_CREAT | O_CLOEXEC, 0644);
    if (*fd < 0) {
        snprintf(err, errcap, "cannot open the models folder's lock %s: %s", path, strerror(errno));
        return FOLDER_LOCK_FAILED;
    }
    /* polled, since flock(2) has no timeout: every 1, 2, 4 .. 64 ms */
    double until = arbor_now_ms() + wait_ms;
    long pause_ms = 1;
    for (;;) {
        if (flock(*fd, LOCK_EX | LOCK_NB) == 0)
            return FOLDER_LOCKED;
        if (errno != EWOULDBLOCK && errno != EINTR)
            break; /* ENOLCK: an NFS mount without locking; going on unlocked would race */
        if (arbor_now_ms() >= until) {
            snprintf(err, errcap, "the models folder's lock %s has been held by another for %d ms: try again",
                     path, wait_ms);
            close(*fd);
            *fd = -1;
            return FOLDER_LOCK_BUSY;
        }
        nanosleep(&(struct timespec){pause_ms / 1000, pause_ms % 1000 * 1000000}, NULL);
        pause_ms = pause_ms < 64 ? 2 * pause_ms : 64;
    }
    snprintf(err, errcap, "cannot lock the models folder's lock %s: %s", path, strerror(errno));
    close(*fd);
    *fd = -1;
    return FOLDER_LOCK_FAILED;
}

void folder_lock_drop(int fd)
{
    close(fd); /* releases the flock */
}

/* Writes dir/name through a temporary file and a rename, so that a daemon
 * reading the folder never sees half a file: a copy of the file at src, or
 * when src is NULL, text. The file is on disk before it takes the name
 * (fsync before the rename), so that after a crash the name holds the old
 * file or the whole new one; readable by all, as the models the operator
 * puts there are (mkstemp makes it 0600). */
static bool publish(const char *dir, const char *name, const char *src, const char *text, char *err, size_t errcap)
{
    char tmp[PATH_MAX], dst[PATH_MAX];
    snprintf(tmp, sizeof tmp, "%s/.%s.XXXXXX", dir, name);
    snprintf(dst, sizeof dst, "%s/%s", dir, name);
    int fd = mkstemp(tmp);
    FILE *in = src != NULL ? fopen(src, "rb") : NULL, *out = fd >= 0 ? fdopen(fd, "wb") : NULL;
    bool ok = (src == NULL || in != NULL) && out != NULL;
    if (ok && src == NULL)
        ok = fputs(text, out) >= 0;
    char buf[65536];
    size_t n;
    while (ok && in != NULL && (n = fread(buf, 1, sizeof buf, in)) > 0)
        ok = fwrite(buf, 1, n, out) == n;
    ok = ok && (in == NULL || !ferror(in));
    if (in != NULL)
        fclose(in);
    ok = ok && fflush(out) == 0 && fchmod(fd, 0644) == 0 && fsync(fd) == 0;
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

bool folder_copy_file(const char *dir, const char *name, const char *src, char *err, size_t errcap)
{
    return publish(dir, name, src, NULL, err, errcap);
}

/* ---- records ---- */

static void record_path(const char *dir, const char *name, char *path, size_t cap)
{
    snprintf(path, cap, "%s/.%s.upload", dir, name);
}

static const record_entry *record_find(const record *r, const char *file)
{
    for (uint32_t i = 0; i < r->n; i++)
        if (strcmp(r->e[i].file, file) == 0)
            return &r->e[i];
    return NULL;
}

static void record_add(record *r, const char *file, bool own, uint64_t stamp)
{
    if (r->n == RECORD_MAX || record_find(r, file) != NULL)
        return;
    record_entry *e = &r->e[r->n++];
    snprintf(e->file, sizeof e->file, "%s", file);
    e->own = own;
    e->stamp = stamp;
}

/* The record at path, empty when there is none. Lines that name no plain
 * file of the folder are skipped: the folder is shared, and a record must
 * not lead a DELETE anywhere else. */
static void record_read_path(const char *path, record *r)
{
    r->n = 0;
    FILE *f = fopen(path, "r");
    char line[NAME_MAX + 64];
    while (f != NULL && fgets(line, sizeof line, f) != NULL) {
        char file[NAME_MAX + 1];
        uint64_t stamp = 0;
        bool own = sscanf(line, "own %" SCNx64 " %255[^\n]", &stamp, file) == 2;
        if ((own || sscanf(line, "use %255[^\n]", file) == 1) && file[0] != '.' && strchr(file, '/') == NULL)
            record_add(r, file, own, stamp);
    }
    if (f != NULL)
        fclose(f);
}

static void record_read(const char *dir, const char *name, record *r)
{
    char path[PATH_MAX];
    record_path(dir, name, path, sizeof path);
    record_read_path(path, r);
}

static bool record_write(const char *dir, const char *name, const record *r, char *err, size_t errcap)
{
    char text[RECORD_MAX * (NAME_MAX + 32)], record_name[NAME_MAX + 1];
    size_t len = 0;
    for (uint32_t i = 0; i < r->n; i++)
        len += (size_t)(r->e[i].own ? snprintf(text + len, sizeof text - len, "own %" PRIx64 " %s\n", r->e[i].stamp,
                                               r->e[i].file)
                                    : snprintf(text + len, sizeof text - len, "use %s\n", r->e[i].file));
    text[len] = '\0';
    snprintf(record_name, sizeof record_name, ".%s.upload", name);
    return publish(dir, record_name, NULL, text, err, errcap);
}

/* Whether an entry's file is still the one its upload wrote: not replaced
 * since (by the operator, say), nor gone. A file being written (stamp 0)
 * is taken as the upload's. */
static bool entry_still_own(const char *dir, const record_entry *e)
{
    char path[PATH_MAX];
    snprintf(path, sizeof path, "%s/%s", dir, e->file);
    return e->own && (e->stamp == 0 || arbor_file_stamp(path) == e->stamp);
}

/* Whether a record other than name's names file. */
static bool other_record_names(const char *dir, const char *name, const char *file)
{
    char mine[NAME_MAX + 1], path[PATH_MAX];
    snprintf(mine, sizeof mine, ".%s.upload", name);
    DIR *d = opendir(dir);
    struct dirent *ent;
    bool named = false;
    record r;
    while (d != NULL && !named && (ent = readdir(d)) != NULL) {
        if (ent->d_name[0] != '.' || !ends_with(ent->d_name, ".upload") || strcmp(ent->d_name, mine) == 0)
            continue;
        snprintf(path, sizeof path, "%s/%s", dir, ent->d_name);
        record_read_path(path, &r);
        named = record_find(&r, file) != NULL;
    }
    if (d != NULL)
        closedir(d);
    return named;
}

/* Removes the files of r that are still its own, that keep (may be NULL)
 * does not have and that no other record names. */
static void remove_own(const char *dir, const char *name, const record *r, const record *keep)
{
    char path[PATH_MAX];
    for (uint32_t i = 0; i < r->n; i++) {
        const record_entry *e = &r->e[i];
        if (entry_still_own(dir, e) && (keep == NULL || record_find(keep, e->file) == NULL) &&
            !other_record_names(dir, name, e->file)) {
            snprintf(path, sizeof path, "%s/%s", dir, e->file);
            unlink(path);
        }
    }
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

/* ---- saving and removing ---- */

/* What an upload of `name` will write (own, stamp 0) and use of the folder,
 * from its stage; FOLDER_CONFLICT (err set) at a part that would overwrite a
 * file with other bytes that `before` does not own, or that another
 * upload's record names. */
static folder_result plan_save(const char *dir, const char *name, const char *stage, const char *model,
                               const char *final, const record *before, record *now, char *err, size_t errcap)
{
    char src[PATH_MAX], dst[PATH_MAX];
    now->n = 0;
    DIR *d = opendir(stage);
    if (d == NULL) {
        snprintf(err, errcap, "cannot read the stored upload");
        return FOLDER_FAILED;
    }
    folder_result res = FOLDER_SAVED;
    struct dirent *ent;
    while (res == FOLDER_SAVED && (ent = readdir(d)) != NULL) {
        if (ent->d_name[0] == '.' || strcmp(ent->d_name, model) == 0)
            continue;
        snprintf(src, sizeof src, "%s/%s", stage, ent->d_name);
        snprintf(dst, sizeof dst, "%s/%s", dir, ent->d_name);
        const record_entry *was = record_find(before, ent->d_name);
        struct stat st;
        /* a file this model's upload wrote is its own to write again, unless
         * another upload uses it and would get other bytes */
        bool ours = was != NULL && entry_still_own(dir, was);
        bool shared = ours && other_record_names(dir, name, ent->d_name);
        if (lstat(dst, &st) != 0 || (ours && !shared)) {
            record_add(now, ent->d_name, true, 0);
        } else if (same_bytes(src, dst)) {
            record_add(now, ent->d_name, ours, 0);
        } else {
            res = FOLDER_CONFLICT;
            snprintf(err, errcap,
                     "'%s' is in the models folder already, with other contents, and %s: give the file another "
                     "name (and the .obj's mtllib line) and upload again",
                     ent->d_name, shared ? "another upload's model uses it" : "this model's uploads did not write it");
        }
    }
    closedir(d);
    record_add(now, final, true, 0); /* last: written last, so its materials are there when it appears */
    return res;
}

folder_result folder_save_upload(const char *dir, const char *name, const char *stage, const char *model,
                                 folder_admit_fn admit, void *admit_ctx, char *file, size_t cap, char *err,
                                 size_t errcap)
{
    int at = arbor_model_ext_index(model);
    const char *ext = arbor_model_exts[at >= 0 ? at : 0];
    char final[NAME_MAX + 1];
    snprintf(final, sizeof final, "%s%s", name, ext);
    record before, now, pending;
    record_read(dir, name, &before);
    folder_result res = plan_save(dir, name, stage, model, final, &before, &now, err, errcap);
    if (res != FOLDER_SAVED)
        return res;
    snprintf(file, cap, "%s/%s", dir, final);
    if (!admit(admit_ctx, file))
        return FOLDER_REFUSED;
    pending = now;
    for (uint32_t i = 0; i < before.n; i++)
        if (entry_still_own(dir, &before.e[i]))
            record_add(&pending, before.e[i].file, true, before.e[i].stamp);
    bool ok = record_write(dir, name, &pending, err, errcap);
    char src[PATH_MAX], dst[PATH_MAX];
    for (uint32_t i = 0; ok && i < now.n; i++) {
        record_entry *e = &now.e[i];
        if (!e->own)
            continue;
        snprintf(src, sizeof src, "%s/%s", stage, strcmp(e->file, final) == 0 ? model : e->file);
        snprintf(dst, sizeof dst, "%s/%s", dir, e->file);
        ok = publish(dir, e->file, src, NULL, err, errcap);
        e->stamp = ok ? arbor_file_stamp(dst) : 0;
    }
    if (!ok || !record_write(dir, name, &now, err, errcap))
        return FOLDER_FAILED;
    /* the renames themselves on disk before the upload is answered */
    int dfd = open(dir, O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (dfd >= 0) {
        fsync(dfd);
        close(dfd);
    }
    remove_own(dir, name, &before, &now);
    for (int i = 0; i < ARBOR_MODEL_NEXTS; i++)
        if (strcmp(arbor_model_exts[i], ext) != 0) {
            snprintf(dst, sizeof dst, "%s/%s%s", dir, name, arbor_model_exts[i]);
            unlink(dst); /* one model file per name */
        }
    return FOLDER_SAVED;
}

void folder_remove_upload(const char *dir, const char *name)
{
    record r;
    char path[PATH_MAX];
    record_read(dir, name, &r);
    remove_own(dir, name, &r, NULL);
    record_path(dir, name, path, sizeof path);
    unlink(path);
}
