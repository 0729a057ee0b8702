/*
 * cmd_serve.c - arbord serve: the render daemon. Parses the flags, starts
 * the pool, the store and the HTTP server, loads the models and prebuilds
 * their trees while /readyz says what is pending, then waits for SIGINT or
 * SIGTERM and shuts down in order: server (which answers or cancels what is
 * in flight), store, pool.
 *
 * Signals are blocked in every thread and taken by one thread with
 * sigwait, so the shutdown runs as ordinary code, not in a handler.
 */
#define _XOPEN_SOURCE 700 /* realpath */
#include <dirent.h>
#include <errno.h>
#include <limits.h>
#include <pthread.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <unistd.h>

#include "arbor/load.h"
#include "arbor/server.h"
#include "arbor/store.h"
#include "arbor/sys.h"
#include "cli.h"

#define MAX_MODEL_DIRS 16
#define MAX_MODEL_FILES 4096
#define MIB ((uint64_t)1 << 20)

typedef struct {
    arbor_server_config server;
    const char *model_dirs[MAX_MODEL_DIRS];
    int nmodel_dirs;
    const char *prebuild;
    const char *token_file;
    uint64_t max_memory;
} serve_args;

static void usage(FILE *out)
{
    fprintf(out,
            "usage: arbord serve [options]\n"
            "  --bind ADDR          address to listen on (default 127.0.0.1)\n"
            "  --port N             TCP port, 0 for any free one (default 8080)\n"
            "  --models DIR         load every .obj, .obj.gz, .ply, .ply.gz in DIR (repeatable;\n"
            "                       default: the repository's models/)\n"
            "  --threads N          render workers, 0 = one per core (default 0)\n"
            "  --queue N            frames that may wait beyond those rendering (default 16)\n"
            "  --prebuild LIST      all, none, or KIND:BUILDER,... built at start (default bvh:sah)\n"
            "  --web DIR            the viewer's files (default: the repository's web/)\n"
            "  --max-pixels N       most samples per frame: width*height*spp (*ao_samples) (default 16M)\n"
            "  --max-body BYTES     largest JSON body (default 1M)\n"
            "  --max-upload BYTES   largest model upload, also its decompressed size (default 256M)\n"
            "  --max-memory BYTES   memory for models and trees (default: half the physical memory)\n"
            "  --frame-timeout S    cancel frames not answered S s after they arrive (default 60; 0 = never)\n"
            "  --connection-timeout S  close a connection idle or stalled this long (default 30)\n"
            "  --max-connections N  open connections at most; more wait to be accepted (default 1000)\n"
            "  --max-per-ip N       open connections from one address at most (default 512)\n"
            "  --token-file FILE    require 'Authorization: Bearer <first line>' for changes\n"
            "  --log text|json      access log format on stderr (default text)\n"
            "Sizes take K, M or G (powers of 1024).\n");
}

/* A size with an optional K, M or G suffix. */
static bool parse_size(const char *opt, const char *s, uint64_t lo, uint64_t *out)
{
    char *end;
    errno = 0;
    unsigned long long v = strtoull(s, &end, 10);
    uint64_t mult = 1;
    if (*end == 'K' || *end == 'k') mult = 1024, end++;
    else if (*end == 'M' || *end == 'm') mult = MIB, end++;
    else if (*end == 'G' || *end == 'g') mult = MIB * 1024, end++;
    if (errno != 0 || end == s || *end != '\0' || s[0] == '-' || v > UINT64_MAX / mult || v * mult < lo) {
        char least[64] = "a positive size";
        if (lo > 1)
            snprintf(least, sizeof least, "a size of at least %llu bytes", (unsigned long long)lo);
        fprintf(stderr, "arbord serve: %s must be %s (K, M, G allowed), not '%s'\n", opt, least, s);
        return false;
    }
    *out = v * mult;
    return true;
}

/* The repository's folder NAME for an arbord built anywhere inside it
 * (build/arbord, build/san-thread/arbord, ...): the nearest folder above
 * the executable that holds the Makefile and NAME, so `make run` and the
 * sanitizer builds serve the repository's models/ and web/ wherever the
 * checkout is (a stray build/web is not the repository's). */
static bool repo_dir(const char *name, char *out, size_t cap)
{
    char dir[PATH_MAX];
    ssize_t n = readlink("/proc/self/exe", dir, sizeof dir - 1);
    if (n <= 0)
        return false;
    dir[n] = '\0';
    char *slash;
    while ((slash = strrchr(dir, '/')) != NULL) {
        *slash = '\0';
        char marker[PATH_MAX + 16], want[PATH_MAX + 64];
        snprintf(marker, sizeof marker, "%s/Makefile", dir);
        snprintf(want, sizeof want, "%s/%s", dir, name);
        if (access(marker, F_OK) == 0 && access(want, F_OK) == 0) {
            char *real = realpath(want, NULL);
            bool ok = real != NULL && strlen(real) < cap;
            if (ok)
                snprintf(out, cap, "%s", real);
            free(real);
            return ok;
        }
    }
    return false;
}

static void defaults(serve_args *a)
{
    memset(a, 0, sizeof *a);
    arbor_server_config *c = &a->server;
    c->bind = "127.0.0.1";
    c->port = 8080;
    c->threads = 0;
    c->queue = 16;
    c->max_pixels = 16 * MIB;
    c->max_body = MIB;
    c->max_upload = 256 * MIB;
    c->frame_timeout_s = 60.0;
    c->connection_limit = 1000;
    c->per_ip_limit = 512;
    c->connection_timeout_s = 30;
    a->prebuild = "bvh:sah";
    long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGESIZE);
    a->max_memory = pages > 0 && page > 0 ? (uint64_t)pages * (uint64_t)page / 2 : 4096 * MIB;
}

static int parse_args(int argc, char **argv, serve_args *a)
{
    const char *cmd = "serve";
    cli_seen seen = {.n = 0};
    arbor_server_config *c = &a->server;
    for (int i = 1; i < argc; i++) {
        const char *o = argv[i], *v = NULL;
        if (strcmp(o, "--help") == 0 || strcmp(o, "-h") == 0) {
            usage(stdout);
            return 0;
        }
        static const char *const valued[] = {"--bind", "--port", "--models", "--threads", "--queue",
                                             "--prebuild", "--web", "--max-pixels", "--max-body",
                                             "--max-upload", "--max-memory", "--frame-timeout",
                                             "--connection-timeout", "--max-connections", "--max-per-ip",
                                             "--token-file", "--log"};
        bool known = false;
        for (size_t k = 0; k < sizeof valued / sizeof valued[0]; k++)
            known |= strcmp(o, valued[k]) == 0;
        if (!known) {
            fprintf(stderr, "arbord serve: unknown option '%s' (see arbord serve --help)\n", o);
            return 2;
        }
        if (strcmp(o, "--models") != 0 && !cli_first(cmd, &seen, o))
            return 2;
        if ((v = cli_value(cmd, argc, argv, &i)) == NULL)
            return 2;
        bool ok = true;
        if (strcmp(o, "--bind") == 0) c->bind = v;
        else if (strcmp(o, "--port") == 0) ok = cli_int(cmd, o, v, 0, 65535, &c->port);
        else if (strcmp(o, "--threads") == 0) ok = cli_int(cmd, o, v, 0, 1024, &c->threads);
        else if (strcmp(o, "--queue") == 0) ok = cli_int(cmd, o, v, 0, 100000, &c->queue);
        else if (strcmp(o, "--prebuild") == 0) a->prebuild = v;
        else if (strcmp(o, "--web") == 0) c->web_dir = v;
        else if (strcmp(o, "--token-file") == 0) a->token_file = v;
        else if (strcmp(o, "--max-pixels") == 0) ok = parse_size(o, v, 1, &c->max_pixels);
        else if (strcmp(o, "--max-body") == 0) ok = parse_size(o, v, 1, &c->max_body);
        else if (strcmp(o, "--max-upload") == 0) ok = parse_size(o, v, 1, &c->max_upload);
        else if (strcmp(o, "--max-memory") == 0) ok = parse_size(o, v, MIB, &a->max_memory);
        else if (strcmp(o, "--connection-timeout") == 0) ok = cli_int(cmd, o, v, 1, 86400, &c->connection_timeout_s);
        else if (strcmp(o, "--max-connections") == 0) ok = cli_int(cmd, o, v, 1, 1000000, &c->connection_limit);
        else if (strcmp(o, "--max-per-ip") == 0) ok = cli_int(cmd, o, v, 1, 1000000, &c->per_ip_limit);
        else if (strcmp(o, "--frame-timeout") == 0) {
            double s;
            ok = cli_number(cmd, o, v, 0, 86400, &s);
            c->frame_timeout_s = s;
        } else if (strcmp(o, "--log") == 0) {
            ok = strcmp(v, "text") == 0 || strcmp(v, "json") == 0;
            c->log_json = strcmp(v, "json") == 0;
            if (!ok)
                fprintf(stderr, "arbord serve: --log must be text or json, not '%s'\n", v);
        } else if (a->nmodel_dirs == MAX_MODEL_DIRS) {
            fprintf(stderr, "arbord serve: at most %d --models folders\n", MAX_MODEL_DIRS);
            ok = false;
        } else {
            a->model_dirs[a->nmodel_dirs++] = v;
        }
        if (!ok)
            return 2;
    }
    return -1;
}

/* ---- --prebuild ---- */

typedef struct {
    bool want[ARBOR_ACCEL_KIND_COUNT][ARBOR_BUILDER_COUNT];
} prebuild_set;

static bool parse_prebuild(const char *list, prebuild_set *p)
{
    memset(p, 0, sizeof *p);
    if (strcmp(list, "none") == 0)
        return true;
    if (strcmp(list, "all") == 0) {
        memset(p->want, 1, sizeof p->want);
        return true;
    }
    char copy[256];
    snprintf(copy, sizeof copy, "%s", list);
    for (char *save = NULL, *item = strtok_r(copy, ",", &save); item != NULL; item = strtok_r(NULL, ",", &save)) {
        char *colon = strchr(item, ':');
        arbor_accel_kind k;
        arbor_builder b;
        if (colon == NULL || (*colon = '\0', !arbor_accel_kind_parse(item, &k)) ||
            !arbor_builder_parse(colon + 1, &b)) {
            fprintf(stderr, "arbord serve: --prebuild takes all, none or KIND:BUILDER,... (bvh:sah,kd:median), "
                            "not '%s'\n", list);
            return false;
        }
        p->want[k][b] = true;
    }
    return true;
}

/* ---- signals ---- */

typedef struct {
    pthread_mutex_t lock;
    pthread_cond_t changed;
    bool stop;  /* protected by lock */
    int signal;
    sigset_t set;
} stop_flag;

static void *signal_thread(void *arg)
{
    stop_flag *f = arg;
    int sig = 0;
    sigwait(&f->set, &sig);
    pthread_mutex_lock(&f->lock);
    f->stop = true;
    f->signal = sig;
    pthread_cond_broadcast(&f->changed);
    pthread_mutex_unlock(&f->lock);
    return NULL;
}

static bool stop_requested(stop_flag *f)
{
    pthread_mutex_lock(&f->lock);
    bool stop = f->stop;
    pthread_mutex_unlock(&f->lock);
    return stop;
}

/* ---- loading ---- */

/* Model files in the order they are loaded: by the model name they make,
 * and of one name's files, the one arbor_model_file_rank chooses first, as
 * the daemon's checks of the folder choose it at every request (sync.c). */
static int compare_model_files(const void *pa, const void *pb)
{
    const char *a = *(char *const *)pa, *b = *(char *const *)pb;
    char na[ARBOR_MODEL_NAME_MAX + 1], nb[ARBOR_MODEL_NAME_MAX + 1];
    arbor_model_name_of_file(a, na, sizeof na);
    arbor_model_name_of_file(b, nb, sizeof nb);
    int by_name = strcmp(na, nb), by_rank = arbor_model_file_rank(a) - arbor_model_file_rank(b);
    return by_name != 0 ? by_name : by_rank != 0 ? by_rank : strcmp(a, b);
}

typedef struct {
    arbor_server *server;
    char what[ARBOR_MODEL_NAME_MAX + 32];
} prebuild_wait;

static void prebuilt(void *user, arbor_tree *tree, const arbor_err *e)
{
    prebuild_wait *w = user;
    if (tree == NULL)
        fprintf(stderr, "arbord: prebuilding %s failed: %s\n", w->what, e->msg);
    arbor_tree_release(tree);
    arbor_server_pending_done(w->server, w->what);
    free(w);
}

static void prebuild_model(arbor_server *server, arbor_store *store, arbor_model *m, const prebuild_set *p)
{
    for (int k = 0; k < ARBOR_ACCEL_KIND_COUNT; k++)
        for (int b = 0; b < ARBOR_BUILDER_COUNT; b++) {
            if (!p->want[k][b])
                continue;
            prebuild_wait *w = malloc(sizeof *w);
            if (w == NULL)
                continue;
            w->server = server;
            snprintf(w->what, sizeof w->what, "%s %s:%s", arbor_model_name(m),
                     arbor_accel_kind_name((arbor_accel_kind)k), arbor_builder_name((arbor_builder)b));
            arbor_server_pending(server, w->what);
            arbor_tree *tree = NULL;
            arbor_err err;
            arbor_acquire got = arbor_store_acquire_tree(store, m, (arbor_accel_kind)k, (arbor_builder)b, &tree,
                                                         prebuilt, w, &err);
            if (got != ARBOR_ACQUIRE_PENDING) {
                if (got == ARBOR_ACQUIRE_FAILED)
                    fprintf(stderr, "arbord: prebuilding %s failed: %s\n", w->what, err.msg);
                arbor_tree_release(tree);
                arbor_server_pending_done(server, w->what);
                free(w);
            }
        }
}

static void load_one(arbor_server *server, arbor_store *store, const char *dir, const char *file,
                     const prebuild_set *p, uint64_t max_upload)
{
    char name[ARBOR_MODEL_NAME_MAX + 1], path[PATH_MAX];
    if (!arbor_model_name_of_file(file, name, sizeof name) || !arbor_model_name_valid(name)) {
        fprintf(stderr, "arbord: skipping %s/%s: its name makes no model name (" ARBOR_MODEL_NAME_RULE ")\n", dir,
                file);
        return;
    }
    snprintf(path, sizeof path, "%s/%s", dir, file);
    char pending[ARBOR_MODEL_NAME_MAX + 16];
    snprintf(pending, sizeof pending, "%s load", name);
    arbor_server_pending(server, pending);
    arbor_mesh mesh;
    arbor_err err;
    double t0 = arbor_now_ms();
    /* Taken before reading, so that a replacement while it loads is seen
     * as a newer file by the next request (the shared folder, sync.c). */
    uint64_t stamp = arbor_file_stamp(path);
    char *real = realpath(path, NULL);
    if (!arbor_load_model_capped(path, (size_t)(max_upload > ARBOR_LOAD_MAX_BYTES ? max_upload : ARBOR_LOAD_MAX_BYTES),
                                 &mesh, &err)) {
        fprintf(stderr, "arbord: skipping %s: %s\n", path, err.msg);
    } else {
        uint32_t ntris = mesh.ntris;
        for (uint32_t w = 0; w < mesh.nwarnings; w++)
            fprintf(stderr, "arbord: %s: warning: %s\n", path, mesh.warnings[w]);
        uint64_t version = 0;
        if (!arbor_store_add_model(store, name, real != NULL ? real : path, &mesh, 0, &version, &err)) {
            fprintf(stderr, "arbord: skipping %s: %s\n", path, err.msg);
            arbor_mesh_free(&mesh);
        } else {
            fprintf(stderr, "arbord: loaded %s (%u triangles) in %.0f ms\n", name, ntris, arbor_now_ms() - t0);
            /* the model added, not one an upload put in its place meanwhile */
            arbor_model *m = arbor_store_acquire_model(store, name);
            if (m != NULL && arbor_model_version(m) == version) {
                arbor_model_set_stamp(m, stamp);
                prebuild_model(server, store, m, p);
            }
            arbor_model_release(m);
        }
    }
    free(real);
    arbor_server_pending_done(server, pending);
}

static void load_dir(arbor_server *server, arbor_store *store, const char *dir, const prebuild_set *p,
                     uint64_t max_upload, stop_flag *stop)
{
    DIR *d = opendir(dir);
    if (d == NULL) {
        fprintf(stderr, "arbord: cannot read --models %s: %s\n", dir, strerror(errno));
        return;
    }
    char *files[MAX_MODEL_FILES];
    int n = 0;
    struct dirent *ent;
    char base[ARBOR_MODEL_NAME_MAX + 1];
    while ((ent = readdir(d)) != NULL && n < MAX_MODEL_FILES)
        if (ent->d_name[0] != '.' && arbor_model_name_of_file(ent->d_name, base, sizeof base) &&
            (files[n] = strdup(ent->d_name)) != NULL)
            n++;
    closedir(d);
    qsort(files, (size_t)n, sizeof *files, compare_model_files);
    char name[ARBOR_MODEL_NAME_MAX + 1], chosen[ARBOR_MODEL_NAME_MAX + 1] = "";
    int chosen_at = -1; /* the file of the name before */
    for (int i = 0; i < n; i++) {
        arbor_model_name_of_file(files[i], name, sizeof name);
        if (chosen_at >= 0 && name[0] != '\0' && strcmp(name, chosen) == 0) {
            fprintf(stderr, "arbord: skipping %s/%s: model %s is %s's\n", dir, files[i], name, files[chosen_at]);
            continue;
        }
        if (!stop_requested(stop))
            load_one(server, store, dir, files[i], p, max_upload);
        snprintf(chosen, sizeof chosen, "%s", name);
        chosen_at = i;
    }
    for (int i = 0; i < n; i++)
        free(files[i]);
}

/* ---- the daemon ---- */

static bool read_token(const char *file, char **token)
{
    FILE *f = fopen(file, "r");
    char line[512];
    if (f == NULL || fgets(line, sizeof line, f) == NULL) {
        fprintf(stderr, "arbord serve: cannot read --token-file %s: %s\n", file, f ? "it is empty" : strerror(errno));
        if (f != NULL)
            fclose(f);
        return false;
    }
    fclose(f);
    line[strcspn(line, "\r\n")] = '\0';
    if (strlen(line) < 8) {
        fprintf(stderr, "arbord serve: the token in %s must be at least 8 characters\n", file);
        return false;
    }
    *token = strdup(line);
    return *token != NULL;
}

/* Lets the daemon hold as many connections as the hard limit allows. */
static void raise_fd_limit(void)
{
    struct rlimit rl;
    if (getrlimit(RLIMIT_NOFILE, &rl) == 0 && rl.rlim_cur < rl.rlim_max) {
        rl.rlim_cur = rl.rlim_max;
        setrlimit(RLIMIT_NOFILE, &rl);
    }
}

int cmd_serve(int argc, char **argv)
{
    serve_args a;
    defaults(&a);
    int rc = parse_args(argc, argv, &a);
    if (rc >= 0)
        return rc;
    prebuild_set prebuild;
    if (!parse_prebuild(a.prebuild, &prebuild))
        return 2;
    char models_default[PATH_MAX], web_default[PATH_MAX];
    if (a.nmodel_dirs == 0) {
        if (!repo_dir("models", models_default, sizeof models_default)) {
            fprintf(stderr, "arbord serve: no --models folder given and the repository's models/ is not found\n");
            return 2;
        }
        a.model_dirs[a.nmodel_dirs++] = models_default;
    }
    if (a.server.web_dir == NULL) {
        if (!repo_dir("web", web_default, sizeof web_default)) {
            fprintf(stderr, "arbord serve: no --web folder given and the repository's web/ is not found\n");
            return 2;
        }
        a.server.web_dir = web_default;
    }
    /* a folder that cannot be read is a bad flag, not a daemon with no
     * models: the first is where uploads go, and in a cluster, the models */
    for (int i = 0; i < a.nmodel_dirs; i++) {
        DIR *d = opendir(a.model_dirs[i]);
        if (d == NULL) {
            fprintf(stderr, "arbord serve: cannot read --models %s: %s\n", a.model_dirs[i], strerror(errno));
            return 2;
        }
        closedir(d);
    }
    DIR *web = opendir(a.server.web_dir); /* the viewer: without it / would be a 404 */
    if (web == NULL) {
        fprintf(stderr, "arbord serve: cannot read --web %s: %s\n", a.server.web_dir, strerror(errno));
        return 2;
    }
    closedir(web);
    a.server.upload_dir = a.model_dirs[0];
    char *token = NULL;
    if (a.token_file != NULL && !read_token(a.token_file, &token))
        return 2;
    a.server.token = token;
    if (a.server.threads == 0)
        a.server.threads = arbor_cpu_count();
    raise_fd_limit();

    stop_flag stop = {.lock = PTHREAD_MUTEX_INITIALIZER, .changed = PTHREAD_COND_INITIALIZER};
    sigemptyset(&stop.set);
    sigaddset(&stop.set, SIGINT);
    sigaddset(&stop.set, SIGTERM);
    pthread_sigmask(SIG_BLOCK, &stop.set, NULL);
    signal(SIGPIPE, SIG_IGN);

    arbor_err err;
    arbor_pool *pool = arbor_pool_create(a.server.threads, &err);
    arbor_store_config sc = {pool, 0, a.max_memory, NULL, NULL};
    arbor_store *store = pool != NULL ? arbor_store_create(&sc, &err) : NULL;
    arbor_server *server = store != NULL ? arbor_server_start(&a.server, store, pool, &err) : NULL;
    pthread_t sig_thread;
    if (server == NULL || pthread_create(&sig_thread, NULL, signal_thread, &stop) != 0) {
        fprintf(stderr, "arbord serve: %s\n", server == NULL ? err.msg : "cannot start the signal thread");
        arbor_server_stop(server);
        arbor_store_destroy(store);
        arbor_pool_destroy(pool);
        free(token);
        return 2;
    }
    fprintf(stderr, "arbord: listening on http://%s:%d/ (%d threads, queue %d, models %s", a.server.bind,
            arbor_server_port(server), a.server.threads, a.server.queue, a.model_dirs[0]);
    for (int i = 1; i < a.nmodel_dirs; i++)
        fprintf(stderr, ", %s", a.model_dirs[i]);
    fprintf(stderr, ", web %s)\n", a.server.web_dir);
    if (arbor_server_writes_forbidden(server))
        fprintf(stderr, "arbord: warning: listening on %s without --token-file: uploads, deletes, POSTs of trees "
                        "and bench jobs are refused (403); frames and reads stay open\n", a.server.bind);

    for (int i = 0; i < a.nmodel_dirs; i++)
        load_dir(server, store, a.model_dirs[i], &prebuild, a.server.max_upload, &stop);
    arbor_server_loaded(server);
    fprintf(stderr, "arbord: open http://%s:%d/ in a browser\n", a.server.bind, arbor_server_port(server));

    pthread_mutex_lock(&stop.lock);
    while (!stop.stop)
        pthread_cond_wait(&stop.changed, &stop.lock);
    pthread_mutex_unlock(&stop.lock);
    pthread_join(sig_thread, NULL);
    fprintf(stderr, "arbord: %s: shutting down\n", stop.signal == SIGINT ? "SIGINT" : "SIGTERM");
    arbor_server_stop(server);
    arbor_store_destroy(store);
    arbor_pool_destroy(pool);
    free(token);
    fprintf(stderr, "arbord: stopped\n");
    return 0;
}
