/*
 * static.c - the viewer's files from the web folder: Content-Type by
 * extension, an ETag from size and modification time, revalidation (304).
 *
 * Containment is decided on real paths: the file's realpath must lie inside
 * the web folder's, so neither "..", nor an encoded one (libmicrohttpd has
 * decoded %2e%2e and %2f by now), nor a symbolic link pointing out, can
 * reach outside. A NUL (%00) never gets here decoded (see server.c's
 * unescape), and any other odd path simply names no file.
 */
#define _XOPEN_SOURCE 700 /* realpath */
#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "arbor/sys.h"
#include "http.h"
#include "static.h"

static const struct {
    const char *ext, *type;
} types[] = {
    {".html", "text/html; charset=utf-8"},
    {".js", "text/javascript; charset=utf-8"},
    {".mjs", "text/javascript; charset=utf-8"},
    {".css", "text/css; charset=utf-8"},
    {".json", "application/json"},
    {".svg", "image/svg+xml"},
    {".png", "image/png"},
    {".ico", "image/x-icon"},
    {".txt", "text/plain; charset=utf-8"},
    {".md", "text/plain; charset=utf-8"},
    {".woff2", "font/woff2"},
    {".wasm", "application/wasm"},
};

static const char *content_type(const char *path)
{
    const char *dot = strrchr(path, '.');
    if (dot != NULL)
        for (size_t i = 0; i < sizeof types / sizeof types[0]; i++)
            if (strcmp(dot, types[i].ext) == 0)
                return types[i].type;
    return "application/octet-stream";
}

/* The real path of want in out, when it exists and is root or lies in it. */
static bool real_inside(const char *root, const char *want, char *out)
{
    return realpath(want, out) != NULL && (strcmp(out, root) == 0 || arbor_real_path_inside(out, root));
}

bool static_resolve(const char *web_dir, const char *path, char *out)
{
    char root[PATH_MAX], want[PATH_MAX * 2];
    if (path[0] != '/' || strstr(path, "%00") != NULL || realpath(web_dir, root) == NULL)
        return false;
    int n = snprintf(want, sizeof want, "%s%s", root, path);
    if (n < 0 || (size_t)n >= sizeof want || !real_inside(root, want, out))
        return false;
    /* A folder names its index.html, which may be a link too: it is
     * resolved and checked like the name asked for (tests/fuzz/fuzz_static.c
     * found an index.html linking out of the web folder being served). */
    struct stat st;
    if (stat(out, &st) == 0 && S_ISDIR(st.st_mode)) {
        n = snprintf(want, sizeof want, "%s/index.html", out);
        if (n < 0 || (size_t)n >= sizeof want || !real_inside(root, want, out))
            return false;
    }
    return true;
}

void route_static(http_req *r, const char *path)
{
    char file[PATH_MAX];
    int fd = -1;
    struct stat st;
    if (static_resolve(r->srv->config.web_dir, path, file))
        fd = open(file, O_RDONLY | O_CLOEXEC | O_NONBLOCK); /* a FIFO would block the polling thread */
    if (fd < 0 || fstat(fd, &st) != 0 || !S_ISREG(st.st_mode)) {
        if (fd >= 0)
            close(fd);
        http_reply_error(r, 404, "not_found", "no such file: %s", path);
        return;
    }
    char etag[64];
    snprintf(etag, sizeof etag, "\"%llx-%llx\"", (unsigned long long)st.st_size,
             (unsigned long long)st.st_mtim.tv_sec * 1000000000ull + (unsigned long long)st.st_mtim.tv_nsec);
    const char *match = MHD_lookup_connection_value(r->conn, MHD_HEADER_KIND, MHD_HTTP_HEADER_IF_NONE_MATCH);
    /* "*" matches any current version of the file (RFC 9110, 13.1.2) */
    if (match != NULL && (strstr(match, etag) != NULL || strcmp(match, "*") == 0)) {
        close(fd);
        http_reply_buffer(r, 304, content_type(file), NULL, 0);
    } else {
        struct MHD_Response *resp = MHD_create_response_from_fd((uint64_t)st.st_size, fd);
        if (resp == NULL) {
            close(fd);
            http_reply_error(r, 507, "insufficient_memory", "out of memory sending %s", path);
            return;
        }
        MHD_add_response_header(resp, MHD_HTTP_HEADER_CONTENT_TYPE, content_type(file));
        http_reply_response(r, 200, resp, (uint64_t)st.st_size);
    }
    http_reply_header(r, MHD_HTTP_HEADER_ETAG, etag);
    http_reply_header(r, MHD_HTTP_HEADER_CACHE_CONTROL, "no-cache");
    http_reply_header(r, "X-Content-Type-Options", "nosniff");
}
