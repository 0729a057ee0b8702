/*
 * vec.h - 3-vectors and axis-aligned boxes in single precision.
 *
 * Everything here is a small value type with static inline operations, so the
 * hot paths (traversal, intersection) can use them without calls. Axis 0, 1, 2
 * is x, y, z throughout arbor.
 */
#ifndef ARBOR_VEC_H
#define ARBOR_VEC_H

#include <float.h>
#include <math.h>
#include <stdbool.h>
#include <stdint.h>
#include <string.h>

typedef struct { float x, y, z; } arbor_vec3;

typedef struct { arbor_vec3 lo, hi; } arbor_aabb;

static inline arbor_vec3 vec3(float x, float y, float z) { arbor_vec3 v = {x, y, z}; return v; }
static inline arbor_vec3 vec3_add(arbor_vec3 a, arbor_vec3 b) { return vec3(a.x + b.x, a.y + b.y, a.z + b.z); }
static inline arbor_vec3 vec3_sub(arbor_vec3 a, arbor_vec3 b) { return vec3(a.x - b.x, a.y - b.y, a.z - b.z); }
static inline arbor_vec3 vec3_mul(arbor_vec3 a, arbor_vec3 b) { return vec3(a.x * b.x, a.y * b.y, a.z * b.z); }
static inline arbor_vec3 vec3_scale(arbor_vec3 a, float s) { return vec3(a.x * s, a.y * s, a.z * s); }
static inline float vec3_dot(arbor_vec3 a, arbor_vec3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
static inline arbor_vec3 vec3_cross(arbor_vec3 a, arbor_vec3 b)
{
    return vec3(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x);
}
static inline float vec3_length(arbor_vec3 a) { return sqrtf(vec3_dot(a, a)); }
static inline bool vec3_finite(arbor_vec3 a) { return isfinite(a.x) && isfinite(a.y) && isfinite(a.z); }
/* a / |a| when |a|^2 overflows or underflows (the cross products of edges
 * of huge or tiny triangles: a model at 1e13 or 1e-13): a is first scaled
 * by the power of two that brings its largest component into [1, 2),
 * exactly for every component that stays a normal float. A largest
 * component that is zero, subnormal, not finite or 2^127 and more is left
 * to the plain formula. */
static inline arbor_vec3 vec3_normalize_scaled(arbor_vec3 a)
{
    float big = fabsf(a.x) > fabsf(a.y) ? fabsf(a.x) : fabsf(a.y);
    big = big > fabsf(a.z) ? big : fabsf(a.z);
    uint32_t bits;
    memcpy(&bits, &big, sizeof bits);
    uint32_t biased = bits >> 23; /* big is not negative: its exponent, biased by 127 */
    if (biased > 0 && biased < 254) {
        uint32_t inverse = (254 - biased) << 23; /* 2^(127 - biased): 1 / big's power of two */
        float down;
        memcpy(&down, &inverse, sizeof down);
        a = vec3_scale(a, down);
    }
    return vec3_scale(a, 1.0f / vec3_length(a));
}

/* a / |a|: the plain formula where |a|^2 is a normal float (every vector
 * of a model of sensible size), else vec3_normalize_scaled. */
static inline arbor_vec3 vec3_normalize(arbor_vec3 a)
{
    float len2 = vec3_dot(a, a);
    if (len2 >= FLT_MIN && len2 <= FLT_MAX)
        return vec3_scale(a, 1.0f / sqrtf(len2));
    return vec3_normalize_scaled(a);
}
/* Compare-and-select rather than fminf/fmaxf: those are libm calls unless
 * NaNs are ruled out at compile time, and these run in builders' inner loops.
 * Coordinates are never NaN (the loaders reject them). */
static inline float arbor_minf(float a, float b) { return a < b ? a : b; }
static inline float arbor_maxf(float a, float b) { return a > b ? a : b; }
static inline arbor_vec3 vec3_min(arbor_vec3 a, arbor_vec3 b)
{
    return vec3(arbor_minf(a.x, b.x), arbor_minf(a.y, b.y), arbor_minf(a.z, b.z));
}
static inline arbor_vec3 vec3_max(arbor_vec3 a, arbor_vec3 b)
{
    return vec3(arbor_maxf(a.x, b.x), arbor_maxf(a.y, b.y), arbor_maxf(a.z, b.z));
}
static inline float vec3_axis(arbor_vec3 a, int axis) { return axis == 0 ? a.x : axis == 1 ? a.y : a.z; }
static inline int vec3_max_axis(arbor_vec3 a)
{
    return (a.x >= a.y && a.x >= a.z) ? 0 : (a.y >= a.z ? 1 : 2);
}

/* The empty box: lo = +inf, hi = -inf, so that growing it by any point works. */
static inline arbor_aabb aabb_empty(void)
{
    arbor_aabb b = {vec3(INFINITY, INFINITY, INFINITY), vec3(-INFINITY, -INFINITY, -INFINITY)};
    return b;
}
static inline arbor_aabb aabb_grow(arbor_aabb b, arbor_vec3 p)
{
    b.lo = vec3_min(b.lo, p);
    b.hi = vec3_max(b.hi, p);
    return b;
}
static inline arbor_aabb aabb_union(arbor_aabb a, arbor_aabb b)
{
    a.lo = vec3_min(a.lo, b.lo);
    a.hi = vec3_max(a.hi, b.hi);
    return a;
}
static inline int aabb_is_empty(arbor_aabb b) { return !(b.lo.x <= b.hi.x && b.lo.y <= b.hi.y && b.lo.z <= b.hi.z); }
static inline arbor_vec3 aabb_extent(arbor_aabb b) { return vec3_sub(b.hi, b.lo); }
static inline arbor_vec3 aabb_center(arbor_aabb b) { return vec3_scale(vec3_add(b.lo, b.hi), 0.5f); }
/* Surface area; 0 for an empty box. */
static inline float aabb_area(arbor_aabb b)
{
    if (aabb_is_empty(b)) return 0.0f;
    arbor_vec3 e = aabb_extent(b);
    return 2.0f * (e.x * e.y + e.y * e.z + e.z * e.x);
}
static inline int aabb_contains(arbor_aabb outer, arbor_aabb inner)
{
    return outer.lo.x <= inner.lo.x && outer.lo.y <= inner.lo.y && outer.lo.z <= inner.lo.z &&
           outer.hi.x >= inner.hi.x && outer.hi.y >= inner.hi.y && outer.hi.z >= inner.hi.z;
}

#endif
