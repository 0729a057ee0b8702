/*
 * render_request.c - reading and checking render and ray requests (see
 * render_request.h). One table of fields drives both the JSON reader and
 * the query-string translation, so the two cannot disagree.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "render_request.h"

#define DEFAULT_WIDTH 640
#define DEFAULT_HEIGHT 480
#define DEFAULT_FOV 45.0f

typedef enum { F_STRING, F_INT, F_NUMBER, F_VEC3, F_CAMERA, F_REGION } field_type;

typedef struct {
    const char *name;
    field_type type;
    bool render, ray;  /* which requests take it */
} field;

static const field fields[] = {
    {"model", F_STRING, true, true},        {"accel", F_STRING, true, true},
    {"builder", F_STRING, true, true},      {"mode", F_STRING, true, false},
    {"width", F_INT, true, true},           {"height", F_INT, true, true},
    {"spp", F_INT, true, false},            {"max_bounces", F_INT, true, false},
    {"ao_samples", F_INT, true, false},     {"background", F_VEC3, true, false},
    {"seed", F_NUMBER, true, false},        {"camera", F_CAMERA, true, true},
    {"region", F_REGION, true, false},      {"heat_scale", F_NUMBER, true, false},
    {"format", F_STRING, true, false},      {"stream", F_STRING, true, false},
    {"x", F_INT, false, true},              {"y", F_INT, false, true},
};

/* The camera's own fields, and those a query string gives flat. */
static const field camera_fields[] = {
    {"yaw", F_NUMBER, true, true},  {"pitch", F_NUMBER, true, true}, {"distance", F_NUMBER, true, true},
    {"fov", F_NUMBER, true, true},  {"eye", F_VEC3, true, true},     {"target", F_VEC3, true, true},
    {"up", F_VEC3, true, true},
};

#define COUNT(a) (sizeof(a) / sizeof((a)[0]))

static const field *find_field(const field *list, size_t n, const char *name)
{
    for (size_t i = 0; i < n; i++)
        if (strcmp(list[i].name, name) == 0)
            return &list[i];
    return NULL;
}

/* ---- typed readers: each names the field in its error ---- */

/* What a JSON value that is not a number is, for messages. */
static const char *json_kind(const cJSON *v)
{
    return cJSON_IsString(v) ? "a string" : cJSON_IsBool(v) ? "a boolean" : cJSON_IsNull(v) ? "null"
         : cJSON_IsArray(v) ? "an array" : "an object";
}

static bool read_number(const cJSON *v, const char *name, double lo, double hi, double *out, arbor_err *e)
{
    if (!cJSON_IsNumber(v))
        return arbor_fail(e, ARBOR_ERR_INVALID, "%s must be a number, not %s", name, json_kind(v));
    double d = v->valuedouble;
    if (!isfinite(d) || d < lo || d > hi)
        return arbor_fail(e, ARBOR_ERR_INVALID, "%s must be a finite number in %.15g..%.15g, not %.17g", name, lo,
                          hi, d);
    *out = d;
    return true;
}

/* A whole number in lo..hi (at most 2^53: exact in a double). */
static bool read_whole(const cJSON *v, const char *name, double lo, double hi, double *out, arbor_err *e)
{
    if (!cJSON_IsNumber(v))
        return arbor_fail(e, ARBOR_ERR_INVALID, "%s must be a whole number, not %s", name, json_kind(v));
    double d = v->valuedouble;
    if (!isfinite(d) || d != floor(d) || d < lo || d > hi)
        return arbor_fail(e, ARBOR_ERR_INVALID, "%s must be a whole number in %.0f..%.0f, not %.17g", name, lo, hi,
                          d);
    *out = d;
    return true;
}

static bool read_int(const cJSON *v, const char *name, int lo, int hi, int *out, arbor_err *e)
{
    double d;
    if (!read_whole(v, name, lo, hi, &d, e))
        return false;
    *out = (int)d;
    return true;
}

static bool read_vec3(const cJSON *v, const char *name, double lo, double hi, arbor_vec3 *out, arbor_err *e)
{
    if (!cJSON_IsArray(v) || cJSON_GetArraySize(v) != 3)
        return arbor_fail(e, ARBOR_ERR_INVALID, "%s must be an array of three numbers", name);
    double c[3];
    for (int i = 0; i < 3; i++) {
        char element[48];
        snprintf(element, sizeof element, "%s[%d]", name, i);
        if (!read_number(cJSON_GetArrayItem(v, i), element, lo, hi, &c[i], e))
            return false;
    }
    *out = vec3((float)c[0], (float)c[1], (float)c[2]);
    return true;
}

static bool read_string(const cJSON *v, const char *name, char *out, size_t cap, arbor_err *e)
{
    if (!cJSON_IsString(v))
        return arbor_fail(e, ARBOR_ERR_INVALID, "%s must be a string", name);
    size_t n = strlen(v->valuestring);
    if (n >= cap || n == 0)
        return arbor_fail(e, ARBOR_ERR_INVALID, "%s must be 1..%zu characters", name, cap - 1);
    memcpy(out, v->valuestring, n + 1);
    return true;
}

/* ---- the camera and the region ---- */

static bool read_camera(const cJSON *o, render_spec *s, arbor_err *e)
{
    if (!cJSON_IsObject(o))
        return arbor_fail(e, ARBOR_ERR_INVALID, "camera must be an object");
    bool orbit = false, look = false;
    const double big = 1e30;
    for (const cJSON *v = o->child; v != NULL; v = v->next) {
        const field *f = find_field(camera_fields, COUNT(camera_fields), v->string);
        if (f == NULL)
            return arbor_fail(e, ARBOR_ERR_INVALID,
                              "unknown camera field '%s' (yaw, pitch, distance, fov or eye, target, up, fov)",
                              v->string);
        double d;
        bool ok = true;
        if (strcmp(f->name, "fov") == 0) {
            ok = read_number(v, "camera.fov", 1, 179, &d, e);
            s->fov = (float)d;
        } else if (strcmp(f->name, "yaw") == 0) {
            ok = read_number(v, "camera.yaw", -big, big, &d, e);
            s->yaw = (float)fmod(d, 360.0);
            orbit = true;
        } else if (strcmp(f->name, "pitch") == 0) {
            ok = read_number(v, "camera.pitch", -ARBOR_MAX_PITCH, ARBOR_MAX_PITCH, &d, e);
            s->pitch = (float)d;
            orbit = true;
        } else if (strcmp(f->name, "distance") == 0) {
            ok = read_number(v, "camera.distance", ARBOR_MIN_DISTANCE, ARBOR_MAX_DISTANCE, &d, e);
            s->distance = (float)d;
            orbit = true;
        } else {
            arbor_vec3 *dst = strcmp(f->name, "eye") == 0 ? &s->eye : strcmp(f->name, "target") == 0 ? &s->target
                                                                                                      : &s->up;
            char name[32];
            snprintf(name, sizeof name, "camera.%s", f->name);
            ok = read_vec3(v, name, -big, big, dst, e);
            look = true;
        }
        if (!ok)
            return false;
    }
    if (orbit && look)
        return arbor_fail(e, ARBOR_ERR_INVALID,
                          "camera takes either yaw/pitch/distance or eye/target/up, not both");
    if (look) {
        if (cJSON_GetObjectItemCaseSensitive(o, "eye") == NULL || cJSON_GetObjectItemCaseSensitive(o, "target") == NULL)
            return arbor_fail(e, ARBOR_ERR_INVALID, "camera needs both eye and target");
        arbor_vec3 dir = vec3_sub(s->target, s->eye);
        if (vec3_length(dir) == 0.0f)
            return arbor_fail(e, ARBOR_ERR_INVALID, "camera.eye must differ from camera.target");
        if (vec3_length(vec3_cross(vec3_normalize(dir), s->up)) < 1e-6f)
            return arbor_fail(e, ARBOR_ERR_INVALID, "camera.up must not be zero or parallel to the view direction");
    }
    s->camera = look ? CAMERA_LOOK_AT : orbit ? CAMERA_ORBIT : s->camera;
    return true;
}

static bool read_region(const cJSON *o, render_spec *s, arbor_err *e)
{
    if (!cJSON_IsObject(o))
        return arbor_fail(e, ARBOR_ERR_INVALID, "region must be an object {x, y, w, h}");
    static const char *const keys[4] = {"x", "y", "w", "h"};
    int *dst[4] = {&s->region.x, &s->region.y, &s->region.w, &s->region.h};
    for (const cJSON *v = o->child; v != NULL; v = v->next) {
        int k = 0;
        while (k < 4 && strcmp(v->string, keys[k]) != 0)
            k++;
        if (k == 4)
            return arbor_fail(e, ARBOR_ERR_INVALID, "unknown region field '%s' (x, y, w, h)", v->string);
        char name[16];
        snprintf(name, sizeof name, "region.%s", keys[k]);
        if (!read_int(v, name, k < 2 ? 0 : 1, ARBOR_MAX_IMAGE_SIZE, dst[k], e))
            return false;
    }
    for (int k = 0; k < 4; k++)
        if (cJSON_GetObjectItemCaseSensitive(o, keys[k]) == NULL)
            return arbor_fail(e, ARBOR_ERR_INVALID, "region needs x, y, w and h");
    return true;
}

/* ---- the request ---- */

static void spec_defaults(render_spec *s)
{
    memset(s, 0, sizeof *s);
    s->kind = ARBOR_ACCEL_BVH;
    s->builder = ARBOR_BUILD_SAH;
    s->mode = ARBOR_MODE_SHADED;
    s->width = DEFAULT_WIDTH;
    s->height = DEFAULT_HEIGHT;
    s->spp = 1;
    s->max_bounces = 4;
    s->ao_samples = 8;
    s->background = vec3(0.1f, 0.1f, 0.12f);
    s->seed = 1;
    s->camera = CAMERA_PROTOCOL;
    s->fov = DEFAULT_FOV;
    s->up = vec3(0.0f, 1.0f, 0.0f);
    s->x = s->y = -1;
    arbor_camera_orbit_protocol(&s->yaw, &s->pitch, &s->distance);
}

static bool read_named(const cJSON *v, render_spec *s, arbor_err *e)
{
    const char *n = v->string;
    char word[32];
    if (strcmp(n, "model") == 0)
        return read_string(v, n, s->model, sizeof s->model, e);
    if (strcmp(n, "stream") == 0)
        return read_string(v, n, s->stream, sizeof s->stream, e);
    if (strcmp(n, "accel") == 0 || strcmp(n, "builder") == 0 || strcmp(n, "mode") == 0 ||
        strcmp(n, "format") == 0) {
        if (!read_string(v, n, word, sizeof word, e))
            return false;
        if (strcmp(n, "accel") == 0 && !arbor_accel_kind_parse(word, &s->kind))
            return arbor_fail(e, ARBOR_ERR_INVALID, "unknown accel '%s' (" ARBOR_ACCEL_KIND_NAMES ")", word);
        if (strcmp(n, "builder") == 0 && !arbor_builder_parse(word, &s->builder))
            return arbor_fail(e, ARBOR_ERR_INVALID, "unknown builder '%s' (" ARBOR_BUILDER_NAMES ")", word);
        if (strcmp(n, "mode") == 0 && !arbor_render_mode_parse(word, &s->mode))
            return arbor_fail(e, ARBOR_ERR_INVALID, "unknown mode '%s' (shaded, normals, depth, ao, heat)", word);
        if (strcmp(n, "format") == 0) {
            static const char *const formats[] = {[RENDER_PNG] = "png", [RENDER_JSON] = "json", [RENDER_COSTS] = "costs"};
            size_t i = 0;
            while (i < COUNT(formats) && strcmp(word, formats[i]) != 0)
                i++;
            if (i == COUNT(formats))
                return arbor_fail(e, ARBOR_ERR_INVALID, "unknown format '%s' (png, json, costs)", word);
            s->format = (render_format)i;
        }
        return true;
    }
    if (strcmp(n, "width") == 0) return read_int(v, n, 1, ARBOR_MAX_IMAGE_SIZE, &s->width, e);
    if (strcmp(n, "height") == 0) return read_int(v, n, 1, ARBOR_MAX_IMAGE_SIZE, &s->height, e);
    if (strcmp(n, "spp") == 0) return read_int(v, n, 1, ARBOR_MAX_SPP, &s->spp, e);
    if (strcmp(n, "max_bounces") == 0) return read_int(v, n, 0, ARBOR_MAX_BOUNCES, &s->max_bounces, e);
    if (strcmp(n, "ao_samples") == 0) return read_int(v, n, 1, ARBOR_MAX_AO_SAMPLES, &s->ao_samples, e);
    if (strcmp(n, "x") == 0) return read_int(v, n, 0, ARBOR_MAX_IMAGE_SIZE - 1, &s->x, e);
    if (strcmp(n, "y") == 0) return read_int(v, n, 0, ARBOR_MAX_IMAGE_SIZE - 1, &s->y, e);
    if (strcmp(n, "background") == 0) return read_vec3(v, n, 0, 1, &s->background, e);
    if (strcmp(n, "camera") == 0) return read_camera(v, s, e);
    if (strcmp(n, "region") == 0) return read_region(v, s, e);
    double d;
    if (strcmp(n, "heat_scale") == 0) {
        if (!read_number(v, n, ARBOR_MIN_HEAT_SCALE, ARBOR_MAX_HEAT_SCALE, &d, e))
            return false;
        s->heat_scale = d;
        return true;
    }
    /* seed */
    if (!read_whole(v, n, 0, (double)ARBOR_MAX_SEED, &d, e))
        return false;
    s->seed = (uint64_t)d;
    return true;
}

bool render_spec_from_json(const cJSON *o, bool ray, render_spec *s, arbor_err *e)
{
    spec_defaults(s);
    for (const cJSON *v = o->child; v != NULL; v = v->next) {
        const field *f = find_field(fields, COUNT(fields), v->string);
        if (f == NULL || !(ray ? f->ray : f->render))
            return arbor_fail(e, ARBOR_ERR_INVALID, "unknown field '%s'", v->string);
        /* A key given twice is refused, as in a query string, rather than
         * letting the last one silently win. */
        for (const cJSON *w = o->child; w != v; w = w->next)
            if (strcmp(w->string, v->string) == 0)
                return arbor_fail(e, ARBOR_ERR_INVALID, "%s is given twice", v->string);
        if (!read_named(v, s, e))
            return false;
    }
    if (s->model[0] == '\0')
        return arbor_fail(e, ARBOR_ERR_INVALID, "model is required");
    if (s->format == RENDER_COSTS && s->mode != ARBOR_MODE_HEAT)
        return arbor_fail(e, ARBOR_ERR_INVALID, "format costs needs mode heat, not %s", arbor_render_mode_name(s->mode));
    if (ray && (s->x < 0 || s->y < 0))
        return arbor_fail(e, ARBOR_ERR_INVALID, "x and y (the pixel) are required");
    if (ray && (s->x >= s->width || s->y >= s->height))
        return arbor_fail(e, ARBOR_ERR_INVALID, "pixel %d,%d is outside the %dx%d frame", s->x, s->y, s->width,
                          s->height);
    return true;
}

/* ---- query strings ---- */

/* "1,2,3" (or any count) as a JSON array of numbers; NULL when a part is
 * not a number. */
static cJSON *number_list(const char *text)
{
    cJSON *a = cJSON_CreateArray();
    const char *p = text;
    while (a != NULL) {
        char *end;
        /* decimal numbers only, as in a JSON body: strtod would also take
         * hex (0x40), inf and nan */
        size_t digits = strspn(p, " \t"); /* as strtod skips them (a query's '+' is a space) */
        digits += strspn(p + digits, "+-.0123456789eE");
        double d = strtod(p, &end);
        if (end > p + digits)
            end = (char *)p;
        /* errno is not looked at: ERANGE comes with subnormals, which JSON
         * accepts, and with overflow, whose inf the field's own check
         * refuses by name. */
        if (end == p || (*end != ',' && *end != '\0')) {
            cJSON_Delete(a);
            return NULL;
        }
        cJSON_AddItemToArray(a, cJSON_CreateNumber(d));
        if (*end == '\0')
            break;
        p = end + 1;
    }
    return a;
}

static cJSON *query_value(field_type type, const char *key, const char *value, arbor_err *e)
{
    if (type == F_STRING)
        return cJSON_CreateString(value);
    cJSON *list = number_list(value);
    if (list == NULL) {
        arbor_fail(e, ARBOR_ERR_INVALID, "%s must be %s, not '%s'", key,
                   type == F_VEC3 ? "three numbers x,y,z" : type == F_REGION ? "x,y,w,h" : "a number", value);
        return NULL;
    }
    if (type == F_VEC3)
        return list;
    int n = cJSON_GetArraySize(list);
    if (type == F_REGION && n == 4) {
        cJSON *r = cJSON_CreateObject();
        static const char *const keys[4] = {"x", "y", "w", "h"};
        for (int i = 0; i < 4; i++)
            cJSON_AddNumberToObject(r, keys[i], cJSON_GetArrayItem(list, i)->valuedouble);
        cJSON_Delete(list);
        return r;
    }
    if (type != F_REGION && n == 1) {
        cJSON *one = cJSON_DetachItemFromArray(list, 0);
        cJSON_Delete(list);
        return one;
    }
    cJSON_Delete(list);
    arbor_fail(e, ARBOR_ERR_INVALID, "%s must be %s, not '%s'", key, type == F_REGION ? "x,y,w,h" : "a number",
               value);
    return NULL;
}

bool render_query_add(cJSON *obj, const char *key, const char *value, arbor_err *e)
{
    const field *f = find_field(camera_fields, COUNT(camera_fields), key);
    cJSON *into = obj;
    if (f != NULL) {
        into = cJSON_GetObjectItemCaseSensitive(obj, "camera");
        if (into == NULL)
            into = cJSON_AddObjectToObject(obj, "camera");
    } else if ((f = find_field(fields, COUNT(fields), key)) == NULL || f->type == F_CAMERA) {
        return arbor_fail(e, ARBOR_ERR_INVALID, "unknown query parameter '%s'", key);
    }
    if (value == NULL)
        return arbor_fail(e, ARBOR_ERR_INVALID, "%s needs a value (%s=...)", key, key);
    if (cJSON_GetObjectItemCaseSensitive(into, key) != NULL)
        return arbor_fail(e, ARBOR_ERR_INVALID, "%s is given twice", key);
    cJSON *v = query_value(f->type, key, value, e);
    if (v == NULL)
        return false;
    if (!cJSON_AddItemToObject(into, key, v)) {
        /* cJSON leaves an item it could not add to the caller. */
        cJSON_Delete(v);
        return arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory reading %s", key);
    }
    return true;
}

/* ---- parameters ---- */

bool render_spec_params(const render_spec *s, const arbor_mesh *m, uint64_t max_pixels, arbor_render_params *p,
                        arbor_err *e)
{
    arbor_render_params_init(p, m, s->width, s->height);
    if (s->camera == CAMERA_LOOK_AT)
        arbor_camera_look_at(&p->camera, s->eye, s->target, s->up, s->fov, s->width, s->height);
    else if (s->camera == CAMERA_ORBIT || s->fov != DEFAULT_FOV)
        arbor_camera_orbit(&p->camera, m->bounds, s->yaw, s->pitch, s->distance, s->fov, s->width, s->height);
    p->region = s->region;
    p->mode = s->mode;
    p->spp = s->spp;
    p->max_bounces = s->max_bounces;
    p->ao_samples = s->ao_samples;
    p->background = s->background;
    p->seed = s->seed;
    p->heat_scale = s->heat_scale;
    uint64_t pixels = s->region.w > 0 ? (uint64_t)s->region.w * (uint64_t)s->region.h
                                      : (uint64_t)s->width * (uint64_t)s->height;
    uint64_t cost = pixels * (uint64_t)s->spp * (s->mode == ARBOR_MODE_AO ? (uint64_t)s->ao_samples : 1);
    if (cost > max_pixels)
        return arbor_fail(e, ARBOR_ERR_INVALID,
                          "the frame costs %llu samples (pixels x spp%s), over the limit of %llu (--max-pixels)",
                          (unsigned long long)cost, s->mode == ARBOR_MODE_AO ? " x ao_samples" : "",
                          (unsigned long long)max_pixels);
    return arbor_render_params_validate(p, e);
}
