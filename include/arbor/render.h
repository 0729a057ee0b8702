/*
 * render.h - rendering frames of a model through an acceleration structure
 * on a worker pool: the shading modes, anti-aliasing, and frame results.
 *
 * A frame is split into 32x32 tiles, each a task of an arbor_pool job, so
 * several frames can render at once on one pool (see pool.h). Every pixel's
 * random numbers come from (frame seed, x, y, sample index) only, and each
 * pixel is written by exactly one tile, so a frame is identical bit for bit
 * whatever the number of threads.
 *
 * Modes:
 *   shaded   Lambert with the material's Kd plus its Ke, lit by one point
 *            light at eye + 0.5 d camera_up (PROTOCOL.md's light for the
 *            protocol view; for other views it moves with the camera), hard
 *            shadows, 15% ambient so shadows are not black, no falloff;
 *            materials of MTL illum 2 add a Blinn-Phong highlight of Ks
 *            with exponent Ns;
 *            mirror materials (arbor_material_is_mirror) reflect, tinted by
 *            Ks (0.9 when Ks is black); glass (below) reflects and refracts;
 *            each reflection or refraction is a bounce, up to max_bounces,
 *            and a mirror or glass met with none left is shaded as an opaque
 *            surface. Radiance is summed in linear light and written with
 *            the sRGB transfer curve (12.92 x up to 0.0031308, then
 *            1.055 x^(1/2.4) - 0.055); the background colour is taken as
 *            sRGB-encoded and decoded with the inverse curve.
 *   normals  the shading normal turned toward the viewer, as n*0.5+0.5.
 * The shading normal is the geometric one, or, on models that carry vertex
 * normals (OBJ vn), those interpolated across the triangle (smooth
 * shading); shadow and secondary rays always leave along the geometric one.
 *   depth    hit distance as grey: white at the nearest point of the
 *            model's bounding box, black at its farthest corner.
 *   ao       ambient occlusion: the fraction of ao_samples cosine-weighted
 *            rays of length ao_radius * d that escape, as grey (any
 *            surface occludes, glass too).
 *   heat     false colour (blue, cyan, green, yellow, red, white) of each
 *            pixel's traversal cost = nodes visited + triangles tested
 *            by its primary rays (mean over samples; arbor_trace_counts,
 *            the same for both kinds); the top of the scale is
 *            the frame's 99th percentile, reported with the max and mean.
 * d is the model's diagonal |B.max - B.min|. The normals, depth, ao and
 * heat modes write their values as they are, without a transfer curve.
 *
 * Glass: a material with MTL d (dissolve) below 1. The fraction d of its
 * surface is shaded as an opaque one (Kd, Ke, shadows); the rest, 1 - d, is a
 * clear dielectric of index Ni (1 when the file gives none) in air: light
 * meeting it splits into a reflected part R and a refracted part 1 - R, R the
 * exact Fresnel reflectance of unpolarised light at that angle (all of it
 * reflected under total internal reflection); Snell's law turns the
 * refracted ray. Which side is inside follows the winding: a ray against the
 * geometric normal (b - a) x (c - a) enters. Both parts are traced (the
 * reflected and refracted rays count as bounces), without tint: Kd colours
 * only the opaque fraction. A shadow ray is not refracted; it goes straight
 * to the light and each glass face it crosses at angle theta passes
 * (1 - d)(1 - R(theta)), R for light arriving from outside (exact for a
 * pane, whose light leaves at the angle it entered); an opaque surface
 * blocks it, as do more than 32 glass faces.
 *
 * Secondary rays (shadow, AO, reflection, refraction) start at the hit point
 * rebuilt from the triangle's corners and barycentrics, offset along the
 * geometric normal n (turned toward the incoming ray; away from it for
 * refraction and glass crossings) by Waechter & Binder's method (Ray Tracing
 * Gems, ch. 6): 256 n_i ulps of each coordinate p_i, or, where |p_i| is
 * below s_i / 32, s_i n_i / 65536, s_i the largest |coordinate| of the model
 * on axis i (at least d / 1024). The offset follows the precision of the point, so
 * models far from the origin do not shadow themselves, and scaling a model
 * by a power of two scales every offset with it. (PROTOCOL.md's ray sets,
 * src/render/raysets.c, keep its p + 1e-4 d n.)
 *
 * Regions: a frame may render only a rectangle of itself. Since a pixel's
 * value depends only on the parameters and its own (x, y), a region's pixels
 * are bit for bit those of the whole frame there (in heat mode, given the
 * whole frame's heat_scale).
 *
 * Anti-aliasing: spp = 1 traces each pixel's centre (the protocol's rays).
 * When spp is a square k*k, sample s lies jittered in cell (s % k, s / k) of
 * a k x k grid over the pixel; otherwise the samples are a Latin hypercube
 * (sample s jittered in column s and in row perm(s) of an spp x spp grid,
 * perm random per pixel). Samples are averaged in order.
 *
 * Ownership: arbor_render_submit returns a frame the caller releases with
 * arbor_frame_release; the frame owns its image. The accel (and its mesh)
 * must outlive the frame's rendering, i.e. until done has been called.
 */
#ifndef ARBOR_RENDER_H
#define ARBOR_RENDER_H

#include <stdbool.h>
#include <stdint.h>

#include "arbor/accel.h"
#include "arbor/camera.h"
#include "arbor/err.h"
#include "arbor/pool.h"

#define ARBOR_TILE_SIZE 32
#define ARBOR_MAX_IMAGE_SIZE 8192
#define ARBOR_MAX_SPP 64
#define ARBOR_MAX_BOUNCES 16
#define ARBOR_MAX_AO_SAMPLES 256
/* The ranges the command line and the daemon both accept for an orbit
 * camera (degrees; distance in model diagonals), a heat frame's scale and a
 * frame's seed. A pitch of 90 would leave the view's up undefined; seeds stop
 * at 2^53 - 1, so that a larger one, which JSON's doubles would round to
 * another, is refused rather than changed. */
#define ARBOR_MAX_PITCH 89.9
#define ARBOR_MIN_DISTANCE 1e-4
#define ARBOR_MAX_DISTANCE 1e4
#define ARBOR_MIN_HEAT_SCALE 1e-9
#define ARBOR_MAX_HEAT_SCALE 1e12
#define ARBOR_MAX_SEED 9007199254740991ULL

typedef enum {
    ARBOR_MODE_SHADED,
    ARBOR_MODE_NORMALS,
    ARBOR_MODE_DEPTH,
    ARBOR_MODE_AO,
    ARBOR_MODE_HEAT,
    ARBOR_MODE_COUNT
} arbor_render_mode;

/* A rectangle of the frame in pixels; w = h = 0 means the whole frame. */
typedef struct {
    int x, y, w, h;
} arbor_region;

typedef struct {
    arbor_camera camera;     /* its width and height are the whole frame's */
    arbor_region region;     /* render only these pixels of the frame (the image is w x h) */
    arbor_render_mode mode;
    int spp;                 /* samples per pixel, 1..ARBOR_MAX_SPP */
    int max_bounces;         /* mirror reflections, 0..ARBOR_MAX_BOUNCES */
    int ao_samples;          /* 1..ARBOR_MAX_AO_SAMPLES */
    float ao_radius;         /* in units of the model's diagonal, > 0 */
    arbor_vec3 background;   /* colour of misses, components in [0, 1] */
    uint64_t seed;           /* frame seed for the per-pixel random numbers */
    double heat_scale;       /* heat mode: the cost at the top of the scale; 0 = the image's 99th percentile */
    bool count_primary;      /* also report mean nodes and triangles per primary ray */
} arbor_render_params;

typedef struct {
    int width, height;         /* of the image: the region's size */
    uint8_t *rgb;              /* width * height * 3, rows top to bottom; owned by the frame */
    bool cancelled;            /* some tiles never rendered */
    double render_ms;          /* first tile started to last tile finished */
    uint64_t rays;             /* every ray traced: primary, shadow, AO, reflection */
    double mrays_per_s;
    /* heat mode: per-pixel cost (nodes + triangle tests) statistics */
    double heat_scale;         /* the cost shown as the top of the scale (99th percentile) */
    double heat_max, heat_mean;
    /* with count_primary (always in heat mode): per primary ray */
    bool counted;
    double mean_nodes, mean_tris;
} arbor_frame_result;

typedef struct arbor_frame arbor_frame;

/* Called once on a pool worker when the frame is complete or cancelled;
 * arbor_frame_result(f) is final from then on. May release f. */
typedef void (*arbor_frame_done_fn)(arbor_frame *f, void *user);

const char *arbor_render_mode_name(arbor_render_mode mode);
bool arbor_render_mode_parse(const char *name, arbor_render_mode *mode);

/* Defaults: the protocol view of the mesh at width x height, shaded, spp 1,
 * 4 bounces, 8 AO samples of radius 0.1 d, dark grey background, seed 1. */
void arbor_render_params_init(arbor_render_params *p, const arbor_mesh *m, int width, int height);
/* Checks every field; the message names the field and its allowed range. */
bool arbor_render_params_validate(const arbor_render_params *p, arbor_err *e);

/* Starts rendering on the pool; done (may be NULL) is called on completion.
 * NULL with e filled on invalid parameters or when out of memory. */
arbor_frame *arbor_render_submit(arbor_pool *pool, const arbor_accel *a, const arbor_render_params *p,
                                 arbor_frame_done_fn done, void *user, arbor_err *e);
/* True once a tile of the frame has started rendering. */
bool arbor_frame_started(const arbor_frame *f);
/* Stops the frame between tiles; its done reports cancelled. */
void arbor_frame_cancel(arbor_frame *f);
/* Blocks until the frame's done has returned; its result. */
const arbor_frame_result *arbor_frame_wait(arbor_frame *f);
/* The result; final only once done was called (or wait returned). */
const arbor_frame_result *arbor_frame_result_of(const arbor_frame *f);
/* Heat mode: the cost of each pixel of the image (the mean over its samples
 * of nodes visited + triangles tested), width * height, rows top to bottom,
 * that its colours were made from; NULL in other modes. Owned by the frame;
 * final once done was called. */
const float *arbor_frame_heat_costs(const arbor_frame *f);
void arbor_frame_release(arbor_frame *f);

/* Submits and waits: the frame (release it) or NULL with e filled. */
arbor_frame *arbor_render(arbor_pool *pool, const arbor_accel *a, const arbor_render_params *p, arbor_err *e);

#endif
