/* support.c - shared unit-test helpers (see support.h). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "arbor/brute.h"
#include "arbor/camera.h"
#include "support.h"

const char *test_shared_model(const char *file)
{
    static char path[1024];
    const char *dir = getenv("ARBOR_SHARED_MODELS");
    snprintf(path, sizeof path, "%s/%s", dir ? dir : "../shared/models", file);
    return path;
}

const char *test_repo_model(const char *file)
{
    static char path[1024];
    snprintf(path, sizeof path, "models/%s", file);
    return path;
}

void test_rng_seed(test_rng *g, uint64_t seed)
{
    g->state = 0;
    g->inc = (seed << 1u) | 1u;
    test_rng_u32(g);
    g->state += 0x853c49e6748fea9bULL ^ seed;
    test_rng_u32(g);
}

uint32_t test_rng_u32(test_rng *g)
{
    uint64_t old = g->state;
    g->state = old * 6364136223846793005ULL + g->inc;
    uint32_t xorshifted = (uint32_t)(((old >> 18u) ^ old) >> 27u);
    uint32_t rot = (uint32_t)(old >> 59u);
    return (xorshifted >> rot) | (xorshifted << ((-rot) & 31));
}

float test_rng_float(test_rng *g)
{
    return (float)(test_rng_u32(g) >> 8) * (1.0f / 16777216.0f);
}

static arbor_vec3 random_direction(test_rng *g)
{
    float z = 2.0f * test_rng_float(g) - 1.0f;
    float phi = 6.28318530718f * test_rng_float(g);
    float s = sqrtf(fmaxf(0.0f, 1.0f - z * z));
    return vec3(s * cosf(phi), s * sinf(phi), z);
}

arbor_ray *test_random_rays(const arbor_mesh *m, size_t n, uint64_t seed)
{
    arbor_ray *rays = malloc(n * sizeof *rays);
    test_rng g;
    test_rng_seed(&g, seed);
    arbor_vec3 ext = aabb_extent(m->bounds);
    float pad = 0.5f * vec3_length(ext);
    arbor_vec3 lo = vec3_sub(m->bounds.lo, vec3(pad, pad, pad));
    arbor_vec3 size = vec3_add(ext, vec3(2 * pad, 2 * pad, 2 * pad));
    for (size_t i = 0; i < n; i++) {
        arbor_vec3 o = vec3(lo.x + size.x * test_rng_float(&g), lo.y + size.y * test_rng_float(&g),
                            lo.z + size.z * test_rng_float(&g));
        /* half the rays aim at a random point inside the bounds, so most of them hit */
        arbor_vec3 d;
        if (i & 1) {
            arbor_vec3 p = vec3(m->bounds.lo.x + ext.x * test_rng_float(&g),
                                m->bounds.lo.y + ext.y * test_rng_float(&g),
                                m->bounds.lo.z + ext.z * test_rng_float(&g));
            d = vec3_sub(p, o);
            if (vec3_length(d) == 0.0f)
                d = random_direction(&g);
            d = vec3_normalize(d);
        } else {
            d = random_direction(&g);
        }
        arbor_ray r = {o, 0.0f, d, INFINITY};
        rays[i] = r;
    }
    return rays;
}

void test_random_soup(arbor_mesh *m, uint32_t n, uint64_t seed)
{
    test_rng g;
    test_rng_seed(&g, seed);
    arbor_mesh_init(m);
    for (uint32_t i = 0; i < n; i++) {
        arbor_vec3 c = vec3(test_rng_float(&g), test_rng_float(&g), test_rng_float(&g));
        /* sizes from 1e-3 to 0.3 of the cube, log-uniform */
        float s = 1e-3f * powf(300.0f, test_rng_float(&g));
        for (int k = 0; k < 3; k++) {
            arbor_vec3 p = vec3_add(c, vec3_scale(random_direction(&g), s));
            arbor_mesh_add_vert(m, p, NULL);
        }
        arbor_mesh_add_tri(m, 3 * i, 3 * i + 1, 3 * i + 2, 0, NULL);
    }
    arbor_mesh_finish(m, NULL);
}

arbor_ray *test_protocol_rays(const arbor_mesh *m, int stride, size_t *n)
{
    arbor_camera cam;
    arbor_camera_protocol(&cam, m->bounds, 1024, 768);
    size_t count = (size_t)((1024 + stride - 1) / stride) * (size_t)((768 + stride - 1) / stride);
    arbor_ray *rays = malloc(count * sizeof *rays);
    size_t k = 0;
    for (int y = 0; y < 768; y += stride)
        for (int x = 0; x < 1024; x += stride)
            rays[k++] = arbor_camera_ray(&cam, (float)x + 0.5f, (float)y + 0.5f);
    *n = k;
    return rays;
}

int test_close(float a, float b, float rel)
{
    return fabsf(a - b) <= rel * fmaxf(fabsf(a), fabsf(b));
}

arbor_vec3 *test_vertices_and_edge_midpoints(const arbor_mesh *m, size_t *n)
{
    arbor_vec3 *targets = malloc((m->nverts + 3 * (size_t)m->ntris) * sizeof *targets);
    if (targets == NULL)
        abort();
    memcpy(targets, m->verts, m->nverts * sizeof *targets);
    *n = m->nverts;
    for (uint32_t t = 0; t < m->ntris; t++)
        for (int k = 0; k < 3; k++) {
            uint32_t a = m->tri_verts[3 * t + k], b = m->tri_verts[3 * t + (k + 1) % 3];
            if (a < b)
                targets[(*n)++] = vec3_scale(vec3_add(m->verts[a], m->verts[b]), 0.5f);
        }
    return targets;
}

arbor_ray *test_aimed_rays(const arbor_vec3 *origins, size_t norigins, const arbor_vec3 *targets, size_t ntargets)
{
    arbor_ray *rays = malloc(norigins * ntargets * sizeof *rays);
    if (rays == NULL)
        abort();
    for (size_t o = 0; o < norigins; o++)
        for (size_t t = 0; t < ntargets; t++) {
            arbor_ray r = {origins[o], 0.0f, vec3_sub(targets[t], origins[o]), INFINITY};
            rays[o * ntargets + t] = r;
        }
    return rays;
}

void test_truth_compute(test_truth *ts, const arbor_mesh *m, arbor_ray *rays, size_t n)
{
    ts->rays = rays;
    ts->n = n;
    ts->hit = malloc((n ? n : 1) * sizeof *ts->hit);
    ts->found = malloc((n ? n : 1) * sizeof *ts->found);
    if (ts->hit == NULL || ts->found == NULL) {
        fprintf(stderr, "test_truth_compute: out of memory for %zu rays\n", n);
        abort();
    }
    arbor_brute_intersect_many(NULL, m, rays, n, ts->hit, ts->found, 0);
}

size_t test_truth_hits(const test_truth *ts)
{
    size_t hits = 0;
    for (size_t i = 0; i < ts->n; i++)
        hits += ts->found[i];
    return hits;
}

void test_truth_free(test_truth *ts)
{
    free(ts->rays);
    free(ts->hit);
    free(ts->found);
    memset(ts, 0, sizeof *ts);
}
