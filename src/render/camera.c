/*
 * camera.c - look-at, orbit and protocol cameras, and primary rays
 * (see include/arbor/camera.h and ../shared/bench/PROTOCOL.md).
 */
#include <math.h>

#include "arbor/camera.h"

#define DEG2RAD 0.017453292519943295f

void arbor_camera_look_at(arbor_camera *c, arbor_vec3 eye, arbor_vec3 target, arbor_vec3 world_up,
                          float fov_deg, int width, int height)
{
    c->eye = eye;
    c->forward = vec3_normalize(vec3_sub(target, eye));
    c->right = vec3_normalize(vec3_cross(c->forward, world_up));
    c->up = vec3_cross(c->right, c->forward);
    c->tan_half_fov = tanf(0.5f * fov_deg * DEG2RAD);
    c->width = width;
    c->height = height;
}

void arbor_camera_protocol(arbor_camera *c, arbor_aabb b, int width, int height)
{
    arbor_vec3 centre = vec3_scale(vec3_add(b.lo, b.hi), 0.5f);
    float d = vec3_length(vec3_sub(b.hi, b.lo));
    arbor_vec3 eye = vec3_add(centre, vec3_scale(vec3_normalize(vec3(0.5f, 0.35f, 1.0f)), 1.307f * d));
    arbor_camera_look_at(c, eye, centre, vec3(0.0f, 1.0f, 0.0f), 45.0f, width, height);
}

void arbor_camera_orbit_protocol(float *yaw_deg, float *pitch_deg, float *distance)
{
    arbor_vec3 dir = vec3_normalize(vec3(0.5f, 0.35f, 1.0f));
    *yaw_deg = atan2f(dir.x, dir.z) / DEG2RAD;
    *pitch_deg = asinf(dir.y) / DEG2RAD;
    *distance = 1.307f;
}

void arbor_camera_orbit(arbor_camera *c, arbor_aabb b, float yaw_deg, float pitch_deg, float distance,
                        float fov_deg, int width, int height)
{
    arbor_vec3 centre = vec3_scale(vec3_add(b.lo, b.hi), 0.5f);
    float d = vec3_length(vec3_sub(b.hi, b.lo));
    /* keep the view off the poles, where "up" would be undefined */
    if (pitch_deg > 89.0f) pitch_deg = 89.0f;
    if (pitch_deg < -89.0f) pitch_deg = -89.0f;
    float yaw = yaw_deg * DEG2RAD, pitch = pitch_deg * DEG2RAD;
    arbor_vec3 dir = vec3(cosf(pitch) * sinf(yaw), sinf(pitch), cosf(pitch) * cosf(yaw));
    arbor_vec3 eye = vec3_add(centre, vec3_scale(dir, distance * d));
    arbor_camera_look_at(c, eye, centre, vec3(0.0f, 1.0f, 0.0f), fov_deg, width, height);
}
