/*
 * brute.c - the brute-force intersector, the ground truth for every tree
 * (see include/arbor/brute.h).
 */
#include <assert.h>

#include "arbor/brute.h"
#include "arbor/sys.h"

bool arbor_brute_intersect(const arbor_mesh *m, arbor_ray *r, arbor_hit *h)
{
    arbor_ray_prep p;
    arbor_ray_prepare(r, &p);
    bool found = false;
    for (uint32_t i = 0; i < m->ntris; i++) {
        arbor_vec3 a, b, c;
        float t, u, v;
        arbor_mesh_tri(m, i, &a, &b, &c);
        /* the test takes t < tmax only, and tmax is the nearest hit so far:
         * a later (higher) index at the same t is not taken, so the lowest
         * index wins a tie (test_exact checks it by enumeration) */
        if (arbor_triangle_intersect_bulk(r, &p, a, b, c, r->tmax, &t, &u, &v)) {
            r->tmax = t;
            h->t = t;
            h->u = u;
            h->v = v;
            h->tri = i;
            found = true;
        }
    }
    return found;
}

bool arbor_brute_occluded(const arbor_mesh *m, const arbor_ray *r)
{
    arbor_ray_prep p;
    arbor_ray_prepare(r, &p);
    for (uint32_t i = 0; i < m->ntris; i++) {
        arbor_vec3 a, b, c;
        float t, u, v;
        arbor_mesh_tri(m, i, &a, &b, &c);
        if (arbor_triangle_intersect_bulk(r, &p, a, b, c, r->tmax, &t, &u, &v))
            return true;
    }
    return false;
}

/* Rays are traced in chunks of this many, each claimed by one thread. */
#define BRUTE_CHUNK 64

typedef struct {
    const arbor_mesh *m;
    const arbor_ray *rays;
    size_t n;
    arbor_hit *hit;
    bool *found;
} brute_pass;

static void brute_chunk(void *ctx, uint32_t chunk)
{
    const brute_pass *p = ctx;
    size_t begin = (size_t)chunk * BRUTE_CHUNK, end = begin + BRUTE_CHUNK < p->n ? begin + BRUTE_CHUNK : p->n;
    for (size_t i = begin; i < end; i++) {
        arbor_ray r = p->rays[i];
        p->found[i] = arbor_brute_intersect(p->m, &r, &p->hit[i]);
    }
}

void arbor_brute_intersect_many(arbor_pool *pool, const arbor_mesh *m, const arbor_ray *rays, size_t n,
                                arbor_hit *hit, bool *found, int threads)
{
    brute_pass pass = {m, rays, n, hit, found};
    size_t nchunks = (n + BRUTE_CHUNK - 1) / BRUTE_CHUNK;
    assert(nchunks <= UINT32_MAX);
    /* without a pool, one of its own for the call; if that cannot be
     * started, everything runs here: slower, never wrong */
    if (pool == NULL && threads <= 0)
        threads = arbor_cpu_count();
    arbor_pool *own = pool == NULL && threads > 1 ? arbor_pool_create(threads - 1, NULL) : NULL;
    arbor_pool_parallel(pool != NULL ? pool : own, (uint32_t)nchunks, threads > 0 ? (uint32_t)threads : 0,
                        brute_chunk, &pass);
    arbor_pool_destroy(own);
}
