/*
 * render_request.h - the fields of a render (or ray) request, read from a
 * JSON body or a query string, checked, and turned into render parameters.
 * Private to src/server/; kept apart from the HTTP plumbing so that the one
 * parser serves POST and GET alike and can be fuzzed on its own.
 *
 * Every check names the field and its allowed range in the error, which the
 * HTTP layer answers as 400.
 */
#ifndef ARBOR_SERVER_RENDER_REQUEST_H
#define ARBOR_SERVER_RENDER_REQUEST_H

#include <cjson/cJSON.h>
#include <stdbool.h>
#include <stdint.h>

#include "arbor/accel.h"
#include "arbor/render.h"
#include "arbor/store.h"

#define RENDER_STREAM_MAX 64

typedef enum { CAMERA_PROTOCOL, CAMERA_ORBIT, CAMERA_LOOK_AT } camera_kind;

/* What a frame is answered as: the PNG, its statistics as JSON, or (heat
 * mode only) each pixel's cost as little-endian float32, rows top to bottom. */
typedef enum { RENDER_PNG, RENDER_JSON, RENDER_COSTS } render_format;

typedef struct {
    char model[ARBOR_MODEL_NAME_MAX + 1];
    arbor_accel_kind kind;
    arbor_builder builder;
    arbor_render_mode mode;
    int width, height, spp, max_bounces, ao_samples;
    arbor_vec3 background;
    uint64_t seed;
    double heat_scale;
    arbor_region region;
    camera_kind camera;
    float yaw, pitch, distance, fov;
    arbor_vec3 eye, target, up;
    render_format format;
    char stream[RENDER_STREAM_MAX + 1];  /* "" when none */
    int x, y;                            /* the pixel, for a ray request */
} render_spec;

/* Reads a request object. `ray` selects the ray request's fields (the
 * render fields less region, format, stream, heat_scale, plus x and y). */
bool render_spec_from_json(const cJSON *o, bool ray, render_spec *s, arbor_err *e);

/* Adds one query argument to obj in the shape render_spec_from_json reads
 * (numbers as numbers, "a,b,c" as arrays, the camera's fields into
 * "camera", region=x,y,w,h as an object). */
bool render_query_add(cJSON *obj, const char *key, const char *value, arbor_err *e);

/* The frame's parameters for a mesh: the camera, and the cost check
 * (pixels x spp, x ao_samples in ao mode, at most max_pixels). */
bool render_spec_params(const render_spec *s, const arbor_mesh *m, uint64_t max_pixels, arbor_render_params *p,
                        arbor_err *e);

#endif
