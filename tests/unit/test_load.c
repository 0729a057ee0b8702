/*
 * test_load.c - the model loaders (include/arbor/load.h): OBJ statements and
 * index forms, MTL materials, gzip, PLY in its three encodings, the errors
 * and their line numbers, hostile input, the number parser against strtof,
 * and every real model in ../shared/models against its README.
 */
#include <dirent.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>
#include <zlib.h>

#include "arbor/load.h"
#include "support.h"
#include "unity.h"

/* ---- scratch files: one folder per process, emptied after each test ---- */

static void tmp_path(char *buf, size_t size, const char *file)
{
    snprintf(buf, size, "/tmp/arbor_test_load.%ld%s%s", (long)getpid(), file ? "/" : "", file ? file : "");
}

static void remove_tree(const char *path)
{
    struct stat st;
    if (lstat(path, &st) != 0)
        return;
    if (S_ISDIR(st.st_mode)) {
        DIR *d = opendir(path);
        struct dirent *ent;
        while (d != NULL && (ent = readdir(d)) != NULL) {
            if (strcmp(ent->d_name, ".") == 0 || strcmp(ent->d_name, "..") == 0)
                continue;
            char child[1024];
            snprintf(child, sizeof child, "%s/%s", path, ent->d_name);
            remove_tree(child);
        }
        if (d != NULL)
            closedir(d);
        rmdir(path);
    } else {
        unlink(path);
    }
}

void setUp(void)
{
    char dir[256];
    tmp_path(dir, sizeof dir, NULL);
    remove_tree(dir);
    TEST_ASSERT_EQUAL_INT(0, mkdir(dir, 0700));
}

void tearDown(void)
{
    char dir[256];
    tmp_path(dir, sizeof dir, NULL);
    remove_tree(dir);
}

static void make_dir(const char *name)
{
    char path[256];
    tmp_path(path, sizeof path, name);
    TEST_ASSERT_EQUAL_INT(0, mkdir(path, 0700));
}

/* Writes len bytes to the scratch file `name`; returns its path (static). */
static const char *write_bytes(const char *name, const void *data, size_t len)
{
    static char path[256];
    tmp_path(path, sizeof path, name);
    FILE *f = fopen(path, "wb");
    TEST_ASSERT_NOT_NULL(f);
    TEST_ASSERT_TRUE(fwrite(data, 1, len, f) == len);
    TEST_ASSERT_EQUAL_INT(0, fclose(f));
    return path;
}

static const char *write_text(const char *name, const char *text)
{
    return write_bytes(name, text, strlen(text));
}

static const char *write_gz(const char *name, const void *data, size_t len)
{
    static char path[256];
    tmp_path(path, sizeof path, name);
    gzFile f = gzopen(path, "wb9");
    TEST_ASSERT_NOT_NULL(f);
    TEST_ASSERT_EQUAL_INT((int)len, gzwrite(f, data, (unsigned)len));
    TEST_ASSERT_EQUAL_INT(Z_OK, gzclose(f));
    return path;
}

/* ---- assertions ---- */

static bool load_obj(const char *text, arbor_mesh *m, arbor_err *e)
{
    arbor_err_clear(e);
    return arbor_load_obj_text(text, strlen(text), "t.obj", NULL, m, e);
}

static void assert_mesh_empty(const arbor_mesh *m)
{
    TEST_ASSERT_EQUAL_UINT32(0, m->ntris);
    TEST_ASSERT_EQUAL_UINT32(0, m->nverts);
    TEST_ASSERT_EQUAL_UINT32(0, m->nmats);
    TEST_ASSERT_NULL(m->verts);
    TEST_ASSERT_NULL(m->tri_verts);
    TEST_ASSERT_NULL(m->mats);
}

static void assert_error(const arbor_err *e, arbor_status status, const char *fragment)
{
    char msg[800];
    snprintf(msg, sizeof msg, "expected '%s' in '%s'", fragment, e->msg);
    TEST_ASSERT_EQUAL_INT_MESSAGE(status, e->status, msg);
    TEST_ASSERT_NOT_NULL_MESSAGE(strstr(e->msg, fragment), msg);
}

/* The OBJ text must fail to load with a message containing fragment. */
static void assert_obj_fails(const char *text, const char *fragment)
{
    arbor_mesh m;
    arbor_err e;
    TEST_ASSERT_FALSE_MESSAGE(load_obj(text, &m, &e), fragment);
    assert_error(&e, ARBOR_ERR_PARSE, fragment);
    assert_mesh_empty(&m);
}

static void assert_ply_fails(const char *data, size_t len, const char *fragment)
{
    arbor_mesh m;
    arbor_err e;
    arbor_err_clear(&e);
    TEST_ASSERT_FALSE_MESSAGE(arbor_load_ply_data(data, len, "t.ply", &m, &e), fragment);
    assert_error(&e, ARBOR_ERR_PARSE, fragment);
    assert_mesh_empty(&m);
}

static void assert_tri(const arbor_mesh *m, uint32_t t, uint32_t a, uint32_t b, uint32_t c)
{
    char msg[64];
    snprintf(msg, sizeof msg, "triangle %u", t);
    TEST_ASSERT_TRUE_MESSAGE(t < m->ntris, msg);
    TEST_ASSERT_EQUAL_UINT32_MESSAGE(a, m->tri_verts[3 * t], msg);
    TEST_ASSERT_EQUAL_UINT32_MESSAGE(b, m->tri_verts[3 * t + 1], msg);
    TEST_ASSERT_EQUAL_UINT32_MESSAGE(c, m->tri_verts[3 * t + 2], msg);
}

static void assert_vec(float x, float y, float z, arbor_vec3 v)
{
    TEST_ASSERT_EQUAL_FLOAT(x, v.x);
    TEST_ASSERT_EQUAL_FLOAT(y, v.y);
    TEST_ASSERT_EQUAL_FLOAT(z, v.z);
}

static bool has_warning(const arbor_mesh *m, const char *fragment)
{
    for (uint32_t i = 0; i < m->nwarnings; i++)
        if (strstr(m->warnings[i], fragment) != NULL)
            return true;
    return false;
}

static const arbor_material *material(const arbor_mesh *m, const char *name)
{
    int i = arbor_mesh_find_material(m, name);
    TEST_ASSERT_TRUE_MESSAGE(i >= 0, name);
    return &m->mats[i];
}

/* ---- OBJ statements ---- */

static void test_every_index_form(void)
{
    arbor_mesh m;
    arbor_err e;
    TEST_ASSERT_TRUE(load_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n"
                              "vt 0 0\nvt 1 0\nvt 0 1\nvn 0 0 1\nvn 0 1 0\n"
                              "f 1 2 3\n"
                              "f 2/1 3/2 4/3\n"
                              "f 1/1/1 3/2/2 4/3/1\n"
                              "f 4//2 3//1 2//2\n",
                              &m, &e));
    TEST_ASSERT_EQUAL_UINT32(4, m.nverts);
    TEST_ASSERT_EQUAL_UINT32(4, m.ntris);
    assert_tri(&m, 0, 0, 1, 2);
    assert_tri(&m, 1, 1, 2, 3);
    assert_tri(&m, 2, 0, 2, 3);
    assert_tri(&m, 3, 3, 2, 1);
    assert_vec(0, 0, 1, m.verts[3]);
    arbor_mesh_free(&m);
}

static void test_negative_indices_count_from_the_current_end(void)
{
    arbor_mesh m;
    arbor_err e;
    TEST_ASSERT_TRUE(load_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\n"
                              "f -3 -2 -1\n"
                              "v 5 0 0\nv 6 0 0\nv 7 0 0\n"
                              "f -3/-1/-1 -2//-1 -1/-1\n"
                              "f -6 -1 -2\n",
                              &m, &e));
    TEST_ASSERT_EQUAL_UINT32(3, m.ntris);
    assert_tri(&m, 0, 0, 1, 2);
    assert_tri(&m, 1, 3, 4, 5);
    assert_tri(&m, 2, 0, 5, 4);
    arbor_mesh_free(&m);
}

static void test_polygons_become_fans_from_their_first_vertex(void)
{
    arbor_mesh m;
    arbor_err e;
    TEST_ASSERT_TRUE(load_obj("v 0 0 0\nv 1 0 0\nv 2 1 0\nv 1 2 0\nv 0 2 0\nv -1 1 0\n"
                              "f 1 2 3 4 5 6\n"
                              "f 6 5 4 3\n",
                              &m, &e));
    TEST_ASSERT_EQUAL_UINT32(4 + 2, m.ntris);
    assert_tri(&m, 0, 0, 1, 2);
    assert_tri(&m, 1, 0, 2, 3);
    assert_tri(&m, 2, 0, 3, 4);
    assert_tri(&m, 3, 0, 4, 5);
    assert_tri(&m, 4, 5, 4, 3);
    assert_tri(&m, 5, 5, 3, 2);
    arbor_mesh_free(&m);
}

/* vn lines are kept, and every triangle of a fan gets its corners' normals;
 * faces naming none have none, and a normal index past the vn lines read is
 * an error with its line. */
static void test_vertex_normals_follow_the_fan(void)
{
    arbor_mesh m;
    arbor_err e;
    TEST_ASSERT_TRUE_MESSAGE(load_obj("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
                              "vn 0 0 1\nvn 0 1 0\nvn 1 0 0\nvn 0 0 -1\n"
                              "f 1 2 3\n"
                              "f 1//1 2//2 3//3 4//4\n"
                              "vt 0 0\nf 4/1/-1 3/1/-2 2/1/-3\n",
                              &m, &e), e.msg);
    TEST_ASSERT_EQUAL_UINT32(4, m.nnormals);
    TEST_ASSERT_EQUAL_FLOAT(-1.0f, m.normals[3].z);
    TEST_ASSERT_EQUAL_UINT32(4, m.ntris);
    TEST_ASSERT_NOT_NULL(m.tri_normals);
    const uint32_t want[4][3] = {{ARBOR_NO_NORMAL, ARBOR_NO_NORMAL, ARBOR_NO_NORMAL}, {0, 1, 2}, {0, 2, 3}, {3, 2, 1}};
    for (int t = 0; t < 4; t++)
        TEST_ASSERT_EQUAL_UINT32_ARRAY(want[t], m.tri_normals + 3 * t, 3);
    arbor_mesh_free(&m);

    TEST_ASSERT_TRUE(load_obj("v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 3\n", &m, &e));
    TEST_ASSERT_NULL(m.tri_normals);
    arbor_mesh_free(&m);
    assert_obj_fails("v 0 0 0\nv 1 0 0\nv 1 1 0\nvn 0 0 1\nvn 0 1 0\nf 1//1 2//2 3//2\nf 1//1 2//2 3//3\n",
                     "t.obj:7: normal index 3 out of range (2 normals)");
}

/* The shading normal interpolates the corners' normals by the hit's
 * barycentrics and falls back to the geometric normal where a corner has
 * none or they cancel out. */
static void test_shading_normal_interpolates(void)
{
    arbor_mesh m;
    arbor_err e;
    TEST_ASSERT_TRUE(load_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 1 0 0\nvn 0 1 0\nvn 0 0 1\nvn -1 0 0\n"
                              "f 1//1 2//2 3//3\nf 1 2 3\nf 1//1 2//4 3//4\n",
                              &m, &e));
    arbor_vec3 g = vec3(0, 0, 1);
    arbor_vec3 n = arbor_mesh_shading_normal(&m, 0, 0.0f, 0.0f, g);
    TEST_ASSERT_EQUAL_FLOAT(1.0f, n.x);
    n = arbor_mesh_shading_normal(&m, 0, 0.5f, 0.5f, g);
    TEST_ASSERT_FLOAT_WITHIN(1e-6f, 0.0f, n.x);
    TEST_ASSERT_FLOAT_WITHIN(1e-6f, sqrtf(0.5f), n.y);
    TEST_ASSERT_FLOAT_WITHIN(1e-6f, sqrtf(0.5f), n.z);
    n = arbor_mesh_shading_normal(&m, 1, 0.25f, 0.25f, g);
    TEST_ASSERT_EQUAL_FLOAT(1.0f, n.z);
    n = arbor_mesh_shading_normal(&m, 2, 0.5f, 0.0f, g); /* (1,0,0) and (-1,0,0) halfway: zero */
    TEST_ASSERT_EQUAL_FLOAT(1.0f, n.z);
    arbor_mesh_free(&m);
}

static void test_crlf_tabs_comments_and_skipped_statements(void)
{
    arbor_mesh m;
    arbor_err e;
    TEST_ASSERT_TRUE(load_obj("# a comment\r\n"
                              "mtllib ignored.mtl\r\n"
                              "o thing\r\n"
                              "\r\n"
                              "v\t0.5 0 0  \r\n"
                              "v 1 0 0 # trailing comment\r\n"
                              "   v 0 1 0 1.0\r\n"
                              "v 0 0 1 0.2 0.3 0.4\r\n"
                              "g group\r\n"
                              "s 1\r\n"
                              "s off\r\n"
                              "vp 0.5 0.5\r\n"
                              "l 1 2\r\n"
                              "cstype bezier\r\n"
                              "\tf 1 2 3\t \r\n"
                              "f 1 3 4",
                              &m, &e));
    TEST_ASSERT_EQUAL_UINT32(4, m.nverts);
    TEST_ASSERT_EQUAL_UINT32(2, m.ntris);
    TEST_ASSERT_EQUAL_UINT32(0, m.nwarnings);
    assert_vec(0.5f, 0, 0, m.verts[0]);
    assert_vec(0, 0, 1, m.verts[3]);
    assert_tri(&m, 1, 0, 2, 3);
    arbor_mesh_free(&m);
}

static void test_faces_before_usemtl_use_the_default_material(void)
{
    arbor_mesh m;
    arbor_err e;
    TEST_ASSERT_TRUE(load_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\n"
                              "f 1 2 3\n"
                              "usemtl red\nf 1 2 3\nf 1 3 2\n"
                              "usemtl blue\nf 1 2 3\n"
                              "usemtl red\nf 3 2 1\n",
                              &m, &e));
    TEST_ASSERT_EQUAL_UINT32(3, m.nmats);
    TEST_ASSERT_EQUAL_STRING("default", m.mats[0].name);
    uint32_t red = (uint32_t)arbor_mesh_find_material(&m, "red");
    uint32_t blue = (uint32_t)arbor_mesh_find_material(&m, "blue");
    uint32_t expected[] = {0, red, red, blue, red};
    TEST_ASSERT_EQUAL_UINT32(5, m.ntris);
    TEST_ASSERT_EQUAL_UINT32_ARRAY(expected, m.tri_mat, 5);
    /* undefined materials get default values and one warning each */
    TEST_ASSERT_EQUAL_FLOAT(0.7f, m.mats[red].kd.x);
    TEST_ASSERT_EQUAL_UINT32(2, m.nwarnings);
    TEST_ASSERT_TRUE(has_warning(&m, "t.obj:5: material 'red' is not defined"));
    TEST_ASSERT_TRUE(has_warning(&m, "t.obj:8: material 'blue'"));
    arbor_mesh_free(&m);
}

/* ---- MTL ---- */

static const char *const cube_faces = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";

static void test_mtl_values_reach_the_materials_faces_use(void)
{
    write_text("m.mtl", "# library\n"
                        "newmtl shiny\n"
                        "Ka 0.1 0.1 0.1\n"
                        "Kd 0.5 0.25 0.125\n"
                        "Ks 0.9 0.8 0.7\n"
                        "Ns 250\n"
                        "Ke 1 2 3\n"
                        "Ni 1.45\n"
                        "d 0.5\n"
                        "illum 3\n"
                        "map_Kd shiny.png\n"
                        "\n"
                        "newmtl grey\r\n"
                        "Kd 0.3\r\n"
                        "d -halo 0.25\r\n");
    char obj[512];
    snprintf(obj, sizeof obj, "mtllib m.mtl\n%sf 1 2 3\nusemtl shiny\nf 1 2 3\nusemtl grey\nf 1 2 3\n", cube_faces);
    const char *path = write_text("model.obj", obj);
    arbor_mesh m;
    arbor_err e;
    TEST_ASSERT_TRUE_MESSAGE(arbor_load_model(path, &m, &e), e.msg);
    TEST_ASSERT_EQUAL_UINT32(0, m.nwarnings);
    const arbor_material *shiny = material(&m, "shiny"), *grey = material(&m, "grey");
    assert_vec(0.5f, 0.25f, 0.125f, shiny->kd);
    assert_vec(0.9f, 0.8f, 0.7f, shiny->ks);
    assert_vec(1, 2, 3, shiny->ke);
    TEST_ASSERT_EQUAL_FLOAT(250.0f, shiny->ns);
    TEST_ASSERT_EQUAL_FLOAT(0.5f, shiny->d);
    TEST_ASSERT_EQUAL_FLOAT(1.45f, shiny->ni);
    TEST_ASSERT_EQUAL_INT(3, shiny->illum);
    assert_vec(0.3f, 0.3f, 0.3f, grey->kd);
    TEST_ASSERT_EQUAL_FLOAT(0.25f, grey->d);
    TEST_ASSERT_EQUAL_FLOAT(0.0f, grey->ni); /* not given: the renderer takes 1 */
    TEST_ASSERT_EQUAL_INT(1, grey->illum);
    uint32_t expected[] = {0, (uint32_t)(shiny - m.mats), (uint32_t)(grey - m.mats)};
    TEST_ASSERT_EQUAL_UINT32_ARRAY(expected, m.tri_mat, 3);
    arbor_mesh_free(&m);
}

static void test_several_libraries_on_one_mtllib_line(void)
{
    write_text("a.mtl", "newmtl a\nKd 1 0 0\n");
    write_text("b.mtl", "newmtl b\nKd 0 1 0\n");
    char obj[256];
    snprintf(obj, sizeof obj, "mtllib a.mtl\tb.mtl \n%susemtl b\nf 1 2 3\n", cube_faces);
    arbor_mesh m;
    arbor_err e;
    TEST_ASSERT_TRUE_MESSAGE(arbor_load_model(write_text("two.obj", obj), &m, &e), e.msg);
    assert_vec(1, 0, 0, material(&m, "a")->kd);
    assert_vec(0, 1, 0, material(&m, "b")->kd);
    TEST_ASSERT_EQUAL_UINT32((uint32_t)arbor_mesh_find_material(&m, "b"), m.tri_mat[0]);
    TEST_ASSERT_EQUAL_UINT32(0, m.nwarnings);
    arbor_mesh_free(&m);
}

static void test_missing_mtl_is_a_warning(void)
{
    char obj[256];
    snprintf(obj, sizeof obj, "mtllib nothere.mtl sub/notthere.mtl\n%susemtl red\nf 1 2 3\n", cube_faces);
    arbor_mesh m;
    arbor_err e;
    TEST_ASSERT_TRUE_MESSAGE(arbor_load_model(write_text("lonely.obj", obj), &m, &e), e.msg);
    TEST_ASSERT_EQUAL_UINT32(1, m.ntris);
    TEST_ASSERT_TRUE(has_warning(&m, "lonely.obj:1: material library not loaded"));
    TEST_ASSERT_TRUE(has_warning(&m, "nothere.mtl"));
    TEST_ASSERT_TRUE(has_warning(&m, "sub/notthere.mtl"));
    /* missing, for a caller that may supply it: the plain name only */
    TEST_ASSERT_EQUAL_UINT32(1, m.nmissing_libraries);
    TEST_ASSERT_EQUAL_STRING("nothere.mtl", m.missing_libraries[0]);
    TEST_ASSERT_EQUAL_FLOAT(0.7f, material(&m, "red")->kd.x);
    arbor_mesh_free(&m);
}

static void test_mtllib_outside_the_models_folder_is_refused(void)
{
    make_dir("models");
    make_dir("models/sub");
    const char *evil = "newmtl evil\nKd 1 0 0\n";
    write_text("evil.mtl", evil);
    write_text("models/ok.mtl", "newmtl ok\nKd 0 0 1\n");
    char outside[256], obj[1024];
    tmp_path(outside, sizeof outside, "evil.mtl");
    snprintf(obj, sizeof obj, "mtllib ../evil.mtl sub/../../evil.mtl %s\nmtllib ./sub/../ok.mtl\n%s"
             "usemtl evil\nf 1 2 3\nusemtl ok\nf 1 2 3\n", outside, cube_faces);
    arbor_mesh m;
    arbor_err e;
    TEST_ASSERT_TRUE_MESSAGE(arbor_load_model(write_text("models/model.obj", obj), &m, &e), e.msg);
    TEST_ASSERT_EQUAL_UINT32(2, m.ntris);
    TEST_ASSERT_TRUE(has_warning(&m, "'../evil.mtl' is outside the model's folder"));
    TEST_ASSERT_TRUE(has_warning(&m, "'sub/../../evil.mtl' is outside the model's folder"));
    TEST_ASSERT_TRUE(has_warning(&m, outside));
    /* none of the refused libraries was read; the one inside was */
    TEST_ASSERT_EQUAL_FLOAT(0.7f, material(&m, "evil")->kd.x);
    assert_vec(0, 0, 1, material(&m, "ok")->kd);
    arbor_mesh_free(&m);
}

/* Containment is decided on real paths: a symbolic link inside the folder,
 * to a file or to a folder outside it, does not lead out; one that stays
 * inside is followed. */
static void test_mtllib_symlinks_cannot_leave_the_models_folder(void)
{
    make_dir("models");
    write_text("evil.mtl", "newmtl evil\nKd 1 0 0\n");
    write_text("models/ok.mtl", "newmtl ok\nKd 0 0 1\n");
    char link[256];
    tmp_path(link, sizeof link, "models/link.mtl");
    TEST_ASSERT_EQUAL_INT(0, symlink("../evil.mtl", link));
    tmp_path(link, sizeof link, "models/up");
    TEST_ASSERT_EQUAL_INT(0, symlink("..", link));
    tmp_path(link, sizeof link, "models/alias.mtl");
    TEST_ASSERT_EQUAL_INT(0, symlink("ok.mtl", link));
    char obj[512];
    snprintf(obj, sizeof obj, "mtllib link.mtl up/evil.mtl\nmtllib alias.mtl\n%s"
             "usemtl evil\nf 1 2 3\nusemtl ok\nf 1 2 3\n", cube_faces);
    arbor_mesh m;
    arbor_err e;
    TEST_ASSERT_TRUE_MESSAGE(arbor_load_model(write_text("models/model.obj", obj), &m, &e), e.msg);
    TEST_ASSERT_TRUE(has_warning(&m, "'link.mtl' is outside the model's folder"));
    TEST_ASSERT_TRUE(has_warning(&m, "'up/evil.mtl' is outside the model's folder"));
    TEST_ASSERT_EQUAL_FLOAT(0.7f, material(&m, "evil")->kd.x);
    assert_vec(0, 0, 1, material(&m, "ok")->kd);
    arbor_mesh_free(&m);
}

static void test_malformed_mtl_fails_with_its_line(void)
{
    write_text("bad.mtl", "newmtl x\nKd 1 0 0\nKs 1 oops 1\n");
    char obj[256];
    snprintf(obj, sizeof obj, "mtllib bad.mtl\n%sf 1 2 3\n", cube_faces);
    arbor_mesh m;
    arbor_err e;
    TEST_ASSERT_FALSE(arbor_load_model(write_text("badmtl.obj", obj), &m, &e));
    assert_error(&e, ARBOR_ERR_PARSE, "bad.mtl:3: malformed number 'oops'");
    assert_mesh_empty(&m);

    write_text("early.mtl", "Kd 1 0 0\n");
    snprintf(obj, sizeof obj, "mtllib early.mtl\n%sf 1 2 3\n", cube_faces);
    TEST_ASSERT_FALSE(arbor_load_model(write_text("early.obj", obj), &m, &e));
    assert_error(&e, ARBOR_ERR_PARSE, "early.mtl:1: Kd before any newmtl");

    write_text("badni.mtl", "newmtl glass\nd 0.1\nNi glassy\n");
    snprintf(obj, sizeof obj, "mtllib badni.mtl\n%sf 1 2 3\n", cube_faces);
    TEST_ASSERT_FALSE(arbor_load_model(write_text("badni.obj", obj), &m, &e));
    assert_error(&e, ARBOR_ERR_PARSE, "badni.mtl:3: malformed number 'glassy'");
}

/* ---- gzip ---- */

/* A strip of n quads as OBJ text (caller frees); large enough that its
 * deflate stream spans many blocks. */
static char *strip_obj(int n, size_t *len)
{
    size_t cap = (size_t)n * 120 + 64;
    char *s = malloc(cap);
    size_t k = 0;
    for (int i = 0; i <= n; i++)
        k += (size_t)snprintf(s + k, cap - k, "v %d.%03d 0 %d\nv %d.%03d 1 %d\n", i, i % 997, i % 7, i, i % 991,
                              i % 5);
    for (int i = 0; i < n; i++)
        k += (size_t)snprintf(s + k, cap - k, "f %d %d %d %d\n", 2 * i + 1, 2 * i + 3, 2 * i + 4, 2 * i + 2);
    *len = k;
    return s;
}

static void test_obj_gz_loads_like_the_plain_file(void)
{
    size_t len;
    char *text = strip_obj(5000, &len);
    arbor_mesh plain, gz;
    arbor_err e;
    TEST_ASSERT_TRUE(arbor_load_obj_text(text, len, "strip", NULL, &plain, &e));
    TEST_ASSERT_TRUE_MESSAGE(arbor_load_model(write_gz("strip.obj.gz", text, len), &gz, &e), e.msg);
    TEST_ASSERT_EQUAL_UINT32(10000, gz.ntris);
    TEST_ASSERT_EQUAL_UINT32(plain.nverts, gz.nverts);
    TEST_ASSERT_EQUAL_MEMORY(plain.verts, gz.verts, plain.nverts * sizeof *plain.verts);
    TEST_ASSERT_EQUAL_MEMORY(plain.tri_verts, gz.tri_verts, 3 * sizeof(uint32_t) * plain.ntris);
    arbor_mesh_free(&plain);
    arbor_mesh_free(&gz);
    free(text);
}

static void test_truncated_gz_is_an_error(void)
{
    size_t len;
    char *text = strip_obj(5000, &len);
    const char *path = write_gz("cut.obj.gz", text, len);
    struct stat st;
    TEST_ASSERT_EQUAL_INT(0, stat(path, &st));
    /* cut in the middle of the deflate stream, and just the trailer's last byte */
    off_t cuts[] = {st.st_size / 2, st.st_size - 1};
    for (size_t i = 0; i < sizeof cuts / sizeof cuts[0]; i++) {
        TEST_ASSERT_EQUAL_INT(0, truncate(path, cuts[i]));
        arbor_mesh m;
        arbor_err e;
        TEST_ASSERT_FALSE(arbor_load_model(path, &m, &e));
        assert_error(&e, ARBOR_ERR_IO, "truncated or corrupt gzip data");
        assert_mesh_empty(&m);
    }
    free(text);
}

/* 64 MiB of zeros deflate to about 64 KiB: a small file that must not be
 * inflated past the caller's cap (nor the whole way: reading stops at it). */
static void test_gz_is_capped_by_its_decompressed_size(void)
{
    const size_t zeros = (size_t)64 << 20, cap = (size_t)1 << 20;
    char path[256];
    tmp_path(path, sizeof path, "zeros.obj.gz");
    gzFile f = gzopen(path, "wb9");
    TEST_ASSERT_NOT_NULL(f);
    char *block = calloc(1, (size_t)1 << 20);
    for (size_t done = 0; done < zeros; done += (size_t)1 << 20)
        TEST_ASSERT_EQUAL_INT(1 << 20, gzwrite(f, block, 1u << 20));
    TEST_ASSERT_EQUAL_INT(Z_OK, gzclose(f));
    free(block);
    struct stat st;
    TEST_ASSERT_EQUAL_INT(0, stat(path, &st));
    TEST_ASSERT_TRUE(st.st_size < (off_t)cap);

    arbor_mesh m;
    arbor_err e;
    char limit[64];
    snprintf(limit, sizeof limit, "limit of %zu bytes", cap);
    TEST_ASSERT_FALSE(arbor_load_model_capped(path, cap, &m, &e));
    assert_error(&e, ARBOR_ERR_IO, limit);
    assert_error(&e, ARBOR_ERR_IO, "zeros.obj.gz");
    assert_mesh_empty(&m);
    char *data;
    size_t len;
    TEST_ASSERT_FALSE(arbor_load_file(path, cap, &data, &len, &e));
    assert_error(&e, ARBOR_ERR_IO, limit);

    /* exactly at the cap is fine; a plain file is capped by its size */
    const char *text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
    const char *gz = write_gz("small.obj.gz", text, strlen(text));
    TEST_ASSERT_TRUE_MESSAGE(arbor_load_model_capped(gz, strlen(text), &m, &e), e.msg);
    arbor_mesh_free(&m);
    TEST_ASSERT_FALSE(arbor_load_model_capped(gz, strlen(text) - 1, &m, &e));
    const char *plain = write_text("small.obj", text);
    TEST_ASSERT_TRUE_MESSAGE(arbor_load_model_capped(plain, strlen(text), &m, &e), e.msg);
    arbor_mesh_free(&m);
    TEST_ASSERT_FALSE(arbor_load_model_capped(plain, strlen(text) - 1, &m, &e));
    assert_error(&e, ARBOR_ERR_IO, "small.obj: 32 bytes, more than the limit of 31 bytes");
}

/* Every OBJ statement arbor does not use is read past without a word. */
static void test_every_skipped_obj_statement_is_silent(void)
{
    const char *statements[] = {
        "vp", "g", "o", "s", "l", "p", "mg", "usemap", "maplib", "cstype", "deg", "bmat", "step", "curv", "curv2",
        "surf", "parm", "trim", "hole", "scrv", "sp", "end", "con", "bevel", "c_interp", "d_interp", "lod",
        "shadow_obj", "trace_obj", "ctech", "stech", "call", "csh", "bsp", "bzp", "cdc", "cdp", "res",
        "#", "#comment", "####", "vt", "vn", "mtllib",
    };
    char text[2048] = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n\n  \t\n";
    for (size_t i = 0; i < sizeof statements / sizeof statements[0]; i++) {
        size_t k = strlen(text);
        snprintf(text + k, sizeof text - k, "%s 0 1 0\n", statements[i]);
    }
    arbor_mesh m;
    arbor_err e;
    TEST_ASSERT_TRUE_MESSAGE(load_obj(text, &m, &e), e.msg);
    TEST_ASSERT_EQUAL_UINT32(1, m.ntris);
    TEST_ASSERT_EQUAL_UINT32_MESSAGE(0, m.nwarnings, m.nwarnings ? m.warnings[0] : "");
    arbor_mesh_free(&m);
}

/* A line that is no OBJ statement would let a model load partly without a
 * word: one warning names the first and counts them all. */
static void test_unknown_obj_statements_are_a_warning(void)
{
    arbor_mesh m;
    arbor_err e;
    TEST_ASSERT_TRUE_MESSAGE(load_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nF 1 2 4\nfo 1 3 4\nf 2 3 4\n", &m, &e),
                             e.msg);
    TEST_ASSERT_EQUAL_UINT32(2, m.ntris);
    TEST_ASSERT_EQUAL_UINT32(1, m.nwarnings);
    TEST_ASSERT_TRUE_MESSAGE(has_warning(&m, "t.obj:6: 'F' is not an OBJ statement; 2 such lines ignored"),
                             m.warnings[0]);
    arbor_mesh_free(&m);

    /* text that is not OBJ after a valid model: one line of it is enough */
    TEST_ASSERT_TRUE_MESSAGE(load_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n<html><body>gone</body></html>", &m, &e),
                             e.msg);
    TEST_ASSERT_EQUAL_UINT32(1, m.nwarnings);
    TEST_ASSERT_TRUE_MESSAGE(has_warning(&m, "t.obj:5: '<html><body>gone</body></html>' is not an OBJ statement; 1 "
                                             "such line ignored"),
                             m.warnings[0]);
    arbor_mesh_free(&m);
}

/* An OBJ of n triangles, each after "usemtl m<i % names>": undefined
 * materials, each a warning and a material. Owned by the caller. */
static char *obj_of_usemtl(int n, int names)
{
    size_t cap = 64 + (size_t)n * 48, len = 0;
    char *t = malloc(cap);
    TEST_ASSERT_NOT_NULL(t);
    len += (size_t)snprintf(t + len, cap - len, "v 0 0 0\nv 1 0 0\nv 0 1 0\n");
    for (int i = 0; i < n; i++)
        len += (size_t)snprintf(t + len, cap - len, "usemtl m%d\nf 1 2 3\n", i % names);
    return t;
}

/* Warnings past ARBOR_MESH_WARNINGS_MAX are counted in one last warning,
 * so a hostile file cannot make a model's description unbounded. */
static void test_warnings_are_capped_and_counted(void)
{
    char *text = obj_of_usemtl(300, 300);
    arbor_mesh m;
    arbor_err e;
    TEST_ASSERT_TRUE_MESSAGE(load_obj(text, &m, &e), e.msg);
    TEST_ASSERT_EQUAL_UINT32(300, m.ntris);
    TEST_ASSERT_EQUAL_UINT32(301, m.nmats);
    TEST_ASSERT_EQUAL_UINT32(ARBOR_MESH_WARNINGS_MAX + 1, m.nwarnings);
    TEST_ASSERT_TRUE_MESSAGE(has_warning(&m, "t.obj:4: material 'm0' is not defined"), m.warnings[0]);
    TEST_ASSERT_EQUAL_STRING("200 more warnings not listed", m.warnings[m.nwarnings - 1]);
    arbor_mesh_free(&m);
    free(text);
}

/* More than ARBOR_MESH_MATERIALS_MAX materials is an error at the line of
 * the one too many; as many as that is a model. */
static void test_materials_are_capped(void)
{
    char *text = obj_of_usemtl(ARBOR_MESH_MATERIALS_MAX - 1, ARBOR_MESH_MATERIALS_MAX - 1);
    arbor_mesh m;
    arbor_err e;
    TEST_ASSERT_TRUE_MESSAGE(load_obj(text, &m, &e), e.msg);
    TEST_ASSERT_EQUAL_UINT32(ARBOR_MESH_MATERIALS_MAX, m.nmats); /* the default and the names */
    arbor_mesh_free(&m);
    free(text);
    text = obj_of_usemtl(ARBOR_MESH_MATERIALS_MAX, ARBOR_MESH_MATERIALS_MAX);
    char line[64];
    snprintf(line, sizeof line, "t.obj:%d: more than %d materials", 3 + 2 * ARBOR_MESH_MATERIALS_MAX - 1,
             ARBOR_MESH_MATERIALS_MAX);
    assert_obj_fails(text, line);
    free(text);
}

/* A model whose box's diagonal overflows single precision has no camera,
 * ray offset or box test: refused, not loaded to render NaN. */
static void test_a_model_too_large_for_floats_is_refused(void)
{
    arbor_mesh m;
    arbor_err e;
    TEST_ASSERT_FALSE(load_obj("v -1e38 -1e38 -1e38\nv 1e38 1e38 1e38\nv 1e38 -1e38 0\nf 1 2 3\n", &m, &e));
    assert_error(&e, ARBOR_ERR_INVALID, "overflows single precision");
    TEST_ASSERT_TRUE_MESSAGE(load_obj("v -1e15 -1e15 -1e15\nv 1e15 1e15 1e15\nv 1e15 -1e15 0\nf 1 2 3\n", &m, &e),
                             e.msg);
    TEST_ASSERT_TRUE_MESSAGE(has_warning(&m, "outside"), m.nwarnings ? m.warnings[0] : "no warning");
    arbor_mesh_free(&m);
}

/* Binary bytes after a valid model: the file is not OBJ, whatever came first. */
static void test_binary_data_in_obj_is_an_error(void)
{
    assert_obj_fails("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n\nPK\x03\x04\x14 junk\n",
                     "t.obj:6: binary data (byte 0x03): not an OBJ file");
    const char text[] = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nx\0\0\0\xff\n";
    arbor_mesh m;
    arbor_err e;
    TEST_ASSERT_FALSE(arbor_load_obj_text(text, sizeof text - 1, "t.obj", NULL, &m, &e));
    assert_error(&e, ARBOR_ERR_PARSE, "t.obj:5: binary data (byte 0x00): not an OBJ file");
    assert_mesh_empty(&m);
}

/* ---- errors ---- */

static void test_errors_name_file_line_and_reason(void)
{
    const char *tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
    struct {
        const char *tail, *fragment;
    } cases[] = {
        {"f 1 2 9\n", "t.obj:4: vertex index 9 out of range (3 vertices)"},
        {"f 1 2 0\n", "t.obj:4: vertex index 0 is invalid"},
        {"f 1 2 -4\n", "t.obj:4: vertex index -4 out of range (3 vertices)"},
        {"f 1 2 4294967297\n", "t.obj:4: vertex index 4294967297 out of range"},
        {"f 1 2 -4294967295\n", "t.obj:4: vertex index -4294967295 out of range"},
        {"f 1 2 123456789012345678901234567890\n", "t.obj:4: vertex index 123456789012345678901234567890 out"},
        {"f 1/4 2/1 3/1\n", "t.obj:4: texture coordinate index 4 out of range (0 texture coordinates)"},
        {"vn 0 0 1\nf 1//1 2//2 3//1\n", "t.obj:5: normal index 2 out of range (1 normals)"},
        {"f 1 2\n", "t.obj:4: face has 2 vertices (needs at least 3)"},
        {"f\n", "t.obj:4: face has 0 vertices"},
        {"f 1/ 2 3\n", "t.obj:4: malformed face vertex '1/'"},
        {"f 1// 2 3\n", "t.obj:4: malformed face vertex '1//'"},
        {"f 1/1/1/1 2 3\n", "t.obj:4: malformed face vertex '1/1/1/1'"},
        {"f 1 2 x\n", "t.obj:4: malformed face vertex 'x'"},
        {"f 1 2 3.0\n", "t.obj:4: malformed face vertex '3.0'"},
        {"v 0 1.5x 0\n", "t.obj:4: malformed number '1.5x'"},
        {"v 0 1e 0\n", "t.obj:4: malformed number '1e'"},
        {"v 0 -- 0\n", "t.obj:4: malformed number '--'"},
        {"v 1 2\n", "t.obj:4: missing vertex coordinate"},
        {"v nan 0 0\n", "t.obj:4: NaN vertex coordinate"},
        {"v 0 1e999 0\n", "t.obj:4: infinite vertex coordinate '1e999'"},
        {"v 0 0 -inf\n", "t.obj:4: infinite vertex coordinate '-inf'"},
        {"v 0 0 3.5e38\n", "t.obj:4: infinite vertex coordinate"},
        {"vn 0 x 1\n", "t.obj:4: malformed number 'x' (normal component)"},
        {"usemtl\n", "t.obj:4: usemtl without a material name"},
        {"# only vertices\n", "t.obj: no triangles"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        char text[512];
        snprintf(text, sizeof text, "%s%s", tri, cases[i].tail);
        assert_obj_fails(text, cases[i].fragment);
    }
    /* CRLF files count lines the same way */
    assert_obj_fails("v 0 0 0\r\nv 1 0 0\r\n\r\nf 1 2 7\r\n", "t.obj:4: vertex index 7 out of range (2 vertices)");
    assert_obj_fails("", "t.obj: no triangles");
}

static void test_file_errors(void)
{
    arbor_mesh m;
    arbor_err e;
    char path[256];
    tmp_path(path, sizeof path, "absent.obj");
    TEST_ASSERT_FALSE(arbor_load_model(path, &m, &e));
    assert_error(&e, ARBOR_ERR_IO, "absent.obj: cannot open: No such file or directory");
    assert_mesh_empty(&m);

    TEST_ASSERT_FALSE(arbor_load_model(write_text("model.stl", "solid x\n"), &m, &e));
    assert_error(&e, ARBOR_ERR_IO, "model.stl: unknown model format");
    assert_mesh_empty(&m);

    make_dir("folder.obj");
    tmp_path(path, sizeof path, "folder.obj");
    TEST_ASSERT_FALSE(arbor_load_model(path, &m, &e));
    assert_error(&e, ARBOR_ERR_IO, "folder.obj: not a regular file");

    TEST_ASSERT_FALSE(arbor_load_model(write_bytes("empty.obj", "", 0), &m, &e));
    assert_error(&e, ARBOR_ERR_PARSE, "empty.obj: no triangles");
    TEST_ASSERT_FALSE(arbor_load_model(write_bytes("empty.ply", "", 0), &m, &e));
    assert_error(&e, ARBOR_ERR_PARSE, "empty.ply:1: not a PLY file");
    TEST_ASSERT_FALSE(arbor_load_model(write_gz("empty.obj.gz", "", 0), &m, &e));
    assert_error(&e, ARBOR_ERR_PARSE, "empty.obj.gz: no triangles");
}

/* ---- hostile input ---- */

static void test_megabyte_lines(void)
{
    size_t big = 1u << 20;
    char *text = malloc(big + 256);
    arbor_mesh m;
    arbor_err e;

    /* a 1 MB comment, then a face whose error must name line 5 */
    size_t k = (size_t)sprintf(text, "v 0 0 0\nv 1 0 0\nv 0 1 0\n# ");
    memset(text + k, 'x', big);
    k += big;
    strcpy(text + k, "\nf 1 2 4\n");
    assert_obj_fails(text, "t.obj:5: vertex index 4 out of range");
    strcpy(text + k, "\nf 1 2 3\n");
    TEST_ASSERT_TRUE(load_obj(text, &m, &e));
    TEST_ASSERT_EQUAL_UINT32(1, m.ntris);
    arbor_mesh_free(&m);

    /* a coordinate of a million digits is infinite; one of a million
     * zeros after the point rounds to 0 as strtof would */
    k = (size_t)sprintf(text, "v 0 0 ");
    memset(text + k, '7', big);
    strcpy(text + k + big, "\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    assert_obj_fails(text, "t.obj:1: infinite vertex coordinate '77777777");
    k = (size_t)sprintf(text, "v 0 0 0.");
    memset(text + k, '0', big);
    strcpy(text + k + big, "1\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    TEST_ASSERT_TRUE(load_obj(text, &m, &e));
    TEST_ASSERT_EQUAL_FLOAT(0.0f, m.verts[0].z);
    arbor_mesh_free(&m);
    free(text);
}

/* Random bytes, and valid text with random bytes sprinkled in, must load or
 * fail cleanly: an error leaves the mesh empty, a success is a finished mesh. */
static void test_garbage_never_crashes(void)
{
    test_rng g;
    test_rng_seed(&g, 7);
    size_t len;
    char *valid = strip_obj(200, &len);
    char *buf = malloc(len);
    int failures = 0;
    for (int round = 0; round < 400; round++) {
        bool random_bytes = round % 2 == 0;
        for (size_t i = 0; i < len; i++)
            buf[i] = random_bytes ? (char)test_rng_u32(&g) : valid[i];
        for (int flips = 0; !random_bytes && flips < 8; flips++)
            buf[test_rng_u32(&g) % len] = (char)test_rng_u32(&g);
        arbor_mesh m;
        arbor_err e;
        bool ok = round % 4 < 2 ? arbor_load_obj_text(buf, len, "g.obj", NULL, &m, &e)
                                : arbor_load_ply_data(buf, len, "g.ply", &m, &e);
        if (ok) {
            TEST_ASSERT_TRUE(m.ntris > 0 && m.nmats > 0);
            for (uint32_t i = 0; i < 3 * m.ntris; i++)
                TEST_ASSERT_TRUE(m.tri_verts[i] < m.nverts);
            arbor_mesh_free(&m);
        } else {
            failures++;
            TEST_ASSERT_TRUE(e.msg[0] != '\0');
            assert_mesh_empty(&m);
        }
    }
    /* pure noise is never a model */
    TEST_ASSERT_TRUE(failures >= 200);
    free(buf);
    free(valid);
}

/* ---- PLY ---- */

static const char *const ply_ascii =
    "ply\n"
    "format ascii 1.0\n"
    "comment written by hand\n"
    "obj_info for the unit tests\n"
    "element vertex 5\n"
    "property float x\n"
    "property float y\n"
    "property float z\n"
    "property uchar red\n"
    "property list uchar float extra\n"
    "element face 2\n"
    "property list uchar int vertex_indices\n"
    "property int flags\n"
    "element edge 1\n"
    "property int vertex1\n"
    "property int vertex2\n"
    "end_header\n"
    "0 0 0 255 2 0.5 0.5\n"
    "1 0 0 255 0\n"
    "1 1 0 0 1 7\n"
    "0 1 0 0 0\n"
    "-2.5 3.25 1e3 0 0\n"
    "4 0 1 2 3 9\n"
    "3 0 1 4 0\n"
    "0 1\n";

/* The quad 0 1 2 3 and the triangle 0 1 4 over the five vertices above. */
static void assert_ply_model(const arbor_mesh *m)
{
    TEST_ASSERT_EQUAL_UINT32(5, m->nverts);
    TEST_ASSERT_EQUAL_UINT32(3, m->ntris);
    assert_vec(1, 1, 0, m->verts[2]);
    assert_vec(-2.5f, 3.25f, 1000.0f, m->verts[4]);
    assert_tri(m, 0, 0, 1, 2);
    assert_tri(m, 1, 0, 2, 3);
    assert_tri(m, 2, 0, 1, 4);
    TEST_ASSERT_EQUAL_UINT32(0, m->tri_mat[2]);
}

static void test_ply_ascii(void)
{
    arbor_mesh m;
    arbor_err e;
    TEST_ASSERT_TRUE_MESSAGE(arbor_load_ply_data(ply_ascii, strlen(ply_ascii), "t.ply", &m, &e), e.msg);
    assert_ply_model(&m);
    arbor_mesh_free(&m);
}

/* A little writer for binary PLY bodies in either byte order. */
typedef struct {
    unsigned char bytes[1024];
    size_t len;
    bool big;
} byte_writer;

static void put(byte_writer *w, uint64_t bits, unsigned size)
{
    for (unsigned i = 0; i < size; i++)
        w->bytes[w->len + (w->big ? size - 1 - i : i)] = (unsigned char)(bits >> (8 * i));
    w->len += size;
}

static void put_f32(byte_writer *w, float f)
{
    uint32_t u;
    memcpy(&u, &f, sizeof u);
    put(w, u, 4);
}

static void put_f64(byte_writer *w, double d)
{
    uint64_t u;
    memcpy(&u, &d, sizeof u);
    put(w, u, 8);
}

static void put_text(byte_writer *w, const char *s)
{
    memcpy(w->bytes + w->len, s, strlen(s));
    w->len += strlen(s);
}

static const float ply_verts[5][3] = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}, {-2.5f, 3.25f, 1000.0f}};

/* Little endian: float coordinates, a skipped list among the vertex
 * properties, and an element after the faces with a list to skip. */
static void build_ply_little(byte_writer *w)
{
    memset(w, 0, sizeof *w);
    put_text(w, "ply\r\nformat binary_little_endian 1.0\r\n"
                "element vertex 5\r\nproperty float32 x\r\nproperty float32 y\r\nproperty float32 z\r\n"
                "property uchar alpha\r\nproperty list uint16 int32 junk\r\n"
                "element face 2\r\nproperty list uchar int vertex_indices\r\nproperty float quality\r\n"
                "element material 2\r\nproperty uchar r\r\nproperty list int int8 name\r\n"
                "end_header\r\n");
    for (int i = 0; i < 5; i++) {
        for (int k = 0; k < 3; k++)
            put_f32(w, ply_verts[i][k]);
        put(w, 200, 1);
        put(w, (uint64_t)(i % 2), 2);
        if (i % 2)
            put(w, (uint64_t)-7, 4);
    }
    put(w, 4, 1);
    for (int i = 0; i < 4; i++)
        put(w, (uint64_t)i, 4);
    put_f32(w, 0.5f);
    put(w, 3, 1);
    put(w, 0, 4);
    put(w, 1, 4);
    put(w, 4, 4);
    put_f32(w, 0.25f);
    for (int i = 0; i < 2; i++) {
        put(w, 9, 1);
        put(w, 3, 4);
        put_text(w, "abc");
    }
}

/* Big endian: double coordinates after a skipped short, the vertex_index
 * spelling with uint items, and a skipped list before it. */
static void build_ply_big(byte_writer *w)
{
    memset(w, 0, sizeof *w);
    w->big = true;
    put_text(w, "ply\nformat binary_big_endian 1.0\ncomment big\n"
                "element vertex 5\nproperty short id\nproperty double x\nproperty double y\nproperty double z\n"
                "element face 2\nproperty list uchar short other\nproperty list int uint vertex_index\n"
                "end_header\n");
    for (int i = 0; i < 5; i++) {
        put(w, (uint64_t)(1000 + i), 2);
        for (int k = 0; k < 3; k++)
            put_f64(w, ply_verts[i][k]);
    }
    unsigned quad[] = {0, 1, 2, 3}, tri[] = {0, 1, 4};
    put(w, 1, 1);
    put(w, 77, 2);
    put(w, 4, 4);
    for (int i = 0; i < 4; i++)
        put(w, quad[i], 4);
    put(w, 0, 1);
    put(w, 3, 4);
    for (int i = 0; i < 3; i++)
        put(w, tri[i], 4);
}

static void test_ply_binary_both_byte_orders(void)
{
    void (*builders[])(byte_writer *) = {build_ply_little, build_ply_big};
    for (int b = 0; b < 2; b++) {
        byte_writer w;
        builders[b](&w);
        arbor_mesh m;
        arbor_err e;
        TEST_ASSERT_TRUE_MESSAGE(arbor_load_ply_data((const char *)w.bytes, w.len, "t.ply", &m, &e), e.msg);
        assert_ply_model(&m);
        arbor_mesh_free(&m);
    }
}

static void test_ply_files_plain_and_gz(void)
{
    byte_writer w;
    build_ply_big(&w);
    arbor_mesh m;
    arbor_err e;
    TEST_ASSERT_TRUE_MESSAGE(arbor_load_model(write_bytes("big.ply", w.bytes, w.len), &m, &e), e.msg);
    assert_ply_model(&m);
    arbor_mesh_free(&m);
    TEST_ASSERT_TRUE_MESSAGE(arbor_load_model(write_gz("big.PLY.gz", w.bytes, w.len), &m, &e), e.msg);
    assert_ply_model(&m);
    arbor_mesh_free(&m);
}

/* The header of ply_ascii with one line replaced. */
static void assert_ply_header_fails(const char *line, const char *replacement, const char *fragment)
{
    char text[2048];
    const char *at = strstr(ply_ascii, line);
    TEST_ASSERT_NOT_NULL(at);
    snprintf(text, sizeof text, "%.*s%s%s", (int)(at - ply_ascii), ply_ascii, replacement, at + strlen(line));
    assert_ply_fails(text, strlen(text), fragment);
}

static void test_ply_errors(void)
{
    assert_ply_header_fails("ply\n", "plx\n", "t.ply:1: not a PLY file");
    assert_ply_header_fails("format ascii 1.0\n", "format binary_middle_endian 1.0\n", "t.ply:2: unknown format");
    assert_ply_header_fails("format ascii 1.0\n", "format ascii 2.0\n", "t.ply:2: unsupported PLY version '2.0'");
    assert_ply_header_fails("format ascii 1.0\n", "", "t.ply: header has no format line");
    assert_ply_header_fails("element vertex 5\n", "property float w\nelement vertex 5\n",
                            "t.ply:5: property before any element");
    assert_ply_header_fails("property float y\n", "property float128 y\n", "t.ply:7: unknown property type 'float128'");
    assert_ply_header_fails("property float z\n", "property float zz\n", "element 'vertex' has no 'z' property");
    assert_ply_header_fails("property list uchar int vertex_indices\n", "property int vertex_indices\n",
                            "t.ply:12: face property 'vertex_indices' is not a list");
    assert_ply_header_fails("element face 2\n", "element face 99999999999\n", "t.ply:11: element count");
    assert_ply_header_fails("element vertex 5\n", "element vertex -1\n", "t.ply:5: element count -1 out of range");
    assert_ply_header_fails("end_header\n", "end_headers\n", "t.ply:17: unknown header line 'end_headers'");
    const char *unended = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n";
    assert_ply_fails(unended, strlen(unended), "t.ply:5: header ends without end_header");
    assert_ply_header_fails("4 0 1 2 3 9\n", "4 0 1 2 5 9\n", "t.ply:23: vertex index 5 out of range (5 vertices)");
    assert_ply_header_fails("4 0 1 2 3 9\n", "4 0 1 -2 3 9\n", "t.ply:23: vertex index -2 out of range");
    assert_ply_header_fails("3 0 1 4 0\n", "2 0 1 0\n", "t.ply:24: face has 2 vertices (needs at least 3)");
    assert_ply_header_fails("1 1 0 0 1 7\n", "1 1 zero 0 1 7\n", "t.ply:20: malformed number 'zero'");
    assert_ply_header_fails("3 0 1 4 0\n0 1\n", "", "t.ply:23: data ends in element 'face' (item 1 of 2)");
    assert_ply_header_fails("3 0 1 4 0\n0 1\n", "3 0 1\n", "t.ply:24: 3 values where element 'face' needs 5");
    assert_ply_header_fails("0 1 0 0 0\n", "0 1 0 0\n", "t.ply:21: 4 values where element 'vertex' needs at least 5");
    assert_ply_header_fails("-2.5 3.25 1e3 0 0\n", "-2.5 3.25 1e39 0 0\n", "t.ply:22: infinite vertex coordinate");
}

/* A triangle's header, for bodies that are wrong in one line; the body
 * starts at line 10. */
static void assert_ply_body_fails(uint32_t nverts, const char *body, const char *fragment)
{
    char text[1024];
    snprintf(text, sizeof text,
             "ply\nformat ascii 1.0\nelement vertex %u\nproperty float x\nproperty float y\nproperty float z\n"
             "element face 1\nproperty list uchar int vertex_indices\nend_header\n%s",
             nverts, body);
    assert_ply_fails(text, strlen(text), fragment);
}

/* In ascii each item is one line: a short or long line is an error there,
 * not a shift of every value after it. */
static void test_ply_ascii_items_are_lines(void)
{
    assert_ply_body_fails(3, "0 0 0\n1 0\n0 1 0 0\n3 0 1 2\n", "t.ply:11: 2 values where element 'vertex' needs 3");
    assert_ply_body_fails(3, "0 0 0\n1 0\n0 1 0\n3 0 1 2\n", "t.ply:11: 2 values where element 'vertex' needs 3");
    assert_ply_body_fails(3, "0 0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", "t.ply:10: 4 values where element 'vertex' needs 3");
    assert_ply_body_fails(4, "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", "t.ply:13: 4 values where element 'vertex' needs 3");
    assert_ply_body_fails(4, "0 0 0\n1 0 0\n0 1 0\n", "t.ply:12: data ends in element 'vertex' (item 3 of 4)");
    assert_ply_body_fails(3, "0 0 0\n1 0 0\n0 1 0\n3 0 1 2 2\n", "t.ply:13: 5 values where element 'face' needs 4");
    assert_ply_body_fails(3, "0 0 0\n1 0 0\n0 1 0\n3 0 1", "t.ply:13: 3 values where element 'face' needs 4");
    assert_ply_body_fails(3, "0 0 0\n1 0 0\n0 1 0\n3\n0 1 2\n", "t.ply:13: 1 value where element 'face' needs 4");
}

/* Blank lines between items are read past; data after the last element
 * loads with a warning naming where it starts. */
static void test_ply_data_after_the_last_element_is_a_warning(void)
{
    const char *header = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                         "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n";
    const char *bodies[] = {"0 0 0\r\n\n  \n1 0 0\r\n0 1 0\r\n\t\n3 0 1 2\r\n \n\n",
                            "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n\n3 0 2 1\n4 0 1 2 0\n",
                            "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n3 0 2 1"};
    const char *warnings[] = {NULL, "t.ply:15: 2 lines after the last element ignored",
                              "t.ply:14: 1 line after the last element ignored"};
    for (int i = 0; i < 3; i++) {
        char text[512];
        snprintf(text, sizeof text, "%s%s", header, bodies[i]);
        arbor_mesh m;
        arbor_err e;
        TEST_ASSERT_TRUE_MESSAGE(arbor_load_ply_data(text, strlen(text), "t.ply", &m, &e), e.msg);
        TEST_ASSERT_EQUAL_UINT32(1, m.ntris);
        assert_tri(&m, 0, 0, 1, 2);
        TEST_ASSERT_EQUAL_UINT32(warnings[i] != NULL, m.nwarnings);
        if (warnings[i] != NULL) {
            TEST_ASSERT_TRUE_MESSAGE(has_warning(&m, warnings[i]), m.warnings[0]);
        }
        arbor_mesh_free(&m);
    }

    byte_writer w;
    build_ply_little(&w);
    arbor_mesh m;
    arbor_err e;
    TEST_ASSERT_TRUE_MESSAGE(arbor_load_ply_data((const char *)w.bytes, w.len, "t.ply", &m, &e), e.msg);
    TEST_ASSERT_EQUAL_UINT32(0, m.nwarnings);
    arbor_mesh_free(&m);
    put(&w, '\n', 1);
    put(&w, 0, 1);
    put(&w, 1, 1);
    TEST_ASSERT_TRUE_MESSAGE(arbor_load_ply_data((const char *)w.bytes, w.len, "t.ply", &m, &e), e.msg);
    assert_ply_model(&m);
    TEST_ASSERT_EQUAL_UINT32(1, m.nwarnings);
    TEST_ASSERT_TRUE_MESSAGE(has_warning(&m, "t.ply: 3 bytes after the last element ignored"), m.warnings[0]);
    arbor_mesh_free(&m);
}

/* Every cut of a binary PLY short of its full length is an error naming
 * where the data ran out, never a partial model. */
static void test_ply_binary_truncated_anywhere_fails(void)
{
    byte_writer w;
    build_ply_little(&w);
    size_t body = (size_t)(strstr((const char *)w.bytes, "end_header\r\n") - (const char *)w.bytes) + 12;
    for (size_t cut = 0; cut < w.len; cut++) {
        arbor_mesh m;
        arbor_err e;
        TEST_ASSERT_FALSE(arbor_load_ply_data((const char *)w.bytes, cut, "t.ply", &m, &e));
        TEST_ASSERT_EQUAL_INT(ARBOR_ERR_PARSE, e.status);
        if (cut >= body) {
            TEST_ASSERT_NOT_NULL_MESSAGE(strstr(e.msg, "truncated binary data"), e.msg);
        }
        assert_mesh_empty(&m);
    }
}

static void test_ply_binary_nan_coordinate(void)
{
    byte_writer w, nan = {.len = 0};
    build_ply_little(&w);
    size_t body = (size_t)(strstr((const char *)w.bytes, "end_header\r\n") - (const char *)w.bytes) + 12;
    put_f32(&nan, NAN);
    memcpy(w.bytes + body + 4, nan.bytes, 4); /* vertex 0's y */
    arbor_mesh m;
    arbor_err e;
    TEST_ASSERT_FALSE(arbor_load_ply_data((const char *)w.bytes, w.len, "t.ply", &m, &e));
    assert_error(&e, ARBOR_ERR_PARSE, "t.ply: vertex 0: NaN vertex coordinate");
    assert_mesh_empty(&m);
}

/* ---- the number parser ---- */

/* arbor_parse_float must agree with strtof on the value (bit for bit) and on
 * where the number ends. */
static void assert_parses_like_strtof(const char *s)
{
    char *strtof_end;
    float want = strtof(s, &strtof_end);
    float got = 0.0f;
    const char *end = arbor_parse_float(s, s + strlen(s), &got);
    const char *want_end = strtof_end == s ? NULL : strtof_end;
    char msg[160];
    snprintf(msg, sizeof msg, "'%.100s': got %.9g want %.9g", s, (double)got, (double)want);
    TEST_ASSERT_EQUAL_PTR_MESSAGE(want_end, end, msg);
    if (end == NULL)
        return;
    uint32_t gb, wb;
    memcpy(&gb, &got, 4);
    memcpy(&wb, &want, 4);
    if (isnan(want)) {
        TEST_ASSERT_TRUE_MESSAGE(isnan(got) && signbit(got) == signbit(want), msg);
    } else {
        TEST_ASSERT_EQUAL_HEX32_MESSAGE(wb, gb, msg);
    }
}

static void test_parse_float_edge_cases(void)
{
    const char *cases[] = {
        "0", "-0", "+0", "0.0", "-0.0e5", "1", "+1.5", ".5", "-.5", "5.", "5.e3", ".5e-3", "1e5", "1E5", "1e+5",
        "1e-5", "0.1", "0.2", "0.3", "123.456", "-38.943748", "41.744942", "0.0527295", "2.5e-3", "00000.00001",
        "1e-38", "1.17549435e-38", "1.1754942e-38", "1e-40", "1e-45", "1.4e-45", "7e-46", "7.1e-46", "1e-46",
        "1e-50", "3.4028235e38", "3.40282347e38", "3.4028236e38", "3.40282357e38", "3.4028236e+38", "1e38",
        "1e39", "1e999", "-1e999", "1e-999", "1e99999999999999999999", "1e-99999999999999999999",
        "16777216", "16777217", "16777218", "16777219", "33554431", "33554433", "16777216.5", "16777217.000001",
        "1.000000059604644775390625", "1.000000059604644775390624", "1.000000059604644775390626",
        "1.00000005960464477539062500000000001", "1.0000000596046447753906249999999999",
        "9007199254740993", "9007199254740992", "18446744073709551615", "18446744073709551616",
        "1234567890123456789012345678901234567890", "0.000000000000000000000000000000000000000000001401298464324817",
        "123456789e-30", "9999999999999999999", "99999999999999999999e-20", "0.30000001192092895507812500001",
        "4.5e15", "1e22", "1e23", "3e22", "8.5e-38", "inf", "-inf", "+INF", "Infinity", "-infinity", "infinit",
        "nan", "-NaN", "1e", "1e+", "1e-x", "1.5.2", "2.5f", "+", "-", ".", "+.", "e5", "", "x1", "--1", "+-1",
        "0.000000000000000000000000000000000000011754943508222875079687365372222456778186655567720875215087517062784",
        "0.0000000000000000000000000000000000000117549421069244107548702944484928734882705242874589333385717453057158",
        "7.00649232162408535461864791644958065640130970938257885878534141944895541342930300743319094181060791015625e-46",
        "7.00649232162408535461864791644958065640130970938257885878534141944895541342930300743319094181060791015626e-46",
        "340282356779733661637539395458142568448", "340282356779733661637539395458142568447",
        /* short decimals whose double is exactly a float midpoint although
         * they are not: rounding through double alone would go wrong */
        "5.027412844356149e-04", "8.812020346522331e-02", "2.35276494640857e-03", "3.040467482060194e-02",
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++)
        assert_parses_like_strtof(cases[i]);

    /* the float midpoint 1 + 2^-24 followed by 300 zeros, then a 1 far past
     * any digit the parser keeps: it must still round up */
    char past[400];
    int n = snprintf(past, sizeof past, "1.000000059604644775390625");
    memset(past + n, '0', 300);
    strcpy(past + n + 300, "1");
    assert_parses_like_strtof(past);
    past[n + 300] = '\0';
    assert_parses_like_strtof(past);
    /* 250 integer digits brought back into range by the exponent */
    memset(past, '3', 250);
    strcpy(past + 250, "e-240");
    assert_parses_like_strtof(past);
}

static void test_parse_float_random_decimals(void)
{
    test_rng g;
    test_rng_seed(&g, 2024);
    for (int i = 0; i < 300000; i++) {
        char s[96];
        size_t n = 0;
        uint32_t r = test_rng_u32(&g);
        if (r % 3)
            s[n++] = r % 3 == 1 ? '-' : '+';
        int int_digits = (int)(test_rng_u32(&g) % 14), frac_digits = (int)(test_rng_u32(&g) % 14);
        if (i % 5 == 0) /* long mantissas, past the 19 digits of the fast path */
            int_digits += 15, frac_digits += 10;
        for (int k = 0; k < int_digits; k++)
            s[n++] = (char)('0' + test_rng_u32(&g) % 10);
        if (frac_digits > 0 || int_digits == 0) {
            s[n++] = '.';
            for (int k = 0; k < frac_digits || (k == 0 && int_digits == 0); k++)
                s[n++] = (char)('0' + test_rng_u32(&g) % 10);
        }
        if (test_rng_u32(&g) % 2)
            n += (size_t)snprintf(s + n, sizeof s - n, "e%d", (int)(test_rng_u32(&g) % 101) - 60);
        s[n] = '\0';
        assert_parses_like_strtof(s);
    }
}

/* Shortest and longer printings of random float bit patterns: every float,
 * from subnormals to the largest, must come back exactly. */
static void test_parse_float_round_trips_random_floats(void)
{
    test_rng g;
    test_rng_seed(&g, 99);
    const char *formats[] = {"%.9g", "%.6g", "%.8e", "%.17g", "%.3f"};
    for (int i = 0; i < 200000; i++) {
        uint32_t bits = test_rng_u32(&g);
        float f;
        memcpy(&f, &bits, 4);
        if (!isfinite(f))
            continue;
        char s[512];
        snprintf(s, sizeof s, formats[i % 5], (double)f);
        assert_parses_like_strtof(s);
    }
}

/* ---- the real models ---- */

typedef struct {
    const char *file;
    uint32_t tris, verts;
    float lo[3], hi[3];
} model_facts;

static void test_every_shared_model_matches_its_readme(void)
{
    const model_facts models[] = {
        {"galleon.obj", 4698, 2372, {-38.943748f, -19.209759f, -22.499998f}, {41.744942f, 54.333931f, 22.499998f}},
        {"castle.obj", 13114, 6620, {-32.562561f, -7.721932f, -15.862883f}, {31.58654f, 38.515659f, 11.31336f}},
        {"soccerball.obj", 3516, 1760, {-4.681843f, -4.693367f, -4.696131f}, {4.681843f, 4.693367f, 4.696131f}},
        {"bunny.obj", 69451, 35947, {-0.09469f, 0.032987f, -0.061874f}, {0.061009f, 0.187321f, 0.0588f}},
        {"sponza.obj.gz", 66454, 39999, {-17.40276f, -0.906689f, -7.798512f}, {17.41724f, 15.653312f, 7.801489f}},
        {"dragon.obj.gz", 871414, 437645, {-0.108324f, 0.0527295f, -0.0504143f}, {0.0965662f, 0.197173f, 0.0412075f}},
        {"f-16.obj", 4592, 2344, {-5.8363f, 2.852378f, -5.98573f}, {2.08683f, 6.51969f, 5.77042f}},
        {"flowers.obj", 7625, 7608, {-5.735474f, -12.469247f, -6.290819f}, {5.735474f, 12.469279f, 6.290739f}},
        {"porsche.obj", 7322, 4099, {-25.25757f, -16.901169f, -57.002853f}, {25.25757f, 16.901169f, 57.002853f}},
        {"rose+vase.obj", 3360, 2184, {-20.1157f, -59.760849f, -32.410851f}, {20.1157f, 59.760849f, 32.410851f}},
    };
    for (size_t i = 0; i < sizeof models / sizeof models[0]; i++) {
        const model_facts *f = &models[i];
        arbor_mesh m;
        arbor_err e;
        char msg[700];
        bool ok = arbor_load_model(test_shared_model(f->file), &m, &e);
        snprintf(msg, sizeof msg, "%s: %s", f->file, ok ? "" : e.msg);
        TEST_ASSERT_TRUE_MESSAGE(ok, msg);
        TEST_ASSERT_EQUAL_UINT32_MESSAGE(f->tris, m.ntris, msg);
        TEST_ASSERT_EQUAL_UINT32_MESSAGE(f->verts, m.nverts, msg);
        /* the README's box is over every v line; the mesh's over the
         * vertices triangles use: in these models they are the same */
        arbor_aabb all = aabb_empty();
        for (uint32_t v = 0; v < m.nverts; v++)
            all = aabb_grow(all, m.verts[v]);
        for (int axis = 0; axis < 3; axis++) {
            TEST_ASSERT_TRUE_MESSAGE(test_close(f->lo[axis], vec3_axis(all.lo, axis), 1e-5f), msg);
            TEST_ASSERT_TRUE_MESSAGE(test_close(f->hi[axis], vec3_axis(all.hi, axis), 1e-5f), msg);
            TEST_ASSERT_TRUE_MESSAGE(test_close(f->lo[axis], vec3_axis(m.bounds.lo, axis), 1e-5f), msg);
            TEST_ASSERT_TRUE_MESSAGE(test_close(f->hi[axis], vec3_axis(m.bounds.hi, axis), 1e-5f), msg);
        }
        arbor_mesh_free(&m);
    }
}

static void test_soccerball_gets_its_mtl_materials(void)
{
    arbor_mesh m;
    arbor_err e;
    TEST_ASSERT_TRUE_MESSAGE(arbor_load_model(test_shared_model("soccerball.obj"), &m, &e), e.msg);
    TEST_ASSERT_EQUAL_UINT32(0, m.nwarnings);
    const arbor_material *white = material(&m, "white"), *black = material(&m, "black");
    assert_vec(1, 1, 1, white->kd);
    assert_vec(0.6f, 0.1f, 0.1f, black->kd);
    assert_vec(0.6f, 0.6f, 0.6f, black->ks);
    TEST_ASSERT_EQUAL_FLOAT(300.0f, black->ns);
    uint32_t counts[2] = {0, 0};
    for (uint32_t t = 0; t < m.ntris; t++) {
        TEST_ASSERT_TRUE(m.tri_mat[t] == (uint32_t)(white - m.mats) || m.tri_mat[t] == (uint32_t)(black - m.mats));
        counts[m.tri_mat[t] == (uint32_t)(black - m.mats)]++;
    }
    TEST_ASSERT_TRUE(counts[0] > 0 && counts[1] > 0);
    arbor_mesh_free(&m);
}

static void test_castle_loads_without_its_missing_mtl(void)
{
    arbor_mesh m;
    arbor_err e;
    TEST_ASSERT_TRUE_MESSAGE(arbor_load_model(test_shared_model("castle.obj"), &m, &e), e.msg);
    TEST_ASSERT_TRUE(has_warning(&m, "castle.obj:5: material library not loaded"));
    TEST_ASSERT_TRUE(has_warning(&m, "castle.mtl"));
    const arbor_material *bone = material(&m, "bone");
    assert_vec(0.7f, 0.7f, 0.7f, bone->kd);
    arbor_mesh_free(&m);
}

int main(void)
{
    UNITY_BEGIN();
    RUN_TEST(test_every_index_form);
    RUN_TEST(test_negative_indices_count_from_the_current_end);
    RUN_TEST(test_polygons_become_fans_from_their_first_vertex);
    RUN_TEST(test_vertex_normals_follow_the_fan);
    RUN_TEST(test_shading_normal_interpolates);
    RUN_TEST(test_crlf_tabs_comments_and_skipped_statements);
    RUN_TEST(test_every_skipped_obj_statement_is_silent);
    RUN_TEST(test_unknown_obj_statements_are_a_warning);
    RUN_TEST(test_warnings_are_capped_and_counted);
    RUN_TEST(test_materials_are_capped);
    RUN_TEST(test_a_model_too_large_for_floats_is_refused);
    RUN_TEST(test_binary_data_in_obj_is_an_error);
    RUN_TEST(test_faces_before_usemtl_use_the_default_material);
    RUN_TEST(test_mtl_values_reach_the_materials_faces_use);
    RUN_TEST(test_several_libraries_on_one_mtllib_line);
    RUN_TEST(test_missing_mtl_is_a_warning);
    RUN_TEST(test_mtllib_outside_the_models_folder_is_refused);
    RUN_TEST(test_mtllib_symlinks_cannot_leave_the_models_folder);
    RUN_TEST(test_malformed_mtl_fails_with_its_line);
    RUN_TEST(test_obj_gz_loads_like_the_plain_file);
    RUN_TEST(test_truncated_gz_is_an_error);
    RUN_TEST(test_gz_is_capped_by_its_decompressed_size);
    RUN_TEST(test_errors_name_file_line_and_reason);
    RUN_TEST(test_file_errors);
    RUN_TEST(test_megabyte_lines);
    RUN_TEST(test_garbage_never_crashes);
    RUN_TEST(test_ply_ascii);
    RUN_TEST(test_ply_binary_both_byte_orders);
    RUN_TEST(test_ply_files_plain_and_gz);
    RUN_TEST(test_ply_errors);
    RUN_TEST(test_ply_ascii_items_are_lines);
    RUN_TEST(test_ply_data_after_the_last_element_is_a_warning);
    RUN_TEST(test_ply_binary_truncated_anywhere_fails);
    RUN_TEST(test_ply_binary_nan_coordinate);
    RUN_TEST(test_parse_float_edge_cases);
    RUN_TEST(test_parse_float_random_decimals);
    RUN_TEST(test_parse_float_round_trips_random_floats);
    RUN_TEST(test_every_shared_model_matches_its_readme);
    RUN_TEST(test_soccerball_gets_its_mtl_materials);
    RUN_TEST(test_castle_loads_without_its_missing_mtl);
    return UNITY_END();
}
