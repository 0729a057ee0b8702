/*
 * test_kd_sah.c - the k-d tree's SAH sweep (kd_sah.c) against a naive
 * O(N^2) plane search, on small triangle sets where the sweep's bookkeeping
 * is easiest to get wrong: random triangles on a coarse grid (many events
 * at one position), axis-aligned triangles lying in planes, triangles on the
 * cell's faces, cells smaller than the scene, cells flat along an axis.
 *
 * The naive search tries every box coordinate as a plane on every axis,
 * classifies every triangle from its box alone by Wald and Havran's rules
 * (below when it ends at or before p, above when it starts at or after p,
 * both when it crosses p, and in p when it is flat there), tries both sides
 * for the triangles in p, with a face plane allowed only when its planar
 * triangles go to the flat side, and keeps the cheapest. The sweep's plane
 * must cost exactly that (both price a split with kd_sah_fractions and
 * kd_sah_cost, whose arithmetic a hand-computed case checks), it must be a
 * split the naive search allows, and where a single plane and side is the
 * cheapest, the sweep must return that very one.
 */
#include <math.h>
#include <stdlib.h>

#include "../../src/accel/kd_internal.h"
#include "support.h"
#include "unity.h"

#define MAX_TRIS 48

void setUp(void) {}
void tearDown(void) {}

/* A node to test: its cell and its triangles' boxes within the cell. */
typedef struct {
    arbor_aabb cell;
    arbor_aabb box[MAX_TRIS];
    uint32_t n;
} node_case;

/* ---- the naive search ------------------------------------------------- */

typedef struct {
    double cost;       /* the cheapest split's; the leaf's when none is cheaper */
    bool found;
    uint32_t winners;  /* how many (plane, side) pairs cost exactly that */
    kd_plane plane;    /* the first of them */
} naive_best;

/* The counts of the split at p on axis k: below and above only, both, in p. */
static void naive_classify(const node_case *c, int k, float p, uint32_t *below, uint32_t *above, uint32_t *both,
                           uint32_t *planar)
{
    *below = *above = *both = *planar = 0;
    for (uint32_t i = 0; i < c->n; i++) {
        float lo = kd_lo(&c->box[i], k), hi = kd_hi(&c->box[i], k);
        if (lo == hi && lo == p)
            (*planar)++;
        else if (hi <= p)
            (*below)++;
        else if (lo >= p)
            (*above)++;
        else
            (*both)++;
    }
}

/* The cost of splitting at (k, p) with the planar triangles on side
 * planar_below, or INFINITY when that split is not allowed. */
static double naive_cost(const kd_builder *b, const node_case *c, int k, float p, bool planar_below)
{
    float lo = kd_lo(&c->cell, k), hi = kd_hi(&c->cell, k);
    uint32_t below, above, both, planar;
    naive_classify(c, k, p, &below, &above, &both, &planar);
    bool inside = lo < p && p < hi;
    bool face_ok = lo < hi && planar > 0 && (planar_below ? p == lo : p == hi);
    if (!inside && !face_ok)
        return INFINITY;
    double pb, pa;
    kd_sah_fractions(&c->cell, k, p, &pb, &pa);
    uint32_t nb = below + both + (planar_below ? planar : 0), na = above + both + (planar_below ? 0 : planar);
    return kd_sah_cost(b, pb, pa, nb, na);
}

static naive_best naive_search(const kd_builder *b, const node_case *c)
{
    naive_best best = {(double)b->cost_intersect * c->n, false, 0, {0, 0.0f, false}};
    for (int k = 0; k < 3; k++)
        for (uint32_t i = 0; i < 2 * c->n; i++) {
            float p = i % 2 ? kd_hi(&c->box[i / 2], k) : kd_lo(&c->box[i / 2], k);
            for (int side = 0; side < 2; side++) {
                double cost = naive_cost(b, c, k, p, side == 1);
                if (cost < best.cost) {
                    best.cost = cost;
                    best.found = true;
                    best.winners = 0;
                    best.plane = (kd_plane){k, p, side == 1};
                }
                /* every (plane, side) at the best cost once: a position
                 * comes from several boxes, so count only its first */
                bool first = true;
                for (uint32_t j = 0; j < i; j++)
                    first = first && (j % 2 ? kd_hi(&c->box[j / 2], k) : kd_lo(&c->box[j / 2], k)) != p;
                best.winners += best.found && first && cost == best.cost;
            }
        }
    return best;
}

/* ---- the sweep -------------------------------------------------------- */

/* The sweep's plane for c: its events made as the builder makes them. */
static bool sweep_search(const kd_builder *b, const node_case *c, kd_plane *pl)
{
    kd_event *events = malloc((KD_RUNS_ROOM * (size_t)c->n + 1) * sizeof *events);
    kd_event *tmp = malloc((KD_RUN_ROOM * (size_t)c->n + 1) * sizeof *tmp);
    TEST_ASSERT_NOT_NULL(events);
    TEST_ASSERT_NOT_NULL(tmp);
    kd_event_runs runs;
    kd_runs_init(&runs, events, c->n);
    for (uint32_t i = 0; i < c->n; i++)
        kd_runs_add(&runs, i, &c->box[i]);
    kd_task t = {0};
    t.events = events;
    kd_runs_finish(&runs, tmp, t.axis_begin);
    t.ntris = c->n;
    t.cell = c->cell;
    bool found = kd_sah_plane(b, &t, pl);
    free(events);
    free(tmp);
    return found;
}

static void check_case(const kd_builder *b, const node_case *c, const char *what, uint32_t trial)
{
    char msg[160];
    snprintf(msg, sizeof msg, "%s, trial %u, %u triangles, KT %g KI %g lambda %g", what, trial, c->n,
             (double)b->cost_traverse, (double)b->cost_intersect, (double)b->empty_factor);
    naive_best want = naive_search(b, c);
    kd_plane got;
    bool found = sweep_search(b, c, &got);
    TEST_ASSERT_EQUAL_MESSAGE(want.found, found, msg);
    if (!found)
        return;
    double cost = naive_cost(b, c, got.axis, got.pos, got.planar_below);
    TEST_ASSERT_TRUE_MESSAGE(isfinite(cost), msg);  /* a split the rules allow */
    TEST_ASSERT_EQUAL_DOUBLE_MESSAGE(want.cost, cost, msg);
    TEST_ASSERT_TRUE_MESSAGE(want.cost == cost, msg);  /* exactly, not within Unity's tolerance */
    if (want.winners == 1) {
        TEST_ASSERT_EQUAL_INT_MESSAGE(want.plane.axis, got.axis, msg);
        TEST_ASSERT_TRUE_MESSAGE(want.plane.pos == got.pos, msg);
        TEST_ASSERT_EQUAL_MESSAGE(want.plane.planar_below, got.planar_below, msg);
    }
}

/* ---- the cases -------------------------------------------------------- */

/* A coordinate on a grid of step 0.5 in [lo, hi]: coarse, so that many
 * events share a position and triangles touch the cell's faces. */
static float grid(test_rng *g, float lo, float hi)
{
    uint32_t steps = (uint32_t)((hi - lo) * 2.0f);
    return lo + 0.5f * (float)(test_rng_u32(g) % (steps + 1));
}

static void set_axis(arbor_vec3 *p, int k, float x)
{
    if (k == 0)
        p->x = x;
    else if (k == 1)
        p->y = x;
    else
        p->z = x;
}

/* The box of a triangle with corners on the grid of the cell; with
 * flat_axis >= 0 the triangle lies in a plane of that axis (at one of the
 * cell's faces when on_face). */
static arbor_aabb grid_triangle_box(test_rng *g, const arbor_aabb *cell, int flat_axis, bool on_face)
{
    arbor_vec3 v[3];
    for (int i = 0; i < 3; i++)
        for (int k = 0; k < 3; k++)
            set_axis(&v[i], k, grid(g, kd_lo(cell, k), kd_hi(cell, k)));
    if (flat_axis >= 0) {
        float lo = kd_lo(cell, flat_axis), hi = kd_hi(cell, flat_axis);
        float x = on_face ? (test_rng_u32(g) % 2 ? hi : lo) : grid(g, lo, hi);
        for (int i = 0; i < 3; i++)
            set_axis(&v[i], flat_axis, x);
    }
    arbor_aabb box = {v[0], v[0]};
    for (int i = 1; i < 3; i++) {
        box.lo = vec3(fminf(box.lo.x, v[i].x), fminf(box.lo.y, v[i].y), fminf(box.lo.z, v[i].z));
        box.hi = vec3(fmaxf(box.hi.x, v[i].x), fmaxf(box.hi.y, v[i].y), fmaxf(box.hi.z, v[i].z));
    }
    return box;
}

/* A cell on the grid within [0, 4]^3; flat along flat_axis when >= 0. */
static arbor_aabb grid_cell(test_rng *g, int flat_axis)
{
    arbor_aabb cell;
    for (int k = 0; k < 3; k++) {
        float a = grid(g, 0.0f, 4.0f), b = grid(g, 0.0f, 4.0f);
        if (a == b)
            b = a < 4.0f ? a + 0.5f : a - 0.5f;
        float lo = fminf(a, b), hi = fmaxf(a, b);
        if (k == flat_axis)
            hi = lo;
        set_axis(&cell.lo, k, lo);
        set_axis(&cell.hi, k, hi);
    }
    return cell;
}

static const kd_builder cost_models[4] = {
    {.cost_traverse = 15.0f, .cost_intersect = 20.0f, .empty_factor = 0.8f},  /* the paper's */
    {.cost_traverse = 15.0f, .cost_intersect = 20.0f / KD_PACK_LANES, .empty_factor = 0.8f}, /* the defaults */
    {.cost_traverse = 1.0f, .cost_intersect = 1.0f, .empty_factor = 1.0f},    /* no empty bonus */
    {.cost_traverse = 5.0f, .cost_intersect = 40.0f, .empty_factor = 0.5f},   /* cheap traversal */
};

/* Runs `trials` cases of a kind: planar_percent of the triangles lie in an
 * axis plane, face_percent of those on one of the cell's faces. */
static void run_cases(const char *what, uint32_t trials, uint64_t seed, int planar_percent, int face_percent,
                      bool flat_cells)
{
    test_rng g;
    test_rng_seed(&g, seed);
    for (uint32_t trial = 0; trial < trials; trial++) {
        node_case c;
        int flat_cell_axis = flat_cells ? (int)(test_rng_u32(&g) % 3) : -1;
        c.cell = grid_cell(&g, flat_cell_axis);
        c.n = 1 + test_rng_u32(&g) % MAX_TRIS;
        for (uint32_t i = 0; i < c.n; i++) {
            bool planar = (int)(test_rng_u32(&g) % 100) < planar_percent;
            bool on_face = (int)(test_rng_u32(&g) % 100) < face_percent;
            int axis = planar ? (int)(test_rng_u32(&g) % 3) : -1;
            c.box[i] = grid_triangle_box(&g, &c.cell, axis, on_face);
        }
        check_case(&cost_models[trial % 4], &c, what, trial);
    }
}

/* The pricing both searches share, by hand: the unit cube split at
 * x = 0.25 has children of areas 2 (1 + 0.25 * 2) and 2 (1 + 0.75 * 2) of
 * the cube's 6. */
static void test_split_cost_by_hand(void)
{
    arbor_aabb cube = {vec3(0, 0, 0), vec3(1, 1, 1)};
    double pb, pa;
    kd_sah_fractions(&cube, 0, 0.25f, &pb, &pa);
    TEST_ASSERT_EQUAL_DOUBLE(0.5, pb);
    TEST_ASSERT_EQUAL_DOUBLE(2.5 / 3.0, pa);
    kd_sah_fractions(&cube, 2, 0.0f, &pb, &pa);  /* a flat child: its two caps */
    TEST_ASSERT_EQUAL_DOUBLE(1.0 / 3.0, pb);
    TEST_ASSERT_EQUAL_DOUBLE(1.0, pa);
    const kd_builder *b = &cost_models[0];
    TEST_ASSERT_EQUAL_DOUBLE(15.0 + 20.0 * (0.5 * 2 + 0.5 * 3), kd_sah_cost(b, 0.5, 0.5, 2, 3));
    TEST_ASSERT_EQUAL_DOUBLE((double)0.8f * (15.0 + 20.0 * (0.5 * 3)), kd_sah_cost(b, 0.5, 0.5, 0, 3));
}

/* A floor on the cell's low face under a few triangles: the sweep cuts the
 * floor off into a flat cell below (a face split, planar triangles below),
 * which beats every inner plane and the leaf. */
static void test_floor_cut_off_at_face(void)
{
    node_case c = {.cell = {vec3(0, 0, 0), vec3(4, 4, 4)}, .n = 0};
    for (int i = 0; i < 20; i++)
        c.box[c.n++] = (arbor_aabb){vec3(0, 0, (float)i * 0.2f), vec3(4, 0, (float)i * 0.2f + 0.2f)};
    c.box[c.n++] = (arbor_aabb){vec3(1, 1, 1), vec3(3, 4, 3)};
    kd_plane pl;
    TEST_ASSERT_TRUE(sweep_search(&cost_models[0], &c, &pl));
    TEST_ASSERT_EQUAL_INT(1, pl.axis);
    TEST_ASSERT_TRUE(pl.pos == 0.0f);
    TEST_ASSERT_TRUE(pl.planar_below);
    check_case(&cost_models[0], &c, "floor", 0);
}

/* Planar triangles on a face with nothing else: the face plane may take
 * them only to the flat side, never leave them on the full one (a split
 * that separates nothing), and a cell flat along the axis offers no plane
 * on it at all. */
static void test_face_planes_only_to_the_flat_side(void)
{
    node_case c = {.cell = {vec3(0, 0, 0), vec3(4, 4, 4)}, .n = 0};
    for (int i = 0; i < 8; i++)
        c.box[c.n++] = (arbor_aabb){vec3(4, (float)i * 0.5f, 0), vec3(4, (float)i * 0.5f + 0.5f, 4)};
    kd_plane pl;
    TEST_ASSERT_TRUE(sweep_search(&cost_models[0], &c, &pl));
    TEST_ASSERT_FALSE(pl.axis == 0 && pl.planar_below);
    check_case(&cost_models[0], &c, "high face", 0);

    c.cell.lo.x = 4.0f;  /* the cell is the face itself */
    TEST_ASSERT_TRUE(sweep_search(&cost_models[0], &c, &pl));
    TEST_ASSERT_TRUE(pl.axis != 0);
    check_case(&cost_models[0], &c, "flat cell", 0);
}

static void test_random_triangles(void) { run_cases("random", 3000, 11, 0, 0, false); }
static void test_planar_heavy(void) { run_cases("planar-heavy", 3000, 12, 70, 10, false); }
static void test_triangles_on_faces(void) { run_cases("on faces", 3000, 13, 80, 60, false); }
static void test_flat_cells(void) { run_cases("flat cells", 2000, 14, 50, 50, true); }

int main(void)
{
    UNITY_BEGIN();
    RUN_TEST(test_split_cost_by_hand);
    RUN_TEST(test_floor_cut_off_at_face);
    RUN_TEST(test_face_planes_only_to_the_flat_side);
    RUN_TEST(test_random_triangles);
    RUN_TEST(test_planar_heavy);
    RUN_TEST(test_triangles_on_faces);
    RUN_TEST(test_flat_cells);
    return UNITY_END();
}
