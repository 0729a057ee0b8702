"""Uploads (PUT OBJ/PLY/gzip, multipart .obj + .mtl), 409 and replace, delete, while frames render."""
import gzip
import os
import struct
import threading
import time

from harness import (Daemon, check, eq, expect_error, expect_json, expect_ok, fail, limits_daemon, multipart, parallel,
                     our, png_of, raw_request, shared, test)

CUBE_OBJ = b"""# a unit cube of quads: 8 vertices, 6 faces, 12 triangles
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 0 0 1
v 1 0 1
v 1 1 1
v 0 1 1
f 1 4 3 2
f 5 6 7 8
f 1 2 6 5
f 2 3 7 6
f 3 4 8 7
f 4 1 5 8
"""
TETRA_OBJ = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"
TETRA_PLY = b"""ply
format ascii 1.0
element vertex 4
property float x
property float y
property float z
element face 4
property list uchar int vertex_indices
end_header
0 0 0
1 0 0
0 1 0
0 0 1
3 0 2 1
3 0 1 3
3 0 3 2
3 1 2 3
"""


def tetra_ply_binary():
    head = (b"ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
            b"property float z\nelement face 4\nproperty list uchar int vertex_indices\nend_header\n")
    verts = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)]
    faces = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]
    body = b"".join(struct.pack("<3f", *v) for v in verts)
    body += b"".join(struct.pack("<B3i", 3, *f) for f in faces)
    return head + body


def upload_daemon():
    # no --frame-timeout: the frames rendering while a model is replaced or deleted are heavy by design, and
    # take over a minute under a sanitizer on a slow day
    return shared("upload", lambda: Daemon([our("cornell.obj"), our("sphere.obj")],
                                           ["--threads", "2", "--max-pixels", "64M", "--frame-timeout", "0"],
                                           copy=True, name="upload daemon"))


def put(d, name, data, query="", headers=None):
    return d.req("PUT", "/api/models/%s%s" % (name, query), body=data,
                 headers=headers or {"Content-Type": "application/octet-stream"})


def _model_ok(j, name, tris, verts, d):
    eq(j.get("name"), name, "uploaded MODEL name")
    eq((j.get("triangles"), j.get("vertices")), (tris, verts), "uploaded %s triangles, vertices" % name)
    check(os.path.exists(j["file"]), "uploaded file %r does not exist" % j["file"])
    eq(os.path.dirname(os.path.realpath(j["file"])), os.path.realpath(d.models_dir),
       "uploaded %s written to the first --models dir" % name)


@test
def test_upload_put_obj_then_render_and_list():
    d = upload_daemon()
    j = expect_json(put(d, "cube", CUBE_OBJ), 201)
    _model_ok(j, "cube", 12, 8, d)
    eq(oct(os.stat(os.path.join(d.models_dir, "cube.obj")).st_mode & 0o777), "0o644", "cube.obj's mode (all read it)")
    eq(j["bounds"], {"min": [0, 0, 0], "max": [1, 1, 1]}, "cube bounds")
    names = [m["name"] for m in expect_json(d.get("/api/models"))["models"]]
    check("cube" in names, "GET /api/models after the upload lacks cube: %s" % names)
    w, h, _, _ = png_of(d.post("/api/render", {"model": "cube", "width": 24, "height": 16}))
    eq((w, h), (24, 16), "frame of the uploaded model")


@test
def test_upload_conflict_without_replace_then_replace():
    d = upload_daemon()
    expect_json(put(d, "swap", TETRA_OBJ), 201)
    e = expect_error(put(d, "swap", CUBE_OBJ), 409, "conflict")
    check("swap" in e["message"], "409 message %r does not name the model" % e["message"])
    eq(d.model("swap")["triangles"], 4, "swap triangles after the refused upload (unchanged)")
    expect_error(put(d, "cornell", CUBE_OBJ), 409, "conflict")
    eq(d.model("cornell")["triangles"], 36, "cornell triangles after a refused upload")
    v1 = d.model("swap")["version"]
    j = expect_json(put(d, "swap", CUBE_OBJ, "?replace=1"), 200)
    eq(j["triangles"], 12, "swap triangles after ?replace=1")
    check(j["version"] > v1, "version %r after replace, was %r" % (j["version"], v1))
    eq(d.model("swap")["triangles"], 12, "GET swap after replace")
    expect_ok(d.post("/api/render", {"model": "swap", "width": 8, "height": 8}))


@test
def test_upload_gzip_by_magic_and_content_encoding():
    d = upload_daemon()
    gz = gzip.compress(CUBE_OBJ)
    j = expect_json(put(d, "cube-gz", gz), 201)
    eq((j["triangles"], j["vertices"]), (12, 8), "gzip (by magic) upload counts")
    j = expect_json(put(d, "cube-ce", gz, headers={"Content-Type": "application/octet-stream",
                                                   "Content-Encoding": "gzip"}), 201)
    eq((j["triangles"], j["vertices"]), (12, 8), "Content-Encoding: gzip upload counts")
    expect_ok(d.post("/api/render", {"model": "cube-gz", "width": 8, "height": 8}))


@test
def test_upload_ply_ascii_and_binary():
    d = upload_daemon()
    j = expect_json(put(d, "tetra-ply", TETRA_PLY), 201)
    eq((j["triangles"], j["vertices"]), (4, 4), "ascii PLY counts")
    j = expect_json(put(d, "tetra-bply", tetra_ply_binary()), 201)
    eq((j["triangles"], j["vertices"]), (4, 4), "binary PLY counts")
    j = expect_json(put(d, "tetra-plygz", gzip.compress(TETRA_PLY)), 201)
    eq((j["triangles"], j["vertices"]), (4, 4), "gzip'd PLY counts")


@test
def test_upload_multipart_obj_and_mtl():
    d = upload_daemon()
    obj = b"mtllib mp.mtl\nusemtl shiny_red\n" + TETRA_OBJ
    mtl = b"newmtl shiny_red\nKd 0.9 0.1 0.1\nKs 0.5 0.5 0.5\n"
    body, ctype = multipart([("model", "mp.obj", "model/obj", obj), ("mtl", "mp.mtl", "text/plain", mtl)])
    r = d.req("POST", "/api/models/mp", body=body, headers={"Content-Type": ctype})
    j = expect_json(r, 201)
    eq((j["triangles"], j["vertices"]), (4, 4), "multipart upload counts")
    check("shiny_red" in j["materials"], "multipart upload materials %r lack the .mtl's shiny_red" % j["materials"])
    check(not any("mp.mtl" in w for w in j.get("warnings", [])), "warnings about the .mtl: %r" % j["warnings"])
    # the .mtl part is read; the part order does not matter
    body, ctype = multipart([("mtl", "mp2.mtl", "text/plain", mtl.replace(b"shiny_red", b"dull_blue")),
                             ("model", "mp2.obj", "model/obj",
                              b"mtllib mp2.mtl\nusemtl dull_blue\n" + TETRA_OBJ)])
    j = expect_json(d.req("POST", "/api/models/mp2", body=body, headers={"Content-Type": ctype}), 201)
    check("dull_blue" in j["materials"], "multipart (mtl first) materials %r lack dull_blue" % j["materials"])
    expect_error(d.req("POST", "/api/models/mp", body=body, headers={"Content-Type": ctype}), 409, "conflict")


@test
def test_upload_multipart_without_model_part():
    d = upload_daemon()
    body, ctype = multipart([("mtl", "only.mtl", "text/plain", b"newmtl a\nKd 1 1 1\n")])
    expect_error(d.req("POST", "/api/models/only", body=body, headers={"Content-Type": ctype}), 400, "bad_request")


@test
def test_upload_multipart_other_files_refused():
    """A multipart part that is neither a model file nor a .mtl is a 400, and nothing of the upload is
    written into the folder."""
    d = upload_daemon()
    before = _folder(d)
    body, ctype = multipart([("model", "ok.obj", "model/obj", TETRA_OBJ), ("f", "run.sh", "text/plain", b"echo hi\n")])
    e = expect_error(d.req("POST", "/api/models/other-files", body=body, headers={"Content-Type": ctype}), 400,
                     "bad_request")
    check("run.sh" in e["message"], "400 does not name the part: %r" % e["message"])
    eq(_folder(d), before, "the models folder after the refused upload")
    expect_error(d.get("/api/models/other-files"), 404, "not_found")


@test
def test_models_named_like_routes():
    """Models may be called boxes or trees: the routes below a model come after its name."""
    d = upload_daemon()
    for name in ("boxes", "trees"):
        eq(expect_json(put(d, name, TETRA_OBJ), 201)["triangles"], 4, "PUT %s" % name)
        eq(d.model(name)["triangles"], 4, "GET %s" % name)
        eq(expect_json(d.req("DELETE", "/api/models/" + name)), {"deleted": name}, "DELETE %s" % name)


@test
def test_upload_multipart_split_anywhere():
    """A multipart upload whose first bytes of a part arrive alone (1-5 bytes after its headers, then the
    rest) is the same upload: libmicrohttpd then starts the part twice."""
    d = upload_daemon()
    body, ctype = multipart([("model", "split.obj", "model/obj", TETRA_OBJ)])
    start = body.index(b"\r\n\r\n") + 4
    for k in range(6):
        head = ("POST /api/models/split%d HTTP/1.1\r\nHost: x\r\nContent-Type: %s\r\nContent-Length: %d\r\n"
                "Connection: close\r\n\r\n" % (k, ctype, len(body))).encode()
        r = raw_request(d.port, [head + body[:start + k], body[start + k:]])
        eq((r.status, r.json().get("triangles")), (201, 4), "split %d bytes into the part: %s" % (k, r.short()))
        expect_json(d.req("DELETE", "/api/models/split%d" % k))


@test
def test_upload_multipart_without_closing_boundary():
    """A multipart body that ends inside its part (no closing boundary) is a 400: the part may be cut
    anywhere, here inside a face, and saving it would keep the wrong model."""
    d = upload_daemon()
    body, ctype = multipart([("model", "cut.obj", "model/obj", b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n")])
    cut = body[:body.rindex(b"\r\n--")]
    r = d.req("POST", "/api/models/cut", body=cut, headers={"Content-Type": ctype})
    e = expect_error(r, 400, "bad_request")
    check("boundary" in e["message"], "400 does not say why: %r" % e["message"])
    expect_error(d.get("/api/models/cut"), 404, "not_found")


@test
def test_upload_survives_restart():
    """An upload is a file in the first --models dir: a daemon started on that dir loads it."""
    d = upload_daemon()
    expect_json(put(d, "keeper", CUBE_OBJ), 201)
    d2 = Daemon(args=["--threads", "1", "--prebuild", "none"], models_dir=d.models_dir, name="restarted daemon")
    try:
        eq(d2.model("keeper")["triangles"], 12, "keeper triangles in a daemon started on the models dir")
        d2.stop_clean()
    finally:
        d2.cleanup()


@test
def test_delete_model_then_404():
    d = upload_daemon()
    expect_json(put(d, "gone", TETRA_OBJ), 201)
    j = expect_json(d.req("DELETE", "/api/models/gone"))
    eq(j, {"deleted": "gone"}, "DELETE /api/models/gone")
    expect_error(d.get("/api/models/gone"), 404, "not_found")
    expect_error(d.post("/api/render", {"model": "gone", "width": 8, "height": 8}), 404, "not_found")
    expect_error(d.req("DELETE", "/api/models/gone"), 404, "not_found")
    names = [m["name"] for m in expect_json(d.get("/api/models"))["models"]]
    check("gone" not in names, "deleted model still listed")
    # the name is free again
    expect_json(put(d, "gone", CUBE_OBJ), 201)


HEAVY = {"width": 1536, "height": 1536, "spp": 16, "format": "json", "camera": {"yaw": 30, "pitch": 20, "distance": 1.2, "fov": 60}}


def _while_rendering(d, name, action):
    """Start a heavy frame of `name`, run action() once it renders; return (frame response, action result)."""
    out = {}

    def frame():
        try:
            out["r"] = d.post("/api/render", dict(HEAVY, model=name), timeout=120)
        except Exception as e:
            out["r"] = e

    t = threading.Thread(target=frame, daemon=True)
    t.start()
    end = time.time() + 20
    while True:
        q = expect_json(d.get("/api/stats"))["daemon"]["queue"]
        if q["rendering"] >= 1:
            break
        if "r" in out or time.time() > end:
            break
        time.sleep(0.01)
    rendering = "r" not in out
    res = action()
    t.join(120)
    check(not t.is_alive(), "the frame never answered")
    r = out["r"]
    if isinstance(r, Exception):
        fail("the frame of %s got no HTTP answer: %r" % (name, r))
    check(rendering, "the frame finished before the action (%s); make HEAVY heavier" % r.short())
    return r, res


@test
def test_delete_while_frames_render():
    d = upload_daemon()
    mem0 = expect_json(d.get("/api/stats"))["daemon"]["memory"]
    with open(our("menger.obj"), "rb") as f:
        expect_json(put(d, "heavy-del", f.read()), 201)
    r, dl = _while_rendering(d, "heavy-del", lambda: d.req("DELETE", "/api/models/heavy-del"))
    eq(dl.status, 200, "DELETE while a frame renders: %s" % dl.short())
    if r.status == 200:
        eq(r.json()["model"], "heavy-del", "the frame's answer")
    else:
        check(r.header("Content-Type", "").startswith("application/json") and "error" in r.json(),
              "the frame on a deleted model answered %s" % r.short())
    expect_error(d.get("/api/models/heavy-del"), 404, "not_found")
    expect_error(d.post("/api/render", {"model": "heavy-del", "width": 8, "height": 8}), 404, "not_found")
    expect_ok(d.get("/healthz"))
    expect_ok(d.post("/api/render", {"model": "cornell", "width": 8, "height": 8}))
    # the memory returns once the last frame is done
    mem = expect_json(d.get("/api/stats"))["daemon"]["memory"]
    eq((mem["models"], mem["trees"]), (mem0["models"], mem0["trees"]),
       "daemon.memory models, trees after the deleted model's frame finished (before the upload: %r)" % mem0)


@test
def test_replace_while_frames_render():
    d = upload_daemon()
    with open(our("menger.obj"), "rb") as f:
        expect_json(put(d, "heavy-rep", f.read()), 201)
    r, rp = _while_rendering(d, "heavy-rep", lambda: put(d, "heavy-rep", CUBE_OBJ, "?replace=1"))
    eq(rp.status, 200, "PUT ?replace=1 while a frame renders: %s" % rp.short())
    eq(r.status, 200, "the frame rendering while its model was replaced: %s" % r.short())
    eq(d.model("heavy-rep")["triangles"], 12, "triangles after replace")
    expect_ok(d.post("/api/render", {"model": "heavy-rep", "width": 8, "height": 8}))


@test
def test_upload_gzip_bomb_refused():
    """A small .gz that inflates past --max-upload (64K) is refused with 413, not inflated."""
    d = limits_daemon()
    bomb = gzip.compress(b"v 0 0 0\n" * (1 << 17))   # 1 MiB inflated, ~2 KB compressed
    check(len(bomb) < 16384, "bomb is %d bytes" % len(bomb))
    expect_error(put(d, "bomb", bomb), 413, "too_large")
    expect_error(d.get("/api/models/bomb"), 404, "not_found")


def _magenta_pixels(d, name):
    _, _, ch, rows = png_of(d.post("/api/render", {"model": name, "width": 32, "height": 32}))
    n = 0
    for row in rows:
        for x in range(0, len(row), ch):
            r, g, b = row[x], row[x + 1], row[x + 2]
            n += r > 2 * g + 30 and b > 2 * g + 30
    return n


@test
def test_upload_mtllib_cannot_lead_outside():
    """An uploaded OBJ's mtllib is read only inside the models folder: not ../, not absolute, not a
    symlink out. The outside .mtl makes the model magenta; a frame shows whether it was read."""
    d = upload_daemon()
    evil = b"newmtl EVIL_OUTSIDE\nKd 1 0 1\nKa 1 0 1\n"
    # control: the same .mtl sent along (inside) does make it magenta
    obj = b"mtllib inside.mtl\nusemtl EVIL_OUTSIDE\n" + TETRA_OBJ
    body, ctype = multipart([("model", "inside.obj", "model/obj", obj), ("mtl", "inside.mtl", "text/plain", evil)])
    expect_json(d.req("POST", "/api/models/mtl-inside", body=body, headers={"Content-Type": ctype}), 201)
    check(_magenta_pixels(d, "mtl-inside") > 20, "control: the model with its magenta .mtl shows no magenta")
    outside = os.path.join(d.tmp, "outside.mtl")
    with open(outside, "wb") as f:
        f.write(evil)
    link = os.path.join(d.models_dir, "link-out.mtl")
    if not os.path.lexists(link):
        os.symlink(outside, link)
    for i, lib in enumerate(("../outside.mtl", outside, "link-out.mtl")):
        obj = ("mtllib %s\nusemtl EVIL_OUTSIDE\n" % lib).encode() + TETRA_OBJ
        r = put(d, "mtl-out-%d" % i, obj)
        if r.status != 201:
            check(r.status == 400, "mtllib %s: %s (expected 201 with a warning, or 400)" % (lib, r.short()))
            continue
        n = _magenta_pixels(d, "mtl-out-%d" % i)
        check(n == 0, "mtllib %s: the .mtl outside the models folder was read (%d magenta pixels)" % (lib, n))


@test
def test_upload_multipart_over_max_upload_413():
    d = limits_daemon()   # --max-upload 64K
    obj = b"v 0 0 0\nv 1 0 0\nv 0 1 0\n" + b"f 1 2 3\n" * 10000
    body, ctype = multipart([("model", "big.obj", "model/obj", obj)])
    expect_error(d.req("POST", "/api/models/bigmp", body=body, headers={"Content-Type": ctype}), 413, "too_large")
    expect_error(d.get("/api/models/bigmp"), 404, "not_found")


@test
def test_delete_keeps_the_operators_files():
    """DELETE unloads a model the operator put in the folder and keeps its file, however often and whenever
    it was loaded (at start, or by a request after a DELETE, or copied in while the daemon runs)."""
    d = Daemon([our("cornell.obj")], ["--threads", "1"], copy=True, name="operator-files daemon")
    try:
        cornell = os.path.join(d.models_dir, "cornell.obj")
        for round_ in range(2):
            eq(expect_json(d.req("DELETE", "/api/models/cornell")), {"deleted": "cornell"}, "DELETE %d" % round_)
            check(os.path.exists(cornell), "DELETE number %d removed the operator's cornell.obj" % (round_ + 1))
            eq(d.model("cornell")["triangles"], 36, "cornell loaded again from its file")
        with open(os.path.join(d.models_dir, "late.obj"), "wb") as f:
            f.write(TETRA_OBJ)
        eq(d.model("late")["triangles"], 4, "a model copied into the folder while the daemon runs")
        expect_json(d.req("DELETE", "/api/models/late"))
        check(os.path.exists(os.path.join(d.models_dir, "late.obj")), "DELETE removed the operator's late.obj")
        d.stop_clean()
    finally:
        d.cleanup()


@test
def test_files_whose_names_are_changed_are_models_at_every_request():
    """A file whose name holds characters a model name may not ("x+y.obj") is model x_y at start, and so
    at every request after: DELETE keeps its file and the next request loads it again; one copied in while
    the daemon runs is listed and loaded under its changed name; removed, it is a 404. A file with the
    name itself (x_y.obj) comes first. Extensions in upper case (Up.OBJ, LATE.PLY) are model files too."""
    d = Daemon([("x+y.obj", our("cornell.obj")), ("Up.OBJ", our("cornell.obj"))], ["--threads", "1"], copy=True,
               name="odd-names daemon")
    try:
        eq(d.model("x_y")["triangles"], 36, "x+y.obj at start")
        eq(d.model("Up")["triangles"], 36, "Up.OBJ at start (an extension in upper case)")
        with open(os.path.join(d.models_dir, "LATE.PLY"), "wb") as f:
            f.write(b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                    b"property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
                    b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
        eq(d.model("LATE")["triangles"], 1, "LATE.PLY copied in while the daemon runs")
        eq(expect_json(d.req("DELETE", "/api/models/x_y")), {"deleted": "x_y"}, "DELETE x_y")
        check(os.path.exists(os.path.join(d.models_dir, "x+y.obj")), "DELETE removed the operator's x+y.obj")
        eq(d.model("x_y")["triangles"], 36, "x_y loaded again from x+y.obj")
        late = os.path.join(d.models_dir, "late one.obj")
        with open(late, "wb") as f:
            f.write(TETRA_OBJ)
        names = [m["name"] for m in expect_json(d.get("/api/models"))["models"]]
        check("late_one" in names, "'late one.obj' copied in is not listed as late_one: %s" % names)
        eq(d.model("late_one")["triangles"], 4, "late_one")
        os.unlink(late)
        expect_error(d.get("/api/models/late_one"), 404, "not_found")
        with open(os.path.join(d.models_dir, "x_y.obj"), "wb") as f:
            f.write(TETRA_OBJ)
        eq(d.model("x_y")["triangles"], 4, "x_y.obj itself comes before x+y.obj")
        d.stop_clean()
    finally:
        d.cleanup()
    # at start the same file is chosen as at every request: no load of the other, no reload after
    d = Daemon([("x+y.obj", our("cornell.obj")), ("x_y.obj", our("sphere.obj"))], ["--threads", "1"], copy=True,
               name="odd-and-plain daemon")
    try:
        first = d.model("x_y")
        check(first["file"].endswith("/x_y.obj"), "x_y at start is %s, not x_y.obj" % first["file"])
        eq(d.model("x_y")["version"], first["version"], "x_y's version after a request (loaded again?)")
        d.stop_clean()
    finally:
        d.cleanup()


def _folder(d):
    return sorted(os.listdir(d.models_dir))


@test
def test_upload_writes_no_file_it_does_not_own():
    """An upload's material library may not overwrite a file of the folder that no upload of that name
    wrote (another model's .mtl, the operator's): 409 and nothing written. The same bytes are left as they
    are and not taken over; DELETE removes exactly the files the upload wrote."""
    d = upload_daemon()
    sphere_mtl = os.path.join(d.models_dir, "sphere.mtl")
    with open(sphere_mtl, "rb") as f:
        before = f.read()
    obj = b"mtllib sphere.mtl\nusemtl evil\n" + TETRA_OBJ
    body, ctype = multipart([("model", "own.obj", "model/obj", obj),
                             ("mtl", "sphere.mtl", "text/plain", b"newmtl evil\nKd 1 0 1\n")])
    folder = _folder(d)
    e = expect_error(d.req("POST", "/api/models/owner", body=body, headers={"Content-Type": ctype}), 409, "conflict")
    check("sphere.mtl" in e["message"], "409 does not name the file: %r" % e["message"])
    with open(sphere_mtl, "rb") as f:
        eq(f.read(), before, "sphere.mtl after a refused upload")
    eq(_folder(d), folder, "the models folder after a refused upload")
    expect_error(d.get("/api/models/owner"), 404, "not_found")
    # the same bytes: accepted, the file left as it is, and kept when the upload is deleted
    body, ctype = multipart([("model", "own.obj", "model/obj", b"mtllib sphere.mtl\n" + TETRA_OBJ),
                             ("mtl", "sphere.mtl", "text/plain", before)])
    expect_json(d.req("POST", "/api/models/owner", body=body, headers={"Content-Type": ctype}), 201)
    # its own library: written, replaced by a replace, removed with the model
    lib = os.path.join(d.models_dir, "owner-lib.mtl")
    for i, kd in enumerate((b"1 0 1", b"0 1 0")):
        body, ctype = multipart([("model", "o.obj", "model/obj", b"mtllib owner-lib.mtl\nusemtl m\n" + TETRA_OBJ),
                                 ("mtl", "owner-lib.mtl", "text/plain", b"newmtl m\nKd " + kd + b"\n")])
        expect_json(d.req("POST", "/api/models/libowner" + ("?replace=1" if i else ""), body=body,
                          headers={"Content-Type": ctype}), 200 if i else 201)
        with open(lib, "rb") as f:
            check(kd in f.read(), "owner-lib.mtl after upload %d lacks Kd %r" % (i, kd))
    for name in ("owner", "libowner"):
        expect_json(d.req("DELETE", "/api/models/" + name))
    left = _folder(d)
    check("sphere.mtl" in left, "deleting an upload that sent sphere.mtl's own bytes removed sphere.mtl")
    for f in ("owner.obj", "libowner.obj", "owner-lib.mtl", ".owner.upload", ".libowner.upload"):
        check(f not in left, "%s left in the models folder after DELETE: %r" % (f, left))
    with open(sphere_mtl, "rb") as f:
        eq(f.read(), before, "sphere.mtl at the end")


@test
def test_upload_one_model_file():
    """A second model file in one upload would become a model of the folder past every check: 400."""
    d = upload_daemon()
    body, ctype = multipart([("a", "a.obj", "model/obj", TETRA_OBJ), ("b", "sphere.obj", "model/obj", CUBE_OBJ)])
    folder = _folder(d)
    e = expect_error(d.req("POST", "/api/models/pair", body=body, headers={"Content-Type": ctype}), 400,
                     "bad_request")
    check("sphere.obj" in e["message"], "400 does not name the second file: %r" % e["message"])
    eq(_folder(d), folder, "the models folder after a refused upload")
    eq(d.model("sphere")["triangles"], 5120, "sphere after the refused upload")


@test
def test_shared_mtl_stays_while_an_upload_uses_it():
    """Two uploads send one .mtl with the same bytes: deleting the one that wrote it keeps it for the
    other, whose materials still load."""
    d = upload_daemon()
    mtl = b"newmtl teal\nKd 0 0.5 0.5\n"
    for name in ("share-a", "share-b"):
        body, ctype = multipart([("model", name + ".obj", "model/obj", b"mtllib shared-lib.mtl\nusemtl teal\n" + TETRA_OBJ),
                                 ("mtl", "shared-lib.mtl", "text/plain", mtl)])
        j = expect_json(d.req("POST", "/api/models/" + name, body=body, headers={"Content-Type": ctype}), 201)
        check("teal" in j["materials"], "%s materials %r" % (name, j["materials"]))
    # share-a wrote it; share-b uses it: share-a's replace may not give it other bytes
    body, ctype = multipart([("model", "share-a.obj", "model/obj", b"mtllib shared-lib.mtl\nusemtl teal\n" + TETRA_OBJ),
                             ("mtl", "shared-lib.mtl", "text/plain", b"newmtl teal\nKd 0.9 0.1 0.1\n")])
    e = expect_error(d.req("POST", "/api/models/share-a?replace=1", body=body, headers={"Content-Type": ctype}), 409,
                     "conflict")
    check("shared-lib.mtl" in e["message"], "409 does not name the file: %r" % e["message"])
    with open(os.path.join(d.models_dir, "shared-lib.mtl"), "rb") as f:
        eq(f.read(), mtl, "shared-lib.mtl after the refused replace")
    expect_json(d.req("DELETE", "/api/models/share-a"))
    check(os.path.exists(os.path.join(d.models_dir, "shared-lib.mtl")),
          "deleting share-a removed shared-lib.mtl, which share-b uses")
    d2 = Daemon(args=["--threads", "1", "--prebuild", "none"], models_dir=d.models_dir, name="restarted daemon")
    try:
        j = d2.model("share-b")
        check("teal" in j["materials"] and not j.get("warnings"), "share-b after a restart: %r" % j)
        d2.stop_clean()
    finally:
        d2.cleanup()
    expect_json(d.req("DELETE", "/api/models/share-b"))


@test
def test_upload_uses_an_mtl_the_folder_has():
    """An upload that does not send the .mtl its mtllib names, which the models folder has (another
    upload's): the model loads with those materials, as every daemon loading it from the folder will,
    and its record names the file, so that deleting the upload that wrote it keeps it."""
    d = upload_daemon()
    obj = b"mtllib folder-lib.mtl\nusemtl plum\n" + TETRA_OBJ
    body, ctype = multipart([("model", "lib-owner.obj", "model/obj", obj),
                             ("mtl", "folder-lib.mtl", "text/plain", b"newmtl plum\nKd 0.5 0 0.5\n")])
    expect_json(d.req("POST", "/api/models/lib-owner", body=body, headers={"Content-Type": ctype}), 201)
    for method, name in (("POST", "lib-user"), ("PUT", "lib-putter")):
        if method == "POST":
            body, ctype = multipart([("model", name + ".obj", "model/obj", obj)])
            j = expect_json(d.req("POST", "/api/models/" + name, body=body, headers={"Content-Type": ctype}), 201)
        else:
            j = expect_json(d.req("PUT", "/api/models/" + name, body=obj), 201)
        check("plum" in j["materials"] and not j["warnings"], "%s %s: %r" % (method, name, j))
        with open(os.path.join(d.models_dir, "." + name + ".upload")) as f:
            check("use folder-lib.mtl" in f.read().splitlines(), "%s's record does not name folder-lib.mtl" % name)
    expect_json(d.req("DELETE", "/api/models/lib-owner"))
    check(os.path.exists(os.path.join(d.models_dir, "folder-lib.mtl")),
          "deleting lib-owner removed folder-lib.mtl, which lib-user and lib-putter use")
    for name in ("lib-user", "lib-putter"):
        expect_json(d.req("DELETE", "/api/models/" + name))


@test
def test_delete_keeps_a_file_the_operator_put_in_an_uploads_place():
    """The operator removes an uploaded model's file and puts their own of that name there: the upload's
    record is stale, and DELETE keeps the operator's file."""
    d = upload_daemon()
    expect_json(put(d, "swapped", TETRA_OBJ), 201)
    path = os.path.join(d.models_dir, "swapped.obj")
    os.unlink(path)
    expect_error(d.get("/api/models/swapped"), 404, "not_found")
    with open(path, "wb") as f:
        f.write(CUBE_OBJ)
    eq(d.model("swapped")["triangles"], 12, "the operator's swapped.obj")
    expect_json(d.req("DELETE", "/api/models/swapped"))
    check(os.path.exists(path), "DELETE removed the operator's swapped.obj (a stale record named it)")
    os.unlink(path)


@test
def test_replace_of_a_model_deleted_through_another_daemon_is_new():
    """A model deleted through another daemon sharing the folder is gone for this one too, though it has
    not unloaded it yet: an upload of its name with ?replace=1 adds it (201), as on a fresh daemon."""
    d = upload_daemon()
    expect_json(put(d, "elsewhere", TETRA_OBJ), 201)
    eq(d.model("elsewhere")["triangles"], 4, "elsewhere loaded here")
    d2 = Daemon(args=["--threads", "1", "--prebuild", "none"], models_dir=d.models_dir, name="second daemon")
    try:
        eq(expect_json(d2.req("DELETE", "/api/models/elsewhere")), {"deleted": "elsewhere"}, "DELETE through d2")
        d2.stop_clean()
    finally:
        d2.cleanup()
    j = expect_json(put(d, "elsewhere", CUBE_OBJ, "?replace=1"), 201)
    eq(j["triangles"], 12, "the new elsewhere")
    expect_json(d.req("DELETE", "/api/models/elsewhere"))


@test
def test_a_file_that_fails_to_load_leaves_the_listing_whole():
    """A model file in the folder that cannot be loaded is left out of GET /api/models (once and again),
    a request for it answers the load's error, and once the file is mended it loads."""
    d = Daemon([our("cornell.obj")], ["--threads", "1", "--prebuild", "none"], copy=True, name="broken-file daemon")
    try:
        path = os.path.join(d.models_dir, "broken.obj")
        with open(path, "wb") as f:
            f.write(b"v 0 0 0\nf 1 2 3\n")
        for i in range(2):
            eq([m["name"] for m in expect_json(d.get("/api/models"))["models"]], ["cornell"], "listing %d" % i)
        e = expect_error(d.get("/api/models/broken"), 500, "bad_model_file")
        check("vertex index 2 out of range" in e["message"], "the load's error in %r" % e["message"])
        with open(path + ".new", "wb") as f:
            f.write(TETRA_OBJ)
        os.rename(path + ".new", path)
        eq(d.model("broken")["triangles"], 4, "broken.obj mended")
        eq([m["name"] for m in expect_json(d.get("/api/models"))["models"]], ["broken", "cornell"], "listing after")
        # broken again, while loaded: the old version is not answered (other daemons answer the new file)
        with open(path + ".new", "wb") as f:
            f.write(b"v 0 0 0\nf 1 2 3\n")
        os.rename(path + ".new", path)
        expect_error(d.get("/api/models/broken"), 500, "bad_model_file")
        eq([m["name"] for m in expect_json(d.get("/api/models"))["models"]], ["cornell"], "listing, broken again")
        # and it can be deleted (unloaded: the operator's file stays) without being loaded first
        eq(expect_json(d.req("DELETE", "/api/models/broken")), {"deleted": "broken"}, "DELETE of a broken file")
        check(os.path.exists(path), "DELETE removed the operator's broken.obj")
        d.stop_clean()
    finally:
        d.cleanup()


@test
def test_uploads_of_one_new_name_at_once():
    """Eight uploads of one new name at once: one is 201, the rest 409, and the model and its file stay."""
    d = upload_daemon()
    res = parallel(8, lambda i: put(d, "racer", TETRA_OBJ if i % 2 else CUBE_OBJ))
    bad = [r for r in res if isinstance(r, Exception)]
    check(not bad, "uploads failed: %r" % bad)
    eq(sorted(r.status for r in res), [201] + [409] * 7, "statuses of eight uploads of one new name")
    won = [r for r in res if r.status == 201][0].json()
    eq(d.model("racer")["triangles"], won["triangles"], "the model is the one that got 201")
    check(os.path.exists(os.path.join(d.models_dir, "racer.obj")), "racer.obj gone after the race")
    expect_json(d.req("DELETE", "/api/models/racer"))
    check(not any(f.startswith("racer") or f.startswith(".racer") for f in os.listdir(d.models_dir)),
          "files of racer left after DELETE: %r" % _folder(d))
