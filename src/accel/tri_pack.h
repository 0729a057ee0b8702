/*
 * tri_pack.h - the watertight ray-triangle test (arbor_triangle_intersect,
 * include/arbor/ray.h) on a pack of SIMD_LANES triangles at once, for the
 * leaves of every tree. Each lane computes every value the scalar test
 * does by the same operations on the same operands (the source computes
 * them in another order, which changes no rounding), with no fused
 * multiply-add (the kernels are compiled with -ffp-contract=off), so each
 * triangle gives exactly the t, u, v brute force computes for it; an edge
 * function that comes out zero in single precision is decided in double by
 * the scalar test's own arbor_edge_functions_exact, as there, in a pass
 * over the pack made out of line because it is rare.
 *
 * A pack's layout is a float array v[3][3][SIMD_LANES]: vertex a, b, c;
 * axis x, y, z; lane = triangle, 4 * SIMD_LANES-byte aligned. Lanes a pack
 * does not use hold NaN vertices, which make every comparison false, so
 * they never hit. Include after defining SIMD_LANES (simd.h).
 */
#ifndef ARBOR_TRI_PACK_H
#define ARBOR_TRI_PACK_H

#include <string.h>

#include "arbor/ray.h"
#include "simd.h"

/* Per-ray constants of the test: the axis permutation k (kz the dominant
 * axis of the direction), the origin in that order, the shear constants.
 * Worth setting up lazily, at the first leaf a ray reaches. */
typedef struct {
    int k[3];
    float org[3], shear[3], tmin;
} tri_ray;

SIMD_INLINE void tri_ray_setup(tri_ray *q, const arbor_ray *r)
{
    const float o[3] = {r->o.x, r->o.y, r->o.z};
    arbor_ray_prep p;
    arbor_ray_prepare(r, &p);
    q->k[0] = p.kx;
    q->k[1] = p.ky;
    q->k[2] = p.kz;
    for (int a = 0; a < 3; a++)
        q->org[a] = o[q->k[a]];
    q->shear[0] = p.sx;
    q->shear[1] = p.sy;
    q->shear[2] = p.sz;
    q->tmin = r->tmin;
}

/* What a pack test found (the lanes hit are its return value): per lane t,
 * and V, W and 1 / det, from which u = V / det and v = W / det as the
 * scalar test gives them. Read whole (a lane read would keep the vectors in
 * memory, stored at every test): tri_pack_lanes gives their lanes once a
 * test has hit. */
typedef struct {
    vfloat t, v, w, inv;
} tri_pack_hits;

/* The lanes of a tri_pack_hits, to read lane by lane. */
typedef struct {
    float t[SIMD_LANES], v[SIMD_LANES], w[SIMD_LANES], inv[SIMD_LANES];
} tri_pack_lanes;

SIMD_INLINE void tri_pack_lanes_of(const tri_pack_hits *h, tri_pack_lanes *out)
{
    memcpy(out->t, &h->t, sizeof out->t);
    memcpy(out->v, &h->v, sizeof out->v);
    memcpy(out->w, &h->w, sizeof out->w);
    memcpy(out->inv, &h->inv, sizeof out->inv);
}

/* nextafterf(t, INFINITY) for the t of a hit (finite: t < tmax), the bound
 * the tests take once there is a hit, so that a tie at t reaches the index
 * rule. In line, not libm's: a call in the traversal loop, even one made
 * only after a hit, clobbers every vector register, and GCC then kept the
 * ray's constant vectors in memory for the whole loop, reloading them at
 * every node (docs/BENCH.md). */
SIMD_INLINE float tri_pack_next_up(float t)
{
    uint32_t u;
    memcpy(&u, &t, sizeof u);
    if (t == 0.0f)
        u = 1;            /* either zero: the smallest positive float */
    else if (u >> 31)
        u--;              /* negative: one step towards zero */
    else if (t < INFINITY)
        u++;
    memcpy(&t, &u, sizeof t);
    return t;
}

/* Row `axis` of vertex `vert` in the pack at v. */
SIMD_INLINE vfloat tri_pack_row(const float *v, int vert, int axis)
{
    return vload(v + (3 * vert + axis) * SIMD_LANES);
}

/* The body of tri_pack_test. The arithmetic is the scalar test's; its
 * order in the source makes each vertex's sheared coordinates just before
 * their first use, so that fewer vectors are live at once (on 16 vector
 * registers the test spilled). A lane whose edge function is zero in single
 * precision is decided in double, as in the scalar test, only when `exact`;
 * otherwise the pack is left for the caller to redo with `exact` set, out
 * of line (-1): in line, the fallback's lane accesses kept every vector of
 * the test in memory, stored at each pack. */
SIMD_INLINE int tri_pack_eval(const float *v, const tri_ray *q, vfloat tmax, tri_pack_hits *out, bool exact)
{
    const int kx = q->k[0], ky = q->k[1], kz = q->k[2];
    const vfloat ox = vset1(q->org[0]), oy = vset1(q->org[1]), oz = vset1(q->org[2]);
    const vfloat sx = vset1(q->shear[0]), sy = vset1(q->shear[1]), sz = vset1(q->shear[2]);
    vfloat bz = tri_pack_row(v, 1, kz) - oz;
    vfloat bx = (tri_pack_row(v, 1, kx) - ox) - sx * bz;
    vfloat by = (tri_pack_row(v, 1, ky) - oy) - sy * bz;
    vfloat cz = tri_pack_row(v, 2, kz) - oz;
    vfloat cx = (tri_pack_row(v, 2, kx) - ox) - sx * cz;
    vfloat cy = (tri_pack_row(v, 2, ky) - oy) - sy * cz;
    vfloat u = cx * by - cy * bx;
    vfloat az = tri_pack_row(v, 0, kz) - oz;
    vfloat ax = (tri_pack_row(v, 0, kx) - ox) - sx * az;
    vfloat ay = (tri_pack_row(v, 0, ky) - oy) - sy * az;
    vfloat vv = ax * cy - ay * cx;
    vfloat w = bx * ay - by * ax;
    const vfloat zero = vset1(0.0f);
    int on_edge = vmask(vor(vor(veq(u, zero), veq(vv, zero)), veq(w, zero)));
    if (on_edge != 0) {
        if (!exact)
            return -1;
        for (int l = 0; l < SIMD_LANES; l++)
            if (on_edge & (1 << l)) {
                float U, V, W;
                arbor_edge_functions_exact(ax[l], ay[l], bx[l], by[l], cx[l], cy[l], &U, &V, &W);
                u[l] = U;
                vv[l] = V;
                w[l] = W;
            }
    }
    vfloat some_neg = vor(vor(vlt(u, zero), vlt(vv, zero)), vlt(w, zero));
    vfloat some_pos = vor(vor(vgt(u, zero), vgt(vv, zero)), vgt(w, zero));
    vfloat det = (u + vv) + w;
    vfloat T = ((u * sz) * az + (vv * sz) * bz) + (w * sz) * cz;
    vfloat inv = vset1(1.0f) / det;
    vfloat t = T * inv;
    /* det == 0 needs no test of its own: then inv is infinite and t is NaN
     * or infinite, outside (tmin, tmax) */
    vfloat hit = vandnot(vand(some_neg, some_pos), vand(vgt(t, vset1(q->tmin)), vlt(t, tmax)));
    out->t = t;
    out->v = vv;
    out->w = w;
    out->inv = inv;
    return vmask(hit);
}

/* The pack test with its edge lanes decided in double: rare, so out of
 * line. The ray comes by value, so that the caller's stays in registers,
 * and tmax by pointer, as simd.h passes no vector to a call. (`unused`: a
 * file may include this header for the other helpers alone.) */
static __attribute__((noinline, cold, unused)) int tri_pack_test_exact(const float *v, tri_ray q,
                                                                        const vfloat *tmax, tri_pack_hits *out)
{
    return tri_pack_eval(v, &q, *tmax, out, true);
}

/* Tests the pack at v against the ray in (tmin, tmax); returns the mask of
 * lanes hit (bit l for lane l) and fills *out. */
SIMD_INLINE int tri_pack_test(const float *v, const tri_ray *q, vfloat tmax, tri_pack_hits *out)
{
    int hits = tri_pack_eval(v, q, tmax, out, false);
    if (__builtin_expect(hits >= 0, 1))
        return hits;
    tri_pack_hits exact;
    hits = tri_pack_test_exact(v, *q, &tmax, &exact);
    *out = exact;
    return hits;
}

#endif
