/*
 * obj.c - the Wavefront OBJ reader (arbor_load_obj_text, see
 * include/arbor/load.h).
 *
 * One pass over the buffer with a cursor, no allocation per line. Read: v
 * (x y z; w or vertex colours after them ignored), vn (kept for smooth
 * shading), vt (counted), f in every index form (a, a/b, a/b/c, a//c; negative = from
 * the end of the list so far), usemtl, mtllib. o, g, s and the other OBJ
 * statements are skipped; a line that is no OBJ statement is skipped too but
 * warned of (a model that loads partly should say so), and one holding
 * control bytes means the file is binary, not OBJ: an error.
 */
#define _XOPEN_SOURCE 700 /* realpath, beyond the build's _POSIX_C_SOURCE */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "arbor/load.h"
#include "arbor/sys.h"
#include "loader.h"

/* At most this many distinct material libraries per model: each one is a
 * file read, and a hostile OBJ could name thousands. */
#define OBJ_MAX_LIBRARIES 16

typedef struct {
    const char *name; /* points into the OBJ text */
    size_t len;
} obj_library;

typedef struct {
    text_cursor c;
    const char *dir; /* folder for mtllib paths; NULL: libraries not loaded */
    char *real_dir;  /* its real path once resolved (malloc'd), for containment */
    arbor_mesh *m;
    material_table mats;
    uint32_t ntexcoords;
    uint32_t mat; /* material of the faces that follow */
    obj_library libs[OBJ_MAX_LIBRARIES];
    uint32_t nlibs;
    uint32_t nunknown; /* lines that are no OBJ statement, for one warning */
    uint32_t unknown_line;
    char unknown_word[40];
} obj_reader;

/* ---- faces ---- */

/* One index of a face vertex as written. */
typedef struct {
    const char *digits;
    size_t ndigits;
    int64_t value;
    bool present;
} obj_index;

/* Splits the face vertex at p ("v", "v/t", "v/t/n" or "v//n") into its
 * position, texture and normal indices; returns its end, or NULL when it is
 * malformed. */
static const char *split_face_vertex(const text_cursor *c, const char *p, obj_index idx[3])
{
    memset(idx, 0, 3 * sizeof *idx);
    for (int k = 0; k < 3; k++) {
        bool skipped = k == 1 && p < c->end && *p == '/'; /* "v//n" */
        if (!skipped) {
            const char *q = text_parse_int(p, c->end, &idx[k].value);
            if (q == NULL)
                return NULL;
            idx[k].digits = p;
            idx[k].ndigits = (size_t)(q - p);
            idx[k].present = true;
            p = q;
        }
        if (k == 2 || p == c->end || *p != '/')
            break;
        p++;
    }
    return text_is_delim(c, p) ? p : NULL;
}

/* Turns a 1-based (or negative, counted back from the end) index into a
 * 0-based one. */
static bool resolve_index(obj_reader *r, const obj_index *idx, uint32_t count, const char *what,
                          const char *plural, uint32_t *out, arbor_err *e)
{
    if (idx->value > 0 && idx->value <= (int64_t)count) {
        *out = (uint32_t)(idx->value - 1);
        return true;
    }
    if (idx->value < 0 && -idx->value <= (int64_t)count) {
        *out = (uint32_t)((int64_t)count + idx->value);
        return true;
    }
    if (idx->value == 0)
        return text_fail(&r->c, e, "%s index 0 is invalid (OBJ indices start at 1)", what);
    int shown = text_shown(idx->ndigits);
    return text_fail(&r->c, e, "%s index %.*s%s out of range (%u %s)", what, shown, idx->digits,
                     (size_t)shown < idx->ndigits ? "..." : "", count, plural);
}

/* Reads one face vertex: its position and normal indices (ARBOR_NO_NORMAL
 * when it names none); the texture index is checked against the vt lines
 * seen so far. */
static bool read_face_vertex(obj_reader *r, uint32_t *vert, uint32_t *normal, arbor_err *e)
{
    obj_index idx[3];
    const char *end = split_face_vertex(&r->c, r->c.p, idx);
    if (end == NULL) {
        char word[40];
        text_excerpt(word, sizeof word, r->c.p, r->c.end);
        return text_fail(&r->c, e, "malformed face vertex '%s'", word);
    }
    uint32_t unused;
    *normal = ARBOR_NO_NORMAL;
    if (!resolve_index(r, &idx[0], r->m->nverts, "vertex", "vertices", vert, e)
        || (idx[1].present
            && !resolve_index(r, &idx[1], r->ntexcoords, "texture coordinate", "texture coordinates", &unused, e))
        || (idx[2].present && !resolve_index(r, &idx[2], r->m->nnormals, "normal", "normals", normal, e)))
        return false;
    r->c.p = end;
    return true;
}

/* A polygon of k vertices becomes the fan of k - 2 triangles around its
 * first vertex, added as the vertices are read. */
static bool read_face(obj_reader *r, arbor_err *e)
{
    uint32_t first = 0, prev = 0, n = 0, first_n = ARBOR_NO_NORMAL, prev_n = ARBOR_NO_NORMAL;
    while (!text_at_eol(&r->c)) {
        uint32_t v, vn;
        if (!read_face_vertex(r, &v, &vn, e))
            return false;
        if (n >= 2 && !arbor_mesh_add_tri(r->m, first, prev, v, r->mat, e))
            return false;
        bool normals = first_n != ARBOR_NO_NORMAL || prev_n != ARBOR_NO_NORMAL || vn != ARBOR_NO_NORMAL;
        if (n >= 2 && normals && !arbor_mesh_set_last_tri_normals(r->m, first_n, prev_n, vn, e))
            return false;
        if (n == 0) {
            first = v;
            first_n = vn;
        }
        prev = v;
        prev_n = vn;
        n++;
    }
    if (n < 3)
        return text_fail(&r->c, e, "face has %u vertices (needs at least 3)", n);
    return true;
}

/* ---- vertices ---- */

static bool read_vertex(obj_reader *r, arbor_err *e)
{
    arbor_vec3 p;
    if (!text_read_float(&r->c, "vertex coordinate", &p.x, e) || !text_read_float(&r->c, "vertex coordinate", &p.y, e)
        || !text_read_float(&r->c, "vertex coordinate", &p.z, e))
        return false;
    return arbor_mesh_add_vert(r->m, p, e);
}

/* Normals are kept for smooth shading; faces refer to them by index. */
static bool read_normal(obj_reader *r, arbor_err *e)
{
    arbor_vec3 n;
    if (!text_read_float(&r->c, "normal component", &n.x, e) || !text_read_float(&r->c, "normal component", &n.y, e)
        || !text_read_float(&r->c, "normal component", &n.z, e))
        return false;
    return arbor_mesh_add_normal(r->m, n, e);
}

/* ---- materials ---- */

static bool use_material(obj_reader *r, arbor_err *e)
{
    const char *w;
    size_t n = text_word(&r->c, &w);
    if (n == 0)
        return text_fail(&r->c, e, "usemtl without a material name");
    char name[ARBOR_MATERIAL_NAME_MAX];
    material_name(name, w, n);
    int64_t found = material_table_find(&r->mats, name);
    if (found >= 0) {
        r->mat = (uint32_t)found;
        return true;
    }
    arbor_mesh_warn(r->m, "%s:%u: material '%s' is not defined; using default values", r->c.name, r->c.line, name);
    return material_table_add(&r->mats, &r->c, name, &r->mat, e);
}

/* The model folder's real path, resolved at the first mtllib; NULL (and a
 * warning) when it cannot be. Running out of memory is no reason to load
 * the model without its materials: it fails the load (false). */
static bool real_dir(obj_reader *r, const char **out, arbor_err *e)
{
    if (r->real_dir == NULL && (r->real_dir = realpath(r->dir, NULL)) == NULL) {
        if (errno == ENOMEM)
            return arbor_fail(e, ARBOR_ERR_NOMEM, "%s:%u: out of memory resolving the model's folder", r->c.name,
                              r->c.line);
        arbor_mesh_warn(r->m, "%s:%u: the model's folder '%s' cannot be resolved; material libraries not loaded",
                        r->c.name, r->c.line, r->dir);
    }
    *out = r->real_dir;
    return true;
}

/* True when the library (w, n) was loaded before; otherwise remembers it
 * (or warns that there are too many). */
static bool seen_library(obj_reader *r, const char *w, size_t n)
{
    for (uint32_t i = 0; i < r->nlibs; i++)
        if (r->libs[i].len == n && memcmp(r->libs[i].name, w, n) == 0)
            return true;
    if (r->nlibs == OBJ_MAX_LIBRARIES) {
        arbor_mesh_warn(r->m, "%s:%u: more than %d material libraries; '%.*s' ignored", r->c.name, r->c.line,
                        OBJ_MAX_LIBRARIES, text_shown(n), w);
        return true;
    }
    r->libs[r->nlibs].name = w;
    r->libs[r->nlibs].len = n;
    r->nlibs++;
    return false;
}

/* Missing or unreadable libraries (and ones outside the model's folder) are
 * warnings: the model still loads, with default materials. A library that
 * exists but is malformed fails the load like the OBJ itself would.
 * "Outside" is decided on real paths, with every symbolic link and ".."
 * resolved, so neither "../x.mtl" nor a link inside the folder that points
 * out of it can make the loader read a file elsewhere. */
static bool load_library(obj_reader *r, const char *w, size_t n, arbor_err *e)
{
    char path[4096];
    if (strlen(r->dir) + 1 + n >= sizeof path) {
        arbor_mesh_warn(r->m, "%s:%u: material library path too long; not loaded", r->c.name, r->c.line);
        return true;
    }
    snprintf(path, sizeof path, "%s/%.*s", r->dir, (int)n, w);
    const char *dir = NULL;
    if (!real_dir(r, &dir, e))
        return false;
    if (dir == NULL)
        return true;
    char *real = realpath(path, NULL);
    arbor_err err;
    bool ok;
    if (real == NULL) {
        int why = errno;
        if (why == ENOENT && strchr(path + strlen(r->dir) + 1, '/') == NULL &&
            !arbor_mesh_add_missing_library(r->m, w, n, e))
            return false;
        ok = arbor_fail_errno(&err, path, "cannot open", why);
    } else if (!arbor_real_path_inside(real, dir)) {
        arbor_mesh_warn(r->m, "%s:%u: material library '%.*s' is outside the model's folder; not loaded", r->c.name,
                        r->c.line, text_shown(n), w);
        free(real);
        return true;
    } else {
        ok = mtl_load(&r->mats, real, &err);
    }
    free(real);
    if (ok)
        return true;
    if (err.status != ARBOR_ERR_IO) {
        if (e != NULL)
            *e = err;
        return false;
    }
    arbor_mesh_warn(r->m, "%s:%u: material library not loaded (%s); using default materials", r->c.name, r->c.line,
                    err.msg);
    return true;
}

static bool load_libraries(obj_reader *r, arbor_err *e)
{
    const char *w;
    size_t n;
    while ((n = text_word(&r->c, &w)) > 0)
        if (r->dir != NULL && !seen_library(r, w, n) && !load_library(r, w, n, e))
            return false;
    return true;
}

/* ---- statements ---- */

/* The OBJ statements arbor has no use for (free-form geometry, grouping,
 * display and render attributes), most frequent first. */
static const char *const skipped_statements[] = {
    "s", "g", "o", "vp", "l", "p", "mg", "usemap", "maplib", "cstype", "deg", "bmat", "step", "curv", "curv2",
    "surf", "parm", "trim", "hole", "scrv", "sp", "end", "con", "bevel", "c_interp", "d_interp", "lod",
    "shadow_obj", "trace_obj", "ctech", "stech", "call", "csh", "bsp", "bzp", "cdc", "cdp", "res",
};

/* A line that starts with no OBJ statement: an error if it holds control
 * bytes (binary data), else counted for the warning at the end. Cold and out
 * of line, so that the parse loop stays as tight as before. */
static __attribute__((noinline, cold)) bool unknown_statement(obj_reader *r, const char *w, size_t n, arbor_err *e)
{
    for (size_t i = 0; i < sizeof skipped_statements / sizeof skipped_statements[0]; i++)
        if (text_word_is(w, n, skipped_statements[i]))
            return true;
    for (const char *p = w; p < r->c.end && *p != '\n'; p++)
        if ((unsigned char)*p < 0x20 && !text_is_blank(*p))
            return text_fail(&r->c, e, "binary data (byte 0x%02x): not an OBJ file", (unsigned char)*p);
    if (r->nunknown++ == 0) {
        r->unknown_line = r->c.line;
        text_excerpt(r->unknown_word, sizeof r->unknown_word, w, r->c.end);
    }
    return true;
}

static bool read_statement(obj_reader *r, const char *w, size_t n, arbor_err *e)
{
    if (n == 1 && w[0] == 'v')
        return read_vertex(r, e);
    if (n == 1 && w[0] == 'f')
        return read_face(r, e);
    if (n == 2 && w[0] == 'v' && w[1] == 'n')
        return read_normal(r, e);
    if (n == 2 && w[0] == 'v' && w[1] == 't') {
        if (r->ntexcoords < UINT32_MAX)
            r->ntexcoords++;
        return true;
    }
    if (text_word_is(w, n, "usemtl"))
        return use_material(r, e);
    if (text_word_is(w, n, "mtllib"))
        return load_libraries(r, e);
    if (n == 0 || w[0] == '#')
        return true;
    return unknown_statement(r, w, n, e);
}

bool arbor_load_obj_text(const char *text, size_t len, const char *name, const char *dir, arbor_mesh *m,
                         arbor_err *e)
{
    arbor_mesh_init(m);
    obj_reader r = {.dir = dir, .m = m};
    text_cursor_init(&r.c, text, len, name);
    material_table_init(&r.mats, m);
    /* material 0 is the default, for faces before any usemtl */
    bool ok = material_table_add(&r.mats, &r.c, "default", &r.mat, e);
    while (ok && r.c.p < r.c.end) {
        const char *w;
        size_t n = text_word(&r.c, &w);
        ok = read_statement(&r, w, n, e);
        text_next_line(&r.c);
    }
    if (ok && r.nunknown > 0)
        arbor_mesh_warn(m, "%s:%u: '%s' is not an OBJ statement; %u such line%s ignored", name, r.unknown_line,
                        r.unknown_word, r.nunknown, r.nunknown == 1 ? "" : "s");
    material_table_free(&r.mats);
    free(r.real_dir);
    return loader_finish(ok, m, name, e);
}
