"""Build once under concurrent first requests; a full queue answers 503 at once; stream keys; timeouts."""
import os
import re
import socket
import threading
import time

from harness import (SHARED, Daemon, check, eq, expect_error, expect_json, expect_ok, fail, metric_value, our,
                     parallel, shared, test)


def builds(d, accel, builder):
    samples, _ = d.metrics()
    return metric_value(samples, "arbor_tree_builds_total", accel=accel, builder=builder) or 0


def lazy_daemon():
    """--prebuild none: every tree starts absent."""
    ms = [our("menger.obj"), our("cornell.obj")]
    bunny = os.path.join(SHARED, "bunny.obj")
    if os.path.exists(bunny):
        ms.append(bunny)
    # --queue 32: the 20 concurrent frames all fit (threads + queue)
    return shared("lazy", lambda: Daemon(ms, ["--threads", "2", "--queue", "32", "--prebuild", "none"],
                                         name="lazy daemon"))


def _big():
    d = lazy_daemon()
    names = [m["name"] for m in expect_json(d.get("/api/models"))["models"]]
    return d, ("bunny" if "bunny" in names else "menger")


@test
def test_build_once_20_concurrent_tree_posts():
    d, model = _big()
    eq(d.tree(model, "kd", "sah")["state"], "absent", "%s kd:sah before" % model)
    eq(builds(d, "kd", "sah"), 0, "arbor_tree_builds_total{accel=kd,builder=sah} before")
    res = parallel(20, lambda i: d.post("/api/models/%s/trees" % model,
                                        {"accel": "kd", "builder": "sah", "wait": True}, timeout=120))
    errs = [r for r in res if isinstance(r, Exception) or r.status != 200]
    check(not errs, "of 20 concurrent POST trees, %d failed: %s" %
          (len(errs), [e if isinstance(e, Exception) else e.short() for e in errs[:3]]))
    stats = [r.json() for r in res]
    keys = [(s["nodes"], s["leaves"], s["refs"], s["bytes"], s["build_ms"]) for s in stats]
    eq(len(set(keys)), 1, "20 answers of one build (nodes, leaves, refs, bytes, build_ms) all equal")
    eq(builds(d, "kd", "sah"), 1, "arbor_tree_builds_total{accel=\"kd\",builder=\"sah\"} after 20 concurrent requests")
    eq(d.tree(model, "kd", "sah")["state"], "ready", "state after")


@test
def test_build_once_20_concurrent_first_renders():
    d, model = _big()
    eq(d.tree(model, "bvh", "median")["state"], "absent", "%s bvh:median before" % model)
    res = parallel(20, lambda i: d.post("/api/render", {"model": model, "accel": "bvh", "builder": "median",
                                                        "width": 32, "height": 32, "camera": {"yaw": 18 * i,
                                                        "pitch": 10, "distance": 1.5, "fov": 45}}, timeout=120))
    errs = [r for r in res if isinstance(r, Exception) or r.status != 200]
    check(not errs, "of 20 concurrent first renders, %d failed: %s" %
          (len(errs), [e if isinstance(e, Exception) else e.short() for e in errs[:3]]))
    eq(builds(d, "bvh", "median"), 1, "arbor_tree_builds_total{accel=\"bvh\",builder=\"median\"} after 20 renders")
    # and 20 concurrent stats requests naming an absent tree
    res = parallel(20, lambda i: d.get("/api/stats?model=%s&accel=kd&builder=mean" % model, timeout=120))
    check(all(not isinstance(r, Exception) and r.status == 200 for r in res), "concurrent /api/stats builds failed")
    eq(builds(d, "kd", "mean"), 1, "arbor_tree_builds_total{accel=\"kd\",builder=\"mean\"} after 20 stats requests")


def busy_daemon():
    # --frame-timeout 0: the frames admitted must render, however slow the build (under TSan on a
    # slow VM one took over the default 60 s, and a burst then rendered nothing)
    return shared("busy", lambda: Daemon([our("menger.obj"), our("cornell.obj")],
                                         ["--threads", "1", "--queue", "1", "--max-pixels", "256M",
                                          "--frame-timeout", "0"],
                                         name="busy daemon (--threads 1 --queue 1)"))


BIG = {"model": "menger", "width": 1024, "height": 1024, "spp": 16, "format": "json",
       "camera": {"yaw": 30, "pitch": 20, "distance": 1.2, "fov": 60}}


@test
def test_queue_full_503_at_once():
    d = busy_daemon()
    rejected0 = metric_value(d.metrics()[0], "arbor_frames_rejected_total") or 0

    def one(i):
        # 4 spp: long enough to hold the daemon through the burst, short enough that the two
        # frames admitted render one after the other within the test's limit under TSan
        t0 = time.time()
        r = d.post("/api/render", dict(BIG, spp=4, seed=i + 1), timeout=120)
        return r, time.time() - t0

    res = parallel(10, one)
    bad = [r for r in res if isinstance(r, Exception)]
    check(not bad, "frames without an HTTP answer: %r" % bad[:3])
    ok = [r for r, _ in res if r.status == 200]
    busy = [(r, dt) for r, dt in res if r.status == 503]
    other = [r.short() for r, _ in res if r.status not in (200, 503)]
    check(not other, "answers other than 200/503: %s" % other)
    check(len(busy) >= 7, "10 concurrent big frames on --threads 1 --queue 1: %d got 503, %d got 200 "
          "(expected at most 2 admitted)" % (len(busy), len(ok)))
    check(len(ok) >= 1, "no frame rendered")
    for r, dt in busy:
        expect_error(r, 503, "busy")
        ra = r.header("Retry-After")
        check(ra is not None and ra.strip().isdigit(), "503 busy with Retry-After %r" % ra)
        check(dt < 1.5, "a 503 came after %.2f s, expected at once" % dt)
    expect_ok(d.get("/healthz"))
    expect_ok(d.get("/readyz"))
    expect_ok(d.post("/api/render", {"model": "cornell", "width": 16, "height": 16}))
    rejected = metric_value(d.metrics()[0], "arbor_frames_rejected_total") or 0
    eq(rejected - rejected0, float(len(busy)), "arbor_frames_rejected_total increase")
    q = expect_json(d.get("/api/stats"))["daemon"]["queue"]
    eq((q["waiting"], q["rendering"], q["limit"], q["threads"]), (0, 0, 1, 1), "queue after the burst")


def _start(d, body, out, key):
    def run():
        t0 = time.time()
        try:
            out[key] = (d.post("/api/render", body, timeout=120), time.time())
        except Exception as e:
            out[key] = (e, time.time())
        out[key + "_t0"] = t0
    t = threading.Thread(target=run, daemon=True)
    t.start()
    return t


def _wait_queue(d, rendering, waiting=0, timeout=20):
    end = time.time() + timeout
    while time.time() < end:
        q = expect_json(d.get("/api/stats"))["daemon"]["queue"]
        if q["rendering"] >= rendering and q["waiting"] >= waiting:
            return
        time.sleep(0.01)
    fail("queue never reached rendering>=%d waiting>=%d" % (rendering, waiting))


def stream_daemon():
    return shared("stream", lambda: Daemon([our("menger.obj"), our("cornell.obj")],
                                           ["--threads", "2", "--max-pixels", "256M"], name="stream daemon"))


@test
def test_stream_key_cancels_rendering_frame():
    d = stream_daemon()
    out = {}
    heavy = dict(BIG, width=2048, height=2048, stream="orbit-1")
    ta = _start(d, heavy, out, "a")
    _wait_queue(d, 1)
    check("a" not in out, "the heavy frame finished before the second was sent")
    tb = _start(d, {"model": "cornell", "width": 32, "height": 32, "stream": "orbit-1"}, out, "b")
    tb.join(60)
    ta.join(60)
    ra, ta_end = out["a"]
    rb, tb_end = out["b"]
    check(not isinstance(rb, Exception), "second frame: %r" % rb)
    check(not isinstance(ra, Exception), "first frame got no HTTP answer: %r" % ra)
    eq(rb.status, 200, "second frame of stream orbit-1: %s" % rb.short())
    expect_error(ra, 409, "superseded")
    check(ta_end - tb_end < 3, "the superseded frame answered %.1f s after the newer one" % (ta_end - tb_end))
    samples, _ = d.metrics()
    c = metric_value(samples, "arbor_frames_cancelled_total") or 0
    check(c >= 1, "arbor_frames_cancelled_total is %r after a superseded frame" % c)


@test
def test_stream_key_cancels_queued_frame():
    """--threads 1 --queue 2: A renders (no stream), B (as heavy) waits with stream s, C with stream s:
    B 409, C 200, A 200. (B is heavy because the pool shares its workers among admitted frames.)"""
    d = Daemon([our("menger.obj"), our("cornell.obj")], ["--threads", "1", "--queue", "2", "--max-pixels", "256M"],
               name="queued-stream daemon")
    try:
        _queued_stream(d)
        d.stop_clean()
    finally:
        d.cleanup()


def _queued_stream(d):
    out = {}
    ta = _start(d, dict(BIG, width=768, height=768), out, "a")
    _wait_queue(d, 1)
    tb = _start(d, dict(BIG, width=768, height=768, seed=5, stream="s-queued"), out, "b")
    _wait_queue(d, 1, 1)
    tc = _start(d, {"model": "cornell", "width": 32, "height": 32, "stream": "s-queued", "seed": 2}, out, "c")
    for t in (ta, tb, tc):
        t.join(60)
    rb, rc, ra = out["b"][0], out["c"][0], out["a"][0]
    for r, what in ((ra, "A"), (rb, "B"), (rc, "C")):
        check(not isinstance(r, Exception), "frame %s: no HTTP answer %r" % (what, r))
    expect_error(rb, 409, "superseded")
    eq(rc.status, 200, "C (the newer frame of stream s-queued): %s" % rc.short())
    eq(ra.status, 200, "A (no stream): %s" % ra.short())


@test
def test_stream_key_supersedes_on_a_full_daemon():
    """--threads 1 --queue 0: the one place is A's (stream s); B on stream s supersedes A and takes its
    place: A 409, B 200, not both refused."""
    d = Daemon([our("menger.obj"), our("cornell.obj")], ["--threads", "1", "--queue", "0", "--max-pixels", "256M"],
               name="full-stream daemon")
    try:
        out = {}
        ta = _start(d, dict(BIG, width=2048, height=2048, stream="s-full"), out, "a")
        _wait_queue(d, 1)
        tb = _start(d, {"model": "cornell", "width": 32, "height": 32, "stream": "s-full"}, out, "b")
        for t in (ta, tb):
            t.join(60)
        ra, rb = out["a"][0], out["b"][0]
        for r, what in ((ra, "A"), (rb, "B")):
            check(not isinstance(r, Exception), "frame %s: no HTTP answer %r" % (what, r))
        expect_error(ra, 409, "superseded")
        eq(rb.status, 200, "B, which superseded A on the full daemon: %s" % rb.short())
        d.stop_clean()
    finally:
        d.cleanup()


@test
def test_frame_timeout_503():
    d = Daemon([our("menger.obj")], ["--threads", "1", "--frame-timeout", "1", "--max-pixels", "256M"],
               name="timeout daemon")
    try:
        t0 = time.time()
        r = d.post("/api/render", dict(BIG, width=2048, height=2048), timeout=60)
        dt = time.time() - t0
        expect_error(r, 503, "timeout")
        check(dt < 5, "a frame with --frame-timeout 1 answered after %.1f s" % dt)
        expect_ok(d.post("/api/render", {"model": "menger", "width": 16, "height": 16}))
        samples, _ = d.metrics()
        c = metric_value(samples, "arbor_frames_cancelled_total") or 0
        check(c >= 1, "arbor_frames_cancelled_total %r after a timeout" % c)
        d.stop_clean()
    finally:
        d.cleanup()


@test
def test_frame_of_a_client_that_left_is_cancelled():
    """A client that closes its connection mid-frame cancels the frame (reason client_gone), though
    libmicrohttpd watches no suspended connection: its worker and queue slot are free again, and the
    frame is not counted as served."""
    d = Daemon([our("menger.obj")], ["--threads", "1", "--frame-timeout", "0", "--max-pixels", "256M"],
               name="client-gone daemon")
    try:
        s = socket.create_connection(("127.0.0.1", d.port))
        s.sendall(b"GET /api/render?model=menger&mode=ao&ao_samples=16&width=4096&height=4096 HTTP/1.1\r\nHost: x\r\n\r\n")
        _wait_queue(d, 1)
        s.close()
        end = time.time() + 30
        while True:
            samples, _ = d.metrics()
            gone = metric_value(samples, "arbor_frames_cancelled_total", reason="client_gone")
            if gone == 1 and metric_value(samples, "arbor_frames_rendering") == 0:
                break
            check(time.time() < end, "the frame of the client that left goes on: %r, rendering %r"
                  % (gone, metric_value(samples, "arbor_frames_rendering")))
            time.sleep(0.1)
        eq(metric_value(samples, "arbor_frames_total") or 0, 0, "frames counted as served")
        expect_ok(d.post("/api/render", {"model": "menger", "width": 16, "height": 16}))
        d.stop_clean()
    finally:
        d.cleanup()


@test
def test_stream_keys_are_independent():
    """Frames of different stream keys (and none) do not cancel each other."""
    d = stream_daemon()
    res = parallel(4, lambda i: d.post("/api/render", dict(BIG, width=384, height=384, seed=i + 1,
                                                           **({"stream": "key-%d" % i} if i < 3 else {})),
                                       timeout=120))
    for i, r in enumerate(res):
        check(not isinstance(r, Exception), "frame %d: %r" % (i, r))
        eq(r.status, 200, "frame %d (stream key-%d): %s" % (i, i, r.short()))


@test
def test_mixed_concurrent_requests_stay_consistent():
    """8 clients for ~4 s: uploads, replaces, deletes, frames, tree builds, lists and stats on a small
    pool of names. Every answer is a well-formed one of the expected statuses; then the daemon is
    consistent and exits 0."""
    import random
    from test_models import CUBE_OBJ, TETRA_OBJ
    d = Daemon([our("cornell.obj"), our("sphere.obj")], ["--threads", "2", "--queue", "8"], copy=True,
               name="mixed daemon")
    try:
        names = ["mix-a", "mix-b", "mix-c"]
        bad = []
        deadline = time.time() + 4

        def client(i):
            rnd = random.Random(i)
            n = 0
            while time.time() < deadline:
                n += 1
                name = rnd.choice(names + ["sphere"])
                op = rnd.randrange(9)
                try:
                    if op == 0 and name != "sphere":
                        r = d.req("PUT", "/api/models/" + name, body=rnd.choice([CUBE_OBJ, TETRA_OBJ]))
                        ok = {201, 409}
                    elif op == 1 and name != "sphere":
                        r = d.req("PUT", "/api/models/%s?replace=1" % name, body=rnd.choice([CUBE_OBJ, TETRA_OBJ]))
                        ok = {200, 201, 409}  # 409: a DELETE of the name came after it was saved
                    elif op == 2 and name != "sphere":
                        r = d.req("DELETE", "/api/models/" + name)
                        ok = {200, 404}
                    elif op in (3, 4):
                        r = d.post("/api/render", {"model": name, "width": 48, "height": 32,
                                                   "accel": rnd.choice(["bvh", "kd"]),
                                                   "builder": rnd.choice(["sah", "median", "mean", "spatial"]),
                                                   "mode": rnd.choice(["shaded", "normals", "depth", "ao", "heat"]),
                                                   **({"stream": "mix-%d" % (i % 2)} if rnd.random() < 0.3 else {})})
                        ok = {200, 404, 409, 503}
                    elif op == 5:
                        r = d.post("/api/models/%s/trees" % name, {"accel": rnd.choice(["bvh", "kd"]),
                                                                  "builder": rnd.choice(["sah", "median", "mean", "spatial"]),
                                                                  "wait": rnd.random() < 0.5})
                        ok = {200, 202, 404}
                    elif op == 6:
                        r = d.get("/api/models")
                        ok = {200}
                    elif op == 7:
                        r = d.get("/api/stats?model=%s" % name)
                        ok = {200, 404}
                    else:
                        r = d.get("/api/models/%s/trees/bvh/sah/boxes?depth=2" % name)
                        ok = {200, 404}
                except Exception as e:
                    bad.append("client %d op %d: %r" % (i, op, e))
                    continue
                if r.status not in ok:
                    bad.append("%s -> %s" % (r.req[:80], r.short()[:300]))
                elif r.status >= 400:
                    try:
                        j = r.json()
                        if not isinstance(j.get("error"), dict):
                            bad.append("%s -> %d without an error object" % (r.req[:80], r.status))
                    except harness_fail:
                        bad.append("%s -> %d not JSON" % (r.req[:80], r.status))
            return n

        from harness import Fail as harness_fail
        counts = parallel(8, client)
        kinds = sorted({re.sub(r"mix-.", "mix-?", re.sub(r"\{.*?\} ->", "->", b))[:420] for b in bad})
        errors = []
        if bad:
            errors.append("%d bad answers of %s requests, %d kinds: %s" % (len(bad), counts, len(kinds),
                                                                           " ; ".join(kinds[:8])))
        try:
            check(d.alive(), "the daemon died")
            ms = expect_json(d.get("/api/models"))["models"]
            files = sorted(f for f in os.listdir(d.models_dir) if f.endswith((".obj", ".ply", ".gz")))
            listed = sorted(os.path.basename(m["file"]) for m in ms)
            eq(listed, files, "models listed vs files in the models folder after the storm")
            for m in ms:
                expect_ok(d.post("/api/render", {"model": m["name"], "width": 16, "height": 16}))
            mem = expect_json(d.get("/api/stats"))["daemon"]
            eq((mem["queue"]["waiting"], mem["queue"]["rendering"]), (0, 0), "queue after the storm")
            eq(mem["memory"]["models"], sum(m["bytes"] for m in ms), "daemon.memory.models vs the models listed")
        except harness_fail as e:
            errors.append("after the storm: %s" % e)
        try:
            d.stop_clean()   # and under ASan: no report
        except harness_fail as e:
            errors.append(str(e))
        check(not errors, " | ".join(errors))
    finally:
        d.cleanup()
