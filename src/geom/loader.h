/*
 * loader.h - private to the model loaders (load.c, textio.c, obj.c, mtl.c,
 * ply.c; procgen.c's OBJ writer shares the I/O error message): reading a
 * whole file into memory, a cursor that walks text line by line with the
 * number readers every format shares, and the table of material names an
 * OBJ and its MTL libraries fill together.
 *
 * Buffers handed out by loader_read_file belong to the caller (free()).
 * Everything else here borrows: a cursor points into text it does not own,
 * a material table points at the mesh whose materials it indexes.
 */
#ifndef ARBOR_GEOM_LOADER_H
#define ARBOR_GEOM_LOADER_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "arbor/err.h"
#include "arbor/mesh.h"

/* Reads the whole file at path into a malloc'd buffer (*data, *len),
 * decompressing it with zlib when gz is true. A missing or unreadable file,
 * gzip data that is truncated or corrupt, or more than max_bytes of file or
 * of decompressed data, is an ARBOR_ERR_IO error. */
bool loader_read_file(const char *path, bool gz, size_t max_bytes, char **data, size_t *len, arbor_err *e);

/* Checks that the mesh has triangles and finishes it (arbor_mesh_finish). On
 * failure, or when ok is false (the parser already failed), frees the mesh,
 * so a loader can end with `return loader_finish(ok, m, name, e);`. */
bool loader_finish(bool ok, arbor_mesh *m, const char *name, arbor_err *e);

/* ---- text cursor ---- */

typedef struct {
    const char *p, *end; /* the unread text */
    const char *name;    /* file name for messages */
    uint32_t line;       /* 1-based line number of p */
} text_cursor;

void text_cursor_init(text_cursor *c, const char *text, size_t len, const char *name);

/* Blanks separate words on a line; '\r' is one, so CRLF files read like LF. */
static inline bool text_is_blank(char ch)
{
    return ch == ' ' || ch == '\t' || ch == '\r' || ch == '\v' || ch == '\f';
}

static inline void text_skip_blanks(text_cursor *c)
{
    while (c->p < c->end && text_is_blank(*c->p))
        c->p++;
}

/* Skips blanks; true when nothing but a comment ('#') is left on the line. */
static inline bool text_at_eol(text_cursor *c)
{
    text_skip_blanks(c);
    return c->p == c->end || *c->p == '\n' || *c->p == '#';
}

/* True when p ends a word: end of text, a blank, a newline or a comment. */
static inline bool text_is_delim(const text_cursor *c, const char *p)
{
    return p == c->end || text_is_blank(*p) || *p == '\n' || *p == '#';
}

/* Moves past the end of the current line. */
void text_next_line(text_cursor *c);

/* Skips blanks and returns the next word on the line (*w, length; 0 at the
 * end of the line), leaving the cursor after it. */
size_t text_word(text_cursor *c, const char **w);

/* True when the word (w, n) is the string s. */
bool text_word_is(const char *w, size_t n, const char *s);

/* Fails with ARBOR_ERR_PARSE and "NAME:LINE: message". */
bool text_fail(const text_cursor *c, arbor_err *e, const char *fmt, ...) __attribute__((format(printf, 3, 4)));

/* A word's length for "%.*s" in messages: at most 60 characters. */
static inline int text_shown(size_t n)
{
    return n > 60 ? 60 : (int)n;
}

/* Copies the word at p (up to a blank or newline) into buf for a message,
 * shortened with "..." and with unprintable bytes shown as '?'. */
void text_excerpt(char *buf, size_t size, const char *p, const char *end);

/* Parses an optionally signed decimal integer at p; returns its end, or NULL
 * when p holds no digits. Magnitudes past 10^17 saturate (still out of any
 * range a caller accepts), so absurdly long numbers never overflow. */
const char *text_parse_int(const char *p, const char *end, int64_t *out);

/* Reads the next word on the line as a finite number; `what` names it in
 * messages ("missing vertex coordinate", "NaN vertex coordinate"). */
bool text_read_float(text_cursor *c, const char *what, float *out, arbor_err *e);

/* Reads the next word on the line as an integer in [lo, hi]. */
bool text_read_int(text_cursor *c, const char *what, int64_t lo, int64_t hi, int64_t *out, arbor_err *e);

/* ---- materials by name (OBJ usemtl and MTL newmtl) ---- */

/* A hash index over the mesh's material names, so files with many materials
 * or many usemtl lines stay linear. */
typedef struct {
    arbor_mesh *m;
    uint32_t *slots; /* material index + 1; 0 marks a free slot */
    uint32_t cap;    /* a power of two, at least twice the materials */
} material_table;

void material_table_init(material_table *t, arbor_mesh *m);
void material_table_free(material_table *t);

/* The material's name as stored: the word (w, n) cut to fit arbor_material. */
void material_name(char name[ARBOR_MATERIAL_NAME_MAX], const char *w, size_t n);

/* Index of the material called name (as made by material_name), or -1. */
int64_t material_table_find(const material_table *t, const char *name);

/* Appends a material with default values to the mesh and the table. */
/* At most ARBOR_MESH_MATERIALS_MAX materials: past it a parse error at c's
 * line. */
bool material_table_add(material_table *t, const text_cursor *c, const char *name, uint32_t *index, arbor_err *e);

/* Reads the MTL file at path into the table's mesh: new names are appended,
 * names already present get the file's values. A file that cannot be read is
 * an ARBOR_ERR_IO error (the OBJ reader turns it into a warning), malformed
 * content an ARBOR_ERR_PARSE one. */
bool mtl_load(material_table *t, const char *path, arbor_err *e);

#endif
