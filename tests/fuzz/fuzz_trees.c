/*
 * fuzz_trees.c - the eight tree builders (bvh and kd, each spatial, median,
 * mean, sah) on triangle soups decoded from the fuzzer's bytes, every tree
 * checked by arbor_accel_validate.
 *
 * The soups aim at what breaks tree builders: triangles far from the origin
 * (an offset of up to 2^47, where a float's step is 2^24), tiny or huge
 * next to each other, degenerate ones, and near-flat ones a few ulps thick,
 * which the k-d builder's clipper cuts into polygons in fixed-size buffers.
 *
 *   byte 0: the offset, 2^(b % 64 - 16) times (1, -0.75, 0.5)
 *   byte 1: the scale of the small coordinates, 2^(b % 48 - 24)
 *   then per triangle 10 bytes: a flag byte and nine signed bytes, the
 *   corners as offset + scale * (x, y, z). Flag bit 0: the third corner is
 *   the middle of the first two moved by (flag >> 1 & 7) ulps off their
 *   line (near-flat); bit 4: the first corner is the previous triangle's
 *   last (fans and shared edges).
 */
#include <math.h>
#include <string.h>

#include "arbor/accel.h"
#include "fuzz.h"

#define MAX_TRIS 96

static float nudge(float x, int ulps)
{
    for (int i = 0; i < ulps; i++)
        x = nextafterf(x, INFINITY);
    return x;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 12)
        return 0;
    float off = ldexpf(1.0f, data[0] % 64 - 16), scale = ldexpf(1.0f, data[1] % 48 - 24);
    arbor_vec3 o = {off, -0.75f * off, 0.5f * off};
    arbor_mesh m;
    arbor_mesh_init(&m);
    arbor_err e;
    for (size_t at = 2; at + 10 <= size && m.ntris < MAX_TRIS; at += 10) {
        const uint8_t *t = data + at;
        arbor_vec3 c[3];
        for (int k = 0; k < 3; k++) {
            const int8_t *s = (const int8_t *)t + 1 + 3 * k;
            c[k] = (arbor_vec3){o.x + scale * s[0], o.y + scale * s[1], o.z + scale * s[2]};
        }
        if ((t[0] & 1) != 0) {
            int ulps = t[0] >> 1 & 7;
            c[2] = (arbor_vec3){nudge(0.5f * (c[0].x + c[1].x), ulps), 0.5f * (c[0].y + c[1].y),
                                nudge(0.5f * (c[0].z + c[1].z), ulps)};
        }
        bool shared = (t[0] & 16) != 0 && m.nverts > 0;
        uint32_t base = m.nverts;
        for (int k = shared ? 1 : 0; k < 3; k++)
            FUZZ_CHECK(arbor_mesh_add_vert(&m, c[k], &e), "%s", e.msg);
        uint32_t first = shared ? base - 1 : base, second = shared ? base : base + 1;
        FUZZ_CHECK(arbor_mesh_add_tri(&m, first, second, second + 1, 0, &e), "%s", e.msg);
    }
    if (m.ntris == 0) {
        arbor_mesh_free(&m);
        return 0;
    }
    FUZZ_CHECK(arbor_mesh_finish(&m, &e), "%s", e.msg);
    for (int kind = 0; kind < ARBOR_ACCEL_KIND_COUNT; kind++)
        for (int b = 0; b < ARBOR_BUILDER_COUNT; b++) {
            arbor_build_opts opts;
            arbor_build_opts_init(&opts, (arbor_accel_kind)kind, (arbor_builder)b);
            opts.threads = 1;
            arbor_accel *a = arbor_accel_build(&m, &opts, &e);
            FUZZ_CHECK(a != NULL, "%s %s: build failed: %s", arbor_accel_kind_name(kind), arbor_builder_name(b),
                       e.msg);
            FUZZ_CHECK(arbor_accel_validate(a, &e), "%s %s: %s", arbor_accel_kind_name(kind), arbor_builder_name(b),
                       e.msg);
            arbor_accel_free(a);
        }
    arbor_mesh_free(&m);
    return 0;
}
