"""--max-memory: least recently used unused trees are evicted; what cannot fit is refused with 507."""
import gzip
import os
import re

import time

from harness import Daemon, check, eq, expect_error, expect_json, expect_ok, fail, our, test

_probe = {}
BYTES = re.compile(r"\d{4,}|\d+(\.\d+)?\s*(bytes|B|KiB|MiB|GiB|KB|MB|GB)\b")
TREES = [("bvh", "mean"), ("bvh", "spatial"), ("bvh", "sah")]  # A, B, C


def probe():
    """Model and tree bytes of menger and cornell as this daemon counts them."""
    if _probe:
        return _probe
    d = Daemon([our("menger.obj"), our("cornell.obj")], ["--threads", "2", "--prebuild", "none"],
               name="memory probe daemon")
    try:
        ms = {m["name"]: m for m in expect_json(d.get("/api/models"))["models"]}
        _probe["models"] = ms["menger"]["bytes"] + ms["cornell"]["bytes"]
        _probe["menger"] = ms["menger"]["bytes"]
        for a, b in TREES + [("kd", "sah")]:
            expect_json(d.post("/api/models/menger/trees", {"accel": a, "builder": b, "wait": True}))
            _probe[(a, b)] = d.tree("menger", a, b)["bytes"]
        mem = expect_json(d.get("/api/stats"))["daemon"]["memory"]
        eq(mem["models"], _probe["models"], "probe: daemon.memory.models")
        d.stop_clean()
    finally:
        d.cleanup()
    return _probe


def states(d):
    return {(t["accel"], t["builder"]): t["state"] for t in d.model("menger")["trees"]}


def build(d, a, b):
    return d.post("/api/models/menger/trees", {"accel": a, "builder": b, "wait": True}, timeout=60)


def grid_obj(n):
    """An n x n grid of quads: (n+1)^2 vertices, 2 n^2 triangles."""
    lines = ["v %d %d 0" % (i, j) for j in range(n + 1) for i in range(n + 1)]
    for j in range(n):
        for i in range(n):
            a = j * (n + 1) + i + 1
            lines.append("f %d %d %d %d" % (a, a + 1, a + n + 2, a + n + 1))
    return ("\n".join(lines) + "\n").encode()


@test
def test_memory_budget_evicts_least_recently_used():
    p = probe()
    A, B, C = (p[t] for t in TREES)
    budget = p["models"] + A + B + C // 2 + 64 * 1024  # fits two of the trees, not three
    check(B + C <= budget - p["models"] and A + B + C > budget - p["models"], "probe sizes %r" % p)
    d = Daemon([our("menger.obj"), our("cornell.obj")],
               ["--threads", "2", "--prebuild", "none", "--max-memory", str(budget)], name="budget daemon")
    try:
        mem = expect_json(d.get("/api/stats"))["daemon"]["memory"]
        eq(mem["limit"], budget, "daemon.memory.limit vs --max-memory")
        ta, tb, tc = TREES
        expect_ok(build(d, *ta))
        expect_ok(build(d, *tb))
        s = states(d)
        eq((s[ta], s[tb]), ("ready", "ready"), "A and B after building them")
        expect_ok(build(d, *tc))
        s = states(d)
        eq((s[ta], s[tb], s[tc]), ("absent", "ready", "ready"),
           "states of A=%s:%s, B=%s:%s, C=%s:%s after building C (A least recently used, evicted)" % (ta + tb + tc))
        mem = expect_json(d.get("/api/stats"))["daemon"]["memory"]
        check(mem["models"] + mem["trees"] <= budget, "memory %r over the budget %d" % (mem, budget))
        # use B, so that C becomes the least recently used
        expect_ok(d.post("/api/render", {"model": "menger", "accel": tb[0], "builder": tb[1], "width": 16, "height": 16}))
        expect_ok(build(d, *ta))
        s = states(d)
        eq((s[ta], s[tb], s[tc]), ("ready", "ready", "absent"),
           "states after rendering with B and building A again (C least recently used, evicted)")
        samples, _ = d.metrics()
        mem = expect_json(d.get("/api/stats"))["daemon"]["memory"]
        check(mem["models"] + mem["trees"] <= budget, "memory %r over the budget %d" % (mem, budget))

        # an upload bigger than the whole budget: 507 naming the bytes; nothing loaded is lost
        per_tri = p["menger"] / 36096.0
        n = 8
        while 2 * n * n * per_tri < 1.5 * budget:
            n *= 2
        before = expect_json(d.get("/api/models"))["models"]
        big = gzip.compress(grid_obj(n), 1)
        r = d.req("PUT", "/api/models/toobig", body=big, headers={"Content-Type": "application/octet-stream"},
                  timeout=120)
        e = expect_error(r, 507, "insufficient_memory")
        check(BYTES.search(e["message"]), "507 message %r does not say how many bytes were needed" % e["message"])
        left = [f for f in os.listdir(d.models_dir) if f.startswith("toobig")]
        check(not left, "the refused upload left %s in the models folder" % left)
        after = expect_json(d.get("/api/models"))["models"]
        eq([(m["name"], m["triangles"], m["version"]) for m in after],
           [(m["name"], m["triangles"], m["version"]) for m in before], "models after the refused upload")
        expect_error(d.get("/api/models/toobig"), 404, "not_found")
        s = states(d)
        eq((s[ta], s[tb]), ("ready", "ready"), "A and B after an upload that could never fit was refused")
        expect_ok(d.post("/api/render", {"model": "menger", "width": 16, "height": 16}))
        expect_ok(d.post("/api/render", {"model": "cornell", "width": 16, "height": 16}))
        d.stop_clean()
    finally:
        d.cleanup()


@test
def test_memory_tree_that_cannot_fit_507():
    p = probe()
    C = p[("bvh", "sah")]
    budget = p["models"] + C // 2
    d = Daemon([our("menger.obj"), our("cornell.obj")],
               ["--threads", "2", "--prebuild", "none", "--max-memory", str(budget)], name="tiny budget daemon")
    try:
        e = expect_error(build(d, "bvh", "sah"), 507, "insufficient_memory")
        check(BYTES.search(e["message"]), "507 message %r does not say how many bytes were needed" % e["message"])
        st = d.tree("menger", "bvh", "sah")["state"]
        check(st in ("absent", "failed"), "bvh:sah state %r after a refused build" % st)
        r = d.post("/api/render", {"model": "menger", "width": 16, "height": 16})
        expect_error(r, 507, "insufficient_memory")
        names = [m["name"] for m in expect_json(d.get("/api/models"))["models"]]
        eq(names, ["cornell", "menger"], "models after the refusals")
        expect_ok(d.post("/api/render", {"model": "cornell", "width": 16, "height": 16}))
        expect_ok(d.get("/healthz"))
        d.stop_clean()
    finally:
        d.cleanup()


@test
def test_memory_replace_that_cannot_fit_keeps_the_old_model():
    """An upload replacing a model, refused for memory (507), leaves the folder as it was and the old
    model loaded: the store takes a model before any file of it is written."""
    p = probe()
    cornell = p["models"] - p["menger"]
    d = Daemon([our("cornell.obj")], ["--threads", "2", "--prebuild", "none", "--max-memory", str(cornell + 1024 * 1024)],
               copy=True, name="replace budget daemon")
    try:
        before = {f: open(os.path.join(d.models_dir, f), "rb").read() for f in os.listdir(d.models_dir)}
        r = d.req("PUT", "/api/models/cornell?replace=1", body=grid_obj(300),
                  headers={"Content-Type": "application/octet-stream"})
        expect_error(r, 507, "insufficient_memory")
        after = {f: open(os.path.join(d.models_dir, f), "rb").read() for f in os.listdir(d.models_dir)
                 if f != ".arbord.lock"}
        eq(sorted(after), sorted(before), "files after the refused replace")
        check(after == before, "a file changed in the refused replace")
        eq(d.model("cornell")["triangles"], 36, "cornell after the refused replace")
        expect_ok(d.post("/api/render", {"model": "cornell", "width": 16, "height": 16}))
        d.stop_clean()
    finally:
        d.cleanup()


@test
def test_memory_delete_through_a_daemon_that_cannot_load_the_model():
    """A model uploaded through one daemon is deleted through another sharing the folder whose budget
    cannot hold it: DELETE needs no load, and the upload's files go."""
    d = Daemon([our("cornell.obj")], ["--threads", "2", "--prebuild", "none"], copy=True, name="roomy daemon")
    try:
        expect_json(d.req("PUT", "/api/models/wide", body=grid_obj(300),
                          headers={"Content-Type": "application/octet-stream"}), 201)
        small = Daemon(args=["--threads", "1", "--prebuild", "none", "--max-memory", "1M"], models_dir=d.models_dir,
                       name="small daemon")
        try:
            expect_error(small.get("/api/models/wide"), 507, "insufficient_memory")
            eq(expect_json(small.req("DELETE", "/api/models/wide")), {"deleted": "wide"}, "DELETE through it")
            check(not os.path.exists(os.path.join(d.models_dir, "wide.obj")), "wide.obj stayed")
            small.stop_clean()
        finally:
            small.cleanup()
        expect_error(d.get("/api/models/wide"), 404, "not_found")
        d.stop_clean()
    finally:
        d.cleanup()


@test
def test_memory_tree_in_use_is_not_evicted():
    """The least recently built tree is rendering a frame: eviction passes it over and takes the next."""
    import threading
    import time
    p = probe()
    A, B, C = (p[t] for t in TREES)
    budget = p["models"] + A + B + C // 2 + 64 * 1024
    d = Daemon([our("menger.obj"), our("cornell.obj")],
               # the frame must outlast C's build, and may take minutes under a sanitizer: no timeout cuts it
               ["--threads", "2", "--prebuild", "none", "--max-memory", str(budget), "--max-pixels", "256M",
                "--frame-timeout", "0"],
               name="in-use budget daemon")
    try:
        ta, tb, tc = TREES
        expect_ok(build(d, *ta))
        expect_ok(build(d, *tb))
        out = {}

        def frame():
            try:
                out["r"] = d.post("/api/render", {"model": "menger", "accel": ta[0], "builder": ta[1],
                                                  "width": 1536, "height": 1536, "spp": 16, "format": "json"},
                                  timeout=120)
            except Exception as e:
                out["r"] = e
        t = threading.Thread(target=frame, daemon=True)
        t.start()
        end = time.time() + 20
        while expect_json(d.get("/api/stats"))["daemon"]["queue"]["rendering"] < 1:
            check(time.time() < end and "r" not in out, "the frame with A never rendered")
            time.sleep(0.01)
        expect_ok(build(d, *tc))
        s = states(d)
        rendering = "r" not in out
        eq((s[ta], s[tb], s[tc]), ("ready", "absent", "ready"),
           "states after building C while a frame renders with A (A in use: B is evicted instead)")
        check(rendering, "the frame with A finished before C was built; make it heavier")
        t.join(120)
        r = out.get("r")
        check(not isinstance(r, Exception) and r is not None and r.status == 200, "the frame with A: %r" %
              (r.short() if hasattr(r, "short") else r))
        d.stop_clean()
    finally:
        d.cleanup()


def _bench_job(d, timeout=120):
    """Runs a one-tree bench job of cornell to its end; its final answer."""
    jid = expect_json(d.post("/api/bench", {"model": "cornell", "accel": ["bvh"], "builder": ["median"],
                                            "runs": 1}), 202)["id"]
    end = time.time() + timeout
    while (job := expect_json(d.get("/api/jobs/%s" % jid)))["state"] in ("queued", "running"):
        if time.time() > end:
            fail("job %s still %s" % (jid, job["state"]))
        time.sleep(0.1)
    return job


@test
def test_memory_bench_job_counts_in_the_budget():
    """A bench job's ray sets and trees live outside the store, but within --max-memory: a job larger than the
    whole budget fails saying so (it ran regardless, past the budget); one that fits once an idle tree is
    evicted evicts it and runs; a job holds nothing after it ends."""
    p = probe()
    budget = p["models"] + 16 * 1024 * 1024  # the sets alone are some 90 MB
    d = Daemon([our("menger.obj"), our("cornell.obj")],
               ["--threads", "2", "--prebuild", "none", "--max-memory", str(budget)], name="bench budget daemon")
    try:
        job = _bench_job(d)
        eq(job["state"], "failed", "a bench job over the budget: %r" % job)
        check("more than the whole memory budget" in job["error"], "its error: %r" % job["error"])
        need = int(re.search(r"needs (\d+) bytes", job["error"]).group(1))
        eq(expect_json(d.get("/api/stats"))["daemon"]["memory"]["benchmarks"], 0, "bytes held after the job")
        expect_json(build(d, "bvh", "sah"))
        d.stop_clean()
    finally:
        d.cleanup()
    # room for the job only once menger's idle bvh:sah tree goes
    tree = p[("bvh", "sah")]
    d = Daemon([our("menger.obj"), our("cornell.obj")],
               ["--threads", "2", "--prebuild", "none", "--max-memory", str(p["models"] + need + tree // 2)],
               name="bench eviction daemon")
    try:
        expect_json(build(d, "bvh", "sah"))
        eq(states(d)[("bvh", "sah")], "ready", "menger's bvh:sah before the job")
        job = _bench_job(d)
        eq(job["state"], "done", "a bench job that fits once a tree is evicted: %r" % job)
        eq(states(d)[("bvh", "sah")], "absent", "menger's bvh:sah, evicted for the job")
        eq(expect_json(d.get("/api/stats"))["daemon"]["memory"]["benchmarks"], 0, "bytes held after the job")
        d.stop_clean()
    finally:
        d.cleanup()
