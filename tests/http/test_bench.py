"""Bench jobs: 202 + id, progress, rows of `arbord bench --format json`, cancel."""
import json
import time

from harness import Daemon, check, eq, expect_error, expect_json, fail, main_daemon, our, run_cli, test

JOB_KEYS = {"id", "model", "state", "progress", "elapsed_ms", "rows", "error"}


def _cli_row():
    rc, out, err = run_cli(["bench", "--model", our("sphere.obj"), "--accel", "bvh", "--builder", "sah",
                            "--runs", "1", "--format", "json"])
    check(rc == 0, "arbord bench failed (%d): %s" % (rc, err[-500:]))
    return json.loads(out.strip().splitlines()[-1])


def _poll(d, jid, until, timeout):
    seen = []
    end = time.time() + timeout
    while True:
        j = expect_json(d.get("/api/jobs/%s" % jid))
        seen.append(j)
        if j["state"] in until:
            return j, seen
        if time.time() > end:
            fail("job %s still %s after %d s: %r" % (jid, j["state"], timeout, j))
        time.sleep(0.1)


@test
def test_bench_job_runs_to_done():
    d = main_daemon()
    r = d.post("/api/bench", {"model": "sphere", "accel": ["bvh", "kd"], "builder": ["sah", "median"], "runs": 1})
    j = expect_json(r, 202)
    check(isinstance(j.get("id"), str) and j["id"], "202 id %r (a string)" % j.get("id"))
    eq(j.get("state"), "queued", "202 state")
    eq(r.header("Location"), "/api/jobs/%s" % j["id"], "Location of the 202")
    job, seen = _poll(d, j["id"], ("done", "failed", "cancelled"), 120)
    eq(job["state"], "done", "final state (error %r)" % job.get("error"))
    check(JOB_KEYS <= set(job), "job lacks %s" % (JOB_KEYS - set(job)))
    eq(job["model"], "sphere", "job model")
    eq(len(job["rows"]), 4, "rows: 2 accels x 2 builders")
    eq(job["progress"], {"done": 4, "total": 4}, "progress when done")
    check(isinstance(job["elapsed_ms"], (int, float)) and job["elapsed_ms"] > 0, "elapsed_ms %r" % job["elapsed_ms"])
    dones = [s["progress"]["done"] for s in seen]
    eq(dones, sorted(dones), "progress.done never goes back")
    check(all(s["progress"]["total"] == 4 for s in seen), "progress.total not 4 throughout")
    check(all(len(s["rows"]) == s["progress"]["done"] for s in seen), "rows so far != progress.done")
    eq(sorted((x["accel"], x["builder"]) for x in job["rows"]),
       [("bvh", "median"), ("bvh", "sah"), ("kd", "median"), ("kd", "sah")], "rows (accel, builder)")
    cli = _cli_row()
    row = [x for x in job["rows"] if (x["accel"], x["builder"]) == ("bvh", "sah")][0]
    eq(set(row), set(cli), "bench row keys vs arbord bench --format json")
    for k in ("triangles", "primary_hits", "sah_cost", "mean_leaf_depth", "mean_tris_per_leaf", "primary_nodes_per_ray",
              "diffuse_tris_per_ray", "shadow_nodes_per_ray"):
        eq(row[k], cli[k], "bvh:sah row %s vs arbord bench" % k)
    check(abs(row["primary_tsum"] - cli["primary_tsum"]) <= 1e-6 * abs(cli["primary_tsum"]),
          "primary_tsum %r vs arbord bench %r" % (row["primary_tsum"], cli["primary_tsum"]))


@test
def test_bench_job_beside_robust_embree():
    """"embree": "robust" adds Embree's row in its robust mode (named so by what Embree reports)
    with the tree's primary hits, and the tree row's ratios to it."""
    d = main_daemon()
    j = expect_json(d.post("/api/bench", {"model": "sphere", "accel": ["bvh"], "builder": ["sah"], "runs": 1,
                                          "embree": "robust"}), 202)
    job, _ = _poll(d, j["id"], ("done", "failed", "cancelled"), 120)
    if job["state"] == "failed" and "built without Embree" in (job.get("error") or ""):
        return
    eq(job["state"], "done", "final state (error %r)" % job.get("error"))
    eq([(x["accel"], x["builder"]) for x in job["rows"]], [("bvh", "sah"), ("embree", "robust")], "rows")
    tree, peer = job["rows"]
    check(peer["primary_hits"] == tree["primary_hits"] > 0, "primary hits %r vs Embree's %r"
          % (tree["primary_hits"], peer["primary_hits"]))
    for s in ("primary", "diffuse", "shadow"):
        check(tree[s + "_ratio"] > 0, "%s_ratio %r" % (s, tree[s + "_ratio"]))


@test
def test_bench_job_ids_name_one_daemons_jobs():
    """Two daemons (as behind one load balancer, or one restarted) each run a job: the ids differ, and
    each daemon answers the other's id with 404, not with its own job of that number."""
    d = main_daemon()
    body = {"model": "cornell", "accel": ["bvh"], "builder": ["median"], "runs": 1}
    a = expect_json(d.post("/api/bench", body), 202)["id"]
    d2 = Daemon([our("cornell.obj")], ["--threads", "1"], name="second bench daemon")
    try:
        b = expect_json(d2.post("/api/bench", body), 202)["id"]
        check(a != b, "both daemons named their first job %r" % a)
        expect_error(d2.get("/api/jobs/%s" % a), 404, "not_found")
        expect_error(d.get("/api/jobs/%s" % b), 404, "not_found")
        # the id only as written: not with a sign, a leading zero or a space before it
        for other in ("+" + a, "0" + a, "%20" + a, "-" + str(2 ** 64 - int(a))):
            expect_error(d.get("/api/jobs/%s" % other), 404, "not_found")
        _poll(d2, b, ("done", "failed", "cancelled"), 60)
        d2.stop_clean()
    finally:
        d2.cleanup()
    _poll(d, a, ("done", "failed", "cancelled"), 60)


@test
def test_bench_jobs_queued_are_bounded():
    """Past 8 jobs queued behind the running one, POST /api/bench is 503 busy with Retry-After, and the
    queued jobs can be cancelled."""
    d = Daemon([our("cornell.obj")], ["--threads", "1"], name="bench queue daemon")
    try:
        body = {"model": "cornell", "accel": ["bvh", "kd"], "builder": ["spatial", "median", "mean", "sah"],
                "runs": 20}
        rs = [d.post("/api/bench", body) for _ in range(10)]
        ids = [expect_json(r, 202)["id"] for r in rs if r.status == 202]
        # 8 queued, and one more when the first had started when the ninth came
        check(len(ids) in (8, 9) and [r.status for r in rs] == [202] * len(ids) + [503] * (10 - len(ids)),
              "statuses of 10 jobs: %r" % [r.status for r in rs])
        expect_error(rs[-1], 503, "busy")
        check(rs[-1].header("Retry-After"), "503 without Retry-After")
        for jid in ids:
            expect_json(d.req("DELETE", "/api/jobs/%s" % jid))
        for jid in ids:
            job, _ = _poll(d, jid, ("cancelled", "done", "failed"), 30)
            # the last was queued behind seven others when cancelled: it says so, as a stopped one does
            if jid == ids[-1]:
                eq((job["state"], job["error"]), ("cancelled", "cancelled while queued"), "a queued job cancelled")
        expect_json(d.post("/api/bench", dict(body, runs=1, accel=["bvh"], builder=["median"])), 202)
        d.stop_clean()
    finally:
        d.cleanup()


@test
def test_bench_job_cancel():
    d = main_daemon()
    j = expect_json(d.post("/api/bench", {"model": "menger", "accel": ["bvh", "kd"],
                                          "builder": ["spatial", "median", "mean", "sah"], "runs": 20}), 202)
    jid = j["id"]
    _poll(d, jid, ("running", "done", "failed"), 30)
    r = d.req("DELETE", "/api/jobs/%s" % jid)
    jj = expect_json(r)
    eq(jj.get("id"), jid, "DELETE /api/jobs/%s answers the job" % jid)
    job, _ = _poll(d, jid, ("cancelled", "done", "failed"), 15)
    eq(job["state"], "cancelled", "state after DELETE")
    check(job["progress"]["done"] < job["progress"]["total"] == 8, "progress of the cancelled job %r" % job["progress"])
    # the daemon is free again: a frame renders at once
    t0 = time.time()
    d.post("/api/render", {"model": "cornell", "width": 16, "height": 16})
    check(time.time() - t0 < 5, "a frame after the cancel took %.1f s" % (time.time() - t0))
