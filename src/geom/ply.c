/*
 * ply.c - the Stanford PLY reader (arbor_load_ply_data, see
 * include/arbor/load.h).
 *
 * The header is read line by line; the body is ascii or binary in either
 * byte order. From the vertex element only x, y, z are kept and from the
 * face element only the vertex_indices (or vertex_index) list; every other
 * property and element is read past, which in binary needs each one's size,
 * lists included. Every value read is bounds-checked, so a short or hostile
 * file ends in an error, never a read past the buffer. In ascii each item is
 * one line: a line with values missing or left over is an error there, as a
 * stream of values would let one short line shift every item after it.
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "arbor/load.h"
#include "loader.h"

#define PLY_MAX_ELEMENTS 16
#define PLY_MAX_PROPERTIES 64

typedef enum { PLY_INT8, PLY_UINT8, PLY_INT16, PLY_UINT16, PLY_INT32, PLY_UINT32, PLY_FLOAT32, PLY_FLOAT64 } ply_type;

static const struct {
    const char *name, *alias;
    unsigned size;
} ply_types[] = {
    [PLY_INT8] = {"char", "int8", 1},      [PLY_UINT8] = {"uchar", "uint8", 1},
    [PLY_INT16] = {"short", "int16", 2},   [PLY_UINT16] = {"ushort", "uint16", 2},
    [PLY_INT32] = {"int", "int32", 4},     [PLY_UINT32] = {"uint", "uint32", 4},
    [PLY_FLOAT32] = {"float", "float32", 4}, [PLY_FLOAT64] = {"double", "float64", 8},
};

typedef enum { ROLE_SKIP, ROLE_X, ROLE_Y, ROLE_Z, ROLE_INDICES } ply_role;

typedef struct {
    ply_type type;       /* of the value, or of each item of a list */
    ply_type count_type; /* of a list's length */
    bool is_list;
    ply_role role;
} ply_property;

typedef enum { ELEMENT_OTHER, ELEMENT_VERTEX, ELEMENT_FACE } ply_element_kind;

typedef struct {
    char name[32];
    ply_element_kind kind;
    uint32_t count;
    uint32_t nprops;
    uint32_t nlists; /* of the properties, how many are lists */
    ply_property props[PLY_MAX_PROPERTIES];
} ply_element;

typedef enum { PLY_ASCII, PLY_BINARY_LE, PLY_BINARY_BE } ply_format;

typedef struct {
    text_cursor c; /* the header, then the body (binary bodies use only c.p) */
    arbor_mesh *m;
    ply_format format;
    bool has_format;
    ply_element elems[PLY_MAX_ELEMENTS];
    uint32_t nelems;
    uint32_t nverts; /* the vertex element's count, for checking indices */
    const ply_element *elem; /* where the body is, for messages */
    uint32_t item;
    /* the item's values so far, and how many it needs: one per property,
     * plus each list's length once read (ascii checks its line by them) */
    uint32_t nvalues, need, lists_unread;
} ply_reader;

/* Body errors: "NAME:LINE:" in ascii, "NAME: ELEMENT ITEM:" in binary. */
static bool body_fail(const ply_reader *r, arbor_err *e, const char *fmt, ...) __attribute__((format(printf, 3, 4)));
static bool body_fail(const ply_reader *r, arbor_err *e, const char *fmt, ...)
{
    char msg[400];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    if (r->format == PLY_ASCII)
        return text_fail(&r->c, e, "%s", msg);
    return arbor_fail(e, ARBOR_ERR_PARSE, "%s: %s %u: %s", r->c.name, r->elem->name, r->item, msg);
}

/* ---- header ---- */

/* The type named by the word (w, n). */
static bool parse_type(const text_cursor *c, const char *w, size_t n, ply_type *out, arbor_err *e)
{
    for (int t = PLY_INT8; t <= PLY_FLOAT64; t++) {
        if (text_word_is(w, n, ply_types[t].name) || text_word_is(w, n, ply_types[t].alias)) {
            *out = (ply_type)t;
            return true;
        }
    }
    if (n == 0)
        return text_fail(c, e, "property without a type");
    char word[40];
    text_excerpt(word, sizeof word, w, c->end);
    return text_fail(c, e, "unknown property type '%s'", word);
}

static bool read_format(ply_reader *r, arbor_err *e)
{
    const char *w, *version;
    size_t n = text_word(&r->c, &w);
    size_t nversion = text_word(&r->c, &version);
    if (text_word_is(w, n, "ascii"))
        r->format = PLY_ASCII;
    else if (text_word_is(w, n, "binary_little_endian"))
        r->format = PLY_BINARY_LE;
    else if (text_word_is(w, n, "binary_big_endian"))
        r->format = PLY_BINARY_BE;
    else
        return text_fail(&r->c, e, "unknown format '%.*s'", text_shown(n), w);
    if (!text_word_is(version, nversion, "1.0"))
        return text_fail(&r->c, e, "unsupported PLY version '%.*s' (1.0 expected)", text_shown(nversion),
                         version);
    r->has_format = true;
    return true;
}

static bool read_element(ply_reader *r, arbor_err *e)
{
    if (r->nelems == PLY_MAX_ELEMENTS)
        return text_fail(&r->c, e, "more than %d elements", PLY_MAX_ELEMENTS);
    ply_element *el = &r->elems[r->nelems];
    memset(el, 0, sizeof *el);
    const char *w;
    size_t n = text_word(&r->c, &w);
    if (n == 0)
        return text_fail(&r->c, e, "element without a name");
    snprintf(el->name, sizeof el->name, "%.*s", text_shown(n), w);
    el->kind = text_word_is(w, n, "vertex") ? ELEMENT_VERTEX : text_word_is(w, n, "face") ? ELEMENT_FACE : ELEMENT_OTHER;
    for (uint32_t i = 0; i < r->nelems; i++)
        if (el->kind != ELEMENT_OTHER && r->elems[i].kind == el->kind)
            return text_fail(&r->c, e, "second '%s' element", el->name);
    int64_t count;
    if (!text_read_int(&r->c, "element count", 0, UINT32_MAX, &count, e))
        return false;
    el->count = (uint32_t)count;
    if (el->kind == ELEMENT_VERTEX)
        r->nverts = el->count;
    r->nelems++;
    return true;
}

/* The role of property `name` in element el; each role goes to the first
 * property that can fill it. */
static bool assign_role(ply_reader *r, ply_element *el, ply_property *prop, const char *w, size_t n, arbor_err *e)
{
    ply_role role = ROLE_SKIP;
    if (el->kind == ELEMENT_VERTEX && n == 1 && (w[0] == 'x' || w[0] == 'y' || w[0] == 'z'))
        role = (ply_role)(ROLE_X + (w[0] - 'x'));
    else if (el->kind == ELEMENT_FACE && (text_word_is(w, n, "vertex_indices") || text_word_is(w, n, "vertex_index")))
        role = ROLE_INDICES;
    for (uint32_t i = 0; i < el->nprops && role != ROLE_SKIP; i++)
        if (el->props[i].role == role)
            role = ROLE_SKIP;
    if (role == ROLE_INDICES && !prop->is_list)
        return text_fail(&r->c, e, "face property '%.*s' is not a list", text_shown(n), w);
    if (role != ROLE_SKIP && role != ROLE_INDICES && prop->is_list)
        return text_fail(&r->c, e, "vertex property '%.*s' is a list", text_shown(n), w);
    prop->role = role;
    return true;
}

static bool read_property(ply_reader *r, arbor_err *e)
{
    if (r->nelems == 0)
        return text_fail(&r->c, e, "property before any element");
    ply_element *el = &r->elems[r->nelems - 1];
    if (el->nprops == PLY_MAX_PROPERTIES)
        return text_fail(&r->c, e, "element '%s' has more than %d properties", el->name, PLY_MAX_PROPERTIES);
    ply_property *prop = &el->props[el->nprops];
    memset(prop, 0, sizeof *prop);
    const char *w;
    size_t n = text_word(&r->c, &w);
    if (text_word_is(w, n, "list")) {
        prop->is_list = true;
        n = text_word(&r->c, &w);
        if (!parse_type(&r->c, w, n, &prop->count_type, e))
            return false;
        if (prop->count_type >= PLY_FLOAT32)
            return text_fail(&r->c, e, "list length type must be an integer type");
        n = text_word(&r->c, &w);
    }
    if (!parse_type(&r->c, w, n, &prop->type, e))
        return false;
    if ((n = text_word(&r->c, &w)) == 0)
        return text_fail(&r->c, e, "property without a name");
    if (!assign_role(r, el, prop, w, n, e))
        return false;
    el->nlists += prop->is_list;
    el->nprops++;
    return true;
}

static bool require_role(const ply_reader *r, const ply_element *el, ply_role role, arbor_err *e)
{
    static const char *const names[] = {[ROLE_X] = "x", [ROLE_Y] = "y", [ROLE_Z] = "z",
                                        [ROLE_INDICES] = "vertex_indices"};
    for (uint32_t k = 0; k < el->nprops; k++)
        if (el->props[k].role == role)
            return true;
    return arbor_fail(e, ARBOR_ERR_PARSE, "%s: element '%s' has no '%s' property", r->c.name, el->name, names[role]);
}

/* The vertex element must carry x, y and z; the face element its index list. */
static bool check_roles(const ply_reader *r, arbor_err *e)
{
    for (uint32_t i = 0; i < r->nelems; i++) {
        const ply_element *el = &r->elems[i];
        if (el->kind == ELEMENT_VERTEX
            && !(require_role(r, el, ROLE_X, e) && require_role(r, el, ROLE_Y, e) && require_role(r, el, ROLE_Z, e)))
            return false;
        if (el->kind == ELEMENT_FACE && !require_role(r, el, ROLE_INDICES, e))
            return false;
    }
    return true;
}

static bool read_header_line(ply_reader *r, const char *w, size_t n, bool *done, arbor_err *e)
{
    if (n == 0 || text_word_is(w, n, "comment") || text_word_is(w, n, "obj_info"))
        return true;
    bool ok;
    if (text_word_is(w, n, "format"))
        ok = read_format(r, e);
    else if (text_word_is(w, n, "element"))
        ok = read_element(r, e);
    else if (text_word_is(w, n, "property"))
        ok = read_property(r, e);
    else if (text_word_is(w, n, "end_header"))
        ok = *done = true;
    else {
        char word[40];
        text_excerpt(word, sizeof word, w, r->c.end);
        return text_fail(&r->c, e, "unknown header line '%s'", word);
    }
    if (ok && !text_at_eol(&r->c))
        return text_fail(&r->c, e, "unexpected text at the end of the line");
    return ok;
}

static bool read_header(ply_reader *r, arbor_err *e)
{
    const char *w;
    size_t n = text_word(&r->c, &w);
    if (!text_word_is(w, n, "ply") || !text_at_eol(&r->c))
        return arbor_fail(e, ARBOR_ERR_PARSE, "%s:1: not a PLY file (no 'ply' line)", r->c.name);
    text_next_line(&r->c);
    bool done = false;
    while (!done) {
        if (r->c.p == r->c.end)
            return text_fail(&r->c, e, "header ends without end_header");
        n = text_word(&r->c, &w);
        if (!read_header_line(r, w, n, &done, e))
            return false;
        /* the body starts right after end_header's newline, which in a
         * binary file is where the bytes begin */
        text_next_line(&r->c);
    }
    if (!r->has_format)
        return arbor_fail(e, ARBOR_ERR_PARSE, "%s: header has no format line", r->c.name);
    return check_roles(r, e);
}

/* ---- body values ---- */

/* Binary: a value of type t at the cursor, in the file's byte order. */
static bool read_binary(ply_reader *r, ply_type t, double *out, arbor_err *e)
{
    unsigned size = ply_types[t].size;
    if ((size_t)(r->c.end - r->c.p) < size)
        return body_fail(r, e, "truncated binary data (element has %u items)", r->elem->count);
    const unsigned char *b = (const unsigned char *)r->c.p;
    uint64_t bits = 0;
    for (unsigned i = 0; i < size; i++)
        bits |= (uint64_t)b[r->format == PLY_BINARY_LE ? i : size - 1 - i] << (8 * i);
    r->c.p += size;
    float f;
    double d;
    uint32_t u32 = (uint32_t)bits;
    switch (t) {
    case PLY_INT8: *out = (int8_t)bits; break;
    case PLY_UINT8: *out = (uint8_t)bits; break;
    case PLY_INT16: *out = (int16_t)bits; break;
    case PLY_UINT16: *out = (uint16_t)bits; break;
    case PLY_INT32: *out = (int32_t)u32; break;
    case PLY_UINT32: *out = u32; break;
    case PLY_FLOAT32: memcpy(&f, &u32, sizeof f); *out = f; break;
    case PLY_FLOAT64: memcpy(&d, &bits, sizeof d); *out = d; break;
    }
    return true;
}

/* Ascii: a line holding other than the item's values. */
static bool wrong_count(const ply_reader *r, uint32_t got, arbor_err *e)
{
    return body_fail(r, e, "%u value%s where element '%s' needs %s%u", got, got == 1 ? "" : "s", r->elem->name,
                     r->lists_unread ? "at least " : "", r->need);
}

/* Ascii: the next number on the item's line. Floats go through the float
 * parser so coordinates round once, straight to float. */
static bool read_ascii(ply_reader *r, ply_type t, double *out, arbor_err *e)
{
    text_skip_blanks(&r->c);
    if (r->c.p == r->c.end || *r->c.p == '\n')
        return wrong_count(r, r->nvalues, e);
    const char *q;
    if (t >= PLY_FLOAT32) {
        float f = 0.0f;
        q = arbor_parse_float(r->c.p, r->c.end, &f);
        *out = f;
    } else {
        int64_t i = 0;
        q = text_parse_int(r->c.p, r->c.end, &i);
        *out = (double)i;
    }
    if (q == NULL || !text_is_delim(&r->c, q)) {
        char word[40];
        text_excerpt(word, sizeof word, r->c.p, r->c.end);
        return body_fail(r, e, "malformed number '%s' in element '%s'", word, r->elem->name);
    }
    r->c.p = q;
    r->nvalues++;
    return true;
}

static bool read_value(ply_reader *r, ply_type t, double *out, arbor_err *e)
{
    return r->format == PLY_ASCII ? read_ascii(r, t, out, e) : read_binary(r, t, out, e);
}

/* A list's length: a whole number, not negative. */
static bool read_length(ply_reader *r, const ply_property *prop, uint32_t *out, arbor_err *e)
{
    double v;
    if (!read_value(r, prop->count_type, &v, e))
        return false;
    if (!(v >= 0 && v <= UINT32_MAX))
        return body_fail(r, e, "list length %.0f out of range", v);
    *out = (uint32_t)v;
    r->need = *out > UINT32_MAX - r->need ? UINT32_MAX : r->need + *out;
    r->lists_unread--;
    return true;
}

static bool skip_property(ply_reader *r, const ply_property *prop, arbor_err *e)
{
    double v;
    uint32_t n = 1;
    if (prop->is_list && !read_length(r, prop, &n, e))
        return false;
    if (r->format != PLY_ASCII) {
        uint64_t bytes = (uint64_t)n * ply_types[prop->type].size;
        if ((uint64_t)(r->c.end - r->c.p) < bytes)
            return body_fail(r, e, "truncated binary data (element has %u items)", r->elem->count);
        r->c.p += bytes;
        return true;
    }
    for (uint32_t i = 0; i < n; i++)
        if (!read_value(r, prop->type, &v, e))
            return false;
    return true;
}

/* ---- elements ---- */

static bool read_coordinate(ply_reader *r, const ply_property *prop, float *out, arbor_err *e)
{
    double v;
    if (!read_value(r, prop->type, &v, e))
        return false;
    *out = (float)v;
    if (!isfinite(*out))
        return body_fail(r, e, "%s vertex coordinate", isnan(v) ? "NaN" : "infinite");
    return true;
}

static bool read_vertex_index(ply_reader *r, const ply_property *prop, uint32_t *out, arbor_err *e)
{
    double v;
    if (!read_value(r, prop->type, &v, e))
        return false;
    if (v != floor(v))
        return body_fail(r, e, "vertex index %g is not a whole number", v);
    if (!(v >= 0 && v < r->nverts))
        return body_fail(r, e, "vertex index %.0f out of range (%u vertices)", v, r->nverts);
    *out = (uint32_t)v;
    return true;
}

/* Fan-triangulates the polygon as its indices are read. */
static bool read_polygon(ply_reader *r, const ply_property *prop, arbor_err *e)
{
    uint32_t n, first = 0, prev = 0;
    if (!read_length(r, prop, &n, e))
        return false;
    if (n < 3)
        return body_fail(r, e, "face has %u vertices (needs at least 3)", n);
    for (uint32_t i = 0; i < n; i++) {
        uint32_t v = 0;
        if (!read_vertex_index(r, prop, &v, e))
            return false;
        if (i >= 2 && !arbor_mesh_add_tri(r->m, first, prev, v, 0, e))
            return false;
        if (i == 0)
            first = v;
        prev = v;
    }
    return true;
}

/* One item of any element: the properties with a role (x, y, z in the
 * vertex element, the index list in the face element) are used, the others
 * read past. */
static bool read_item(ply_reader *r, const ply_element *el, arbor_err *e)
{
    float xyz[3] = {0, 0, 0};
    r->nvalues = 0;
    r->need = el->nprops;
    r->lists_unread = el->nlists;
    for (uint32_t k = 0; k < el->nprops; k++) {
        const ply_property *prop = &el->props[k];
        bool ok = prop->role == ROLE_SKIP      ? skip_property(r, prop, e)
                  : prop->role == ROLE_INDICES ? read_polygon(r, prop, e)
                                               : read_coordinate(r, prop, &xyz[prop->role - ROLE_X], e);
        if (!ok)
            return false;
    }
    return el->kind != ELEMENT_VERTEX || arbor_mesh_add_vert(r->m, vec3(xyz[0], xyz[1], xyz[2]), e);
}

/* Ascii: moves past blank lines; true when text is left. */
static bool skip_blank_lines(ply_reader *r)
{
    for (text_skip_blanks(&r->c); r->c.p < r->c.end && *r->c.p == '\n'; text_skip_blanks(&r->c))
        text_next_line(&r->c);
    return r->c.p < r->c.end;
}

/* Ascii: finds the item's line (blank lines before it are allowed). */
static bool start_line(ply_reader *r, const ply_element *el, arbor_err *e)
{
    if (!skip_blank_lines(r)) {
        /* name the file's last line, not the empty one after its newline */
        if (r->c.line > 1 && r->c.end[-1] == '\n')
            r->c.line--;
        return body_fail(r, e, "data ends in element '%s' (item %u of %u)", el->name, r->item, el->count);
    }
    return true;
}

/* Ascii: the item's line must end after its values. */
static bool end_line(ply_reader *r, arbor_err *e)
{
    const char *w;
    uint32_t got = r->nvalues;
    while (text_word(&r->c, &w) > 0)
        got++;
    if (got != r->nvalues)
        return wrong_count(r, got, e);
    text_next_line(&r->c);
    return true;
}

/* What follows the last element is ignored, with a warning: a reader
 * that stopped early, or a writer that counted wrong, should be seen. */
static void warn_trailing(ply_reader *r)
{
    if (r->format != PLY_ASCII) {
        if (r->c.p < r->c.end)
            arbor_mesh_warn(r->m, "%s: %zu bytes after the last element ignored", r->c.name,
                            (size_t)(r->c.end - r->c.p));
        return;
    }
    if (!skip_blank_lines(r))
        return;
    uint32_t first = r->c.line, lines = 0;
    while (skip_blank_lines(r)) {
        lines++;
        text_next_line(&r->c);
    }
    arbor_mesh_warn(r->m, "%s:%u: %u line%s after the last element ignored", r->c.name, first, lines,
                    lines == 1 ? "" : "s");
}

static bool read_body(ply_reader *r, arbor_err *e)
{
    bool ascii = r->format == PLY_ASCII;
    for (uint32_t i = 0; i < r->nelems; i++) {
        const ply_element *el = &r->elems[i];
        r->elem = el;
        /* an element without properties has nothing to read, however many items */
        for (r->item = 0; el->nprops > 0 && r->item < el->count; r->item++) {
            if ((ascii && !start_line(r, el, e)) || !read_item(r, el, e) || (ascii && !end_line(r, e)))
                return false;
        }
    }
    warn_trailing(r);
    return true;
}

bool arbor_load_ply_data(const char *data, size_t len, const char *name, arbor_mesh *m, arbor_err *e)
{
    arbor_mesh_init(m);
    ply_reader *r = calloc(1, sizeof *r);
    if (r == NULL)
        return arbor_fail(e, ARBOR_ERR_NOMEM, "%s: out of memory", name);
    r->m = m;
    text_cursor_init(&r->c, data, len, name);
    bool ok = read_header(r, e) && read_body(r, e);
    free(r);
    return loader_finish(ok, m, name, e);
}
