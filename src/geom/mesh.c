/*
 * mesh.c - growing, finishing and freeing triangle meshes
 * (see include/arbor/mesh.h).
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "arbor/mesh.h"
#include "arbor/ray.h"

void arbor_mesh_init(arbor_mesh *m)
{
    memset(m, 0, sizeof *m);
    m->bounds = aabb_empty();
}

void arbor_mesh_free(arbor_mesh *m)
{
    free(m->verts);
    free(m->tri_verts);
    free(m->tri_mat);
    free(m->normals);
    free(m->tri_normals);
    free(m->mats);
    for (uint32_t i = 0; i < m->nwarnings; i++)
        free(m->warnings[i]);
    free(m->warnings);
    for (uint32_t i = 0; i < m->nmissing_libraries; i++)
        free(m->missing_libraries[i]);
    free(m->missing_libraries);
    arbor_mesh_init(m);
}

/* Makes room for one more element in an array of *cap elements of `size`
 * bytes (doubling), so appends are amortised O(1). */
static bool grow(void **arr, uint32_t *cap, uint32_t count, size_t size, arbor_err *e)
{
    if (count < *cap)
        return true;
    if (*cap >= UINT32_MAX / 2)
        return arbor_fail(e, ARBOR_ERR_NOMEM, "mesh too large (%u elements)", count);
    uint32_t ncap = *cap ? *cap * 2 : 256;
    void *p = realloc(*arr, (size_t)ncap * size);
    if (p == NULL)
        return arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory growing mesh to %u elements", ncap);
    *arr = p;
    *cap = ncap;
    return true;
}

bool arbor_mesh_add_vert(arbor_mesh *m, arbor_vec3 p, arbor_err *e)
{
    if (!grow((void **)&m->verts, &m->cap_verts, m->nverts, sizeof *m->verts, e))
        return false;
    m->verts[m->nverts++] = p;
    return true;
}

bool arbor_mesh_add_tri(arbor_mesh *m, uint32_t a, uint32_t b, uint32_t c, uint32_t mat, arbor_err *e)
{
    uint32_t cap = m->cap_tris;
    if (!grow((void **)&m->tri_mat, &cap, m->ntris, sizeof *m->tri_mat, e))
        return false;
    if (cap != m->cap_tris) {
        uint32_t *tv = realloc(m->tri_verts, (size_t)cap * 3 * sizeof *tv);
        if (tv == NULL)
            return arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory growing mesh to %u triangles", cap);
        m->tri_verts = tv;
    }
    if (m->tri_normals != NULL && cap != m->cap_tris) {
        uint32_t *tn = realloc(m->tri_normals, (size_t)cap * 3 * sizeof *tn);
        if (tn == NULL)
            return arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory growing mesh to %u triangles", cap);
        m->tri_normals = tn;
    }
    m->cap_tris = cap > m->cap_tris ? cap : m->cap_tris;
    uint32_t *t = m->tri_verts + 3 * (size_t)m->ntris;
    t[0] = a;
    t[1] = b;
    t[2] = c;
    if (m->tri_normals != NULL)
        for (int k = 0; k < 3; k++)
            m->tri_normals[3 * (size_t)m->ntris + (size_t)k] = ARBOR_NO_NORMAL;
    m->tri_mat[m->ntris++] = mat;
    return true;
}

bool arbor_mesh_add_normal(arbor_mesh *m, arbor_vec3 n, arbor_err *e)
{
    if (!grow((void **)&m->normals, &m->cap_normals, m->nnormals, sizeof *m->normals, e))
        return false;
    m->normals[m->nnormals++] = n;
    return true;
}

bool arbor_mesh_set_last_tri_normals(arbor_mesh *m, uint32_t a, uint32_t b, uint32_t c, arbor_err *e)
{
    if (m->ntris == 0)
        return arbor_fail(e, ARBOR_ERR_INVALID, "no triangle to give normals to");
    /* Made at the first triangle with normals, the corners before it have none. */
    if (m->tri_normals == NULL) {
        m->tri_normals = malloc((size_t)m->cap_tris * 3 * sizeof *m->tri_normals);
        if (m->tri_normals == NULL)
            return arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory for %u triangles' normals", m->cap_tris);
        for (size_t i = 0; i < 3 * (size_t)m->ntris; i++)
            m->tri_normals[i] = ARBOR_NO_NORMAL;
    }
    uint32_t *t = m->tri_normals + 3 * (size_t)(m->ntris - 1);
    t[0] = a;
    t[1] = b;
    t[2] = c;
    return true;
}

void arbor_material_default(arbor_material *mat, const char *name)
{
    memset(mat, 0, sizeof *mat);
    snprintf(mat->name, sizeof mat->name, "%s", name);
    mat->kd = vec3(0.7f, 0.7f, 0.7f);
    mat->ns = 1.0f;
    mat->d = 1.0f;
    mat->illum = 1;
}

bool arbor_material_is_mirror(const arbor_material *mat)
{
    return mat->illum == 3 || mat->illum == 5;
}

bool arbor_mesh_add_material(arbor_mesh *m, const char *name, uint32_t *index, arbor_err *e)
{
    if (!grow((void **)&m->mats, &m->cap_mats, m->nmats, sizeof *m->mats, e))
        return false;
    arbor_material_default(&m->mats[m->nmats], name);
    *index = m->nmats++;
    return true;
}

int arbor_mesh_find_material(const arbor_mesh *m, const char *name)
{
    for (uint32_t i = 0; i < m->nmats; i++)
        if (strcmp(m->mats[i].name, name) == 0)
            return (int)i;
    return -1;
}

bool arbor_mesh_add_missing_library(arbor_mesh *m, const char *name, size_t len, arbor_err *e)
{
    char **grown = realloc(m->missing_libraries, (m->nmissing_libraries + 1) * sizeof *grown);
    /* not strndup: name is a word inside the file's text, not a string (ASan's strndup reads past len) */
    char *s = grown != NULL ? malloc(len + 1) : NULL;
    if (grown != NULL)
        m->missing_libraries = grown;
    if (s != NULL) {
        memcpy(s, name, len);
        s[len] = '\0';
    }
    if (s == NULL)
        return arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory noting material library '%.*s'", (int)(len < 64 ? len : 64),
                          name);
    m->missing_libraries[m->nmissing_libraries++] = s;
    return true;
}

/* Keeps one warning (the caller has checked the cap). */
static void mesh_keep_warning(arbor_mesh *m, const char *buf)
{
    if (!grow((void **)&m->warnings, &m->cap_warnings, m->nwarnings, sizeof *m->warnings, NULL))
        return;
    char *s = strdup(buf);
    if (s != NULL)
        m->warnings[m->nwarnings++] = s;
}

void arbor_mesh_warn(arbor_mesh *m, const char *fmt, ...)
{
    if (m->nwarnings >= ARBOR_MESH_WARNINGS_MAX) {
        m->warnings_dropped++;
        return;
    }
    char buf[512];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    mesh_keep_warning(m, buf);
}

bool arbor_mesh_finish(arbor_mesh *m, arbor_err *e)
{
    if (m->nmats == 0) {
        uint32_t idx;
        if (!arbor_mesh_add_material(m, "default", &idx, e))
            return false;
    }
    arbor_aabb b = aabb_empty();
    for (uint32_t t = 0; t < m->ntris; t++) {
        const uint32_t *i = m->tri_verts + 3 * (size_t)t;
        for (int k = 0; k < 3; k++) {
            if (i[k] >= m->nverts)
                return arbor_fail(e, ARBOR_ERR_INVALID, "triangle %u: vertex index %u out of range (%u vertices)",
                                  t, i[k], m->nverts);
            b = aabb_grow(b, m->verts[i[k]]);
        }
        if (m->tri_mat[t] >= m->nmats)
            return arbor_fail(e, ARBOR_ERR_INVALID, "triangle %u: material %u out of range (%u materials)",
                              t, m->tri_mat[t], m->nmats);
        for (int k = 0; m->tri_normals != NULL && k < 3; k++) {
            uint32_t n = m->tri_normals[3 * (size_t)t + (size_t)k];
            if (n != ARBOR_NO_NORMAL && n >= m->nnormals)
                return arbor_fail(e, ARBOR_ERR_INVALID, "triangle %u: normal index %u out of range (%u normals)", t,
                                  n, m->nnormals);
        }
    }
    m->bounds = b;
    float size = vec3_length(vec3_sub(b.hi, b.lo));
    if (m->ntris > 0 && !isfinite(size)) /* no camera, no ray offset, no box test can be made for it */
        return arbor_fail(e, ARBOR_ERR_INVALID,
                          "the model's size (its box's diagonal) overflows single precision (box %g,%g,%g .. %g,%g,%g): "
                          "scale it into %.3g..%.3g",
                          (double)b.lo.x, (double)b.lo.y, (double)b.lo.z, (double)b.hi.x, (double)b.hi.y,
                          (double)b.hi.z, (double)ARBOR_SIZE_MIN, (double)ARBOR_SIZE_MAX);
    if (m->ntris > 0 && !arbor_size_traceable(size))
        arbor_mesh_warn(m, "the model's size (its box's diagonal) is %.3g, outside %.3g..%.3g where single-precision "
                           "ray tests stay exact: rays may miss its triangles (scale it into that range)",
                        (double)size, (double)ARBOR_SIZE_MIN, (double)ARBOR_SIZE_MAX);
    if (m->warnings_dropped > 0) {
        char more[96];
        snprintf(more, sizeof more, "%u more warnings not listed", m->warnings_dropped);
        m->warnings_dropped = 0;
        mesh_keep_warning(m, more);
    }
    return true;
}

arbor_aabb arbor_mesh_tri_bounds(const arbor_mesh *m, uint32_t t)
{
    arbor_vec3 a, b, c;
    arbor_mesh_tri(m, t, &a, &b, &c);
    arbor_aabb box = {vec3_min(a, vec3_min(b, c)), vec3_max(a, vec3_max(b, c))};
    return box;
}

arbor_vec3 arbor_mesh_tri_normal(const arbor_mesh *m, uint32_t t)
{
    arbor_vec3 a, b, c;
    arbor_mesh_tri(m, t, &a, &b, &c);
    return vec3_cross(vec3_sub(b, a), vec3_sub(c, a));
}

arbor_vec3 arbor_mesh_shading_normal(const arbor_mesh *m, uint32_t t, float u, float v, arbor_vec3 geometric)
{
    if (m->tri_normals == NULL)
        return geometric;
    const uint32_t *i = m->tri_normals + 3 * (size_t)t;
    if (i[0] == ARBOR_NO_NORMAL || i[1] == ARBOR_NO_NORMAL || i[2] == ARBOR_NO_NORMAL)
        return geometric;
    arbor_vec3 n = vec3_add(vec3_scale(m->normals[i[0]], 1.0f - u - v),
                            vec3_add(vec3_scale(m->normals[i[1]], u), vec3_scale(m->normals[i[2]], v)));
    float len = vec3_length(n);
    /* zero, or not a number, when the file's normals are */
    return len > 1e-20f ? vec3_scale(n, 1.0f / len) : geometric;
}
