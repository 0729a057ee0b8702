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

/* The model's diagonal |B.max - B.min| (PROTOCOL.md's d). */
static inline float sample_model_size(const arbor_mesh *m)
{
    return vec3_length(aabb_extent(m->bounds));
}

#endif
