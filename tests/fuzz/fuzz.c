/*
 * fuzz.c - the helpers of fuzz.h.
 */
#define _XOPEN_SOURCE 700 /* nftw, mkdtemp */
#include <dirent.h>
#include <ftw.h>
#include <limits.h>
#include <math.h>
#include <string.h>
#include <unistd.h>
#include <zlib.h>

#include "fuzz.h"

static char scratch[64];

static int remove_entry(const char *path, const struct stat *st, int flag, struct FTW *ftw)
{
    (void)st;
    (void)flag;
    (void)ftw;
    remove(path);
    return 0;
}

static void remove_scratch(void)
{
    nftw(scratch, remove_entry, 16, FTW_DEPTH | FTW_PHYS);
}

const char *fuzz_scratch(void)
{
    if (scratch[0] == '\0') {
        const char *tmp = getenv("TMPDIR");
        snprintf(scratch, sizeof scratch, "%s/arbor-fuzz-XXXXXX", tmp != NULL && strlen(tmp) < 40 ? tmp : "/tmp");
        FUZZ_CHECK(mkdtemp(scratch) != NULL, "cannot make %s", scratch);
        atexit(remove_scratch);
    }
    return scratch;
}

const char *fuzz_write(const char *name, const void *data, size_t n, int gz)
{
    static char path[PATH_MAX];
    snprintf(path, sizeof path, "%s/%s", fuzz_scratch(), name);
    if (gz) {
        gzFile g = gzopen(path, "wb");
        FUZZ_CHECK(g != NULL, "cannot write %s", path);
        FUZZ_CHECK(n == 0 || gzwrite(g, data, (unsigned)n) == (int)n, "cannot write %s", path);
        FUZZ_CHECK(gzclose(g) == Z_OK, "cannot write %s", path);
    } else {
        FILE *f = fopen(path, "wb");
        FUZZ_CHECK(f != NULL, "cannot write %s", path);
        FUZZ_CHECK(fwrite(data, 1, n, f) == n && fclose(f) == 0, "cannot write %s", path);
    }
    return path;
}

void fuzz_empty_dir(const char *dir)
{
    DIR *d = opendir(dir);
    if (d == NULL)
        return;
    char path[PATH_MAX];
    struct dirent *ent;
    while ((ent = readdir(d)) != NULL)
        if (strcmp(ent->d_name, ".") != 0 && strcmp(ent->d_name, "..") != 0) {
            snprintf(path, sizeof path, "%s/%s", dir, ent->d_name);
            unlink(path);
        }
    closedir(d);
}

void fuzz_check_mesh(const arbor_mesh *m)
{
    FUZZ_CHECK(m->ntris > 0, "a loaded mesh without triangles");
    FUZZ_CHECK(m->nmats > 0, "a loaded mesh without the default material");
    for (uint32_t t = 0; t < m->ntris; t++) {
        FUZZ_CHECK(m->tri_mat[t] < m->nmats, "triangle %u: material %u of %u", t, m->tri_mat[t], m->nmats);
        for (int k = 0; k < 3; k++) {
            uint32_t v = m->tri_verts[3 * (size_t)t + k];
            FUZZ_CHECK(v < m->nverts, "triangle %u: vertex %u of %u", t, v, m->nverts);
            arbor_vec3 p = m->verts[v];
            FUZZ_CHECK(isfinite(p.x) && isfinite(p.y) && isfinite(p.z), "vertex %u is not finite", v);
            FUZZ_CHECK(p.x >= m->bounds.lo.x && p.y >= m->bounds.lo.y && p.z >= m->bounds.lo.z &&
                           p.x <= m->bounds.hi.x && p.y <= m->bounds.hi.y && p.z <= m->bounds.hi.z,
                       "vertex %u outside the mesh bounds", v);
        }
    }
}
