/*
 * test_exact.c - exact at every scale, and one rule for ties (issue 12,
 * item 5).
 *
 * Scale: bunny and dragon, as loaded and with every vertex multiplied by
 * 1/1024 and by 1024 (arbor_bench_scale_mesh; a power of two, so no
 * coordinate rounds). The rays are the benchmark's own (raysets.h): a
 * sample of PROTOCOL.md's primary rays over the model, and the diffuse and
 * shadow rays the protocol makes from their hits, offset by 1e-4 of the
 * model's diagonal. That offset is relative, so at any scale the sets are
 * the unscaled rays times the scale, bit for bit, and brute force's answers
 * are the same triangles at the same distances times the scale: the test
 * checks every ray of that and brute force on the scaled model (every ray
 * on bunny, an eighth on dragon). Then every kind x builder, built over the
 * scaled model, must find exactly brute force's closest hit (the same
 * triangle, the same t to the bit) and agree on any-hit, also to the ulp:
 * nothing occludes a ray cut at its closest hit, the hit occludes a ray cut
 * one float beyond it.
 *
 * Ties: grids in which several triangles are hit at exactly the same t
 * (each triangle listed again with the same corners, with copies of them,
 * with its corners rotated, and wound the other way; rays also aimed
 * exactly through vertices and edges). Brute force must return the lowest
 * triangle index among the nearest, checked against an enumeration of
 * every triangle, and so must every tree, and any-hit must agree to the
 * ulp there too.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "arbor/accel.h"
#include "arbor/bench.h"
#include "arbor/brute.h"
#include "arbor/camera.h"
#include "arbor/load.h"
#include "arbor/raysets.h"
#include "support.h"
#include "unity.h"

#define SECONDARY_SEED 12u

void setUp(void) {}
void tearDown(void) {}

/* ---- rays and their brute-force answers ---- */

static void *xmalloc(size_t size)
{
    void *p = malloc(size ? size : 1);
    TEST_ASSERT_NOT_NULL_MESSAGE(p, "out of memory");
    return p;
}

/* ---- the sample of the protocol's rays ---- */

/* The pixel rectangle the model's bounds project to in the protocol view
 * (clamped to the image), so that most sampled rays hit the model. */
static void model_pixels(const arbor_mesh *m, int *x0, int *y0, int *x1, int *y1)
{
    arbor_camera cam;
    arbor_camera_protocol(&cam, m->bounds, ARBOR_PROTOCOL_WIDTH, ARBOR_PROTOCOL_HEIGHT);
    float aspect = (float)ARBOR_PROTOCOL_WIDTH / (float)ARBOR_PROTOCOL_HEIGHT;
    float lo[2] = {INFINITY, INFINITY}, hi[2] = {-INFINITY, -INFINITY};
    for (int c = 0; c < 8; c++) {
        arbor_vec3 p = vec3(c & 1 ? m->bounds.hi.x : m->bounds.lo.x, c & 2 ? m->bounds.hi.y : m->bounds.lo.y,
                            c & 4 ? m->bounds.hi.z : m->bounds.lo.z);
        arbor_vec3 v = vec3_sub(p, cam.eye);
        float z = vec3_dot(v, cam.forward);
        float sx = vec3_dot(v, cam.right) / z / (cam.tan_half_fov * aspect);
        float sy = vec3_dot(v, cam.up) / z / cam.tan_half_fov;
        float px = 0.5f * (sx + 1.0f) * ARBOR_PROTOCOL_WIDTH, py = 0.5f * (1.0f - sy) * ARBOR_PROTOCOL_HEIGHT;
        lo[0] = fminf(lo[0], px), hi[0] = fmaxf(hi[0], px);
        lo[1] = fminf(lo[1], py), hi[1] = fmaxf(hi[1], py);
    }
    *x0 = (int)fmaxf(0.0f, lo[0]);
    *y0 = (int)fmaxf(0.0f, lo[1]);
    *x1 = (int)fminf(ARBOR_PROTOCOL_WIDTH - 1, hi[0]);
    *y1 = (int)fminf(ARBOR_PROTOCOL_HEIGHT - 1, hi[1]);
}

/* Indices (into the primary set, increasing) of an about `want`-pixel grid
 * over the model's rectangle; *n gets the count. The same pixels at every
 * scale: the protocol view of a scaled model looks the same way. */
static size_t *sample_pixels(const arbor_mesh *m, size_t want, size_t *n)
{
    int x0, y0, x1, y1;
    model_pixels(m, &x0, &y0, &x1, &y1);
    TEST_ASSERT_TRUE_MESSAGE(x1 > x0 && y1 > y0, "the model is not in view");
    double step = sqrt((double)(x1 - x0 + 1) * (double)(y1 - y0 + 1) / (double)want);
    if (step < 1.0)
        step = 1.0;
    size_t cap = (size_t)((x1 - x0) / step + 2) * (size_t)((y1 - y0) / step + 2);
    size_t *index = xmalloc(cap * sizeof *index);
    *n = 0;
    for (double y = y0; y <= y1; y += step)
        for (double x = x0; x <= x1; x += step)
            index[(*n)++] = (size_t)y * ARBOR_PROTOCOL_WIDTH + (size_t)x;
    return index;
}

/* The benchmark's rays for the sampled pixels, with brute force's answers:
 * primary and diffuse closest hits, shadow occlusion. */
typedef struct {
    test_truth primary, diffuse, shadow;
} scaled_truth;

/* The scaled model's rays, brute force's unscaled answers carried over.
 * The set at scale s is the unscaled set times s, bit for bit: origins
 * times s; primary and diffuse rays (t in (0, inf) along a unit direction)
 * keep their directions, and so their hits are the same triangles at t
 * times s; shadow rays (t in (0, 1) along the vector to the light) have
 * that vector times s and the same t. Takes ownership of rays. */
static void carry_over(test_truth *ts, arbor_ray *rays, size_t n, const test_truth *unscaled, float s, const char *what)
{
    char msg[256];
    TEST_ASSERT_EQUAL_UINT64_MESSAGE(unscaled->n, n, what);
    ts->rays = rays;
    ts->n = n;
    ts->hit = xmalloc(n * sizeof *ts->hit);
    ts->found = xmalloc(n * sizeof *ts->found);
    for (size_t i = 0; i < n; i++) {
        const arbor_ray *a = &unscaled->rays[i], *b = &rays[i];
        bool unit = isinf(a->tmax);
        arbor_vec3 d = unit ? a->d : vec3_scale(a->d, s);
        bool same_ray = b->o.x == a->o.x * s && b->o.y == a->o.y * s && b->o.z == a->o.z * s && b->d.x == d.x &&
                        b->d.y == d.y && b->d.z == d.z && b->tmin == a->tmin && b->tmax == a->tmax;
        snprintf(msg, sizeof msg, "%s ray %zu is not the unscaled ray times %g", what, i, (double)s);
        TEST_ASSERT_TRUE_MESSAGE(same_ray, msg);
        ts->found[i] = unscaled->found[i];
        ts->hit[i] = unscaled->hit[i];
        ts->hit[i].t = unit ? unscaled->hit[i].t * s : unscaled->hit[i].t;
    }
}

/* Brute force over the scaled model gives every `stride`-th ray of the set
 * exactly the answer carried over. */
static void brute_agrees(const arbor_mesh *m, const test_truth *ts, size_t stride, const char *what)
{
    size_t n = (ts->n + stride - 1) / stride;
    arbor_ray *rays = xmalloc(n * sizeof *rays);
    for (size_t i = 0; i < n; i++)
        rays[i] = ts->rays[i * stride];
    test_truth brute;
    test_truth_compute(&brute, m, rays, n);
    for (size_t i = 0; i < n; i++) {
        const arbor_hit *want = &ts->hit[i * stride], *got = &brute.hit[i];
        char msg[256];
        snprintf(msg, sizeof msg, "%s ray %zu: brute force %s tri %u t %.9g; unscaled times the scale %s tri %u t %.9g",
                 what, i * stride, brute.found[i] ? "hit" : "miss", got->tri, (double)got->t,
                 ts->found[i * stride] ? "hit" : "miss", want->tri, (double)want->t);
        TEST_ASSERT_TRUE_MESSAGE(brute.found[i] == ts->found[i * stride] &&
                                     (!brute.found[i] || (got->tri == want->tri && got->t == want->t)),
                                 msg);
    }
    test_truth_free(&brute);
}

/* The benchmark's rays for the sampled pixels of m and their answers. With
 * unscaled NULL (m as loaded) brute force answers every ray. Otherwise m
 * is the model scaled by s: the answers are carried over from `unscaled`,
 * and brute force checks every `stride`-th ray of each set. */
static void scaled_truth_compute(scaled_truth *st, const arbor_mesh *m, const size_t *pixels, size_t npixels,
                                 const scaled_truth *unscaled, float s, size_t stride)
{
    arbor_raysets sets;
    arbor_err e;
    char what[64];
    TEST_ASSERT_TRUE_MESSAGE(arbor_raysets_primary(m, &sets, &e), e.msg);
    arbor_ray *primary = xmalloc(npixels * sizeof *primary);
    for (size_t i = 0; i < npixels; i++)
        primary[i] = sets.primary[pixels[i]];
    snprintf(what, sizeof what, "x %g primary", (double)s);
    if (unscaled == NULL)
        test_truth_compute(&st->primary, m, primary, npixels);
    else
        carry_over(&st->primary, primary, npixels, &unscaled->primary, s, what);
    /* the secondary rays of the sampled pixels' hits, as the benchmark makes
     * them (the other pixels count as misses) */
    arbor_hit *hits = calloc(sets.nprimary, sizeof *hits);
    bool *found = calloc(sets.nprimary, sizeof *found);
    TEST_ASSERT_TRUE(hits != NULL && found != NULL);
    for (size_t i = 0; i < npixels; i++) {
        hits[pixels[i]] = st->primary.hit[i];
        found[pixels[i]] = st->primary.found[i];
    }
    TEST_ASSERT_TRUE_MESSAGE(arbor_raysets_secondary(m, &sets, hits, found, SECONDARY_SEED, &e), e.msg);
    free(hits);
    free(found);
    TEST_ASSERT_EQUAL_UINT64(test_truth_hits(&st->primary), sets.ndiffuse);
    if (unscaled == NULL) {
        test_truth_compute(&st->diffuse, m, sets.diffuse, sets.ndiffuse);
        test_truth_compute(&st->shadow, m, sets.shadow, sets.nshadow);
    } else {
        snprintf(what, sizeof what, "x %g diffuse", (double)s);
        carry_over(&st->diffuse, sets.diffuse, sets.ndiffuse, &unscaled->diffuse, s, what);
        snprintf(what, sizeof what, "x %g shadow", (double)s);
        carry_over(&st->shadow, sets.shadow, sets.nshadow, &unscaled->shadow, s, what);
    }
    sets.diffuse = sets.shadow = NULL; /* now the truth sets' */
    arbor_raysets_free(&sets);
    if (unscaled != NULL) {
        const test_truth *scaled_sets[] = {&st->primary, &st->diffuse, &st->shadow};
        const char *names[] = {"primary", "diffuse", "shadow"};
        for (int i = 0; i < 3; i++) {
            snprintf(what, sizeof what, "x %g %s", (double)s, names[i]);
            brute_agrees(m, scaled_sets[i], stride, what);
        }
    }
}

static void scaled_truth_free(scaled_truth *st)
{
    test_truth_free(&st->primary);
    test_truth_free(&st->diffuse);
    test_truth_free(&st->shadow);
}

/* ---- every tree against the truth ---- */

/* Mismatches of one tree, and the first described. */
typedef struct {
    size_t bad, closest; /* rays that differ, and of them those whose closest hit does */
    char first[400];
} mismatches;

/* What check_set asks of each ray. */
typedef enum {
    CHECK_CLOSEST, /* the closest hit, and any-hit with the ray's own tmax */
    CHECK_AT_TMAX  /* any-hit with tmax exactly at the closest hit and a float past it */
} check_kind;

/* CHECK_CLOSEST: the tree's closest hit is brute force's exactly (same
 * triangle, same t, tmax shrunk to it), and any-hit agrees with it.
 * CHECK_AT_TMAX: any-hit to the ulp: a ray cut at its closest hit is not
 * occluded (t is open at tmax), one cut a float beyond it is. */
static void check_set(const arbor_accel *tree, const char *set, const test_truth *ts, check_kind kind,
                      mismatches *mm)
{
    for (size_t i = 0; i < ts->n; i++) {
        const arbor_hit *want = &ts->hit[i];
        arbor_ray r = ts->rays[i];
        arbor_hit h = {0.0f, 0.0f, 0.0f, 0};
        bool found = false, ok;
        const char *query;
        if (kind == CHECK_CLOSEST) {
            query = "closest hit";
            found = arbor_accel_intersect(tree, &r, &h);
            ok = found == ts->found[i] && (!found || (h.tri == want->tri && h.t == want->t && r.tmax == h.t));
            mm->closest += !ok;
            if (ok) {
                query = "any hit";
                r = ts->rays[i];
                ok = arbor_accel_occluded(tree, &r) == ts->found[i];
            }
        } else {
            if (!ts->found[i])
                continue;
            query = "occluded with tmax at the hit";
            r.tmax = want->t;
            ok = !arbor_accel_occluded(tree, &r);
            if (ok) {
                query = "not occluded with tmax a float past the hit";
                r.tmax = nextafterf(want->t, INFINITY);
                ok = arbor_accel_occluded(tree, &r);
            }
        }
        if (!ok && mm->bad++ == 0)
            snprintf(mm->first, sizeof mm->first, "%s ray %zu (%s): tree %s tri %u t %.9g, brute force %s tri %u t %.9g",
                     set, i, query, found ? "hit" : "miss", h.tri, (double)h.t, ts->found[i] ? "hit" : "miss",
                     want->tri, (double)want->t);
    }
}

/* A tree of that kind and builder over m, which the validator accepts
 * when asked to check it. */
static arbor_accel *build_tree(const arbor_mesh *m, arbor_accel_kind kind, arbor_builder builder, bool validate,
                               const char *what)
{
    arbor_build_opts o;
    arbor_build_opts_init(&o, kind, builder);
    arbor_err e;
    char f[768];
    arbor_accel *tree = arbor_accel_build(m, &o, &e);
    snprintf(f, sizeof f, "%s: build failed: %s", what, tree ? "" : e.msg);
    TEST_ASSERT_NOT_NULL_MESSAGE(tree, f);
    bool valid = !validate || arbor_accel_validate(tree, &e);
    snprintf(f, sizeof f, "%s: invalid tree: %s", what, valid ? "" : e.msg);
    TEST_ASSERT_TRUE_MESSAGE(valid, f);
    return tree;
}

static void tree_name(char *what, size_t len, const char *model, float scale, int k, int b)
{
    snprintf(what, len, "%s x %g %s %s", model, (double)scale, arbor_accel_kind_name((arbor_accel_kind)k),
             arbor_builder_name((arbor_builder)b));
}

/* Fails naming every tree (of `trees`, built by each kind x builder) that
 * has mismatches, with the first of each. */
typedef struct {
    size_t failed;
    char msg[2048];
} tree_failures;

static void note_tree(tree_failures *tf, const char *what, const mismatches *mm, size_t n)
{
    if (mm->bad == 0)
        return;
    size_t used = strlen(tf->msg);
    if (used < sizeof tf->msg)
        snprintf(tf->msg + used, sizeof tf->msg - used, "%s%s: %zu of %zu rays differ (%zu in the closest hit), first: %s",
                 tf->failed ? "; " : "", what, mm->bad, n, mm->closest, mm->first);
    tf->failed++;
}

/* Which trees a scale of a model is traced by, and whether they are
 * validated. */
typedef struct {
    float scale;
    bool kd_simple; /* the kd spatial, median and mean trees too (slow to build on a big model) */
    bool validate;
} scale_plan;

static void check_trees_at_scale(const char *model, const scale_plan *plan, const arbor_mesh *m,
                                 const scaled_truth *st)
{
    tree_failures tf = {0, ""};
    for (int k = 0; k < ARBOR_ACCEL_KIND_COUNT; k++)
        for (int b = 0; b < ARBOR_BUILDER_COUNT; b++) {
            if (k == ARBOR_ACCEL_KD && b != ARBOR_BUILD_SAH && !plan->kd_simple)
                continue;
            char what[128];
            tree_name(what, sizeof what, model, plan->scale, k, b);
            arbor_accel *tree = build_tree(m, (arbor_accel_kind)k, (arbor_builder)b, plan->validate, what);
            mismatches mm = {0, 0, ""};
            const test_truth *sets[] = {&st->primary, &st->diffuse, &st->shadow};
            const char *names[] = {"primary", "diffuse", "shadow"};
            for (int i = 0; i < 3; i++) {
                check_set(tree, names[i], sets[i], CHECK_CLOSEST, &mm);
                check_set(tree, names[i], sets[i], CHECK_AT_TMAX, &mm);
            }
            arbor_accel_free(tree);
            note_tree(&tf, what, &mm, st->primary.n + st->diffuse.n + st->shadow.n);
        }
    TEST_ASSERT_EQUAL_UINT64_MESSAGE(0, tf.failed, tf.msg);
}

/* ---- scaled models ---- */

static void set_scale(arbor_mesh *m, const arbor_vec3 *verts, arbor_aabb bounds, float scale)
{
    memcpy(m->verts, verts, m->nverts * sizeof *verts);
    m->bounds = bounds;
    arbor_err e;
    TEST_ASSERT_TRUE_MESSAGE(arbor_bench_scale_mesh(m, scale, &e), e.msg);
}

/* The model's trees at each planned scale, on about `rays` sampled pixels:
 * brute force answers them as loaded, and every brute_stride-th ray of
 * each set scaled. */
static void check_model_at_scales(const char *file, size_t rays, size_t brute_stride, const scale_plan *plans,
                                  size_t nplans)
{
    arbor_mesh m;
    arbor_err e;
    TEST_ASSERT_TRUE_MESSAGE(arbor_load_model(test_shared_model(file), &m, &e), e.msg);
    arbor_vec3 *verts = xmalloc(m.nverts * sizeof *verts);
    memcpy(verts, m.verts, m.nverts * sizeof *verts);
    const arbor_aabb bounds = m.bounds;
    size_t npixels;
    size_t *pixels = sample_pixels(&m, rays, &npixels);

    scaled_truth unscaled;
    scaled_truth_compute(&unscaled, &m, pixels, npixels, NULL, 1.0f, 1);
    /* rays that mostly miss, or secondary rays never hitting, would prove little */
    TEST_ASSERT_TRUE_MESSAGE(test_truth_hits(&unscaled.primary) > npixels / 4, "too few sampled rays hit the model");
    TEST_ASSERT_TRUE_MESSAGE(test_truth_hits(&unscaled.diffuse) > 0, "no diffuse ray hit");
    TEST_ASSERT_TRUE_MESSAGE(test_truth_hits(&unscaled.shadow) > 0, "no shadow ray blocked");

    for (size_t i = 0; i < nplans; i++) {
        const scale_plan *plan = &plans[i];
        if (plan->scale == 1.0f) {
            check_trees_at_scale(file, plan, &m, &unscaled);
            continue;
        }
        set_scale(&m, verts, bounds, plan->scale);
        scaled_truth st;
        scaled_truth_compute(&st, &m, pixels, npixels, &unscaled, plan->scale, brute_stride);
        check_trees_at_scale(file, plan, &m, &st);
        scaled_truth_free(&st);
        set_scale(&m, verts, bounds, 1.0f);
    }
    scaled_truth_free(&unscaled);
    free(pixels);
    free(verts);
    arbor_mesh_free(&m);
}

/* Bunny: every tree at every scale, validated. */
static void test_bunny_at_every_scale(void)
{
    const scale_plan plans[] = {{1.0f, true, true}, {1.0f / 1024.0f, true, true}, {1024.0f, true, true}};
    check_model_at_scales("bunny.obj", 3000, 1, plans, sizeof plans / sizeof plans[0]);
}

/* Dragon (871k triangles): brute force (some 15 ns a triangle, 13 ms a
 * ray) and the kd simple builders (3 to 6 s each) are costly, so brute
 * force checks an eighth of the scaled rays, every tree is traced at
 * 1/1024 and the bvh trees and the kd sah tree at 1024, none validated
 * (test_accel and the kinds' own suites validate trees). */
static void test_dragon_at_every_scale(void)
{
    const scale_plan plans[] = {{1.0f / 1024.0f, true, false}, {1024.0f, false, false}};
    check_model_at_scales("dragon.obj.gz", 1200, 8, plans, sizeof plans / sizeof plans[0]);
}

/* Scaling is refused, the mesh untouched, unless exact. */
static void test_only_exact_scales_are_accepted(void)
{
    arbor_mesh m;
    arbor_err e;
    arbor_mesh_init(&m);
    TEST_ASSERT_TRUE(arbor_mesh_add_vert(&m, vec3(1.5f, -3.0f, 0.0f), &e));
    TEST_ASSERT_TRUE(arbor_mesh_add_vert(&m, vec3(1e-30f, 2.0f, 1e10f), &e));
    TEST_ASSERT_TRUE(arbor_mesh_add_vert(&m, vec3(0.0f, 1.0f, 0.0f), &e));
    TEST_ASSERT_TRUE(arbor_mesh_add_tri(&m, 0, 1, 2, 0, &e));
    TEST_ASSERT_TRUE(arbor_mesh_finish(&m, &e));
    const float refused[] = {3.0f, 0.75f, -2.0f, 0.0f, INFINITY, NAN, 0x1p-30f /* 1e-30 goes subnormal */,
                             0x1p100f /* 1e10 overflows */,
                             0x1p30f /* 1e19 across: beyond single-precision ray tests (ARBOR_SIZE_MAX) */};
    for (size_t i = 0; i < sizeof refused / sizeof refused[0]; i++) {
        TEST_ASSERT_FALSE(arbor_bench_scale_mesh(&m, refused[i], &e));
        TEST_ASSERT_EQUAL_INT(ARBOR_ERR_INVALID, e.status);
        TEST_ASSERT_EQUAL_FLOAT(1.5f, m.verts[0].x);
        TEST_ASSERT_EQUAL_FLOAT(1e10f, m.bounds.hi.z);
    }
    TEST_ASSERT_TRUE_MESSAGE(arbor_bench_scale_mesh(&m, 0x1p-8f, &e), e.msg);
    TEST_ASSERT_TRUE(m.verts[0].x == 1.5f / 256 && m.verts[1].x == 1e-30f / 256 && m.verts[1].z == 1e10f / 256);
    TEST_ASSERT_TRUE(m.bounds.lo.y == -3.0f / 256 && m.bounds.hi.z == 1e10f / 256);
    arbor_mesh_free(&m);
}

/* ---- ties ---- */

#define GRID 16
#define GRID_VERTS ((GRID + 1) * (GRID + 1))
#define VARIANTS 4

/* A GRID x GRID grid of quads over the unit square, two triangles each
 * (sharing the diagonal), on the plane z = 0 or tilted (z = x/4 + y/8:
 * every vertex and edge midpoint exact in float); each triangle listed
 * VARIANTS times, in a shuffled order: as it is, with its corners rotated,
 * on a second copy of the vertices, and wound the other way. */
static void tie_mesh(arbor_mesh *m, bool tilted, uint64_t seed)
{
    arbor_err e;
    arbor_mesh_init(m);
    for (int copy = 0; copy < 2; copy++)
        for (int j = 0; j <= GRID; j++)
            for (int i = 0; i <= GRID; i++) {
                float x = (float)i / GRID, y = (float)j / GRID;
                TEST_ASSERT_TRUE(arbor_mesh_add_vert(m, vec3(x, y, tilted ? x / 4 + y / 8 : 0.0f), &e));
            }
    uint32_t n = 2 * GRID * GRID * VARIANTS;
    uint32_t *order = xmalloc(n * sizeof *order);
    for (uint32_t k = 0; k < n; k++)
        order[k] = k;
    test_rng g;
    test_rng_seed(&g, seed);
    for (uint32_t k = n - 1; k > 0; k--) {
        uint32_t r = test_rng_u32(&g) % (k + 1), t = order[k];
        order[k] = order[r];
        order[r] = t;
    }
    for (uint32_t k = 0; k < n; k++) {
        uint32_t base = order[k] / VARIANTS, variant = order[k] % VARIANTS;
        uint32_t quad = base / 2, i = quad % GRID, j = quad / GRID;
        uint32_t v00 = j * (GRID + 1) + i, v10 = v00 + 1, v01 = v00 + GRID + 1, v11 = v01 + 1;
        uint32_t c[3] = {v00, v10, v11};
        if (base & 1)
            c[1] = v11, c[2] = v01;
        if (variant == 1) {
            uint32_t t = c[0];
            c[0] = c[1], c[1] = c[2], c[2] = t;
        } else if (variant == 2) {
            c[0] += GRID_VERTS, c[1] += GRID_VERTS, c[2] += GRID_VERTS;
        } else if (variant == 3) {
            uint32_t t = c[1];
            c[1] = c[2], c[2] = t;
        }
        TEST_ASSERT_TRUE(arbor_mesh_add_tri(m, c[0], c[1], c[2], 0, &e));
    }
    free(order);
    TEST_ASSERT_TRUE_MESSAGE(arbor_mesh_finish(m, &e), e.msg);
}

/* Rays from above and below the grid: to random points of it, and exactly
 * through every grid vertex and the midpoint of every edge and diagonal,
 * where the triangles around it are all hit. */
static arbor_ray *tie_rays(const arbor_mesh *m, size_t nrandom, uint64_t seed, size_t *n)
{
    const arbor_vec3 origins[] = {vec3(0.3f, 0.4f, 2.0f), vec3(1.7f, -0.6f, 0.9f), vec3(0.55f, 0.45f, -1.5f)};
    const size_t norigins = sizeof origins / sizeof origins[0];
    size_t ntargets = 0;
    arbor_vec3 *targets = xmalloc((GRID_VERTS * 4) * sizeof *targets);
    for (uint32_t v = 0; v < GRID_VERTS; v++) {
        arbor_vec3 p = m->verts[v];
        targets[ntargets++] = p;
        uint32_t i = v % (GRID + 1), j = v / (GRID + 1);
        if (i < GRID)
            targets[ntargets++] = vec3_scale(vec3_add(p, m->verts[v + 1]), 0.5f);
        if (j < GRID)
            targets[ntargets++] = vec3_scale(vec3_add(p, m->verts[v + GRID + 1]), 0.5f);
        if (i < GRID && j < GRID)
            targets[ntargets++] = vec3_scale(vec3_add(p, m->verts[v + GRID + 2]), 0.5f);
    }
    arbor_ray *aimed = test_aimed_rays(origins, norigins, targets, ntargets);
    free(targets);
    *n = norigins * ntargets + nrandom;
    arbor_ray *rays = xmalloc(*n * sizeof *rays);
    memcpy(rays, aimed, norigins * ntargets * sizeof *rays);
    free(aimed);
    test_rng g;
    test_rng_seed(&g, seed);
    for (size_t k = norigins * ntargets; k < *n; k++) {
        arbor_vec3 o = vec3(-0.2f + 1.4f * test_rng_float(&g), -0.2f + 1.4f * test_rng_float(&g),
                            (k & 1 ? 1.0f : -1.0f) * (0.5f + test_rng_float(&g)));
        arbor_vec3 target = vec3(test_rng_float(&g), test_rng_float(&g), 0.3f * test_rng_float(&g));
        arbor_ray r = {o, 0.0f, vec3_normalize(vec3_sub(target, o)), INFINITY};
        rays[k] = r;
    }
    return rays;
}

/* The nearest hit by enumeration, highest index first, so a lower index
 * replaces an equal t: the rule by another route than brute force's.
 * *ties gets how many triangles are hit at that t. */
static bool nearest_lowest(const arbor_mesh *m, const arbor_ray *r, arbor_hit *best, uint32_t *ties)
{
    arbor_ray_prep p;
    arbor_ray_prepare(r, &p);
    bool found = false;
    *ties = 0;
    for (uint32_t i = m->ntris; i-- > 0;) {
        arbor_vec3 a, b, c;
        float t, u, v;
        arbor_mesh_tri(m, i, &a, &b, &c);
        if (!arbor_triangle_intersect(r, &p, a, b, c, INFINITY, &t, &u, &v))
            continue;
        if (!found || t < best->t)
            *ties = 0;
        if (!found || t <= best->t) {
            best->t = t;
            best->tri = i;
            found = true;
            (*ties)++;
        }
    }
    return found;
}

/* A tie mesh, its rays and their nearest hits, lowest index first: brute
 * force must give exactly those. */
static void tie_truth(arbor_mesh *m, test_truth *ts, const char *name, bool tilted)
{
    tie_mesh(m, tilted, 5);
    ts->rays = tie_rays(m, 4000, 6, &ts->n);
    ts->hit = xmalloc(ts->n * sizeof *ts->hit);
    ts->found = xmalloc(ts->n * sizeof *ts->found);
    size_t tied = 0, hits = 0;
    for (size_t i = 0; i < ts->n; i++) {
        uint32_t ties;
        ts->found[i] = nearest_lowest(m, &ts->rays[i], &ts->hit[i], &ties);
        hits += ts->found[i];
        tied += ties > 1;
        arbor_ray r = ts->rays[i];
        arbor_hit h;
        bool found = arbor_brute_intersect(m, &r, &h);
        char f[256];
        snprintf(f, sizeof f, "%s ray %zu: brute force %s tri %u t %.9g, lowest index at the nearest t: %s tri %u t %.9g",
                 name, i, found ? "hit" : "miss", found ? h.tri : 0, found ? (double)h.t : 0.0,
                 ts->found[i] ? "hit" : "miss", ts->hit[i].tri, (double)ts->hit[i].t);
        TEST_ASSERT_TRUE_MESSAGE(found == ts->found[i] && (!found || (h.tri == ts->hit[i].tri && h.t == ts->hit[i].t)),
                                 f);
    }
    /* every triangle is listed twice with the very same corners, so most
     * hits are ties (not all: a rotated or rewound copy may round nearer) */
    TEST_ASSERT_TRUE_MESSAGE(hits > ts->n / 2, "too few rays hit the grid");
    TEST_ASSERT_TRUE_MESSAGE(tied > hits / 2, "too few ties");
}

/* Every tree on both grids. */
static void check_trees_on_grids(check_kind kind)
{
    tree_failures tf = {0, ""};
    for (int tilted = 0; tilted < 2; tilted++) {
        const char *name = tilted ? "tilted grid" : "flat grid";
        arbor_mesh m;
        test_truth ts;
        tie_truth(&m, &ts, name, tilted);
        for (int k = 0; k < ARBOR_ACCEL_KIND_COUNT; k++)
            for (int b = 0; b < ARBOR_BUILDER_COUNT; b++) {
                char what[128];
                tree_name(what, sizeof what, name, 1.0f, k, b);
                arbor_accel *tree = build_tree(&m, (arbor_accel_kind)k, (arbor_builder)b, true, what);
                mismatches mm = {0, 0, ""};
                check_set(tree, "grid", &ts, kind, &mm);
                arbor_accel_free(tree);
                note_tree(&tf, what, &mm, ts.n);
            }
        test_truth_free(&ts);
        arbor_mesh_free(&m);
    }
    TEST_ASSERT_EQUAL_UINT64_MESSAGE(0, tf.failed, tf.msg);
}

/* Where boxes are flat (the flat grid) or meet at the edge or vertex a ray
 * hits, a box's or cell's entry distance may round past the hit's t: a
 * tree that culled against t itself would skip the box holding the tie. */
static void test_ties_go_to_the_lowest_index(void) { check_trees_on_grids(CHECK_CLOSEST); }

/* The same rounding against a tmax one float past the hit. */
static void test_any_hit_is_exact_at_tmax(void) { check_trees_on_grids(CHECK_AT_TMAX); }

int main(void)
{
    UNITY_BEGIN();
    RUN_TEST(test_only_exact_scales_are_accepted);
    RUN_TEST(test_ties_go_to_the_lowest_index);
    RUN_TEST(test_any_hit_is_exact_at_tmax);
    RUN_TEST(test_bunny_at_every_scale);
    RUN_TEST(test_dragon_at_every_scale);
    return UNITY_END();
}
