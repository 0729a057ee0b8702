/* sys.c - clock, core count, file identity, prefaulting and UTF-8 repair
 * (see include/arbor/sys.h). */
#define _DEFAULT_SOURCE /* madvise */
#include <errno.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "arbor/sys.h"

double arbor_now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec * 1e3 + (double)ts.tv_nsec * 1e-6;
}

int arbor_cpu_count(void)
{
    long n = sysconf(_SC_NPROCESSORS_ONLN);
    return n > 0 ? (int)n : 1;
}

bool arbor_real_path_inside(const char *real, const char *dir)
{
    size_t n = strlen(dir);
    if (n == 1 && dir[0] == '/')
        return real[0] == '/';
    return strncmp(real, dir, n) == 0 && real[n] == '/';
}

/* FNV-1a over the fields that change when a file is replaced or rewritten.
 * Not the device: an NFS client numbers the mount when it mounts it, so
 * hosts sharing a folder (and one host after a remount) see other device
 * numbers for the same file, and its identity must not change with them. */
uint64_t arbor_file_stamp(const char *path)
{
    struct stat st;
    if (stat(path, &st) != 0)
        return 0;
    uint64_t fields[4] = {(uint64_t)st.st_ino, (uint64_t)st.st_size, (uint64_t)st.st_mtim.tv_sec,
                          (uint64_t)st.st_mtim.tv_nsec};
    uint64_t h = 14695981039346656037ull;
    for (int i = 0; i < 4; i++)
        for (int b = 0; b < 8; b++) {
            h ^= (fields[i] >> (8 * b)) & 0xff;
            h *= 1099511628211ull;
        }
    return h != 0 ? h : 1;
}

void arbor_prefault(void *p, size_t bytes)
{
#ifdef MADV_POPULATE_WRITE
    long page = sysconf(_SC_PAGESIZE);
    if (page <= 0)
        return;
    uintptr_t lo = ((uintptr_t)p + (uintptr_t)page - 1) & ~((uintptr_t)page - 1);
    uintptr_t hi = ((uintptr_t)p + bytes) & ~((uintptr_t)page - 1);
    if (hi > lo)
        (void)madvise((void *)lo, hi - lo, MADV_POPULATE_WRITE); /* a hint: failure leaves the faults to come */
#else
    (void)p;
    (void)bytes;
#endif
}

/* The length of the well-formed UTF-8 sequence at s (of n bytes), or 0:
 * RFC 3629's table, so no overlong form, surrogate or code point past
 * U+10FFFF passes. */
static size_t utf8_sequence(const unsigned char *s, size_t n)
{
    unsigned char c = s[0];
    if (c < 0x80)
        return 1;
    size_t len = c >= 0xC2 && c <= 0xDF ? 2 : c >= 0xE0 && c <= 0xEF ? 3 : c >= 0xF0 && c <= 0xF4 ? 4 : 0;
    if (len == 0 || len > n)
        return 0;
    unsigned char lo = c == 0xE0 ? 0xA0 : c == 0xF0 ? 0x90 : 0x80;
    unsigned char hi = c == 0xED ? 0x9F : c == 0xF4 ? 0x8F : 0xBF;
    if (s[1] < lo || s[1] > hi)
        return 0;
    for (size_t i = 2; i < len; i++)
        if (s[i] < 0x80 || s[i] > 0xBF)
            return 0;
    return len;
}

void arbor_utf8_repair(char *text, size_t len)
{
    unsigned char *s = (unsigned char *)text;
    for (size_t i = 0; i < len;) {
        size_t k = utf8_sequence(s + i, len - i);
        if (k == 0) {
            s[i] = '?';
            k = 1;
        }
        i += k;
    }
}

/* ---- files written whole ---- */

/* The permissions a new file gets (0666 less the umask). The umask is read
 * from /proc, because umask() can only be read by setting it, which would
 * race with other threads creating files. */
static mode_t new_file_mode(void)
{
    mode_t mask = 022;
    FILE *f = fopen("/proc/self/status", "r");
    char line[128];
    while (f != NULL && fgets(line, sizeof line, f) != NULL) {
        unsigned m;
        if (sscanf(line, "Umask: %o", &m) == 1) {
            mask = (mode_t)m;
            break;
        }
    }
    if (f != NULL)
        fclose(f);
    return 0666 & ~mask;
}

/* o->f on a temporary file beside o->path (same folder, so the rename
 * cannot cross file systems), with permissions mode. */
static bool open_temporary(arbor_file_out *o, mode_t mode, arbor_err *e)
{
    if (snprintf(o->tmp, sizeof o->tmp, "%s.XXXXXX", o->path) >= (int)sizeof o->tmp)
        return arbor_fail(e, ARBOR_ERR_INVALID, "%s: path too long", o->path);
    int fd = mkstemp(o->tmp);
    if (fd < 0)
        return arbor_fail_errno(e, o->path, "cannot create a temporary file beside it", errno);
    o->f = fchmod(fd, mode) == 0 ? fdopen(fd, "wb") : NULL;
    if (o->f == NULL) {
        int err = errno;
        close(fd);
        unlink(o->tmp);
        return arbor_fail_errno(e, o->path, "cannot create", err);
    }
    return true;
}

bool arbor_file_out_open(arbor_file_out *o, const char *path, arbor_err *e)
{
    o->f = NULL;
    o->tmp[0] = '\0';
    if (snprintf(o->path, sizeof o->path, "%s", path) >= (int)sizeof o->path)
        return arbor_fail(e, ARBOR_ERR_INVALID, "%s: path too long", path);
    struct stat st;
    if (stat(path, &st) != 0) {
        if (errno != ENOENT)
            return arbor_fail_errno(e, path, "cannot create", errno);
        return open_temporary(o, new_file_mode(), e);
    }
    if (!S_ISREG(st.st_mode)) {
        o->f = fopen(path, "wb");
        return o->f != NULL || arbor_fail_errno(e, path, "cannot open", errno);
    }
    char *target = realpath(path, NULL);
    if (target == NULL)
        return arbor_fail_errno(e, path, "cannot resolve", errno);
    bool fits = snprintf(o->path, sizeof o->path, "%s", target) < (int)sizeof o->path;
    free(target);
    if (!fits)
        return arbor_fail(e, ARBOR_ERR_INVALID, "%s: its target's path is too long", path);
    return open_temporary(o, st.st_mode & 07777, e);
}

bool arbor_file_out_close(arbor_file_out *o, bool complete, arbor_err *e)
{
    int err = ferror(o->f) ? (errno ? errno : EIO) : 0;
    if (fclose(o->f) != 0 && err == 0)
        err = errno;
    o->f = NULL;
    bool placed = complete && err == 0;
    if (placed && o->tmp[0] != '\0' && rename(o->tmp, o->path) != 0) {
        err = errno;
        placed = false;
    }
    if (!placed && o->tmp[0] != '\0')
        unlink(o->tmp);
    return placed || (err != 0 && arbor_fail_errno(e, o->path, "cannot write", err));
}
