#!/usr/bin/python3
"""make soak: one arbord serve under mixed load for SOAK_SECONDS (600 by default).

Eight client threads keep asking, at random: frames of every mode over every tree (GET and POST),
/api/stats, /api/models, uploads (PUT of a model under one of four names), replaces, deletes,
bench jobs (started, polled, some cancelled), and pairs of frames on one stream key (the older
answers 409 superseded) or frames whose client hangs up before the answer.

Every minute it prints the requests answered by status, their p50 and p99 latency, and the
daemon's RSS and open file descriptors. It fails on any 5xx but 503 and 507, on the daemon dying
or exiting unclean after SIGTERM, or on growth: the highest RSS (or fd count) of the last two
minutes more than 10% above the highest of the first minute (fds: and more than 16 above, since a
few connections come and go). Before the first minute every tree of every model is built
(--prebuild all), so that the first minute is the steady state, not the warm-up.

Env: ARBORD (build/arbord), SOAK_SECONDS (600), SOAK_CLIENTS (8).
"""
import http.client
import json
import os
import random
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
ARBORD = os.path.abspath(os.environ.get("ARBORD", os.path.join(REPO, "build", "arbord")))
SECONDS = int(os.environ.get("SOAK_SECONDS", "600"))
CLIENTS = int(os.environ.get("SOAK_CLIENTS", "8"))
MODES = ["shaded", "normals", "depth", "ao", "heat"]
ACCELS = ["bvh", "kd"]
BUILDERS = ["spatial", "median", "mean", "sah"]
MODELS = ["cornell", "sphere", "menger"]
UPLOADS = ["soak-0", "soak-1", "soak-2", "soak-3"]


def free_port():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    p = s.getsockname()[1]
    s.close()
    return p


class Stats:
    def __init__(self):
        self.lock = threading.Lock()
        self.status = {}
        self.ms = []
        self.bad = []

    def add(self, what, status, ms):
        with self.lock:
            self.status[status] = self.status.get(status, 0) + 1
            self.ms.append(ms)
            if status >= 500 and status not in (503, 507):
                self.bad.append("%s -> %d" % (what, status))

    def take(self):
        with self.lock:
            s, m = self.status, self.ms
            self.status, self.ms = {}, []
            return s, m


def pct(sorted_ms, p):
    if not sorted_ms:
        return 0.0
    return sorted_ms[min(len(sorted_ms) - 1, int(p / 100.0 * len(sorted_ms)))]


class Client:
    def __init__(self, port, stats, sphere):
        self.port = port
        self.stats = stats
        self.sphere = sphere
        self.rng = random.Random()

    def req(self, method, path, body=None, headers=None, what=None, timeout=120):
        t0 = time.monotonic()
        conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=timeout)
        try:
            conn.request(method, path, body=body, headers=headers or {})
            r = conn.getresponse()
            data = r.read()
            status = r.status
        except (OSError, http.client.HTTPException) as e:
            data, status = str(e).encode(), 0
        finally:
            conn.close()
        self.stats.add(what or path, status, (time.monotonic() - t0) * 1000.0)
        return status, data

    def frame(self, stream=None):
        q = {"model": self.rng.choice(MODELS), "accel": self.rng.choice(ACCELS),
             "builder": self.rng.choice(BUILDERS), "mode": self.rng.choice(MODES),
             "width": 96, "height": 72, "yaw": self.rng.randint(0, 359)}
        if stream:
            q["stream"] = stream
        if self.rng.random() < 0.5 and not stream:
            return self.req("GET", "/api/render?" + "&".join("%s=%s" % kv for kv in q.items()), what="render get")
        q["camera"] = {"yaw": q.pop("yaw")}  # flat in a query, an object in JSON
        return self.req("POST", "/api/render", json.dumps(q), {"Content-Type": "application/json"},
                        what="render post")

    def superseded_pair(self):
        key = "soak-%d" % self.rng.randint(0, 1 << 30)
        t = threading.Thread(target=self.frame, args=(key,), daemon=True)
        t.start()
        time.sleep(0.005)
        self.frame(key)
        t.join()

    def hang_up(self):
        s = socket.create_connection(("127.0.0.1", self.port))
        s.sendall(b"GET /api/render?model=menger&mode=ao&width=256&height=192 HTTP/1.1\r\nHost: x\r\n\r\n")
        time.sleep(self.rng.random() * 0.05)
        s.close()

    def upload(self):
        name = self.rng.choice(UPLOADS)
        self.req("PUT", "/api/models/%s?replace=1" % name, self.sphere, what="upload/replace")

    def delete(self):
        self.req("DELETE", "/api/models/%s" % self.rng.choice(UPLOADS), what="delete")

    def bench(self):
        st, data = self.req("POST", "/api/bench", json.dumps({"model": "cornell", "accel": ["bvh"],
                                                              "builder": ["sah"], "runs": 1}),
                            {"Content-Type": "application/json"}, what="bench")
        if st != 202:
            return
        job = json.loads(data)["id"]
        if self.rng.random() < 0.3:
            self.req("DELETE", "/api/jobs/%s" % job, what="bench cancel")
            return
        for _ in range(100):
            st, data = self.req("GET", "/api/jobs/%s" % job, what="bench poll")
            if st != 200 or json.loads(data)["state"] in ("done", "failed", "cancelled"):
                return
            time.sleep(0.1)

    def run(self, until):
        actions = [(30, self.frame), (8, lambda: self.req("GET", "/api/stats")),
                   (5, lambda: self.req("GET", "/api/models")), (4, self.upload), (2, self.delete),
                   (1, self.bench), (4, self.superseded_pair), (3, self.hang_up)]
        weights = [w for w, _ in actions]
        while time.time() < until:
            self.rng.choices(actions, weights)[0][1]()


def proc_figures(pid):
    with open("/proc/%d/status" % pid) as f:
        rss = next(int(l.split()[1]) for l in f if l.startswith("VmRSS:")) * 1024
    return rss, len(os.listdir("/proc/%d/fd" % pid))


def main():
    tmp = tempfile.mkdtemp(prefix="arbor-soak-")
    models = os.path.join(tmp, "models")
    os.makedirs(models)
    for m in MODELS:
        for ext in (".obj", ".mtl"):
            src = os.path.join(REPO, "models", m + ext)
            if os.path.exists(src):
                shutil.copy(src, models)
    with open(os.path.join(REPO, "models", "sphere.obj"), "rb") as f:
        sphere = f.read()
    port = free_port()
    err = open(os.path.join(tmp, "stderr.log"), "wb")
    cmd = [ARBORD, "serve", "--port", str(port), "--models", models, "--threads", "2", "--queue", "8",
           "--prebuild", "all", "--connection-timeout", "5"]
    d = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err)
    failures = []
    try:
        probe = Client(port, Stats(), sphere)
        end = time.time() + 300
        while time.time() < end:
            try:
                if probe.req("GET", "/readyz", timeout=5)[0] == 200:
                    break
            except OSError:
                pass
            if d.poll() is not None:
                sys.exit("soak: the daemon exited at start")
            time.sleep(0.2)
        print("soak: %s for %d s, %d clients" % (" ".join(cmd), SECONDS, CLIENTS), flush=True)
        stats = Stats()
        until = time.time() + SECONDS
        threads = [threading.Thread(target=Client(port, stats, sphere).run, args=(until,), daemon=True)
                   for _ in range(CLIENTS)]
        for t in threads:
            t.start()
        minutes = []
        start = time.time()
        print("%6s %8s %9s %9s %9s %5s  %s" % ("minute", "requests", "p50 ms", "p99 ms", "RSS MiB", "fds",
                                                "by status"), flush=True)
        while time.time() < until:
            time.sleep(min(60, max(0.1, until - time.time())))
            if d.poll() is not None:
                failures.append("the daemon died (exit %s)" % d.returncode)
                break
            rss, fds = proc_figures(d.pid)
            status, ms = stats.take()
            ms.sort()
            minutes.append((rss, fds))
            print("%6d %8d %9.1f %9.1f %9.1f %5d  %s" % (len(minutes), len(ms), pct(ms, 50), pct(ms, 99),
                                                       rss / 2**20, fds,
                                                       " ".join("%d:%d" % kv for kv in sorted(status.items()))),
                  flush=True)
        for t in threads:
            t.join(180)
        print("soak: %.0f s" % (time.time() - start))
        if stats.bad:
            failures.append("%d answers 5xx other than 503/507, e.g. %s" % (len(stats.bad), stats.bad[:5]))
        if len(minutes) >= 3:
            first_rss, first_fds = minutes[0]
            last_rss = max(r for r, _ in minutes[-2:])
            last_fds = max(f for _, f in minutes[-2:])
            print("soak: RSS first minute %.1f MiB, last two minutes at most %.1f MiB; fds %d, %d"
                  % (first_rss / 2**20, last_rss / 2**20, first_fds, last_fds))
            if last_rss > first_rss * 1.10:
                failures.append("RSS grew more than 10%%: %.1f -> %.1f MiB" % (first_rss / 2**20, last_rss / 2**20))
            if last_fds > first_fds * 1.10 and last_fds > first_fds + 16:
                failures.append("open fds grew: %d -> %d" % (first_fds, last_fds))
    finally:
        if d.poll() is None:
            d.send_signal(signal.SIGTERM)
            try:
                rc = d.wait(60)
            except subprocess.TimeoutExpired:
                d.kill()
                rc = "killed after 60 s"
            if rc != 0:
                failures.append("exit after SIGTERM: %s" % rc)
        err.close()
        with open(os.path.join(tmp, "stderr.log"), "rb") as f:
            log = f.read().decode("utf-8", "replace")
        if "Sanitizer" in log or "runtime error" in log:
            failures.append("sanitizer report in the daemon's stderr")
        shutil.rmtree(tmp, ignore_errors=True)
    for f in failures:
        print("FAIL: " + f)
    print("soak: " + ("FAILED" if failures else "OK"), flush=True)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
