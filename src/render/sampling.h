/*
 * sampling.h - random numbers and hit geometry shared by the shading modes
 * (render.c) and PROTOCOL.md's ray sets (raysets.c); private to src/render.
 *
 * Random numbers are counter-based: a generator's state is a hash of the
 * values that identify one use (frame seed, pixel, sample index, or a ray's
 * index in a set), never of thread state, so an image or a ray set is the
 * same whichever thread computed which part of it.
 */
#ifndef ARBOR_RENDER_SAMPLING_H
#define ARBOR_RENDER_SAMPLING_H

#include <stdint.h>
#include <string.h>

#include "arbor/mesh.h"
#include "arbor/ray.h"
#include "arbor/vec.h"

/* splitmix64: a counter-based generator; its finaliser doubles as a hash. */
typedef struct { uint64_t state; } sample_rng;

static inline uint64_t sample_mix64(uint64_t z)
{
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    return z ^ (z >> 31);
}

/* A generator for the use identified by (a, b, c, d). */
static inline sample_rng sample_rng_for(uint64_t a, uint64_t b, uint64_t c, uint64_t d)
{
    uint64_t h = sample_mix64(a + 0x9e3779b97f4a7c15ULL);
    h = sample_mix64(h ^ (b + 0x632be59bd9b4e019ULL));
    h = sample_mix64(h ^ (c + 0x85157af5a1e9c0b3ULL));
    h = sample_mix64(h ^ (d + 0xd1b54a32d192ed03ULL));
    sample_rng g = {h};
    return g;
}

static inline uint64_t sample_next(sample_rng *g)
{
    g->state += 0x9e3779b97f4a7c15ULL;
    return sample_mix64(g->state);
}

/* Uniform in [0, 1): the top 24 bits, exactly representable as a float. */
static inline float sample_float(sample_rng *g)
{
    return (float)(sample_next(g) >> 40) * 0x1.0p-24f;
}

/* A cosine-weighted direction about the unit vector n (Malley's method on an
 * orthonormal basis by Duff et al. 2017, which has no branch on n's axis). */
static inline arbor_vec3 sample_cosine_dir(arbor_vec3 n, float u1, float u2)
{
    float sign = copysignf(1.0f, n.z);
    float a = -1.0f / (sign + n.z);
    float b = n.x * n.y * a;
    arbor_vec3 t = vec3(1.0f + sign * n.x * n.x * a, sign * b, -sign * n.x);
    arbor_vec3 s = vec3(b, sign + n.y * n.y * a, -n.y);
    float r = sqrtf(u1), phi = 6.28318530718f * u2;
    float x = r * cosf(phi), y = r * sinf(phi), z = sqrtf(fmaxf(0.0f, 1.0f - u1));
    return vec3_add(vec3_add(vec3_scale(t, x), vec3_scale(s, y)), vec3_scale(n, z));
}

/* Where a closest-hit query ended: the point, the unit geometric normal
 * turned to face the incoming ray, and the origin for secondary rays,
 * lifted off the surface by eps along that normal (PROTOCOL.md: p + 1e-4 d n). */
typedef struct {
    arbor_vec3 p, n, origin;
} sample_surface;

static inline sample_surface sample_surface_at(const arbor_mesh *m, const arbor_ray *r, const arbor_hit *h,
                                               float eps)
{
    sample_surface s;
    s.p = vec3_add(r->o, vec3_scale(r->d, h->t));
    s.n = vec3_normalize(arbor_mesh_tri_normal(m, h->tri));
    if (vec3_dot(s.n, r->d) > 0.0f)
        s.n = vec3_scale(s.n, -1.0f);
    s.origin = vec3_add(s.p, vec3_scale(s.n, eps));
    return s;
}

/* ---- the renderer's robust offset ----
 *
 * PROTOCOL.md's p + 1e-4 d n above serves the benchmark's ray sets, which
 * must be the same for every tracer. Its hit point o + t d carries an error
 * proportional to |o| + t |d|, and its lift is fixed in units of the model:
 * far from the origin (a model of diagonal 20 at 1e5, where floats are 2^-7
 * apart) the lift rounds away and about half the shadow rays hit their own
 * triangle, while a fixed lift wider than a gap lets light through it. The
 * renderer instead rebuilds the hit point from the triangle's corners and
 * offsets it by a few ulps of its own coordinates (Waechter & Binder, "A Fast
 * and Robust Method for Avoiding Self-Intersection", Ray Tracing Gems ch. 6). */

/* The hit point as the barycentric mix w a + u b + v c of the corners: an
 * affine combination of the corners lies on their plane whatever the error in
 * (u, v), so it is off the plane only by the rounding of this sum, a few ulps
 * of the corners' coordinates, however far the ray came. *normal gets the
 * triangle's unnormalised geometric normal (b - a) x (c - a), as
 * arbor_mesh_tri_normal gives it, from the same fetch of the corners. */
static inline arbor_vec3 sample_hit_point(const arbor_mesh *m, const arbor_hit *h, arbor_vec3 *normal)
{
    arbor_vec3 a, b, c;
    arbor_mesh_tri(m, h->tri, &a, &b, &c);
    *normal = vec3_cross(vec3_sub(b, a), vec3_sub(c, a));
    float w = 1.0f - h->u - h->v;
    return vec3_add(vec3_add(vec3_scale(a, w), vec3_scale(b, h->u)), vec3_scale(c, h->v));
}

/* Waechter & Binder's constants: 256 ulps per unit of the normal, and, for
 * coordinates below 1/32 where ulps shrink toward zero faster than the error
 * (which follows the corners, not the point), a fixed 1/65536 instead. The
 * two fallback constants assume a scene of about unit size; here they are in
 * units of s_i, per axis the largest |coordinate| the model reaches, which
 * bounds the corners' and so the error's size near zero. A model thus gets
 * the same offsets, and the same image, in any unit: scaled by a power of two
 * every offset scales exactly with it. s_i is at least d / 1024 so that a
 * model flat on an axis plane (s_i = 0, p_i exactly 0) still steps off it by
 * a normal float rather than by denormals. */
#define SAMPLE_OFFSET_ULPS 256.0f
#define SAMPLE_OFFSET_NEAR (1.0f / 32.0f)
#define SAMPLE_OFFSET_STEP (1.0f / 65536.0f)

typedef struct {
    arbor_vec3 near;  /* |p_i| below near_i: offset by step_i n_i instead of ulps */
    arbor_vec3 step;
} sample_offset_scale;

static inline float sample__max3(float a, float b, float c)
{
    float m = a > b ? a : b;
    return m > c ? m : c;
}

static inline sample_offset_scale sample_offset_scale_of(const arbor_mesh *m)
{
    float floor = vec3_length(aabb_extent(m->bounds)) * 0x1p-10f;
    arbor_vec3 lo = m->bounds.lo, hi = m->bounds.hi;
    arbor_vec3 s = vec3(sample__max3(fabsf(lo.x), fabsf(hi.x), floor), sample__max3(fabsf(lo.y), fabsf(hi.y), floor),
                        sample__max3(fabsf(lo.z), fabsf(hi.z), floor));
    sample_offset_scale o = {vec3_scale(s, SAMPLE_OFFSET_NEAR), vec3_scale(s, SAMPLE_OFFSET_STEP)};
    return o;
}

/* p moved k ulps toward +infinity (k < 0: toward -infinity), through its
 * bits: floats of one sign are ordered as their integer bits (magnitudes). */
static inline float sample__ulps(float p, int32_t k)
{
    int32_t bits;
    memcpy(&bits, &p, sizeof bits);
    bits += p < 0.0f ? -k : k;
    memcpy(&p, &bits, sizeof p);
    return p;
}

static inline float sample__offset1(float p, float n, float near, float step)
{
    if (fabsf(p) < near)
        return p + step * n;
    return sample__ulps(p, (int32_t)(SAMPLE_OFFSET_ULPS * n));
}

/* The origin of a ray leaving the surface at p (from sample_hit_point) on the
 * side the unit geometric normal n points to. */
static inline arbor_vec3 sample_offset_ray(arbor_vec3 p, arbor_vec3 n, const sample_offset_scale *s)
{
    return vec3(sample__offset1(p.x, n.x, s->near.x, s->step.x), sample__offset1(p.y, n.y, s->near.y, s->step.y),
                sample__offset1(p.z, n.z, s->near.z, s->step.z));
}

/* The model's diagonal |B.max - B.min| (PROTOCOL.md's d). */
static inline float sample_model_size(const arbor_mesh *m)
{
    return vec3_length(aabb_extent(m->bounds));
}

#endif
