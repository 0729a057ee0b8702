/*
 * fuzz_render_request.c - the render and ray request reader of
 * src/server/render_request.c on arbitrary bytes, in both of its forms.
 *
 * The first byte picks the form and the request kind: bit 0 a JSON body
 * (cJSON, then render_spec_from_json) or a query string ("k=v&k=v", each
 * pair through render_query_add as the daemon does after libmicrohttpd has
 * split and decoded it; a key without '=' has no value); bit 1 a ray
 * request instead of a render. A request that reads is turned into render
 * parameters for a two-triangle mesh (render_spec_params) and, when those
 * pass, rendered: a frame of at most MAX_SAMPLES samples, so the camera and
 * the renderer meet every value the checks let through.
 */
#include <string.h>

#include "arbor/accel.h"
#include "arbor/render.h"
#include "fuzz.h"
#include "../../src/server/render_request.h"

#define MAX_SAMPLES 4096

static arbor_mesh mesh;
static arbor_accel *tree;
static arbor_pool *pool;

static void setup(void)
{
    arbor_err e;
    arbor_mesh_init(&mesh);
    static const arbor_vec3 v[4] = {{-1, -1, 0}, {1, -1, 0}, {1, 1, 0}, {-1, 1, 0.5f}};
    for (int i = 0; i < 4; i++)
        FUZZ_CHECK(arbor_mesh_add_vert(&mesh, v[i], &e), "%s", e.msg);
    FUZZ_CHECK(arbor_mesh_add_tri(&mesh, 0, 1, 2, 0, &e) && arbor_mesh_add_tri(&mesh, 0, 2, 3, 0, &e), "%s", e.msg);
    FUZZ_CHECK(arbor_mesh_finish(&mesh, &e), "%s", e.msg);
    arbor_build_opts o;
    arbor_build_opts_init(&o, ARBOR_ACCEL_BVH, ARBOR_BUILD_SAH);
    o.threads = 1;
    tree = arbor_accel_build(&mesh, &o, &e);
    FUZZ_CHECK(tree != NULL, "%s", e.msg);
    pool = arbor_pool_create(1, &e);
    FUZZ_CHECK(pool != NULL, "%s", e.msg);
}

/* The query string's pairs into obj, as render_route.c collects them. */
static bool read_query(char *q, cJSON *obj, arbor_err *e)
{
    for (char *pair = q, *next; pair != NULL; pair = next) {
        next = strchr(pair, '&');
        if (next != NULL)
            *next++ = '\0';
        if (*pair == '\0')
            continue;
        char *value = strchr(pair, '=');
        if (value != NULL)
            *value++ = '\0';
        if (!render_query_add(obj, pair, value, e))
            return false;
    }
    return true;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 1)
        return 0;
    if (tree == NULL)
        setup();
    bool json = (data[0] & 1) != 0, ray = (data[0] & 2) != 0;
    char *text = malloc(size);
    FUZZ_CHECK(text != NULL, "out of memory");
    memcpy(text, data + 1, size - 1);
    text[size - 1] = '\0';

    arbor_err e;
    arbor_err_clear(&e);
    cJSON *obj;
    bool ok;
    if (json) {
        obj = cJSON_ParseWithLength(text, size - 1);
        ok = cJSON_IsObject(obj);
    } else {
        obj = cJSON_CreateObject();
        FUZZ_CHECK(obj != NULL, "out of memory");
        ok = read_query(text, obj, &e);
        FUZZ_CHECK(ok || e.msg[0] != '\0', "a refused query argument without a message");
    }
    render_spec spec;
    if (ok) {
        ok = render_spec_from_json(obj, ray, &spec, &e);
        FUZZ_CHECK(ok || e.msg[0] != '\0', "a refused request without a message");
    }
    arbor_render_params p;
    if (ok && render_spec_params(&spec, &mesh, MAX_SAMPLES, &p, &e)) {
        FUZZ_CHECK(spec.width > 0 && spec.height > 0 && spec.spp > 0, "a frame of %dx%d, spp %d passed", spec.width,
                   spec.height, spec.spp);
        arbor_frame *f = arbor_render(pool, tree, &p, &e);
        FUZZ_CHECK(f != NULL, "valid parameters did not render: %s", e.msg);
        arbor_frame_release(f);
    }
    cJSON_Delete(obj);
    free(text);
    return 0;
}
