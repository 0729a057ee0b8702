/*
 * metrics.c - counters, histograms and their Prometheus exposition (see
 * metrics.h). Histogram buckets are in seconds, from 1 ms to a minute, so
 * one set serves requests, frames and builds alike.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "metrics.h"

static const double bucket_bounds[METRICS_BUCKETS] = {0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1,
                                                      0.25,  0.5,    1.0,   2.5,  5.0,   10.0, 60.0};

static const char *const route_names[ROUTE_COUNT] = {
    "static", "healthz", "readyz", "metrics", "models", "model", "trees",
    "boxes",  "stats",   "render", "ray",     "bench",  "jobs",  "unknown"};

static const char *const reason_names[CANCEL_REASONS] = {"superseded", "timeout", "shutdown", "client_gone"};

void metrics_init(http_metrics *m)
{
    memset(m, 0, sizeof *m);
    pthread_mutex_init(&m->lock, NULL);
}

void metrics_destroy(http_metrics *m)
{
    pthread_mutex_destroy(&m->lock);
}

static void observe(histogram *h, double seconds)
{
    int b = 0;
    while (b < METRICS_BUCKETS && seconds > bucket_bounds[b])
        b++;
    h->counts[b]++;
    h->sum += seconds;
    h->n++;
}

/* The slot of a status code; codes past METRICS_STATUSES share the last. Lock held. */
static uint32_t status_slot(http_metrics *m, unsigned status)
{
    for (uint32_t i = 0; i < m->nstatuses; i++)
        if (m->statuses[i] == status)
            return i;
    if (m->nstatuses == METRICS_STATUSES)
        return METRICS_STATUSES - 1;
    m->statuses[m->nstatuses] = status;
    return m->nstatuses++;
}

void metrics_request(http_metrics *m, http_route route, unsigned status, double seconds)
{
    pthread_mutex_lock(&m->lock);
    m->requests[route][status_slot(m, status)]++;
    observe(&m->request_seconds[route], seconds);
    pthread_mutex_unlock(&m->lock);
}

void metrics_frame(http_metrics *m, arbor_render_mode mode, uint64_t rays, double render_ms)
{
    pthread_mutex_lock(&m->lock);
    m->frames++;
    m->rays[mode] += rays;
    observe(&m->render_seconds, render_ms / 1e3);
    m->frame_ms[m->frame_ms_next] = render_ms;
    m->frame_ms_next = (m->frame_ms_next + 1) % METRICS_FRAME_WINDOW;
    if (m->frame_ms_count < METRICS_FRAME_WINDOW)
        m->frame_ms_count++;
    pthread_mutex_unlock(&m->lock);
}

void metrics_frame_rejected(http_metrics *m)
{
    pthread_mutex_lock(&m->lock);
    m->frames_rejected++;
    pthread_mutex_unlock(&m->lock);
}

void metrics_frame_cancelled(http_metrics *m, cancel_reason why)
{
    pthread_mutex_lock(&m->lock);
    m->frames_cancelled[why]++;
    pthread_mutex_unlock(&m->lock);
}

void metrics_build(http_metrics *m, arbor_accel_kind kind, arbor_builder builder, double ms, bool ok)
{
    pthread_mutex_lock(&m->lock);
    if (ok) {
        m->builds[kind][builder]++;
        observe(&m->build_seconds, ms / 1e3);
    } else {
        m->builds_failed++;
    }
    pthread_mutex_unlock(&m->lock);
}

static int compare_doubles(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

void metrics_frame_summary(http_metrics *m, uint64_t *frames, uint64_t *rays, double *mean_ms, double *p99_ms)
{
    double window[METRICS_FRAME_WINDOW];
    pthread_mutex_lock(&m->lock);
    uint32_t n = m->frame_ms_count;
    memcpy(window, m->frame_ms, n * sizeof *window);
    *frames = m->frames;
    *rays = 0;
    for (int i = 0; i < ARBOR_MODE_COUNT; i++)
        *rays += m->rays[i];
    pthread_mutex_unlock(&m->lock);
    *mean_ms = *p99_ms = 0.0;
    if (n == 0)
        return;
    double sum = 0.0;
    for (uint32_t i = 0; i < n; i++)
        sum += window[i];
    qsort(window, n, sizeof *window, compare_doubles);
    *mean_ms = sum / n;
    uint32_t k = (uint32_t)(0.99 * (n - 1) + 0.5);
    *p99_ms = window[k];
}

static void expose_histogram(FILE *f, const char *name, const char *labels, const histogram *h)
{
    uint64_t cumulative = 0;
    const char *sep = labels[0] ? "," : "";
    for (int b = 0; b < METRICS_BUCKETS; b++) {
        cumulative += h->counts[b];
        fprintf(f, "%s_bucket{%s%sle=\"%g\"} %llu\n", name, labels, sep, bucket_bounds[b],
                (unsigned long long)cumulative);
    }
    cumulative += h->counts[METRICS_BUCKETS];
    fprintf(f, "%s_bucket{%s%sle=\"+Inf\"} %llu\n", name, labels, sep, (unsigned long long)cumulative);
    const char *open = labels[0] ? "{" : "", *close = labels[0] ? "}" : ""; /* no empty braces */
    fprintf(f, "%s_sum%s%s%s %.9g\n", name, open, labels, close, h->sum);
    fprintf(f, "%s_count%s%s%s %llu\n", name, open, labels, close, (unsigned long long)h->n);
}

static void header(FILE *f, const char *name, const char *type, const char *help)
{
    fprintf(f, "# HELP %s %s\n# TYPE %s %s\n", name, help, name, type);
}

static void expose_requests(FILE *f, const http_metrics *m)
{
    header(f, "arbor_http_requests_total", "counter", "HTTP requests answered, by route and status.");
    for (int r = 0; r < ROUTE_COUNT; r++)
        for (uint32_t s = 0; s < m->nstatuses; s++)
            if (m->requests[r][s] > 0)
                fprintf(f, "arbor_http_requests_total{route=\"%s\",status=\"%u\"} %llu\n", route_names[r],
                        m->statuses[s], (unsigned long long)m->requests[r][s]);
    header(f, "arbor_http_request_seconds", "histogram", "Time from a request's arrival to its answer.");
    for (int r = 0; r < ROUTE_COUNT; r++) {
        char labels[64];
        snprintf(labels, sizeof labels, "route=\"%s\"", route_names[r]);
        if (m->request_seconds[r].n > 0)
            expose_histogram(f, "arbor_http_request_seconds", labels, &m->request_seconds[r]);
    }
}

static void expose_frames(FILE *f, const http_metrics *m, const metrics_gauges *g)
{
    header(f, "arbor_render_seconds", "histogram", "Render time of frames, first tile to last.");
    expose_histogram(f, "arbor_render_seconds", "", &m->render_seconds);
    header(f, "arbor_rays_total", "counter", "Rays traced by frames (primary, shadow, AO, reflection), by mode.");
    for (int i = 0; i < ARBOR_MODE_COUNT; i++)
        fprintf(f, "arbor_rays_total{mode=\"%s\"} %llu\n", arbor_render_mode_name((arbor_render_mode)i),
                (unsigned long long)m->rays[i]);
    header(f, "arbor_frames_total", "counter", "Frames rendered to the end.");
    fprintf(f, "arbor_frames_total %llu\n", (unsigned long long)m->frames);
    header(f, "arbor_frames_queued", "gauge", "Frames admitted beyond those rendering: waiting for a worker or a tree.");
    fprintf(f, "arbor_frames_queued %u\n", g->frames_waiting);
    header(f, "arbor_frames_rendering", "gauge", "Frames rendering now (at most one per worker).");
    fprintf(f, "arbor_frames_rendering %u\n", g->frames_rendering);
    header(f, "arbor_frames_rejected_total", "counter", "Frames refused because the queue was full.");
    fprintf(f, "arbor_frames_rejected_total %llu\n", (unsigned long long)m->frames_rejected);
    header(f, "arbor_frames_cancelled_total", "counter", "Frames cancelled, by reason.");
    for (int i = 0; i < CANCEL_REASONS; i++)
        fprintf(f, "arbor_frames_cancelled_total{reason=\"%s\"} %llu\n", reason_names[i],
                (unsigned long long)m->frames_cancelled[i]);
}

static void expose_store(FILE *f, const http_metrics *m, const metrics_gauges *g)
{
    header(f, "arbor_tree_builds_total", "counter", "Trees built, by kind and builder.");
    for (int k = 0; k < ARBOR_ACCEL_KIND_COUNT; k++)
        for (int b = 0; b < ARBOR_BUILDER_COUNT; b++)
            fprintf(f, "arbor_tree_builds_total{accel=\"%s\",builder=\"%s\"} %llu\n",
                    arbor_accel_kind_name((arbor_accel_kind)k), arbor_builder_name((arbor_builder)b),
                    (unsigned long long)m->builds[k][b]);
    header(f, "arbor_tree_build_failures_total", "counter", "Tree builds that failed or were cancelled.");
    fprintf(f, "arbor_tree_build_failures_total %llu\n", (unsigned long long)m->builds_failed);
    header(f, "arbor_tree_build_seconds", "histogram", "Build time of trees.");
    expose_histogram(f, "arbor_tree_build_seconds", "", &m->build_seconds);
    header(f, "arbor_model_bytes", "gauge", "Bytes held by loaded meshes.");
    fprintf(f, "arbor_model_bytes %llu\n", (unsigned long long)g->model_bytes);
    header(f, "arbor_tree_bytes", "gauge", "Bytes held by built trees.");
    fprintf(f, "arbor_tree_bytes %llu\n", (unsigned long long)g->tree_bytes);
    header(f, "arbor_models_loaded", "gauge", "Models loaded.");
    fprintf(f, "arbor_models_loaded %u\n", g->models);
    header(f, "arbor_uptime_seconds", "gauge", "Seconds since the daemon started.");
    fprintf(f, "arbor_uptime_seconds %.3f\n", g->uptime_s);
}

char *metrics_expose(http_metrics *m, const metrics_gauges *g, size_t *len)
{
    char *text = NULL;
    FILE *f = open_memstream(&text, len);
    if (f == NULL)
        return NULL;
    pthread_mutex_lock(&m->lock);
    expose_requests(f, m);
    expose_frames(f, m, g);
    expose_store(f, m, g);
    pthread_mutex_unlock(&m->lock);
    if (fclose(f) != 0) {
        free(text);
        return NULL;
    }
    return text;
}
