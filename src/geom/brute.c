/*
 * brute.c - the brute-force intersector, the ground truth for every tree
 * (see include/arbor/brute.h).
 */
#include <pthread.h>
#include <stdlib.h>

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
        if (arbor_triangle_intersect(r, &p, a, b, c, r->tmax, &t, &u, &v)) {
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
        if (arbor_triangle_intersect(r, &p, a, b, c, r->tmax, &t, &u, &v))
            return true;
    }
    return false;
}

typedef struct {
    const arbor_mesh *m;
    const arbor_ray *rays;
    arbor_hit *hit;
    bool *found;
    size_t begin, end;
} brute_slice;

static void *brute_slice_run(void *arg)
{
    brute_slice *s = arg;
    for (size_t i = s->begin; i < s->end; i++) {
        arbor_ray r = s->rays[i];
        s->found[i] = arbor_brute_intersect(s->m, &r, &s->hit[i]);
    }
    return NULL;
}

void arbor_brute_intersect_many(arbor_pool *pool, const arbor_mesh *m, const arbor_ray *rays, size_t n,
                                arbor_hit *hit, bool *found, int threads)
{
    (void)pool; /* not used yet: the pool's parallel-for comes next */
    if (threads <= 0)
        threads = arbor_cpu_count();
    if ((size_t)threads > n)
        threads = n > 0 ? (int)n : 1;
    brute_slice *slices = calloc((size_t)threads, sizeof *slices);
    pthread_t *tids = calloc((size_t)threads, sizeof *tids);
    bool *started = calloc((size_t)threads, sizeof *started);
    if (slices == NULL || tids == NULL || started == NULL) {
        brute_slice all = {m, rays, hit, found, 0, n};
        brute_slice_run(&all);
    } else {
        for (int k = 0; k < threads; k++) {
            brute_slice s = {m, rays, hit, found, n * (size_t)k / (size_t)threads,
                             n * (size_t)(k + 1) / (size_t)threads};
            slices[k] = s;
            started[k] = pthread_create(&tids[k], NULL, brute_slice_run, &slices[k]) == 0;
            if (!started[k])
                brute_slice_run(&slices[k]);
        }
        for (int k = 0; k < threads; k++)
            if (started[k])
                pthread_join(tids[k], NULL);
    }
    free(slices);
    free(tids);
    free(started);
}
