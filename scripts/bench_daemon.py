#!/usr/bin/python3
"""The daemon's figures for docs/BENCH.md (issue: the daemon), medians of repeated runs:

1. a 512x512 shaded frame over HTTP (request sent to PNG received, one keep-alive
   connection) against the same frame rendered and encoded in-process by `arbord render`;
2. the in-process frame rate of 256x256 frames on the pool (what `make loadtest` is
   compared with);
3. RSS with every shared model loaded and bvh:sah prebuilt, against the bytes the store
   counts for meshes and trees.

usage: scripts/bench_daemon.py [--arbord build/arbord] [--shared ../shared/models] [--runs 15]
"""
import argparse
import http.client
import json
import os
import re
import socket
import statistics
import subprocess
import sys
import tempfile
import time


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Daemon:
    def __init__(self, arbord, args):
        self.port = free_port()
        self.log = tempfile.TemporaryFile()
        self.proc = subprocess.Popen([arbord, "serve", "--port", str(self.port)] + args,
                                     stdout=self.log, stderr=self.log)
        self.conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=600)
        deadline = time.time() + 600
        while time.time() < deadline:
            try:
                if self.get("/readyz")[0] == 200:
                    return
            except OSError:
                self.conn.close()
            time.sleep(0.1)
        raise RuntimeError("daemon never became ready")

    def get(self, path):
        self.conn.request("GET", path)
        r = self.conn.getresponse()
        return r.status, r.read()

    def post(self, path, body):
        self.conn.request("POST", path, body=json.dumps(body), headers={"Content-Type": "application/json"})
        r = self.conn.getresponse()
        return r.status, r.read()

    def stop(self):
        self.conn.close()
        self.proc.terminate()
        self.proc.wait(60)


def rss_kb(pid):
    with open("/proc/%d/status" % pid) as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    return 0


def in_process_ms(arbord, model, width, height, runs, extra):
    """Median render + PNG encode ms of `arbord render` (load and build excluded)."""
    times = []
    out = os.path.join(tempfile.gettempdir(), "arbor-bench-frame.png")
    for _ in range(runs):
        text = subprocess.run([arbord, "render", "--model", model, "--width", str(width), "--height",
                               str(height), "-o", out] + extra, check=True, capture_output=True,
                              text=True).stdout
        render = float(re.search(r"render \S+ .*?: ([0-9.]+) ms", text).group(1))
        encode = float(re.search(r"png encode ([0-9.]+) ms", text).group(1))
        times.append(render + encode)
    os.unlink(out)
    return statistics.median(times)


def http_frame(arbord, model, runs):
    d = Daemon(arbord, ["--models", os.path.dirname(model), "--prebuild", "bvh:sah"])
    name = os.path.basename(model).split(".")[0]
    body = {"model": name, "width": 512, "height": 512, "mode": "shaded"}
    try:
        d.post("/api/render", body)  # warm: the connection, the caches
        times = []
        for _ in range(runs):
            t0 = time.perf_counter()
            status, png = d.post("/api/render", body)
            times.append((time.perf_counter() - t0) * 1e3)
            assert status == 200 and png[:4] == b"\x89PNG", status
        return statistics.median(times)
    finally:
        d.stop()


def memory(arbord, shared):
    d = Daemon(arbord, ["--models", shared, "--prebuild", "bvh:sah"])
    try:
        stats = json.loads(d.get("/api/stats")[1])
        mem = stats["daemon"]["memory"]
        return rss_kb(d.proc.pid) * 1024, mem["models"], mem["trees"], len(stats["trees"])
    finally:
        d.stop()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--arbord", default="build/arbord")
    ap.add_argument("--shared", default="../shared/models")
    ap.add_argument("--runs", type=int, default=15)
    a = ap.parse_args()
    cpu = next((l.split(":", 1)[1].strip() for l in open("/proc/cpuinfo") if l.startswith("model name")), "?")
    print("machine: %s, %d cores; runs %d (medians)\n" % (cpu, os.cpu_count(), a.runs))

    print("| model | 512x512 over HTTP ms | in-process render+encode ms | ratio |")
    print("| --- | ---: | ---: | ---: |")
    for m in ("castle.obj", "bunny.obj", "dragon.obj.gz"):
        path = os.path.join(a.shared, m)
        if not os.path.exists(path):
            continue
        local = in_process_ms(a.arbord, path, 512, 512, a.runs, ["--threads", "0"])
        remote = http_frame(a.arbord, path, a.runs)
        print("| %s | %.1f | %.1f | %.3f |" % (m, remote, local, remote / local))

    print("\n| model | 256x256 frames/s in-process (2 threads) |")
    print("| --- | ---: |")
    for m in ("cornell", "heightfield", "menger", "sphere", "sphereflake"):
        ms = in_process_ms(a.arbord, "models/%s.obj" % m, 256, 256, a.runs,
                           ["--yaw", "30", "--pitch", "10", "--distance", "1.6"])
        print("| %s | %.1f |" % (m, 1000.0 / ms))

    rss, models, trees, ntrees = memory(a.arbord, a.shared)
    print("\nall shared models, bvh:sah prebuilt (%d trees): RSS %.1f MiB, meshes %.1f MiB, trees %.1f MiB, "
          "overhead %.1f%%" % (ntrees, rss / 2**20, models / 2**20, trees / 2**20,
                               100.0 * (rss - models - trees) / (models + trees)))


if __name__ == "__main__":
    sys.exit(main())
