"""Static files: index.html for /, Content-Type, ETag, Cache-Control, 304; nothing outside --web."""
import os
import tempfile
import time

from harness import Daemon, check, eq, expect_error, expect_ok, fail, our, shared, test

SECRET = b"ARBOR-SECRET-MARKER-7f3a"
INDEX = b"<!doctype html><title>arbor test</title><p>index of the test web folder</p>\n"
CSS = b"body { color: #123456; }\n"
JS = b"console.log('arbor');\n"


def web_daemon():
    def make():
        root = tempfile.mkdtemp(prefix="arbor-web-")
        web = os.path.join(root, "web")
        os.makedirs(os.path.join(web, "sub"))
        with open(os.path.join(root, "secret.txt"), "wb") as f:
            f.write(SECRET)
        for name, data in (("index.html", INDEX), ("style.css", CSS), ("app.js", JS),
                           ("sub/page.html", INDEX.replace(b"index", b"sub page")),
                           ("data.json", b'{"a": 1}\n'), ("pic.png", b"\x89PNG\r\n\x1a\nnot really")):
            with open(os.path.join(web, name), "wb") as f:
                f.write(data)
        os.symlink(os.path.join(root, "secret.txt"), os.path.join(web, "link-out.txt"))
        os.symlink("../secret.txt", os.path.join(web, "rel-link-out.txt"))
        os.symlink(root, os.path.join(web, "linkdir"))
        os.symlink("/etc/passwd", os.path.join(web, "passwd"))
        os.mkfifo(os.path.join(web, "pipe.txt"))
        d = Daemon([our("cornell.obj")], ["--threads", "1", "--web", web], name="web daemon")
        d.web = web
        d.root = root
        return d
    return shared("web", make)


@test
def test_static_index_for_root():
    d = web_daemon()
    r = d.get("/")
    expect_ok(r)
    eq(r.body, INDEX, "GET / body (the web folder's index.html)")
    check(r.header("Content-Type", "").startswith("text/html"), "GET / Content-Type %r" % r.header("Content-Type"))
    r2 = d.get("/index.html")
    eq(r2.body, INDEX, "GET /index.html body")
    r3 = d.get("/sub/page.html")
    eq(r3.body, INDEX.replace(b"index", b"sub page"), "GET /sub/page.html body")


@test
def test_static_content_types():
    d = web_daemon()
    for path, want in (("/style.css", "text/css"), ("/app.js", ("application/javascript", "text/javascript")),
                       ("/data.json", "application/json"), ("/pic.png", "image/png"),
                       ("/index.html", "text/html")):
        r = d.get(path)
        expect_ok(r)
        ct = r.header("Content-Type", "")
        wants = want if isinstance(want, tuple) else (want,)
        check(any(ct.startswith(w) for w in wants), "GET %s Content-Type %r, expected %s" % (path, ct, want))


@test
def test_static_etag_and_304():
    d = web_daemon()
    r = d.get("/style.css")
    expect_ok(r)
    eq(r.body, CSS, "GET /style.css body")
    etag = r.header("ETag")
    check(etag, "GET /style.css without ETag")
    cc = r.header("Cache-Control", "")
    check("no-cache" in cc, "GET /style.css Cache-Control %r, expected no-cache" % cc)
    r2 = d.get("/style.css", headers={"If-None-Match": etag})
    eq(r2.status, 304, "GET /style.css with If-None-Match: its ETag")
    eq(r2.body, b"", "304 body")
    r3 = d.get("/style.css", headers={"If-None-Match": '"something-else"'})
    eq(r3.status, 200, "GET /style.css with a stale If-None-Match")
    eq(d.get("/style.css", headers={"If-None-Match": "*"}).status, 304, "GET /style.css with If-None-Match: *")
    # ETag follows size and modification time
    path = os.path.join(d.web, "style.css")
    with open(path, "wb") as f:
        f.write(CSS + b"p { margin: 0; }\n")
    os.utime(path, (time.time() + 5, time.time() + 5))
    r4 = d.get("/style.css", headers={"If-None-Match": etag})
    eq(r4.status, 200, "GET /style.css after the file changed, with the old ETag")
    check(r4.header("ETag") != etag, "ETag unchanged after the file changed")
    with open(path, "wb") as f:
        f.write(CSS)


TRAVERSALS = [
    "/../secret.txt",
    "/../../../../etc/passwd",
    "/%2e%2e/secret.txt",
    "/%2E%2E/%2E%2E/etc/passwd",
    "/..%2fsecret.txt",
    "/%2e%2e%2fsecret.txt",
    "/sub/../../secret.txt",
    "/sub/%2e%2e/%2e%2e/secret.txt",
    "/./../secret.txt",
    "/..\\secret.txt",
    "//etc/passwd",
    "/%2fetc%2fpasswd",
    "/link-out.txt",
    "/rel-link-out.txt",
    "/linkdir/secret.txt",
    "/passwd",
    "/index.html%00.png",
    "/%00",
    "/..%00/secret.txt",
    "/%252e%252e/secret.txt",
]


@test
def test_static_fifo_is_not_found_and_blocks_nothing():
    """A FIFO in the web folder is no file to serve: 404 at once, and the daemon answers the next request
    (opening it for reading would wait for a writer on the polling thread, stopping every request)."""
    d = web_daemon()
    expect_error(d.get("/pipe.txt", timeout=10), 404, "not_found")
    expect_ok(d.get("/healthz", timeout=10))


@test
def test_static_traversal_never_serves_outside():
    d = web_daemon()
    bad = []
    # the absolute path of the secret, too
    paths = TRAVERSALS + ["/" + os.path.join(d.root, "secret.txt"), os.path.join(d.root, "secret.txt")]
    for p in paths:
        r = d.raw(b"GET " + p.encode() + b" HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
        if SECRET in r.body or b"root:x:0:0" in r.body or b"root:" in r.body:
            bad.append("%s -> %d served outside content" % (p, r.status))
        elif r.status == 200:
            bad.append("%s -> 200 (%r)" % (p, r.body[:60]))
        elif r.status not in (400, 403, 404):
            bad.append("%s -> %d, expected 400/403/404" % (p, r.status))
    # a literal NUL byte in the request line
    r = d.raw(b"GET /index.html\x00/../../secret.txt HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
    if SECRET in r.body:
        bad.append("literal NUL -> %d served outside content" % r.status)
    check(d.alive(), "daemon died during the traversal requests")
    if bad:
        fail("; ".join(bad))


@test
def test_static_traversal_answers_are_json_errors():
    """Refused static paths answer the API's error shape (404 not_found, or 400/403)."""
    d = web_daemon()
    for p in ("/../secret.txt", "/%2e%2e/secret.txt", "/link-out.txt", "/index.html%00.png"):
        r = d.raw(b"GET " + p.encode() + b" HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
        check(r.status in (400, 403, 404), "GET %s -> %d" % (p, r.status))
        check(r.header("Content-Type", "").startswith("application/json") and b'"error"' in r.body,
              "GET %s -> %d without a JSON error body: %r" % (p, r.status, r.body[:100]))
