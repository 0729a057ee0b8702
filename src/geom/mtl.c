/*
 * mtl.c - Wavefront MTL material libraries and the name index that OBJ
 * usemtl lines and MTL newmtl lines share (see src/geom/loader.h).
 *
 * Read: newmtl, Kd, Ks, Ke (colours), Ns, Ni, d (floats), illum (integer);
 * every other statement is skipped.
 */
#include <stdlib.h>
#include <string.h>

#include "arbor/load.h"
#include "loader.h"

/* ---- the name index ---- */

void material_table_init(material_table *t, arbor_mesh *m)
{
    t->m = m;
    t->slots = NULL;
    t->cap = 0;
}

void material_table_free(material_table *t)
{
    free(t->slots);
    material_table_init(t, t->m);
}

void material_name(char name[ARBOR_MATERIAL_NAME_MAX], const char *w, size_t n)
{
    if (n >= ARBOR_MATERIAL_NAME_MAX)
        n = ARBOR_MATERIAL_NAME_MAX - 1;
    memcpy(name, w, n);
    name[n] = '\0';
}

/* FNV-1a */
static uint32_t name_hash(const char *s)
{
    uint32_t h = 2166136261u;
    for (; *s; s++)
        h = (h ^ (unsigned char)*s) * 16777619u;
    return h;
}

/* The slot holding name, or the free slot where it belongs. */
static uint32_t find_slot(const material_table *t, const char *name)
{
    uint32_t mask = t->cap - 1, i = name_hash(name) & mask;
    while (t->slots[i] != 0 && strcmp(t->m->mats[t->slots[i] - 1].name, name) != 0)
        i = (i + 1) & mask;
    return i;
}

int64_t material_table_find(const material_table *t, const char *name)
{
    if (t->cap == 0)
        return -1;
    uint32_t slot = t->slots[find_slot(t, name)];
    return slot ? (int64_t)slot - 1 : -1;
}

/* Keeps the table at most half full, re-indexing every material name. */
static bool table_reserve(material_table *t, uint32_t nmats, arbor_err *e)
{
    if ((uint64_t)nmats * 2 < t->cap)
        return true;
    uint32_t cap = t->cap ? t->cap * 2 : 64;
    uint32_t *slots = cap <= (1u << 30) ? calloc(cap, sizeof *slots) : NULL;
    if (slots == NULL)
        return arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory indexing %u materials", nmats);
    free(t->slots);
    t->slots = slots;
    t->cap = cap;
    for (uint32_t i = 0; i < t->m->nmats; i++)
        t->slots[find_slot(t, t->m->mats[i].name)] = i + 1;
    return true;
}

bool material_table_add(material_table *t, const text_cursor *c, const char *name, uint32_t *index, arbor_err *e)
{
    if (t->m->nmats >= ARBOR_MESH_MATERIALS_MAX)
        return text_fail(c, e, "more than %d materials", ARBOR_MESH_MATERIALS_MAX);
    if (!table_reserve(t, t->m->nmats + 1, e) || !arbor_mesh_add_material(t->m, name, index, e))
        return false;
    t->slots[find_slot(t, name)] = *index + 1;
    return true;
}

/* ---- MTL files ---- */

typedef struct {
    text_cursor c;
    material_table *table;
    int64_t current; /* index of the material being defined; -1 before newmtl */
} mtl_reader;

static bool new_material(mtl_reader *r, arbor_err *e)
{
    const char *w;
    size_t n = text_word(&r->c, &w);
    if (n == 0)
        return text_fail(&r->c, e, "newmtl without a material name");
    char name[ARBOR_MATERIAL_NAME_MAX];
    material_name(name, w, n);
    int64_t found = material_table_find(r->table, name);
    if (found >= 0) {
        /* a name that usemtl met first, or defined twice: the file's values win */
        arbor_material_default(&r->table->m->mats[found], name);
        r->current = found;
        return true;
    }
    uint32_t index;
    if (!material_table_add(r->table, &r->c, name, &index, e))
        return false;
    r->current = index;
    return true;
}

/* "Kd r [g b]": g and b default to r. The spectral and xyz forms are not
 * supported; they leave the colour alone, with a warning. */
static bool read_colour(mtl_reader *r, const char *what, arbor_vec3 *out, arbor_err *e)
{
    float first;
    if (!text_at_eol(&r->c) && arbor_parse_float(r->c.p, r->c.end, &first) == NULL) {
        arbor_mesh_warn(r->table->m, "%s:%u: %s form not supported; statement ignored", r->c.name, r->c.line, what);
        return true;
    }
    arbor_vec3 v;
    if (!text_read_float(&r->c, what, &v.x, e))
        return false;
    v.y = v.z = v.x;
    if (!text_at_eol(&r->c) && (!text_read_float(&r->c, what, &v.y, e) || !text_read_float(&r->c, what, &v.z, e)))
        return false;
    *out = v;
    return true;
}

/* "d [-halo] factor" */
static bool read_opacity(mtl_reader *r, float *out, arbor_err *e)
{
    text_skip_blanks(&r->c);
    const char *after = r->c.p + 5;
    if (after <= r->c.end && memcmp(r->c.p, "-halo", 5) == 0 && text_is_delim(&r->c, after))
        r->c.p = after;
    return text_read_float(&r->c, "d", out, e);
}

static bool read_illum(mtl_reader *r, int *out, arbor_err *e)
{
    int64_t illum;
    if (!text_read_int(&r->c, "illum", 0, 10, &illum, e))
        return false;
    *out = (int)illum;
    return true;
}

/* The statements that set a value of the current material. */
static bool is_value_statement(const char *w, size_t n)
{
    static const char *const names[] = {"Kd", "Ks", "Ke", "Ns", "Ni", "d", "illum"};
    for (size_t i = 0; i < sizeof names / sizeof names[0]; i++)
        if (text_word_is(w, n, names[i]))
            return true;
    return false;
}

static bool read_statement(mtl_reader *r, const char *w, size_t n, arbor_err *e)
{
    if (text_word_is(w, n, "newmtl"))
        return new_material(r, e);
    if (!is_value_statement(w, n))
        return true; /* Ka, Tr, texture maps, ...: nothing arbor renders */
    if (r->current < 0)
        return text_fail(&r->c, e, "%.*s before any newmtl", text_shown(n), w);
    arbor_material *mat = &r->table->m->mats[r->current];
    if (text_word_is(w, n, "Kd"))
        return read_colour(r, "Kd", &mat->kd, e);
    if (text_word_is(w, n, "Ks"))
        return read_colour(r, "Ks", &mat->ks, e);
    if (text_word_is(w, n, "Ke"))
        return read_colour(r, "Ke", &mat->ke, e);
    if (text_word_is(w, n, "Ns"))
        return text_read_float(&r->c, "Ns", &mat->ns, e);
    if (text_word_is(w, n, "Ni"))
        return text_read_float(&r->c, "Ni", &mat->ni, e);
    if (text_word_is(w, n, "d"))
        return read_opacity(r, &mat->d, e);
    return read_illum(r, &mat->illum, e);
}

bool mtl_load(material_table *t, const char *path, arbor_err *e)
{
    char *data;
    size_t len;
    if (!loader_read_file(path, false, ARBOR_LOAD_MAX_BYTES, &data, &len, e))
        return false;
    mtl_reader r = {.table = t, .current = -1};
    text_cursor_init(&r.c, data, len, path);
    bool ok = true;
    while (ok && r.c.p < r.c.end) {
        const char *w;
        size_t n = text_word(&r.c, &w);
        ok = read_statement(&r, w, n, e);
        text_next_line(&r.c);
    }
    free(data);
    return ok;
}
