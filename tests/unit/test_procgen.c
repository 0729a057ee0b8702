/*
 * test_procgen.c - the procedural models (triangle counts from closed-form
 * formulas, bounds, closed surfaces, materials, determinism), the OBJ writer
 * (its text, its errors, and a round trip through the loader), and the
 * watertightness test: rays from inside closed meshes, including rays aimed
 * exactly through every vertex and edge midpoint, must all hit.
 */
#include <dirent.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "arbor/brute.h"
#include "arbor/load.h"
#include "arbor/procgen.h"
#include "support.h"
#include "unity.h"

static char tmpdir[256];

void setUp(void)
{
    snprintf(tmpdir, sizeof tmpdir, "/tmp/arbor-procgen-XXXXXX");
    TEST_ASSERT_NOT_NULL(mkdtemp(tmpdir));
}

void tearDown(void)
{
    DIR *dir = opendir(tmpdir);
    if (dir != NULL) {
        struct dirent *entry;
        char path[512];
        while ((entry = readdir(dir)) != NULL) {
            snprintf(path, sizeof path, "%s/%s", tmpdir, entry->d_name);
            if (entry->d_name[0] != '.')
                unlink(path);
        }
        closedir(dir);
    }
    rmdir(tmpdir);
}

static const char *tmp_path(const char *file)
{
    static char path[512];
    snprintf(path, sizeof path, "%s/%s", tmpdir, file);
    return path;
}

static uint64_t ipow(uint64_t base, int exp)
{
    uint64_t r = 1;
    while (exp-- > 0)
        r *= base;
    return r;
}

/* ---- edge bookkeeping: is the surface closed and consistently wound? ---- */

static int cmp_u64(const void *a, const void *b)
{
    uint64_t x = *(const uint64_t *)a, y = *(const uint64_t *)b;
    return x < y ? -1 : x > y;
}

typedef struct {
    size_t edges;          /* distinct undirected edges */
    size_t used_once;      /* edges of one triangle (a border) */
    size_t used_twice;     /* edges of exactly two triangles */
    size_t used_more;      /* edges of three or more (non-manifold) */
    size_t directed_dupes; /* directed edges used twice: inconsistent winding */
} edge_census;

static edge_census count_edges(const arbor_mesh *m)
{
    size_t n = 3 * (size_t)m->ntris;
    uint64_t *undirected = malloc(n * sizeof *undirected), *directed = malloc(n * sizeof *directed);
    TEST_ASSERT_NOT_NULL(undirected);
    TEST_ASSERT_NOT_NULL(directed);
    for (uint32_t t = 0; t < m->ntris; t++)
        for (int k = 0; k < 3; k++) {
            uint64_t a = m->tri_verts[3 * t + k], b = m->tri_verts[3 * t + (k + 1) % 3];
            directed[3 * t + k] = a << 32 | b;
            undirected[3 * t + k] = a < b ? (a << 32 | b) : (b << 32 | a);
        }
    qsort(undirected, n, sizeof *undirected, cmp_u64);
    qsort(directed, n, sizeof *directed, cmp_u64);
    edge_census c = {0, 0, 0, 0, 0};
    for (size_t i = 0; i < n;) {
        size_t j = i;
        while (j < n && undirected[j] == undirected[i])
            j++;
        c.edges++;
        if (j - i == 1)
            c.used_once++;
        else if (j - i == 2)
            c.used_twice++;
        else
            c.used_more++;
        i = j;
    }
    for (size_t i = 1; i < n; i++)
        c.directed_dupes += directed[i] == directed[i - 1];
    free(undirected);
    free(directed);
    return c;
}

/* Every edge in exactly two triangles, wound opposite ways in them. */
static void assert_closed_oriented(const arbor_mesh *m)
{
    edge_census c = count_edges(m);
    TEST_ASSERT_EQUAL_UINT64(0, c.used_once);
    TEST_ASSERT_EQUAL_UINT64(0, c.used_more);
    TEST_ASSERT_EQUAL_UINT64(3 * (size_t)m->ntris / 2, c.used_twice);
    TEST_ASSERT_EQUAL_UINT64(0, c.directed_dupes);
}

static int cmp_vec3_bits(const void *a, const void *b)
{
    return memcmp(a, b, sizeof(arbor_vec3));
}

static size_t duplicate_positions(const arbor_mesh *m)
{
    arbor_vec3 *v = malloc(m->nverts * sizeof *v);
    TEST_ASSERT_NOT_NULL(v);
    memcpy(v, m->verts, m->nverts * sizeof *v);
    qsort(v, m->nverts, sizeof *v, cmp_vec3_bits);
    size_t dupes = 0;
    for (uint32_t i = 1; i < m->nverts; i++)
        dupes += v[i].x == v[i - 1].x && v[i].y == v[i - 1].y && v[i].z == v[i - 1].z;
    free(v);
    return dupes;
}

/* Signed volume (positive when triangles wind counter-clockwise from outside). */
static double signed_volume(const arbor_mesh *m)
{
    double vol = 0.0;
    for (uint32_t t = 0; t < m->ntris; t++) {
        arbor_vec3 a, b, c;
        arbor_mesh_tri(m, t, &a, &b, &c);
        vol += vec3_dot(a, vec3_cross(b, c)) / 6.0;
    }
    return vol;
}

static void assert_bounds(const arbor_mesh *m, arbor_vec3 lo, arbor_vec3 hi)
{
    TEST_ASSERT_EQUAL_FLOAT(lo.x, m->bounds.lo.x);
    TEST_ASSERT_EQUAL_FLOAT(lo.y, m->bounds.lo.y);
    TEST_ASSERT_EQUAL_FLOAT(lo.z, m->bounds.lo.z);
    TEST_ASSERT_EQUAL_FLOAT(hi.x, m->bounds.hi.x);
    TEST_ASSERT_EQUAL_FLOAT(hi.y, m->bounds.hi.y);
    TEST_ASSERT_EQUAL_FLOAT(hi.z, m->bounds.hi.z);
}

static const arbor_material *material_named(const arbor_mesh *m, const char *name)
{
    int i = arbor_mesh_find_material(m, name);
    TEST_ASSERT_TRUE_MESSAGE(i >= 0, name);
    return &m->mats[i];
}

/* ---- the generators ---- */

static void test_cornell_counts_bounds_materials(void)
{
    for (int n = 1; n <= 3; n++) {
        arbor_mesh m;
        TEST_ASSERT_TRUE(arbor_gen_cornell(&m, n, NULL));
        /* 5 walls + the light + 2 blocks of 6 faces, n x n quads each */
        TEST_ASSERT_EQUAL_UINT32(2u * 18u * (uint32_t)(n * n), m.ntris);
        assert_bounds(&m, vec3(-1, 0, -1), vec3(1, 2, 1));
        TEST_ASSERT_EQUAL_STRING("default", m.mats[0].name);
        const arbor_material *mirror = material_named(&m, "mirror"), *light = material_named(&m, "light");
        TEST_ASSERT_EQUAL_INT(3, mirror->illum);
        TEST_ASSERT_EQUAL_FLOAT(0.9f, mirror->ks.x);
        TEST_ASSERT_TRUE(arbor_material_is_mirror(mirror));
        TEST_ASSERT_TRUE(light->ke.x > 1.0f && light->ke.y > 1.0f && light->ke.z > 1.0f);
        int red = arbor_mesh_find_material(&m, "red"), green = arbor_mesh_find_material(&m, "green");
        TEST_ASSERT_TRUE(m.mats[red].kd.x > 4 * m.mats[red].kd.y);
        TEST_ASSERT_TRUE(m.mats[green].kd.y > 2 * m.mats[green].kd.x);
        /* the left wall (x = -1) is red, the right wall green; the light faces down */
        uint32_t on_left = 0, on_right = 0, lights = 0, mirrors = 0;
        for (uint32_t t = 0; t < m.ntris; t++) {
            arbor_vec3 a, b, c;
            arbor_mesh_tri(&m, t, &a, &b, &c);
            if (a.x == -1 && b.x == -1 && c.x == -1) {
                TEST_ASSERT_EQUAL_UINT32(red, m.tri_mat[t]);
                on_left++;
            }
            if (a.x == 1 && b.x == 1 && c.x == 1) {
                TEST_ASSERT_EQUAL_UINT32(green, m.tri_mat[t]);
                on_right++;
            }
            if (m.tri_mat[t] == (uint32_t)arbor_mesh_find_material(&m, "light")) {
                TEST_ASSERT_TRUE(arbor_mesh_tri_normal(&m, t).y < 0);
                lights++;
            }
            mirrors += m.tri_mat[t] == (uint32_t)arbor_mesh_find_material(&m, "mirror");
        }
        TEST_ASSERT_EQUAL_UINT32(2 * n * n, on_left);
        TEST_ASSERT_EQUAL_UINT32(2 * n * n, on_right);
        TEST_ASSERT_EQUAL_UINT32(2 * n * n, lights);
        TEST_ASSERT_EQUAL_UINT32(12 * n * n, mirrors);
        arbor_mesh_free(&m);
    }
}

static void test_menger_counts_bounds_closed(void)
{
    for (int level = 0; level <= 3; level++) {
        arbor_mesh m;
        TEST_ASSERT_TRUE(arbor_gen_menger(&m, level, NULL));
        /* surface area 2 (20/9)^L + 4 (8/9)^L of the unit sponge, in squares of side 3^-L */
        uint64_t squares = 2 * ipow(20, level) + 4 * ipow(8, level);
        TEST_ASSERT_EQUAL_UINT64(2 * squares, m.ntris);
        assert_bounds(&m, vec3(-1, -1, -1), vec3(1, 1, 1));
        assert_closed_oriented(&m);
        TEST_ASSERT_EQUAL_UINT64(0, duplicate_positions(&m));
        /* volume (20/27)^L of the cube's 8 */
        TEST_ASSERT_DOUBLE_WITHIN(1e-4, 8.0 * pow(20.0 / 27.0, level), signed_volume(&m));
        arbor_mesh_free(&m);
    }
}

static void test_sphere_is_closed_manifold(void)
{
    for (int k = 0; k <= 4; k++) {
        arbor_mesh m;
        TEST_ASSERT_TRUE(arbor_gen_sphere(&m, k, NULL));
        TEST_ASSERT_EQUAL_UINT64(20 * ipow(4, k), m.ntris);
        TEST_ASSERT_EQUAL_UINT64(10 * ipow(4, k) + 2, m.nverts);
        TEST_ASSERT_EQUAL_UINT64(0, duplicate_positions(&m));
        assert_closed_oriented(&m);
        edge_census c = count_edges(&m);
        TEST_ASSERT_EQUAL_INT64(2, (int64_t)m.nverts - (int64_t)c.edges + (int64_t)m.ntris); /* Euler */
        for (uint32_t i = 0; i < m.nverts; i++)
            TEST_ASSERT_FLOAT_WITHIN(1e-6f, 1.0f, vec3_length(m.verts[i]));
        TEST_ASSERT_TRUE(m.bounds.lo.x >= -1.0f && m.bounds.hi.x <= 1.0f && m.bounds.hi.x > 0.85f);
        TEST_ASSERT_TRUE(m.bounds.lo.y >= -1.0f && m.bounds.hi.y <= 1.0f && m.bounds.lo.y < -0.85f);
        /* outward winding, and the volume approaches the ball's as k grows */
        double vol = signed_volume(&m), ball = 4.0 / 3.0 * 3.14159265358979;
        TEST_ASSERT_TRUE(vol > 0.6 * ball && vol < ball);
        if (k == 4) {
            TEST_ASSERT_DOUBLE_WITHIN(0.01 * ball, ball, vol);
        }
        arbor_mesh_free(&m);
    }
}

static void test_sphereflake_counts_bounds(void)
{
    static const int cases[][2] = {{0, 2}, {1, 0}, {1, 3}, {2, 4}, {3, 3}};
    for (size_t c = 0; c < sizeof cases / sizeof cases[0]; c++) {
        int level = cases[c][0], root = cases[c][1];
        uint64_t expect = 0;
        for (int d = 0; d <= level; d++)
            expect += ipow(9, d) * 20 * ipow(4, root > d ? root - d : 0);
        arbor_mesh m;
        TEST_ASSERT_TRUE(arbor_gen_sphereflake(&m, level, root, NULL));
        TEST_ASSERT_EQUAL_UINT64(expect, m.ntris);
        /* the root is the unit sphere; children reach at most 1 + 2/3 + 2/9 + ... = 2 */
        TEST_ASSERT_TRUE(m.bounds.lo.x >= -2 && m.bounds.lo.y >= -2 && m.bounds.lo.z >= -2);
        TEST_ASSERT_TRUE(m.bounds.hi.x <= 2 && m.bounds.hi.y <= 2 && m.bounds.hi.z <= 2);
        TEST_ASSERT_TRUE(m.bounds.lo.y < -0.8f && m.bounds.hi.y > 0.8f);
        if (level >= 1) { /* the equator's children stick out to 5/3 */
            TEST_ASSERT_TRUE(m.bounds.hi.x > 1.5f || m.bounds.hi.z > 1.5f);
        }
        for (uint32_t t = 0; t < m.ntris; t++)
            TEST_ASSERT_EQUAL_UINT32(arbor_mesh_find_material(&m, "flake"), m.tri_mat[t]);
        arbor_mesh_free(&m);
    }
}

static void test_heightfield_grid_and_bounds(void)
{
    static const int sizes[] = {1, 7, 128};
    for (size_t s = 0; s < sizeof sizes / sizeof sizes[0]; s++) {
        int n = sizes[s];
        arbor_mesh m;
        TEST_ASSERT_TRUE(arbor_gen_heightfield(&m, n, NULL));
        TEST_ASSERT_EQUAL_UINT32(2 * n * n, m.ntris);
        TEST_ASSERT_EQUAL_UINT32((n + 1) * (n + 1), m.nverts);
        TEST_ASSERT_EQUAL_FLOAT(-1, m.bounds.lo.x);
        TEST_ASSERT_EQUAL_FLOAT(1, m.bounds.hi.x);
        TEST_ASSERT_EQUAL_FLOAT(-1, m.bounds.lo.z);
        TEST_ASSERT_EQUAL_FLOAT(1, m.bounds.hi.z);
        TEST_ASSERT_TRUE(m.bounds.lo.y >= -0.25f && m.bounds.hi.y <= 0.25f);
        /* one sheet: the 4n border edges in one triangle, every other edge in two */
        edge_census c = count_edges(&m);
        TEST_ASSERT_EQUAL_UINT64(4 * (size_t)n, c.used_once);
        TEST_ASSERT_EQUAL_UINT64(0, c.used_more);
        TEST_ASSERT_EQUAL_UINT64(0, c.directed_dupes);
        for (uint32_t t = 0; t < m.ntris; t++)
            TEST_ASSERT_TRUE(arbor_mesh_tri_normal(&m, t).y > 0); /* facing up */
        if (n == 128) {
            TEST_ASSERT_TRUE(m.bounds.hi.y - m.bounds.lo.y > 0.1f); /* not flat */
            bool used[8] = {false};
            for (uint32_t t = 0; t < m.ntris; t++)
                used[m.tri_mat[t]] = true;
            TEST_ASSERT_TRUE(used[arbor_mesh_find_material(&m, "grass")]);
            TEST_ASSERT_TRUE(used[arbor_mesh_find_material(&m, "rock")]);
        }
        arbor_mesh_free(&m);
    }
}

static void test_generators_are_deterministic(void)
{
    for (int k = 0; k < ARBOR_GEN_COUNT; k++) {
        arbor_gen_params p = arbor_gen_preset((arbor_gen_kind)k, false);
        arbor_mesh a, b;
        TEST_ASSERT_TRUE(arbor_gen((arbor_gen_kind)k, p, &a, NULL));
        TEST_ASSERT_TRUE(arbor_gen((arbor_gen_kind)k, p, &b, NULL));
        TEST_ASSERT_EQUAL_UINT32(a.nverts, b.nverts);
        TEST_ASSERT_EQUAL_UINT32(a.ntris, b.ntris);
        TEST_ASSERT_EQUAL_MEMORY(a.verts, b.verts, a.nverts * sizeof *a.verts);
        TEST_ASSERT_EQUAL_MEMORY(a.tri_verts, b.tri_verts, 3 * (size_t)a.ntris * sizeof *a.tri_verts);
        TEST_ASSERT_EQUAL_MEMORY(a.tri_mat, b.tri_mat, a.ntris * sizeof *a.tri_mat);
        arbor_mesh_free(&a);
        arbor_mesh_free(&b);
    }
}

static void test_gen_names_and_parameter_errors(void)
{
    for (int k = 0; k < ARBOR_GEN_COUNT; k++) {
        arbor_gen_kind back;
        TEST_ASSERT_TRUE(arbor_gen_parse(arbor_gen_name((arbor_gen_kind)k), &back));
        TEST_ASSERT_EQUAL_INT(k, back);
    }
    arbor_gen_kind kind;
    TEST_ASSERT_FALSE(arbor_gen_parse("teapot", &kind));
    arbor_mesh m;
    arbor_err e;
    arbor_gen_params menger_with_n = {2, 5};
    TEST_ASSERT_FALSE(arbor_gen(ARBOR_GEN_MENGER, menger_with_n, &m, &e));
    TEST_ASSERT_EQUAL_INT(ARBOR_ERR_INVALID, e.status);
    TEST_ASSERT_NOT_NULL(strstr(e.msg, "menger"));
    arbor_mesh_free(&m);
    TEST_ASSERT_FALSE(arbor_gen_menger(&m, 6, &e));
    TEST_ASSERT_EQUAL_INT(ARBOR_ERR_INVALID, e.status);
    TEST_ASSERT_NOT_NULL(strstr(e.msg, "level"));
    arbor_mesh_free(&m);
    TEST_ASSERT_FALSE(arbor_gen_heightfield(&m, 0, &e));
    TEST_ASSERT_EQUAL_INT(ARBOR_ERR_INVALID, e.status);
    arbor_mesh_free(&m);
    /* an unset parameter takes the small preset */
    arbor_gen_params unset = {ARBOR_GEN_UNSET, ARBOR_GEN_UNSET};
    TEST_ASSERT_TRUE(arbor_gen(ARBOR_GEN_HEIGHTFIELD, unset, &m, &e));
    TEST_ASSERT_EQUAL_UINT32(2u * 128u * 128u, m.ntris);
    arbor_mesh_free(&m);
}

/* ---- the OBJ writer ---- */

static char *read_text(const char *path)
{
    FILE *f = fopen(path, "rb");
    if (f == NULL)
        return NULL;
    fseek(f, 0, SEEK_END);
    long len = ftell(f);
    fseek(f, 0, SEEK_SET);
    char *text = malloc((size_t)len + 1);
    TEST_ASSERT_NOT_NULL(text);
    TEST_ASSERT_EQUAL_UINT64((size_t)len, fread(text, 1, (size_t)len, f));
    text[len] = '\0';
    fclose(f);
    return text;
}

/* Lines of text that start with prefix. */
static size_t count_lines(const char *text, const char *prefix)
{
    size_t count = 0, plen = strlen(prefix);
    for (const char *line = text; line != NULL && *line != '\0';) {
        count += strncmp(line, prefix, plen) == 0;
        line = strchr(line, '\n');
        line = line ? line + 1 : NULL;
    }
    return count;
}

static void test_writer_writes_obj_and_mtl(void)
{
    arbor_mesh m;
    TEST_ASSERT_TRUE(arbor_gen_cornell(&m, 2, NULL));
    arbor_err e;
    TEST_ASSERT_TRUE(arbor_write_obj(&m, tmp_path("m.obj"), "first line\nsecond line", &e));
    char *obj = read_text(tmp_path("m.obj")), *mtl = read_text(tmp_path("m.mtl"));
    TEST_ASSERT_NOT_NULL(obj);
    TEST_ASSERT_NOT_NULL(mtl);
    TEST_ASSERT_EQUAL_UINT64(2, count_lines(obj, "# "));
    TEST_ASSERT_EQUAL_UINT64(1, count_lines(obj, "mtllib m.mtl\n"));
    TEST_ASSERT_EQUAL_UINT64(m.nverts, count_lines(obj, "v "));
    TEST_ASSERT_EQUAL_UINT64(m.ntris, count_lines(obj, "f "));
    size_t runs = 0;
    for (uint32_t t = 0; t < m.ntris; t++)
        runs += t == 0 || m.tri_mat[t] != m.tri_mat[t - 1];
    TEST_ASSERT_EQUAL_UINT64(runs, count_lines(obj, "usemtl "));
    /* the five materials the triangles use; the unused default is left out */
    TEST_ASSERT_EQUAL_UINT64(5, count_lines(mtl, "newmtl "));
    TEST_ASSERT_EQUAL_UINT64(0, count_lines(mtl, "newmtl default"));
    TEST_ASSERT_NOT_NULL(strstr(mtl, "newmtl mirror\nKd 0.05 0.05 0.05\nKs 0.9 0.9 0.9\n"));
    TEST_ASSERT_NOT_NULL(strstr(mtl, "newmtl light\n"));
    TEST_ASSERT_NOT_NULL(strstr(mtl, "Ke 17 12 4\n"));
    TEST_ASSERT_EQUAL_UINT64(1, count_lines(mtl, "illum 3"));
    free(obj);
    free(mtl);
    arbor_mesh_free(&m);
}

static void test_writer_without_materials_writes_no_mtl(void)
{
    arbor_mesh m;
    arbor_mesh_init(&m);
    arbor_mesh_add_vert(&m, vec3(0, 0, 0), NULL);
    arbor_mesh_add_vert(&m, vec3(1, 0, 0), NULL);
    arbor_mesh_add_vert(&m, vec3(0, 1, 0.125f), NULL);
    arbor_mesh_add_tri(&m, 0, 1, 2, 0, NULL);
    TEST_ASSERT_TRUE(arbor_mesh_finish(&m, NULL));
    TEST_ASSERT_TRUE(arbor_write_obj(&m, tmp_path("plain.obj"), NULL, NULL));
    char *obj = read_text(tmp_path("plain.obj"));
    TEST_ASSERT_EQUAL_STRING("v 0 0 0\nv 1 0 0\nv 0 1 0.125\nf 1 2 3\n", obj);
    TEST_ASSERT_EQUAL_INT(-1, access(tmp_path("plain.mtl"), F_OK));
    free(obj);
    arbor_mesh_free(&m);
}

static void test_writer_reports_missing_directory(void)
{
    arbor_mesh m;
    TEST_ASSERT_TRUE(arbor_gen_menger(&m, 1, NULL));
    arbor_err e;
    arbor_err_clear(&e);
    const char *path = "/nonexistent-arbor-dir/sub/menger.obj";
    TEST_ASSERT_FALSE(arbor_write_obj(&m, path, NULL, &e));
    TEST_ASSERT_EQUAL_INT(ARBOR_ERR_IO, e.status);
    TEST_ASSERT_NOT_NULL(strstr(e.msg, "/nonexistent-arbor-dir/sub/menger."));
    arbor_mesh_free(&m);
    char buf[8];
    TEST_ASSERT_TRUE(arbor_obj_mtl_path("a.obj", buf, sizeof buf));
    TEST_ASSERT_EQUAL_STRING("a.mtl", buf);
    TEST_ASSERT_FALSE(arbor_obj_mtl_path("abcdef.obj", buf, sizeof buf));
}

static void assert_close_vec3(arbor_vec3 a, arbor_vec3 b)
{
    TEST_ASSERT_TRUE(test_close(a.x, b.x, 1e-6f) && test_close(a.y, b.y, 1e-6f) && test_close(a.z, b.z, 1e-6f));
}

static void assert_round_trip(const arbor_mesh *m)
{
    arbor_err e;
    arbor_err_clear(&e);
    TEST_ASSERT_TRUE(arbor_write_obj(m, tmp_path("m.obj"), "round trip", &e));
    arbor_mesh back;
    bool loaded = arbor_load_model(tmp_path("m.obj"), &back, &e);
    TEST_ASSERT_TRUE_MESSAGE(loaded, e.msg);
    TEST_ASSERT_EQUAL_UINT32(0, back.nwarnings);
    TEST_ASSERT_EQUAL_UINT32(m->ntris, back.ntris);
    for (uint32_t t = 0; t < m->ntris; t++) {
        arbor_vec3 p[3], q[3];
        arbor_mesh_tri(m, t, &p[0], &p[1], &p[2]);
        arbor_mesh_tri(&back, t, &q[0], &q[1], &q[2]);
        for (int k = 0; k < 3; k++)
            assert_close_vec3(p[k], q[k]);
        const arbor_material *a = &m->mats[m->tri_mat[t]], *b = &back.mats[back.tri_mat[t]];
        TEST_ASSERT_EQUAL_STRING(a->name, b->name);
        assert_close_vec3(a->kd, b->kd);
        assert_close_vec3(a->ks, b->ks);
        assert_close_vec3(a->ke, b->ke);
        TEST_ASSERT_EQUAL_INT(a->illum, b->illum);
    }
    arbor_mesh_free(&back);
}

static void test_obj_round_trips_through_loader(void)
{
    arbor_mesh m;
    TEST_ASSERT_TRUE(arbor_gen_cornell(&m, 2, NULL));
    assert_round_trip(&m);
    arbor_mesh_free(&m);
    TEST_ASSERT_TRUE(arbor_gen_heightfield(&m, 16, NULL));
    assert_round_trip(&m);
    arbor_mesh_free(&m);
    TEST_ASSERT_TRUE(arbor_gen_sphereflake(&m, 1, 2, NULL));
    assert_round_trip(&m);
    arbor_mesh_free(&m);
}

/* Text with the "# " comment lines left out. */
static char *strip_comments(char *text)
{
    char *out = text;
    for (const char *line = text; *line != '\0';) {
        const char *end = strchr(line, '\n');
        size_t len = end ? (size_t)(end - line) + 1 : strlen(line);
        if (line[0] != '#') {
            memmove(out, line, len);
            out += len;
        }
        line += len;
    }
    *out = '\0';
    return text;
}

/* Compares a committed file of models/ with a fresh one, comments aside. */
static void assert_same_text(const char *committed_path, const char *fresh_path)
{
    char *committed = read_text(committed_path), *fresh = read_text(fresh_path);
    TEST_ASSERT_NOT_NULL_MESSAGE(committed, committed_path);
    TEST_ASSERT_NOT_NULL_MESSAGE(fresh, fresh_path);
    TEST_ASSERT_TRUE_MESSAGE(strcmp(strip_comments(committed), strip_comments(fresh)) == 0, committed_path);
    free(committed);
    free(fresh);
}

/* models/ holds what the generators make now: `make models` would not change it. */
static void test_committed_models_match_generators(void)
{
    for (int k = 0; k < ARBOR_GEN_COUNT; k++) {
        arbor_gen_kind kind = (arbor_gen_kind)k;
        char obj[64], mtl[64], committed[256];
        snprintf(obj, sizeof obj, "%s.obj", arbor_gen_name(kind));
        snprintf(mtl, sizeof mtl, "%s.mtl", arbor_gen_name(kind));
        arbor_mesh m;
        TEST_ASSERT_TRUE(arbor_gen(kind, arbor_gen_preset(kind, false), &m, NULL));
        TEST_ASSERT_TRUE(arbor_write_obj(&m, tmp_path(obj), NULL, NULL));
        snprintf(committed, sizeof committed, "%s", test_repo_model(obj));
        assert_same_text(committed, tmp_path(obj));
        snprintf(committed, sizeof committed, "%s", test_repo_model(mtl));
        assert_same_text(committed, tmp_path(mtl));
        arbor_mesh_free(&m);
    }
}

/* ---- watertightness: every ray from inside a closed mesh hits it ---- */

static arbor_vec3 uniform_direction(test_rng *g)
{
    float z = 2.0f * test_rng_float(g) - 1.0f, phi = 6.28318530718f * test_rng_float(g);
    float s = sqrtf(fmaxf(0.0f, 1.0f - z * z));
    return vec3(s * cosf(phi), s * sinf(phi), z);
}

/* Traces the rays on 2 threads; returns how many found nothing. */
static size_t count_misses(const arbor_mesh *m, const arbor_ray *rays, size_t n, arbor_hit *hits)
{
    bool *found = malloc(n * sizeof *found);
    TEST_ASSERT_NOT_NULL(found);
    arbor_brute_intersect_many(NULL, m, rays, n, hits, found, 2);
    size_t misses = 0;
    for (size_t i = 0; i < n; i++)
        misses += !found[i];
    free(found);
    return misses;
}

static void test_watertight_random_rays_from_inside_sphere(void)
{
    arbor_mesh m;
    TEST_ASSERT_TRUE(arbor_gen_sphere(&m, 4, NULL));
    TEST_ASSERT_EQUAL_UINT32(5120, m.ntris);
    const size_t n = 100000;
    arbor_ray *rays = malloc(n * sizeof *rays);
    arbor_hit *hits = malloc(n * sizeof *hits);
    test_rng g;
    test_rng_seed(&g, 77);
    for (size_t i = 0; i < n; i++) {
        /* uniform in the ball of radius 0.9 */
        arbor_vec3 o = vec3_scale(uniform_direction(&g), 0.9f * cbrtf(test_rng_float(&g)));
        arbor_ray r = {o, 0.0f, uniform_direction(&g), INFINITY};
        rays[i] = r;
    }
    size_t misses = count_misses(&m, rays, n, hits);
    char msg[64];
    snprintf(msg, sizeof msg, "%zu of %zu rays from inside missed", misses, n);
    TEST_ASSERT_EQUAL_UINT64_MESSAGE(0, misses, msg);
    /* and each hit is on the surface: between the facets' inradius and 1 */
    for (size_t i = 0; i < n; i++) {
        arbor_vec3 p = vec3_add(rays[i].o, vec3_scale(rays[i].d, hits[i].t));
        TEST_ASSERT_TRUE(vec3_length(p) > 0.99f && vec3_length(p) < 1.0001f);
    }
    free(rays);
    free(hits);
    arbor_mesh_free(&m);
}

static void assert_aimed_rays_hit(const arbor_mesh *m, const arbor_vec3 *origins, size_t norigins)
{
    size_t ntargets;
    arbor_vec3 *targets = test_vertices_and_edge_midpoints(m, &ntargets);
    TEST_ASSERT_EQUAL_UINT64(m->nverts + 3 * (size_t)m->ntris / 2, ntargets);
    arbor_ray *rays = test_aimed_rays(origins, norigins, targets, ntargets);
    size_t n = norigins * ntargets;
    arbor_hit *hits = malloc(n * sizeof *hits);
    size_t misses = count_misses(m, rays, n, hits);
    char msg[96];
    snprintf(msg, sizeof msg, "%zu of %zu rays aimed at vertices and edge midpoints missed", misses, n);
    TEST_ASSERT_EQUAL_UINT64_MESSAGE(0, misses, msg);
    free(targets);
    free(rays);
    free(hits);
}

static void test_watertight_rays_through_sphere_vertices_and_edges(void)
{
    arbor_mesh m;
    TEST_ASSERT_TRUE(arbor_gen_sphere(&m, 4, NULL));
    const arbor_vec3 origins[] = {vec3(0, 0, 0), vec3(0.3f, -0.2f, 0.1f), vec3(-0.55f, 0.4f, 0.25f),
                                  vec3(0.123f, 0.456f, -0.789f), vec3(-0.01f, 0.02f, 0.6f)};
    assert_aimed_rays_hit(&m, origins, sizeof origins / sizeof origins[0]);
    arbor_mesh_free(&m);
}

/* The sponge's faces are axis-aligned and its edges lie on a lattice: the
 * hardest case for a non-watertight test. Origins are inside solid cells. */
static void test_watertight_rays_through_menger_vertices_and_edges(void)
{
    arbor_mesh m;
    TEST_ASSERT_TRUE(arbor_gen_menger(&m, 2, NULL));
    /* cells of the 9^3 lattice that are solid: no two base-3 digits 1 at any level */
    static const int cells[][3] = {{0, 0, 0}, {4, 0, 0}, {2, 5, 7}, {8, 8, 6}, {0, 4, 8}};
    const size_t ncells = sizeof cells / sizeof cells[0];
    arbor_vec3 origins[2 * sizeof cells / sizeof cells[0]];
    for (size_t c = 0; c < ncells; c++) {
        arbor_vec3 lo = vec3(-1 + cells[c][0] * 2.0f / 9, -1 + cells[c][1] * 2.0f / 9, -1 + cells[c][2] * 2.0f / 9);
        origins[2 * c] = vec3_add(lo, vec3(1.0f / 9, 1.0f / 9, 1.0f / 9));          /* the cell's centre */
        origins[2 * c + 1] = vec3_add(lo, vec3(0.03f, 0.17f, 0.11f));              /* off-centre */
    }
    assert_aimed_rays_hit(&m, origins, 2 * ncells);
    arbor_mesh_free(&m);
}

int main(void)
{
    UNITY_BEGIN();
    RUN_TEST(test_cornell_counts_bounds_materials);
    RUN_TEST(test_menger_counts_bounds_closed);
    RUN_TEST(test_sphere_is_closed_manifold);
    RUN_TEST(test_sphereflake_counts_bounds);
    RUN_TEST(test_heightfield_grid_and_bounds);
    RUN_TEST(test_generators_are_deterministic);
    RUN_TEST(test_gen_names_and_parameter_errors);
    RUN_TEST(test_writer_writes_obj_and_mtl);
    RUN_TEST(test_writer_without_materials_writes_no_mtl);
    RUN_TEST(test_writer_reports_missing_directory);
    RUN_TEST(test_obj_round_trips_through_loader);
    RUN_TEST(test_committed_models_match_generators);
    RUN_TEST(test_watertight_random_rays_from_inside_sphere);
    RUN_TEST(test_watertight_rays_through_sphere_vertices_and_edges);
    RUN_TEST(test_watertight_rays_through_menger_vertices_and_edges);
    return UNITY_END();
}
