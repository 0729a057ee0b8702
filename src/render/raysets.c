/*
 * raysets.c - PROTOCOL.md's ray sets and the timed pass loop shared by every
 * tracer (see include/arbor/raysets.h).
 *
 * A pass splits the set into chunks of ARBOR_TRACE_CHUNK rays, a parallel
 * loop on the pool over the chunks: each thread claims the next chunk not
 * yet traced and writes its tally to the chunk's own slot, summed in chunk
 * order after the loop. The calling thread is one of the threads, so a
 * 1-thread pass uses no pool at all.
 */
#include <stdlib.h>
#include <string.h>

#include "arbor/camera.h"
#include "arbor/raysets.h"
#include "arbor/sys.h"
#include "sampling.h"

#define PROTOCOL_EPS 1e-4f

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

/* ---- the threads a pass runs on ---- */

/* A pass runs on the caller and up to threads - 1 workers of `pool`, which
 * is the caller's or, when the caller has none, `own`, started for the
 * call: a benchmark measuring N threads gets N, the caller the Nth. */
typedef struct {
    arbor_pool *pool, *own;
    uint32_t threads;  /* 0: as many as the pool has */
} trace_threads;

static bool trace_threads_init(trace_threads *t, arbor_pool *pool, int threads, arbor_err *e)
{
    t->pool = pool;
    t->own = NULL;
    t->threads = threads > 0 ? (uint32_t)threads : 0;
    if (pool == NULL) {
        t->threads = threads > 0 ? (uint32_t)threads : (uint32_t)arbor_cpu_count();
        if (t->threads > 1 && (t->own = arbor_pool_create((int)t->threads - 1, e)) == NULL)
            return false;
        t->pool = t->own;
    }
    return true;
}

/* Runs fn(ctx, c) for every chunk c, each chunk claimed by one thread. */
static void trace_threads_run(const trace_threads *t, size_t nchunks, void (*fn)(void *ctx, uint32_t chunk),
                              void *ctx)
{
    arbor_pool_parallel(t->pool, (uint32_t)nchunks, t->threads, fn, ctx);
}

static void trace_threads_free(trace_threads *t)
{
    arbor_pool_destroy(t->own);
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

/* Chunks are numbered by uint32_t, the pool's loop index. */
static bool check_count(size_t n, arbor_err *e)
{
    if (chunk_count(n) > UINT32_MAX)
        return arbor_fail(e, ARBOR_ERR_INVALID, "%zu rays are more than one pass can trace", n);
    return true;
}

/* ---- tracing and timing sets ---- */

typedef struct {
    arbor_trace_kernel kernel;
    const void *tracer;
    const arbor_ray *rays;
    size_t n;
    bool any_hit;
    arbor_tally *chunk_tallies; /* one slot per chunk, each written by one thread */
    trace_threads threads;
} set_pass;

static void set_pass_chunk(void *ctx, uint32_t chunk)
{
    set_pass *p = ctx;
    size_t begin, end;
    chunk_range(chunk, p->n, &begin, &end);
    arbor_tally t = {0, 0.0};
    p->kernel(p->tracer, p->rays + begin, end - begin, p->any_hit, &t);
    p->chunk_tallies[chunk] = t;
}

/* Traces every chunk, then sums their tallies in chunk order. */
static void run_pass(set_pass *pass, arbor_tally *tally)
{
    size_t nchunks = chunk_count(pass->n);
    trace_threads_run(&pass->threads, nchunks, set_pass_chunk, pass);
    tally->hits = 0;
    tally->tsum = 0.0;
    for (size_t c = 0; c < nchunks; c++) {
        tally->hits += pass->chunk_tallies[c].hits;
        tally->tsum += pass->chunk_tallies[c].tsum;
    }
}

static bool pass_init(set_pass *pass, arbor_pool *pool, int threads, arbor_trace_kernel kernel, const void *tracer,
                      const arbor_ray *rays, size_t n, bool any_hit, arbor_err *e)
{
    memset(pass, 0, sizeof *pass);
    pass->kernel = kernel;
    pass->tracer = tracer;
    pass->rays = rays;
    pass->n = n;
    pass->any_hit = any_hit;
    if (!check_count(n, e))
        return false;
    pass->chunk_tallies = calloc(chunk_count(n) + 1, sizeof(arbor_tally));
    if (pass->chunk_tallies == NULL)
        return arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory tracing %zu rays", n);
    if (!trace_threads_init(&pass->threads, pool, threads, e)) {
        free(pass->chunk_tallies);
        return false;
    }
    return true;
}

static void pass_free(set_pass *pass)
{
    trace_threads_free(&pass->threads);
    free(pass->chunk_tallies);
}

bool arbor_trace_set(arbor_pool *pool, arbor_trace_kernel kernel, const void *tracer, const arbor_ray *rays, size_t n,
                     bool any_hit, int threads, arbor_tally *tally, arbor_err *e)
{
    set_pass pass;
    if (!pass_init(&pass, pool, threads, kernel, tracer, rays, n, any_hit, e))
        return false;
    run_pass(&pass, tally);
    pass_free(&pass);
    return true;
}

bool arbor_time_set(arbor_pool *pool, arbor_trace_kernel kernel, const void *tracer, const arbor_ray *rays, size_t n,
                    bool any_hit, int threads, double min_ms, arbor_set_timing *out, arbor_err *e)
{
    set_pass pass;
    if (!pass_init(&pass, pool, threads, kernel, tracer, rays, n, any_hit, e))
        return false;
    memset(out, 0, sizeof *out);
    double start = arbor_now_ms();
    do {
        run_pass(&pass, &out->tally);
        out->passes++;
        out->ms = arbor_now_ms() - start;
    } while (out->ms < min_ms);
    pass_free(&pass);
    out->mrays_per_s = out->ms > 0.0 ? (double)n * out->passes / (out->ms * 1e3) : 0.0;
    return true;
}

/* ---- the reference trace ---- */

typedef struct {
    const arbor_accel *a;
    const arbor_ray *rays;
    size_t n;
    arbor_hit *hits;
    bool *found;
} hits_pass;

static void hits_pass_chunk(void *ctx, uint32_t chunk)
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
    hits_pass pass = {a, rays, n, hits, found};
    trace_threads t;
    if (!check_count(n, e) || !trace_threads_init(&t, pool, threads, e))
        return false;
    trace_threads_run(&t, chunk_count(n), hits_pass_chunk, &pass);
    trace_threads_free(&t);
    return true;
}
