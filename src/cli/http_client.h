/*
 * http_client.h - the little HTTP/1.1 client `arbord render --url` needs:
 * one keep-alive connection per hc_conn over blocking sockets, requests
 * with a body, answers read by Content-Length, chunks or close. Plain http
 * only: a cluster is reached through its load balancer on a private network
 * (docs/SCALE.md); TLS belongs to the balancer.
 *
 * Errors come back as arbor_err (ARBOR_ERR_IO for the network), never
 * printed.
 */
#ifndef ARBOR_CLI_HTTP_CLIENT_H
#define ARBOR_CLI_HTTP_CLIENT_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "arbor/err.h"

typedef struct {
    char host[256];
    char port[8];
    char prefix[256];   /* path of the URL, prepended to every request ("" for none) */
    int fd;             /* -1 when not connected */
    int timeout_s;      /* for connecting, sending and each wait for data */
} hc_conn;

typedef struct {
    int status;
    char *head;         /* the status line and headers, NUL-terminated */
    uint8_t *body;
    size_t len;
} hc_response;

/* Reads http://HOST[:PORT][/PREFIX] into c (not connected yet). */
bool hc_init(hc_conn *c, const char *url, int timeout_s, arbor_err *e);
/* Sends one request and reads its answer into *out (free with
 * hc_response_free). A kept-alive connection the server has closed
 * meanwhile is opened again once, transparently. */
bool hc_request(hc_conn *c, const char *method, const char *path, const char *content_type, const void *body,
                size_t len, hc_response *out, arbor_err *e);
/* The value of header `name` (case-insensitive), copied into out; false
 * when absent. */
bool hc_header(const hc_response *r, const char *name, char *out, size_t cap);
void hc_response_free(hc_response *r);
void hc_close(hc_conn *c);

#endif
