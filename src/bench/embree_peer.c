/*
 * embree_peer.c - Intel Embree 3 as the benchmark peer (see include/arbor/embree_peer.h).
 * Without ARBOR_HAVE_EMBREE only the stubs at the end are compiled.
 */
#include "arbor/embree_peer.h"

#ifdef ARBOR_HAVE_EMBREE

#include <embree3/rtcore.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "arbor/sys.h"

struct arbor_embree_peer {
    RTCDevice device;
    RTCScene scene;
    arbor_err *err;           /* where the device's error callback reports, during build only */
    atomic_llong allocated;   /* the device's bytes, from its memory monitor (its build threads too) */
    uint64_t bvh_bytes;       /* what the scene's commit left allocated */
};

static bool on_device_memory(void *user, ssize_t bytes, bool post)
{
    (void)post;
    arbor_embree_peer *p = user;
    atomic_fetch_add(&p->allocated, (long long)bytes);
    return true;
}

static void on_device_error(void *user, enum RTCError code, const char *msg)
{
    arbor_embree_peer *p = user;
    if (p->err != NULL && p->err->status == ARBOR_OK)
        arbor_fail(p->err, ARBOR_ERR_INVALID, "embree error %d: %s", (int)code, msg ? msg : "");
}

bool arbor_embree_available(void)
{
    return true;
}

/* The mesh's vertices and triangles, copied into buffers Embree allocates
 * (they are padded as Embree requires, which the mesh's arrays are not). */
static bool add_mesh(arbor_embree_peer *p, const arbor_mesh *m, arbor_err *e)
{
    RTCGeometry g = rtcNewGeometry(p->device, RTC_GEOMETRY_TYPE_TRIANGLE);
    float *verts = rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float),
                                           m->nverts);
    unsigned *tris = rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(unsigned),
                                             m->ntris);
    if (verts == NULL || tris == NULL) {
        rtcReleaseGeometry(g);
        return arbor_fail(e, ARBOR_ERR_NOMEM, "embree: cannot allocate the geometry buffers");
    }
    for (uint32_t i = 0; i < m->nverts; i++) {
        verts[3 * i] = m->verts[i].x;
        verts[3 * i + 1] = m->verts[i].y;
        verts[3 * i + 2] = m->verts[i].z;
    }
    memcpy(tris, m->tri_verts, 3 * sizeof(unsigned) * (size_t)m->ntris);
    rtcCommitGeometry(g);
    rtcAttachGeometry(p->scene, g);
    rtcReleaseGeometry(g);
    return true;
}

arbor_embree_peer *arbor_embree_build(const arbor_mesh *m, int threads, const char *max_isa, bool robust,
                                      double *commit_ms, arbor_err *e)
{
    arbor_embree_peer *p = calloc(1, sizeof *p);
    if (p == NULL) {
        arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory for the embree peer");
        return NULL;
    }
    arbor_err local;
    arbor_err_clear(&local);
    p->err = &local;
    char config[64] = "";
    int len = 0;
    if (threads > 0)
        len = snprintf(config, sizeof config, "threads=%d", threads);
    if (max_isa != NULL)
        snprintf(config + len, sizeof config - (size_t)len, "%smax_isa=%s", len > 0 ? "," : "", max_isa);
    p->device = rtcNewDevice(config);
    if (p->device == NULL) {
        free(p);
        arbor_fail(e, ARBOR_ERR_INVALID, "embree: rtcNewDevice(\"%s\") failed", config);
        return NULL;
    }
    rtcSetDeviceErrorFunction(p->device, on_device_error, p);
    rtcSetDeviceMemoryMonitorFunction(p->device, on_device_memory, p);
    p->scene = rtcNewScene(p->device);
    if (p->scene != NULL && robust)
        rtcSetSceneFlags(p->scene, RTC_SCENE_FLAG_ROBUST);
    bool ok = p->scene != NULL && add_mesh(p, m, &local);
    long long before = atomic_load(&p->allocated);
    double t0 = arbor_now_ms();
    if (ok)
        rtcCommitScene(p->scene);
    *commit_ms = arbor_now_ms() - t0;
    long long after = atomic_load(&p->allocated);
    p->bvh_bytes = after > before ? (uint64_t)(after - before) : 0;
    p->err = NULL;
    if (!ok || local.status != ARBOR_OK) {
        if (local.status == ARBOR_OK)
            arbor_fail(&local, ARBOR_ERR_INVALID, "embree: cannot create the scene");
        if (e != NULL)
            *e = local;
        arbor_embree_free(p);
        return NULL;
    }
    return p;
}

uint64_t arbor_embree_bvh_bytes(const arbor_embree_peer *p)
{
    return p->bvh_bytes;
}

const char *arbor_embree_mode(const arbor_embree_peer *p)
{
    return (rtcGetSceneFlags(p->scene) & RTC_SCENE_FLAG_ROBUST) ? "robust" : "default";
}

void arbor_embree_kernel(const void *peer, const arbor_ray *rays, size_t n, bool any_hit, arbor_tally *t)
{
    const arbor_embree_peer *p = peer;
    struct RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    uint64_t hits = 0;
    double tsum = 0.0;
    for (size_t i = 0; i < n; i++) {
        const arbor_ray *r = &rays[i];
        struct RTCRayHit rh;
        rh.ray.org_x = r->o.x;
        rh.ray.org_y = r->o.y;
        rh.ray.org_z = r->o.z;
        rh.ray.tnear = r->tmin;
        rh.ray.dir_x = r->d.x;
        rh.ray.dir_y = r->d.y;
        rh.ray.dir_z = r->d.z;
        rh.ray.time = 0.0f;
        rh.ray.tfar = r->tmax;
        rh.ray.mask = 0xffffffffu;
        rh.ray.id = 0;
        rh.ray.flags = 0;
        if (any_hit) {
            rtcOccluded1(p->scene, &ctx, &rh.ray);
            /* Embree marks an occluded ray by setting tfar to -inf */
            hits += rh.ray.tfar < 0.0f;
        } else {
            rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
            rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
            rtcIntersect1(p->scene, &ctx, &rh);
            if (rh.hit.geomID != RTC_INVALID_GEOMETRY_ID) {
                hits++;
                tsum += rh.ray.tfar;
            }
        }
    }
    t->hits += hits;
    t->tsum += tsum;
}

void arbor_embree_free(arbor_embree_peer *p)
{
    if (p == NULL)
        return;
    if (p->scene != NULL)
        rtcReleaseScene(p->scene);
    rtcReleaseDevice(p->device);
    free(p);
}

#else /* !ARBOR_HAVE_EMBREE */

bool arbor_embree_available(void)
{
    return false;
}

arbor_embree_peer *arbor_embree_build(const arbor_mesh *m, int threads, const char *max_isa, bool robust,
                                      double *commit_ms, arbor_err *e)
{
    (void)m;
    (void)threads;
    (void)max_isa;
    (void)robust;
    *commit_ms = 0.0;
    arbor_fail(e, ARBOR_ERR_INVALID, "built without Embree; run `make bench-embree`");
    return NULL;
}

uint64_t arbor_embree_bvh_bytes(const arbor_embree_peer *p)
{
    (void)p;
    return 0;
}

const char *arbor_embree_mode(const arbor_embree_peer *p)
{
    (void)p;
    return "default";
}

void arbor_embree_kernel(const void *peer, const arbor_ray *rays, size_t n, bool any_hit, arbor_tally *t)
{
    (void)peer;
    (void)rays;
    (void)n;
    (void)any_hit;
    (void)t;
}

void arbor_embree_free(arbor_embree_peer *p)
{
    (void)p;
}

#endif
