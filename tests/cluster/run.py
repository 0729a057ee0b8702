#!/usr/bin/python3
"""arbord as a cluster: deploy/cluster.sh's 3 daemons, each a host in its own network
namespace, behind Debian's nginx, over one shared models folder (docs/SCALE.md).

    tests/cluster/run.py

Needs root (network namespaces) and nginx; without them every test is IGNOREd with the
reason. Env: ARBORD (default build/arbord), ARBOR_SHARED_MODELS (default ../shared/models).
Prints Unity's lines and last "N Tests M Failures K Ignored"; exit status 1 on a failure.
"""
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import traceback

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(os.path.dirname(HERE))
sys.path.insert(0, os.path.join(REPO, "tests", "http"))
sys.dont_write_bytecode = True

import harness  # noqa: E402
from harness import Fail, Ignore, check, eq, expect_error, expect_ok, fail, png_decode, request  # noqa: E402

TESTS = []
CUBE_OBJ = b"".join(b"v %d %d %d\n" % (x, y, z) for x in (0, 1) for y in (0, 1) for z in (0, 1)) + \
    b"f 1 2 4 3\nf 5 7 8 6\nf 1 5 6 2\nf 3 4 8 7\nf 1 3 7 5\nf 2 6 8 4\n"
TETRA_OBJ = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"
# Heavy enough that 16 strips of it keep three single-thread nodes busy for seconds.
HEAVY = ["--model", "menger", "--width", "768", "--height", "768", "--spp", "6", "--yaw", "20", "--pitch", "15",
         "--distance", "1.4"]


def test(func):
    TESTS.append((func.__name__, func, func.__code__.co_firstlineno))
    return func


class Cluster:
    """deploy/cluster.sh -n 3 on a free port, over a models folder of its own."""

    def __init__(self, n=3):
        self.state = tempfile.mkdtemp(prefix="arbor-cluster-")
        self.port = harness.free_port()
        env = dict(os.environ, ARBORD=harness.ARBORD)
        self.out = open(os.path.join(self.state, "cluster.out"), "w+")
        # SIGINT at its default: a suite started in the background without
        # job control (nohup, `cmd &` in a script) inherits it ignored, and
        # bash cannot trap a signal ignored on entry, so Ctrl-C's test would
        # find cluster.sh deaf to it (CI once did).
        self.proc = subprocess.Popen([os.path.join(REPO, "deploy", "cluster.sh"), "-n", str(n), "--port",
                                      str(self.port), "--threads", "1", "--state", self.state],
                                     stdout=self.out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=env,
                                     preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
        end = time.time() + 120
        while "open http://" not in self.output():
            if self.proc.poll() is not None or time.time() > end:
                fail("deploy/cluster.sh did not come up: %s" % self.output()[-2000:])
            time.sleep(0.1)
        self.token = open(os.path.join(self.state, "token")).read().strip()

    def output(self):
        self.out.flush()
        with open(self.out.name) as f:
            return f.read()

    def nodes(self):
        """[(address, port, pid, namespace)] as the script last wrote them."""
        with open(os.path.join(self.state, "nodes")) as f:
            return [(p[1], int(p[2]), int(p[3]), p[4]) for p in (line.split() for line in f) if len(p) == 5]

    def node(self, i, method, path, **kw):
        addr, port, _, _ = self.nodes()[i]
        return request(port, method, path, host=addr, **kw)

    def lb(self, method, path, **kw):
        return request(self.port, method, path, **kw)

    def access_log(self):
        with open(os.path.join(self.state, "nginx", "access.log")) as f:
            return f.read().splitlines()

    def render(self, args, out, timeout=180):
        p = subprocess.run([harness.ARBORD, "render", "--url", "http://127.0.0.1:%d" % self.port] + args +
                           ["-o", out], capture_output=True, timeout=timeout)
        return p.returncode, (p.stdout + p.stderr).decode("utf-8", "replace")

    def stop(self):
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(60)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        return self.proc.returncode


CLUSTER = None


def cluster():
    global CLUSTER
    if CLUSTER is None:
        CLUSTER = Cluster()
    return CLUSTER


def pixels(png_bytes):
    return png_decode(png_bytes)[3]


def whole_frame(c, i, args):
    """The frame of render flags `args` rendered whole by node i alone, as its PNG bytes."""
    keys = {"--model": "model", "--width": "width", "--height": "height", "--spp": "spp", "--yaw": "yaw",
            "--pitch": "pitch", "--distance": "distance"}
    q = "&".join("%s=%s" % (keys[args[k]], args[k + 1]) for k in range(0, len(args), 2))
    r = c.node(i, "GET", "/api/render?" + q + "&fov=45", timeout=180)
    expect_ok(r)
    return r.body


# ---------------------------------------------------------------------------- tests

@test
def test_three_nodes_each_its_own_host_behind_nginx():
    c = cluster()
    nodes = c.nodes()
    eq(len(nodes), 3, "nodes")
    eq(len({a for a, _, _, _ in nodes}), 3, "distinct node addresses")
    for i, (addr, _, _, ns) in enumerate(nodes):
        check(addr.startswith("10.77.") and ns != "-", "node %d is not in a namespace of its own: %s %s" % (i, addr, ns))
        eq(c.node(i, "GET", "/readyz").status, 200, "node %d /readyz" % i)
    r = harness.parallel(9, lambda i: c.lb("GET", "/api/render?model=cornell&width=64&height=48&spp=1&seed=%d" % i))
    for x in r:
        check(not isinstance(x, Exception) and x.status == 200, "a frame through nginx: %r" % x)
    used = {m.group(1) for m in (re.search(r"upstream=(\S+) upstream_status=200", l) for l in c.access_log())
            if m and "/api/render" in m.string}
    check(len(used) >= 2, "9 concurrent frames went to %d node(s): %s" % (len(used), used))


@test
def test_frame_in_8_regions_equals_one_nodes_frame_byte_for_byte():
    c = cluster()
    args = ["--model", "menger", "--width", "320", "--height", "240", "--spp", "2", "--yaw", "30", "--pitch", "20",
            "--distance", "1.6"]
    out = os.path.join(c.state, "split8.png")
    before = len(c.access_log())
    rc, text = c.render(args + ["--split", "8"], out)
    eq(rc, 0, "arbord render --split 8: %s" % text)
    with open(out, "rb") as f:
        split = f.read()
    whole = whole_frame(c, 2, args)
    check(pixels(split) == pixels(whole), "the 8 regions differ from node 2's whole frame")
    check(split == whole, "same pixels, but the PNG bytes differ (%d vs %d bytes)" % (len(split), len(whole)))
    strips = [l for l in c.access_log()[before:] if "POST /api/render" in l]
    eq(len(strips), 8, "regions asked of nginx")
    check(len({re.search(r"upstream=(\S+)", l).group(1) for l in strips}) >= 2,
          "the 8 regions were rendered by one node only: %s" % strips)


@test
def test_upload_through_a_is_rendered_by_c_and_a_delete_is_seen_by_all():
    c = cluster()
    auth = {"Authorization": "Bearer " + c.token}
    j = expect_ok(c.node(0, "PUT", "/api/models/shared-cube", body=CUBE_OBJ, headers=auth), 201).json()
    eq(j["triangles"], 12, "triangles uploaded through node A")
    r = c.node(2, "POST", "/api/render", js={"model": "shared-cube", "width": 48, "height": 32})
    expect_ok(r)
    check(len(set(pixels(r.body))) > 1, "node C's frame of the cube is blank")
    eq(c.node(2, "GET", "/api/models/shared-cube").json()["triangles"], 12, "node C's MODEL")
    # A newer version through A: C loads it on its next request.
    expect_ok(c.node(0, "PUT", "/api/models/shared-cube?replace=1", body=TETRA_OBJ, headers=auth), 200)
    eq(c.node(2, "GET", "/api/models/shared-cube").json()["triangles"], 4, "node C after the replace through A")
    # Refused as a conflict by B, which has never loaded it: the folder has it.
    expect_error(c.node(1, "PUT", "/api/models/shared-cube", body=CUBE_OBJ, headers=auth), 409, "conflict")
    # Deleted through B: A and C answer 404, and so does nginx.
    expect_ok(c.node(1, "DELETE", "/api/models/shared-cube", headers=auth))
    for i in (0, 2):
        expect_error(c.node(i, "POST", "/api/render", js={"model": "shared-cube", "width": 8, "height": 8}), 404,
                     "not_found")
    expect_error(c.lb("GET", "/api/models/shared-cube"), 404, "not_found")
    names = [m["name"] for m in c.node(2, "GET", "/api/models").json()["models"]]
    check("shared-cube" not in names, "node C still lists the deleted model: %s" % names)


@test
def test_killed_node_loses_no_region_and_rejoins_after_building():
    c = cluster()
    dragon = os.path.join(harness.SHARED, "dragon.obj.gz")
    out = os.path.join(c.state, "killed.png")
    before = len(c.access_log())
    victim = 1
    _, _, old_pid, _ = c.nodes()[victim]
    result = {}
    t = threading.Thread(target=lambda: result.update(r=c.render(HEAVY + ["--split", "16", "--connections", "6"], out)),
                         daemon=True)
    t.start()
    end = time.time() + 60
    while c.node(victim, "GET", "/api/stats").json()["daemon"]["queue"]["rendering"] < 1:
        check(t.is_alive() and time.time() < end, "node %d never rendered a region" % victim)
        time.sleep(0.02)
    # A big model in the shared folder makes the restarted node take seconds to be ready.
    slow = os.path.exists(dragon)
    if slow:
        os.symlink(dragon, os.path.join(c.state, "models", "dragon.obj.gz"))
    os.kill(old_pid, signal.SIGKILL)
    t.join(180)
    check(not t.is_alive(), "arbord render never finished")
    rc, text = result["r"]
    eq(rc, 0, "arbord render --split 16 with node %d killed mid-run: %s" % (victim, text))
    with open(out, "rb") as f:
        got = f.read()
    check(pixels(got) == pixels(whole_frame(c, 0, HEAVY)), "the frame differs from node 0's whole frame")
    log = c.access_log()[before:]
    strips = [l for l in log if "POST /api/render" in l]
    eq(len(strips), 16, "regions asked of nginx (the client never had to ask again)")
    retried = [l for l in strips if re.search(r"upstream=\S+, ", l)]
    check(retried, "no region was passed to a second node: %s" % strips)
    # The node comes back (deploy/cluster.sh starts it again); while it builds it answers 503.
    end = time.time() + 120
    while c.nodes()[victim][2] == old_pid or not _listening(c, victim):
        check(time.time() < end, "node %d was not started again" % victim)
        time.sleep(0.05)
    # Loading the dragon and building its tree take it about half a second on
    # one thread, which the node may already be past: while /readyz says 503
    # it must refuse frames with 503 and Retry-After (test_endpoints.py's
    # readyz test holds a daemon with several big trees to build to it).
    if slow and c.node(victim, "GET", "/readyz").status == 503:
        r = c.node(victim, "POST", "/api/render", js={"model": "cornell", "width": 8, "height": 8})
        if r.status != 200 or c.node(victim, "GET", "/readyz").status != 200:
            expect_error(r, 503, "busy")
            check(r.header("Retry-After"), "no Retry-After on the 503 of a node still building")
    mark = len(c.access_log())
    frames = harness.parallel(6, lambda i: c.lb("GET", "/api/render?model=cornell&width=32&height=24&seed=%d" % i))
    check(all(not isinstance(f, Exception) and f.status == 200 for f in frames),
          "frames through nginx while node %d builds: %r" % (victim, [getattr(f, "status", f) for f in frames]))
    while c.node(victim, "GET", "/readyz").status != 200:
        check(time.time() < end, "node %d never became ready again" % victim)
        time.sleep(0.1)
    # nginx tries a node it left out again once fail_timeout (3 s, counted in
    # whole seconds) has passed since its last failure, which may have been
    # one of the frames above: give it three times that.
    addr = "%s:%d" % c.nodes()[victim][:2]
    rejoined = False
    seed = 100
    end = time.time() + 12
    while not rejoined and time.time() < end:
        expect_ok(c.lb("GET", "/api/render?model=cornell&width=32&height=24&seed=%d" % seed))
        seed += 1
        rejoined = any(("upstream=%s upstream_status=200" % addr) in l for l in c.access_log()[mark:])
        time.sleep(0.1)
    check(rejoined, "node %d (%s) answered no frame through nginx in the 12 s after it was ready again" %
          (victim, addr))
    if slow:
        os.unlink(os.path.join(c.state, "models", "dragon.obj.gz"))


@test
def test_nginx_lends_its_token_to_tools_and_its_own_pages_only():
    c = cluster()
    body, ctype = harness.multipart([("model", "lent.obj", "text/plain", TETRA_OBJ)])
    own = "http://127.0.0.1:%d" % c.port

    def upload(origin):
        h = {"Content-Type": ctype}
        if origin:
            h["Origin"] = origin
        return c.lb("POST", "/api/models/lent?replace=1", body=body, headers=h)

    # A form another site's page posts here needs no CORS preflight: it must not get the token.
    for origin in ("http://evil.example", "null", "http://evil.example:%d" % c.port):
        expect_error(upload(origin), 401, "unauthorized")
    expect_error(c.lb("GET", "/api/models/lent"), 404, "not_found")
    eq(expect_ok(upload(own), 201).json()["triangles"], 4, "an upload from the cluster's own page")
    eq(expect_ok(upload(None)).json()["triangles"], 4, "an upload from a tool (no Origin)")
    expect_ok(c.lb("DELETE", "/api/models/lent"))


@test
def test_bench_job_is_polled_and_cancelled_on_the_node_that_runs_it():
    c = cluster()
    # A job of each node's own first, so that every node has jobs: a poll
    # passed to the wrong node finds none of that id (ids start at random).
    auth = {"Authorization": "Bearer " + c.token}
    for i in range(3):
        expect_ok(c.node(i, "POST", "/api/bench", js={"model": "cornell", "accel": ["bvh"], "builder": ["median"],
                                                       "runs": 1}, headers=auth), 202)
    r = expect_ok(c.lb("POST", "/api/bench", js={"model": "sphere", "accel": ["bvh", "kd"], "builder": ["sah"],
                                                  "runs": 3}), 202)
    job = r.json()["id"]
    for _ in range(9):
        r = c.lb("GET", "/api/jobs/%s" % job)
        expect_ok(r)
        eq((r.json()["id"], r.json()["model"]), (job, "sphere"), "job %s polled through nginx" % job)
    r = expect_ok(c.lb("DELETE", "/api/jobs/%s" % job))
    eq(r.json()["model"], "sphere", "the job cancelled through nginx")
    end = time.time() + 30
    while c.lb("GET", "/api/jobs/%s" % job).json()["state"] not in ("cancelled", "done"):
        check(time.time() < end, "job %s never ended after its DELETE through nginx" % job)
        time.sleep(0.1)


@test
def test_errors_nginx_makes_are_the_apis_json():
    c = cluster()
    # A body over client_max_body_size (1 MB outside uploads).
    expect_error(c.lb("POST", "/api/render", body=b" " * (1100 * 1024),
                      headers={"Content-Type": "application/json"}), 413, "too_large")
    # More frames at once than the nodes' queues hold (3 x (1 + --queue 16)):
    # nodes that answer 503 are left out for fail_timeout, and then nginx
    # itself answers; each answer is a frame or the API's 503 busy.
    before = len(c.access_log())
    rs = harness.parallel(150, lambda i: c.lb("GET", "/api/render?model=menger&width=384&height=384&seed=%d" % i))
    busy = 0
    for r in rs:
        check(not isinstance(r, Exception), "a frame of the burst: %r" % r)
        if r.status != 200:
            expect_error(r, 503, "busy")
            check(r.header("Retry-After"), "%s: a 503 with no Retry-After" % r.req)
            busy += 1
    check(busy > 0, "150 frames at once all answered 200: the burst overflowed no queue, so it tested nothing")
    check(any(re.search(r"upstream=(\S+, )*arbord ", l) for l in c.access_log()[before:]),
          "no frame of the burst was answered by nginx itself (no live node): %d busy" % busy)
    time.sleep(4)  # fail_timeout (3 s): the nodes are back for the next test


def _listening(c, i):
    try:
        return c.node(i, "GET", "/healthz", timeout=2).status == 200
    except OSError:
        return False


@test
def test_everything_stops_with_no_process_left():
    c = cluster()
    nodes = c.nodes()
    rc = c.stop()
    eq(rc, 0, "deploy/cluster.sh exit status after SIGINT: %s" % c.output()[-1000:])
    check("stopped" in c.output(), "no 'stopped' line: %s" % c.output()[-500:])
    left = subprocess.run(["ps", "-eo", "pid,args"], capture_output=True, text=True).stdout
    stray = [l for l in left.splitlines() if c.state in l]
    check(not stray, "processes left behind: %s" % stray)
    netns = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
    for _, _, pid, ns in nodes:
        check(ns not in netns, "namespace %s left behind" % ns)
    links = subprocess.run(["ip", "-o", "link"], capture_output=True, text=True).stdout
    tag = nodes[0][3].rsplit("-", 1)[0]
    check(tag + "v" not in links, "veth links left behind: %s" % [l for l in links.splitlines() if tag in l])


# ---------------------------------------------------------------------------- running

def why_not():
    """Why this machine cannot run the cluster, or None."""
    if os.geteuid() != 0:
        return "needs root for network namespaces (ip netns add)"
    if not os.path.exists("/usr/sbin/nginx"):
        return "needs Debian's nginx (scripts/deps.sh, run by make, installs it)"
    if not os.access(harness.ARBORD, os.X_OK):
        return "no executable %s" % harness.ARBORD
    probe = "arbor-probe-%d" % os.getpid()
    if subprocess.run(["ip", "netns", "add", probe], capture_output=True).returncode != 0:
        return "network namespaces are not allowed here (ip netns add failed)"
    subprocess.run(["ip", "netns", "del", probe], capture_output=True)
    return None


def main():
    reason = why_not()
    failures = ignored = 0
    start = time.time()
    try:
        for name, func, line in TESTS:
            t0 = time.time()
            try:
                if reason:
                    raise Ignore(reason)
                func()
                print("tests/cluster/run.py:%d:%s:PASS (%.1fs)" % (line, name, time.time() - t0), flush=True)
            except Ignore as e:
                ignored += 1
                print("tests/cluster/run.py:%d:%s:IGNORE: %s" % (line, name, e), flush=True)
            except BaseException as e:
                if isinstance(e, KeyboardInterrupt):
                    raise
                failures += 1
                msg = str(e) if isinstance(e, Fail) else "%s: %s %s" % (type(e).__name__, e,
                                                                         traceback.format_exc().splitlines()[-3:])
                print("tests/cluster/run.py:%d:%s:FAIL: %s" % (line, name, " ".join(msg.split())), flush=True)
    finally:
        if CLUSTER is not None:
            CLUSTER.stop()
            if not failures:
                shutil.rmtree(CLUSTER.state, ignore_errors=True)
            else:
                print("(cluster state kept in %s)" % CLUSTER.state)
    print("(%.1f s)" % (time.time() - start))
    print("-----------------------")
    print("%d Tests %d Failures %d Ignored" % (len(TESTS), failures, ignored), flush=True)
    return 1 if failures else 0


if __name__ == "__main__":
    rc = main()
    sys.stdout.flush()
    os._exit(rc)
