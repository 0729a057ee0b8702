/*
 * fuzz_upload.c - a model upload, end to end, on arbitrary bodies.
 *
 * libmicrohttpd's multipart parser needs a connection, so this target runs
 * the real server in-process (arbor_server_start on a free loopback port,
 * its store and a one-worker pool, made once) and sends each input over a
 * real socket, as a client would: the multipart parser, models.c's part
 * handling (file names made safe, parts streamed to a temporary folder,
 * at most 16 of them), the gzip and format sniffing, the loaders through
 * the stored file and its .mtl parts, saving into the models folder and
 * replacing the model in the store. It is slower per input than the other
 * targets, and worth it: nothing here is reachable without a connection.
 *
 * The first byte picks the request: bit 0 a POST of multipart/form-data
 * with the boundary "fzB" (the rest is the body), else a PUT of the rest.
 * The answer must be one the API documents for a bad or good upload
 * (200/201 loaded, 400 malformed, 413 too large, 415 not a model), never a
 * 5xx or a dropped connection; uploads go to one name with replace=1, and
 * the models folder is emptied after each, so the store stays small.
 *
 * libFuzzer's timeout is a SIGALRM every few seconds, installed without
 * SA_RESTART: a blocking connect, send or recv it interrupts fails with
 * EINTR, which the client retries (before it did, an interrupted recv read
 * as "no answer", twice in 4 hours of fuzzing, each time ~6 s into a run).
 */
#include <arpa/inet.h>
#include <errno.h>
#include <netinet/in.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/time.h>
#include <unistd.h>

#include "arbor/server.h"
#include "fuzz.h"

static arbor_server *server;
static char models_dir[256];

static void setup(void)
{
    arbor_err e;
    snprintf(models_dir, sizeof models_dir, "%s/models", fuzz_scratch());
    FUZZ_CHECK(mkdir(models_dir, 0700) == 0, "cannot make %s", models_dir);
    arbor_pool *pool = arbor_pool_create(1, &e);
    FUZZ_CHECK(pool != NULL, "%s", e.msg);
    arbor_store_config sc = {pool, 1, 0, NULL, NULL};
    arbor_store *store = arbor_store_create(&sc, &e);
    FUZZ_CHECK(store != NULL, "%s", e.msg);
    arbor_server_config c = {
        .bind = "127.0.0.1", .threads = 1, .queue = 4, .max_pixels = 1 << 16, .max_body = 1 << 16,
        .max_upload = 1 << 18, .web_dir = models_dir, .upload_dir = models_dir, .connection_limit = 1000,
        .per_ip_limit = 1000, .connection_timeout_s = 10,
    };
    server = arbor_server_start(&c, store, pool, &e);
    FUZZ_CHECK(server != NULL, "%s", e.msg);
    arbor_server_loaded(server);
}

/* Sends all of buf, through interruptions; false when the peer stopped it. */
static bool send_all(int fd, const void *buf, size_t len)
{
    const char *p = buf;
    while (len > 0) {
        ssize_t n = send(fd, p, len, MSG_NOSIGNAL);
        if (n < 0 && errno == EINTR)
            continue;
        if (n <= 0)
            return false;
        p += n;
        len -= (size_t)n;
    }
    return true;
}

/* Sends the request and reads the answer to its end; its status, 0 when
 * none came. */
static int exchange(const char *head, size_t head_len, const uint8_t *body, size_t body_len)
{
    int fd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    FUZZ_CHECK(fd >= 0, "no socket");
    struct timeval tv = {30, 0};
    setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
    struct sockaddr_in a = {.sin_family = AF_INET, .sin_port = htons((uint16_t)arbor_server_port(server))};
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    int rc;
    while ((rc = connect(fd, (struct sockaddr *)&a, sizeof a)) != 0 && (errno == EINTR || errno == EALREADY))
        ;
    FUZZ_CHECK(rc == 0 || errno == EISCONN, "cannot connect to the server");
    /* The server may answer (413) and close before reading it all: a
     * failed send is no failure, the answer is what counts. */
    if (send_all(fd, head, head_len))
        (void)send_all(fd, body, body_len);
    char answer[4096];
    size_t got = 0;
    ssize_t n;
    while ((n = recv(fd, answer + got, sizeof answer - 1 - got, 0)) != 0) {
        if (n < 0 && errno == EINTR)
            continue;
        if (n < 0)
            break;
        if ((got += (size_t)n) == sizeof answer - 1)
            got = 16; /* keep the status line, drop the body */
    }
    close(fd);
    answer[got] = '\0';
    int status = 0;
    sscanf(answer, "HTTP/1.%*d %d", &status);
    return status;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 1)
        return 0;
    if (server == NULL)
        setup();
    bool post = (data[0] & 1) != 0;
    char head[256];
    int n = snprintf(head, sizeof head,
                     "%s /api/models/fz?replace=1 HTTP/1.1\r\nHost: fuzz\r\nConnection: close\r\n"
                     "Content-Type: %s\r\nContent-Length: %zu\r\n\r\n",
                     post ? "POST" : "PUT", post ? "multipart/form-data; boundary=fzB" : "application/octet-stream",
                     size - 1);
    int status = exchange(head, (size_t)n, data + 1, size - 1);
    FUZZ_CHECK(status == 200 || status == 201 || status == 400 || status == 413 || status == 415,
               "answer %d to a %s of %zu bytes", status, post ? "POST" : "PUT", size - 1);
    fuzz_empty_dir(models_dir);
    return 0;
}
