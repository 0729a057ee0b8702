/*
 * procgen.c - the project's procedural models (Cornell box, Menger sponge,
 * sphere-flake, heightfield, icosphere) and the OBJ/MTL writer
 * (see include/arbor/procgen.h).
 *
 * Every generator goes through one small builder. It welds vertices by exact
 * position, so a lattice point or an edge midpoint that two faces compute the
 * same way becomes one vertex and closed surfaces are closed by index too.
 * Quads become two triangles in one helper, and every flat part (the Cornell
 * room and its blocks, the Menger cubes, the heightfield's grid before it is
 * displaced) comes from one axis-aligned face-grid emitter.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "arbor/procgen.h"
#include "arbor/sys.h"
#include "loader.h"

/* ---- the builder: welded vertices, quads, face grids, boxes ---- */

typedef struct {
    arbor_mesh *m;
    arbor_err *e;
    uint32_t *slots;  /* open addressing over m->verts: vertex index + 1, 0 = empty */
    uint32_t nslots;  /* a power of two, at least twice the vertices in it */
    uint32_t used;
    uint32_t *rows;   /* scratch: two rows of vertex indices for the face grid */
    size_t cap_rows;
} builder;

static void builder_init(builder *b, arbor_mesh *m, arbor_err *e)
{
    memset(b, 0, sizeof *b);
    b->m = m;
    b->e = e;
}

static void builder_free(builder *b)
{
    free(b->slots);
    free(b->rows);
}

static uint32_t float_bits(float f)
{
    uint32_t u;
    memcpy(&u, &f, sizeof u);
    return u;
}

static bool same_position(arbor_vec3 a, arbor_vec3 b)
{
    return float_bits(a.x) == float_bits(b.x) && float_bits(a.y) == float_bits(b.y) &&
           float_bits(a.z) == float_bits(b.z);
}

static uint32_t position_hash(arbor_vec3 p)
{
    uint64_t h = float_bits(p.x) * 0x9E3779B97F4A7C15ull ^ float_bits(p.y) * 0xC2B2AE3D27D4EB4Full ^
                 float_bits(p.z) * 0x165667B19E3779F9ull;
    h ^= h >> 29;
    h *= 0xBF58476D1CE4E5B9ull;
    h ^= h >> 32;
    return (uint32_t)h;
}

static void slots_insert(uint32_t *slots, uint32_t nslots, uint32_t hash, uint32_t value)
{
    uint32_t s = hash & (nslots - 1);
    while (slots[s] != 0)
        s = (s + 1) & (nslots - 1);
    slots[s] = value;
}

/* Doubles the table, keeping the load under one half so probes stay short. */
static bool builder_grow_slots(builder *b)
{
    if (b->nslots >= (1u << 31))
        return arbor_fail(b->e, ARBOR_ERR_NOMEM, "too many vertices to weld (%u)", b->used);
    uint32_t nslots = b->nslots ? b->nslots * 2 : 4096;
    uint32_t *slots = calloc(nslots, sizeof *slots);
    if (slots == NULL)
        return arbor_fail(b->e, ARBOR_ERR_NOMEM, "out of memory welding %u vertices", b->used);
    for (uint32_t s = 0; s < b->nslots; s++)
        if (b->slots[s] != 0)
            slots_insert(slots, nslots, position_hash(b->m->verts[b->slots[s] - 1]), b->slots[s]);
    free(b->slots);
    b->slots = slots;
    b->nslots = nslots;
    return true;
}

/* The index of the vertex at exactly p, added if there is none yet. */
static bool builder_vertex(builder *b, arbor_vec3 p, uint32_t *index)
{
    /* adding +0 turns -0 into +0, so both zeros weld */
    p = vec3(p.x + 0.0f, p.y + 0.0f, p.z + 0.0f);
    if ((uint64_t)(b->used + 1) * 2 > b->nslots && !builder_grow_slots(b))
        return false;
    uint32_t mask = b->nslots - 1;
    for (uint32_t s = position_hash(p) & mask;; s = (s + 1) & mask) {
        if (b->slots[s] == 0) {
            if (!arbor_mesh_add_vert(b->m, p, b->e))
                return false;
            b->slots[s] = b->m->nverts;
            b->used++;
            *index = b->m->nverts - 1;
            return true;
        }
        if (same_position(b->m->verts[b->slots[s] - 1], p)) {
            *index = b->slots[s] - 1;
            return true;
        }
    }
}

/* The quad v0 v1 v2 v3 (in winding order) as two triangles. */
static bool add_quad(arbor_mesh *m, const uint32_t v[4], uint32_t mat, arbor_err *e)
{
    return arbor_mesh_add_tri(m, v[0], v[1], v[2], mat, e) && arbor_mesh_add_tri(m, v[0], v[2], v[3], mat, e);
}

/* A rotation about +y followed by a translation: where a Cornell block stands. */
typedef struct {
    arbor_vec3 offset;
    float cos_y, sin_y;
} placement;

static arbor_vec3 place(const placement *pl, arbor_vec3 p)
{
    if (pl == NULL)
        return p;
    return vec3(pl->offset.x + pl->cos_y * p.x + pl->sin_y * p.z, pl->offset.y + p.y,
                pl->offset.z - pl->sin_y * p.x + pl->cos_y * p.z);
}

/* Point i of n on [lo, hi]. The ends are exact, and every face that shares an
 * edge computes its points with the same arguments, so they weld. */
static float grid_coord(float lo, float hi, int i, int n)
{
    return i == n ? hi : lo + (hi - lo) * ((float)i / (float)n);
}

/* Faces of an axis-aligned box: face f lies on axis f / 2, on the low side
 * when f is even. */
enum { FACE_NX, FACE_PX, FACE_NY, FACE_PY, FACE_NZ, FACE_PZ, FACE_COUNT };
#define ALL_FACES ((1u << FACE_COUNT) - 1)

/* Face `face` of the box [lo, hi] as an n x n grid of quads, facing out of
 * the box (or into it when inward), each point placed by pl before welding. */
static bool add_face_grid(builder *b, const placement *pl, arbor_vec3 lo, arbor_vec3 hi, int face, int n,
                          bool inward, uint32_t mat)
{
    const int axis = face / 2, ua = (axis + 1) % 3, va = (axis + 2) % 3;
    const float lo3[3] = {lo.x, lo.y, lo.z}, hi3[3] = {hi.x, hi.y, hi.z};
    /* corners in (u, v) order wind about u x v = +axis; the low face and the
     * inward view each turn that around */
    const bool reverse = (face % 2 == 0) != inward;
    size_t need = 2 * ((size_t)n + 1);
    if (need > b->cap_rows) {
        uint32_t *rows = realloc(b->rows, need * sizeof *rows);
        if (rows == NULL)
            return arbor_fail(b->e, ARBOR_ERR_NOMEM, "out of memory for a %d x %d grid", n, n);
        b->rows = rows;
        b->cap_rows = need;
    }
    uint32_t *prev = b->rows, *cur = b->rows + n + 1;
    for (int j = 0; j <= n; j++) {
        for (int i = 0; i <= n; i++) {
            float p[3];
            p[axis] = face % 2 ? hi3[axis] : lo3[axis];
            p[ua] = grid_coord(lo3[ua], hi3[ua], i, n);
            p[va] = grid_coord(lo3[va], hi3[va], j, n);
            if (!builder_vertex(b, place(pl, vec3(p[0], p[1], p[2])), &cur[i]))
                return false;
            if (i == 0 || j == 0)
                continue;
            uint32_t q[4] = {prev[i - 1], prev[i], cur[i], cur[i - 1]};
            if (reverse) {
                uint32_t t = q[1];
                q[1] = q[3];
                q[3] = t;
            }
            if (!add_quad(b->m, q, mat, b->e))
                return false;
        }
        uint32_t *t = prev;
        prev = cur;
        cur = t;
    }
    return true;
}

/* The faces of [lo, hi] whose bits are set in face_mask, face f in mats[f]. */
static bool add_box(builder *b, const placement *pl, arbor_vec3 lo, arbor_vec3 hi, unsigned face_mask, int n,
                    bool inward, const uint32_t mats[FACE_COUNT])
{
    for (int f = 0; f < FACE_COUNT; f++)
        if ((face_mask & (1u << f)) && !add_face_grid(b, pl, lo, hi, f, n, inward, mats[f]))
            return false;
    return true;
}

/* ---- materials ---- */

typedef struct {
    const char *name;
    arbor_vec3 kd, ks, ke;
    float ns;
    int illum;
} material_spec;

static bool add_material(arbor_mesh *m, const material_spec *spec, uint32_t *index, arbor_err *e)
{
    if (!arbor_mesh_add_material(m, spec->name, index, e))
        return false;
    arbor_material *mat = &m->mats[*index];
    mat->kd = spec->kd;
    mat->ks = spec->ks;
    mat->ke = spec->ke;
    mat->ns = spec->ns;
    mat->illum = spec->illum;
    return true;
}

/* mats[0] is always the default; a generator's own materials follow it. */
static bool add_materials(arbor_mesh *m, const material_spec *specs, int count, uint32_t *index, arbor_err *e)
{
    uint32_t unused;
    if (!arbor_mesh_add_material(m, "default", &unused, e))
        return false;
    for (int i = 0; i < count; i++)
        if (!add_material(m, &specs[i], &index[i], e))
            return false;
    return true;
}

static bool check_range(const char *model, const char *what, int value, int lo, int hi, arbor_err *e)
{
    if (value < lo || value > hi)
        return arbor_fail(e, ARBOR_ERR_INVALID, "%s: %s must be %d..%d, not %d", model, what, lo, hi, value);
    return true;
}

/* ---- Cornell box ---- */

enum { CB_WHITE, CB_RED, CB_GREEN, CB_MIRROR, CB_LIGHT, CB_COUNT };

static const material_spec cornell_materials[CB_COUNT] = {
    [CB_WHITE] = {"white", {0.73f, 0.73f, 0.73f}, {0, 0, 0}, {0, 0, 0}, 1.0f, 1},
    [CB_RED] = {"red", {0.65f, 0.05f, 0.05f}, {0, 0, 0}, {0, 0, 0}, 1.0f, 1},
    [CB_GREEN] = {"green", {0.12f, 0.45f, 0.15f}, {0, 0, 0}, {0, 0, 0}, 1.0f, 1},
    [CB_MIRROR] = {"mirror", {0.05f, 0.05f, 0.05f}, {0.9f, 0.9f, 0.9f}, {0, 0, 0}, 1000.0f, 3},
    /* the classic box's light: warm, 17 12 4 */
    [CB_LIGHT] = {"light", {0.78f, 0.78f, 0.78f}, {0, 0, 0}, {17.0f, 12.0f, 4.0f}, 1.0f, 1},
};

static placement block_placement(float x, float z, float degrees)
{
    float rad = degrees * 3.14159265358979f / 180.0f;
    placement pl = {vec3(x, 0.0f, z), cosf(rad), sinf(rad)};
    return pl;
}

/* The room, a box seen from inside, open towards +z (the viewer), and its light. */
static bool cornell_room(builder *b, int n, const uint32_t *mat)
{
    const uint32_t room[FACE_COUNT] = {mat[CB_RED], mat[CB_GREEN], mat[CB_WHITE],
                                       mat[CB_WHITE], mat[CB_WHITE], mat[CB_WHITE]};
    if (!add_box(b, NULL, vec3(-1, 0, -1), vec3(1, 2, 1), ALL_FACES & ~(1u << FACE_PZ), n, true, room))
        return false;
    /* the light hangs just below the ceiling (as in the original box), facing down */
    return add_face_grid(b, NULL, vec3(-0.25f, 1.995f, -0.25f), vec3(0.25f, 1.995f, 0.25f), FACE_NY, n, false,
                         mat[CB_LIGHT]);
}

static bool cornell_block(builder *b, int n, bool tall, uint32_t mat)
{
    uint32_t faces[FACE_COUNT];
    for (int f = 0; f < FACE_COUNT; f++)
        faces[f] = mat;
    placement pl = tall ? block_placement(-0.35f, -0.3f, 17.0f) : block_placement(0.33f, 0.3f, -17.0f);
    return add_box(b, &pl, vec3(-0.3f, 0, -0.3f), vec3(0.3f, tall ? 1.2f : 0.6f, 0.3f), ALL_FACES, n, false, faces);
}

static bool cornell_parts(builder *b, int n, const uint32_t *mat)
{
    return cornell_room(b, n, mat) && cornell_block(b, n, false, mat[CB_WHITE]) &&
           cornell_block(b, n, true, mat[CB_MIRROR]);
}

bool arbor_gen_cornell(arbor_mesh *m, int n, arbor_err *e)
{
    arbor_mesh_init(m);
    if (!check_range("cornell", "n", n, 1, 1024, e))
        return false;
    uint32_t mat[CB_COUNT];
    builder b;
    builder_init(&b, m, e);
    bool ok = add_materials(m, cornell_materials, CB_COUNT, mat, e) && cornell_parts(&b, n, mat);
    builder_free(&b);
    return ok && arbor_mesh_finish(m, e);
}

/* ---- Menger sponge ---- */

static const material_spec menger_material = {"sponge", {0.75f, 0.72f, 0.65f}, {0, 0, 0}, {0, 0, 0}, 1.0f, 1};

/* Cell (x, y, z) of the side x side lattice is solid when, at every level, at
 * most one of its base-3 digits is 1 (two or more is one of the tunnels). */
static bool menger_solid(int x, int y, int z, int side)
{
    if (x < 0 || y < 0 || z < 0 || x >= side || y >= side || z >= side)
        return false;
    for (; side > 1; side /= 3, x /= 3, y /= 3, z /= 3)
        if ((x % 3 == 1) + (y % 3 == 1) + (z % 3 == 1) >= 2)
            return false;
    return true;
}

/* The faces of a solid cell that no solid neighbour covers. */
static unsigned menger_open_faces(int x, int y, int z, int side)
{
    static const int step[FACE_COUNT][3] = {{-1, 0, 0}, {1, 0, 0}, {0, -1, 0}, {0, 1, 0}, {0, 0, -1}, {0, 0, 1}};
    unsigned mask = 0;
    for (int f = 0; f < FACE_COUNT; f++)
        if (!menger_solid(x + step[f][0], y + step[f][1], z + step[f][2], side))
            mask |= 1u << f;
    return mask;
}

static bool menger_cells(builder *b, int side, uint32_t mat)
{
    uint32_t mats[FACE_COUNT];
    for (int f = 0; f < FACE_COUNT; f++)
        mats[f] = mat;
    for (int z = 0; z < side; z++)
        for (int y = 0; y < side; y++)
            for (int x = 0; x < side; x++) {
                if (!menger_solid(x, y, z, side))
                    continue;
                unsigned open = menger_open_faces(x, y, z, side);
                if (open == 0)
                    continue;
                arbor_vec3 lo = vec3(grid_coord(-1, 1, x, side), grid_coord(-1, 1, y, side), grid_coord(-1, 1, z, side));
                arbor_vec3 hi = vec3(grid_coord(-1, 1, x + 1, side), grid_coord(-1, 1, y + 1, side),
                                     grid_coord(-1, 1, z + 1, side));
                if (!add_box(b, NULL, lo, hi, open, 1, false, mats))
                    return false;
            }
    return true;
}

bool arbor_gen_menger(arbor_mesh *m, int level, arbor_err *e)
{
    arbor_mesh_init(m);
    if (!check_range("menger", "level", level, 0, 5, e))
        return false;
    int side = 1;
    for (int i = 0; i < level; i++)
        side *= 3;
    uint32_t mat;
    builder b;
    builder_init(&b, m, e);
    bool ok = add_materials(m, &menger_material, 1, &mat, e) && menger_cells(&b, side, mat);
    builder_free(&b);
    return ok && arbor_mesh_finish(m, e);
}

/* ---- icospheres and the sphere-flake ---- */

static const material_spec sphere_material = {"sphere", {0.6f, 0.7f, 0.9f}, {0, 0, 0}, {0, 0, 0}, 1.0f, 1};
static const material_spec flake_material = {"flake", {0.8f, 0.6f, 0.3f}, {0.3f, 0.3f, 0.3f}, {0, 0, 0}, 50.0f, 2};

typedef struct {
    arbor_vec3 centre;
    float radius;
    uint32_t mat;
} sphere_spec;

/* The triangle (a, b, c) of the unit sphere, split `depth` times at the
 * normalised edge midpoints; an edge's midpoint is computed from the same two
 * points by both triangles that share it, so it welds. */
static bool sphere_triangle(builder *b, const sphere_spec *s, arbor_vec3 a, arbor_vec3 c1, arbor_vec3 c2, int depth)
{
    if (depth == 0) {
        const arbor_vec3 corner[3] = {a, c1, c2};
        uint32_t v[3];
        for (int k = 0; k < 3; k++)
            if (!builder_vertex(b, vec3_add(s->centre, vec3_scale(corner[k], s->radius)), &v[k]))
                return false;
        return arbor_mesh_add_tri(b->m, v[0], v[1], v[2], s->mat, b->e);
    }
    arbor_vec3 ab = vec3_normalize(vec3_add(a, c1));
    arbor_vec3 bc = vec3_normalize(vec3_add(c1, c2));
    arbor_vec3 ca = vec3_normalize(vec3_add(c2, a));
    return sphere_triangle(b, s, a, ab, ca, depth - 1) && sphere_triangle(b, s, ab, c1, bc, depth - 1) &&
           sphere_triangle(b, s, ca, bc, c2, depth - 1) && sphere_triangle(b, s, ab, bc, ca, depth - 1);
}

/* An icosphere: the icosahedron with each face split 4^subdivisions ways. */
static bool add_icosphere(builder *b, const sphere_spec *s, int subdivisions)
{
    const float g = 1.61803398874989f; /* the golden ratio */
    const arbor_vec3 ico[12] = {
        vec3(-1, g, 0), vec3(1, g, 0), vec3(-1, -g, 0), vec3(1, -g, 0), vec3(0, -1, g), vec3(0, 1, g),
        vec3(0, -1, -g), vec3(0, 1, -g), vec3(g, 0, -1), vec3(g, 0, 1), vec3(-g, 0, -1), vec3(-g, 0, 1),
    };
    static const uint8_t faces[20][3] = {
        {0, 11, 5}, {0, 5, 1}, {0, 1, 7}, {0, 7, 10}, {0, 10, 11}, {1, 5, 9}, {5, 11, 4},
        {11, 10, 2}, {10, 7, 6}, {7, 1, 8}, {3, 9, 4}, {3, 4, 2}, {3, 2, 6}, {3, 6, 8},
        {3, 8, 9}, {4, 9, 5}, {2, 4, 11}, {6, 2, 10}, {8, 6, 7}, {9, 8, 1},
    };
    arbor_vec3 unit[12];
    for (int i = 0; i < 12; i++)
        unit[i] = vec3_normalize(ico[i]);
    for (int f = 0; f < 20; f++)
        if (!sphere_triangle(b, s, unit[faces[f][0]], unit[faces[f][1]], unit[faces[f][2]], subdivisions))
            return false;
    return true;
}

bool arbor_gen_sphere(arbor_mesh *m, int subdivisions, arbor_err *e)
{
    arbor_mesh_init(m);
    if (!check_range("sphere", "level", subdivisions, 0, 9, e))
        return false;
    sphere_spec s = {vec3(0, 0, 0), 1.0f, 0};
    builder b;
    builder_init(&b, m, e);
    bool ok = add_materials(m, &sphere_material, 1, &s.mat, e) && add_icosphere(&b, &s, subdivisions);
    builder_free(&b);
    return ok && arbor_mesh_finish(m, e);
}

/* ---- a glass sphere in the Cornell box ---- */

/* Clear glass: MTL d 0 (no opaque fraction), Ni 1.5, illum 7 (MTL's
 * refraction with Fresnel); Kd black, what the
 * renderer shows of it when it runs out of bounces inside. */
static const material_spec glass_material = {"glass", {0, 0, 0}, {0, 0, 0}, {0, 0, 0}, 1.0f, 7};

bool arbor_gen_glass(arbor_mesh *m, int subdivisions, arbor_err *e)
{
    arbor_mesh_init(m);
    if (!check_range("glass", "level", subdivisions, 0, 9, e))
        return false;
    uint32_t mat[CB_COUNT];
    sphere_spec s = {vec3(0.3f, 0.3f, 0.3f), 0.3f, 0};
    builder b;
    builder_init(&b, m, e);
    bool ok = add_materials(m, cornell_materials, CB_COUNT, mat, e) && add_material(m, &glass_material, &s.mat, e);
    if (ok) {
        m->mats[s.mat].d = 0.0f;
        m->mats[s.mat].ni = 1.5f;
    }
    ok = ok && cornell_room(&b, 1, mat) && add_icosphere(&b, &s, subdivisions) &&
         cornell_block(&b, 1, true, mat[CB_MIRROR]);
    builder_free(&b);
    return ok && arbor_mesh_finish(m, e);
}

typedef struct {
    builder *b;
    int root_subdivisions;
    uint32_t mat;
} flake;

/* Two unit vectors that make a right-handed frame with axis. */
static void frame_around(arbor_vec3 axis, arbor_vec3 *u, arbor_vec3 *v)
{
    arbor_vec3 helper = fabsf(axis.y) < 0.9f ? vec3(0, 1, 0) : vec3(1, 0, 0);
    *u = vec3_normalize(vec3_cross(helper, axis));
    *v = vec3_cross(axis, *u);
}

/* One sphere of the flake and, while levels remain, its nine children: six
 * around its equator and three at 60 degrees towards its axis (the direction
 * away from its parent), each touching it. */
static bool flake_sphere(const flake *f, arbor_vec3 centre, float radius, arbor_vec3 axis, int depth, int levels)
{
    int subdivisions = f->root_subdivisions - depth > 0 ? f->root_subdivisions - depth : 0;
    sphere_spec s = {centre, radius, f->mat};
    if (!add_icosphere(f->b, &s, subdivisions))
        return false;
    if (levels == 0)
        return true;
    static const float elevation_deg[9] = {0, 0, 0, 0, 0, 0, 60, 60, 60};
    static const float azimuth_deg[9] = {0, 60, 120, 180, 240, 300, 30, 150, 270};
    arbor_vec3 u, v;
    frame_around(axis, &u, &v);
    const float deg = 3.14159265358979f / 180.0f;
    for (int k = 0; k < 9; k++) {
        float el = elevation_deg[k] * deg, az = azimuth_deg[k] * deg;
        arbor_vec3 dir = vec3_add(vec3_scale(vec3_add(vec3_scale(u, cosf(az)), vec3_scale(v, sinf(az))), cosf(el)),
                                  vec3_scale(axis, sinf(el)));
        dir = vec3_normalize(dir);
        arbor_vec3 child = vec3_add(centre, vec3_scale(dir, radius * (4.0f / 3.0f)));
        if (!flake_sphere(f, child, radius / 3.0f, dir, depth + 1, levels - 1))
            return false;
    }
    return true;
}

bool arbor_gen_sphereflake(arbor_mesh *m, int level, int root_subdivisions, arbor_err *e)
{
    arbor_mesh_init(m);
    if (!check_range("sphereflake", "level", level, 0, 5, e) ||
        !check_range("sphereflake", "n (root subdivisions)", root_subdivisions, 0, 8, e))
        return false;
    builder b;
    builder_init(&b, m, e);
    flake f = {&b, root_subdivisions, 0};
    bool ok = add_materials(m, &flake_material, 1, &f.mat, e) &&
              flake_sphere(&f, vec3(0, 0, 0), 1.0f, vec3(0, 1, 0), 0, level);
    builder_free(&b);
    return ok && arbor_mesh_finish(m, e);
}

/* ---- heightfield ---- */

enum { HF_GRASS, HF_ROCK, HF_SNOW, HF_COUNT };

static const material_spec heightfield_materials[HF_COUNT] = {
    [HF_GRASS] = {"grass", {0.25f, 0.45f, 0.15f}, {0, 0, 0}, {0, 0, 0}, 1.0f, 1},
    [HF_ROCK] = {"rock", {0.45f, 0.40f, 0.35f}, {0, 0, 0}, {0, 0, 0}, 1.0f, 1},
    [HF_SNOW] = {"snow", {0.92f, 0.92f, 0.95f}, {0.1f, 0.1f, 0.1f}, {0, 0, 0}, 10.0f, 2},
};

/* A fixed pseudo-random value in [-1, 1) for a lattice point of one octave. */
static float lattice_value(int32_t ix, int32_t iz, uint32_t octave)
{
    uint32_t h = (uint32_t)ix * 0x8DA6B343u ^ (uint32_t)iz * 0xD8163841u ^ (octave + 1u) * 0xCB1AB31Fu;
    h ^= h >> 15;
    h *= 0x2C1B3C6Du;
    h ^= h >> 12;
    h *= 0x297A2D39u;
    h ^= h >> 15;
    return (float)(h >> 8) * (2.0f / 16777216.0f) - 1.0f;
}

/* Value noise: lattice values blended with the quintic fade, in [-1, 1]. */
static float value_noise(float x, float z, uint32_t octave)
{
    float fx = floorf(x), fz = floorf(z);
    int32_t ix = (int32_t)fx, iz = (int32_t)fz;
    float tx = x - fx, tz = z - fz;
    tx = tx * tx * tx * (tx * (tx * 6.0f - 15.0f) + 10.0f);
    tz = tz * tz * tz * (tz * (tz * 6.0f - 15.0f) + 10.0f);
    float a = lattice_value(ix, iz, octave), b = lattice_value(ix + 1, iz, octave);
    float c = lattice_value(ix, iz + 1, octave), d = lattice_value(ix + 1, iz + 1, octave);
    float near = a + (b - a) * tx, far = c + (d - c) * tx;
    return near + (far - near) * tz;
}

/* Six octaves of value noise over [-1, 1]^2, each half the last's weight;
 * dividing by the total weight keeps the height within [-0.25, 0.25] (the
 * clamp only absorbs rounding). */
static float terrain_height(float x, float z)
{
    float sum = 0.0f, total = 0.0f, weight = 1.0f, freq = 2.0f;
    for (uint32_t octave = 0; octave < 6; octave++) {
        sum += weight * value_noise((x + 1.0f) * freq, (z + 1.0f) * freq, octave);
        total += weight;
        weight *= 0.5f;
        freq *= 2.0f;
    }
    return 0.25f * fminf(1.0f, fmaxf(-1.0f, sum / total));
}

static uint32_t terrain_material(const arbor_mesh *m, uint32_t t, const uint32_t *mat)
{
    arbor_vec3 a, b, c;
    arbor_mesh_tri(m, t, &a, &b, &c);
    float mean = (a.y + b.y + c.y) / 3.0f;
    return mean < 0.03f ? mat[HF_GRASS] : mean < 0.09f ? mat[HF_ROCK] : mat[HF_SNOW];
}

/* A flat n x n grid on y = 0, facing up, then lifted to the terrain. The
 * builder is done with once the heights change (its keys are the flat points). */
static bool heightfield_grid(builder *b, int n, const uint32_t *mat)
{
    uint32_t first_vert = b->m->nverts, first_tri = b->m->ntris;
    if (!add_face_grid(b, NULL, vec3(-1, 0, -1), vec3(1, 0, 1), FACE_PY, n, false, mat[HF_GRASS]))
        return false;
    for (uint32_t i = first_vert; i < b->m->nverts; i++)
        b->m->verts[i].y = terrain_height(b->m->verts[i].x, b->m->verts[i].z);
    for (uint32_t t = first_tri; t < b->m->ntris; t++)
        b->m->tri_mat[t] = terrain_material(b->m, t, mat);
    return true;
}

bool arbor_gen_heightfield(arbor_mesh *m, int n, arbor_err *e)
{
    arbor_mesh_init(m);
    if (!check_range("heightfield", "n", n, 1, 4096, e))
        return false;
    uint32_t mat[HF_COUNT];
    builder b;
    builder_init(&b, m, e);
    bool ok = add_materials(m, heightfield_materials, HF_COUNT, mat, e) && heightfield_grid(&b, n, mat);
    builder_free(&b);
    return ok && arbor_mesh_finish(m, e);
}

/* ---- the catalogue ---- */

#define U ARBOR_GEN_UNSET
static const struct {
    const char *name, *summary;
    arbor_gen_params small, large;
} catalogue[ARBOR_GEN_COUNT] = {
    [ARBOR_GEN_CORNELL] = {"cornell", "Cornell box, mirror block, ceiling light; n: every quad split n x n",
                           {U, 1}, {U, 128}},
    [ARBOR_GEN_MENGER] = {"menger", "Menger sponge, closed surface; level: recursion depth", {3, U}, {4, U}},
    [ARBOR_GEN_SPHEREFLAKE] = {"sphereflake",
                               "Haines' sphere-flake; level: recursion depth, n: root sphere's subdivisions",
                               {3, 3}, {5, 5}},
    [ARBOR_GEN_HEIGHTFIELD] = {"heightfield", "fractal terrain; n: n x n quads", {U, 128}, {U, 1024}},
    [ARBOR_GEN_SPHERE] = {"sphere", "closed icosphere with shared vertices; level: subdivisions", {4, U}, {8, U}},
    [ARBOR_GEN_GLASS] = {"glass",
                         "Cornell box with a glass sphere and the mirror block; level: the sphere's subdivisions",
                         {3, U}, {8, U}},
};
#undef U

const char *arbor_gen_name(arbor_gen_kind kind)
{
    return (unsigned)kind < ARBOR_GEN_COUNT ? catalogue[kind].name : "?";
}

bool arbor_gen_parse(const char *name, arbor_gen_kind *kind)
{
    for (int k = 0; k < ARBOR_GEN_COUNT; k++)
        if (strcmp(name, catalogue[k].name) == 0) {
            *kind = (arbor_gen_kind)k;
            return true;
        }
    return false;
}

const char *arbor_gen_summary(arbor_gen_kind kind)
{
    return (unsigned)kind < ARBOR_GEN_COUNT ? catalogue[kind].summary : "?";
}

arbor_gen_params arbor_gen_preset(arbor_gen_kind kind, bool large)
{
    arbor_gen_params none = {ARBOR_GEN_UNSET, ARBOR_GEN_UNSET};
    if ((unsigned)kind >= ARBOR_GEN_COUNT)
        return none;
    return large ? catalogue[kind].large : catalogue[kind].small;
}

/* A parameter the kind does not read must stay unset; one it reads and
 * the caller left unset takes the small preset. */
static bool resolve_param(arbor_gen_kind kind, const char *what, int given, int preset, int *out, arbor_err *e)
{
    if (preset == ARBOR_GEN_UNSET && given != ARBOR_GEN_UNSET)
        return arbor_fail(e, ARBOR_ERR_INVALID, "%s has no %s parameter", catalogue[kind].name, what);
    *out = given == ARBOR_GEN_UNSET ? preset : given;
    return true;
}

bool arbor_gen(arbor_gen_kind kind, arbor_gen_params params, arbor_mesh *m, arbor_err *e)
{
    arbor_mesh_init(m);
    if ((unsigned)kind >= ARBOR_GEN_COUNT)
        return arbor_fail(e, ARBOR_ERR_INVALID, "unknown model kind %d", (int)kind);
    arbor_gen_params p = {ARBOR_GEN_UNSET, ARBOR_GEN_UNSET};
    if (!resolve_param(kind, "level", params.level, catalogue[kind].small.level, &p.level, e) ||
        !resolve_param(kind, "n", params.n, catalogue[kind].small.n, &p.n, e))
        return false;
    switch (kind) {
    case ARBOR_GEN_CORNELL: return arbor_gen_cornell(m, p.n, e);
    case ARBOR_GEN_MENGER: return arbor_gen_menger(m, p.level, e);
    case ARBOR_GEN_SPHEREFLAKE: return arbor_gen_sphereflake(m, p.level, p.n, e);
    case ARBOR_GEN_HEIGHTFIELD: return arbor_gen_heightfield(m, p.n, e);
    case ARBOR_GEN_SPHERE: return arbor_gen_sphere(m, p.level, e);
    case ARBOR_GEN_GLASS: return arbor_gen_glass(m, p.level, e);
    case ARBOR_GEN_COUNT: break;
    }
    return false;
}

/* ---- the OBJ / MTL writer ---- */

bool arbor_obj_mtl_path(const char *path, char *buf, size_t size)
{
    size_t len = strlen(path);
    if (len >= 4 && strcmp(path + len - 4, ".obj") == 0)
        len -= 4;
    int written = snprintf(buf, size, "%.*s.mtl", (int)len, path);
    return written >= 0 && (size_t)written < size;
}

/* Each line of comment as a "# " line. */
static void write_comment(FILE *f, const char *comment)
{
    while (comment != NULL && *comment != '\0') {
        size_t len = strcspn(comment, "\n");
        fprintf(f, "# %.*s\n", (int)len, comment);
        comment += len + (comment[len] == '\n');
    }
}

/* used[i]: whether a triangle uses material i; returns whether any uses one
 * other than the default mats[0] (which is when a .mtl is worth writing). */
static bool mark_used_materials(const arbor_mesh *m, bool *used)
{
    bool any_named = false;
    memset(used, 0, m->nmats * sizeof *used);
    for (uint32_t t = 0; t < m->ntris; t++) {
        used[m->tri_mat[t]] = true;
        any_named |= m->tri_mat[t] != 0;
    }
    return any_named;
}

static bool write_mtl(const arbor_mesh *m, const bool *used, const char *path, const char *comment, arbor_err *e)
{
    /* written whole or not at all: a full disk leaves no half a file */
    arbor_file_out out;
    if (!arbor_file_out_open(&out, path, e))
        return false;
    FILE *f = out.f;
    write_comment(f, comment);
    for (uint32_t i = 0; i < m->nmats; i++) {
        if (!used[i])
            continue;
        const arbor_material *mat = &m->mats[i];
        fprintf(f, "\nnewmtl %s\nKd %.6g %.6g %.6g\nKs %.6g %.6g %.6g\nNs %.6g\nKe %.6g %.6g %.6g\nd %.6g\n",
                mat->name, mat->kd.x, mat->kd.y, mat->kd.z, mat->ks.x, mat->ks.y, mat->ks.z, mat->ns, mat->ke.x,
                mat->ke.y, mat->ke.z, mat->d);
        /* only where given, so the files of materials without one stay as they were */
        if (mat->ni > 0.0f)
            fprintf(f, "Ni %.6g\n", mat->ni);
        fprintf(f, "illum %d\n", mat->illum);
    }
    return arbor_file_out_close(&out, true, e);
}

static void write_obj_body(FILE *f, const arbor_mesh *m, const char *mtl_name)
{
    if (mtl_name != NULL)
        fprintf(f, "mtllib %s\n", mtl_name);
    for (uint32_t i = 0; i < m->nverts; i++)
        fprintf(f, "v %.7g %.7g %.7g\n", m->verts[i].x, m->verts[i].y, m->verts[i].z);
    uint32_t current = UINT32_MAX;
    for (uint32_t t = 0; t < m->ntris; t++) {
        if (mtl_name != NULL && m->tri_mat[t] != current) {
            current = m->tri_mat[t];
            fprintf(f, "usemtl %s\n", m->mats[current].name);
        }
        const uint32_t *v = m->tri_verts + 3 * (size_t)t;
        fprintf(f, "f %u %u %u\n", v[0] + 1, v[1] + 1, v[2] + 1);
    }
}

bool arbor_write_obj(const arbor_mesh *m, const char *path, const char *comment, arbor_err *e)
{
    bool *used = calloc(m->nmats ? m->nmats : 1, sizeof *used);
    if (used == NULL)
        return arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory writing %s", path);
    char mtl_path[4096];
    const char *mtl_name = NULL;
    bool ok = true, mtl_new = false;
    if (mark_used_materials(m, used)) {
        if (!arbor_obj_mtl_path(path, mtl_path, sizeof mtl_path))
            ok = arbor_fail(e, ARBOR_ERR_INVALID, "path too long: %s", path);
        else {
            mtl_new = access(mtl_path, F_OK) != 0;
            if ((ok = write_mtl(m, used, mtl_path, comment, e))) {
                const char *slash = strrchr(mtl_path, '/');
                mtl_name = slash ? slash + 1 : mtl_path;
            }
        }
    }
    free(used);
    if (!ok)
        return false;
    arbor_file_out out;
    ok = arbor_file_out_open(&out, path, e);
    if (ok) {
        write_comment(out.f, comment);
        write_obj_body(out.f, m, mtl_name);
        ok = arbor_file_out_close(&out, true, e);
    }
    if (!ok && mtl_name != NULL && mtl_new)
        unlink(mtl_path); /* the library made for a model that is not there */
    return ok;
}
