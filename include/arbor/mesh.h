/*
 * mesh.h - a triangle mesh in memory: positions, triangles, materials.
 *
 * A mesh owns all of its arrays; arbor_mesh_free releases them. Triangles are
 * triples of vertex indices (0-based, always < nverts once a loader returns
 * success). Every triangle has a material index into mats; mats[0] is the
 * default material (grey Lambert), present in every finished mesh. `bounds` is
 * the box of the vertices that triangles use (PROTOCOL.md's B), set by
 * arbor_mesh_finish. `warnings` collects problems that did not stop the load
 * (a refused or missing mtllib, for instance), for the caller to report.
 *
 * Acceleration structures keep a pointer to the mesh they were built over and
 * never modify it; the mesh must outlive them.
 */
#ifndef ARBOR_MESH_H
#define ARBOR_MESH_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "arbor/err.h"
#include "arbor/vec.h"

#define ARBOR_MATERIAL_NAME_MAX 64
/* Materials a loaded model may have (the shared models have at most a few
 * hundred), and warnings a mesh keeps: past ARBOR_MESH_WARNINGS_MAX they
 * are counted, and arbor_mesh_finish adds one saying how many more. Both
 * bound what a model costs to describe (the daemon's MODEL JSON). */
#define ARBOR_MESH_MATERIALS_MAX 4096
#define ARBOR_MESH_WARNINGS_MAX 100

typedef struct {
    char name[ARBOR_MATERIAL_NAME_MAX];
    arbor_vec3 kd;  /* diffuse colour */
    arbor_vec3 ks;  /* specular colour */
    arbor_vec3 ke;  /* emission */
    float ns;       /* specular exponent */
    float d;        /* opacity (MTL dissolve); below 1 the renderer treats it as glass */
    float ni;       /* index of refraction (MTL Ni); 0 when not given, rendered as 1 */
    int illum;      /* MTL illumination model; 3 and 5 are mirrors */
} arbor_material;

/* A triangle corner without a vertex normal (tri_normals). */
#define ARBOR_NO_NORMAL UINT32_MAX

typedef struct {
    uint32_t nverts, ntris, nmats;
    arbor_vec3 *verts;     /* nverts positions */
    uint32_t *tri_verts;   /* 3 * ntris vertex indices */
    uint32_t *tri_mat;     /* ntris material indices into mats */
    arbor_material *mats;  /* nmats materials; mats[0] is the default */
    /* Vertex normals for smooth shading (OBJ vn), or none: normals holds
     * nnormals vectors as read; tri_normals, 3 * ntris indices into them
     * (ARBOR_NO_NORMAL for a corner without one), is NULL when no face
     * names a normal. */
    arbor_vec3 *normals;
    uint32_t *tri_normals;
    uint32_t nnormals, cap_normals;
    arbor_aabb bounds;     /* of the vertices triangles use */
    char **warnings;       /* nwarnings owned strings */
    uint32_t nwarnings;
    uint32_t warnings_dropped; /* past ARBOR_MESH_WARNINGS_MAX, until arbor_mesh_finish */
    /* The material libraries the model names by a plain file name (no '/')
     * that do not exist in its folder: for a caller that can supply them (an
     * upload whose .mtl is in the models folder already). */
    char **missing_libraries;  /* nmissing_libraries owned strings */
    uint32_t nmissing_libraries;
    /* capacities of the growable arrays above (loader bookkeeping) */
    uint32_t cap_verts, cap_tris, cap_mats, cap_warnings;
} arbor_mesh;

/* An empty mesh (no arrays allocated); safe to free. */
void arbor_mesh_init(arbor_mesh *m);
void arbor_mesh_free(arbor_mesh *m);

/* Growing the mesh. Each returns false (and fills e) only when memory runs out. */
bool arbor_mesh_add_vert(arbor_mesh *m, arbor_vec3 p, arbor_err *e);
bool arbor_mesh_add_tri(arbor_mesh *m, uint32_t a, uint32_t b, uint32_t c, uint32_t mat, arbor_err *e);
bool arbor_mesh_add_normal(arbor_mesh *m, arbor_vec3 n, arbor_err *e);
/* Gives the last triangle added the normals a, b, c of its corners (indices
 * into normals, or ARBOR_NO_NORMAL). */
bool arbor_mesh_set_last_tri_normals(arbor_mesh *m, uint32_t a, uint32_t b, uint32_t c, arbor_err *e);
/* Records the library named by the len bytes at name as missing
 * (missing_libraries); false (e filled) when memory runs out. */
bool arbor_mesh_add_missing_library(arbor_mesh *m, const char *name, size_t len, arbor_err *e);
/* Appends a material with the default values and the given name; *index gets its index. */
bool arbor_mesh_add_material(arbor_mesh *m, const char *name, uint32_t *index, arbor_err *e);
/* Index of the material called name, or -1. */
int arbor_mesh_find_material(const arbor_mesh *m, const char *name);
/* Records a warning (printf-style); silently dropped if memory runs out. */
void arbor_mesh_warn(arbor_mesh *m, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

/* Checks every index against nverts, ensures the default material exists,
 * computes bounds. Loaders call it last; tests that build meshes by hand too. */
bool arbor_mesh_finish(arbor_mesh *m, arbor_err *e);

/* The default material's values (grey 0.7 Lambert, no specular). */
void arbor_material_default(arbor_material *mat, const char *name);
/* True for materials the renderer treats as mirrors: MTL illum 3 or 5 (the
 * ray-traced reflection models). Ks alone is a highlight's colour (illum 2),
 * as exporters write it for every material (Blender's 0.5 grey). */
bool arbor_material_is_mirror(const arbor_material *mat);

static inline void arbor_mesh_tri(const arbor_mesh *m, uint32_t t, arbor_vec3 *a, arbor_vec3 *b, arbor_vec3 *c)
{
    const uint32_t *i = m->tri_verts + 3 * (size_t)t;
    *a = m->verts[i[0]];
    *b = m->verts[i[1]];
    *c = m->verts[i[2]];
}

/* The triangle's bounding box. */
arbor_aabb arbor_mesh_tri_bounds(const arbor_mesh *m, uint32_t t);

/* Unnormalised geometric normal (b - a) x (c - a). */
arbor_vec3 arbor_mesh_tri_normal(const arbor_mesh *m, uint32_t t);

/* The unit normal to shade triangle t with at barycentrics (u, v) of its
 * corners b and c: its vertex normals interpolated when all three corners
 * have one (and they do not cancel out), else `geometric` (a unit vector). */
arbor_vec3 arbor_mesh_shading_normal(const arbor_mesh *m, uint32_t t, float u, float v, arbor_vec3 geometric);

#endif
