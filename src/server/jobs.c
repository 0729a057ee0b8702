/*
 * jobs.c - bench jobs: POST /api/bench starts one and answers 202 at once,
 * GET /api/jobs/{id} reports its progress and the rows so far, DELETE
 * cancels it.
 *
 * Jobs run one at a time on the table's own thread, never on the HTTP
 * thread and never on a pool worker: a benchmark waits for its frames, and
 * a pool worker waiting for the pool could wait for itself. Its renders and
 * builds still run on the shared pool, so they take their fair share of the
 * workers rather than extra threads. Finished jobs are kept (the newest
 * JOBS_KEPT) so that a client can read the result after the fact.
 */
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/random.h>
#include <time.h>
#include <unistd.h>

#include "arbor/bench.h"
#include "arbor/report.h"
#include "arbor/sys.h"
#include "http.h"

#define JOBS_KEPT 64
/* Jobs queued behind the running one at most: each holds its model in
 * memory, and one job can take minutes. */
#define JOBS_QUEUED_MAX 8
#define JOB_RUNS_MAX 20

typedef enum { JOB_QUEUED, JOB_RUNNING, JOB_DONE, JOB_FAILED, JOB_CANCELLED } job_state;

static const char *const state_names[] = {"queued", "running", "done", "failed", "cancelled"};

typedef struct job {
    uint64_t id;
    arbor_model *model;        /* a reference, until the job ends */
    char model_name[ARBOR_MODEL_NAME_MAX + 1];
    arbor_bench_opts opts;
    arbor_bench_row *rows;
    size_t total;
    atomic_bool cancel;
    double created_ms;
    /* protected by the table's lock */
    double started_ms, ended_ms;
    job_state state;
    size_t done;
    char error[512];
    struct job *next;          /* newest first */
} job;

struct job_table {
    pthread_mutex_t lock;
    pthread_cond_t work;       /* a job was queued, or the table is closing */
    job *jobs;                 /* every kept job, newest first */
    uint64_t next_id;
    bool closing;
    pthread_t thread;
    bool started;
    arbor_pool *pool;
    arbor_store *store;        /* whose memory budget a running job's trees count in */
};

static void job_free(job *j)
{
    arbor_model_release(j->model);
    free(j->rows);
    free(j);
}

/* ---- running ---- */

typedef struct {
    job_table *table;
    job *job;
} row_ctx;

static void row_done(void *user, const arbor_bench_row *row, size_t done, size_t total)
{
    (void)row;
    (void)total;
    row_ctx *c = user;
    pthread_mutex_lock(&c->table->lock);
    c->job->done = done;
    pthread_mutex_unlock(&c->table->lock);
}

/* The oldest queued job, or NULL (lock held). */
static job *next_queued(job_table *t)
{
    job *pick = NULL;
    for (job *j = t->jobs; j != NULL; j = j->next)
        if (j->state == JOB_QUEUED)
            pick = j;
    return pick;
}

/* The bytes a job holds at its peak: the ray sets, and the largest of its
 * trees (each built, measured and freed before the next) with Embree's BVH
 * beside it, reckoned as ours. */
static uint64_t job_peak_bytes(const job *j)
{
    uint32_t ntris = arbor_model_mesh(j->model)->ntris;
    uint64_t tree = 0;
    for (int k = 0; k < ARBOR_ACCEL_KIND_COUNT; k++)
        for (int b = 0; b < ARBOR_BUILDER_COUNT; b++)
            if (j->opts.kinds[k] && j->opts.builders[b]) {
                uint64_t need = arbor_store_tree_estimate((arbor_accel_kind)k, (arbor_builder)b, ntris, true);
                tree = need > tree ? need : tree;
            }
    uint64_t embree = j->opts.embree ? arbor_store_tree_estimate(ARBOR_ACCEL_BVH, ARBOR_BUILD_SAH, ntris, false) : 0;
    return arbor_bench_sets_bytes() + tree + embree;
}

static void run_job(job_table *t, job *j)
{
    row_ctx ctx = {t, j};
    j->opts.row_done = row_done;
    j->opts.user = &ctx;
    j->opts.pool = t->pool;
    j->opts.cancel = &j->cancel;
    arbor_err err;
    arbor_err_clear(&err);
    /* the job's trees live outside the store but within --max-memory */
    uint64_t peak = job_peak_bytes(j);
    bool ok = arbor_store_reserve(t->store, peak, "the benchmark", &err);
    if (ok) {
        ok = arbor_bench_mesh(j->model_name, arbor_model_mesh(j->model), &j->opts, j->rows, &err);
        arbor_store_unreserve(t->store, peak);
    }
    pthread_mutex_lock(&t->lock);
    j->ended_ms = arbor_now_ms();
    j->state = ok ? JOB_DONE : err.status == ARBOR_ERR_CANCELLED ? JOB_CANCELLED : JOB_FAILED;
    if (!ok)
        snprintf(j->error, sizeof j->error, "%s", err.msg);
    arbor_model *m = j->model;
    j->model = NULL;
    pthread_mutex_unlock(&t->lock);
    arbor_model_release(m);
}

static void *jobs_thread(void *arg)
{
    job_table *t = arg;
    pthread_mutex_lock(&t->lock);
    for (;;) {
        job *j = next_queued(t);
        if (j == NULL && t->closing)
            break;
        if (j == NULL) {
            pthread_cond_wait(&t->work, &t->lock);
            continue;
        }
        j->state = JOB_RUNNING;
        j->started_ms = arbor_now_ms();
        pthread_mutex_unlock(&t->lock);
        run_job(t, j);
        pthread_mutex_lock(&t->lock);
    }
    pthread_mutex_unlock(&t->lock);
    return NULL;
}

/* Ids name the jobs of one run of one daemon: they count up from a random
 * start, so that an id kept across a restart, or asked of another daemon
 * behind the same load balancer, finds no job (404) rather than another
 * client's. Below 2^53, so that a client may read one as a number. */
static uint64_t job_first_id(void)
{
    uint64_t r;
    if (getrandom(&r, sizeof r, GRND_NONBLOCK) != (ssize_t)sizeof r)
        r = (uint64_t)time(NULL) << 22 ^ (uint64_t)getpid();
    return 1 + (r & ((UINT64_C(1) << 52) - 1));
}

job_table *jobs_create(arbor_pool *pool, arbor_store *store)
{
    job_table *t = calloc(1, sizeof *t);
    if (t == NULL)
        return NULL;
    t->pool = pool;
    t->store = store;
    t->next_id = job_first_id();
    pthread_mutex_init(&t->lock, NULL);
    pthread_cond_init(&t->work, NULL);
    if (pthread_create(&t->thread, NULL, jobs_thread, t) != 0) {
        pthread_cond_destroy(&t->work);
        pthread_mutex_destroy(&t->lock);
        free(t);
        return NULL;
    }
    t->started = true;
    return t;
}

/* Cancels a job (lock held): a queued one ends now, a running one at its
 * next check. Returns the model a queued job held, for the caller to
 * release (after unlocking: freeing a mesh is slow), else NULL. */
static arbor_model *cancel_locked(job *j)
{
    atomic_store(&j->cancel, true);
    if (j->state != JOB_QUEUED)
        return NULL;
    j->state = JOB_CANCELLED;
    j->ended_ms = arbor_now_ms();
    snprintf(j->error, sizeof j->error, "cancelled while queued"); /* a running one says where it stopped */
    arbor_model *m = j->model;
    j->model = NULL;
    return m;
}

void jobs_cancel_all(job_table *t)
{
    pthread_mutex_lock(&t->lock);
    /* shutdown: nothing waits on this lock for the meshes freed under it */
    for (job *j = t->jobs; j != NULL; j = j->next)
        arbor_model_release(cancel_locked(j));
    t->closing = true;
    pthread_cond_broadcast(&t->work);
    pthread_mutex_unlock(&t->lock);
}

void jobs_destroy(job_table *t)
{
    if (t == NULL)
        return;
    jobs_cancel_all(t);
    pthread_join(t->thread, NULL);
    while (t->jobs != NULL) {
        job *next = t->jobs->next;
        job_free(t->jobs);
        t->jobs = next;
    }
    pthread_cond_destroy(&t->work);
    pthread_mutex_destroy(&t->lock);
    free(t);
}

/* ---- the routes ---- */

/* Drops finished jobs past the newest JOBS_KEPT (lock held). */
static void trim(job_table *t)
{
    uint32_t n = 0;
    for (job **p = &t->jobs; *p != NULL;) {
        job *j = *p;
        bool over = ++n > JOBS_KEPT && (j->state == JOB_DONE || j->state == JOB_FAILED || j->state == JOB_CANCELLED);
        if (over) {
            *p = j->next;
            job_free(j);
        } else {
            p = &j->next;
        }
    }
}

static cJSON *job_json(const job *j, double now)
{
    cJSON *o = cJSON_CreateObject();
    char id[24];
    snprintf(id, sizeof id, "%" PRIu64, j->id);
    cJSON_AddStringToObject(o, "id", id);
    cJSON_AddStringToObject(o, "model", j->model_name);
    cJSON_AddStringToObject(o, "state", state_names[j->state]);
    cJSON *p = cJSON_AddObjectToObject(o, "progress");
    cJSON_AddNumberToObject(p, "done", (double)j->done);
    cJSON_AddNumberToObject(p, "total", (double)j->total);
    double end = j->ended_ms > 0.0 ? j->ended_ms : now;
    cJSON_AddNumberToObject(o, "elapsed_ms", j->started_ms > 0.0 ? end - j->started_ms : 0.0);
    cJSON *rows = cJSON_AddArrayToObject(o, "rows");
    bool ratios = j->opts.embree && j->state == JOB_DONE;
    for (size_t i = 0; i < j->done; i++)
        json_push(rows, arbor_report_bench_row(&j->rows[i], ratios));
    if (j->error[0] != '\0')
        cJSON_AddStringToObject(o, "error", j->error);
    else
        cJSON_AddNullToObject(o, "error");
    return o;
}

/* Reads a list of names ("bvh", ...) into chosen[]; a missing list means all. */
static bool read_names(http_req *r, const cJSON *list, const char *field, const char *names, bool *chosen,
                       int count, bool (*parse)(const char *, int *))
{
    if (list == NULL) {
        for (int i = 0; i < count; i++)
            chosen[i] = true;
        return true;
    }
    if (!cJSON_IsArray(list) || cJSON_GetArraySize(list) == 0) {
        http_reply_error(r, 400, "bad_request", "%s must be a non-empty array of names", field);
        return false;
    }
    for (const cJSON *v = list->child; v != NULL; v = v->next) {
        int i;
        if (!cJSON_IsString(v) || !parse(v->valuestring, &i)) {
            if (cJSON_IsString(v))
                http_reply_error(r, 400, "bad_request", "unknown %s '%s' (%s)", field, v->valuestring, names);
            else
                http_reply_error(r, 400, "bad_request", "%s must be an array of names (%s)", field, names);
            return false;
        }
        chosen[i] = true;
    }
    return true;
}



static bool read_bench(http_req *r, const cJSON *body, job *j)
{
    static const char *const known[] = {"model", "accel", "builder", "runs", "embree"};
    for (const cJSON *v = body->child; v != NULL; v = v->next) {
        size_t k = 0;
        while (k < sizeof known / sizeof known[0] && strcmp(v->string, known[k]) != 0)
            k++;
        if (k == sizeof known / sizeof known[0]) {
            http_reply_error(r, 400, "bad_request", "unknown field '%s' (model, accel, builder, runs, embree)",
                             v->string);
            return false;
        }
    }
    const cJSON *model = cJSON_GetObjectItemCaseSensitive(body, "model");
    const cJSON *runs = cJSON_GetObjectItemCaseSensitive(body, "runs");
    const cJSON *embree = cJSON_GetObjectItemCaseSensitive(body, "embree");
    if (!cJSON_IsString(model)) {
        http_reply_error(r, 400, "bad_request", "model (a string) is required");
        return false;
    }
    if (!sync_name_valid(r, model->valuestring))
        return false;
    arbor_bench_opts_init(&j->opts);
    memset(j->opts.kinds, 0, sizeof j->opts.kinds);
    memset(j->opts.builders, 0, sizeof j->opts.builders);
    if (!read_names(r, cJSON_GetObjectItemCaseSensitive(body, "accel"), "accel", ARBOR_ACCEL_KIND_NAMES,
                    j->opts.kinds, ARBOR_ACCEL_KIND_COUNT, arbor_bench_kind_index) ||
        !read_names(r, cJSON_GetObjectItemCaseSensitive(body, "builder"), "builder", ARBOR_BUILDER_NAMES,
                    j->opts.builders, ARBOR_BUILDER_COUNT, arbor_bench_builder_index))
        return false;
    j->opts.runs = 1;
    if (runs != NULL) {
        /* in range before the cast: a double beyond int's range makes it undefined */
        if (!cJSON_IsNumber(runs) || !(runs->valuedouble >= 1 && runs->valuedouble <= JOB_RUNS_MAX) ||
            runs->valuedouble != (int)runs->valuedouble) {
            http_reply_error(r, 400, "bad_request", "runs must be a whole number in 1..%d", JOB_RUNS_MAX);
            return false;
        }
        j->opts.runs = (int)runs->valuedouble;
    }
    /* "robust": Embree in its robust mode, as arbord bench --embree-robust */
    bool robust = cJSON_IsString(embree) && strcmp(embree->valuestring, "robust") == 0;
    if (embree != NULL && !cJSON_IsBool(embree) && !robust) {
        http_reply_error(r, 400, "bad_request", "embree must be true, false or \"robust\"");
        return false;
    }
    j->opts.embree = cJSON_IsTrue(embree) || robust;
    j->opts.embree_robust = robust;
    j->opts.threads = r->srv->config.threads;
    snprintf(j->model_name, sizeof j->model_name, "%s", model->valuestring);
    return true;
}

void route_bench(http_req *r)
{
    if (!http_may_write(r))
        return;
    cJSON *body = http_body_json(r);
    if (body == NULL)
        return;
    job *j = calloc(1, sizeof *j);
    bool ok = j != NULL && read_bench(r, body, j);
    cJSON_Delete(body);
    if (j == NULL)
        http_reply_error(r, 507, "insufficient_memory", "out of memory");
    if (ok && (j->model = sync_model(r, j->model_name)) == NULL)
        ok = false;
    if (ok) {
        j->total = arbor_bench_row_count(&j->opts);
        j->rows = calloc(j->total, sizeof *j->rows);
        if (j->rows == NULL) {
            http_reply_error(r, 507, "insufficient_memory", "out of memory");
            ok = false;
        }
    }
    if (!ok) {
        if (j != NULL)
            job_free(j);
        return;
    }
    job_table *t = r->srv->jobs;
    atomic_init(&j->cancel, false);
    j->created_ms = arbor_now_ms();
    pthread_mutex_lock(&t->lock);
    uint32_t queued = 0;
    for (const job *q = t->jobs; q != NULL; q = q->next)
        queued += q->state == JOB_QUEUED;
    /* closing: jobs_cancel_all has run (a route that began before the stop
     * ends after it), and a job queued now would run on into the shutdown */
    bool closing = t->closing;
    if (closing || queued >= JOBS_QUEUED_MAX) {
        pthread_mutex_unlock(&t->lock);
        job_free(j);
        if (closing) {
            http_reply_stopping(r);
        } else {
            http_reply_error(r, 503, "busy", "%d bench jobs are queued: try again when one has run", JOBS_QUEUED_MAX);
            http_reply_header(r, "Retry-After", "10");
        }
        return;
    }
    j->id = t->next_id++;
    j->state = JOB_QUEUED;
    j->next = t->jobs;
    t->jobs = j;
    trim(t);
    cJSON *o = job_json(j, arbor_now_ms());
    pthread_cond_signal(&t->work);
    pthread_mutex_unlock(&t->lock);
    char location[48];
    snprintf(location, sizeof location, "/api/jobs/%" PRIu64, j->id);
    http_reply_json(r, 202, o);
    http_reply_header(r, MHD_HTTP_HEADER_LOCATION, location);
}

void route_job(http_req *r, const char *id)
{
    bool get = http_method_is(r, "GET") || http_method_is(r, "HEAD"), del = http_method_is(r, "DELETE");
    if (!get && !del) {
        http_method_not_allowed(r, "GET, HEAD, DELETE");
        return;
    }
    if (!http_args_known(r, "") || (del && !http_may_write(r)))
        return;
    char *end;
    uint64_t want = strtoull(id, &end, 10);
    job_table *t = r->srv->jobs;
    pthread_mutex_lock(&t->lock);
    job *j = t->jobs;
    /* only the id as job_json writes it: no sign, space or leading zero that strtoull would take */
    bool canonical = id[0] >= '1' && id[0] <= '9' && *end == '\0';
    while (j != NULL && (j->id != want || !canonical))
        j = j->next;
    arbor_model *dropped = j != NULL && del ? cancel_locked(j) : NULL;
    cJSON *o = j != NULL ? job_json(j, arbor_now_ms()) : NULL;
    pthread_mutex_unlock(&t->lock);
    arbor_model_release(dropped);
    if (o == NULL)
        http_reply_error(r, 404, "not_found", "no job %s", id);
    else
        http_reply_json(r, 200, o);
}
