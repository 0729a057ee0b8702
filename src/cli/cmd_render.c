/*
 * cmd_render.c - arbord render: load a model, build one tree, render one
 * frame on the worker pool and write it as a PNG, printing the timings; or,
 * with --url, have daemons render it, in --split regions at once
 * (remote_render.c).
 */
#include <stdio.h>
#include <string.h>

#include "arbor/accel.h"
#include "arbor/load.h"
#include "arbor/png.h"
#include "arbor/render.h"
#include "arbor/sys.h"
#include "cli.h"

static void usage(FILE *out)
{
    fprintf(out,
            "usage: arbord render --model FILE -o OUT.png [options]\n"
            "       arbord render --url http://HOST:PORT --model NAME [--split K] -o OUT.png [options]\n"
            "  --accel bvh|kd          tree kind (default bvh)\n"
            "  --builder NAME          spatial, median, mean, sah (default sah)\n"
            "  --width W --height H    image size, 1..%d (default 1024 x 768)\n"
            "  --spp N                 samples per pixel, 1..%d (default 1)\n"
            "  --mode M                shaded, normals, depth, ao, heat (default shaded)\n"
            "  --yaw D --pitch D       orbit angles in degrees around the model's centre (yaw -3600..3600,\n"
            "                          pitch -%g..%g)\n"
            "  --distance X            orbit distance in model diagonals, %g..%g (default: the protocol\n"
            "                          view's)\n"
            "  --bounces N             mirror reflections, 0..%d (default 4)\n"
            "  --ao-samples N          rays per AO sample, 1..%d (default 8)\n"
            "  --seed N                frame seed for the sample positions, 0..2^53-1 (default 1)\n"
            "  --threads N             render and build threads; 0 = one per core (default 0)\n"
            "  --heat-scale S          heat mode: the cost at the top of the colour scale, %g..%g\n"
            "                          (default: the frame's 99th percentile)\n"
            "  --counts                also report nodes visited and triangles tested per primary ray\n"
            "  --url URL               render on the daemon (or load balancer) at URL; --model names a\n"
            "                          model it serves\n"
            "  --split K               with --url: ask for K horizontal strips at once (default 1)\n"
            "  --connections N         with --url: keep-alive connections at once (default K)\n"
            "Without --yaw/--pitch/--distance the camera is PROTOCOL.md's view.\n",
            ARBOR_MAX_IMAGE_SIZE, ARBOR_MAX_SPP, ARBOR_MAX_PITCH, ARBOR_MAX_PITCH, ARBOR_MIN_DISTANCE,
            ARBOR_MAX_DISTANCE, ARBOR_MAX_BOUNCES, ARBOR_MAX_AO_SAMPLES, ARBOR_MIN_HEAT_SCALE, ARBOR_MAX_HEAT_SCALE);
}

typedef struct {
    const char *model, *output, *url;
    arbor_accel_kind kind;
    arbor_builder builder;
    arbor_render_mode mode;
    int width, height, spp, bounces, ao_samples, threads, split, connections;
    uint64_t seed;
    bool orbit, counts, threads_given;
    double yaw, pitch, distance, heat_scale; /* doubles, as the request's JSON carries them */
} render_args;

static bool takes_value(const char *opt)
{
    static const char *const names[] = {"--model", "-o", "--output", "--accel", "--builder", "--mode", "--width",
                                        "--height", "--spp", "--bounces", "--ao-samples", "--threads", "--seed",
                                        "--url", "--split", "--connections", "--heat-scale", "--yaw", "--pitch",
                                        "--distance"};
    for (size_t i = 0; i < sizeof names / sizeof names[0]; i++)
        if (strcmp(opt, names[i]) == 0)
            return true;
    return false;
}

/* The flags that belong to one side only: the local renderer's threads and
 * counts, the remote one's strips. Returns -1 to go on, else 2. */
static int check_remote_args(const render_args *a)
{
    const char *bad = a->url != NULL ? (a->threads_given ? "--threads" : a->counts ? "--counts" : NULL)
                                     : (a->split > 1 ? "--split" : a->connections > 0 ? "--connections" : NULL);
    if (bad != NULL) {
        fprintf(stderr, "arbord render: %s %s\n", bad,
                a->url != NULL ? "is the local renderer's: the daemons have their own" : "needs --url");
        return 2;
    }
    /* Heat colours scale to the frame's 99th percentile, which no strip
     * knows on its own: every strip must be given the same scale. */
    if (a->split > 1 && a->mode == ARBOR_MODE_HEAT && a->heat_scale <= 0.0) {
        fprintf(stderr, "arbord render: heat mode in %d strips needs --heat-scale S (the whole frame's scale: "
                        "render it once whole and read its X-Heat-Scale or 'heat scale')\n", a->split);
        return 2;
    }
    return -1;
}

/* Parses argv into a; returns -1 to go on, else the exit code. */
static int parse_args(int argc, char **argv, render_args *a)
{
    const char *cmd = "render";
    cli_seen seen = {.n = 0};
    for (int i = 1; i < argc; i++) {
        const char *opt = argv[i], *v = NULL;
        if (strcmp(opt, "--help") == 0 || strcmp(opt, "-h") == 0) {
            usage(stdout);
            return 0;
        }
        if (strcmp(opt, "--counts") != 0 && !takes_value(opt)) {
            fprintf(stderr, "arbord render: unknown option '%s'\n", opt);
            usage(stderr);
            return 2;
        }
        if (!cli_first(cmd, &seen, opt))
            return 2;
        if (strcmp(opt, "--counts") == 0) {
            a->counts = true;
            continue;
        }
        if ((v = cli_value(cmd, argc, argv, &i)) == NULL)
            return 2;
        bool ok = true;
        if (strcmp(opt, "--model") == 0) {
            a->model = v;
        } else if (strcmp(opt, "-o") == 0 || strcmp(opt, "--output") == 0) {
            a->output = v;
        } else if (strcmp(opt, "--accel") == 0) {
            if (!(ok = arbor_accel_kind_parse(v, &a->kind)))
                fprintf(stderr, "arbord render: unknown accel '%s' (bvh, kd)\n", v);
        } else if (strcmp(opt, "--builder") == 0) {
            if (!(ok = arbor_builder_parse(v, &a->builder)))
                fprintf(stderr, "arbord render: unknown builder '%s' (" ARBOR_BUILDER_NAMES ")\n", v);
        } else if (strcmp(opt, "--mode") == 0) {
            if (!(ok = arbor_render_mode_parse(v, &a->mode)))
                fprintf(stderr, "arbord render: unknown mode '%s' (shaded, normals, depth, ao, heat)\n", v);
        } else if (strcmp(opt, "--width") == 0) {
            ok = cli_int(cmd, opt, v, 1, ARBOR_MAX_IMAGE_SIZE, &a->width);
        } else if (strcmp(opt, "--height") == 0) {
            ok = cli_int(cmd, opt, v, 1, ARBOR_MAX_IMAGE_SIZE, &a->height);
        } else if (strcmp(opt, "--spp") == 0) {
            ok = cli_int(cmd, opt, v, 1, ARBOR_MAX_SPP, &a->spp);
        } else if (strcmp(opt, "--bounces") == 0) {
            ok = cli_int(cmd, opt, v, 0, ARBOR_MAX_BOUNCES, &a->bounces);
        } else if (strcmp(opt, "--ao-samples") == 0) {
            ok = cli_int(cmd, opt, v, 1, ARBOR_MAX_AO_SAMPLES, &a->ao_samples);
        } else if (strcmp(opt, "--threads") == 0) {
            ok = a->threads_given = cli_int(cmd, opt, v, 0, 1024, &a->threads);
        } else if (strcmp(opt, "--url") == 0) {
            a->url = v;
        } else if (strcmp(opt, "--split") == 0) {
            ok = cli_int(cmd, opt, v, 1, ARBOR_MAX_IMAGE_SIZE, &a->split);
        } else if (strcmp(opt, "--connections") == 0) {
            ok = cli_int(cmd, opt, v, 1, 256, &a->connections);
        } else if (strcmp(opt, "--heat-scale") == 0) {
            ok = cli_number(cmd, opt, v, ARBOR_MIN_HEAT_SCALE, ARBOR_MAX_HEAT_SCALE, &a->heat_scale);
        } else if (strcmp(opt, "--seed") == 0) {
            ok = cli_u64(cmd, opt, v, ARBOR_MAX_SEED, &a->seed);
        } else if (strcmp(opt, "--yaw") == 0) {
            ok = a->orbit = cli_number(cmd, opt, v, -3600.0, 3600.0, &a->yaw);
        } else if (strcmp(opt, "--pitch") == 0) {
            ok = a->orbit = cli_number(cmd, opt, v, -ARBOR_MAX_PITCH, ARBOR_MAX_PITCH, &a->pitch);
        } else { /* --distance, the last of takes_value's names */
            ok = a->orbit = cli_number(cmd, opt, v, ARBOR_MIN_DISTANCE, ARBOR_MAX_DISTANCE, &a->distance);
        }
        if (!ok)
            return 2;
    }
    if (a->model == NULL || a->output == NULL) {
        fprintf(stderr, "arbord render: %s is required\n", a->model == NULL ? "--model FILE" : "-o OUT.png");
        usage(stderr);
        return 2;
    }
    /* PNG is the one format written: a name promising another (x.jpg) would
     * get PNG bytes under the wrong extension */
    if (!cli_ends_with(a->output, ".png")) {
        fprintf(stderr, "arbord render: -o %s: the image is written as PNG, so its name must end in .png\n",
                a->output);
        return 2;
    }
    return check_remote_args(a);
}

static int render_model(const render_args *a, const arbor_mesh *mesh, arbor_accel *tree, arbor_pool *pool)
{
    arbor_err err;
    arbor_render_params params;
    arbor_render_params_init(&params, mesh, a->width, a->height);
    if (a->orbit)
        arbor_camera_orbit(&params.camera, mesh->bounds, (float)a->yaw, (float)a->pitch, (float)a->distance, 45.0f,
                           a->width, a->height);
    params.mode = a->mode;
    params.spp = a->spp;
    params.max_bounces = a->bounces;
    params.ao_samples = a->ao_samples;
    params.seed = a->seed;
    params.count_primary = a->counts;
    params.heat_scale = a->heat_scale;
    arbor_frame *frame = arbor_render(pool, tree, &params, &err);
    int status = 0;
    if (frame == NULL) {
        fprintf(stderr, "arbord render: %s\n", err.msg);
        status = err.status == ARBOR_ERR_INVALID ? 2 : 1;
    } else {
        const arbor_frame_result *r = arbor_frame_result_of(frame);
        printf("render %dx%d %s spp %d on %d threads: %.1f ms, %llu rays, %.2f Mrays/s\n", r->width, r->height,
               arbor_render_mode_name(a->mode), a->spp, arbor_pool_threads(pool), r->render_ms,
               (unsigned long long)r->rays, r->mrays_per_s);
        if (r->counted)
            printf("per primary ray: %.1f nodes visited (inner and leaf, of the tree rays traverse), %.1f triangles tested\n",
                   r->mean_nodes, r->mean_tris);
        if (a->mode == ARBOR_MODE_HEAT)
            printf("heat scale: %.17g (99th percentile; max %.1f, mean %.1f nodes + triangles per pixel)\n",
                   r->heat_scale, r->heat_max, r->heat_mean);
        double t0 = arbor_now_ms();
        if (!arbor_png_write_file(a->output, r->rgb, r->width, r->height, &err)) {
            fprintf(stderr, "arbord render: %s\n", err.msg);
            status = 1;
        } else {
            printf("wrote %s (png encode %.1f ms)\n", a->output, arbor_now_ms() - t0);
        }
        arbor_frame_release(frame);
    }
    return status;
}

/* The render request (docs/API.md) for the frame a asks for; fields left
 * out take the daemon's defaults, which are the renderer's. */
static cJSON *request_of(const render_args *a)
{
    cJSON *o = cJSON_CreateObject(), *cam = NULL;
    bool ok = o != NULL && cJSON_AddStringToObject(o, "model", a->model) &&
              cJSON_AddStringToObject(o, "accel", arbor_accel_kind_name(a->kind)) &&
              cJSON_AddStringToObject(o, "builder", arbor_builder_name(a->builder)) &&
              cJSON_AddStringToObject(o, "mode", arbor_render_mode_name(a->mode)) &&
              cJSON_AddNumberToObject(o, "width", a->width) && cJSON_AddNumberToObject(o, "height", a->height) &&
              cJSON_AddNumberToObject(o, "spp", a->spp) && cJSON_AddNumberToObject(o, "max_bounces", a->bounces) &&
              cJSON_AddNumberToObject(o, "ao_samples", a->ao_samples) && cJSON_AddNumberToObject(o, "seed", (double)a->seed);
    if (ok && a->heat_scale > 0.0)
        ok = cJSON_AddNumberToObject(o, "heat_scale", a->heat_scale) != NULL;
    if (ok && a->orbit)
        ok = (cam = cJSON_AddObjectToObject(o, "camera")) != NULL && cJSON_AddNumberToObject(cam, "yaw", a->yaw) &&
             cJSON_AddNumberToObject(cam, "pitch", a->pitch) &&
             cJSON_AddNumberToObject(cam, "distance", a->distance) && cJSON_AddNumberToObject(cam, "fov", 45);
    if (!ok) {
        cJSON_Delete(o);
        return NULL;
    }
    return o;
}

static int render_via(const render_args *a)
{
    cJSON *request = request_of(a);
    if (request == NULL) {
        fprintf(stderr, "arbord render: out of memory\n");
        return 1;
    }
    int split = a->split > 0 ? a->split : 1;
    int status = remote_render(a->url, request, a->width, a->height, split, a->connections > 0 ? a->connections : split,
                               a->output);
    cJSON_Delete(request);
    return status;
}

int cmd_render(int argc, char **argv)
{
    render_args a = {.kind = ARBOR_ACCEL_BVH, .builder = ARBOR_BUILD_SAH, .mode = ARBOR_MODE_SHADED, .width = 1024,
                     .height = 768, .spp = 1, .bounces = 4, .ao_samples = 8, .seed = 1};
    float yaw, pitch, distance;
    arbor_camera_orbit_protocol(&yaw, &pitch, &distance);
    a.yaw = yaw, a.pitch = pitch, a.distance = distance;
    int code = parse_args(argc, argv, &a);
    if (code >= 0)
        return code;
    if (a.url != NULL)
        return render_via(&a);

    arbor_mesh mesh;
    arbor_err err;
    double t0 = arbor_now_ms();
    if (!arbor_load_model(a.model, &mesh, &err)) {
        fprintf(stderr, "arbord render: %s\n", err.msg);
        return 1;
    }
    for (uint32_t w = 0; w < mesh.nwarnings; w++)
        fprintf(stderr, "arbord render: warning: %s\n", mesh.warnings[w]);
    printf("model %s: %u triangles, load %.1f ms\n", a.model, mesh.ntris, arbor_now_ms() - t0);
    /* one pool for the whole command: the build and the frame share its workers */
    arbor_pool *pool = arbor_pool_create(a.threads, &err);
    if (pool == NULL) {
        fprintf(stderr, "arbord render: %s\n", err.msg);
        arbor_mesh_free(&mesh);
        return 1;
    }
    arbor_build_opts opts;
    arbor_build_opts_init(&opts, a.kind, a.builder);
    opts.threads = a.threads;
    opts.pool = pool;
    arbor_accel *tree = arbor_accel_build(&mesh, &opts, &err);
    int status = 1;
    if (tree == NULL) {
        fprintf(stderr, "arbord render: build %s %s: %s\n", arbor_accel_kind_name(a.kind),
                arbor_builder_name(a.builder), err.msg);
    } else {
        arbor_tree_stats stats;
        arbor_accel_stats(tree, &stats);
        printf("build %s %s: %.1f ms\n", arbor_accel_kind_name(a.kind), arbor_builder_name(a.builder),
               stats.build_ms);
        status = render_model(&a, &mesh, tree, pool);
        arbor_accel_free(tree);
    }
    arbor_pool_destroy(pool);
    arbor_mesh_free(&mesh);
    return status;
}
