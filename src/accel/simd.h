/*
 * simd.h - float vectors of SIMD_LANES lanes (4 or 8) for the traversal
 * kernels, written once for every instruction set a kernel is compiled
 * for (accel_impl.h): with AVX an 8-lane vector is one 256-bit register,
 * without it two 128-bit halves, and a 4-lane vector is one SSE register.
 *
 * Arithmetic uses GCC's vector operators (+ - * /), which map lane for
 * lane onto the instructions of the target; the rest (min, max, compares,
 * bitwise, movemask) goes through the intrinsics below, because GCC lowers
 * vector compares of 8 lanes without AVX into scalar code. min and max keep
 * the intrinsics' rule that matters to the slab tests: when the first
 * operand is NaN the result is the second.
 *
 * A translation unit defines SIMD_LANES before including this header, and
 * may include it once. Every function is inlined: an 8-lane vector passed
 * by value across a call without AVX would change the ABI (the kernels are
 * compiled with -Wno-psabi for that reason only).
 */
#ifndef ARBOR_SIMD_H
#define ARBOR_SIMD_H

#include <immintrin.h>

#if !defined(SIMD_LANES) || (SIMD_LANES != 4 && SIMD_LANES != 8)
#error "define SIMD_LANES as 4 or 8 before including simd.h"
#endif

#define SIMD_INLINE static inline __attribute__((always_inline))

typedef float vfloat __attribute__((vector_size(4 * SIMD_LANES)));

#if SIMD_LANES == 4
#define SIMD_OP(op, a, b) ((vfloat)_mm_##op##_ps((__m128)(a), (__m128)(b)))
#define SIMD_CMP(sse, avx, a, b) ((vfloat)_mm_cmp##sse##_ps((__m128)(a), (__m128)(b)))
SIMD_INLINE int vmask(vfloat m) { return _mm_movemask_ps((__m128)m); }
SIMD_INLINE vfloat vset1(float s) { return (vfloat){s, s, s, s}; }
#elif defined(__AVX__)
#define SIMD_OP(op, a, b) ((vfloat)_mm256_##op##_ps((__m256)(a), (__m256)(b)))
#define SIMD_CMP(sse, avx, a, b) ((vfloat)_mm256_cmp_ps((__m256)(a), (__m256)(b), avx))
SIMD_INLINE int vmask(vfloat m) { return _mm256_movemask_ps((__m256)m); }
SIMD_INLINE vfloat vset1(float s) { return (vfloat){s, s, s, s, s, s, s, s}; }
#else
typedef union {
    vfloat v;
    __m128 h[2];
} simd_halves;
/* fn applied to each 128-bit half of a and b */
#define SIMD_HALVES(fn, a, b)                      \
    __extension__({                                \
        simd_halves x_ = {a}, y_ = {b}, r_;        \
        r_.h[0] = fn(x_.h[0], y_.h[0]);            \
        r_.h[1] = fn(x_.h[1], y_.h[1]);            \
        r_.v;                                      \
    })
#define SIMD_OP(op, a, b) SIMD_HALVES(_mm_##op##_ps, a, b)
#define SIMD_CMP(sse, avx, a, b) SIMD_HALVES(_mm_cmp##sse##_ps, a, b)
SIMD_INLINE int vmask(vfloat m)
{
    simd_halves x = {m};
    return _mm_movemask_ps(x.h[0]) | _mm_movemask_ps(x.h[1]) << 4;
}
SIMD_INLINE vfloat vset1(float s) { return (vfloat){s, s, s, s, s, s, s, s}; }
#endif

SIMD_INLINE vfloat vmin(vfloat a, vfloat b) { return SIMD_OP(min, a, b); }
SIMD_INLINE vfloat vmax(vfloat a, vfloat b) { return SIMD_OP(max, a, b); }
SIMD_INLINE vfloat vand(vfloat a, vfloat b) { return SIMD_OP(and, a, b); }
SIMD_INLINE vfloat vor(vfloat a, vfloat b) { return SIMD_OP(or, a, b); }
/* ~a & b */
SIMD_INLINE vfloat vandnot(vfloat a, vfloat b) { return SIMD_OP(andnot, a, b); }
SIMD_INLINE vfloat vlt(vfloat a, vfloat b) { return SIMD_CMP(lt, _CMP_LT_OQ, a, b); }
SIMD_INLINE vfloat vle(vfloat a, vfloat b) { return SIMD_CMP(le, _CMP_LE_OQ, a, b); }
SIMD_INLINE vfloat vgt(vfloat a, vfloat b) { return SIMD_CMP(gt, _CMP_GT_OQ, a, b); }
SIMD_INLINE vfloat veq(vfloat a, vfloat b) { return SIMD_CMP(eq, _CMP_EQ_OQ, a, b); }

/* A row of SIMD_LANES floats, aligned to its size. */
SIMD_INLINE vfloat vload(const float *p)
{
    return *(const vfloat *)__builtin_assume_aligned(p, sizeof(vfloat));
}

#endif
