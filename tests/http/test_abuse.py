"""Limits that hold under abuse: slow and never-finished requests, 1 MiB headers, 5,000 connections at
once (--max-connections, --max-per-ip), bodies that lie about their length, pipelined floods, uploads
cut off halfway, a disk that fills during an upload.

Each test checks, while the abuse goes on, that /healthz answers from another client address
(127.0.0.2: the per-IP limit is per address) within 100 ms -- the median of 11 probes, each on a
fresh connection, so that one scheduling hiccup on a loaded 2-core machine does not decide it --
and, after it, that nothing loaded was lost (GET /api/models: the same names and versions) and
that the daemon's open file descriptors come back to where they were (+2 at most: an epoll or
eventfd MHD may open lazily) and its RSS to within 10% + 8 MiB of where it was (allocator caches).
"""
import contextlib
import os
import resource
import select
import shutil
import socket
import statistics
import subprocess
import tempfile
import threading
import time

from harness import Daemon, check, eq, expect_error, expect_json, fail, ignore, multipart, our, test

PROBE_FROM = "127.0.0.2"
HEALTHZ_BUDGET_MS = 100.0
FD_SLACK = 2
RSS_SLACK = 0.10
RSS_SLACK_BYTES = 8 << 20


def sanitized(d):
    """Whether the daemon runs under a sanitizer runtime (ASan/TSan keep freed memory in a
    quarantine, so its RSS says nothing of leaks: LeakSanitizer does that job there)."""
    with open("/proc/%d/maps" % d.proc.pid) as f:
        return any("libasan" in line or "libtsan" in line for line in f)


def rss_slack_bytes(d):
    return RSS_SLACK_BYTES + (256 << 20 if sanitized(d) else 0)


def fds(d):
    return len(os.listdir("/proc/%d/fd" % d.proc.pid))


def rss(d):
    with open("/proc/%d/status" % d.proc.pid) as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    fail("no VmRSS for the daemon")


def listing(d):
    return [(m["name"], m["version"]) for m in expect_json(d.get("/api/models"))["models"]]


def healthz_ms(d):
    """One /healthz on a fresh connection from PROBE_FROM: ms from connect to the whole answer."""
    t0 = time.monotonic()
    s = socket.socket()
    s.settimeout(10)
    try:
        s.bind((PROBE_FROM, 0))
        s.connect(("127.0.0.1", d.port))
        s.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
        data = b""
        while True:
            c = s.recv(4096)
            if not c:
                break
            data += c
    finally:
        s.close()
    ms = (time.monotonic() - t0) * 1000.0
    check(data.startswith(b"HTTP/1.1 200"), "/healthz under abuse: %r" % data[:100])
    return ms


def expect_healthz_fast(d, what):
    ms = sorted(healthz_ms(d) for _ in range(11))
    med = statistics.median(ms)
    check(med < HEALTHZ_BUDGET_MS, "%s: /healthz median %.1f ms over 11 probes (budget %.0f ms): %s"
          % (what, med, HEALTHZ_BUDGET_MS, ["%.1f" % x for x in ms]))


class Baseline:
    """What the daemon holds before the abuse; back() waits (up to `wait` s) for it to return."""

    def __init__(self, d):
        self.d = d
        for _ in range(3):  # warm: the first answers allocate what later ones reuse
            expect_healthz_fast(d, "before")
        self.models = listing(d)
        self.fds = fds(d)
        self.rss = rss(d)

    def back(self, what, wait=15):
        end = time.time() + wait
        while True:
            f, r = fds(self.d), rss(self.d)
            ok = f <= self.fds + FD_SLACK and r <= self.rss * (1 + RSS_SLACK) + rss_slack_bytes(self.d)
            if ok or time.time() > end:
                break
            time.sleep(0.2)
        check(self.d.alive(), "%s: the daemon died: %s" % (what, self.d.stderr()[-1500:]))
        check(f <= self.fds + FD_SLACK, "%s: %d fds open, %d before" % (what, f, self.fds))
        check(r <= self.rss * (1 + RSS_SLACK) + rss_slack_bytes(self.d),
              "%s: RSS %.1f MiB, %.1f MiB before" % (what, r / 2**20, self.rss / 2**20))
        eq(listing(self.d), self.models, "%s: models listed" % what)
        expect_healthz_fast(self.d, "after " + what)


def raise_nofile(want):
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if hard != resource.RLIM_INFINITY and hard < want:
        ignore("needs %d file descriptors, the hard limit is %d" % (want, hard))
    if soft == resource.RLIM_INFINITY or soft < want:
        resource.setrlimit(resource.RLIMIT_NOFILE, (want, hard))


def open_many(port, n, src="127.0.0.1"):
    """n connected sockets (non-blocking connects, then waited for)."""
    socks = []
    for _ in range(n):
        s = socket.socket()
        s.setblocking(False)
        s.bind((src, 0))
        try:
            s.connect(("127.0.0.1", port))
        except BlockingIOError:
            pass
        socks.append(s)
    return socks


def closed_by_peer(socks, wait):
    """How many of socks the daemon closed (EOF or reset) within `wait` s."""
    p = select.poll()
    by_fd = {s.fileno(): s for s in socks}
    for s in socks:
        p.register(s, select.POLLIN | select.POLLHUP | select.POLLERR)
    closed = set()
    end = time.time() + wait
    while time.time() < end and len(closed) < len(socks):
        for fd, ev in p.poll(200):
            if fd in closed:
                continue
            s = by_fd[fd]
            try:
                data = s.recv(65536)
            except BlockingIOError:
                continue
            except OSError:
                data = b""
            if not data or ev & (select.POLLHUP | select.POLLERR):
                closed.add(fd)
                p.unregister(fd)
    return len(closed)


def close_all(socks):
    for s in socks:
        s.close()


def abuse_daemon(*args):
    return Daemon([our("cornell.obj"), our("sphere.obj")],
                  ["--threads", "2", "--connection-timeout", "2"] + list(args), name="abuse daemon")


@test
def test_abuse_slow_and_unfinished_requests_time_out():
    d = abuse_daemon()
    try:
        base = Baseline(d)
        # 200 requests that stop halfway through their headers, 50 bodies that stop after 10 of
        # 1000 bytes, and 20 that trickle a header byte every 100 ms.
        stalled = open_many(d.port, 200)
        time.sleep(0.2)
        for s in stalled:
            try:
                s.send(b"GET /api/models HTTP/1.1\r\nHost: x\r\nX-Half: ")
            except OSError:
                pass
        bodies = open_many(d.port, 50)
        time.sleep(0.2)
        for s in bodies:
            try:
                s.send(b"POST /api/render HTTP/1.1\r\nHost: x\r\nContent-Length: 1000\r\n\r\n{\"model\":")
            except OSError:
                pass
        stop = threading.Event()

        def trickle():
            ts = open_many(d.port, 20)
            time.sleep(0.2)
            req = b"GET /healthz HTTP/1.1\r\nHost: x\r\nX-Slow: " + b"a" * 1000
            i = 0
            while not stop.is_set() and i < len(req):
                for s in ts:
                    try:
                        s.send(req[i:i + 1])
                    except OSError:
                        pass
                i += 1
                time.sleep(0.1)
            close_all(ts)

        t = threading.Thread(target=trickle, daemon=True)
        t.start()
        expect_healthz_fast(d, "270 slow or stalled requests")
        # --connection-timeout 2: every stalled connection is closed by the daemon, none answered
        n = closed_by_peer(stalled + bodies, wait=10)
        eq(n, len(stalled) + len(bodies), "stalled connections closed by the daemon within 10 s")
        stop.set()
        t.join()
        close_all(stalled + bodies)
        base.back("slow and unfinished requests")
    finally:
        d.stop_clean()


@test
def test_abuse_one_mib_of_headers():
    d = abuse_daemon()
    try:
        base = Baseline(d)
        for header in (b"X-Big: " + b"a" * (1 << 20), b"\r\n".join(b"X-%d: %s" % (i, b"b" * 1000)
                                                                 for i in range(1024))):
            r = d.raw(b"GET /api/models HTTP/1.1\r\nHost: x\r\n" + header + b"\r\n\r\n", timeout=20)
            # libmicrohttpd answers 431 (headers past the per-connection memory, 64 KiB) and closes;
            # a close without an answer is as good, a 200 is not
            check(r.status in (0, 413, 431), "1 MiB of headers: %r" % r.short())
        base.back("1 MiB headers")
    finally:
        d.stop_clean()


@test
def test_abuse_5000_connections_per_ip_limit():
    raise_nofile(12000)
    d = abuse_daemon("--max-per-ip", "100", "--max-connections", "6000")
    try:
        base = Baseline(d)
        socks = open_many(d.port, 5000)
        try:
            time.sleep(1)
            expect_healthz_fast(d, "5,000 connections from 127.0.0.1")
            # all but 100 are closed at once by the per-IP limit, the rest by the connection timeout
            n = closed_by_peer(socks, wait=1.5)
            check(n >= 4900, "per-IP limit 100: only %d of 5000 connections closed within 1.5 s" % n)
        finally:
            close_all(socks)
        base.back("5,000 connections, per-IP limit")
    finally:
        d.stop_clean()


@test
def test_abuse_5000_connections_global_limit():
    raise_nofile(12000)
    d = abuse_daemon("--max-connections", "300", "--max-per-ip", "6000")
    try:
        base = Baseline(d)
        socks = open_many(d.port, 5000)
        try:
            time.sleep(1.5)
            # at the limit the daemon accepts no more: the rest wait in the kernel's listen backlog
            held = fds(d) - base.fds
            check(held <= 300 + FD_SLACK, "--max-connections 300: the daemon holds %d more fds" % held)
        finally:
            close_all(socks)
        # the held ones time out (2 s), the queued ones are accepted, find their peer gone, close
        base.back("5,000 connections, global limit", wait=60)
    finally:
        d.stop_clean()


@test
def test_abuse_bodies_that_lie_about_their_length():
    d = abuse_daemon()
    try:
        base = Baseline(d)
        body = b'{"model":"cornell","width":8,"height":8,"format":"json"}'
        # longer than sent, then closed: nothing to answer, nothing kept
        for _ in range(50):
            s = socket.create_connection(("127.0.0.1", d.port))
            s.sendall(b"POST /api/render HTTP/1.1\r\nHost: x\r\nContent-Length: 100000\r\n\r\n" + body)
            s.close()
        # shorter than sent: the body is the first 10 bytes (malformed JSON: 400), the rest is read as
        # the next request (not HTTP: 400 or closed)
        r = d.raw(b"POST /api/render HTTP/1.1\r\nHost: x\r\nContent-Length: 10\r\n\r\n" + body, timeout=10)
        expect_error(r, 400, "bad_request")
        # a length that is not a number, and one past 2^64
        for cl in (b"abc", b"99999999999999999999999"):
            r = d.raw(b"POST /api/render HTTP/1.1\r\nHost: x\r\nContent-Length: " + cl + b"\r\n\r\n" + body,
                      timeout=10)
            check(r.status in (0, 400, 413), "Content-Length %r: %s" % (cl, r.short()))
        expect_healthz_fast(d, "lying bodies")
        base.back("bodies that lie about their length")
    finally:
        d.stop_clean()


@test
def test_abuse_pipelined_flood():
    d = abuse_daemon()
    try:
        base = Baseline(d)
        n = 2000
        results = [None] * 4

        def flood(i):
            s = socket.create_connection(("127.0.0.1", d.port), timeout=30)
            s.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n" * (n - 1) +
                      b"GET /healthz HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
            data = b""
            while True:
                c = s.recv(1 << 16)
                if not c:
                    break
                data += c
            s.close()
            results[i] = data.count(b"HTTP/1.1 200 OK")

        ts = [threading.Thread(target=flood, args=(i,), daemon=True) for i in range(4)]
        for t in ts:
            t.start()
        expect_healthz_fast(d, "4 x 2000 pipelined requests")
        for t in ts:
            t.join(60)
        eq(results, [n] * 4, "answers to 4 connections of 2000 pipelined /healthz each")
        base.back("pipelined flood")
    finally:
        d.stop_clean()


def upload_dirs():
    return {e for e in os.listdir(tempfile.gettempdir()) if e.startswith("arbord-upload-")}


@test
def test_abuse_uploads_cut_off_halfway():
    d = abuse_daemon()
    try:
        base = Baseline(d)
        before = upload_dirs()
        with open(our("sphere.obj"), "rb") as f:
            obj = f.read()
        boundary = b"cutcutcut"
        multipart = (b"--" + boundary + b"\r\nContent-Disposition: form-data; name=\"f\"; filename=\"cut.obj\"\r\n"
                     b"Content-Type: text/plain\r\n\r\n" + obj + b"\r\n--" + boundary + b"--\r\n")
        for i in range(20):
            for head, body in ((b"PUT /api/models/cut HTTP/1.1\r\n", obj),
                               (b"POST /api/models/cut HTTP/1.1\r\nContent-Type: multipart/form-data; boundary="
                                + boundary + b"\r\n", multipart)):
                s = socket.create_connection(("127.0.0.1", d.port))
                s.sendall(head + b"Host: x\r\nContent-Length: %d\r\n\r\n" % len(body) + body[:len(body) // 2])
                s.close()
        expect_healthz_fast(d, "uploads cut off")
        base.back("uploads cut off halfway")
        left = upload_dirs() - before
        eq(sorted(left), [], "temporary upload folders left behind")
        eq([f for f in os.listdir(d.models_dir) if f.startswith("cut") or f.startswith(".cut")], [],
           "files of the cut uploads in the models folder")
    finally:
        d.stop_clean()


@contextlib.contextmanager
def tmpfs(size, prefix):
    """A tmpfs of `size` mounted on a fresh folder for the block (the test is ignored without root)."""
    if os.geteuid() != 0:
        ignore("needs root to mount a tmpfs")
    mnt = tempfile.mkdtemp(prefix=prefix)
    p = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=" + size, "tmpfs", mnt], capture_output=True)
    if p.returncode != 0:
        os.rmdir(mnt)
        ignore("cannot mount a tmpfs: %s" % p.stderr.decode().strip())
    try:
        yield mnt
    finally:
        subprocess.run(["umount", mnt])
        os.rmdir(mnt)


@test
def test_abuse_disk_full_on_upload():
    """--models on a 256 KiB tmpfs: an upload that does not fit is 507 insufficient_storage, leaves no
    partial file, and the daemon goes on."""
    with tmpfs("256k", "arbor-full-") as mnt:
        with open(our("cornell.obj"), "rb") as f:
            small = f.read()
        with open(our("sphere.obj"), "rb") as f:
            big = f.read()  # 160 KiB: fits once, not twice
        with open(os.path.join(mnt, "cornell.obj"), "wb") as f:
            f.write(small)
        d = Daemon(models_dir=mnt, args=["--threads", "2"], name="disk-full daemon")
        try:
            base = Baseline(d)
            expect_json(d.req("PUT", "/api/models/first", body=big), 201)
            base.models = listing(d)
            r = d.req("PUT", "/api/models/second", body=big)
            expect_error(r, 507, "insufficient_storage")
            # the refused upload left nothing, its record included; the first keeps its record
            eq(sorted(os.listdir(mnt)), [".arbord.lock", ".first.upload", "cornell.obj", "first.obj"],
               "files in the full models folder")
            base.back("disk full on upload")
        finally:
            d.stop_clean()


@test
def test_abuse_temporary_folder_full_on_upload():
    """TMPDIR with 256 KiB free: the upload is received there, and one that does not fit is 507
    insufficient_storage (not a 400: the client's body was fine), leaving nothing behind; a small one
    still goes through."""
    with tmpfs("64m", "arbor-tmp-") as tmp:
        d = Daemon([our("cornell.obj")], ["--threads", "2"], copy=True, env={"TMPDIR": tmp},
                   name="small-TMPDIR daemon")
        try:
            # TSan's runtime keeps a file of its own there (unlinked): the free space is what is left
            # after the daemon started, less a ballast
            st = os.statvfs(tmp)
            with open(os.path.join(tmp, ".ballast"), "wb") as f:
                f.write(b"\0" * (st.f_bavail * st.f_frsize - 256 * 1024))
            with open(our("menger.obj"), "rb") as f:
                big = f.read()
            for method, kind in (("PUT", "application/octet-stream"), ("POST", None)):
                if kind is None:
                    body, kind = multipart([("model", "big.obj", "model/obj", big)])
                else:
                    body = big
                r = d.req(method, "/api/models/big", body=body, headers={"Content-Type": kind})
                e = expect_error(r, 507, "insufficient_storage")
                check("big.obj" in e["message"] or "upload.bin" in e["message"], "507 names no part: %r" % e)
                eq(os.listdir(tmp), [".ballast"], "the temporary folder after the refused %s" % method)
            expect_json(d.req("PUT", "/api/models/small", body=b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"), 201)
            eq(os.listdir(tmp), [".ballast"], "the temporary folder after an upload")
        finally:
            d.stop_clean()


@test
def test_abuse_folder_mounted_again_under_another_device():
    """The models folder's filesystem mounted again through another loop device (as another host, or a
    remount, sees an NFS folder: the device number differs, the files do not): DELETE still knows the
    files its upload wrote and removes them."""
    if os.geteuid() != 0:
        ignore("needs root to mount a loop device")
    work = tempfile.mkdtemp(prefix="arbor-dev-")
    img, mnt = os.path.join(work, "fs.img"), os.path.join(work, "mnt")
    os.mkdir(mnt)
    loops = []

    def attach():
        p = subprocess.run(["losetup", "--find", "--show", img], capture_output=True, text=True)
        if p.returncode != 0:
            ignore("no loop device: %s" % p.stderr.strip())
        loops.append(p.stdout.strip())
        subprocess.run(["mount", loops[-1], mnt], check=True)

    try:
        with open(img, "wb") as f:
            f.truncate(8 << 20)
        if subprocess.run(["mkfs.ext4", "-q", img], capture_output=True).returncode != 0:
            ignore("mkfs.ext4 failed")
        attach()
        models = os.path.join(mnt, "models")
        os.mkdir(models)
        d = Daemon(models_dir=models, args=["--threads", "1", "--prebuild", "none"], name="first-mount daemon")
        body, ctype = multipart([("model", "moved.obj", "model/obj", b"mtllib moved.mtl\nusemtl m\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"),
                                 ("mtl", "moved.mtl", "text/plain", b"newmtl m\nKd 1 0 0\n")])
        try:
            expect_json(d.req("POST", "/api/models/moved", body=body, headers={"Content-Type": ctype}), 201)
        finally:
            d.stop_clean()
        dev = os.stat(models).st_dev
        subprocess.run(["umount", mnt], check=True)
        attach()  # the first loop device is still attached: this is another one
        check(os.stat(models).st_dev != dev, "the second mount has the first one's device number")
        d = Daemon(models_dir=models, args=["--threads", "1", "--prebuild", "none"], name="second-mount daemon")
        try:
            eq(expect_json(d.req("DELETE", "/api/models/moved")), {"deleted": "moved"}, "DELETE after the remount")
            eq(sorted(os.listdir(models)), [".arbord.lock"], "files after the DELETE")
        finally:
            d.stop_clean()
    finally:
        subprocess.run(["umount", mnt], capture_output=True)
        for loop in loops:
            subprocess.run(["losetup", "-d", loop], capture_output=True)
        shutil.rmtree(work, ignore_errors=True)


@test
def test_abuse_folder_lock_held_by_another():
    """Another process holds the models folder's lock and does not let go (a stuck daemon, an operator's
    flock): uploads and DELETEs wait a bounded time and answer 503 busy with Retry-After, the folder
    and the store as they were. They wait in one line, so at most one worker waits on the lock: a frame
    asked for meanwhile is answered before any of them; once the lock is free, the DELETE goes through."""
    import fcntl
    mnt = tempfile.mkdtemp(prefix="arbor-lock-")
    d = Daemon(models_dir=mnt, args=["--threads", "2"], name="held-lock daemon")
    try:
        expect_json(d.req("PUT", "/api/models/first", body=b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"), 201)
        before = sorted(os.listdir(mnt))
        with open(os.path.join(mnt, ".arbord.lock"), "r+") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            answers, order = {}, []

            def ask(key, method, path, **kw):
                answers[key] = d.req(method, path, timeout=60, **kw)
                order.append(key)

            # two DELETEs and an upload, more than the workers of --threads 2
            asks = [threading.Thread(target=ask, args=("delete%d" % i, "DELETE", "/api/models/first")) for i in range(2)]
            asks.append(threading.Thread(target=ask, args=("upload", "PUT", "/api/models/second"),
                                         kwargs={"body": b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"}))
            for t in asks:
                t.start()
            time.sleep(0.5)  # let them reach the daemon first (the order below holds whatever the delay)
            ask("frame", "POST", "/api/render", js={"model": "first", "width": 8, "height": 8})
            eq(answers["frame"].status, 200, "a frame while the folder's lock is held: %s" % answers["frame"].body[:200])
            for t in asks:
                t.join()
            eq(order[0], "frame", "answered first (each change waits 5 s on the lock, in one line)")
            for key in sorted(k for k in answers if k != "frame"):
                expect_error(answers[key], 503, "busy")
                eq(answers[key].header("Retry-After"), "1", "Retry-After of the refused %s" % key)
            eq(sorted(os.listdir(mnt)), before, "files after the refused changes")
            eq(d.model("first")["triangles"], 1, "first still loaded")
            expect_error(d.req("GET", "/api/models/second"), 404, "not_found")
        eq(expect_json(d.req("DELETE", "/api/models/first")), {"deleted": "first"}, "DELETE once the lock is free")
        eq(sorted(os.listdir(mnt)), [".arbord.lock"], "files after the DELETE")
    finally:
        d.stop_clean()
        shutil.rmtree(mnt)


@test
def test_abuse_folder_lock_unusable():
    """A writable models folder whose lock cannot be opened (.arbord.lock made a folder): DELETE of an
    uploaded model is 507 and the model stays loaded with its files, since they would load it again;
    once the lock works, the DELETE goes through and removes them."""
    mnt = tempfile.mkdtemp(prefix="arbor-lock-")
    d = Daemon(models_dir=mnt, args=["--threads", "2"], name="unusable-lock daemon")
    try:
        expect_json(d.req("PUT", "/api/models/first", body=b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"), 201)
        lock = os.path.join(mnt, ".arbord.lock")
        os.unlink(lock)
        os.mkdir(lock)
        expect_error(d.req("DELETE", "/api/models/first"), 507, "insufficient_storage")
        eq(d.model("first")["triangles"], 1, "first still loaded")
        eq(sorted(os.listdir(mnt)), [".arbord.lock", ".first.upload", "first.obj"], "files after the refused DELETE")
        os.rmdir(lock)
        eq(expect_json(d.req("DELETE", "/api/models/first")), {"deleted": "first"}, "DELETE with the lock back")
        eq(sorted(os.listdir(mnt)), [".arbord.lock"], "files after the DELETE")
    finally:
        d.stop_clean()
        shutil.rmtree(mnt)


@test
def test_abuse_read_only_models_folder():
    """--models on a read-only mount: DELETE unloads a model (its file stays, and the next request loads it
    again), and an upload is a clear 507, not a hang or a crash."""
    with tmpfs("1m", "arbor-ro-") as mnt:
        with open(our("cornell.obj"), "rb") as f, open(os.path.join(mnt, "cornell.obj"), "wb") as out:
            out.write(f.read())
        subprocess.run(["mount", "-o", "remount,ro", mnt], check=True)
        d = Daemon(models_dir=mnt, args=["--threads", "2"], name="read-only folder daemon")
        try:
            eq(expect_json(d.req("DELETE", "/api/models/cornell")), {"deleted": "cornell"}, "DELETE on a read-only folder")
            eq(sorted(os.listdir(mnt)), ["cornell.obj"], "files in the read-only folder")
            eq(d.model("cornell")["triangles"], 36, "cornell loaded again")
            expect_error(d.req("PUT", "/api/models/new", body=b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"), 507,
                         "insufficient_storage")
        finally:
            d.stop_clean()
