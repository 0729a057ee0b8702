/*
 * ray.h - rays, hits, and the watertight ray/triangle test.
 *
 * A ray is valid for t in the open interval (tmin, tmax). A closest-hit query
 * that finds a triangle shrinks r->tmax to the hit distance and fills an
 * arbor_hit whose `tri` is the triangle's index in the mesh (never a tree's
 * internal order) and whose u, v are barycentric weights of the triangle's
 * second and third vertex.
 *
 * The triangle test is the watertight algorithm of Woop, Benthin and Wald
 * (JCGT 2013): the ray is sheared so its direction is the +z axis, and the
 * 2D edge functions are evaluated with a double-precision fallback when one
 * is exactly zero, so that a ray through a shared edge or vertex of a closed
 * mesh hits at least one of the triangles around it. arbor_ray_prep holds the
 * per-ray values (computed once per ray, not per triangle).
 */
#ifndef ARBOR_RAY_H
#define ARBOR_RAY_H

#include <stdbool.h>
#include <stdint.h>

#include "arbor/vec.h"

typedef struct {
    arbor_vec3 o;
    float tmin;
    arbor_vec3 d;
    float tmax;
} arbor_ray;

typedef struct {
    float t, u, v;
    uint32_t tri;
} arbor_hit;

/* The sizes of a model (its box's diagonal) for which the test stays exact
 * when rays come from a camera a few sizes away: its t is a quotient of
 * products of three coordinate differences, which past 2^40 overflow (rays
 * then miss every triangle) and below 2^-40 fall among float's subnormals
 * and lose bits. Loaders warn of a model outside them; the benchmark
 * refuses a scale that takes a model out. */
#define ARBOR_SIZE_MIN 0x1p-40f
#define ARBOR_SIZE_MAX 0x1p40f

static inline bool arbor_size_traceable(float diagonal)
{
    return diagonal >= ARBOR_SIZE_MIN && diagonal <= ARBOR_SIZE_MAX;
}

/* Per-ray constants of the watertight test. */
typedef struct {
    int kx, ky, kz;      /* axis permutation: kz is the dominant direction axis */
    float sx, sy, sz;    /* shear constants */
} arbor_ray_prep;

static inline float arbor__axis(arbor_vec3 v, int k) { return k == 0 ? v.x : (k == 1 ? v.y : v.z); }

static inline void arbor_ray_prepare(const arbor_ray *r, arbor_ray_prep *p)
{
    float ax = fabsf(r->d.x), ay = fabsf(r->d.y), az = fabsf(r->d.z);
    int kz = (ax > ay) ? (ax > az ? 0 : 2) : (ay > az ? 1 : 2);
    int kx = kz == 2 ? 0 : kz + 1;
    int ky = kx == 2 ? 0 : kx + 1;
    /* keep the winding: swap kx and ky when the dominant component is negative */
    if (arbor__axis(r->d, kz) < 0.0f) { int tmp = kx; kx = ky; ky = tmp; }
    p->kx = kx; p->ky = ky; p->kz = kz;
    float dz = arbor__axis(r->d, kz);
    p->sx = arbor__axis(r->d, kx) / dz;
    p->sy = arbor__axis(r->d, ky) / dz;
    p->sz = 1.0f / dz;
}

/* The edge functions U, V, W of the sheared triangle, in double precision:
 * what the test falls back to when one is exactly zero in single precision.
 * Shared by every triangle test, scalar or SIMD, so they decide edges alike. */
static inline void arbor_edge_functions_exact(float Ax, float Ay, float Bx, float By, float Cx, float Cy,
                                              float *U, float *V, float *W)
{
    *U = (float)((double)Cx * (double)By - (double)Cy * (double)Bx);
    *V = (float)((double)Ax * (double)Cy - (double)Ay * (double)Cx);
    *W = (float)((double)Bx * (double)Ay - (double)By * (double)Ax);
}

/* The body of both tests below. `bulk` says how to combine the edge
 * functions' signs: with || and && for a caller that mostly tests triangles
 * its ray is likely to hit (a tree's leaf: the short circuits are well
 * predicted and end early), with | and & for one that tests a ray against
 * triangle after triangle it mostly misses, in patterns of signs that
 * change from one to the next (brute force: there the short circuits'
 * branches mispredicted so often that it ran at two thirds the speed). The
 * arithmetic, and so every result, is the same either way. */
static inline bool arbor__triangle_test(const arbor_ray *r, const arbor_ray_prep *p, arbor_vec3 a, arbor_vec3 b,
                                        arbor_vec3 c, float tmax, float *t_out, float *u_out, float *v_out,
                                        bool bulk)
{
    const arbor_vec3 A = vec3_sub(a, r->o), B = vec3_sub(b, r->o), C = vec3_sub(c, r->o);
    const float Akz = arbor__axis(A, p->kz), Bkz = arbor__axis(B, p->kz), Ckz = arbor__axis(C, p->kz);
    const float Ax = arbor__axis(A, p->kx) - p->sx * Akz;
    const float Ay = arbor__axis(A, p->ky) - p->sy * Akz;
    const float Bx = arbor__axis(B, p->kx) - p->sx * Bkz;
    const float By = arbor__axis(B, p->ky) - p->sy * Bkz;
    const float Cx = arbor__axis(C, p->kx) - p->sx * Ckz;
    const float Cy = arbor__axis(C, p->ky) - p->sy * Ckz;
    float U = Cx * By - Cy * Bx;
    float V = Ax * Cy - Ay * Cx;
    float W = Bx * Ay - By * Ax;
    if (U == 0.0f || V == 0.0f || W == 0.0f) {
        /* on an edge in single precision: decide it exactly in double */
        arbor_edge_functions_exact(Ax, Ay, Bx, By, Cx, Cy, &U, &V, &W);
    }
    const bool mixed_signs = bulk ? ((U < 0.0f) | (V < 0.0f) | (W < 0.0f)) & ((U > 0.0f) | (V > 0.0f) | (W > 0.0f))
                                  : (U < 0.0f || V < 0.0f || W < 0.0f) && (U > 0.0f || V > 0.0f || W > 0.0f);
    if (mixed_signs)
        return false;
    const float det = U + V + W;
    if (det == 0.0f)
        return false;
    const float T = U * p->sz * Akz + V * p->sz * Bkz + W * p->sz * Ckz;
    const float inv = 1.0f / det;
    const float t = T * inv;
    if (!(t > r->tmin && t < tmax))
        return false;
    *t_out = t;
    *u_out = V * inv;
    *v_out = W * inv;
    return true;
}

/* Tests the triangle (a, b, c) against the ray for t in (r->tmin, tmax).
 * On a hit stores t and the barycentrics of b and c, and returns true. */
static inline bool arbor_triangle_intersect(const arbor_ray *r, const arbor_ray_prep *p,
                                            arbor_vec3 a, arbor_vec3 b, arbor_vec3 c,
                                            float tmax, float *t_out, float *u_out, float *v_out)
{
    return arbor__triangle_test(r, p, a, b, c, tmax, t_out, u_out, v_out, false);
}

/* arbor_triangle_intersect for a ray tested against many triangles in turn,
 * most of them missed (brute force): the same results, faster there. */
static inline bool arbor_triangle_intersect_bulk(const arbor_ray *r, const arbor_ray_prep *p,
                                                 arbor_vec3 a, arbor_vec3 b, arbor_vec3 c,
                                                 float tmax, float *t_out, float *u_out, float *v_out)
{
    return arbor__triangle_test(r, p, a, b, c, tmax, t_out, u_out, v_out, true);
}

#endif
