"""Success paths of every endpoint, checked against independent truth."""
import json
import math
import os
import re
import struct
import subprocess
import time

from harness import (Daemon, add_test, default_web_daemon, check, eq, expect_json, expect_ok, fail, ignore, limits_daemon,
                     main_daemon,
                     need_shared, our, our_readme_counts, png_of, shared_readme_counts, test, run_cli,
                     metric_value, REPO, ARBORD)

ACCELS = ("bvh", "kd")
BUILDERS = ("spatial", "median", "mean", "sah")
MODEL_KEYS = {"name", "file", "triangles", "vertices", "bounds", "materials", "warnings", "bytes",
              "version", "trees"}
STATS_KEYS = {"model", "triangles", "accel", "builder", "layout", "build_ms", "nodes", "leaves", "empty_leaves",
              "max_depth", "mean_leaf_depth", "mean_tris_per_leaf", "refs", "bytes", "sah_cost"}
FRAME_JSON_KEYS = {"model", "accel", "builder", "mode", "width", "height", "spp", "render_ms", "rays",
                   "mrays_per_s", "queue_ms", "build_ms", "heat_scale", "heat_max", "heat_mean",
                   "mean_nodes", "mean_tris"}
ORBIT = {"yaw": 25, "pitch": 15, "distance": 1.6, "fov": 50}


@test
def test_healthz():
    d = main_daemon()
    j = expect_json(d.get("/healthz"))
    eq(j, {"status": "ok"}, "GET /healthz")


@test
def test_readyz_when_ready():
    d = main_daemon()
    j = expect_json(d.get("/readyz"))
    eq(j.get("status"), "ready", "GET /readyz status")


@test
def test_readyz_503_while_prebuilding_then_200():
    """A big model with several prebuilt trees: /readyz 503 {"status":"loading","pending":[..]}, then 200."""
    try:
        (model,) = need_shared("dragon.obj.gz")
        prebuild = "bvh:sah,kd:sah"
    except Exception:
        (model,) = need_shared("bunny.obj")
        prebuild = "all"
    d = Daemon([model], ["--threads", "2", "--prebuild", prebuild], wait_ready=False,
               name="readyz daemon")
    try:
        first = d.get("/readyz")
        health = d.get("/healthz")
        eq(health.status, 200, "GET /healthz while loading")
        if first.status == 200:
            ignore("the daemon was ready before the first /readyz (%s, --prebuild %s)" % (os.path.basename(model), prebuild))
        j = expect_json(first, 503)
        eq(j.get("status"), "loading", "GET /readyz while loading: status")
        check(isinstance(j.get("pending"), list), "GET /readyz while loading: no pending list: %r" % j)
        # the pending entries name the model and the trees ("castle bvh:sah")
        name = os.path.basename(model).split(".")[0]
        if j["pending"]:
            check(any(name in p for p in j["pending"]), "pending %r does not name %s" % (j["pending"], name))
        d.wait_ready(150)
        j = expect_json(d.get("/readyz"))
        eq(j.get("status"), "ready", "GET /readyz after loading")
        m = d.model(name)
        want = [("bvh", "sah"), ("kd", "sah")] if prebuild != "all" else \
            [(a, b) for a in ACCELS for b in BUILDERS]
        for t in m["trees"]:
            if (t["accel"], t["builder"]) in want:
                eq(t["state"], "ready", "tree %s:%s after /readyz 200" % (t["accel"], t["builder"]))
        d.stop_clean()
    finally:
        d.cleanup()


@test
def test_metrics_parse_and_families():
    d = main_daemon()
    r = d.post("/api/render", {"model": "cornell", "width": 32, "height": 24})
    expect_ok(r)
    rays = int(r.header("X-Rays", "0"))
    d.get("/api/no-such-endpoint")
    r = d.get("/metrics")
    expect_ok(r)
    ct = r.header("Content-Type", "")
    check(ct.startswith("text/plain") and "version=0.0.4" in ct,
          "GET /metrics Content-Type %r, expected text/plain; version=0.0.4" % ct)
    empty = [ln for ln in r.body.decode().splitlines() if "{}" in ln]
    check(not empty, "GET /metrics: a sample with an empty label set's braces: %s" % empty[:3])
    samples, families = d.metrics()
    names = set(samples) | set(families)
    want_counters = ["arbor_http_requests_total", "arbor_rays_total", "arbor_frames_rejected_total",
                     "arbor_frames_cancelled_total", "arbor_tree_builds_total"]
    want_hist = ["arbor_http_request_seconds", "arbor_render_seconds", "arbor_tree_build_seconds"]
    want_gauges = ["arbor_frames_queued", "arbor_frames_rendering", "arbor_model_bytes",
                   "arbor_tree_bytes", "arbor_models_loaded", "arbor_uptime_seconds"]
    missing = [n for n in want_counters if n not in names and n[:-len("_total")] not in names]
    missing += [n for n in want_hist + want_gauges if n not in names]
    check(not missing, "GET /metrics lacks families %s" % missing)
    for h in want_hist:
        fam = families.get(h)
        eq(fam.type if fam else None, "histogram", "type of %s" % h)
    for h in ("arbor_http_request_seconds", "arbor_render_seconds"):
        check(samples.get(h + "_bucket") and samples.get(h + "_count"), "%s has no _bucket/_count samples" % h)
        check(any(lab.get("le") == "+Inf" for lab, _ in samples[h + "_bucket"]), "%s has no +Inf bucket" % h)
    labs = [lab for lab, _ in samples.get("arbor_http_requests_total", [])]
    check(any("route" in lab and "status" in lab for lab in labs),
          "arbor_http_requests_total has no {route,status} samples: %r" % labs[:5])
    check(any(lab.get("status") == "404" for lab in labs), "no status=\"404\" in arbor_http_requests_total: %r" % labs)
    models = expect_json(d.get("/api/models"))["models"]
    eq(metric_value(samples, "arbor_models_loaded"), float(len(models)), "arbor_models_loaded")
    shaded = metric_value(samples, "arbor_rays_total", mode="shaded")
    check(shaded is not None and shaded >= rays > 0,
          "arbor_rays_total{mode=\"shaded\"} = %r after a frame of X-Rays %d" % (shaded, rays))
    eq(metric_value(samples, "arbor_model_bytes"), float(sum(m["bytes"] for m in models)),
       "arbor_model_bytes vs the sum of MODEL bytes")
    check((metric_value(samples, "arbor_uptime_seconds") or -1) >= 0, "arbor_uptime_seconds")


def _check_model_shape(m):
    check(MODEL_KEYS <= set(m), "MODEL %s lacks keys %s" % (m.get("name"), MODEL_KEYS - set(m)))
    check(os.path.isabs(m["file"]), "MODEL file %r is not absolute" % m["file"])
    b = m["bounds"]
    check(len(b["min"]) == 3 and len(b["max"]) == 3, "MODEL bounds %r" % b)
    combos = sorted((t["accel"], t["builder"]) for t in m["trees"])
    eq(combos, sorted((a, b) for a in ACCELS for b in BUILDERS), "MODEL %s trees (accel, builder)" % m["name"])
    for t in m["trees"]:
        check(t["state"] in ("absent", "building", "ready", "failed"), "tree state %r" % t["state"])
        if t["state"] == "ready":
            check(isinstance(t["build_ms"], (int, float)) and isinstance(t["bytes"], int) and t["bytes"] > 0,
                  "ready tree %s:%s of %s: build_ms %r bytes %r" % (t["accel"], t["builder"], m["name"],
                                                                  t["build_ms"], t["bytes"]))
        else:
            check(t.get("build_ms") is None and t.get("bytes") is None,
                  "%s tree %s:%s of %s has build_ms/bytes %r/%r, expected null" %
                  (t["state"], t["accel"], t["builder"], m["name"], t.get("build_ms"), t.get("bytes")))
        if t["state"] == "failed":
            check(t.get("error"), "failed tree without error")


@test
def test_models_list_our_models():
    d = main_daemon()
    ms = expect_json(d.get("/api/models"))["models"]
    names = [m["name"] for m in ms]
    eq(names, sorted(names), "GET /api/models order")
    truth = our_readme_counts()
    by = {m["name"]: m for m in ms}
    for f in ("cornell.obj", "sphere.obj", "menger.obj"):
        name = f[:-4]
        check(name in by, "GET /api/models lacks %s: %s" % (name, names))
        m = by[name]
        _check_model_shape(m)
        eq((m["triangles"], m["vertices"]), truth[f], "%s triangles, vertices (models/README.md)" % name)
        eq(os.path.realpath(m["file"]), os.path.realpath(our(f)), "%s file (symlink resolved)" % name)
        # the prebuilt default, bvh:sah, is ready
        t = [t for t in m["trees"] if (t["accel"], t["builder"]) == ("bvh", "sah")][0]
        eq(t["state"], "ready", "%s bvh:sah state with the default --prebuild" % name)
    # materials: the .mtl's newmtl names
    with open(our("cornell.mtl")) as f:
        mtl = {ln.split()[1] for ln in f if ln.startswith("newmtl")}
    check(mtl <= set(by["cornell"]["materials"]),
          "cornell materials %r lack some of cornell.mtl's %r" % (by["cornell"]["materials"], sorted(mtl)))
    one = expect_json(d.get("/api/models/cornell"))
    for k in ("name", "file", "triangles", "vertices", "bounds", "materials", "bytes"):
        eq(one[k], by["cornell"][k], "GET /api/models/cornell %s vs the list" % k)


@test
def test_models_list_shared_counts():
    need_shared("castle.obj", "galleon.obj", "bunny.obj")
    d = main_daemon()
    truth = shared_readme_counts()
    by = {m["name"]: m for m in expect_json(d.get("/api/models"))["models"]}
    for f in ("castle.obj", "galleon.obj", "bunny.obj"):
        name = f[:-4]
        check(name in by, "GET /api/models lacks %s" % name)
        m = by[name]
        _check_model_shape(m)
        tri, ver, bmin, bmax = truth[f]
        eq((m["triangles"], m["vertices"]), (tri, ver), "%s triangles, vertices (../shared/models/README.md)" % name)
        diag = math.dist(bmin, bmax)
        for got, want, what in ((m["bounds"]["min"], bmin, "min"), (m["bounds"]["max"], bmax, "max")):
            check(all(abs(g - w) <= 1e-5 * diag for g, w in zip(got, want)),
                  "%s bounds.%s %r, README says %r" % (name, what, got, want))


def _cli_stats(path):
    rc, out, err = run_cli(["stats", "--model", path, "--accel", "all", "--builder", "all", "--json"])
    check(rc == 0, "arbord stats --model %s failed (%d): %s" % (path, rc, err))
    rows = [json.loads(ln) for ln in out.splitlines() if ln.strip()]
    by = {(r["accel"], r["builder"]): r for r in rows if r["layout"] == "binary"}
    for r in rows:
        if r["layout"] == "wide":
            by[(r["accel"], r["builder"])]["wide"] = r
    eq(sorted(set((r["accel"], r["layout"]) for r in rows)), [("bvh", "binary"), ("bvh", "wide"), ("kd", "binary")],
       "arbord stats --json layouts")
    return by


def _same_stats(http, cli, what):
    check(STATS_KEYS <= set(http), "%s: STATS lacks %s" % (what, STATS_KEYS - set(http)))
    # bytes too: a bvh's binary tree as built, although the daemon frees it once collapsed
    skip = {"build_ms", "model"}
    for k in STATS_KEYS - skip:
        a, b = http[k], cli[k]
        if isinstance(b, float) or isinstance(a, float):
            ok = a is not None and abs(a - b) <= 1e-12 * max(1.0, abs(b))
        else:
            ok = a == b
        check(ok, "%s: %s over HTTP %r, arbord stats --json %r" % (what, k, a, b))
    # the bvh's wide tree, which its rays traverse, as the object "wide"
    eq("wide" in http, "wide" in cli, "%s: a wide layout over HTTP as in arbord stats" % what)
    if "wide" in cli:
        _same_stats(http["wide"], cli["wide"], what + " (wide)")


def _stats_vs_cli(name, path):
    d = main_daemon()
    cli = _cli_stats(path)
    eq(sorted(cli), sorted((a, b) for a in ACCELS for b in BUILDERS), "arbord stats rows")
    for (a, b), row in sorted(cli.items()):
        r = d.get("/api/stats?model=%s&accel=%s&builder=%s" % (name, a, b))
        j = expect_json(r)
        trees = [t for t in j["trees"] if t.get("accel") == a and t.get("builder") == b
                 and t.get("model") in (name, d.model(name)["file"])]
        check(len(trees) == 1, "%s: one STATS of %s %s:%s expected, got %r" % (r.req, name, a, b, j["trees"]))
        _same_stats(trees[0], row, r.req)
        # POST .../trees answers the same STATS
        r2 = d.post("/api/models/%s/trees" % name, {"accel": a, "builder": b, "wait": True})
        _same_stats(expect_json(r2), row, r2.req)
        eq(d.tree(name, a, b)["state"], "ready", "%s %s:%s state after stats" % (name, a, b))


@test
def test_stats_equal_cli_sphere():
    _stats_vs_cli("sphere", our("sphere.obj"))


@test
def test_stats_equal_cli_castle():
    (p,) = need_shared("castle.obj")
    _stats_vs_cli("castle", p)


@test
def test_stats_daemon_section():
    d = main_daemon()
    j = expect_json(d.get("/api/stats"))
    dm = j.get("daemon")
    check(isinstance(dm, dict), "GET /api/stats: no daemon object: %r" % j)
    for k in ("uptime_s", "frames", "rays", "frame_ms_mean", "frame_ms_p99", "queue", "memory"):
        check(k in dm, "GET /api/stats daemon lacks %s: %r" % (k, dm))
    check({"waiting", "rendering", "limit"} <= set(dm["queue"]), "daemon.queue keys %s" % sorted(dm["queue"]))
    check({"models", "trees", "limit", "rss"} <= set(dm["memory"]), "daemon.memory keys %s" % sorted(dm["memory"]))
    eq(dm["queue"]["limit"], 16, "daemon.queue.limit with the default --queue")
    models = expect_json(d.get("/api/models"))["models"]
    eq(dm["memory"]["models"], sum(m["bytes"] for m in models), "daemon.memory.models vs the MODELs' bytes")
    ready = [t["bytes"] for m in models for t in m["trees"] if t["state"] == "ready"]
    eq(dm["memory"]["trees"], sum(ready), "daemon.memory.trees vs the ready trees' bytes")
    check(dm["memory"]["rss"] > 0 and dm["memory"]["limit"] > 0, "daemon.memory %r" % dm["memory"])
    check(all(STATS_KEYS <= set(t) for t in j["trees"]), "STATS in /api/stats lack keys")
    eq(len(j["trees"]), len(ready), "GET /api/stats trees: one STATS per ready tree")
    r = d.post("/api/render", {"model": "cornell", "width": 20, "height": 10})
    expect_ok(r)
    dm2 = expect_json(d.get("/api/stats"))["daemon"]
    eq(dm2["frames"], dm["frames"] + 1, "daemon.frames after one frame")
    eq(dm2["rays"], dm["rays"] + int(r.header("X-Rays")), "daemon.rays after one frame of X-Rays")
    check(dm2["uptime_s"] >= dm["uptime_s"], "uptime_s went back")
    limits = expect_json(limits_daemon().get("/api/stats"))["daemon"]["limits"]
    eq(limits, {"max_pixels": 100000, "max_body": 4096, "max_upload": 65536},
       "daemon.limits of --max-pixels 100000 --max-body 4K --max-upload 64K")
    # daemon.embree says what the binary's own bench finds: it runs Embree beside the trees, or refuses
    bench = subprocess.run([ARBORD, "bench", "--model", our("cornell.obj"), "--accel", "bvh", "--builder",
                            "sah", "--runs", "1", "--embree"], capture_output=True, text=True, timeout=300)
    eq(dm["embree"], bench.returncode == 0, "daemon.embree against `arbord bench --embree` (exit %d: %s)" %
       (bench.returncode, bench.stderr.strip()[-200:]))


@test
def test_render_png_sizes_and_headers():
    d = main_daemon()
    for w, h in ((1, 1), (17, 9), (None, None), (8192, 1), (1, 300)):
        body = {"model": "sphere"}
        if w:
            body.update(width=w, height=h)
        r = d.post("/api/render", body)
        pw, ph, ch, _ = png_of(r)
        eq((pw, ph), (w or 640, h or 480), "%s: PNG size" % r.req)
        eq(ch, 3, "%s: PNG channels (8-bit RGB)" % r.req)
        for hd in ("X-Render-Ms", "X-Rays", "X-Mrays-Per-S"):
            v = r.header(hd)
            check(v is not None and re.match(r"^[0-9.eE+-]+$", v), "%s: header %s = %r" % (r.req, hd, v))
        eq(int(r.header("X-Rays")) >= pw * ph, True, "%s: X-Rays %s >= one per pixel" % (r.req, r.header("X-Rays")))
        st = r.header("Server-Timing", "")
        for part in ("queue", "build", "render", "encode"):
            check(re.search(r"\b%s;dur=[0-9.]+" % part, st), "%s: Server-Timing %r lacks %s;dur=" % (r.req, st, part))


def _rect(rows, ch, x, y, w, h):
    return [row[x * ch:(x + w) * ch] for row in rows[y:y + h]]


def _region_test(mode, extra=None, model="cornell", accel="bvh"):
    d = main_daemon()
    W, H = 160, 120
    base = {"model": model, "accel": accel, "mode": mode, "width": W, "height": H, "camera": ORBIT}
    base.update(extra or {})
    r = d.post("/api/render", base)
    fw, fh, ch, full = png_of(r)
    eq((fw, fh), (W, H), "full frame size")
    if mode == "heat":
        hs = r.header("X-Heat-Scale")
        check(hs is not None, "heat frame without X-Heat-Scale")
        base["heat_scale"] = float(hs)
    for x, y, w, h in ((37, 21, 50, 40), (W - 13, H - 7, 13, 7), (0, 0, W, 1), (101, 77, 1, 1)):
        body = dict(base, region={"x": x, "y": y, "w": w, "h": h})
        rr = d.post("/api/render", body)
        rw, rh, rch, reg = png_of(rr)
        eq((rw, rh), (w, h), "%s: region PNG size" % rr.req)
        want = _rect(full, ch, x, y, w, h)
        if reg != want:
            bad = [(i, j) for j in range(h) for i in range(w)
                   if reg[j][i * rch:(i + 1) * rch] != want[j][i * ch:(i + 1) * ch]]
            i, j = bad[0]
            fail("%s: region differs from the full frame at %d of %d pixels; first at region (%d,%d): got %r, "
                 "full frame has %r" % (rr.req, len(bad), w * h, i, j, reg[j][i * rch:(i + 1) * rch],
                                        want[j][i * ch:(i + 1) * ch]))


@test
def test_region_equals_full_frame_shaded():
    _region_test("shaded", {"spp": 2})


@test
def test_region_equals_full_frame_shaded_kd():
    _region_test("shaded", {"spp": 1}, model="menger", accel="kd")


@test
def test_region_equals_full_frame_normals():
    _region_test("normals")


@test
def test_region_equals_full_frame_depth():
    _region_test("depth", model="sphere")


@test
def test_region_equals_full_frame_ao():
    _region_test("ao", {"spp": 2, "ao_samples": 4})


@test
def test_region_equals_full_frame_heat():
    _region_test("heat", model="menger")


@test
def test_render_get_equals_post():
    d = main_daemon()
    cases = [
        ("model=cornell&width=64&height=48&mode=shaded&spp=2&yaw=30&pitch=10&distance=1.5&fov=45",
         {"model": "cornell", "width": 64, "height": 48, "mode": "shaded", "spp": 2,
          "camera": {"yaw": 30, "pitch": 10, "distance": 1.5, "fov": 45}}),
        ("model=sphere&accel=kd&builder=sah&width=50&height=40&mode=normals"
         "&eye=0,1,4&target=0,0,0&up=0,1,0&fov=40&background=0.5,0.25,1",
         {"model": "sphere", "accel": "kd", "builder": "sah", "width": 50, "height": 40, "mode": "normals",
          "camera": {"eye": [0, 1, 4], "target": [0, 0, 0], "up": [0, 1, 0], "fov": 40},
          "background": [0.5, 0.25, 1]}),
        ("model=cornell&width=80&height=60&mode=ao&ao_samples=3&seed=7&region=10,5,30,20",
         {"model": "cornell", "width": 80, "height": 60, "mode": "ao", "ao_samples": 3, "seed": 7,
          "region": {"x": 10, "y": 5, "w": 30, "h": 20}}),
    ]
    for q, body in cases:
        g = d.get("/api/render?" + q)
        p = d.post("/api/render", body)
        png_of(g)
        png_of(p)
        check(g.body == p.body, "GET /api/render?%s and POST of the same fields differ (%d vs %d bytes)"
              % (q, len(g.body), len(p.body)))
    # and the same frame twice is the same bytes
    again = d.post("/api/render", cases[0][1])
    check(again.body == d.post("/api/render", cases[0][1]).body, "the same frame twice gave different bytes")


@test
def test_render_format_json():
    d = main_daemon()
    body = {"model": "cornell", "width": 40, "height": 30, "spp": 2}
    png = d.post("/api/render", body)
    expect_ok(png)
    j = expect_json(d.post("/api/render", dict(body, format="json")))
    eq(set(j), FRAME_JSON_KEYS, "format=json keys")
    eq((j["model"], j["accel"], j["builder"], j["mode"], j["width"], j["height"], j["spp"]),
       ("cornell", "bvh", "sah", "shaded", 40, 30, 2), "format=json echo of the frame")
    eq(j["rays"], int(png.header("X-Rays")), "format=json rays vs X-Rays of the PNG of the same frame")
    check(j["heat_scale"] is None, "heat_scale not null outside heat mode: %r" % j["heat_scale"])
    h = expect_json(d.post("/api/render", dict(body, mode="heat", format="json")))
    check(isinstance(h["heat_scale"], (int, float)) and isinstance(h["heat_max"], (int, float)),
          "heat mode format=json: heat_scale %r heat_max %r" % (h["heat_scale"], h["heat_max"]))
    g = expect_json(d.get("/api/render?model=cornell&width=40&height=30&spp=2&format=json"))
    eq(g["rays"], j["rays"], "GET format=json rays vs POST")


def _costs(r, w, h):
    """The float32 costs of a format=costs answer, checked for its type and length."""
    expect_ok(r)
    eq(r.header("Content-Type"), "application/octet-stream", "format=costs content type")
    eq(len(r.body), 4 * w * h, "format=costs bytes for %dx%d" % (w, h))
    return struct.unpack("<%df" % (w * h), r.body)


@test
def test_render_format_costs():
    """A heat frame's per-pixel costs: each pixel's is its ray's own count (POST /api/ray, a traversal with a
    visitor), their mean and max are the JSON statistics', a region's are the full frame's there, GET = POST."""
    d = main_daemon()
    w, h = 48, 36
    for model, accel in (("menger", "kd"), ("menger", "bvh"), ("sphere", "bvh")):
        body = {"model": model, "accel": accel, "mode": "heat", "width": w, "height": h,
                "camera": {"yaw": 35, "pitch": 25, "distance": 1.3, "fov": 50}}
        costs = _costs(d.post("/api/render", dict(body, format="costs")), w, h)
        stats = expect_json(d.post("/api/render", dict(body, format="json")))
        check(abs(sum(costs) / len(costs) - stats["heat_mean"]) <= 1e-6 * stats["heat_mean"],
              "%s %s: mean cost %r, heat_mean %r" % (model, accel, sum(costs) / len(costs), stats["heat_mean"]))
        eq(max(costs), stats["heat_max"], "%s %s: max cost vs heat_max" % (model, accel))
        for x, y in ((0, 0), (24, 18), (10, 30), (40, 5), (31, 22), (47, 35)):
            ray = expect_json(d.post("/api/ray", {k: body[k] for k in ("model", "accel", "camera", "width", "height")}
                                     | {"x": x, "y": y}))
            eq(costs[y * w + x], ray["counts"]["nodes"] + ray["counts"]["tris"],
               "%s %s pixel (%d,%d): cost vs its ray's counts %r" % (model, accel, x, y, ray["counts"]))
        region = _costs(d.post("/api/render", dict(body, format="costs", region={"x": 8, "y": 4, "w": 20, "h": 10})), 20, 10)
        eq(list(region), [costs[(4 + j) * w + 8 + i] for j in range(10) for i in range(20)],
           "%s %s: a region's costs vs the full frame's" % (model, accel))
    g = d.get("/api/render?model=menger&accel=bvh&mode=heat&width=%d&height=%d&yaw=35&pitch=25&distance=1.3&fov=50"
              "&format=costs" % (w, h))
    p = d.post("/api/render", {"model": "menger", "accel": "bvh", "mode": "heat", "width": w, "height": h,
                               "camera": {"yaw": 35, "pitch": 25, "distance": 1.3, "fov": 50}, "format": "costs"})
    eq(_costs(g, w, h), _costs(p, w, h), "GET vs POST costs")
    # with samples, a pixel's cost is the mean over them: the frame's mean is heat_mean still
    aa = {"model": "menger", "mode": "heat", "width": 24, "height": 18, "spp": 4}
    costs = _costs(d.post("/api/render", dict(aa, format="costs")), 24, 18)
    stats = expect_json(d.post("/api/render", dict(aa, format="json")))
    check(any(c != int(c) for c in costs), "no pixel at 4 spp has a fractional mean cost")
    check(abs(sum(costs) / len(costs) - stats["heat_mean"]) <= 1e-6 * stats["heat_mean"], "4 spp: mean cost vs heat_mean")


@test
def test_ray_hit_and_miss():
    d = main_daemon()
    cam = {"eye": [0, 0, 5], "target": [0, 0, 0], "up": [0, 1, 0], "fov": 30}
    j = expect_json(d.post("/api/ray", {"model": "sphere", "camera": cam, "width": 101, "height": 101,
                                        "x": 50, "y": 50}))
    o, dr = j["ray"]["origin"], j["ray"]["dir"]
    check(all(abs(a - b) < 1e-6 for a, b in zip(o, [0, 0, 5])), "ray origin %r, expected the eye" % o)
    n = math.sqrt(sum(c * c for c in dr))
    check(abs(dr[0] / n) < 1e-6 and abs(dr[1] / n) < 1e-6 and dr[2] < 0, "centre ray dir %r, expected (0,0,-1)" % dr)
    hit = j["hit"]
    check(hit is not None, "centre ray of the unit sphere from z=5 missed: %r" % j)
    # the icosphere is inscribed in the unit sphere: its surface is within 1.5% of radius 1
    check(4.0 - 1e-5 <= hit["t"] <= 4.02, "hit t %r, expected 4..4.02" % hit["t"])
    check(hit["normal"][2] > 0.99, "hit normal %r, expected ~ +z" % hit["normal"])
    check(abs(hit["point"][2] - (5 - hit["t"])) < 1e-4, "hit point %r vs t %r" % (hit["point"], hit["t"]))
    check(0 <= hit["triangle"] < 5120, "hit triangle %r" % hit["triangle"])
    check(j["counts"]["nodes"] > 0 and j["counts"]["tris"] > 0, "counts %r" % j["counts"])
    check(j["steps"] and all({"box", "depth", "leaf", "tris"} <= set(s) for s in j["steps"]), "steps %r" % j["steps"][:3])
    miss = expect_json(d.post("/api/ray", {"model": "sphere", "camera": cam, "width": 101, "height": 101,
                                           "x": 0, "y": 0}))
    check(miss["hit"] is None, "corner ray (outside the sphere's disc at fov 30) hit: %r" % miss["hit"])


@test
def test_boxes_root_is_model_bounds():
    d = main_daemon()
    m = d.model("sphere")
    j = expect_json(d.get("/api/models/sphere/trees/bvh/sah/boxes?depth=0"))
    eq((j["depth"], j["count"], j["truncated"]), (0, 1, False), "boxes depth 0: depth, count, truncated")
    b = j["boxes"][0]
    for k in ("min", "max"):
        check(all(abs(g - w) < 1e-5 for g, w in zip(b[k], m["bounds"][k])),
              "bvh root box %s %r vs model bounds %r" % (k, b[k], m["bounds"][k]))
    j2 = expect_json(d.get("/api/models/sphere/trees/bvh/sah/boxes?depth=2&all=1"))
    # the 8-wide tree rays traverse: the root, up to 8 children, up to 64 grandchildren
    check(3 <= j2["count"] <= 1 + 8 + 64 and j2["count"] == len(j2["boxes"]),
          "boxes depth 2 all=1: count %r" % j2["count"])
    eq(sorted({x["depth"] for x in j2["boxes"]}), [0, 1, 2], "depths with all=1")
    j3 = expect_json(d.get("/api/models/sphere/trees/bvh/sah/boxes?depth=30&leaves=1"))
    check(j3["count"] > 0 and all(x["leaf"] for x in j3["boxes"]), "leaves=1 gave non-leaves or none")
    eq(j3["max_boxes"], 20000, "max_boxes")


@test
def test_trees_post_wait_false():
    d = main_daemon()
    r = d.post("/api/models/cornell/trees", {"accel": "kd", "builder": "mean", "wait": False})
    j = expect_json(r, 202)
    eq((j.get("model"), j.get("accel"), j.get("builder")), ("cornell", "kd", "mean"), "202 body")
    check(j.get("state") in ("absent", "building", "ready"), "202 state %r" % j.get("state"))
    end = time.time() + 20
    while d.tree("cornell", "kd", "mean")["state"] != "ready":
        check(time.time() < end, "kd:mean of cornell not ready 20 s after wait:false")
        time.sleep(0.05)


@test
def test_request_id_on_every_answer():
    d = main_daemon()
    ids = []
    for method, path, body in (("GET", "/healthz", None), ("GET", "/api/models", None),
                               ("GET", "/api/nope", None), ("GET", "/metrics", None),
                               ("POST", "/api/render", b'{"model":"cornell","width":8,"height":8}'),
                               ("POST", "/api/render", b'{bad'), ("GET", "/", None)):
        r = d.req(method, path, body=body)
        rid = r.header("X-Request-Id")
        check(rid, "%s %s (%d): no X-Request-Id" % (method, path, r.status))
        ids.append(rid)
    eq(len(set(ids)), len(ids), "X-Request-Id values distinct")


@test
def test_default_web_index():
    """Without --web, the repository's web/ answers / with its index.html."""
    d = default_web_daemon()
    r = d.get("/")
    expect_ok(r)
    check(r.header("Content-Type", "").startswith("text/html"), "GET / Content-Type %r" % r.header("Content-Type"))
    with open(os.path.join(REPO, "web", "index.html"), "rb") as f:
        check(r.body == f.read(), "GET / without --web is not the repository's web/index.html (%s)" % ARBORD)


@test
def test_keep_alive_across_answers_and_errors():
    """One connection carries frames, errors (400, 404, 405, 413-free) and reads in turn."""
    import http.client
    d = main_daemon()
    conn = http.client.HTTPConnection(d.host, d.port, timeout=60)
    try:
        seq = [("POST", "/api/render", b'{"model":"cornell","width":16,"height":16}', 200),
               ("POST", "/api/render", b'{"model":', 400),
               ("GET", "/api/models/no-such-model", None, 404),
               ("DELETE", "/api/render", None, 405),
               ("GET", "/api/render?model=sphere&width=8&height=8", None, 200),
               ("POST", "/api/render", b'{"model":"cornell","width":16,"height":16,"format":"json"}', 200),
               ("GET", "/healthz", None, 200)]
        for method, path, body, want in seq * 2:
            conn.request(method, path, body=body, headers={"Content-Type": "application/json"} if body else {})
            r = conn.getresponse()
            data = r.read()
            eq(r.status, want, "%s %s on a kept-alive connection (body %r)" % (method, path, data[:120]))
    finally:
        conn.close()


@test
def test_stats_filtered_by_model():
    d = main_daemon()
    j = expect_json(d.get("/api/stats?model=cornell"))
    check(j["trees"] and all(t["model"] in ("cornell", d.model("cornell")["file"]) for t in j["trees"]),
          "GET /api/stats?model=cornell has other models' trees: %r" % [t["model"] for t in j["trees"]])
    j = expect_json(d.get("/api/stats?model=sphere&accel=bvh"))
    check(j["trees"] and all(t["accel"] == "bvh" for t in j["trees"]), "?accel=bvh gave %r" %
          [(t["accel"], t["builder"]) for t in j["trees"]])


@test
def test_long_and_odd_urls_answered():
    """Odd URLs get a 4xx and leave the daemon serving. (A query of ~1000 parameters gets no HTTP
    answer at all -- libmicrohttpd's connection memory -- which is noted, not failed.)"""
    d = main_daemon()
    for path in ("/api/models/" + "x" * 20000, "/api/render?" + "&".join("k%d=1" % i for i in range(100)),
                 "/api/models/%ff%fe", "/api//models", "/api/models/cornell/"):
        r = d.raw(b"GET " + path.encode() + b" HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
        check(400 <= r.status < 500, "GET %s... -> %d, expected a 4xx" % (path[:60], r.status))
    d.raw(b"GET /api/render?" + "&".join("k%d=1" % i for i in range(3000)).encode() +
          b" HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
    check(d.alive(), "daemon died on odd URLs")
    expect_ok(d.get("/healthz"))


@test
def test_ray_bvh_and_kd_agree():
    """The primary ray through a pixel hits the same triangle at the same t in every tree."""
    d = main_daemon()
    cam = {"yaw": 35, "pitch": 25, "distance": 1.3, "fov": 50}
    for model in ("menger", "sphere"):
        for x, y in ((10, 10), (32, 24), (40, 17), (55, 40), (5, 44)):
            hits = {}
            for accel, builder in (("bvh", "sah"), ("kd", "sah"), ("bvh", "median"), ("kd", "spatial")):
                j = expect_json(d.post("/api/ray", {"model": model, "accel": accel, "builder": builder,
                                                    "camera": cam, "width": 64, "height": 48, "x": x, "y": y}))
                h = j["hit"]
                hits[accel + ":" + builder] = None if h is None else (h["triangle"], round(h["t"], 5))
            check(len(set(hits.values())) == 1, "%s pixel (%d,%d): trees disagree: %r" % (model, x, y, hits))


@test
def test_metrics_count_requests_and_frames():
    d = main_daemon()
    s0, _ = d.metrics()
    st0 = expect_json(d.get("/api/stats"))["daemon"]
    for _ in range(3):
        expect_ok(d.get("/healthz"))
    for i in range(2):
        expect_ok(d.post("/api/render", {"model": "cornell", "width": 8, "height": 8, "seed": i + 1}))
    s1, _ = d.metrics()
    st1 = expect_json(d.get("/api/stats"))["daemon"]

    def healthz(samples):
        return sum(v for lab, v in samples.get("arbor_http_requests_total", [])
                   if "health" in lab.get("route", "") and lab.get("status") == "200")
    eq(healthz(s1) - healthz(s0), 3.0, "arbor_http_requests_total{route=~health,status=200} after 3 GET /healthz")
    rc0 = metric_value(s0, "arbor_render_seconds_count") or 0
    rc1 = metric_value(s1, "arbor_render_seconds_count") or 0
    eq(rc1 - rc0, 2.0, "arbor_render_seconds_count after 2 frames")
    eq(st1["frames"] - st0["frames"], 2, "daemon.frames after 2 frames")
    eq(metric_value(s1, "arbor_render_seconds_count"), float(st1["frames"]),
       "arbor_render_seconds_count vs daemon.frames")


@test
def test_boxes_truncated_at_max_boxes():
    d = main_daemon()
    j = expect_json(d.get("/api/models/menger/trees/kd/spatial/boxes?depth=40&all=1"))
    st = expect_json(d.get("/api/stats?model=menger&accel=kd&builder=spatial"))["trees"][0]
    check(st["max_depth"] <= 40 and st["nodes"] > j["max_boxes"] == 20000,
          "kd:spatial of menger: %d nodes to depth %d, max_boxes %r" % (st["nodes"], st["max_depth"], j["max_boxes"]))
    # max_boxes of them listed, and all of them counted
    eq((j["count"], j["truncated"], len(j["boxes"])), (st["nodes"], True, j["max_boxes"]),
       "every node to depth 40: count, truncated, boxes listed")
    # an even sample over the whole tree, not its first max_boxes in depth-first order (one corner of
    # the model): the leaves listed reach every side of the model's box
    model = expect_json(d.get("/api/models/menger"))["bounds"]
    leaves = [b for b in j["boxes"] if b["leaf"]]
    for axis in range(3):
        size = model["max"][axis] - model["min"][axis]
        lo = min(b["min"][axis] for b in leaves)
        hi = max(b["max"][axis] for b in leaves)
        check(lo - model["min"][axis] < 0.1 * size and model["max"][axis] - hi < 0.1 * size,
              "sampled leaves span %g..%g on axis %d of the model's %g..%g" %
              (lo, hi, axis, model["min"][axis], model["max"][axis]))
