/*
 * server.h - the HTTP/JSON front of the daemon (libmicrohttpd): routes,
 * static files, metrics, access log, readiness and shutdown.
 *
 * The server renders through the pool and keeps models in the store; it
 * owns neither (the caller creates both first and destroys them after
 * arbor_server_stop). It runs on libmicrohttpd's own polling thread (epoll);
 * its callbacks never block: work that takes time (frames, tree builds,
 * uploads, bench jobs) runs on the pool while the connection is suspended,
 * and the worker that finishes resumes it.
 *
 * Readiness: the server starts "loading"; the caller names what is pending
 * (models being loaded, trees prebuilt) with arbor_server_pending and marks
 * each done with arbor_server_pending_done; /readyz answers 200 once
 * arbor_server_loaded has been called and nothing is pending.
 */
#ifndef ARBOR_SERVER_H
#define ARBOR_SERVER_H

#include <stdbool.h>
#include <stdint.h>

#include "arbor/err.h"
#include "arbor/pool.h"
#include "arbor/store.h"

typedef struct {
    const char *bind;          /* address to listen on, "127.0.0.1" */
    int port;                  /* 0: any free port (see arbor_server_port) */
    int threads;               /* the pool's workers, for admission */
    int queue;                 /* frames that may wait beyond `threads` */
    uint64_t max_pixels;       /* width * height * spp (* ao_samples) of one frame */
    uint64_t max_body;         /* JSON bodies */
    uint64_t max_upload;       /* model uploads, and their decompressed size */
    double frame_timeout_s;    /* 0: none */
    const char *web_dir;       /* static files */
    const char *upload_dir;    /* where uploaded models are written (the first --models folder) */
    const char *token;         /* bearer token for state changes, or NULL */
    bool log_json;             /* access log as JSON lines */
    int connection_limit;      /* open connections at most */
    int per_ip_limit;          /* open connections per client address */
    int connection_timeout_s;  /* idle or slow connections are closed after this */
} arbor_server_config;

typedef struct arbor_server arbor_server;

/* Listens and serves. NULL with e filled when the address cannot be bound
 * or the configuration is unusable. */
arbor_server *arbor_server_start(const arbor_server_config *c, arbor_store *store, arbor_pool *pool,
                                 arbor_err *e);
/* The port listened on (the chosen one when the config said 0). */
int arbor_server_port(const arbor_server *s);
/* True when state-changing requests are refused for want of a token (a
 * non-loopback bind without one). */
bool arbor_server_writes_forbidden(const arbor_server *s);

/* Readiness bookkeeping; `what` is copied. */
void arbor_server_pending(arbor_server *s, const char *what);
void arbor_server_pending_done(arbor_server *s, const char *what);
void arbor_server_loaded(arbor_server *s);

/* Turns /readyz to 503, stops accepting, cancels frames and jobs in flight,
 * answers every suspended connection, stops the polling thread and frees the
 * server. The store and pool are the caller's to destroy afterwards. */
void arbor_server_stop(arbor_server *s);

#endif
