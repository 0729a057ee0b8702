"""Token rules: --token-file guards state changes (401); a non-loopback bind without one refuses them (403).
Model names from bodies and queries never reach files outside the models folder."""
import os
import re
import subprocess
import tempfile
import time
import urllib.parse

from harness import (Daemon, check, eq, expect_error, expect_json, expect_ok, ignore, main_daemon, multipart, our, shared,
                     test)

TOKEN = "arbor-test-token-5b0d9e"
OBJ = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"


def token_file():
    fd, path = tempfile.mkstemp(prefix="arbor-token-")
    os.write(fd, (TOKEN + "\n").encode())
    os.close(fd)
    return path


def token_daemon():
    return shared("token", lambda: Daemon([our("cornell.obj"), our("sphere.obj")],
                                          ["--threads", "2", "--token-file", token_file()], copy=True,
                                          name="token daemon"))


GOOD = {"Authorization": "Bearer " + TOKEN}
BAD_AUTH = [None, {"Authorization": "Bearer wrong-token"}, {"Authorization": "Bearer " + TOKEN + "x"},
            {"Authorization": "Bearer " + TOKEN[:-1]}, {"Authorization": "Basic " + TOKEN},
            {"Authorization": TOKEN}, {"Authorization": "Bearer"}]


def _state_changes(name):
    """(method, path, body, content-type) of every kind of state-changing request."""
    mp, mct = multipart([("model", name + "-mp.obj", "model/obj", OBJ)])
    return [
        ("PUT", "/api/models/" + name, OBJ, "application/octet-stream", 201),
        ("POST", "/api/models/" + name + "-mp", mp, mct, 201),
        ("POST", "/api/models/cornell/trees", b'{"accel":"kd","builder":"median","wait":true}', "application/json", 200),
        ("POST", "/api/bench", b'{"model":"cornell","accel":["bvh"],"builder":["sah"],"runs":1}', "application/json", 202),
        ("PUT", "/api/models/" + name + "?replace=1", OBJ, "application/octet-stream", 200),
        ("DELETE", "/api/models/" + name, None, None, 200),
    ]


@test
def test_token_required_for_state_changes():
    d = token_daemon()
    for method, path, body, ct, ok_status in _state_changes("tok"):
        for auth in BAD_AUTH:
            hdrs = dict(auth or {})
            if ct:
                hdrs["Content-Type"] = ct
            r = d.req(method, path, body=body, headers=hdrs)
            e = expect_error(r, 401, "unauthorized")
            check(TOKEN not in e["message"], "the 401 message shows the token")
        hdrs = dict(GOOD)
        if ct:
            hdrs["Content-Type"] = ct
        r = d.req(method, path, body=body, headers=hdrs)
        eq(r.status, ok_status, "%s %s with the right bearer: %s" % (method, path, r.short()))
        if method == "POST" and path == "/api/bench":
            job = r.json()["id"]
            expect_error(d.req("DELETE", "/api/jobs/%s" % job), 401, "unauthorized")
            expect_ok(d.req("DELETE", "/api/jobs/%s" % job, headers=GOOD))
    expect_error(d.get("/api/models/tok"), 404, "not_found")


@test
def test_token_refused_requests_change_nothing():
    d = token_daemon()
    r = d.req("PUT", "/api/models/nope", body=OBJ, headers={"Authorization": "Bearer wrong"})
    expect_error(r, 401, "unauthorized")
    expect_error(d.get("/api/models/nope"), 404, "not_found")
    expect_error(d.req("DELETE", "/api/models/sphere"), 401, "unauthorized")
    eq(d.model("sphere")["triangles"], 5120, "sphere after a refused DELETE")
    expect_error(d.post("/api/models/sphere/trees", {"accel": "kd", "builder": "spatial"}), 401, "unauthorized")
    eq(d.tree("sphere", "kd", "spatial")["state"], "absent", "kd:spatial after a refused POST trees")


def _reads_open(d):
    expect_ok(d.post("/api/render", {"model": "cornell", "width": 16, "height": 16}))
    expect_ok(d.get("/api/render?model=cornell&width=16&height=16"))
    expect_ok(d.post("/api/ray", {"model": "cornell", "width": 16, "height": 16, "x": 8, "y": 8}))
    for p in ("/api/models", "/api/models/cornell", "/api/stats", "/metrics", "/healthz", "/readyz"):
        expect_ok(d.get(p))


@test
def test_token_renders_and_reads_stay_open():
    _reads_open(token_daemon())


def non_loopback_ip():
    try:
        out = subprocess.run(["hostname", "-I"], capture_output=True, timeout=5).stdout.decode()
    except Exception:
        out = ""
    for a in out.split():
        if ":" not in a and not a.startswith("127."):
            return a
    return None


@test
def test_non_loopback_bind_without_token_403():
    ip = non_loopback_ip()
    if not ip:
        ignore("the machine has no non-loopback IPv4 address (hostname -I)")
    d = Daemon([our("cornell.obj")], ["--threads", "1"], bind=ip, copy=True, name="non-loopback daemon")
    try:
        err = d.stderr().lower()
        check("token" in err, "bound to %s without --token-file, the daemon did not say so at start: %r"
              % (ip, d.stderr()[:800]))
        for method, path, body, ct, _ in _state_changes("nl"):
            hdrs = {"Content-Type": ct} if ct else {}
            expect_error(d.req(method, path, body=body, headers=hdrs), 403, "forbidden")
            # a bearer does not help when there is no token file
            hdrs["Authorization"] = "Bearer anything"
            expect_error(d.req(method, path, body=body, headers=hdrs), 403, "forbidden")
        expect_error(d.get("/api/models/nl"), 404, "not_found")
        _reads_open(d)
        d.stop_clean()
    finally:
        d.cleanup()


@test
def test_non_loopback_bind_with_token():
    ip = non_loopback_ip()
    if not ip:
        ignore("the machine has no non-loopback IPv4 address (hostname -I)")
    d = Daemon([our("cornell.obj")], ["--threads", "1", "--token-file", token_file()], bind=ip, copy=True,
               name="non-loopback token daemon")
    try:
        expect_error(d.req("PUT", "/api/models/nlt", body=OBJ), 401, "unauthorized")
        expect_json(d.req("PUT", "/api/models/nlt", body=OBJ, headers=GOOD), 201)
        expect_ok(d.req("DELETE", "/api/models/nlt", headers=GOOD))
        d.stop_clean()
    finally:
        d.cleanup()


@test
def test_wildcard_bind_without_token_403():
    """--bind 0.0.0.0 listens on every address, non-loopback ones included: state changes get 403,
    even from a client on 127.0.0.1."""
    d = Daemon([our("cornell.obj")], ["--threads", "1"], bind="0.0.0.0", copy=True, name="0.0.0.0 daemon")
    try:
        expect_error(d.req("PUT", "/api/models/wild", body=OBJ), 403, "forbidden")
        expect_error(d.req("DELETE", "/api/models/cornell"), 403, "forbidden")
        expect_ok(d.post("/api/render", {"model": "cornell", "width": 16, "height": 16}))
        d.stop_clean()
    finally:
        d.cleanup()


@test
def test_token_scheme_name_in_any_case():
    """The scheme's name is case-insensitive (RFC 9110, 11.1); the token is not."""
    d = token_daemon()
    for scheme in ("bearer", "BEARER", "BeArEr"):
        r = d.post("/api/models/cornell/trees", {"accel": "kd", "builder": "median", "wait": True},
                   headers={"Authorization": scheme + " " + TOKEN})
        eq(r.status, 200, "%s <token>: %s" % (scheme, r.short()))
    expect_error(d.post("/api/models/cornell/trees", {"accel": "kd", "builder": "median"},
                        headers={"Authorization": "bearer " + TOKEN.upper()}), 401, "unauthorized")


@test
def test_model_names_in_bodies_and_queries_stay_in_the_folder():
    """A model name is a file name in the models folder: "../x" named a file beside it, which the daemon read
    (its contents in the error) or served; a name of 65 characters was read again on every retry."""
    d = main_daemon()
    secret = "zzSECRETzz"
    with open(os.path.join(d.tmp, "leak.obj"), "w") as f:
        f.write("v 0 0 0\nv " + secret + " 0 0\n")
    with open(os.path.join(d.tmp, "outside.obj"), "w") as f:
        f.write("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    before = sorted(m["name"] for m in d.get("/api/models").json()["models"])
    view = {"width": 16, "height": 12}
    for name in ("../leak", "../outside", "./../models/../outside", "n" * 65):
        q = urllib.parse.quote(name, safe="")
        for r in (d.get("/api/stats?model=" + q),
                  d.get("/api/render?model=%s&width=16&height=12" % q),
                  d.post("/api/render", dict(view, model=name)),
                  d.post("/api/ray", dict(view, model=name, x=1, y=1)),
                  d.post("/api/bench", {"model": name, "accel": ["bvh"], "builder": ["sah"], "runs": 1})):
            e = expect_error(r, 400, "bad_request", re.compile("is no model name|model must be 1..64 characters"))
            check(secret not in e["message"], "%s: the message shows the outside file: %r" % (r.req, e["message"]))
    eq(sorted(m["name"] for m in d.get("/api/models").json()["models"]), before, "models after the outside names")
