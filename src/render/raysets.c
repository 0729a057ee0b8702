/*
 * raysets.c - PROTOCOL.md's ray sets and the timed pass loop shared by every
 * tracer (see include/arbor/raysets.h).
 *
 * A pass splits the set into chunks of ARBOR_TRACE_CHUNK rays; thread k
 * traces chunks k, k + T, k + 2T, ... and writes each chunk's tally to its
 * own slot, summed in chunk order after the join. The calling thread is
 * thread 0, so a 1-thread pass starts no thread at all.
 */
#include <pthread.h>
#include <stdlib.h>
#include <string.h>

#include "arbor/camera.h"
#include "arbor/raysets.h"
#include "arbor/sys.h"
#include "sampling.h"

#define PROTOCOL_EPS 1e-4f
#define MAX_TRACE_THREADS 256

bool arbor_raysets_primary(const arbor_mesh *m, arbor_raysets *s, arbor_err *e)
{
    memset(s, 0, sizeof *s);
    arbor_camera cam;
    arbor_camera_protocol(&cam, m->bounds, ARBOR_PROTOCOL_WIDTH, ARBOR_PROTOCOL_HEIGHT);
    s->size = sample_model_size(m);
    s->light = vec3_add(cam.eye, vec3_scale(cam.up, 0.5f * s->size));
    size_t n = (size_t)ARBOR_PROTOCOL_WIDTH * ARBOR_PROTOCOL_HEIGHT;
    s->primary = malloc(n * sizeof *s->primary);
    if (s->primary == NULL)
        return arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory for %zu primary rays", n);
    for (int y = 0; y < ARBOR_PROTOCOL_HEIGHT; y++)
        for (int x = 0; x < ARBOR_PROTOCOL_WIDTH; x++)
            s->primary[(size_t)y * ARBOR_PROTOCOL_WIDTH + (size_t)x] =
                arbor_camera_ray(&cam, (float)x + 0.5f, (float)y + 0.5f);
    s->nprimary = n;
    return true;
}

bool arbor_raysets_secondary(const arbor_mesh *m, arbor_raysets *s, const arbor_hit *hits, const bool *found,
                             uint64_t seed, arbor_err *e)
{
    size_t nhits = 0;
    for (size_t i = 0; i < s->nprimary; i++)
        nhits += found[i];
    free(s->diffuse);
    free(s->shadow);
    s->ndiffuse = s->nshadow = 0;
    s->diffuse = malloc((nhits ? nhits : 1) * sizeof *s->diffuse);
    s->shadow = malloc((nhits ? nhits : 1) * sizeof *s->shadow);
    if (s->diffuse == NULL || s->shadow == NULL)
        return arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory for %zu secondary rays", 2 * nhits);
    float eps = PROTOCOL_EPS * s->size;
    for (size_t i = 0; i < s->nprimary; i++) {
        if (!found[i])
            continue;
        sample_surface surf = sample_surface_at(m, &s->primary[i], &hits[i], eps);
        sample_rng g = sample_rng_for(seed, i, 0, 0);
        float u1 = sample_float(&g), u2 = sample_float(&g);
        arbor_ray diffuse = {surf.origin, 0.0f, sample_cosine_dir(surf.n, u1, u2), INFINITY};
        arbor_ray shadow = {surf.origin, 0.0f, vec3_sub(s->light, surf.origin), 1.0f};
        s->diffuse[s->ndiffuse++] = diffuse;
        s->shadow[s->nshadow++] = shadow;
    }
    return true;
}

void arbor_raysets_free(arbor_raysets *s)
{
    free(s->primary);
    free(s->diffuse);
    free(s->shadow);
    memset(s, 0, sizeof *s);
}

void arbor_accel_kernel(const void *tracer, const arbor_ray *rays, size_t n, bool any_hit, arbor_tally *t)
{
    const arbor_accel *a = tracer;
    uint64_t hits = 0;
    double tsum = 0.0;
    if (any_hit) {
        for (size_t i = 0; i < n; i++)
            hits += arbor_accel_occluded(a, &rays[i]);
    } else {
        for (size_t i = 0; i < n; i++) {
            arbor_ray r = rays[i];
            arbor_hit h;
            if (arbor_accel_intersect(a, &r, &h)) {
                hits++;
                tsum += h.t;
            }
        }
    }
    t->hits += hits;
    t->tsum += tsum;
}

/* ---- running chunks on threads ---- */

typedef struct {
    void (*chunk_fn)(void *ctx, size_t chunk);
    void *ctx;
    size_t nchunks;
    int threads;
} chunk_plan;

typedef struct {
    const chunk_plan *plan;
    int k;
} chunk_worker;

static void *chunk_worker_run(void *arg)
{
    const chunk_worker *w = arg;
    const chunk_plan *p = w->plan;
    for (size_t c = (size_t)w->k; c < p->nchunks; c += (size_t)p->threads)
        p->chunk_fn(p->ctx, c);
    return NULL;
}

/* Runs every chunk once, thread k taking chunks k, k + T, ... */
static bool run_chunks(chunk_plan *plan, arbor_err *e)
{
    if (plan->threads <= 0)
        plan->threads = arbor_cpu_count();
    if (plan->threads > MAX_TRACE_THREADS)
        return arbor_fail(e, ARBOR_ERR_INVALID, "at most %d tracing threads, not %d", MAX_TRACE_THREADS,
                          plan->threads);
    if ((size_t)plan->threads > plan->nchunks)
        plan->threads = plan->nchunks > 0 ? (int)plan->nchunks : 1;
    chunk_worker workers[MAX_TRACE_THREADS];
    pthread_t tids[MAX_TRACE_THREADS];
    int started = 1;
    bool ok = true;
    for (int k = 0; k < plan->threads; k++) {
        workers[k].plan = plan;
        workers[k].k = k;
    }
    for (int k = 1; k < plan->threads; k++, started++)
        if (pthread_create(&tids[k], NULL, chunk_worker_run, &workers[k]) != 0) {
            ok = arbor_fail(e, ARBOR_ERR_NOMEM, "cannot start tracing thread %d of %d", k + 1, plan->threads);
            break;
        }
    if (ok)
        chunk_worker_run(&workers[0]);
    for (int k = 1; k < started; k++)
        pthread_join(tids[k], NULL);
    return ok;
}

/* The rays [begin, end) of chunk number `chunk` of a set of n rays. */
static void chunk_range(size_t chunk, size_t n, size_t *begin, size_t *end)
{
    *begin = chunk * ARBOR_TRACE_CHUNK;
    *end = *begin + ARBOR_TRACE_CHUNK < n ? *begin + ARBOR_TRACE_CHUNK : n;
}

static size_t chunk_count(size_t n)
{
    return (n + ARBOR_TRACE_CHUNK - 1) / ARBOR_TRACE_CHUNK;
}

/* ---- tracing and timing sets ---- */

typedef struct {
    arbor_trace_kernel kernel;
    const void *tracer;
    const arbor_ray *rays;
    size_t n;
    bool any_hit;
    arbor_tally *chunk_tallies; /* one slot per chunk, each written by one thread */
} set_pass;

static void set_pass_chunk(void *ctx, size_t chunk)
{
    set_pass *p = ctx;
    size_t begin, end;
    chunk_range(chunk, p->n, &begin, &end);
    arbor_tally t = {0, 0.0};
    p->kernel(p->tracer, p->rays + begin, end - begin, p->any_hit, &t);
    p->chunk_tallies[chunk] = t;
}

static bool run_pass(set_pass *pass, int threads, arbor_tally *tally, arbor_err *e)
{
    chunk_plan plan = {set_pass_chunk, pass, chunk_count(pass->n), threads};
    if (!run_chunks(&plan, e))
        return false;
    tally->hits = 0;
    tally->tsum = 0.0;
    for (size_t c = 0; c < plan.nchunks; c++) {
        tally->hits += pass->chunk_tallies[c].hits;
        tally->tsum += pass->chunk_tallies[c].tsum;
    }
    return true;
}

static bool pass_init(set_pass *pass, arbor_trace_kernel kernel, const void *tracer, const arbor_ray *rays,
                      size_t n, bool any_hit, arbor_err *e)
{
    set_pass p = {kernel, tracer, rays, n, any_hit, calloc(chunk_count(n) + 1, sizeof(arbor_tally))};
    *pass = p;
    if (pass->chunk_tallies == NULL)
        return arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory tracing %zu rays", n);
    return true;
}

bool arbor_trace_set(arbor_pool *pool, arbor_trace_kernel kernel, const void *tracer, const arbor_ray *rays, size_t n,
                     bool any_hit, int threads, arbor_tally *tally, arbor_err *e)
{
    (void)pool; /* not used yet: the pool's parallel-for comes next */
    set_pass pass;
    if (!pass_init(&pass, kernel, tracer, rays, n, any_hit, e))
        return false;
    bool ok = run_pass(&pass, threads, tally, e);
    free(pass.chunk_tallies);
    return ok;
}

bool arbor_time_set(arbor_pool *pool, arbor_trace_kernel kernel, const void *tracer, const arbor_ray *rays, size_t n,
                    bool any_hit, int threads, double min_ms, arbor_set_timing *out, arbor_err *e)
{
    (void)pool; /* not used yet: the pool's parallel-for comes next */
    set_pass pass;
    if (!pass_init(&pass, kernel, tracer, rays, n, any_hit, e))
        return false;
    memset(out, 0, sizeof *out);
    bool ok = true;
    double start = arbor_now_ms();
    do {
        ok = run_pass(&pass, threads, &out->tally, e);
        out->passes++;
        out->ms = arbor_now_ms() - start;
    } while (ok && out->ms < min_ms);
    free(pass.chunk_tallies);
    out->mrays_per_s = out->ms > 0.0 ? (double)n * out->passes / (out->ms * 1e3) : 0.0;
    return ok;
}

/* ---- the reference trace ---- */

typedef struct {
    const arbor_accel *a;
    const arbor_ray *rays;
    size_t n;
    arbor_hit *hits;
    bool *found;
} hits_pass;

static void hits_pass_chunk(void *ctx, size_t chunk)
{
    hits_pass *p = ctx;
    size_t begin, end;
    chunk_range(chunk, p->n, &begin, &end);
    for (size_t i = begin; i < end; i++) {
        arbor_ray r = p->rays[i];
        p->found[i] = arbor_accel_intersect(p->a, &r, &p->hits[i]);
    }
}

bool arbor_accel_trace_hits(arbor_pool *pool, const arbor_accel *a, const arbor_ray *rays, size_t n, int threads,
                            arbor_hit *hits, bool *found, arbor_err *e)
{
    (void)pool; /* not used yet: the pool's parallel-for comes next */
    hits_pass pass = {a, rays, n, hits, found};
    chunk_plan plan = {hits_pass_chunk, &pass, chunk_count(n), threads};
    return run_chunks(&plan, e);
}
