/*
 * metrics.h - the daemon's counters and histograms, and their Prometheus
 * text exposition (format 0.0.4). Private to src/server/.
 *
 * One mutex guards every figure: an update is a few additions, a scrape
 * reads them all at once, so a consistent snapshot costs nothing worth
 * splitting the lock for.
 */
#ifndef ARBOR_SERVER_METRICS_H
#define ARBOR_SERVER_METRICS_H

#include <pthread.h>
#include <stddef.h>
#include <stdint.h>

#include "arbor/accel.h"
#include "arbor/render.h"

/* Routes: the metrics' route label and the access log's. */
typedef enum {
    ROUTE_STATIC,
    ROUTE_HEALTHZ,
    ROUTE_READYZ,
    ROUTE_METRICS,
    ROUTE_MODELS,
    ROUTE_MODEL,
    ROUTE_TREES,
    ROUTE_BOXES,
    ROUTE_STATS,
    ROUTE_RENDER,
    ROUTE_RAY,
    ROUTE_BENCH,
    ROUTE_JOBS,
    ROUTE_UNKNOWN,
    ROUTE_COUNT
} http_route;

#define METRICS_BUCKETS 14
#define METRICS_STATUSES 20
#define METRICS_FRAME_WINDOW 1024

typedef enum { CANCEL_SUPERSEDED, CANCEL_TIMEOUT, CANCEL_SHUTDOWN, CANCEL_CLIENT_GONE, CANCEL_REASONS } cancel_reason;

typedef struct {
    uint64_t counts[METRICS_BUCKETS + 1];  /* the last is +Inf */
    double sum;
    uint64_t n;
} histogram;

typedef struct {
    pthread_mutex_t lock;
    unsigned statuses[METRICS_STATUSES];   /* status codes seen, in first-seen order */
    uint32_t nstatuses;
    uint64_t requests[ROUTE_COUNT][METRICS_STATUSES];
    histogram request_seconds[ROUTE_COUNT];
    histogram render_seconds, build_seconds;
    uint64_t rays[ARBOR_MODE_COUNT];
    uint64_t frames, frames_rejected, frames_cancelled[CANCEL_REASONS];
    uint64_t builds[ARBOR_ACCEL_KIND_COUNT][ARBOR_BUILDER_COUNT];
    uint64_t builds_failed;
    double frame_ms[METRICS_FRAME_WINDOW]; /* the last frames' render times, for mean and p99 */
    uint32_t frame_ms_next, frame_ms_count;
} http_metrics;

/* What a scrape reads from elsewhere (the store, the frame list). */
typedef struct {
    double uptime_s;
    uint32_t frames_waiting, frames_rendering;
    uint64_t model_bytes, tree_bytes;
    uint32_t models;
} metrics_gauges;

void metrics_init(http_metrics *m);
void metrics_destroy(http_metrics *m);
void metrics_request(http_metrics *m, http_route route, unsigned status, double seconds);
void metrics_frame(http_metrics *m, arbor_render_mode mode, uint64_t rays, double render_ms);
void metrics_frame_rejected(http_metrics *m);
void metrics_frame_cancelled(http_metrics *m, cancel_reason why);
void metrics_build(http_metrics *m, arbor_accel_kind kind, arbor_builder builder, double ms, bool ok);
/* Frames rendered, rays traced, mean and 99th percentile frame ms (of the
 * last METRICS_FRAME_WINDOW frames; 0 when none). */
void metrics_frame_summary(http_metrics *m, uint64_t *frames, uint64_t *rays, double *mean_ms, double *p99_ms);
/* The exposition text, malloc'd; NULL when out of memory. */
char *metrics_expose(http_metrics *m, const metrics_gauges *g, size_t *len);

#endif
