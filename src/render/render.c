/*
 * render.c - frames as pool jobs of 32x32 tiles, the shading modes and
 * anti-aliasing (see include/arbor/render.h for what each mode shows).
 *
 * A tile task writes only its own pixels and its own slot of `tiles`, so
 * tasks share nothing mutable and need no lock; the totals are summed in
 * tile order when the job is done, on one thread, which keeps them the same
 * for any number of threads. Heat colours need the whole frame's cost
 * distribution, so heat tiles store per-pixel costs and the colouring runs
 * in the done step.
 */
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>

#include "arbor/render.h"
#include "arbor/sys.h"
#include "sampling.h"

#define AMBIENT 0.15f
#define MIRROR_TINT_DEFAULT 0.9f
/* Translucent faces a shadow ray may cross before its light counts as
 * blocked: each costs a closest-hit ray, and a closed glass object takes two. */
#define MAX_SHADOW_CROSSINGS 32
#define HEAT_PERCENTILE 0.99
#define HEAT_BINS 4096

/* What one tile traced; written only by the tile's task. */
typedef struct {
    uint64_t rays, nodes, tris;
} tile_tally;

struct arbor_frame {
    arbor_render_params params;
    const arbor_accel *accel;
    const arbor_mesh *mesh;
    arbor_job *job;
    arbor_frame_done_fn done;
    void *user;

    /* derived once at submission, read-only while rendering */
    bool count;                 /* count nodes and triangles of primary rays */
    bool translucent;           /* some material has d < 1: shadow rays look for glass */
    sample_offset_scale offset; /* of secondary-ray origins (sampling.h) */
    float ao_length;            /* AO ray length */
    arbor_vec3 light;
    arbor_vec3 background_linear;
    float depth_near, depth_far;
    arbor_region region;        /* the pixels rendered; the whole frame when none was asked for */
    int tiles_x, tiles_y;

    /* written by the tile tasks, each to its own pixels / slot */
    uint8_t *rgb;
    float *heat;                /* per-pixel cost, heat mode only */
    tile_tally *tiles;

    atomic_bool started;        /* set by the first tile task to run */
    double start_ms;            /* written by that task; read in the done step */
    arbor_frame_result result;  /* filled in the done step */
};

static const char *const mode_names[ARBOR_MODE_COUNT] = {"shaded", "normals", "depth", "ao", "heat"};

const char *arbor_render_mode_name(arbor_render_mode mode)
{
    return (unsigned)mode < ARBOR_MODE_COUNT ? mode_names[mode] : "?";
}

bool arbor_render_mode_parse(const char *name, arbor_render_mode *mode)
{
    for (int i = 0; i < ARBOR_MODE_COUNT; i++)
        if (strcmp(name, mode_names[i]) == 0) {
            *mode = (arbor_render_mode)i;
            return true;
        }
    return false;
}

void arbor_render_params_init(arbor_render_params *p, const arbor_mesh *m, int width, int height)
{
    memset(p, 0, sizeof *p);
    arbor_camera_protocol(&p->camera, m->bounds, width, height);
    p->mode = ARBOR_MODE_SHADED;
    p->spp = 1;
    p->max_bounces = 4;
    p->ao_samples = 8;
    p->ao_radius = 0.1f;
    p->background = vec3(0.1f, 0.1f, 0.12f);
    p->seed = 1;
}

static bool unit_interval(float v)
{
    return v >= 0.0f && v <= 1.0f;
}

bool arbor_render_params_validate(const arbor_render_params *p, arbor_err *e)
{
    const arbor_camera *c = &p->camera;
    if (c->width < 1 || c->width > ARBOR_MAX_IMAGE_SIZE)
        return arbor_fail(e, ARBOR_ERR_INVALID, "width must be in 1..%d, not %d", ARBOR_MAX_IMAGE_SIZE, c->width);
    if (c->height < 1 || c->height > ARBOR_MAX_IMAGE_SIZE)
        return arbor_fail(e, ARBOR_ERR_INVALID, "height must be in 1..%d, not %d", ARBOR_MAX_IMAGE_SIZE,
                          c->height);
    if ((unsigned)p->mode >= ARBOR_MODE_COUNT)
        return arbor_fail(e, ARBOR_ERR_INVALID, "unknown mode %d (shaded, normals, depth, ao, heat)", (int)p->mode);
    if (p->spp < 1 || p->spp > ARBOR_MAX_SPP)
        return arbor_fail(e, ARBOR_ERR_INVALID, "spp must be in 1..%d, not %d", ARBOR_MAX_SPP, p->spp);
    if (p->max_bounces < 0 || p->max_bounces > ARBOR_MAX_BOUNCES)
        return arbor_fail(e, ARBOR_ERR_INVALID, "bounces must be in 0..%d, not %d", ARBOR_MAX_BOUNCES,
                          p->max_bounces);
    if (p->ao_samples < 1 || p->ao_samples > ARBOR_MAX_AO_SAMPLES)
        return arbor_fail(e, ARBOR_ERR_INVALID, "ao samples must be in 1..%d, not %d", ARBOR_MAX_AO_SAMPLES,
                          p->ao_samples);
    if (!(p->ao_radius > 0.0f) || !isfinite(p->ao_radius))
        return arbor_fail(e, ARBOR_ERR_INVALID, "ao radius must be a positive number, not %g", (double)p->ao_radius);
    if (!unit_interval(p->background.x) || !unit_interval(p->background.y) || !unit_interval(p->background.z))
        return arbor_fail(e, ARBOR_ERR_INVALID, "background components must be in 0..1");
    const arbor_region *g = &p->region;
    if (!(g->w == 0 && g->h == 0 && g->x == 0 && g->y == 0) &&
        (g->w < 1 || g->h < 1 || g->x < 0 || g->y < 0 || g->x > c->width - g->w || g->y > c->height - g->h))
        return arbor_fail(e, ARBOR_ERR_INVALID, "region %d,%d %dx%d is not inside the %dx%d frame", g->x, g->y, g->w,
                          g->h, c->width, c->height);
    if (!(p->heat_scale >= 0.0) || !isfinite(p->heat_scale))
        return arbor_fail(e, ARBOR_ERR_INVALID, "heat_scale must be a positive number, not %g", p->heat_scale);
    if (!isfinite(c->tan_half_fov) || !(c->tan_half_fov > 0.0f))
        return arbor_fail(e, ARBOR_ERR_INVALID, "the camera's field of view must be in (0, 180) degrees");
    if (!vec3_finite(c->forward) || !vec3_finite(c->right) || !vec3_finite(c->up))
        return arbor_fail(e, ARBOR_ERR_INVALID,
                          "the camera looks nowhere: its eye is its target (around a model of no extent, every "
                          "orbit is; give camera.eye and camera.target)");
    return true;
}

/* ---- tracing, with the frame's ray and work counts ---- */

static bool trace_primary(const arbor_frame *f, arbor_ray *r, arbor_hit *h, tile_tally *t)
{
    t->rays++;
    if (!f->count)
        return arbor_accel_intersect(f->accel, r, h);
    arbor_trace_counts c = {0, 0};
    bool hit = arbor_accel_intersect_counted(f->accel, r, h, &c);
    t->nodes += c.nodes;
    t->tris += c.tris;
    return hit;
}

static bool trace_secondary(const arbor_frame *f, arbor_ray *r, arbor_hit *h, tile_tally *t)
{
    t->rays++;
    return arbor_accel_intersect(f->accel, r, h);
}

static bool occluded(const arbor_frame *f, const arbor_ray *r, tile_tally *t)
{
    t->rays++;
    return arbor_accel_occluded(f->accel, r);
}

/* ---- the modes: each returns one sample's colour ---- */

/* v clamped to [0, 1], NaN to 0; plain comparisons, which compile to
 * min/max instructions where fminf/fmaxf would be library calls. */
static float clamp01(float v)
{
    return v > 1.0f ? 1.0f : (v > 0.0f ? v : 0.0f);
}

static arbor_vec3 grey(float v)
{
    return vec3(v, v, v);
}

static const arbor_material *material_of(const arbor_frame *f, uint32_t tri)
{
    return &f->mesh->mats[f->mesh->tri_mat[tri]];
}

/* Where a ray hit: the point rebuilt on the triangle, the unit geometric
 * normal turned to face the incoming ray, and the origin for rays leaving on
 * that side (shadow, AO, reflection), offset robustly (sampling.h). */
static sample_surface surface_at(const arbor_frame *f, const arbor_ray *r, const arbor_hit *h)
{
    sample_surface s;
    s.p = sample_hit_point(f->mesh, h, &s.n);
    s.n = vec3_normalize(s.n);
    if (vec3_dot(s.n, r->d) > 0.0f)
        s.n = vec3_scale(s.n, -1.0f);
    s.origin = sample_offset_ray(s.p, s.n, &f->offset);
    return s;
}

/* The origin for a ray that goes through the surface (refraction, a shadow
 * ray crossing glass): offset to the far side. */
static arbor_vec3 origin_behind(const arbor_frame *f, const sample_surface *s)
{
    return sample_offset_ray(s->p, vec3_scale(s->n, -1.0f), &f->offset);
}

/* The normal to shade with: the vertex normals interpolated where the
 * model has them (smooth shading), turned to the side of the geometric
 * normal s->n faces (the viewer's), else s->n itself. */
static arbor_vec3 shading_normal(const arbor_frame *f, const arbor_hit *h, const sample_surface *s)
{
    arbor_vec3 n = arbor_mesh_shading_normal(f->mesh, h->tri, h->u, h->v, s->n);
    return vec3_dot(n, s->n) < 0.0f ? vec3_scale(n, -1.0f) : n;
}

/* ---- glass: MTL d below 1 (see render.h for the model) ---- */

static bool is_translucent(const arbor_material *mat)
{
    return mat->d < 1.0f;
}

/* The index of refraction; an MTL without Ni leaves it 0, which (like any
 * value not above 0) is taken as 1: no bending, no reflection. */
static float index_of(const arbor_material *mat)
{
    return mat->ni > 0.0f ? mat->ni : 1.0f;
}

/* The exact Fresnel reflectance of unpolarised light meeting an interface at
 * cos_i (> 0) from the side of index n1, eta = n1 / n2; 1 under total
 * internal reflection. *cos_t gets the cosine of the refracted ray. */
static float fresnel(float cos_i, float eta, float *cos_t)
{
    float sin2_t = eta * eta * (1.0f - cos_i * cos_i);
    if (sin2_t >= 1.0f) {
        *cos_t = 0.0f;
        return 1.0f;
    }
    float ct = sqrtf(1.0f - sin2_t);
    float rs = (eta * cos_i - ct) / (eta * cos_i + ct);
    float rp = (cos_i - eta * ct) / (cos_i + eta * ct);
    *cos_t = ct;
    return 0.5f * (rs * rs + rp * rp);
}

/* What a translucent face passes of a shadow ray crossing it at cos_i:
 * (1 - d)(1 - R), R the reflectance of light meeting the face from outside at
 * that angle. The ray goes on straight; light through a pane leaves at the
 * angle it entered, and by reciprocity the inner face reflects as much of it
 * as the outer one, so a pane passes (1 - d)^2 (1 - R)^2, as the path that
 * refracts would. */
static float crossing_transmittance(const arbor_material *mat, float cos_i)
{
    float cos_t;
    return (1.0f - clamp01(mat->d)) * (1.0f - fresnel(cos_i, 1.0f / index_of(mat), &cos_t));
}

/* The fraction of the point light reaching origin along the straight
 * segment: 1 when nothing is in the way, 0 behind an opaque surface, else the
 * product of the translucent faces' crossing_transmittance. Scenes without
 * glass ask one any-hit query. */
static float light_transmittance(const arbor_frame *f, arbor_vec3 origin, tile_tally *t)
{
    /* t in (0, 1) along the unnormalised vector: the light itself is not an occluder */
    arbor_ray r = {origin, 0.0f, vec3_sub(f->light, origin), 1.0f};
    if (!f->translucent)
        return occluded(f, &r, t) ? 0.0f : 1.0f;
    float pass = 1.0f;
    for (int i = 0; i < MAX_SHADOW_CROSSINGS && pass > 0.0f; i++) {
        arbor_hit h;
        if (!trace_secondary(f, &r, &h, t))
            return pass;
        const arbor_material *mat = material_of(f, h.tri);
        if (!is_translucent(mat))
            return 0.0f;
        sample_surface s = surface_at(f, &r, &h);
        pass *= crossing_transmittance(mat, -vec3_dot(vec3_normalize(r.d), s.n));
        r.o = origin_behind(f, &s);
        r.d = vec3_sub(f->light, r.o);
        r.tmax = 1.0f; /* the query shrank it to the hit */
    }
    return 0.0f;
}

/* Light leaving s toward the eye (linear), shaded with normal n, for a ray
 * that came along dir: Kd times ambient plus the Lambert term of the point
 * light, and for MTL illum 2 ("highlight on") Ks times a Blinn-Phong
 * highlight of exponent Ns; the light's terms times what reaches s of it. */
static arbor_vec3 direct_light(const arbor_frame *f, const sample_surface *s, arbor_vec3 n, arbor_vec3 dir,
                               const arbor_material *mat, tile_tally *t)
{
    arbor_vec3 to_light = vec3_normalize(vec3_sub(f->light, s->origin));
    float cosine = vec3_dot(n, to_light);
    float reaching = cosine > 0.0f ? light_transmittance(f, s->origin, t) : 0.0f;
    arbor_vec3 c = vec3_scale(mat->kd, AMBIENT + (1.0f - AMBIENT) * (cosine * reaching));
    if (mat->illum == 2 && reaching > 0.0f) {
        float nh = vec3_dot(n, vec3_normalize(vec3_sub(to_light, vec3_normalize(dir))));
        if (nh > 0.0f)
            c = vec3_add(c, vec3_scale(mat->ks, powf(nh, mat->ns) * reaching));
    }
    return c;
}

static arbor_vec3 mirror_tint(const arbor_material *mat)
{
    bool black = mat->ks.x <= 0.0f && mat->ks.y <= 0.0f && mat->ks.z <= 0.0f;
    return black ? grey(MIRROR_TINT_DEFAULT) : mat->ks;
}

static bool is_black(arbor_vec3 c)
{
    return !(c.x > 0.0f || c.y > 0.0f || c.z > 0.0f);
}

/* A ray followed by shade_shaded, with what it carries to the pixel. */
typedef struct {
    arbor_ray r;
    arbor_vec3 weight;
    int bounce;
} shaded_path;

static shaded_path path_from(arbor_vec3 o, arbor_vec3 d, arbor_vec3 weight, int bounce)
{
    shaded_path q = {{o, 0.0f, d, INFINITY}, weight, bounce};
    return q;
}

/* A hit on glass within the bounce budget: the opaque fraction d of the
 * surface is shaded as usual into *sum, the clear rest splits by Fresnel into
 * a reflected and a refracted path (only the reflected one under total
 * internal reflection). The side is the winding's: a ray against the
 * geometric normal (b - a) x (c - a) enters, one along it leaves. *q becomes
 * the refracted path, or the reflected one when it is the only one carrying
 * light; a reflected path that has to wait goes on `waiting`. False when
 * neither carries any. */
static bool shade_glass(const arbor_frame *f, shaded_path *q, const arbor_hit *h, const sample_surface *s,
                        const arbor_material *mat, shaded_path *waiting, int *nwaiting, arbor_vec3 *sum,
                        tile_tally *t)
{
    float d = clamp01(mat->d);
    if (d > 0.0f) {
        arbor_vec3 opaque = vec3_add(mat->ke, direct_light(f, s, shading_normal(f, h, s), q->r.d, mat, t));
        *sum = vec3_add(*sum, vec3_mul(q->weight, vec3_scale(opaque, d)));
    }
    arbor_vec3 dir = vec3_normalize(q->r.d);
    float cos_i = -vec3_dot(dir, s->n);
    bool entering = vec3_dot(q->r.d, arbor_mesh_tri_normal(f->mesh, h->tri)) < 0.0f;
    float eta = entering ? 1.0f / index_of(mat) : index_of(mat);
    float cos_t;
    float reflectance = fresnel(cos_i, eta, &cos_t);
    arbor_vec3 clear = vec3_scale(q->weight, 1.0f - d);
    arbor_vec3 mirrored = vec3_add(dir, vec3_scale(s->n, 2.0f * cos_i));
    shaded_path reflected = path_from(s->origin, mirrored, vec3_scale(clear, reflectance), q->bounce + 1);
    arbor_vec3 through = vec3_scale(clear, 1.0f - reflectance);
    if (is_black(through)) {
        *q = reflected;
        return !is_black(reflected.weight);
    }
    if (!is_black(reflected.weight))
        waiting[(*nwaiting)++] = reflected;
    arbor_vec3 refracted = vec3_add(vec3_scale(dir, eta), vec3_scale(s->n, eta * cos_i - cos_t));
    *q = path_from(origin_behind(f, s), refracted, through, q->bounce + 1);
    return true;
}

/* Follows one path at a time through mirrors and glass, without recursion;
 * a path's weight is the product of the tints and Fresnel factors met so
 * far. Where glass splits a path, the reflected part waits until the
 * refracted one has ended; the waiting paths' bounces grow from the bottom of
 * the list up, so it never holds more than max_bounces. Linear radiance. */
static arbor_vec3 shade_shaded(const arbor_frame *f, arbor_ray r, tile_tally *t)
{
    shaded_path waiting[ARBOR_MAX_BOUNCES];
    int nwaiting = 0;
    shaded_path q = path_from(r.o, r.d, grey(1.0f), 0);
    arbor_vec3 sum = grey(0.0f);
    for (;;) {
        arbor_hit h;
        bool hit = q.bounce == 0 ? trace_primary(f, &q.r, &h, t) : trace_secondary(f, &q.r, &h, t);
        bool goes_on = false;
        if (!hit) {
            sum = vec3_add(sum, vec3_mul(q.weight, f->background_linear));
        } else {
            const arbor_material *mat = material_of(f, h.tri);
            sample_surface s = surface_at(f, &q.r, &h);
            bool bounces_left = q.bounce < f->params.max_bounces;
            if (bounces_left && is_translucent(mat)) {
                goes_on = shade_glass(f, &q, &h, &s, mat, waiting, &nwaiting, &sum, t);
            } else if (bounces_left && arbor_material_is_mirror(mat)) {
                arbor_vec3 d = vec3_sub(q.r.d, vec3_scale(s.n, 2.0f * vec3_dot(q.r.d, s.n)));
                q = path_from(s.origin, d, vec3_mul(q.weight, mirror_tint(mat)), q.bounce + 1);
                goes_on = true;
            } else {
                arbor_vec3 opaque = vec3_add(mat->ke, direct_light(f, &s, shading_normal(f, &h, &s), q.r.d, mat, t));
                sum = vec3_add(sum, vec3_mul(q.weight, opaque));
            }
        }
        if (goes_on)
            continue;
        if (nwaiting == 0)
            return sum;
        q = waiting[--nwaiting];
    }
}

static arbor_vec3 shade_normals(const arbor_frame *f, arbor_ray r, tile_tally *t)
{
    arbor_hit h;
    if (!trace_primary(f, &r, &h, t))
        return f->params.background;
    sample_surface s = surface_at(f, &r, &h);
    return vec3_add(vec3_scale(shading_normal(f, &h, &s), 0.5f), grey(0.5f));
}

static arbor_vec3 shade_depth(const arbor_frame *f, arbor_ray r, tile_tally *t)
{
    arbor_hit h;
    if (!trace_primary(f, &r, &h, t))
        return f->params.background;
    float v = 1.0f - (h.t - f->depth_near) / (f->depth_far - f->depth_near);
    return grey(clamp01(v));
}

static arbor_vec3 shade_ao(const arbor_frame *f, arbor_ray r, sample_rng *g, tile_tally *t)
{
    arbor_hit h;
    if (!trace_primary(f, &r, &h, t))
        return f->params.background;
    sample_surface s = surface_at(f, &r, &h);
    int open = 0;
    for (int i = 0; i < f->params.ao_samples; i++) {
        float u1 = sample_float(g), u2 = sample_float(g);
        arbor_ray probe = {s.origin, 0.0f, sample_cosine_dir(s.n, u1, u2), f->ao_length};
        open += !occluded(f, &probe, t);
    }
    return grey((float)open / (float)f->params.ao_samples);
}

/* Heat colours are assigned in the done step; here only the counts matter. */
static arbor_vec3 shade_heat(const arbor_frame *f, arbor_ray r, tile_tally *t)
{
    arbor_hit h;
    trace_primary(f, &r, &h, t);
    return grey(0.0f);
}

static arbor_vec3 shade_sample(const arbor_frame *f, arbor_ray r, sample_rng *g, tile_tally *t)
{
    switch (f->params.mode) {
    case ARBOR_MODE_SHADED: return shade_shaded(f, r, t);
    case ARBOR_MODE_NORMALS: return shade_normals(f, r, t);
    case ARBOR_MODE_DEPTH: return shade_depth(f, r, t);
    case ARBOR_MODE_AO: return shade_ao(f, r, g, t);
    case ARBOR_MODE_HEAT: return shade_heat(f, r, t);
    case ARBOR_MODE_COUNT: break;
    }
    return grey(0.0f);
}

/* ---- pixels and tiles ---- */

static int square_root_if_square(int n)
{
    int k = (int)sqrtf((float)n + 0.5f);
    return k * k == n ? k : 0;
}

/* The Latin hypercube's row permutation for a pixel (Fisher-Yates). */
static void row_permutation(uint8_t *perm, int n, sample_rng *g)
{
    for (int i = 0; i < n; i++)
        perm[i] = (uint8_t)i;
    for (int i = n - 1; i > 0; i--) {
        int j = (int)(sample_next(g) % (uint64_t)(i + 1));
        uint8_t tmp = perm[i];
        perm[i] = perm[j];
        perm[j] = tmp;
    }
}

/* Sample s's position inside the pixel, in [0, 1)^2 (see render.h). */
static void sample_offset(int s, int spp, int grid, const uint8_t *perm, sample_rng *g, float *dx, float *dy)
{
    if (spp == 1) {
        *dx = *dy = 0.5f;
        return;
    }
    float u = sample_float(g), v = sample_float(g);
    if (grid > 0) {
        *dx = ((float)(s % grid) + u) / (float)grid;
        *dy = ((float)(s / grid) + v) / (float)grid;
    } else {
        *dx = ((float)s + u) / (float)spp;
        *dy = ((float)perm[s] + v) / (float)spp;
    }
}

/* The sRGB transfer curve (IEC 61966-2-1) and its inverse, on [0, 1]: a
 * line near black, a 2.4 power above, so that the bytes mean what every PNG
 * viewer assumes they mean. */
static float srgb_encode(float linear)
{
    return linear <= 0.0031308f ? 12.92f * linear : 1.055f * powf(linear, 1.0f / 2.4f) - 0.055f;
}

static float srgb_decode(float encoded)
{
    return encoded <= 0.04045f ? encoded / 12.92f : powf((encoded + 0.055f) / 1.055f, 2.4f);
}

static uint8_t to_byte(float v)
{
    return (uint8_t)(clamp01(v) * 255.0f + 0.5f);
}

static void store_rgb(uint8_t *px, arbor_vec3 c)
{
    px[0] = to_byte(c.x);
    px[1] = to_byte(c.y);
    px[2] = to_byte(c.z);
}

static void render_pixel(arbor_frame *f, int x, int y, tile_tally *t)
{
    const arbor_render_params *p = &f->params;
    int spp = p->spp, grid = square_root_if_square(spp);
    uint8_t perm[ARBOR_MAX_SPP];
    if (spp > 1 && grid == 0) {
        sample_rng pg = sample_rng_for(p->seed, (uint64_t)x, (uint64_t)y, UINT64_MAX);
        row_permutation(perm, spp, &pg);
    }
    uint64_t cost_before = t->nodes + t->tris;
    arbor_vec3 sum = grey(0.0f);
    for (int s = 0; s < spp; s++) {
        sample_rng g = sample_rng_for(p->seed, (uint64_t)x, (uint64_t)y, (uint64_t)s);
        float dx, dy;
        sample_offset(s, spp, grid, perm, &g, &dx, &dy);
        arbor_ray r = arbor_camera_ray(&p->camera, (float)x + dx, (float)y + dy);
        sum = vec3_add(sum, shade_sample(f, r, &g, t));
    }
    size_t index = (size_t)(y - f->region.y) * (size_t)f->region.w + (size_t)(x - f->region.x);
    if (p->mode == ARBOR_MODE_HEAT) {
        f->heat[index] = (float)(t->nodes + t->tris - cost_before) / (float)spp;
        return;
    }
    arbor_vec3 c = vec3_scale(sum, 1.0f / (float)spp);
    if (p->mode == ARBOR_MODE_SHADED) {
        c = vec3(srgb_encode(clamp01(c.x)), srgb_encode(clamp01(c.y)), srgb_encode(clamp01(c.z)));
    }
    store_rgb(f->rgb + 3 * index, c);
}

static void render_tile(void *ctx, uint32_t task)
{
    arbor_frame *f = ctx;
    if (!atomic_exchange(&f->started, true))
        f->start_ms = arbor_now_ms();
    int x0 = f->region.x + (int)(task % (uint32_t)f->tiles_x) * ARBOR_TILE_SIZE;
    int y0 = f->region.y + (int)(task / (uint32_t)f->tiles_x) * ARBOR_TILE_SIZE;
    int x1 = x0 + ARBOR_TILE_SIZE, y1 = y0 + ARBOR_TILE_SIZE;
    if (x1 > f->region.x + f->region.w) x1 = f->region.x + f->region.w;
    if (y1 > f->region.y + f->region.h) y1 = f->region.y + f->region.h;
    tile_tally t = {0, 0, 0};
    for (int y = y0; y < y1; y++)
        for (int x = x0; x < x1; x++)
            render_pixel(f, x, y, &t);
    f->tiles[task] = t;
}

/* ---- the done step ---- */

/* Blue, cyan, green, yellow, red, white at v = 0, 0.2, ..., 1. */
static arbor_vec3 heat_colour(float v)
{
    static const float stops[6][3] = {{0, 0, 1}, {0, 1, 1}, {0, 1, 0}, {1, 1, 0}, {1, 0, 0}, {1, 1, 1}};
    v = clamp01(v) * 5.0f;
    int i = v >= 5.0f ? 4 : (int)v;
    float w = v - (float)i;
    return vec3(stops[i][0] + w * (stops[i + 1][0] - stops[i][0]), stops[i][1] + w * (stops[i + 1][1] - stops[i][1]),
                stops[i][2] + w * (stops[i + 1][2] - stops[i][2]));
}

/* Max, mean and the 99th percentile (upper edge of the histogram bin that
 * reaches it: HEAT_BINS bins over [0, max]), then the colours. */
static void colour_heat(arbor_frame *f)
{
    size_t n = (size_t)f->region.w * (size_t)f->region.h;
    double max = 0.0, sum = 0.0;
    for (size_t i = 0; i < n; i++) {
        sum += f->heat[i];
        if (f->heat[i] > max)
            max = f->heat[i];
    }
    double scale = max;
    uint32_t bins[HEAT_BINS] = {0};
    if (max > 0.0) {
        for (size_t i = 0; i < n; i++) {
            int b = (int)(f->heat[i] / max * (HEAT_BINS - 1));
            bins[b]++;
        }
        size_t want = (size_t)ceil(HEAT_PERCENTILE * (double)n), seen = 0;
        for (int b = 0; b < HEAT_BINS; b++) {
            seen += bins[b];
            if (seen >= want) {
                scale = max * (double)(b + 1) / (HEAT_BINS - 1);
                break;
            }
        }
        if (scale > max)
            scale = max;
    }
    f->result.heat_max = max;
    f->result.heat_mean = sum / (double)n;
    f->result.heat_scale = f->params.heat_scale > 0.0 ? f->params.heat_scale : scale > 0.0 ? scale : 1.0;
    for (size_t i = 0; i < n; i++)
        store_rgb(f->rgb + 3 * i, heat_colour((float)(f->heat[i] / f->result.heat_scale)));
}

static void frame_done(void *ctx, bool cancelled)
{
    arbor_frame *f = ctx;
    double end_ms = arbor_now_ms();
    arbor_frame_result *r = &f->result;
    uint64_t nodes = 0, tris = 0;
    uint32_t ntiles = (uint32_t)(f->tiles_x * f->tiles_y);
    for (uint32_t i = 0; i < ntiles; i++) {
        r->rays += f->tiles[i].rays;
        nodes += f->tiles[i].nodes;
        tris += f->tiles[i].tris;
    }
    r->cancelled = cancelled;
    r->render_ms = atomic_load(&f->started) ? end_ms - f->start_ms : 0.0;
    r->mrays_per_s = r->render_ms > 0.0 ? (double)r->rays / (r->render_ms * 1e3) : 0.0;
    if (f->count) {
        double primary = (double)f->region.w * f->region.h * f->params.spp;
        r->counted = true;
        r->mean_nodes = (double)nodes / primary;
        r->mean_tris = (double)tris / primary;
    }
    if (f->params.mode == ARBOR_MODE_HEAT && !cancelled)
        colour_heat(f);
    if (f->done != NULL)
        f->done(f, f->user);
}

static void frame_free(void *ctx)
{
    arbor_frame *f = ctx;
    free(f->rgb);
    free(f->heat);
    free(f->tiles);
    free(f);
}

/* Distances from p to the nearest point of box b (0 inside) and to its
 * farthest corner: the depth range any hit can have. */
static void box_distances(arbor_aabb b, arbor_vec3 p, float *near, float *far)
{
    arbor_vec3 nearest = vec3_min(vec3_max(p, b.lo), b.hi);
    arbor_vec3 farthest = vec3(p.x < 0.5f * (b.lo.x + b.hi.x) ? b.hi.x : b.lo.x,
                               p.y < 0.5f * (b.lo.y + b.hi.y) ? b.hi.y : b.lo.y,
                               p.z < 0.5f * (b.lo.z + b.hi.z) ? b.hi.z : b.lo.z);
    *near = vec3_length(vec3_sub(nearest, p));
    *far = vec3_length(vec3_sub(farthest, p));
}

/* The values every pixel uses, derived once from the parameters. */
static void frame_setup(arbor_frame *f)
{
    const arbor_render_params *p = &f->params;
    const arbor_camera *c = &p->camera;
    float d = sample_model_size(f->mesh);
    f->count = p->count_primary || p->mode == ARBOR_MODE_HEAT;
    f->offset = sample_offset_scale_of(f->mesh);
    f->translucent = false;
    for (uint32_t i = 0; i < f->mesh->nmats; i++)
        f->translucent |= is_translucent(&f->mesh->mats[i]);
    f->ao_length = p->ao_radius * d;
    f->light = vec3_add(c->eye, vec3_scale(c->up, 0.5f * d));
    f->background_linear = vec3(srgb_decode(p->background.x), srgb_decode(p->background.y),
                                srgb_decode(p->background.z));
    box_distances(f->mesh->bounds, c->eye, &f->depth_near, &f->depth_far);
    if (!(f->depth_far > f->depth_near))
        f->depth_far = f->depth_near + 1.0f;
    f->region = p->region;
    if (f->region.w == 0) {
        f->region.w = c->width;
        f->region.h = c->height;
    }
    f->tiles_x = (f->region.w + ARBOR_TILE_SIZE - 1) / ARBOR_TILE_SIZE;
    f->tiles_y = (f->region.h + ARBOR_TILE_SIZE - 1) / ARBOR_TILE_SIZE;
    f->result.width = f->region.w;
    f->result.height = f->region.h;
}

arbor_frame *arbor_render_submit(arbor_pool *pool, const arbor_accel *a, const arbor_render_params *p,
                                 arbor_frame_done_fn done, void *user, arbor_err *e)
{
    if (!arbor_render_params_validate(p, e))
        return NULL;
    arbor_frame *f = calloc(1, sizeof *f);
    if (f == NULL) {
        arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory for a frame");
        return NULL;
    }
    f->params = *p;
    f->accel = a;
    f->mesh = arbor_accel_mesh(a);
    f->done = done;
    f->user = user;
    atomic_init(&f->started, false);
    frame_setup(f);
    size_t pixels = (size_t)f->region.w * (size_t)f->region.h;
    f->rgb = calloc(pixels, 3);
    f->tiles = calloc((size_t)f->tiles_x * (size_t)f->tiles_y, sizeof *f->tiles);
    f->heat = p->mode == ARBOR_MODE_HEAT ? calloc(pixels, sizeof *f->heat) : NULL;
    if (f->rgb == NULL || f->tiles == NULL || (p->mode == ARBOR_MODE_HEAT && f->heat == NULL)) {
        frame_free(f);
        arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory for a %dx%d frame", p->camera.width, p->camera.height);
        return NULL;
    }
    f->result.rgb = f->rgb;
    f->job = arbor_job_new((uint32_t)(f->tiles_x * f->tiles_y), render_tile, frame_done, frame_free, f, e);
    if (f->job == NULL) {
        frame_free(f);
        return NULL;
    }
    if (!arbor_pool_submit(pool, f->job, e)) {
        arbor_job_release(f->job);
        return NULL;
    }
    return f;
}

bool arbor_frame_started(const arbor_frame *f)
{
    return atomic_load(&f->started);
}

void arbor_frame_cancel(arbor_frame *f)
{
    arbor_job_cancel(f->job);
}

const arbor_frame_result *arbor_frame_wait(arbor_frame *f)
{
    arbor_job_wait(f->job);
    return &f->result;
}

const arbor_frame_result *arbor_frame_result_of(const arbor_frame *f)
{
    return &f->result;
}

const float *arbor_frame_heat_costs(const arbor_frame *f)
{
    return f->heat;
}

void arbor_frame_release(arbor_frame *f)
{
    if (f != NULL)
        arbor_job_release(f->job);
}

arbor_frame *arbor_render(arbor_pool *pool, const arbor_accel *a, const arbor_render_params *p, arbor_err *e)
{
    arbor_frame *f = arbor_render_submit(pool, a, p, NULL, NULL, e);
    if (f != NULL)
        arbor_frame_wait(f);
    return f;
}
