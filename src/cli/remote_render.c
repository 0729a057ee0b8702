/*
 * remote_render.c - `arbord render --url`: one frame rendered by daemons,
 * asked for as horizontal strips (the `region` of /api/render) over several
 * keep-alive connections at once, through one daemon or a load balancer in
 * front of many (docs/SCALE.md), and assembled into one PNG.
 *
 * A region is the same pixels, bit for bit, as the whole frame has there,
 * so the assembled image is the frame one daemon renders whole. Each
 * connection takes the next strip not yet asked for until none is left; a
 * strip that fails on the network or with 503 (a queue full, a node
 * stopping) is asked for again after a pause, a few times. Connections run
 * on a pool, one thread each, since each spends its time waiting.
 */
#include <math.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "arbor/png.h"
#include "arbor/pool.h"
#include "arbor/render.h"
#include "arbor/sys.h"
#include "cli.h"
#include "http_client.h"

#define ATTEMPTS 5
#define TIMEOUT_S 600

typedef struct {
    double render_ms;     /* X-Render-Ms of the answer */
    double rays;          /* X-Rays */
    arbor_err err;        /* why it failed, when it did */
    bool ok;
} region_result;

typedef struct {
    const cJSON *request;
    int width, height;
    uint32_t nregions;
    hc_conn *conns;
    uint8_t *rgb;               /* the frame, assembled */
    region_result *results;
    atomic_uint next;           /* the next region to ask for */
    atomic_bool failed;         /* a region failed for good: stop asking */
} remote_frame;

/* Rows [y0, y1) of strip k of n: as even as whole rows allow. */
static void strip_rows(const remote_frame *f, uint32_t k, int *y0, int *y1)
{
    *y0 = (int)((uint64_t)f->height * k / f->nregions);
    *y1 = (int)((uint64_t)f->height * (k + 1) / f->nregions);
}

static void pause_ms(double ms)
{
    struct timespec ts = {(time_t)(ms / 1e3), (long)(fmod(ms, 1e3) * 1e6)};
    nanosleep(&ts, NULL);
}

/* The daemon's {"error":{"message"}} of a failed answer, else its status. */
static void answer_error(const hc_response *r, uint32_t k, arbor_err *e)
{
    cJSON *j = cJSON_ParseWithLength((const char *)r->body, r->len);
    const cJSON *msg = cJSON_GetObjectItemCaseSensitive(cJSON_GetObjectItemCaseSensitive(j, "error"), "message");
    arbor_fail(e, ARBOR_ERR_IO, "region %u: HTTP %d: %s", k, r->status,
               cJSON_IsString(msg) ? msg->valuestring : "(no error message)");
    cJSON_Delete(j);
}

/* Decodes a strip's PNG into its rows of the frame. */
static bool place_strip(remote_frame *f, const hc_response *r, int y0, int y1, region_result *res)
{
    uint8_t *rgb = NULL;
    int w = 0, h = 0;
    if (!arbor_png_decode(r->body, r->len, ARBOR_MAX_IMAGE_SIZE, &rgb, &w, &h, &res->err))
        return false;
    bool fits = w == f->width && h == y1 - y0;
    if (fits)
        memcpy(f->rgb + (size_t)y0 * (size_t)f->width * 3, rgb, (size_t)w * (size_t)h * 3);
    else
        arbor_fail(&res->err, ARBOR_ERR_IO, "rows %d..%d came back %dx%d, not %dx%d", y0, y1, w, h, f->width,
                   y1 - y0);
    free(rgb);
    return fits;
}

/* The request for strip k: the frame's fields plus its region. */
static char *strip_body(const remote_frame *f, int y0, int y1)
{
    cJSON *o = cJSON_Duplicate(f->request, true);
    cJSON *region = o != NULL ? cJSON_AddObjectToObject(o, "region") : NULL;
    char *text = NULL;
    if (region != NULL && cJSON_AddNumberToObject(region, "x", 0) && cJSON_AddNumberToObject(region, "y", y0) &&
        cJSON_AddNumberToObject(region, "w", f->width) && cJSON_AddNumberToObject(region, "h", y1 - y0))
        text = cJSON_PrintUnformatted(o);
    cJSON_Delete(o);
    return text;
}

/* Asks for strip k until it arrives, fails for good, or ATTEMPTS run out.
 * 503 answers and network errors are worth another try (a node stopping,
 * a queue full, a balancer with no node left for a moment). */
static void fetch_strip(remote_frame *f, hc_conn *c, uint32_t k)
{
    region_result *res = &f->results[k];
    int y0, y1;
    strip_rows(f, k, &y0, &y1);
    char *body = strip_body(f, y0, y1);
    if (body == NULL) {
        arbor_fail(&res->err, ARBOR_ERR_NOMEM, "out of memory");
        return;
    }
    for (int attempt = 0; attempt < ATTEMPTS && !res->ok; attempt++) {
        hc_response r;
        double wait_ms = 250.0 * (1 << attempt);
        if (!hc_request(c, "POST", "/api/render", "application/json", body, strlen(body), &r, &res->err)) {
            pause_ms(wait_ms);
            continue;
        }
        char v[64];
        if (r.status == 200) {
            res->ok = place_strip(f, &r, y0, y1, res);
            res->render_ms = hc_header(&r, "X-Render-Ms", v, sizeof v) ? atof(v) : 0.0;
            res->rays = hc_header(&r, "X-Rays", v, sizeof v) ? atof(v) : 0.0;
            attempt = ATTEMPTS; /* a bad image will not get better */
        } else {
            answer_error(&r, k, &res->err);
            if (r.status != 503)
                attempt = ATTEMPTS;
            else
                pause_ms(hc_header(&r, "Retry-After", v, sizeof v) ? atof(v) * 1e3 : wait_ms);
        }
        hc_response_free(&r);
    }
    free(body);
    if (!res->ok)
        atomic_store(&f->failed, true);
}

static void connection_run(void *ctx, uint32_t i)
{
    remote_frame *f = ctx;
    for (;;) {
        uint32_t k = atomic_fetch_add(&f->next, 1);
        if (k >= f->nregions || atomic_load(&f->failed))
            break;
        fetch_strip(f, &f->conns[i], k);
    }
    hc_close(&f->conns[i]);
}

static int by_value(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static void print_summary(const remote_frame *f, const char *url, uint32_t nconn, double ms)
{
    double rays = 0.0, *each = malloc(f->nregions * sizeof *each);
    for (uint32_t k = 0; k < f->nregions; k++) {
        rays += f->results[k].rays;
        if (each != NULL)
            each[k] = f->results[k].render_ms;
    }
    printf("render %dx%d via %s: %u regions on %u connections in %.1f ms, %.0f rays", f->width, f->height, url,
           f->nregions, nconn, ms, rays);
    if (each != NULL) {
        qsort(each, f->nregions, sizeof *each, by_value);
        printf(" (region render ms: min %.1f, median %.1f, max %.1f)", each[0], each[f->nregions / 2],
               each[f->nregions - 1]);
    }
    printf("\n");
    free(each);
}

/* Runs every connection at once: on the caller and a pool of the rest. */
static bool fetch_all(remote_frame *f, uint32_t nconn, arbor_err *e)
{
    arbor_pool *pool = NULL;
    if (nconn > 1 && (pool = arbor_pool_create((int)nconn - 1, e)) == NULL)
        return false;
    arbor_pool_parallel(pool, nconn, nconn, connection_run, f);
    arbor_pool_destroy(pool);
    return true;
}

int remote_render(const char *url, const cJSON *request, int width, int height, int nregions, int nconn,
                  const char *out)
{
    remote_frame f = {.request = request, .width = width, .height = height};
    f.nregions = (uint32_t)(nregions < height ? nregions : height);
    if (nconn > (int)f.nregions)
        nconn = (int)f.nregions;
    f.conns = calloc((size_t)nconn, sizeof *f.conns);
    f.results = calloc(f.nregions, sizeof *f.results);
    f.rgb = calloc((size_t)width * (size_t)height, 3);
    atomic_init(&f.next, 0);
    atomic_init(&f.failed, false);
    arbor_err err;
    arbor_err_clear(&err);
    bool ok = f.conns != NULL && f.results != NULL && f.rgb != NULL;
    if (!ok)
        arbor_fail(&err, ARBOR_ERR_NOMEM, "out of memory for a %dx%d frame", width, height);
    for (int i = 0; ok && i < nconn; i++)
        ok = hc_init(&f.conns[i], url, TIMEOUT_S, &err);
    double t0 = arbor_now_ms();
    ok = ok && fetch_all(&f, (uint32_t)nconn, &err);
    /* The error to show: the first region that failed, not one left unasked after it. */
    for (uint32_t k = 0; ok && k < f.nregions; k++)
        ok = f.results[k].ok;
    for (uint32_t k = 0; !ok && err.msg[0] == '\0' && k < f.nregions; k++)
        err = f.results[k].err;
    if (ok)
        print_summary(&f, url, (uint32_t)nconn, arbor_now_ms() - t0);
    if (ok && !arbor_png_write_file(out, f.rgb, width, height, &err))
        ok = false;
    if (ok)
        printf("wrote %s\n", out);
    else
        fprintf(stderr, "arbord render: %s\n", err.msg[0] ? err.msg : "a region was not rendered");
    free(f.conns);
    free(f.results);
    free(f.rgb);
    return ok ? 0 : err.status == ARBOR_ERR_INVALID ? 2 : 1; /* 2: a usage error (a bad --url), as the local render */
}
