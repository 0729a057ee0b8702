/*
 * kd_validate.c - checks a built k-d tree against its invariants
 * (kd_internal.h) without trusting the builder: cells are recomputed from
 * the root box and the planes, and whether a triangle meets a cell is
 * decided by the separating-axis test of Akenine-Moeller ("Fast 3D
 * triangle-box overlap testing", 2001) in double precision, not by the
 * builder's clipping.
 *
 *  1. The walk: from the root, every node is reached exactly once; inner
 *     nodes have an axis, a split within their cell (on a face only when
 *     the cell has extent along the axis: the SAH's flat children) and
 *     children in range; leaves are no deeper than max_depth and list
 *     valid triangles, each of which touches the leaf's cell grown by a
 *     tolerance, and their packs hold exactly those triangles' corners.
 *     The walk also recounts every statistic, which must equal the stored
 *     ones.
 *  2. Coverage: each triangle is listed somewhere, and in every leaf whose
 *     cell, shrunk by the tolerance at faces that are split planes, it
 *     overlaps (found by descending the tree with the triangle's box).
 *
 * The tolerance, 2^-16 of the scene's largest coordinate or extent, is
 * well above the builder's outward rounding of clipped boxes (2^-20): near
 * a split plane either side may hold a triangle that only touches it.
 */
#include <float.h>
#include <math.h>
#include <stdlib.h>

#include "kd_internal.h"

typedef struct {
    double lo[3], hi[3];
} kd_dbox;

typedef struct {
    const kd_tree *tree;
    const arbor_mesh *mesh;
    arbor_err *e;
    double tol;
    uint8_t *seen;        /* per node: reached by the walk */
    uint32_t *listed;     /* per triangle: leaves listing it */
    /* the statistics as the walk counts them */
    uint64_t leaves, empty_leaves, refs, depth_sum;
    uint32_t max_depth;
    double inner_area, leaf_area_tris;
} kd_check;

static kd_dbox kd_dbox_of(const arbor_aabb *b)
{
    kd_dbox d = {{b->lo.x, b->lo.y, b->lo.z}, {b->hi.x, b->hi.y, b->hi.z}};
    return d;
}

static double kd_dbox_area(const kd_dbox *b)
{
    double x = b->hi[0] - b->lo[0], y = b->hi[1] - b->lo[1], z = b->hi[2] - b->lo[2];
    if (!(x >= 0 && y >= 0 && z >= 0))
        return 0.0;
    return 2.0 * (x * y + y * z + z * x);
}

/* Whether |p| stays within r along an axis: the projections p0..p2 of the
 * triangle (relative to the box centre) against the box's radius r. */
static inline bool kd_axis_overlaps(double p0, double p1, double p2, double r)
{
    double lo = p0 < p1 ? p0 : p1, hi = p0 < p1 ? p1 : p0;
    lo = p2 < lo ? p2 : lo;
    hi = p2 > hi ? p2 : hi;
    return !(lo > r || hi < -r);
}

/* Separating-axis test: does triangle tri meet box b (faces included)?
 * The triangle's normal is the one axis that can be ill-conditioned: for a
 * needle, two of whose corners are a few float ulps apart, it is the cross
 * product of two nearly opposite long edges and mostly rounding (a fuzzed
 * needle from near the origin to 4e6 had its normal wrong, and touched a
 * cell it was said to miss). So that axis decides only beyond a bound on
 * its rounding: with `lenient` the answer is "may meet" (the leaf check:
 * fail only when the triangle surely misses), otherwise "surely meets"
 * (the coverage check: fail only when it surely enters an unlisted cell).
 * The other axes are sums of products of long edges and stay exact to far
 * below the tolerance. */
static bool kd_tri_meets_box(const arbor_mesh *m, uint32_t tri, const kd_dbox *b, bool lenient)
{
    arbor_vec3 p[3];
    arbor_mesh_tri(m, tri, &p[0], &p[1], &p[2]);
    double c[3], h[3], v[3][3];
    for (int k = 0; k < 3; k++) {
        if (b->lo[k] > b->hi[k])
            return false;
        c[k] = 0.5 * (b->lo[k] + b->hi[k]);
        h[k] = 0.5 * (b->hi[k] - b->lo[k]);
    }
    for (int i = 0; i < 3; i++) {
        v[i][0] = p[i].x - c[0];
        v[i][1] = p[i].y - c[1];
        v[i][2] = p[i].z - c[2];
    }
    /* the box's face normals */
    for (int k = 0; k < 3; k++)
        if (!kd_axis_overlaps(v[0][k], v[1][k], v[2][k], h[k]))
            return false;
    double edge[3][3];
    for (int i = 0; i < 3; i++)
        for (int k = 0; k < 3; k++)
            edge[i][k] = v[(i + 1) % 3][k] - v[i][k];
    /* the triangle's normal */
    double n[3] = {edge[0][1] * edge[1][2] - edge[0][2] * edge[1][1], edge[0][2] * edge[1][0] - edge[0][0] * edge[1][2],
                   edge[0][0] * edge[1][1] - edge[0][1] * edge[1][0]};
    double pn = n[0] * v[0][0] + n[1] * v[0][1] + n[2] * v[0][2];
    double rn = h[0] * fabs(n[0]) + h[1] * fabs(n[1]) + h[2] * fabs(n[2]);
    /* d bounds each edge component's rounding (the corners' offsets from
     * the centre, then their differences), e_n[k] that of n[k], and slack
     * that of |pn| - rn, all generously (DBL_EPSILON is 2u) */
    double vmax = 0.0;
    for (int i = 0; i < 3; i++)
        for (int k = 0; k < 3; k++)
            vmax = fmax(vmax, fabs(v[i][k]));
    double d = 4.0 * DBL_EPSILON * vmax, slack = DBL_EPSILON * (fabs(pn) + rn);
    for (int k = 0; k < 3; k++) {
        int k1 = (k + 1) % 3, k2 = (k + 2) % 3;
        double e_n = d * (fabs(edge[0][k1]) + fabs(edge[1][k2]) + fabs(edge[0][k2]) + fabs(edge[1][k1])) + 2.0 * d * d +
                     DBL_EPSILON * (fabs(edge[0][k1] * edge[1][k2]) + fabs(edge[0][k2] * edge[1][k1]));
        slack += e_n * (fabs(v[0][k]) + h[k]);
    }
    if (fabs(pn) > rn + (lenient ? slack : -slack))
        return false;
    /* the cross products of the edges with the box's axes */
    for (int i = 0; i < 3; i++)
        for (int k = 0; k < 3; k++) {
            double a[3] = {0, 0, 0};
            int k1 = (k + 1) % 3, k2 = (k + 2) % 3;
            a[k1] = -edge[i][k2];  /* e_k x edge */
            a[k2] = edge[i][k1];
            double r = h[0] * fabs(a[0]) + h[1] * fabs(a[1]) + h[2] * fabs(a[2]);
            double q[3];
            for (int j = 0; j < 3; j++)
                q[j] = a[0] * v[j][0] + a[1] * v[j][1] + a[2] * v[j][2];
            if (!kd_axis_overlaps(q[0], q[1], q[2], r))
                return false;
        }
    return true;
}

/* The node's cell grown by tol on every face. */
static kd_dbox kd_grown(const kd_dbox *cell, double tol)
{
    kd_dbox g = *cell;
    for (int k = 0; k < 3; k++) {
        g.lo[k] -= tol;
        g.hi[k] += tol;
    }
    return g;
}

/* Bits of a cell's faces: the low face on axis k is bit 2k, the high one
 * bit 2k + 1. */
static unsigned kd_face_bit(uint32_t k, bool high) { return 1u << (2 * k + high); }

/* The cell shrunk by tol at faces that are split planes (the bits of
 * split_faces) and grown at the root box's own faces, where no neighbour
 * could take the triangle. Which faces are split planes is known from the
 * descent, not from coordinates: a split may lie on the root box's face. */
static kd_dbox kd_shrunk(const kd_check *c, const kd_dbox *cell, unsigned split_faces)
{
    kd_dbox s = *cell;
    for (uint32_t k = 0; k < 3; k++) {
        s.lo[k] += (split_faces & kd_face_bit(k, false)) ? c->tol : -c->tol;
        s.hi[k] += (split_faces & kd_face_bit(k, true)) ? -c->tol : c->tol;
    }
    return s;
}

/* Whether the packs of leaf `at` (count > 1 triangles, in range) hold
 * exactly its list's corners, and NaN in the lanes past its count. */
static bool kd_check_packs(kd_check *c, uint32_t at, const kd_node *n, uint32_t count)
{
    const kd_tree *t = c->tree;
    if (n->first % KD_PACK_LANES != 0 || n->first / KD_PACK_LANES + (count - 1) / KD_PACK_LANES >= t->npacks)
        return arbor_fail(c->e, ARBOR_ERR_INVALID, "kd leaf %u: list at %u not on a pack of the %zu", at, n->first,
                          t->npacks);
    const kd_pack *p = t->packs + n->first / KD_PACK_LANES;
    uint32_t lanes = (count + KD_PACK_LANES - 1) / KD_PACK_LANES * KD_PACK_LANES;
    for (uint32_t i = 0; i < lanes; i++) {
        arbor_vec3 v[3];
        if (i < count)
            arbor_mesh_tri(c->mesh, t->tri_index[n->first + i], &v[0], &v[1], &v[2]);
        for (int a = 0; a < 3; a++)
            for (int k = 0; k < 3; k++) {
                float got = p[i / KD_PACK_LANES].v[a][k][i % KD_PACK_LANES];
                if (i < count ? got != vec3_axis(v[a], k) : !isnan(got))
                    return arbor_fail(c->e, ARBOR_ERR_INVALID, "kd leaf %u: pack lane %u corner %d axis %d is %g",
                                      at, i, a, k, (double)got);
            }
    }
    return true;
}

static bool kd_check_leaf(kd_check *c, uint32_t at, const kd_dbox *cell, uint32_t depth)
{
    const kd_tree *t = c->tree;
    const kd_node *n = &t->nodes[at];
    uint32_t count = kd_node_high(*n);
    if (count > 1 && ((size_t)n->first + count > t->nindex || n->first + count < n->first))
        return arbor_fail(c->e, ARBOR_ERR_INVALID, "kd leaf %u: list [%u, +%u) outside the %zu indices", at, n->first,
                          count, t->nindex);
    const uint32_t *tris = kd_leaf_tris(n, t->tri_index);
    kd_dbox grown = kd_grown(cell, c->tol);
    for (uint32_t i = 0; i < count; i++) {
        if (tris[i] >= c->mesh->ntris)
            return arbor_fail(c->e, ARBOR_ERR_INVALID, "kd leaf %u: triangle %u of %u", at, tris[i], c->mesh->ntris);
        if (!kd_tri_meets_box(c->mesh, tris[i], &grown, true))
            return arbor_fail(c->e, ARBOR_ERR_INVALID,
                              "kd leaf %u (depth %u): triangle %u does not touch the cell [%g %g %g]-[%g %g %g]", at,
                              depth, tris[i], cell->lo[0], cell->lo[1], cell->lo[2], cell->hi[0], cell->hi[1],
                              cell->hi[2]);
        c->listed[tris[i]]++;
    }
    if (count > 1 && !kd_check_packs(c, at, n, count))
        return false;
    c->leaves++;
    c->empty_leaves += count == 0;
    c->refs += count;
    c->depth_sum += depth;
    if (depth > c->max_depth)
        c->max_depth = depth;
    c->leaf_area_tris += kd_dbox_area(cell) * count;
    return true;
}

/* Step 1 for the subtree at node `at` with cell `cell`. */
static bool kd_walk(kd_check *c, uint32_t at, const kd_dbox *cell, uint32_t depth)
{
    const kd_tree *t = c->tree;
    if (at >= t->nnodes)
        return arbor_fail(c->e, ARBOR_ERR_INVALID, "kd node %u: past the %zu nodes", at, t->nnodes);
    if (c->seen[at]++)
        return arbor_fail(c->e, ARBOR_ERR_INVALID, "kd node %u: reached twice", at);
    if (depth > t->max_depth)
        return arbor_fail(c->e, ARBOR_ERR_INVALID, "kd node %u: depth %u over the limit %u", at, depth,
                          t->max_depth);
    kd_node n = t->nodes[at];
    uint32_t axis = kd_node_kind(n);
    if (axis == KD_LEAF)
        return kd_check_leaf(c, at, cell, depth);
    double split = n.split;
    if (!(split >= cell->lo[axis] && split <= cell->hi[axis] && cell->lo[axis] < cell->hi[axis]))
        return arbor_fail(c->e, ARBOR_ERR_INVALID, "kd node %u: split %g on axis %u outside its cell [%g, %g]", at,
                          split, axis, cell->lo[axis], cell->hi[axis]);
    uint32_t above = kd_node_high(n);
    if (above <= at + 1)
        return arbor_fail(c->e, ARBOR_ERR_INVALID, "kd node %u: above child %u not after the below one", at, above);
    c->inner_area += kd_dbox_area(cell);
    kd_dbox below_cell = *cell, above_cell = *cell;
    below_cell.hi[axis] = above_cell.lo[axis] = split;
    return kd_walk(c, at + 1, &below_cell, depth + 1) && kd_walk(c, above, &above_cell, depth + 1);
}

static bool kd_listed_in(const kd_tree *t, uint32_t at, uint32_t tri)
{
    const kd_node *n = &t->nodes[at];
    const uint32_t *tris = kd_leaf_tris(n, t->tri_index);
    for (uint32_t i = 0; i < kd_node_high(*n); i++)
        if (tris[i] == tri)
            return true;
    return false;
}

/* Step 2 for triangle tri (box tbox) in the subtree at `at`, whose cell's
 * faces in split_faces are split planes. */
static bool kd_cover(kd_check *c, uint32_t tri, const kd_dbox *tbox, uint32_t at, const kd_dbox *cell,
                     unsigned split_faces)
{
    kd_node n = c->tree->nodes[at];
    uint32_t axis = kd_node_kind(n);
    if (axis == KD_LEAF) {
        kd_dbox inner = kd_shrunk(c, cell, split_faces);
        if (kd_tri_meets_box(c->mesh, tri, &inner, false) && !kd_listed_in(c->tree, at, tri))
            return arbor_fail(c->e, ARBOR_ERR_INVALID,
                              "kd leaf %u: triangle %u enters its cell [%g %g %g]-[%g %g %g] but is not listed", at,
                              tri, cell->lo[0], cell->lo[1], cell->lo[2], cell->hi[0], cell->hi[1], cell->hi[2]);
        return true;
    }
    kd_dbox below_cell = *cell, above_cell = *cell;
    below_cell.hi[axis] = above_cell.lo[axis] = n.split;
    unsigned below_faces = split_faces | kd_face_bit(axis, true);
    unsigned above_faces = split_faces | kd_face_bit(axis, false);
    if (tbox->lo[axis] <= n.split + c->tol && !kd_cover(c, tri, tbox, at + 1, &below_cell, below_faces))
        return false;
    return !(tbox->hi[axis] >= n.split - c->tol) ||
           kd_cover(c, tri, tbox, kd_node_high(n), &above_cell, above_faces);
}

static bool kd_stat_equal(double walked, double stored)
{
    return fabs(walked - stored) <= 1e-9 * fmax(fabs(walked), fabs(stored));
}

/* Step 1's counts against the stored statistics. */
static bool kd_check_stats(const kd_check *c, const arbor_tree_stats *s)
{
    const kd_tree *t = c->tree;
    uint64_t nonempty = c->leaves - c->empty_leaves;
    kd_dbox root = kd_dbox_of(&t->bounds);
    double root_area = kd_dbox_area(&root);
    double mean_depth = c->leaves ? (double)c->depth_sum / (double)c->leaves : 0.0;
    double mean_tris = nonempty ? (double)c->refs / (double)nonempty : 0.0;
    double sah = root_area > 0.0 ? (c->inner_area + c->leaf_area_tris) / root_area
                                 : (double)(t->nnodes - c->leaves) + (double)c->refs;
    uint64_t bytes = kd_tree_bytes(t);
    if (s->nodes != t->nnodes || s->leaves != c->leaves || s->empty_leaves != c->empty_leaves ||
        s->refs != c->refs || s->max_depth != c->max_depth || s->bytes != bytes || s->binary_bytes != bytes)
        return arbor_fail(c->e, ARBOR_ERR_INVALID,
                          "kd stats: stored nodes %llu leaves %llu empty %llu refs %llu depth %u bytes %llu, "
                          "walk finds %zu %llu %llu %llu %u %llu",
                          (unsigned long long)s->nodes, (unsigned long long)s->leaves,
                          (unsigned long long)s->empty_leaves, (unsigned long long)s->refs, s->max_depth,
                          (unsigned long long)s->bytes, t->nnodes, (unsigned long long)c->leaves,
                          (unsigned long long)c->empty_leaves, (unsigned long long)c->refs, c->max_depth,
                          (unsigned long long)bytes);
    if (!kd_stat_equal(mean_depth, s->mean_leaf_depth) || !kd_stat_equal(mean_tris, s->mean_tris_per_leaf) ||
        !kd_stat_equal(sah, s->sah_cost))
        return arbor_fail(c->e, ARBOR_ERR_INVALID,
                          "kd stats: stored leaf depth %g tris/leaf %g sah %g, walk finds %g %g %g",
                          s->mean_leaf_depth, s->mean_tris_per_leaf, s->sah_cost, mean_depth, mean_tris, sah);
    return true;
}

static bool kd_check_all(kd_check *c, const arbor_tree_stats *stats)
{
    const kd_tree *t = c->tree;
    const arbor_mesh *m = c->mesh;
    if (t->nnodes == 0)
        return arbor_fail(c->e, ARBOR_ERR_INVALID, "kd tree: no nodes");
    if (t->max_depth > KD_MAX_DEPTH)
        return arbor_fail(c->e, ARBOR_ERR_INVALID, "kd tree: depth limit %u over %d", t->max_depth, KD_MAX_DEPTH);
    kd_dbox root = kd_dbox_of(&t->bounds);
    if (!kd_walk(c, 0, &root, 0))
        return false;
    for (size_t i = 0; i < t->nnodes; i++)
        if (!c->seen[i])
            return arbor_fail(c->e, ARBOR_ERR_INVALID, "kd node %zu: not reachable from the root", i);
    if (!kd_check_stats(c, stats))
        return false;
    for (uint32_t tri = 0; tri < m->ntris; tri++) {
        if (c->listed[tri] == 0)
            return arbor_fail(c->e, ARBOR_ERR_INVALID, "kd tree: triangle %u is in no leaf", tri);
        arbor_aabb b = arbor_mesh_tri_bounds(m, tri);
        kd_dbox tbox = kd_dbox_of(&b);
        if (!kd_cover(c, tri, &tbox, 0, &root, 0))
            return false;
    }
    return true;
}

bool kd_validate(const void *impl, const arbor_mesh *m, const arbor_tree_stats *stats, arbor_err *e)
{
    const kd_tree *t = impl;
    kd_check c = {0};
    c.tree = t;
    c.mesh = m;
    c.e = e;
    kd_dbox root = kd_dbox_of(&t->bounds);
    double scale = 0.0;
    for (int k = 0; k < 3; k++)
        scale = fmax(scale, fmax(fabs(root.lo[k]), fmax(fabs(root.hi[k]), root.hi[k] - root.lo[k])));
    c.tol = isfinite(scale) ? scale * 0x1p-16 : 0.0;
    c.seen = calloc(t->nnodes + 1, 1);
    c.listed = calloc((size_t)m->ntris + 1, sizeof *c.listed);
    bool ok = c.seen != NULL && c.listed != NULL ? kd_check_all(&c, stats)
                                                 : arbor_fail(e, ARBOR_ERR_NOMEM, "kd validate: out of memory");
    free(c.seen);
    free(c.listed);
    return ok;
}
