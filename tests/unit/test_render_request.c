/*
 * test_render_request.c - reading render and ray requests (src/server/
 * render_request.c): every field's range edges from JSON, NaN and infinity
 * (1e999), whole numbers, wrong types, unknown fields named in the message,
 * the camera's checks (eye == target, up parallel to the view, orbit and
 * look-at mixed), regions checked against the frame, ray pixels inside the
 * frame, the query-string form (lists, regions, duplicated keys), and that
 * the query and JSON forms of a request give identical render parameters.
 */
#include <cjson/cJSON.h>
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../../src/server/render_request.h"
#include "arbor/procgen.h"
#include "support.h"
#include "unity.h"

#define MAX_PIXELS ((uint64_t)1 << 40)

static arbor_mesh mesh;

void setUp(void) {}
void tearDown(void) {}

/* ---- helpers ---- */

/* Reads a request written as JSON text; false with e filled when refused. */
static bool read_json(const char *json, bool ray, render_spec *s, arbor_err *e)
{
    cJSON *o = cJSON_Parse(json);
    TEST_ASSERT_NOT_NULL_MESSAGE(o, json);
    arbor_err_clear(e);
    bool ok = render_spec_from_json(o, ray, s, e);
    cJSON_Delete(o);
    return ok;
}

/* A render request's body: {"model":"m", <fields>}. */
static void body(char *out, size_t cap, const char *fields)
{
    snprintf(out, cap, "{\"model\":\"m\"%s%s}", fields[0] ? "," : "", fields);
}

static render_spec accept(const char *fields, bool ray)
{
    char json[1024];
    body(json, sizeof json, fields);
    render_spec s;
    arbor_err e;
    TEST_ASSERT_TRUE_MESSAGE(read_json(json, ray, &s, &e), e.msg);
    return s;
}

/* Refused with ARBOR_ERR_INVALID and a message containing every word of
 * `words` (separated by '|'). */
static void assert_message(const arbor_err *e, const char *words, const char *input)
{
    char msg[1200];
    snprintf(msg, sizeof msg, "input %s: message '%s' should name '%s'", input, e->msg, words);
    TEST_ASSERT_EQUAL_INT_MESSAGE(ARBOR_ERR_INVALID, e->status, msg);
    char copy[256];
    snprintf(copy, sizeof copy, "%s", words);
    for (char *w = strtok(copy, "|"); w != NULL; w = strtok(NULL, "|"))
        TEST_ASSERT_NOT_NULL_MESSAGE(strstr(e->msg, w), msg);
}

static void refuse(const char *fields, bool ray, const char *words)
{
    char json[1024];
    body(json, sizeof json, fields);
    render_spec s;
    arbor_err e;
    TEST_ASSERT_FALSE_MESSAGE(read_json(json, ray, &s, &e), json);
    assert_message(&e, words, json);
}

/* The render parameters of a spec, or false with e filled. */
static bool params_of(const render_spec *s, uint64_t max_pixels, arbor_render_params *p, arbor_err *e)
{
    memset(p, 0, sizeof *p);
    arbor_err_clear(e);
    return render_spec_params(s, &mesh, max_pixels, p, e);
}

static arbor_render_params params_ok(const char *fields)
{
    render_spec s = accept(fields, false);
    arbor_render_params p;
    arbor_err e;
    TEST_ASSERT_TRUE_MESSAGE(params_of(&s, MAX_PIXELS, &p, &e), e.msg);
    return p;
}

static void params_refused(const char *fields, uint64_t max_pixels, const char *words)
{
    render_spec s = accept(fields, false);
    arbor_render_params p;
    arbor_err e;
    TEST_ASSERT_FALSE_MESSAGE(params_of(&s, max_pixels, &p, &e), fields);
    assert_message(&e, words, fields);
}

/* A query string "k=v&k=v" (no escaping) through render_query_add into
 * obj; false with e filled at the first refused argument. */
static bool add_query(cJSON *obj, const char *query, arbor_err *e)
{
    char copy[1024];
    snprintf(copy, sizeof copy, "%s", query);
    arbor_err_clear(e);
    char *save = NULL;
    for (char *arg = strtok_r(copy, "&", &save); arg != NULL; arg = strtok_r(NULL, "&", &save)) {
        char *eq = strchr(arg, '=');
        if (eq != NULL)
            *eq = '\0';
        if (!render_query_add(obj, arg, eq != NULL ? eq + 1 : NULL, e))
            return false;
    }
    return true;
}

static bool read_query(const char *query, bool ray, render_spec *s, arbor_err *e)
{
    cJSON *o = cJSON_CreateObject();
    bool ok = add_query(o, query, e) && render_spec_from_json(o, ray, s, e);
    cJSON_Delete(o);
    return ok;
}

static void query_refused(const char *query, bool ray, const char *words)
{
    render_spec s;
    arbor_err e;
    TEST_ASSERT_FALSE_MESSAGE(read_query(query, ray, &s, &e), query);
    assert_message(&e, words, query);
}

/* The JSON object a query makes, printed without spaces. */
static void assert_query_makes(const char *query, const char *want)
{
    cJSON *o = cJSON_CreateObject();
    arbor_err e;
    TEST_ASSERT_TRUE_MESSAGE(add_query(o, query, &e), e.msg);
    char *got = cJSON_PrintUnformatted(o);
    TEST_ASSERT_EQUAL_STRING_MESSAGE(want, got, query);
    free(got);
    cJSON_Delete(o);
}

/* ---- ranges ---- */

typedef struct {
    const char *name;
    int lo, hi;
    size_t offset; /* of the int in render_spec */
    bool ray;      /* a ray request's field */
} int_field;

static const int_field int_fields[] = {
    {"width", 1, ARBOR_MAX_IMAGE_SIZE, offsetof(render_spec, width), false},
    {"height", 1, ARBOR_MAX_IMAGE_SIZE, offsetof(render_spec, height), false},
    {"spp", 1, ARBOR_MAX_SPP, offsetof(render_spec, spp), false},
    {"max_bounces", 0, ARBOR_MAX_BOUNCES, offsetof(render_spec, max_bounces), false},
    {"ao_samples", 1, ARBOR_MAX_AO_SAMPLES, offsetof(render_spec, ao_samples), false},
    {"x", 0, ARBOR_MAX_IMAGE_SIZE - 1, offsetof(render_spec, x), true},
    {"y", 0, ARBOR_MAX_IMAGE_SIZE - 1, offsetof(render_spec, y), true},
};

/* A ray request's field (x or y) goes with the other coordinate and an
 * 8192 x 8192 frame, so that only the field under test decides. */
static void int_field_body(char *out, size_t cap, const int_field *f, const char *value)
{
    if (f->ray)
        snprintf(out, cap, "\"width\":8192,\"height\":8192,\"%s\":0,\"%s\":%s", f->name[0] == 'x' ? "y" : "x",
                 f->name, value);
    else
        snprintf(out, cap, "\"%s\":%s", f->name, value);
}

static void check_int_value(const int_field *f, int v, bool ok)
{
    char value[32], fields[256];
    snprintf(value, sizeof value, "%d", v);
    int_field_body(fields, sizeof fields, f, value);
    if (!ok) {
        refuse(fields, f->ray, f->name);
        return;
    }
    render_spec s = accept(fields, f->ray);
    TEST_ASSERT_EQUAL_INT_MESSAGE(v, *(const int *)((const char *)&s + f->offset), f->name);
}

static void test_int_fields_at_their_edges(void)
{
    for (size_t i = 0; i < sizeof int_fields / sizeof int_fields[0]; i++) {
        const int_field *f = &int_fields[i];
        check_int_value(f, f->lo - 1, false);
        check_int_value(f, f->lo, true);
        check_int_value(f, f->hi, true);
        check_int_value(f, f->hi + 1, false);
        const char *bad[] = {"1e999", "-1e999", "1.5", "\"8\"", "true", "null", "[1]", "{}"};
        for (size_t k = 0; k < sizeof bad / sizeof bad[0]; k++) {
            char fields[256];
            int_field_body(fields, sizeof fields, f, bad[k]);
            refuse(fields, f->ray, f->name);
        }
    }
}

static void test_camera_numbers_at_their_edges(void)
{
    render_spec s = accept("\"camera\":{\"fov\":1}", false);
    TEST_ASSERT_EQUAL_FLOAT(1.0f, s.fov);
    s = accept("\"camera\":{\"fov\":179}", false);
    TEST_ASSERT_EQUAL_FLOAT(179.0f, s.fov);
    refuse("\"camera\":{\"fov\":0}", false, "camera.fov");
    refuse("\"camera\":{\"fov\":0.999}", false, "camera.fov");
    refuse("\"camera\":{\"fov\":179.001}", false, "camera.fov");
    refuse("\"camera\":{\"fov\":180}", false, "camera.fov");
    refuse("\"camera\":{\"fov\":1e999}", false, "camera.fov");

    s = accept("\"camera\":{\"pitch\":89.9}", false);
    TEST_ASSERT_EQUAL_FLOAT(89.9f, s.pitch);
    TEST_ASSERT_EQUAL_INT(CAMERA_ORBIT, s.camera);
    s = accept("\"camera\":{\"pitch\":-89.9}", false);
    TEST_ASSERT_EQUAL_FLOAT(-89.9f, s.pitch);
    refuse("\"camera\":{\"pitch\":89.91}", false, "camera.pitch");
    refuse("\"camera\":{\"pitch\":-90}", false, "camera.pitch");
    refuse("\"camera\":{\"pitch\":-1e999}", false, "camera.pitch");

    s = accept("\"camera\":{\"yaw\":390}", false);
    TEST_ASSERT_EQUAL_FLOAT(30.0f, s.yaw);
    refuse("\"camera\":{\"yaw\":1e999}", false, "camera.yaw");
    refuse("\"camera\":{\"distance\":0}", false, "camera.distance");
    refuse("\"camera\":{\"distance\":-1}", false, "camera.distance");
    s = accept("\"camera\":{\"distance\":2.5}", false);
    TEST_ASSERT_EQUAL_FLOAT(2.5f, s.distance);
}

static void test_other_numbers_at_their_edges(void)
{
    render_spec s = accept("\"background\":[0,1,0.5]", false);
    TEST_ASSERT_EQUAL_FLOAT(0.0f, s.background.x);
    TEST_ASSERT_EQUAL_FLOAT(1.0f, s.background.y);
    TEST_ASSERT_EQUAL_FLOAT(0.5f, s.background.z);
    refuse("\"background\":[0,1.01,0]", false, "background[1]");
    refuse("\"background\":[-0.01,0,0]", false, "background[0]");
    refuse("\"background\":[0,0,1e999]", false, "background[2]");

    s = accept("\"seed\":0", false);
    TEST_ASSERT_EQUAL_UINT64(0, s.seed);
    s = accept("\"seed\":9007199254740991", false);
    TEST_ASSERT_EQUAL_UINT64(((uint64_t)1 << 53) - 1, s.seed);
    refuse("\"seed\":9007199254740992", false, "seed");
    refuse("\"seed\":9007199254740993", false, "seed"); /* rounds to 2^53 in a double: refused, not changed */
    refuse("\"seed\":-1", false, "seed");
    refuse("\"seed\":1.5", false, "seed");

    s = accept("\"heat_scale\":12.5", false);
    TEST_ASSERT_EQUAL_DOUBLE(12.5, s.heat_scale);
    refuse("\"heat_scale\":0", false, "heat_scale");
    refuse("\"heat_scale\":-1", false, "heat_scale");
    refuse("\"heat_scale\":1e999", false, "heat_scale");
}

/* ---- names, types, required fields ---- */

static void test_defaults_and_names(void)
{
    render_spec s = accept("", false);
    TEST_ASSERT_EQUAL_STRING("m", s.model);
    TEST_ASSERT_EQUAL_INT(ARBOR_ACCEL_BVH, s.kind);
    TEST_ASSERT_EQUAL_INT(ARBOR_BUILD_SAH, s.builder);
    TEST_ASSERT_EQUAL_INT(ARBOR_MODE_SHADED, s.mode);
    TEST_ASSERT_EQUAL_INT(640, s.width);
    TEST_ASSERT_EQUAL_INT(480, s.height);
    TEST_ASSERT_EQUAL_INT(1, s.spp);
    TEST_ASSERT_EQUAL_INT(CAMERA_PROTOCOL, s.camera);
    TEST_ASSERT_EQUAL_INT(RENDER_PNG, s.format);
    TEST_ASSERT_EQUAL_STRING("", s.stream);

    s = accept("\"accel\":\"kd\",\"builder\":\"median\",\"mode\":\"ao\",\"format\":\"json\",\"stream\":\"tab-1\"",
               false);
    TEST_ASSERT_EQUAL_INT(ARBOR_ACCEL_KD, s.kind);
    TEST_ASSERT_EQUAL_INT(ARBOR_BUILD_MEDIAN, s.builder);
    TEST_ASSERT_EQUAL_INT(ARBOR_MODE_AO, s.mode);
    TEST_ASSERT_EQUAL_INT(RENDER_JSON, s.format);
    TEST_ASSERT_EQUAL_STRING("tab-1", s.stream);
    TEST_ASSERT_EQUAL_INT(RENDER_COSTS, accept("\"mode\":\"heat\",\"format\":\"costs\"", false).format);
    TEST_ASSERT_EQUAL_INT(RENDER_PNG, accept("\"format\":\"png\"", false).format);

    refuse("\"accel\":\"octree\"", false, "octree");
    refuse("\"builder\":\"hlbvh\"", false, "hlbvh");
    refuse("\"mode\":\"phong\"", false, "phong");
    refuse("\"format\":\"jpg\"", false, "jpg");
    refuse("\"format\":\"costs\"", false, "format costs needs mode heat, not shaded");
    refuse("\"format\":\"costs\",\"mode\":\"depth\"", false, "format costs needs mode heat, not depth");
    refuse("\"stream\":\"\"", false, "stream");
    char stream[128];
    snprintf(stream, sizeof stream, "\"stream\":\"%065d\"", 0);
    refuse(stream, false, "stream");

    render_spec out;
    arbor_err e;
    TEST_ASSERT_FALSE(read_json("{\"width\":10}", false, &out, &e));
    assert_message(&e, "model", "no model");
    TEST_ASSERT_FALSE(read_json("{\"model\":\"\"}", false, &out, &e));
    assert_message(&e, "model", "empty model");
    TEST_ASSERT_FALSE(read_json("{\"model\":7}", false, &out, &e));
    assert_message(&e, "model|string", "numeric model");
}

static void test_unknown_fields_and_wrong_types_are_named(void)
{
    refuse("\"colour\":1", false, "unknown field 'colour'");
    refuse("\"Width\":10", false, "unknown field 'Width'");
    refuse("\"camera\":{\"zoom\":2}", false, "unknown camera field 'zoom'");
    refuse("\"region\":{\"x\":0,\"y\":0,\"w\":8,\"h\":8,\"z\":1}", false, "unknown region field 'z'");
    /* each request takes only its own fields */
    refuse("\"x\":1", false, "unknown field 'x'");
    refuse("\"x\":1,\"y\":1,\"spp\":4", true, "unknown field 'spp'");
    refuse("\"x\":1,\"y\":1,\"region\":{\"x\":0,\"y\":0,\"w\":8,\"h\":8}", true, "unknown field 'region'");
    refuse("\"x\":1,\"y\":1,\"heat_scale\":2", true, "unknown field 'heat_scale'");

    refuse("\"width\":\"640\"", false, "width|number");
    refuse("\"accel\":1", false, "accel|string");
    refuse("\"background\":\"0.1,0.1,0.1\"", false, "background|three numbers");
    refuse("\"background\":[0.1,0.1]", false, "background|three numbers");
    refuse("\"background\":[0.1,0.1,0.1,0.1]", false, "background|three numbers");
    refuse("\"background\":[0.1,\"x\",0.1]", false, "background[1]|number");
    refuse("\"camera\":[1,2,3]", false, "camera|object");
    refuse("\"camera\":{\"eye\":[1,2],\"target\":[0,0,0]}", false, "camera.eye|three numbers");
    refuse("\"region\":[0,0,8,8]", false, "region|object");
    refuse("\"region\":{\"x\":0,\"y\":0,\"w\":8}", false, "region|x, y, w and h");
    refuse("\"region\":{\"x\":0,\"y\":0,\"w\":0,\"h\":8}", false, "region.w");
    refuse("\"region\":{\"x\":-1,\"y\":0,\"w\":8,\"h\":8}", false, "region.x");
    refuse("\"region\":{\"x\":0,\"y\":0,\"w\":8,\"h\":1.5}", false, "region.h|whole");
}

/* ---- the camera ---- */

static void test_camera_look_at_checks(void)
{
    render_spec s = accept("\"camera\":{\"eye\":[1,2,3],\"target\":[0,0,0],\"up\":[0,0,1],\"fov\":30}", false);
    TEST_ASSERT_EQUAL_INT(CAMERA_LOOK_AT, s.camera);
    TEST_ASSERT_EQUAL_FLOAT(2.0f, s.eye.y);
    TEST_ASSERT_EQUAL_FLOAT(1.0f, s.up.z);
    TEST_ASSERT_EQUAL_FLOAT(30.0f, s.fov);

    refuse("\"camera\":{\"eye\":[1,2,3],\"target\":[1,2,3]}", false, "camera.eye|camera.target");
    /* the default up, (0,1,0), along the view, and a given up along it or zero */
    refuse("\"camera\":{\"eye\":[0,5,0],\"target\":[0,0,0]}", false, "camera.up|parallel");
    refuse("\"camera\":{\"eye\":[0,0,5],\"target\":[0,0,0],\"up\":[0,0,-2]}", false, "camera.up|parallel");
    refuse("\"camera\":{\"eye\":[0,0,5],\"target\":[0,0,0],\"up\":[0,0,0]}", false, "camera.up");
    refuse("\"camera\":{\"eye\":[0,0,5]}", false, "eye and target");
    refuse("\"camera\":{\"target\":[0,0,5],\"up\":[0,1,0]}", false, "eye and target");
    refuse("\"camera\":{\"eye\":[0,0,5],\"target\":[0,0,0],\"yaw\":10}", false, "not both");
    refuse("\"camera\":{\"eye\":[0,1e999,5],\"target\":[0,0,0]}", false, "camera.eye[1]");
}

/* The camera in the parameters is the one arbor_camera_look_at or
 * arbor_camera_orbit makes from the same numbers. */
static void test_params_camera(void)
{
    arbor_render_params p = params_ok("\"camera\":{\"eye\":[1,2,3],\"target\":[0,0.5,0],\"fov\":30},"
                                      "\"width\":200,\"height\":100");
    arbor_camera want;
    arbor_camera_look_at(&want, vec3(1, 2, 3), vec3(0, 0.5f, 0), vec3(0, 1, 0), 30.0f, 200, 100);
    TEST_ASSERT_EQUAL_MEMORY(&want, &p.camera, sizeof want);

    p = params_ok("\"camera\":{\"yaw\":20,\"pitch\":-10,\"distance\":2,\"fov\":60}");
    arbor_camera_orbit(&want, mesh.bounds, 20.0f, -10.0f, 2.0f, 60.0f, 640, 480);
    TEST_ASSERT_EQUAL_MEMORY(&want, &p.camera, sizeof want);

    p = params_ok("");
    arbor_camera_protocol(&want, mesh.bounds, 640, 480);
    TEST_ASSERT_EQUAL_MEMORY(&want, &p.camera, sizeof want);
}

/* ---- regions, cost, the ray's pixel ---- */

static void region_fields(char *out, size_t cap, int x, int y, int w, int h)
{
    snprintf(out, cap, "\"width\":100,\"height\":80,\"region\":{\"x\":%d,\"y\":%d,\"w\":%d,\"h\":%d}", x, y, w, h);
}

static void check_region(int x, int y, int w, int h, bool inside)
{
    char fields[256];
    region_fields(fields, sizeof fields, x, y, w, h);
    if (!inside) {
        params_refused(fields, MAX_PIXELS, "region");
        return;
    }
    arbor_render_params p = params_ok(fields);
    TEST_ASSERT_EQUAL_INT(x, p.region.x);
    TEST_ASSERT_EQUAL_INT(y, p.region.y);
    TEST_ASSERT_EQUAL_INT(w, p.region.w);
    TEST_ASSERT_EQUAL_INT(h, p.region.h);
}

static void test_regions_inside_the_frame(void)
{
    check_region(0, 0, 100, 80, true);  /* the whole frame */
    check_region(10, 20, 30, 40, true); /* inside */
    check_region(99, 79, 1, 1, true);   /* the last pixel */
    check_region(60, 0, 40, 80, true);  /* touching the right edge */
    check_region(0, 50, 100, 30, true); /* touching the bottom */
    check_region(61, 0, 40, 10, false); /* one past the right edge */
    check_region(0, 51, 10, 30, false); /* one past the bottom */
    check_region(100, 0, 1, 1, false);  /* starting outside */
    check_region(0, 80, 1, 1, false);
    check_region(0, 0, 101, 80, false);
    check_region(0, 0, 8192, 8192, false);
}

/* The cost check: pixels (of the region when there is one) x spp, times
 * ao_samples in ao mode, at most max_pixels. */
static void test_cost_limit(void)
{
    render_spec s = accept("\"width\":100,\"height\":80,\"spp\":4", false);
    arbor_render_params p;
    arbor_err e;
    TEST_ASSERT_TRUE_MESSAGE(params_of(&s, 100 * 80 * 4, &p, &e), e.msg);
    params_refused("\"width\":100,\"height\":80,\"spp\":4", 100 * 80 * 4 - 1, "32000|max-pixels");
    params_refused("\"width\":100,\"height\":80,\"mode\":\"ao\",\"ao_samples\":8", 100 * 80 * 8 - 1,
                   "64000|ao_samples");
    s = accept("\"width\":100,\"height\":80,\"spp\":4,\"region\":{\"x\":0,\"y\":0,\"w\":10,\"h\":10}", false);
    TEST_ASSERT_TRUE_MESSAGE(params_of(&s, 10 * 10 * 4, &p, &e), e.msg);
    TEST_ASSERT_FALSE(params_of(&s, 10 * 10 * 4 - 1, &p, &e));
}

static void test_ray_pixel_inside_the_frame(void)
{
    render_spec s = accept("\"width\":100,\"height\":80,\"x\":99,\"y\":79", true);
    TEST_ASSERT_EQUAL_INT(99, s.x);
    TEST_ASSERT_EQUAL_INT(79, s.y);
    s = accept("\"x\":0,\"y\":0", true);
    TEST_ASSERT_EQUAL_INT(0, s.x);
    refuse("\"width\":100,\"height\":80,\"x\":100,\"y\":0", true, "100,0|100x80");
    refuse("\"width\":100,\"height\":80,\"x\":0,\"y\":80", true, "0,80|100x80");
    refuse("\"x\":640,\"y\":0", true, "640x480");
    refuse("\"x\":-1,\"y\":0", true, "x");
    refuse("\"x\":1", true, "x and y");
    refuse("\"y\":1", true, "x and y");
    refuse("", true, "x and y");
}

/* ---- query strings ---- */

static void test_query_values_become_json(void)
{
    assert_query_makes("eye=1,2,3", "{\"camera\":{\"eye\":[1,2,3]}}");
    assert_query_makes("region=0,0,8,8", "{\"region\":{\"x\":0,\"y\":0,\"w\":8,\"h\":8}}");
    assert_query_makes("background=0.1,0.2,0.3", "{\"background\":[0.1,0.2,0.3]}");
    assert_query_makes("model=m&width=64&yaw=30&fov=50",
                       "{\"model\":\"m\",\"width\":64,\"camera\":{\"yaw\":30,\"fov\":50}}");
    assert_query_makes("accel=kd", "{\"accel\":\"kd\"}");

    render_spec s;
    arbor_err e;
    TEST_ASSERT_TRUE_MESSAGE(read_query("model=m&background=0.1,0.2,0.3&region=0,0,8,8&eye=1,2,3&target=0,0,0",
                                        false, &s, &e),
                             e.msg);
    TEST_ASSERT_EQUAL_FLOAT(0.2f, s.background.y);
    TEST_ASSERT_EQUAL_INT(8, s.region.h);
    TEST_ASSERT_EQUAL_INT(CAMERA_LOOK_AT, s.camera);
    TEST_ASSERT_EQUAL_FLOAT(3.0f, s.eye.z);
}

static void test_bad_queries_are_refused(void)
{
    query_refused("model=m&width=640&width=320", false, "width|twice");
    query_refused("model=m&yaw=1&yaw=2", false, "yaw|twice");
    query_refused("model=m&region=0,0,8,8&region=0,0,4,4", false, "region|twice");
    query_refused("model=m&colour=red", false, "unknown query parameter 'colour'");
    query_refused("model=m&camera=1", false, "unknown query parameter 'camera'");
    query_refused("model=m&width", false, "width|value");
    query_refused("model=m&width=", false, "width|number");
    query_refused("model=m&width=abc", false, "width|number|abc");
    query_refused("model=m&width=64,64", false, "width|number");
    query_refused("model=m&width=1e999", false, "width");
    query_refused("model=m&fov=nan", false, "fov");
    query_refused("model=m&yaw=inf", false, "yaw");
    query_refused("model=m&region=0,0,8", false, "region|x,y,w,h");
    query_refused("model=m&region=0,0,8,8,8", false, "region|x,y,w,h");
    query_refused("model=m&region=a,0,8,8", false, "region|x,y,w,h");
    query_refused("model=m&eye=1,2", false, "camera.eye|three numbers");
    query_refused("model=m&eye=1,2,3&target=1,2,3", false, "camera.eye|camera.target");
    query_refused("model=m&eye=0,5,0&target=0,0,0&up=0,1,0", false, "camera.up");
    query_refused("model=m&pitch=90", false, "camera.pitch");
    query_refused("model=m&x=1&y=1", false, "unknown field 'x'");
    query_refused("model=m&width=10&x=10&y=0", true, "10x480");
}

/* The same request as a query and as JSON: the same spec, and the same
 * render parameters (arbor_render_params_init zeroes them, padding too). */
static void assert_same_request(const char *query, const char *json, bool ray)
{
    render_spec from_query, from_json;
    arbor_err e;
    TEST_ASSERT_TRUE_MESSAGE(read_query(query, ray, &from_query, &e), e.msg);
    TEST_ASSERT_TRUE_MESSAGE(read_json(json, ray, &from_json, &e), e.msg);
    TEST_ASSERT_EQUAL_MEMORY_MESSAGE(&from_json, &from_query, sizeof from_json, query);
    arbor_render_params pq, pj;
    TEST_ASSERT_TRUE_MESSAGE(params_of(&from_query, MAX_PIXELS, &pq, &e), e.msg);
    TEST_ASSERT_TRUE_MESSAGE(params_of(&from_json, MAX_PIXELS, &pj, &e), e.msg);
    TEST_ASSERT_EQUAL_MEMORY_MESSAGE(&pj, &pq, sizeof pj, query);
    /* and not merely the defaults on both sides */
    render_spec plain = accept("", false);
    TEST_ASSERT_TRUE_MESSAGE(memcmp(&plain, &from_json, sizeof plain) != 0, json);
}

static void test_query_and_json_give_the_same_params(void)
{
    assert_same_request("model=m&accel=kd&builder=mean&mode=depth&width=321&height=123&spp=9&seed=77"
                        "&eye=1,2,3&target=0,0.5,0&up=0,0,1&fov=33&region=5,6,70,80&background=0,0.5,1"
                        "&format=json&stream=s1",
                        "{\"model\":\"m\",\"accel\":\"kd\",\"builder\":\"mean\",\"mode\":\"depth\","
                        "\"width\":321,\"height\":123,\"spp\":9,\"seed\":77,"
                        "\"camera\":{\"eye\":[1,2,3],\"target\":[0,0.5,0],\"up\":[0,0,1],\"fov\":33},"
                        "\"region\":{\"x\":5,\"y\":6,\"w\":70,\"h\":80},\"background\":[0,0.5,1],"
                        "\"format\":\"json\",\"stream\":\"s1\"}",
                        false);
    assert_same_request("model=m&mode=heat&heat_scale=42.5&yaw=-30&pitch=89.9&distance=1.5&fov=70",
                        "{\"model\":\"m\",\"mode\":\"heat\",\"heat_scale\":42.5,"
                        "\"camera\":{\"yaw\":-30,\"pitch\":89.9,\"distance\":1.5,\"fov\":70}}",
                        false);
    assert_same_request("model=m&mode=ao&ao_samples=256&max_bounces=0&spp=64",
                        "{\"model\":\"m\",\"mode\":\"ao\",\"ao_samples\":256,\"max_bounces\":0,\"spp\":64}", false);
    assert_same_request("model=m&accel=kd&width=200&height=100&x=199&y=0&yaw=10",
                        "{\"model\":\"m\",\"accel\":\"kd\",\"width\":200,\"height\":100,\"x\":199,\"y\":0,"
                        "\"camera\":{\"yaw\":10}}",
                        true);
}

/* A number JSON accepts is accepted from a query too: a subnormal such as
 * 1e-310 is a finite number (strtod reports ERANGE for it, but returns it). */
static void test_query_accepts_what_json_accepts(void)
{
    assert_same_request("model=m&yaw=1e-310", "{\"model\":\"m\",\"camera\":{\"yaw\":1e-310}}", false);
}

int main(void)
{
    arbor_err e;
    if (!arbor_gen_sphere(&mesh, 1, &e)) {
        fprintf(stderr, "%s\n", e.msg);
        return 1;
    }
    UNITY_BEGIN();
    RUN_TEST(test_int_fields_at_their_edges);
    RUN_TEST(test_camera_numbers_at_their_edges);
    RUN_TEST(test_other_numbers_at_their_edges);
    RUN_TEST(test_defaults_and_names);
    RUN_TEST(test_unknown_fields_and_wrong_types_are_named);
    RUN_TEST(test_camera_look_at_checks);
    RUN_TEST(test_params_camera);
    RUN_TEST(test_regions_inside_the_frame);
    RUN_TEST(test_cost_limit);
    RUN_TEST(test_ray_pixel_inside_the_frame);
    RUN_TEST(test_query_values_become_json);
    RUN_TEST(test_bad_queries_are_refused);
    RUN_TEST(test_query_and_json_give_the_same_params);
    RUN_TEST(test_query_accepts_what_json_accepts);
    int failures = UNITY_END();
    arbor_mesh_free(&mesh);
    return failures;
}
