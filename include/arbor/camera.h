/*
 * camera.h - pinhole cameras: look-at, orbit, and the protocol view of
 * ../shared/bench/PROTOCOL.md, and the ray through a point of the image.
 *
 * A camera is a plain value; nothing to free. Image coordinates have x to the
 * right and y downward from the top-left corner; pixel (x, y) covers
 * [x, x+1) x [y, y+1), so its centre is (x + 0.5, y + 0.5).
 */
#ifndef ARBOR_CAMERA_H
#define ARBOR_CAMERA_H

#include "arbor/ray.h"
#include "arbor/vec.h"

typedef struct {
    arbor_vec3 eye;
    arbor_vec3 forward, right, up;  /* orthonormal basis */
    float tan_half_fov;             /* tan(vertical fov / 2) */
    int width, height;
} arbor_camera;

/* Look-at camera; fov_deg is the vertical field of view. */
void arbor_camera_look_at(arbor_camera *c, arbor_vec3 eye, arbor_vec3 target, arbor_vec3 world_up,
                          float fov_deg, int width, int height);

/* PROTOCOL.md's view of a model with bounds b: 45 degrees, looking at the
 * centre from c + 1.307 d normalize(0.5, 0.35, 1.0). */
void arbor_camera_protocol(arbor_camera *c, arbor_aabb b, int width, int height);

/* Orbit: yaw and pitch in degrees and distance in units of the bounds'
 * diagonal, around the centre of b. yaw = 0, pitch = 0 looks along -z; the
 * protocol view is arbor_camera_orbit_protocol's values. */
void arbor_camera_orbit(arbor_camera *c, arbor_aabb b, float yaw_deg, float pitch_deg, float distance,
                        float fov_deg, int width, int height);
/* The yaw, pitch and distance that reproduce the protocol view's eye. */
void arbor_camera_orbit_protocol(float *yaw_deg, float *pitch_deg, float *distance);

/* The ray through image point (px, py) in pixels (pixel centres at +0.5):
 * origin the eye, direction normalised, t in (0, +inf). Inline because the
 * renderer calls it once per sample: as a call, returning the ray through
 * memory cost a store-forwarding stall per pixel. */
static inline arbor_ray arbor_camera_ray(const arbor_camera *c, float px, float py)
{
    float aspect = (float)c->width / (float)c->height;
    float sx = (2.0f * px / (float)c->width - 1.0f) * c->tan_half_fov * aspect;
    float sy = (1.0f - 2.0f * py / (float)c->height) * c->tan_half_fov;
    arbor_vec3 d = vec3_add(c->forward, vec3_add(vec3_scale(c->right, sx), vec3_scale(c->up, sy)));
    arbor_ray r = {c->eye, 0.0f, vec3_normalize(d), INFINITY};
    return r;
}

#endif
