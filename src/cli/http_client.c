/*
 * http_client.c - a keep-alive HTTP/1.1 client over blocking sockets (see
 * http_client.h).
 *
 * An answer is read into one growing buffer: the head up to the blank line,
 * then the body by Content-Length, by chunks, or up to the close. Sockets
 * carry SO_RCVTIMEO/SO_SNDTIMEO, so a daemon that stops answering turns
 * into an error instead of a hang.
 */
#include <errno.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/socket.h>
#include <sys/time.h>
#include <unistd.h>

#include "http_client.h"

#define HEAD_MAX (64 * 1024)
#define BODY_MAX ((size_t)1 << 30)

bool hc_init(hc_conn *c, const char *url, int timeout_s, arbor_err *e)
{
    memset(c, 0, sizeof *c);
    c->fd = -1;
    c->timeout_s = timeout_s;
    if (strncmp(url, "http://", 7) != 0)
        return arbor_fail(e, ARBOR_ERR_INVALID, "--url must start with http://, not '%s'", url);
    const char *host = url + 7, *path = strchr(host, '/');
    size_t hostlen = path != NULL ? (size_t)(path - host) : strlen(host);
    const char *colon = memchr(host, ':', hostlen);
    size_t namelen = colon != NULL ? (size_t)(colon - host) : hostlen;
    size_t portlen = colon != NULL ? hostlen - namelen - 1 : 2;
    if (namelen == 0 || namelen >= sizeof c->host || portlen == 0 || portlen >= sizeof c->port ||
        (path != NULL && strlen(path) >= sizeof c->prefix))
        return arbor_fail(e, ARBOR_ERR_INVALID, "--url '%s' is not http://HOST[:PORT][/PATH]", url);
    memcpy(c->host, host, namelen);
    memcpy(c->port, colon != NULL ? colon + 1 : "80", portlen);
    snprintf(c->prefix, sizeof c->prefix, "%s", path != NULL ? path : "");
    size_t n = strlen(c->prefix);
    if (n > 0 && c->prefix[n - 1] == '/')
        c->prefix[n - 1] = '\0';
    return true;
}

void hc_close(hc_conn *c)
{
    if (c->fd >= 0)
        close(c->fd);
    c->fd = -1;
}

static bool fail_net(arbor_err *e, const hc_conn *c, const char *what, int err)
{
    char why[128] = "closed";
    if (err != 0)
        strerror_r(err == EAGAIN ? ETIMEDOUT : err, why, sizeof why);
    return arbor_fail(e, ARBOR_ERR_IO, "%s %s:%s: %s", what, c->host, c->port, why);
}

static bool hc_connect(hc_conn *c, arbor_err *e)
{
    struct addrinfo hints = {0}, *res = NULL;
    hints.ai_socktype = SOCK_STREAM;
    int rc = getaddrinfo(c->host, c->port, &hints, &res);
    if (rc != 0)
        return arbor_fail(e, ARBOR_ERR_IO, "cannot resolve %s: %s", c->host, gai_strerror(rc));
    int err = 0;
    for (struct addrinfo *a = res; a != NULL && c->fd < 0; a = a->ai_next) {
        int fd = socket(a->ai_family, a->ai_socktype | SOCK_CLOEXEC, a->ai_protocol);
        struct timeval tv = {c->timeout_s, 0};
        int one = 1;
        /* No Nagle: a request's head and body go in two sends, and the
         * second must not wait for the ACK of the first. */
        if (fd >= 0 && setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one) == 0 &&
            setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv) == 0 &&
            setsockopt(fd, SOL_SOCKET, SO_SNDTIMEO, &tv, sizeof tv) == 0 && connect(fd, a->ai_addr, a->ai_addrlen) == 0)
            c->fd = fd;
        else {
            err = errno;
            if (fd >= 0)
                close(fd);
        }
    }
    freeaddrinfo(res);
    return c->fd >= 0 || fail_net(e, c, "cannot connect to", err);
}

static bool send_all(hc_conn *c, const void *data, size_t len, arbor_err *e)
{
    const char *p = data;
    while (len > 0) {
        ssize_t n = send(c->fd, p, len, MSG_NOSIGNAL);
        if (n < 0 && errno == EINTR)
            continue;
        if (n <= 0)
            return fail_net(e, c, "cannot send to", errno);
        p += n;
        len -= (size_t)n;
    }
    return true;
}

/* ---- reading the answer ---- */

typedef struct {
    uint8_t *data;
    size_t len, cap, pos; /* pos: how far it has been parsed */
} rbuf;

/* Reads more into b; false on EOF (errno 0) or error. */
static bool fill(hc_conn *c, rbuf *b)
{
    if (b->cap - b->len < 65536) {
        size_t cap = b->cap ? b->cap * 2 : 131072;
        uint8_t *grown = cap <= BODY_MAX + HEAD_MAX ? realloc(b->data, cap) : NULL;
        if (grown == NULL) {
            errno = ENOMEM;
            return false;
        }
        b->data = grown;
        b->cap = cap;
    }
    ssize_t n;
    do
        n = recv(c->fd, b->data + b->len, b->cap - b->len, 0);
    while (n < 0 && errno == EINTR);
    if (n == 0)
        errno = 0;
    if (n <= 0)
        return false;
    b->len += (size_t)n;
    return true;
}

/* Makes sure `need` bytes are buffered from b->pos on. */
static bool want(hc_conn *c, rbuf *b, size_t need, arbor_err *e)
{
    while (b->len - b->pos < need)
        if (!fill(c, b))
            return fail_net(e, c, "the answer was cut short by", errno);
    return true;
}

/* The next line (chunk sizes) from b->pos, without its CRLF. */
static bool read_line(hc_conn *c, rbuf *b, char *line, size_t cap, arbor_err *e)
{
    for (;;) {
        uint8_t *nl = memchr(b->data + b->pos, '\n', b->len - b->pos);
        if (nl != NULL) {
            size_t n = (size_t)(nl - (b->data + b->pos));
            snprintf(line, cap, "%.*s", (int)(n < cap ? n : cap - 1), (const char *)b->data + b->pos);
            line[strcspn(line, "\r")] = '\0';
            b->pos += n + 1;
            return true;
        }
        if (!fill(c, b))
            return fail_net(e, c, "the answer was cut short by", errno);
    }
}

/* Decodes a chunked body in place: the chunks' data moved together at `at`. */
static bool read_chunked(hc_conn *c, rbuf *b, size_t at, size_t *len, arbor_err *e)
{
    char line[64];
    *len = 0;
    for (;;) {
        if (!read_line(c, b, line, sizeof line, e))
            return false;
        char *end;
        size_t n = strtoul(line, &end, 16);
        if (end == line || (*end != '\0' && *end != ';' && *end != ' ' && *end != '\t'))
            return arbor_fail(e, ARBOR_ERR_IO, "a chunk's size line '%s' is no hex number", line);
        if (n == 0)
            return read_line(c, b, line, sizeof line, e); /* the last, empty line */
        if (n > BODY_MAX || !want(c, b, n + 2, e))
            return n > BODY_MAX ? arbor_fail(e, ARBOR_ERR_IO, "a chunk of %zu bytes is too large", n) : false;
        memmove(b->data + at + *len, b->data + b->pos, n);
        *len += n;
        b->pos += n + 2;
    }
}

bool hc_header(const hc_response *r, const char *name, char *out, size_t cap)
{
    size_t n = strlen(name);
    for (const char *p = strchr(r->head, '\n'); p != NULL; p = strchr(p, '\n')) {
        p++;
        if (strncasecmp(p, name, n) == 0 && p[n] == ':') {
            const char *v = p + n + 1;
            while (*v == ' ' || *v == '\t')
                v++;
            size_t vl = strcspn(v, "\r\n");
            snprintf(out, cap, "%.*s", (int)(vl < cap ? vl : cap - 1), v);
            return true;
        }
    }
    return false;
}

/* The end of the head: just past its blank line, or NULL. */
static uint8_t *head_end(const rbuf *b)
{
    for (size_t i = 3; i < b->len; i++)
        if (b->data[i] == '\n' && b->data[i - 1] == '\r' && b->data[i - 2] == '\n' && b->data[i - 3] == '\r')
            return b->data + i + 1;
    return NULL;
}

/* Reads one answer; *fresh_eof is set when the connection closed before
 * its first byte (a kept-alive connection the server had closed). */
static bool read_response(hc_conn *c, hc_response *out, bool *fresh_eof, arbor_err *e)
{
    rbuf b = {0};
    uint8_t *end = NULL;
    *fresh_eof = false;
    while ((end = head_end(&b)) == NULL) {
        if (b.len > HEAD_MAX || !fill(c, &b)) {
            *fresh_eof = b.len == 0 && errno == 0;
            free(b.data);
            return fail_net(e, c, "no answer from", b.len > HEAD_MAX ? EMSGSIZE : errno);
        }
    }
    size_t head_len = (size_t)(end - b.data);
    out->head = malloc(head_len + 1);
    if (out->head == NULL) {
        free(b.data);
        return arbor_fail(e, ARBOR_ERR_NOMEM, "out of memory reading an answer");
    }
    memcpy(out->head, b.data, head_len);
    out->head[head_len] = '\0';
    out->status = strncmp(out->head, "HTTP/1.", 7) == 0 ? atoi(out->head + 9) : 0;
    char value[64];
    bool ok = true, chunked = hc_header(out, "Transfer-Encoding", value, sizeof value) &&
                              strcasecmp(value, "chunked") == 0;
    b.pos = head_len;
    if (chunked) {
        ok = read_chunked(c, &b, head_len, &out->len, e);
    } else if (hc_header(out, "Content-Length", value, sizeof value)) {
        out->len = strtoull(value, NULL, 10);
        ok = out->len <= BODY_MAX ? want(c, &b, out->len, e)
                                  : arbor_fail(e, ARBOR_ERR_IO, "an answer of %zu bytes is too large", out->len);
    } else {
        /* the body ends where the connection does: any other stop is an error */
        while (fill(c, &b))
            ;
        if (errno != 0)
            ok = fail_net(e, c, "the answer was cut short by", errno);
        out->len = b.len - head_len;
        hc_close(c);
    }
    if (hc_header(out, "Connection", value, sizeof value) && strcasecmp(value, "close") == 0)
        hc_close(c);
    if (ok) {
        memmove(b.data, b.data + head_len, out->len);
        out->body = b.data;
    } else {
        free(b.data);
        hc_response_free(out);
    }
    return ok;
}

bool hc_request(hc_conn *c, const char *method, const char *path, const char *content_type, const void *body,
                size_t len, hc_response *out, arbor_err *e)
{
    char head[1024];
    int n = snprintf(head, sizeof head,
                     "%s %s%s HTTP/1.1\r\nHost: %s:%s\r\nUser-Agent: arbord-render\r\nContent-Type: %s\r\n"
                     "Content-Length: %zu\r\n\r\n",
                     method, c->prefix, path, c->host, c->port, content_type, len);
    if (n < 0 || (size_t)n >= sizeof head)
        return arbor_fail(e, ARBOR_ERR_INVALID, "request path too long");
    memset(out, 0, sizeof *out);
    for (int attempt = 0; attempt < 2; attempt++) {
        bool reused = c->fd >= 0, fresh_eof = false;
        if (!reused && !hc_connect(c, e))
            return false;
        bool sent = send_all(c, head, (size_t)n, e) && send_all(c, body, len, e);
        if (sent && read_response(c, out, &fresh_eof, e))
            return true;
        hc_close(c);
        /* A kept-alive connection may have been closed by the server just
         * before this request: one more try on a new one. */
        if (!reused || (sent && !fresh_eof))
            return false;
    }
    return false;
}

void hc_response_free(hc_response *r)
{
    free(r->head);
    free(r->body);
    r->head = NULL;
    r->body = NULL;
}
