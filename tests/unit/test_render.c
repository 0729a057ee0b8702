/*
 * test_render.c - the tracer: known images of a quad that fills the view
 * (written with the sRGB curve), secondary rays' robust offsets (origins off
 * the plane at any magnitude, no self-shadowing far from the origin, frames
 * the same at scales 2^-10..2^10, thin gaps that do not leak), glass against
 * closed forms (a pane's lateral displacement and Fresnel transmittance,
 * shadows through it, total internal reflection), PROTOCOL.md's primary hits
 * against brute force, PROTOCOL.md's secondary sets, frames identical on 1
 * and 4 threads, frames in flight together, every mode through PNG and back,
 * cancelling, parameter checks, and regions: byte for byte the same
 * rectangle of the whole frame (in heat mode given the whole frame's
 * heat_scale), invalid regions refused.
 */
#include <math.h>
#include <png.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "arbor/brute.h"
#include "arbor/load.h"
#include "arbor/png.h"
#include "arbor/raysets.h"
#include "arbor/render.h"
#include "../../src/render/sampling.h"
#include "support.h"
#include "unity.h"

static arbor_pool *pool1, *pool4;

void setUp(void) {}
void tearDown(void) {}

static arbor_accel *build(const arbor_mesh *m, arbor_accel_kind kind)
{
    arbor_build_opts o;
    arbor_build_opts_init(&o, kind, ARBOR_BUILD_SAH);
    arbor_err e;
    arbor_accel *a = arbor_accel_build(m, &o, &e);
    TEST_ASSERT_NOT_NULL_MESSAGE(a, e.msg);
    return a;
}

/* A 20 x 20 square in the plane z = 0 centred on the origin, with material
 * mat: 0 the default, 1 a second one for the test to set. */
static void make_quad(arbor_mesh *m, uint32_t mat)
{
    arbor_mesh_init(m);
    arbor_mesh_add_vert(m, vec3(-10, -10, 0), NULL);
    arbor_mesh_add_vert(m, vec3(10, -10, 0), NULL);
    arbor_mesh_add_vert(m, vec3(10, 10, 0), NULL);
    arbor_mesh_add_vert(m, vec3(-10, 10, 0), NULL);
    uint32_t index;
    arbor_mesh_add_material(m, "default", &index, NULL);
    arbor_mesh_add_material(m, "test", &index, NULL);
    arbor_mesh_add_tri(m, 0, 1, 2, mat, NULL);
    arbor_mesh_add_tri(m, 0, 2, 3, mat, NULL);
    TEST_ASSERT_TRUE(arbor_mesh_finish(m, NULL));
}

/* Looking straight at the quad from z = 5: the view (about +-2.7 x +-2.1 at
 * z = 0) lies well inside it, so every pixel hits. */
static void quad_params(arbor_render_params *p, const arbor_mesh *m, arbor_render_mode mode)
{
    arbor_render_params_init(p, m, 64, 48);
    arbor_camera_look_at(&p->camera, vec3(0, 0, 5), vec3(0, 0, 0), vec3(0, 1, 0), 45.0f, 64, 48);
    p->mode = mode;
}

static arbor_frame *render_ok(arbor_pool *pool, const arbor_accel *a, const arbor_render_params *p)
{
    arbor_err e;
    arbor_frame *f = arbor_render(pool, a, p, &e);
    TEST_ASSERT_NOT_NULL_MESSAGE(f, e.msg);
    TEST_ASSERT_FALSE(arbor_frame_result_of(f)->cancelled);
    return f;
}

static void assert_every_pixel(const arbor_frame_result *r, int red, int green, int blue)
{
    for (int i = 0; i < r->width * r->height; i++) {
        TEST_ASSERT_EQUAL_UINT8(red, r->rgb[3 * i]);
        TEST_ASSERT_EQUAL_UINT8(green, r->rgb[3 * i + 1]);
        TEST_ASSERT_EQUAL_UINT8(blue, r->rgb[3 * i + 2]);
    }
}

static void test_quad_normals_fill_the_view(void)
{
    arbor_mesh m;
    make_quad(&m, 0);
    arbor_accel *a = build(&m, ARBOR_ACCEL_BVH);
    arbor_render_params p;
    quad_params(&p, &m, ARBOR_MODE_NORMALS);
    p.spp = 4;
    arbor_frame *f = render_ok(pool4, a, &p);
    const arbor_frame_result *r = arbor_frame_result_of(f);
    /* n = (0, 0, 1) faces the viewer: (0.5, 0.5, 1) */
    assert_every_pixel(r, 128, 128, 255);
    TEST_ASSERT_EQUAL_UINT64(64 * 48 * 4, r->rays);
    arbor_frame_release(f);
    /* seen from behind, the normal turned toward the viewer is (0, 0, -1): (0.5, 0.5, 0) */
    arbor_camera_look_at(&p.camera, vec3(0, 0, -5), vec3(0, 0, 0), vec3(0, 1, 0), 45.0f, 64, 48);
    f = render_ok(pool4, a, &p);
    assert_every_pixel(arbor_frame_result_of(f), 128, 128, 0);
    arbor_frame_release(f);
    arbor_accel_free(a);
    arbor_mesh_free(&m);
}

static uint8_t expected_byte(float v)
{
    return (uint8_t)(fminf(1.0f, fmaxf(0.0f, v)) * 255.0f + 0.5f);
}

/* The sRGB transfer curve of IEC 61966-2-1, in double, and its inverse. */
static double srgb(double linear)
{
    return linear <= 0.0031308 ? 12.92 * linear : 1.055 * pow(linear, 1.0 / 2.4) - 0.055;
}

static double srgb_inverse(double encoded)
{
    return encoded <= 0.04045 ? encoded / 12.92 : pow((encoded + 0.055) / 1.055, 2.4);
}

/* The byte a shaded pixel of linear radiance v is written as. */
static uint8_t shaded_byte(double v)
{
    return expected_byte((float)srgb(v));
}

/* The pixel at the image centre sees the origin; the light is at
 * eye + 0.5 d up = (0, 0.5 d, 5), d the quad's diagonal. */
static void test_quad_shaded_centre_is_lambert(void)
{
    arbor_mesh m;
    make_quad(&m, 1);
    m.mats[1].kd = vec3(0.8f, 0.4f, 0.2f);
    arbor_accel *a = build(&m, ARBOR_ACCEL_BVH);
    arbor_render_params p;
    quad_params(&p, &m, ARBOR_MODE_SHADED);
    p.camera.width = p.camera.height = 65; /* odd, so one pixel centre is the image centre */
    arbor_frame *f = render_ok(pool4, a, &p);
    const uint8_t *px = arbor_frame_result_of(f)->rgb + 3 * (32 * 65 + 32);
    float d = sqrtf(800.0f);
    arbor_vec3 light = vec3(0.0f, 0.5f * d, 5.0f);
    float cosine = light.z / vec3_length(light);
    float kd[3] = {0.8f, 0.4f, 0.2f};
    for (int c = 0; c < 3; c++) {
        float linear = kd[c] * (0.15f + 0.85f * cosine);
        TEST_ASSERT_INT_WITHIN(1, shaded_byte(linear), px[c]);
    }
    arbor_frame_release(f);
    /* dark colours, where the sRGB curve's linear toe and gamma 2.2 part:
     * 0.0022 linear is byte 7 in sRGB, 16 with gamma 2.2; 0.022 is 40, not 45 */
    m.mats[1].kd = vec3(0.005f, 0.05f, 0.5f);
    f = render_ok(pool4, a, &p);
    px = arbor_frame_result_of(f)->rgb + 3 * (32 * 65 + 32);
    float dark[3] = {0.005f, 0.05f, 0.5f};
    for (int c = 0; c < 3; c++) {
        double linear = dark[c] * (0.15 + 0.85 * cosine);
        TEST_ASSERT_INT_WITHIN(1, shaded_byte(linear), px[c]);
        if (c < 2) {
            TEST_ASSERT_TRUE(abs(expected_byte((float)pow(linear, 1.0 / 2.2)) - px[c]) > 3);
        }
    }
    arbor_frame_release(f);
    arbor_accel_free(a);
    arbor_mesh_free(&m);
}

/* A model of no extent (every vertex at one point) puts any orbit camera's
 * eye on its target: refused with a message, not rendered with NaN rays. */
static void test_camera_around_a_point_is_refused(void)
{
    arbor_mesh m;
    arbor_mesh_init(&m);
    for (int i = 0; i < 3; i++)
        arbor_mesh_add_vert(&m, vec3(1, 2, 3), NULL);
    arbor_mesh_add_tri(&m, 0, 1, 2, 0, NULL);
    TEST_ASSERT_TRUE(arbor_mesh_finish(&m, NULL));
    arbor_render_params p;
    arbor_render_params_init(&p, &m, 32, 24);
    arbor_err e;
    TEST_ASSERT_FALSE(arbor_render_params_validate(&p, &e));
    TEST_ASSERT_NOT_NULL_MESSAGE(strstr(e.msg, "camera.eye"), e.msg);
    arbor_camera_orbit(&p.camera, m.bounds, 30.0f, 10.0f, 1.5f, 45.0f, 32, 24);
    TEST_ASSERT_FALSE(arbor_render_params_validate(&p, &e));
    /* an explicit camera that looks at it is fine */
    arbor_camera_look_at(&p.camera, vec3(1, 2, 8), vec3(1, 2, 3), vec3(0, 1, 0), 45.0f, 32, 24);
    TEST_ASSERT_TRUE_MESSAGE(arbor_render_params_validate(&p, &e), e.msg);
    arbor_mesh_free(&m);
}

/* MTL Ks is a highlight's colour, not a mirror's (exporters such as
 * Blender write Ks 0.5 on every material): under illum 2 every pixel of the
 * lit quad is Kd's Lambert plus Ks times the Blinn-Phong term (n.h)^Ns,
 * computed here per pixel centre in double; under illum 1 Lambert alone. */
static void test_ks_is_a_highlight_under_illum_2(void)
{
    arbor_mesh m;
    make_quad(&m, 1);
    m.mats[1].kd = vec3(0.4f, 0.3f, 0.2f);
    m.mats[1].ks = vec3(0.6f, 0.6f, 0.5f);
    m.mats[1].ns = 8.0f;
    arbor_accel *a = build(&m, ARBOR_ACCEL_BVH);
    arbor_render_params p;
    quad_params(&p, &m, ARBOR_MODE_SHADED);
    arbor_vec3 light = vec3_add(p.camera.eye, vec3_scale(p.camera.up, 0.5f * sqrtf(800.0f)));
    for (int illum = 1; illum <= 2; illum++) {
        m.mats[1].illum = illum;
        TEST_ASSERT_FALSE(arbor_material_is_mirror(&m.mats[1]));
        arbor_frame *f = render_ok(pool4, a, &p);
        const arbor_frame_result *r = arbor_frame_result_of(f);
        int brightened = 0;
        for (int y = 0; y < r->height; y++)
            for (int x = 0; x < r->width; x++) {
                arbor_ray ray = arbor_camera_ray(&p.camera, (float)x + 0.5f, (float)y + 0.5f);
                double dl = sqrt((double)ray.d.x * ray.d.x + (double)ray.d.y * ray.d.y + (double)ray.d.z * ray.d.z);
                double t = -ray.o.z / ray.d.z, v[3] = {-ray.d.x / dl, -ray.d.y / dl, -ray.d.z / dl};
                double l[3] = {light.x - (ray.o.x + t * ray.d.x), light.y - (ray.o.y + t * ray.d.y), light.z};
                double ll = sqrt(l[0] * l[0] + l[1] * l[1] + l[2] * l[2]);
                double h[3] = {l[0] / ll + v[0], l[1] / ll + v[1], l[2] / ll + v[2]};
                double highlight = illum == 2 ? pow(h[2] / sqrt(h[0] * h[0] + h[1] * h[1] + h[2] * h[2]), 8.0) : 0.0;
                const float kd[3] = {0.4f, 0.3f, 0.2f}, ks[3] = {0.6f, 0.6f, 0.5f};
                const uint8_t *px = r->rgb + 3 * (y * r->width + x);
                for (int c = 0; c < 3; c++)
                    TEST_ASSERT_INT_WITHIN(1, shaded_byte(kd[c] * (0.15 + 0.85 * l[2] / ll) + ks[c] * highlight), px[c]);
                brightened += highlight * 0.5 > 0.05;
            }
        TEST_ASSERT_EQUAL_UINT64(2 * 64 * 48, r->rays); /* primary + shadow ray each, no reflection */
        TEST_ASSERT_TRUE(illum == 1 || brightened > 64 * 48 / 2);
        arbor_frame_release(f);
    }
    for (int illum = 3; illum <= 5; illum += 2) {
        m.mats[1].illum = illum;
        TEST_ASSERT_TRUE(arbor_material_is_mirror(&m.mats[1]));
    }
    arbor_accel_free(a);
    arbor_mesh_free(&m);
}

/* A mirror facing the camera sends every ray back past the eye into the
 * background, tinted 0.9 (Ks is black): the background's sRGB bytes are
 * decoded to linear light, dimmed, and encoded again. */
static void test_mirror_reflects_the_background(void)
{
    arbor_mesh m;
    make_quad(&m, 1);
    m.mats[1].illum = 3;
    arbor_accel *a = build(&m, ARBOR_ACCEL_BVH);
    arbor_render_params p;
    quad_params(&p, &m, ARBOR_MODE_SHADED);
    p.background = vec3(0.2f, 0.6f, 1.0f);
    arbor_frame *f = render_ok(pool4, a, &p);
    const arbor_frame_result *r = arbor_frame_result_of(f);
    for (int i = 0; i < r->width * r->height; i++) {
        TEST_ASSERT_INT_WITHIN(1, shaded_byte(0.9 * srgb_inverse(0.2)), r->rgb[3 * i]);
        TEST_ASSERT_INT_WITHIN(1, shaded_byte(0.9 * srgb_inverse(0.6)), r->rgb[3 * i + 1]);
        TEST_ASSERT_INT_WITHIN(1, shaded_byte(0.9 * srgb_inverse(1.0)), r->rgb[3 * i + 2]);
    }
    TEST_ASSERT_EQUAL_UINT64(2 * 64 * 48, r->rays); /* primary + one reflection each */
    arbor_frame_release(f);
    /* with no bounces allowed, the mirror is shaded as a diffuse surface instead */
    p.max_bounces = 0;
    f = render_ok(pool4, a, &p);
    TEST_ASSERT_TRUE(arbor_frame_result_of(f)->rgb[1] > 128);
    arbor_frame_release(f);
    arbor_accel_free(a);
    arbor_mesh_free(&m);
}

/* Nothing lies above a lone plane: every AO ray escapes (white), and the
 * ray count is primary + ao_samples per pixel. */
static void test_ao_of_an_open_plane_is_white(void)
{
    arbor_mesh m;
    make_quad(&m, 0);
    arbor_accel *a = build(&m, ARBOR_ACCEL_BVH);
    arbor_render_params p;
    quad_params(&p, &m, ARBOR_MODE_AO);
    p.ao_samples = 5;
    arbor_frame *f = render_ok(pool4, a, &p);
    const arbor_frame_result *r = arbor_frame_result_of(f);
    assert_every_pixel(r, 255, 255, 255);
    TEST_ASSERT_EQUAL_UINT64(64 * 48 * 6, r->rays);
    arbor_frame_release(f);
    arbor_accel_free(a);
    arbor_mesh_free(&m);
}

/* ---- robust offsets of secondary rays ---- */

/* Which side of the plane of (a, b, c) q lies on, in the direction of
 * (b - a) x (c - a): the orientation determinant in long double, whose 64-bit
 * significand holds the float differences and their products closely
 * enough that its sign is right for points more than a few ulps off. */
static int plane_side(arbor_vec3 a, arbor_vec3 b, arbor_vec3 c, arbor_vec3 q)
{
    long double ux = (long double)b.x - a.x, uy = (long double)b.y - a.y, uz = (long double)b.z - a.z;
    long double vx = (long double)c.x - a.x, vy = (long double)c.y - a.y, vz = (long double)c.z - a.z;
    long double wx = (long double)q.x - a.x, wy = (long double)q.y - a.y, wz = (long double)q.z - a.z;
    long double det = wx * (uy * vz - uz * vy) + wy * (uz * vx - ux * vz) + wz * (ux * vy - uy * vx);
    return det > 0.0L ? 1 : det < 0.0L ? -1 : 0;
}

/* Random triangles at magnitudes from 2^-10 to 1e5 and at scales 2^-10..2^10,
 * random points on them rebuilt from barycentrics: the offset origin lies
 * strictly on the side of the plane it was offset to, on either side.
 * (PROTOCOL.md's p + 1e-4 d n, with p = o + t d from an eye 1.3 d away, puts
 * 1,320 of the 4,000 origins at 1e5 on the plane or behind it, where floats
 * are 2^-7 apart and 1e-4 d of a model of diagonal 20 rounds away; 1,953 at
 * 300 when the model is scaled by 2^-10, measured.) */
static void test_offset_origin_leaves_the_plane(void)
{
    static const float places[] = {0.0f, 0x1p-10f, 1.0f, 300.0f, 1e5f};
    static const float scales[] = {0x1p-10f, 1.0f, 0x1p10f};
    test_rng g;
    test_rng_seed(&g, 7);
    int tested = 0;
    for (size_t pi = 0; pi < sizeof places / sizeof places[0]; pi++)
        for (size_t si = 0; si < sizeof scales / sizeof scales[0]; si++) {
            arbor_mesh m;
            arbor_mesh_init(&m);
            float size = 20.0f * scales[si];
            for (int v = 0; v < 3 * 200; v++) {
                arbor_vec3 q = vec3(test_rng_float(&g) - 0.5f, test_rng_float(&g) - 0.5f, test_rng_float(&g) - 0.5f);
                arbor_mesh_add_vert(&m, vec3_add(vec3(places[pi], -places[pi], places[pi] * 0.5f), vec3_scale(q, size)),
                                    NULL);
            }
            for (uint32_t t = 0; t < 200; t++)
                arbor_mesh_add_tri(&m, 3 * t, 3 * t + 1, 3 * t + 2, 0, NULL);
            TEST_ASSERT_TRUE(arbor_mesh_finish(&m, NULL));
            sample_offset_scale scale = sample_offset_scale_of(&m);
            for (uint32_t t = 0; t < m.ntris; t++) {
                arbor_vec3 a, b, c;
                arbor_mesh_tri(&m, t, &a, &b, &c);
                arbor_vec3 n = vec3_normalize(arbor_mesh_tri_normal(&m, t));
                if (!(vec3_length(n) > 0.5f))
                    continue; /* degenerate after rounding */
                for (int k = 0; k < 20; k++) {
                    float u = test_rng_float(&g), v = test_rng_float(&g) * (1.0f - u);
                    arbor_hit h = {1.0f, u, v, t};
                    arbor_vec3 normal, expected = arbor_mesh_tri_normal(&m, t);
                    arbor_vec3 p = sample_hit_point(&m, &h, &normal);
                    TEST_ASSERT_EQUAL_MEMORY(&expected, &normal, sizeof normal);
                    TEST_ASSERT_EQUAL_INT(1, plane_side(a, b, c, sample_offset_ray(p, n, &scale)));
                    TEST_ASSERT_EQUAL_INT(-1, plane_side(a, b, c, sample_offset_ray(p, vec3_scale(n, -1.0f), &scale)));
                    tested++;
                }
            }
            arbor_mesh_free(&m);
        }
    TEST_ASSERT_TRUE(tested > 40000);
}

/* A plane of 16 x 16 quads tilted toward the protocol camera, vertices
 * (T + u e1 + v e2) * scale: the tilted position is rounded first, then
 * scaled exactly by a power of two. */
static void make_tilted_plane(arbor_mesh *m, float translate, float scale)
{
    arbor_mesh_init(m);
    arbor_vec3 e1 = vec3_normalize(vec3(1.0f, 0.0f, -0.3f)), e2 = vec3_normalize(vec3(0.0f, 1.0f, -0.2f));
    for (int j = 0; j <= 16; j++)
        for (int i = 0; i <= 16; i++) {
            arbor_vec3 q =
                vec3_add(vec3_scale(e1, -10.0f + 1.25f * (float)i), vec3_scale(e2, -10.0f + 1.25f * (float)j));
            arbor_mesh_add_vert(m, vec3_scale(vec3_add(vec3(translate, translate, translate), q), scale), NULL);
        }
    uint32_t index;
    arbor_mesh_add_material(m, "white", &index, NULL);
    m->mats[index].kd = vec3(1.0f, 1.0f, 1.0f);
    for (uint32_t j = 0; j < 16; j++)
        for (uint32_t i = 0; i < 16; i++) {
            uint32_t v = j * 17 + i;
            arbor_mesh_add_tri(m, v, v + 1, v + 18, index, NULL);
            arbor_mesh_add_tri(m, v, v + 18, v + 17, index, NULL);
        }
    TEST_ASSERT_TRUE(arbor_mesh_finish(m, NULL));
}

/* A lone plane lit from the side it shows the camera cannot shadow itself:
 * every pixel on it is brighter than the ambient light alone (byte 108 of
 * white; lit ones are above 200). Far from the origin (1e5) as near it, and
 * at scales 2^-10, 1 and 2^10, where the frames are the same bytes: every
 * offset scales with the model. Measured with PROTOCOL.md's p + 1e-4 d n
 * (p = o + t d) instead: none of the 5,724 plane pixels shadowed at the
 * origin, 2,877 of them at 1e5; with Waechter & Binder's fallback constants
 * fixed rather than in the model's units, the 2^-10 frame differs from the
 * others in 195 bytes. */
static void test_no_self_shadowing_far_away_or_at_any_scale(void)
{
    static const float places[] = {0.0f, 1e5f};
    static const float scales[] = {0x1p-10f, 1.0f, 0x1p10f};
    for (size_t pi = 0; pi < 2; pi++) {
        uint8_t *first = NULL;
        for (size_t si = 0; si < 3; si++) {
            arbor_mesh m;
            make_tilted_plane(&m, places[pi], scales[si]);
            arbor_accel *a = build(&m, ARBOR_ACCEL_BVH);
            arbor_render_params p;
            arbor_render_params_init(&p, &m, 160, 120);
            p.background = vec3(0.0f, 0.0f, 1.0f);
            arbor_frame *f = render_ok(pool4, a, &p);
            const arbor_frame_result *r = arbor_frame_result_of(f);
            int plane = 0, shadowed = 0;
            for (int i = 0; i < r->width * r->height; i++) {
                if (r->rgb[3 * i + 2] == 255 && r->rgb[3 * i] == 0)
                    continue; /* the background */
                plane++;
                shadowed += r->rgb[3 * i] < 150;
            }
            char what[64];
            snprintf(what, sizeof what, "at %g, scale %g", (double)places[pi], (double)scales[si]);
            TEST_ASSERT_TRUE_MESSAGE(plane > 5000, what);
            TEST_ASSERT_EQUAL_INT_MESSAGE(0, shadowed, what);
            if (first == NULL) {
                first = malloc((size_t)r->width * r->height * 3);
                memcpy(first, r->rgb, (size_t)r->width * r->height * 3);
            } else {
                TEST_ASSERT_EQUAL_MEMORY_MESSAGE(first, r->rgb, (size_t)r->width * r->height * 3, what);
            }
            arbor_frame_release(f);
            arbor_accel_free(a);
            arbor_mesh_free(&m);
        }
        free(first);
    }
}

/* A floor of 8 x 8 quads at height z0 and a 4 x 4 sheet 1e-3 above it (the
 * model's diagonal is about 28): rays straight up from points on the floor
 * are blocked exactly where the sheet is above them. The offset must stay
 * below the gap: PROTOCOL.md's 1e-4 d = 2.8e-3 starts every ray above the
 * sheet (all 436 points under it leak, at every scale); so does Waechter &
 * Binder's fixed 1/65536 fallback at scale 2^-10 (all 436, both floors). */
static void test_thin_gaps_do_not_leak(void)
{
    static const float heights[] = {0.0f, 5.0f};
    static const float scales[] = {0x1p-10f, 1.0f, 0x1p10f};
    for (size_t hi = 0; hi < 2; hi++)
        for (size_t si = 0; si < 3; si++) {
            float z0 = heights[hi], k = scales[si], gap = 1e-3f;
            arbor_mesh m;
            arbor_mesh_init(&m);
            for (int j = 0; j <= 8; j++)
                for (int i = 0; i <= 8; i++)
                    arbor_mesh_add_vert(&m, vec3_scale(vec3(-10.0f + 2.5f * (float)i, -10.0f + 2.5f * (float)j, z0), k),
                                        NULL);
            for (uint32_t j = 0; j < 8; j++)
                for (uint32_t i = 0; i < 8; i++) {
                    uint32_t v = j * 9 + i;
                    arbor_mesh_add_tri(&m, v, v + 1, v + 10, 0, NULL);
                    arbor_mesh_add_tri(&m, v, v + 10, v + 9, 0, NULL);
                }
            uint32_t s0 = m.nverts;
            arbor_mesh_add_vert(&m, vec3_scale(vec3(-2.0f, -2.0f, z0 + gap), k), NULL);
            arbor_mesh_add_vert(&m, vec3_scale(vec3(2.0f, -2.0f, z0 + gap), k), NULL);
            arbor_mesh_add_vert(&m, vec3_scale(vec3(2.0f, 2.0f, z0 + gap), k), NULL);
            arbor_mesh_add_vert(&m, vec3_scale(vec3(-2.0f, 2.0f, z0 + gap), k), NULL);
            arbor_mesh_add_tri(&m, s0, s0 + 1, s0 + 2, 0, NULL);
            arbor_mesh_add_tri(&m, s0, s0 + 2, s0 + 3, 0, NULL);
            TEST_ASSERT_TRUE(arbor_mesh_finish(&m, NULL));
            arbor_accel *a = build(&m, ARBOR_ACCEL_BVH);
            sample_offset_scale scale = sample_offset_scale_of(&m);
            test_rng g;
            test_rng_seed(&g, 3);
            int under = 0, wrong = 0;
            for (uint32_t t = 0; t < 128; t++)
                for (int n = 0; n < 100; n++) {
                    float u = test_rng_float(&g), v = test_rng_float(&g) * (1.0f - u);
                    arbor_hit h = {1.0f, u, v, t};
                    arbor_vec3 normal;
                    arbor_vec3 p = sample_hit_point(&m, &h, &normal);
                    float x = p.x / k, y = p.y / k;
                    if (fabsf(fabsf(x) - 2.0f) < 1e-3f || fabsf(fabsf(y) - 2.0f) < 1e-3f)
                        continue; /* on the sheet's outline: either answer is right */
                    bool below = fabsf(x) < 2.0f && fabsf(y) < 2.0f;
                    arbor_ray up = {sample_offset_ray(p, vec3(0.0f, 0.0f, 1.0f), &scale), 0.0f, vec3(0.0f, 0.0f, 1.0f),
                                    INFINITY};
                    under += below;
                    wrong += arbor_accel_occluded(a, &up) != below;
                }
            char what[64];
            snprintf(what, sizeof what, "floor at %g, scale %g", (double)z0, (double)k);
            TEST_ASSERT_TRUE_MESSAGE(under > 300, what);
            TEST_ASSERT_EQUAL_INT_MESSAGE(0, wrong, what);
            arbor_accel_free(a);
            arbor_mesh_free(&m);
        }
}

/* ---- glass ---- */

/* An axis-aligned box as 12 triangles wound counter-clockwise seen from
 * outside, so that (b - a) x (c - a) points out. */
static void add_box(arbor_mesh *m, arbor_vec3 lo, arbor_vec3 hi, uint32_t mat)
{
    uint32_t v0 = m->nverts;
    for (int i = 0; i < 8; i++)
        arbor_mesh_add_vert(m, vec3(i & 1 ? hi.x : lo.x, i & 2 ? hi.y : lo.y, i & 4 ? hi.z : lo.z), NULL);
    static const uint32_t quads[6][4] = {{0, 4, 6, 2}, {1, 3, 7, 5}, {0, 1, 5, 4},
                                         {2, 6, 7, 3}, {0, 2, 3, 1}, {4, 5, 7, 6}};
    for (int q = 0; q < 6; q++) {
        arbor_mesh_add_tri(m, v0 + quads[q][0], v0 + quads[q][1], v0 + quads[q][2], mat, NULL);
        arbor_mesh_add_tri(m, v0 + quads[q][0], v0 + quads[q][2], v0 + quads[q][3], mat, NULL);
    }
}

/* The exact Fresnel reflectance of unpolarised light going from air into
 * index n at cos_i, in double. */
static double fresnel_from_air(double cos_i, double n)
{
    double sin_t = sqrt(1.0 - cos_i * cos_i) / n, cos_t = sqrt(1.0 - sin_t * sin_t);
    double rs = (cos_i - n * cos_t) / (cos_i + n * cos_t);
    double rp = (n * cos_i - cos_t) / (n * cos_i + cos_t);
    return 0.5 * (rs * rs + rp * rp);
}

#define PANE_FRONT 1.0f
#define PANE_BACK (-2.0f)
#define PANE_INDEX 1.5f
#define WALL_Z (-4.0f)
#define WALL_EDGE 6.0f
#define WALL_KD 0.8f

/* A pane (a box 3 thick, index 1.5, opacity d, black Kd) between the eye at
 * z = 5 and a wall at z = -4 whose diffuse Kd is red left of x = 6 and green
 * right of it. */
static void make_pane_scene(arbor_mesh *m, float d)
{
    arbor_mesh_init(m);
    uint32_t fallback, glass, red, green;
    arbor_mesh_add_material(m, "default", &fallback, NULL);
    arbor_mesh_add_material(m, "glass", &glass, NULL);
    arbor_mesh_add_material(m, "red", &red, NULL);
    arbor_mesh_add_material(m, "green", &green, NULL);
    m->mats[glass].kd = vec3(0.0f, 0.0f, 0.0f);
    m->mats[glass].d = d;
    m->mats[glass].ni = PANE_INDEX;
    m->mats[red].kd = vec3(WALL_KD, 0.0f, 0.0f);
    m->mats[green].kd = vec3(0.0f, WALL_KD, 0.0f);
    add_box(m, vec3(-40.0f, -40.0f, PANE_BACK), vec3(40.0f, 40.0f, PANE_FRONT), glass);
    uint32_t v = m->nverts;
    float xs[3] = {-40.0f, WALL_EDGE, 40.0f};
    for (int i = 0; i < 3; i++) {
        arbor_mesh_add_vert(m, vec3(xs[i], -40.0f, WALL_Z), NULL);
        arbor_mesh_add_vert(m, vec3(xs[i], 40.0f, WALL_Z), NULL);
    }
    arbor_mesh_add_tri(m, v, v + 2, v + 3, red, NULL);
    arbor_mesh_add_tri(m, v, v + 3, v + 1, red, NULL);
    arbor_mesh_add_tri(m, v + 2, v + 4, v + 5, green, NULL);
    arbor_mesh_add_tri(m, v + 2, v + 5, v + 3, green, NULL);
    TEST_ASSERT_TRUE(arbor_mesh_finish(m, NULL));
}

/* Each pixel's ray through the pane, in closed form: it leaves the pane
 * parallel to itself, displaced sideways by t sin(theta) (1 - cos(theta) /
 * sqrt(n^2 - sin^2(theta))), so on the wall it lands that over cos(theta)
 * closer to the foot of the normal than the straight ray would. Its light is
 * the wall's Lambert term under a shadow ray that crosses the pane's two
 * faces, times the view's two crossings: each passes (1 - d)(1 - R) with R
 * the Fresnel reflectance at that angle. With 2 bounces nothing else
 * reaches the eye (the background is black, the pane's Kd too). The pixels
 * where the straight ray would land on the other colour show that the
 * refraction is not skipped. */
static void test_glass_pane_displaces_and_dims_as_in_closed_form(void)
{
    static const float opacities[] = {0.0f, 0.25f};
    for (int oi = 0; oi < 2; oi++) {
        float d = opacities[oi];
        arbor_mesh m;
        make_pane_scene(&m, d);
        arbor_accel *a = build(&m, ARBOR_ACCEL_BVH);
        arbor_render_params p;
        arbor_render_params_init(&p, &m, 160, 120);
        arbor_camera_look_at(&p.camera, vec3(0, 0, 5), vec3(0, 0, 0), vec3(0, 1, 0), 90.0f, 160, 120);
        p.background = vec3(0.0f, 0.0f, 0.0f);
        p.max_bounces = 2;
        arbor_frame *f = render_ok(pool4, a, &p);
        const arbor_frame_result *r = arbor_frame_result_of(f);
        double diag = vec3_length(aabb_extent(m.bounds));
        arbor_vec3 light = vec3_add(p.camera.eye, vec3_scale(p.camera.up, 0.5f * (float)diag));
        double t = PANE_FRONT - PANE_BACK, n = PANE_INDEX;
        int checked = 0, moved = 0;
        for (int y = 0; y < r->height; y++)
            for (int x = 0; x < r->width; x++) {
                arbor_ray ray = arbor_camera_ray(&p.camera, (float)x + 0.5f, (float)y + 0.5f);
                double len = sqrt((double)ray.d.x * ray.d.x + (double)ray.d.y * ray.d.y + (double)ray.d.z * ray.d.z);
                double dx = ray.d.x / len, dy = ray.d.y / len, dz = ray.d.z / len;
                double cos_v = -dz, sin_v = sqrt(1.0 - cos_v * cos_v);
                double reach = (WALL_Z - ray.o.z) / dz;
                double straight_x = ray.o.x + dx * reach, straight_y = ray.o.y + dy * reach;
                double shift = t * sin_v * (1.0 - cos_v / sqrt(n * n - sin_v * sin_v)) / cos_v;
                double h = sqrt(dx * dx + dy * dy);
                double wx = straight_x - (h > 0.0 ? shift * dx / h : 0.0);
                double wy = straight_y - (h > 0.0 ? shift * dy / h : 0.0);
                if (fabs(wx - WALL_EDGE) < 1e-3)
                    continue;
                moved += (wx < WALL_EDGE) != (straight_x < WALL_EDGE);
                double lx = light.x - wx, ly = light.y - wy, lz = light.z - WALL_Z;
                double cos_l = lz / sqrt(lx * lx + ly * ly + lz * lz);
                double pass_v = (1.0 - d) * (1.0 - fresnel_from_air(cos_v, n));
                double pass_l = (1.0 - d) * (1.0 - fresnel_from_air(cos_l, n));
                double value = pass_v * pass_v * WALL_KD * (0.15 + 0.85 * cos_l * pass_l * pass_l);
                const uint8_t *px = r->rgb + 3 * (y * r->width + x);
                int lit = wx < WALL_EDGE ? 0 : 1;
                TEST_ASSERT_INT_WITHIN(1, shaded_byte(value), px[lit]);
                TEST_ASSERT_EQUAL_UINT8(0, px[1 - lit]);
                TEST_ASSERT_EQUAL_UINT8(0, px[2]);
                checked++;
            }
        TEST_ASSERT_TRUE(checked > 19000);
        TEST_ASSERT_TRUE(moved > 500); /* 878 */
        arbor_frame_release(f);
        arbor_accel_free(a);
        arbor_mesh_free(&m);
    }
}

/* Seen from inside the pane (the eye at z = -1, looking at its back face
 * 1 below), rays meeting the face beyond the critical angle, sin = 1 / n,
 * are reflected whole: with 1 bounce their reflection ends on the pane's
 * front face (black Kd), so those pixels are black, and every other one sees
 * the wall through the face. */
static void test_glass_total_internal_reflection(void)
{
    arbor_mesh m;
    make_pane_scene(&m, 0.0f);
    arbor_accel *a = build(&m, ARBOR_ACCEL_BVH);
    arbor_render_params p;
    arbor_render_params_init(&p, &m, 160, 120);
    arbor_camera_look_at(&p.camera, vec3(0, 0, -1), vec3(0, 0, -2), vec3(0, 1, 0), 90.0f, 160, 120);
    p.background = vec3(0.0f, 0.0f, 0.0f);
    p.max_bounces = 1;
    arbor_frame *f = render_ok(pool4, a, &p);
    const arbor_frame_result *r = arbor_frame_result_of(f);
    double critical = asin(1.0 / PANE_INDEX);
    int reflected = 0, through = 0;
    for (int y = 0; y < r->height; y++)
        for (int x = 0; x < r->width; x++) {
            arbor_ray ray = arbor_camera_ray(&p.camera, (float)x + 0.5f, (float)y + 0.5f);
            double angle = acos(-ray.d.z / vec3_length(ray.d));
            if (fabs(angle - critical) < 1e-3)
                continue;
            const uint8_t *px = r->rgb + 3 * (y * r->width + x);
            bool black = px[0] == 0 && px[1] == 0 && px[2] == 0;
            TEST_ASSERT_EQUAL_INT(angle > critical, black);
            reflected += black;
            through += !black;
        }
    TEST_ASSERT_TRUE(reflected > 1000);
    TEST_ASSERT_TRUE(through > 1000);
    arbor_frame_release(f);
    arbor_accel_free(a);
    arbor_mesh_free(&m);
}

static void load(const char *file, arbor_mesh *m)
{
    arbor_err e;
    TEST_ASSERT_TRUE_MESSAGE(arbor_load_model(test_shared_model(file), m, &e), e.msg);
}

/* Hits of the rays with each tree kind (sah): found[k][i], t[k][i]. */
static void trace_each_kind(const arbor_mesh *m, const arbor_ray *rays, size_t n, bool *found[], float *t[])
{
    for (int k = 0; k < ARBOR_ACCEL_KIND_COUNT; k++) {
        arbor_accel *a = build(m, (arbor_accel_kind)k);
        for (size_t i = 0; i < n; i++) {
            arbor_ray r = rays[i];
            arbor_hit h;
            found[k][i] = arbor_accel_intersect(a, &r, &h);
            t[k][i] = found[k][i] ? h.t : 0.0f;
        }
        arbor_accel_free(a);
    }
}

/* PROTOCOL.md's primary set on galleon: bvh sah and kd sah agree on all of
 * it (hit count exactly, sum of t to 1e-5, through arbor_trace_set), and
 * with brute force ray by ray on every 5th pixel in x and y (brute force on
 * all 786k rays would take most of a minute). */
static void test_protocol_primary_hits_agree_with_brute_force(void)
{
    arbor_mesh m;
    load("galleon.obj", &m);
    arbor_raysets sets;
    arbor_err e;
    TEST_ASSERT_TRUE(arbor_raysets_primary(&m, &sets, &e));
    TEST_ASSERT_EQUAL_UINT64((uint64_t)(1024 * 768), (uint64_t)(sets.nprimary));
    arbor_tally tally[ARBOR_ACCEL_KIND_COUNT];
    for (int k = 0; k < ARBOR_ACCEL_KIND_COUNT; k++) {
        arbor_accel *a = build(&m, (arbor_accel_kind)k);
        TEST_ASSERT_TRUE(arbor_trace_set(NULL, arbor_accel_kernel, a, sets.primary, sets.nprimary, false, 2, &tally[k], &e));
        arbor_accel_free(a);
    }
    TEST_ASSERT_TRUE(tally[0].hits > 100000);
    TEST_ASSERT_EQUAL_UINT64(tally[0].hits, tally[1].hits);
    TEST_ASSERT_TRUE(test_close((float)tally[0].tsum, (float)tally[1].tsum, 1e-5f));

    size_t n = 0;
    arbor_ray *rays = malloc(sets.nprimary * sizeof *rays);
    for (int y = 0; y < 768; y += 5)
        for (int x = 0; x < 1024; x += 5)
            rays[n++] = sets.primary[(size_t)y * 1024 + (size_t)x];
    arbor_hit *brute = malloc(n * sizeof *brute);
    bool *brute_found = malloc(n * sizeof *brute_found);
    arbor_brute_intersect_many(NULL, &m, rays, n, brute, brute_found, 2);
    bool *found[ARBOR_ACCEL_KIND_COUNT];
    float *t[ARBOR_ACCEL_KIND_COUNT];
    for (int k = 0; k < ARBOR_ACCEL_KIND_COUNT; k++) {
        found[k] = malloc(n * sizeof *found[k]);
        t[k] = malloc(n * sizeof *t[k]);
    }
    trace_each_kind(&m, rays, n, found, t);
    size_t hits = 0;
    for (size_t i = 0; i < n; i++) {
        hits += brute_found[i];
        for (int k = 0; k < ARBOR_ACCEL_KIND_COUNT; k++) {
            TEST_ASSERT_EQUAL_INT_MESSAGE(brute_found[i], found[k][i], arbor_accel_kind_name((arbor_accel_kind)k));
            if (brute_found[i]) {
                TEST_ASSERT_TRUE_MESSAGE(test_close(brute[i].t, t[k][i], 1e-6f),
                                         arbor_accel_kind_name((arbor_accel_kind)k));
            }
        }
    }
    TEST_ASSERT_TRUE(hits > 4000);
    for (int k = 0; k < ARBOR_ACCEL_KIND_COUNT; k++) {
        free(found[k]);
        free(t[k]);
    }
    free(brute);
    free(brute_found);
    free(rays);
    arbor_raysets_free(&sets);
    arbor_mesh_free(&m);
}

/* The secondary sets against their definition: one diffuse and one shadow
 * ray per primary hit, from p + 1e-4 d n; diffuse directions in n's
 * hemisphere and cosine-distributed (mean cos = 2/3); shadow rays end at
 * the light at t = 1. */
static void test_protocol_secondary_sets(void)
{
    arbor_mesh m;
    load("galleon.obj", &m);
    arbor_raysets sets;
    arbor_err e;
    TEST_ASSERT_TRUE(arbor_raysets_primary(&m, &sets, &e));
    arbor_accel *a = build(&m, ARBOR_ACCEL_BVH);
    arbor_hit *hits = malloc(sets.nprimary * sizeof *hits);
    bool *found = malloc(sets.nprimary * sizeof *found);
    TEST_ASSERT_TRUE(arbor_accel_trace_hits(NULL, a, sets.primary, sets.nprimary, 2, hits, found, &e));
    TEST_ASSERT_TRUE(arbor_raysets_secondary(&m, &sets, hits, found, 5, &e));
    size_t nhits = 0;
    for (size_t i = 0; i < sets.nprimary; i++)
        nhits += found[i];
    TEST_ASSERT_EQUAL_UINT64((uint64_t)(nhits), (uint64_t)(sets.ndiffuse));
    TEST_ASSERT_EQUAL_UINT64((uint64_t)(nhits), (uint64_t)(sets.nshadow));
    float d = vec3_length(aabb_extent(m.bounds));
    TEST_ASSERT_FLOAT_WITHIN(1e-5f * d, d, sets.size);
    double cos_sum = 0.0;
    size_t k = 0;
    for (size_t i = 0; i < sets.nprimary; i++) {
        if (!found[i])
            continue;
        const arbor_ray *pr = &sets.primary[i], *dr = &sets.diffuse[k], *sr = &sets.shadow[k];
        k++;
        arbor_vec3 p = vec3_add(pr->o, vec3_scale(pr->d, hits[i].t));
        arbor_vec3 n = vec3_normalize(arbor_mesh_tri_normal(&m, hits[i].tri));
        if (vec3_dot(n, pr->d) > 0.0f)
            n = vec3_scale(n, -1.0f);
        arbor_vec3 lift = vec3_sub(dr->o, p);
        TEST_ASSERT_FLOAT_WITHIN(1e-6f * d, 1e-4f * d, vec3_dot(lift, n));
        TEST_ASSERT_FLOAT_WITHIN(1e-4f, 1.0f, vec3_length(dr->d));
        float c = vec3_dot(dr->d, n);
        TEST_ASSERT_TRUE(c >= -1e-6f);
        cos_sum += c;
        TEST_ASSERT_EQUAL_FLOAT(1.0f, sr->tmax);
        arbor_vec3 end = vec3_add(sr->o, sr->d);
        TEST_ASSERT_FLOAT_WITHIN(1e-4f * d, 0.0f, vec3_length(vec3_sub(end, sets.light)));
    }
    TEST_ASSERT_FLOAT_WITHIN(0.01, 2.0 / 3.0, cos_sum / (double)nhits);
    free(hits);
    free(found);
    arbor_accel_free(a);
    arbor_raysets_free(&sets);
    arbor_mesh_free(&m);
}

/* A soup of random triangles, every fifth a mirror, every seventh glass and
 * every third red, so every code path of every mode is taken. */
static void make_soup(arbor_mesh *m)
{
    test_random_soup(m, 3000, 11);
    uint32_t mirror, red, glass;
    arbor_mesh_add_material(m, "mirror", &mirror, NULL);
    arbor_mesh_add_material(m, "red", &red, NULL);
    arbor_mesh_add_material(m, "glass", &glass, NULL);
    m->mats[mirror].illum = 3;
    m->mats[red].kd = vec3(0.9f, 0.1f, 0.1f);
    m->mats[glass].d = 0.2f;
    m->mats[glass].ni = 1.5f;
    for (uint32_t t = 0; t < m->ntris; t++)
        m->tri_mat[t] = t % 5 == 0 ? mirror : t % 7 == 0 ? glass : t % 3 == 0 ? red : 0;
}

static void soup_params(arbor_render_params *p, const arbor_mesh *m, arbor_render_mode mode, int spp)
{
    arbor_render_params_init(p, m, 150, 110); /* not a multiple of the tile size */
    p->mode = mode;
    p->spp = spp;
    p->seed = 99;
}

static void test_one_thread_and_four_threads_give_the_same_bytes(void)
{
    arbor_mesh m;
    make_soup(&m);
    arbor_accel *a = build(&m, ARBOR_ACCEL_BVH);
    for (int mode = 0; mode < ARBOR_MODE_COUNT; mode++) {
        const int spps[2] = {4, 3}; /* the grid and the Latin hypercube */
        for (int k = 0; k < 2; k++) {
            arbor_render_params p;
            soup_params(&p, &m, (arbor_render_mode)mode, spps[k]);
            arbor_frame *f1 = render_ok(pool1, a, &p), *f4 = render_ok(pool4, a, &p);
            const arbor_frame_result *r1 = arbor_frame_result_of(f1), *r4 = arbor_frame_result_of(f4);
            TEST_ASSERT_EQUAL_MEMORY_MESSAGE(r1->rgb, r4->rgb, 150 * 110 * 3, arbor_render_mode_name(p.mode));
            TEST_ASSERT_EQUAL_UINT64(r1->rays, r4->rays);
            TEST_ASSERT_EQUAL_DOUBLE(r1->heat_scale, r4->heat_scale);
            arbor_frame_release(f1);
            arbor_frame_release(f4);
        }
    }
    arbor_accel_free(a);
    arbor_mesh_free(&m);
}

/* A different seed moves the samples: the anti-aliased image changes. */
static void test_seed_changes_the_samples(void)
{
    arbor_mesh m;
    make_soup(&m);
    arbor_accel *a = build(&m, ARBOR_ACCEL_BVH);
    arbor_render_params p;
    soup_params(&p, &m, ARBOR_MODE_NORMALS, 4);
    arbor_frame *f1 = render_ok(pool4, a, &p);
    p.seed = 100;
    arbor_frame *f2 = render_ok(pool4, a, &p);
    TEST_ASSERT_TRUE(memcmp(arbor_frame_result_of(f1)->rgb, arbor_frame_result_of(f2)->rgb, 150 * 110 * 3) != 0);
    arbor_frame_release(f1);
    arbor_frame_release(f2);
    arbor_accel_free(a);
    arbor_mesh_free(&m);
}

static void test_heat_scale_and_counts(void)
{
    arbor_mesh m;
    make_soup(&m);
    arbor_accel *a = build(&m, ARBOR_ACCEL_BVH);
    arbor_render_params p;
    soup_params(&p, &m, ARBOR_MODE_HEAT, 1);
    arbor_frame *f = render_ok(pool4, a, &p);
    const arbor_frame_result *r = arbor_frame_result_of(f);
    TEST_ASSERT_TRUE(r->counted);
    TEST_ASSERT_TRUE(r->mean_nodes >= 1.0);
    TEST_ASSERT_TRUE(r->heat_mean > 0.0);
    TEST_ASSERT_TRUE(r->heat_scale > r->heat_mean);
    TEST_ASSERT_TRUE(r->heat_scale <= r->heat_max);
    /* the mean cost per pixel is the mean per primary ray at spp 1 */
    TEST_ASSERT_FLOAT_WITHIN(1e-3 * r->heat_mean, r->mean_nodes + r->mean_tris, r->heat_mean);
    /* the costs the colours came from: whole numbers at spp 1, with the frame's mean and max */
    const float *costs = arbor_frame_heat_costs(f);
    TEST_ASSERT_NOT_NULL(costs);
    double sum = 0.0, max = 0.0;
    for (int i = 0; i < r->width * r->height; i++) {
        TEST_ASSERT_EQUAL_FLOAT(floorf(costs[i]), costs[i]);
        sum += costs[i];
        max = fmax(max, costs[i]);
    }
    TEST_ASSERT_FLOAT_WITHIN(1e-9 * r->heat_mean, r->heat_mean, sum / (r->width * r->height));
    TEST_ASSERT_EQUAL_DOUBLE(r->heat_max, max);
    arbor_frame_release(f);
    soup_params(&p, &m, ARBOR_MODE_SHADED, 1);
    f = render_ok(pool4, a, &p);
    TEST_ASSERT_NULL(arbor_frame_heat_costs(f));
    arbor_frame_release(f);
    arbor_accel_free(a);
    arbor_mesh_free(&m);
}

typedef struct {
    atomic_int calls;
    atomic_bool cancelled;
} done_record;

static void record_done(arbor_frame *f, void *user)
{
    done_record *d = user;
    atomic_store(&d->cancelled, arbor_frame_result_of(f)->cancelled);
    atomic_fetch_add(&d->calls, 1);
}

/* Frames of every mode submitted together on a 2-thread pool: each
 * completes, calls back once, and equals the same frame rendered alone. */
static void test_frames_in_flight_together(void)
{
    arbor_mesh m;
    make_soup(&m);
    arbor_accel *a = build(&m, ARBOR_ACCEL_BVH);
    arbor_err e;
    arbor_pool *pool2 = arbor_pool_create(2, &e);
    arbor_frame *frames[ARBOR_MODE_COUNT];
    done_record records[ARBOR_MODE_COUNT];
    memset(records, 0, sizeof records);
    for (int mode = 0; mode < ARBOR_MODE_COUNT; mode++) {
        arbor_render_params p;
        soup_params(&p, &m, (arbor_render_mode)mode, 2);
        frames[mode] = arbor_render_submit(pool2, a, &p, record_done, &records[mode], &e);
        TEST_ASSERT_NOT_NULL_MESSAGE(frames[mode], e.msg);
    }
    for (int mode = 0; mode < ARBOR_MODE_COUNT; mode++) {
        const arbor_frame_result *r = arbor_frame_wait(frames[mode]);
        TEST_ASSERT_EQUAL_INT(1, atomic_load(&records[mode].calls));
        TEST_ASSERT_FALSE(atomic_load(&records[mode].cancelled));
        arbor_render_params p;
        soup_params(&p, &m, (arbor_render_mode)mode, 2);
        arbor_frame *alone = render_ok(pool1, a, &p);
        TEST_ASSERT_EQUAL_MEMORY(arbor_frame_result_of(alone)->rgb, r->rgb, 150 * 110 * 3);
        arbor_frame_release(alone);
        arbor_frame_release(frames[mode]);
    }
    arbor_pool_destroy(pool2);
    arbor_accel_free(a);
    arbor_mesh_free(&m);
}

static void test_every_mode_round_trips_through_png(void)
{
    arbor_mesh m;
    make_soup(&m);
    arbor_accel *a = build(&m, ARBOR_ACCEL_BVH);
    for (int mode = 0; mode < ARBOR_MODE_COUNT; mode++) {
        arbor_render_params p;
        soup_params(&p, &m, (arbor_render_mode)mode, 1);
        arbor_frame *f = render_ok(pool4, a, &p);
        const arbor_frame_result *r = arbor_frame_result_of(f);
        uint8_t *png;
        size_t len;
        arbor_err e;
        TEST_ASSERT_TRUE(arbor_png_encode(r->rgb, r->width, r->height, &png, &len, &e));
        png_image img;
        memset(&img, 0, sizeof img);
        img.version = PNG_IMAGE_VERSION;
        TEST_ASSERT_TRUE(png_image_begin_read_from_memory(&img, png, len));
        TEST_ASSERT_EQUAL_UINT32(150, img.width);
        TEST_ASSERT_EQUAL_UINT32(110, img.height);
        img.format = PNG_FORMAT_RGB;
        uint8_t *back = malloc(PNG_IMAGE_SIZE(img));
        TEST_ASSERT_TRUE(png_image_finish_read(&img, NULL, back, 0, NULL));
        TEST_ASSERT_EQUAL_MEMORY_MESSAGE(r->rgb, back, 150 * 110 * 3, arbor_render_mode_name(p.mode));
        free(back);
        free(png);
        arbor_frame_release(f);
    }
    arbor_accel_free(a);
    arbor_mesh_free(&m);
}

/* A 2048 x 2048 AO frame at 64 spp would take minutes on one thread;
 * cancelled at once it stops after at most the tile that was running. */
static void test_cancel_stops_a_big_frame_early(void)
{
    arbor_mesh m;
    make_soup(&m);
    arbor_accel *a = build(&m, ARBOR_ACCEL_BVH);
    arbor_render_params p;
    arbor_render_params_init(&p, &m, 2048, 2048);
    p.mode = ARBOR_MODE_AO;
    p.spp = 64;
    done_record rec;
    memset(&rec, 0, sizeof rec);
    arbor_err e;
    arbor_frame *f = arbor_render_submit(pool1, a, &p, record_done, &rec, &e);
    TEST_ASSERT_NOT_NULL(f);
    arbor_frame_cancel(f);
    const arbor_frame_result *r = arbor_frame_wait(f);
    TEST_ASSERT_TRUE(r->cancelled);
    TEST_ASSERT_TRUE(atomic_load(&rec.cancelled));
    TEST_ASSERT_EQUAL_INT(1, atomic_load(&rec.calls));
    /* at most one 32 x 32 tile's primary rays (plus its AO rays) were traced */
    TEST_ASSERT_TRUE(r->rays <= (uint64_t)32 * 32 * 64 * (1 + 8));
    arbor_frame_release(f);
    arbor_accel_free(a);
    arbor_mesh_free(&m);
}

static void assert_rejected(arbor_render_params *p, const char *word)
{
    arbor_err e;
    arbor_err_clear(&e);
    TEST_ASSERT_FALSE(arbor_render_params_validate(p, &e));
    TEST_ASSERT_EQUAL_INT(ARBOR_ERR_INVALID, e.status);
    TEST_ASSERT_NOT_NULL_MESSAGE(strstr(e.msg, word), e.msg);
}

static void test_bad_parameters_are_rejected(void)
{
    arbor_mesh m;
    make_quad(&m, 0);
    arbor_accel *a = build(&m, ARBOR_ACCEL_BVH);
    arbor_render_params p, good;
    quad_params(&good, &m, ARBOR_MODE_SHADED);
    arbor_err e;
    TEST_ASSERT_TRUE(arbor_render_params_validate(&good, &e));
    p = good, p.spp = 0, assert_rejected(&p, "spp");
    p = good, p.spp = 65, assert_rejected(&p, "spp");
    p = good, p.camera.width = 0, assert_rejected(&p, "width");
    p = good, p.camera.height = 8193, assert_rejected(&p, "height");
    p = good, p.mode = ARBOR_MODE_COUNT, assert_rejected(&p, "mode");
    p = good, p.ao_samples = 0, assert_rejected(&p, "ao samples");
    p = good, p.max_bounces = -1, assert_rejected(&p, "bounces");
    p = good, p.background.x = 2.0f, assert_rejected(&p, "background");
    arbor_render_mode mode;
    TEST_ASSERT_FALSE(arbor_render_mode_parse("phong", &mode));
    TEST_ASSERT_TRUE(arbor_render_mode_parse("heat", &mode));
    TEST_ASSERT_EQUAL_INT(ARBOR_MODE_HEAT, mode);
    /* submit checks too, and starts nothing */
    p = good, p.spp = 65;
    TEST_ASSERT_NULL(arbor_render_submit(pool1, a, &p, NULL, NULL, &e));
    TEST_ASSERT_NOT_NULL(strstr(e.msg, "spp"));
    arbor_accel_free(a);
    arbor_mesh_free(&m);
}

/* ---- regions ---- */

/* Regions of the 150 x 110 soup frame: the whole of it, its corners,
 * rectangles touching each edge, and ones off the 32-pixel tile grid. */
static const arbor_region soup_regions[] = {
    {0, 0, 150, 110}, {0, 0, 1, 1},   {149, 109, 1, 1}, {118, 78, 32, 32}, {7, 5, 45, 33},
    {0, 40, 150, 3},  {32, 32, 64, 64}, {100, 0, 50, 110}, {149, 0, 1, 110}, {33, 71, 31, 39},
};

/* part is, byte for byte, the rectangle g of whole. */
static void assert_crop(const arbor_frame_result *whole, const arbor_frame_result *part, arbor_region g,
                        const char *what)
{
    TEST_ASSERT_EQUAL_INT_MESSAGE(g.w, part->width, what);
    TEST_ASSERT_EQUAL_INT_MESSAGE(g.h, part->height, what);
    for (int row = 0; row < g.h; row++) {
        const uint8_t *want = whole->rgb + 3 * ((size_t)(g.y + row) * (size_t)whole->width + (size_t)g.x);
        TEST_ASSERT_EQUAL_MEMORY_MESSAGE(want, part->rgb + 3 * (size_t)row * (size_t)g.w, 3 * (size_t)g.w, what);
    }
}

/* Renders region g of the frame p (p's own region is ignored) and checks it
 * against `whole`, the frame rendered entire. */
static void check_region(const arbor_accel *a, const arbor_render_params *p, const arbor_frame_result *whole,
                         arbor_region g)
{
    char what[96];
    snprintf(what, sizeof what, "%s spp %d region %d,%d %dx%d", arbor_render_mode_name(p->mode), p->spp, g.x, g.y,
             g.w, g.h);
    arbor_render_params q = *p;
    q.region = g;
    arbor_frame *f = render_ok(pool4, a, &q);
    const arbor_frame_result *r = arbor_frame_result_of(f);
    assert_crop(whole, r, g, what);
    if (p->mode == ARBOR_MODE_NORMALS) { /* one primary ray per sample, nothing else */
        TEST_ASSERT_EQUAL_UINT64_MESSAGE((uint64_t)g.w * (uint64_t)g.h * (uint64_t)p->spp, r->rays, what);
    }
    if (p->mode == ARBOR_MODE_HEAT) {
        TEST_ASSERT_EQUAL_DOUBLE_MESSAGE(whole->heat_scale, r->heat_scale, what);
    }
    arbor_frame_release(f);
}

static void check_every_region(const arbor_accel *a, const arbor_render_params *p, const arbor_frame_result *whole)
{
    for (size_t i = 0; i < sizeof soup_regions / sizeof soup_regions[0]; i++)
        check_region(a, p, whole, soup_regions[i]);
}

/* Every mode but heat, at spp 1, 4 (the grid) and 3 (the Latin hypercube):
 * a region's pixels are the whole frame's there. */
static void test_regions_are_crops_of_the_whole_frame(void)
{
    arbor_mesh m;
    make_soup(&m);
    arbor_accel *a = build(&m, ARBOR_ACCEL_BVH);
    const int spps[3] = {1, 4, 3};
    for (int mode = 0; mode < ARBOR_MODE_COUNT; mode++) {
        if (mode == ARBOR_MODE_HEAT)
            continue;
        for (int k = 0; k < 3; k++) {
            arbor_render_params p;
            soup_params(&p, &m, (arbor_render_mode)mode, spps[k]);
            arbor_frame *whole = render_ok(pool4, a, &p);
            check_every_region(a, &p, arbor_frame_result_of(whole));
            arbor_frame_release(whole);
        }
    }
    arbor_accel_free(a);
    arbor_mesh_free(&m);
}

/* Heat colours depend on the scale: given the whole frame's heat_scale, a
 * region is its crop; the whole frame given its own scale is unchanged. */
static void test_heat_regions_with_the_whole_frames_scale(void)
{
    arbor_mesh m;
    make_soup(&m);
    arbor_accel *a = build(&m, ARBOR_ACCEL_KD);
    const int spps[2] = {1, 4};
    for (int k = 0; k < 2; k++) {
        arbor_render_params p;
        soup_params(&p, &m, ARBOR_MODE_HEAT, spps[k]);
        arbor_frame *whole = render_ok(pool4, a, &p);
        const arbor_frame_result *w = arbor_frame_result_of(whole);
        TEST_ASSERT_TRUE(w->heat_scale > 0.0 && w->heat_scale < w->heat_max);
        p.heat_scale = w->heat_scale;
        arbor_frame *again = render_ok(pool4, a, &p);
        TEST_ASSERT_EQUAL_MEMORY(w->rgb, arbor_frame_result_of(again)->rgb, 150 * 110 * 3);
        arbor_frame_release(again);
        check_every_region(a, &p, w);
        arbor_frame_release(whole);
    }
    arbor_accel_free(a);
    arbor_mesh_free(&m);
}

static void test_bad_regions_are_rejected(void)
{
    arbor_mesh m;
    make_quad(&m, 0);
    arbor_render_params good, p;
    quad_params(&good, &m, ARBOR_MODE_NORMALS); /* 64 x 48 */
    arbor_err e;
    const arbor_region fine[] = {{0, 0, 0, 0}, {0, 0, 64, 48}, {63, 47, 1, 1}, {32, 0, 32, 48}, {5, 7, 11, 13}};
    for (size_t i = 0; i < sizeof fine / sizeof fine[0]; i++) {
        p = good, p.region = fine[i];
        TEST_ASSERT_TRUE_MESSAGE(arbor_render_params_validate(&p, &e), e.msg);
    }
    const arbor_region bad[] = {
        {-1, 0, 8, 8},  {0, -1, 8, 8}, {0, 0, 0, 8},  {0, 0, 8, 0},   {0, 0, -8, 8},  {0, 0, 8, -8},
        {57, 0, 8, 8},  {0, 41, 8, 8}, {64, 0, 1, 1}, {0, 48, 1, 1},  {0, 0, 65, 48}, {0, 0, 64, 49},
        {5, 5, 0, 0},   {0, 0, 8192, 8192},
    };
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        p = good, p.region = bad[i];
        assert_rejected(&p, "region");
    }
    /* submit checks too */
    arbor_accel *a = build(&m, ARBOR_ACCEL_BVH);
    p = good, p.region = bad[6];
    TEST_ASSERT_NULL(arbor_render_submit(pool1, a, &p, NULL, NULL, &e));
    TEST_ASSERT_NOT_NULL_MESSAGE(strstr(e.msg, "region"), e.msg);
    p = good, p.heat_scale = -1.0;
    assert_rejected(&p, "heat_scale");
    p = good, p.heat_scale = NAN;
    assert_rejected(&p, "heat_scale");
    arbor_accel_free(a);
    arbor_mesh_free(&m);
}

int main(void)
{
    arbor_err e;
    pool1 = arbor_pool_create(1, &e);
    pool4 = arbor_pool_create(4, &e);
    UNITY_BEGIN();
    RUN_TEST(test_quad_normals_fill_the_view);
    RUN_TEST(test_quad_shaded_centre_is_lambert);
    RUN_TEST(test_camera_around_a_point_is_refused);
    RUN_TEST(test_ks_is_a_highlight_under_illum_2);
    RUN_TEST(test_mirror_reflects_the_background);
    RUN_TEST(test_ao_of_an_open_plane_is_white);
    RUN_TEST(test_offset_origin_leaves_the_plane);
    RUN_TEST(test_no_self_shadowing_far_away_or_at_any_scale);
    RUN_TEST(test_thin_gaps_do_not_leak);
    RUN_TEST(test_glass_pane_displaces_and_dims_as_in_closed_form);
    RUN_TEST(test_glass_total_internal_reflection);
    RUN_TEST(test_protocol_primary_hits_agree_with_brute_force);
    RUN_TEST(test_protocol_secondary_sets);
    RUN_TEST(test_one_thread_and_four_threads_give_the_same_bytes);
    RUN_TEST(test_seed_changes_the_samples);
    RUN_TEST(test_heat_scale_and_counts);
    RUN_TEST(test_frames_in_flight_together);
    RUN_TEST(test_every_mode_round_trips_through_png);
    RUN_TEST(test_cancel_stops_a_big_frame_early);
    RUN_TEST(test_bad_parameters_are_rejected);
    RUN_TEST(test_regions_are_crops_of_the_whole_frame);
    RUN_TEST(test_heat_regions_with_the_whole_frames_scale);
    RUN_TEST(test_bad_regions_are_rejected);
    int failures = UNITY_END();
    arbor_pool_destroy(pool1);
    arbor_pool_destroy(pool4);
    return failures;
}
