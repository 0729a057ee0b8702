"""Test harness for arbord's HTTP tests (standard library only).

- a tiny registry of test functions (@test), with Unity-style reporting in run.py
- Daemon: starts `arbord serve` on a free port with a temp --models dir of symlinks
- http helpers (http.client; raw sockets for paths nothing should normalise)
- a PNG decoder (zlib + struct; 8-bit gray/RGB/RGBA, filter types 0-4)
- the truth tables of ../shared/models/README.md and models/README.md
"""
import http.client
import json
import os
import re
import shutil
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
import zlib

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(os.path.dirname(HERE))
# ARBORD and ARBOR_SHARED_MODELS: relative paths are taken from the current directory.
ARBORD = os.path.abspath(os.environ["ARBORD"]) if os.environ.get("ARBORD") else os.path.join(REPO, "build", "arbord")
SHARED = os.path.abspath(os.environ["ARBOR_SHARED_MODELS"]) if os.environ.get("ARBOR_SHARED_MODELS") \
    else os.path.abspath(os.path.join(REPO, "..", "shared", "models"))
OUR_MODELS = os.path.join(REPO, "models")
VERBOSE = bool(os.environ.get("HTTP_TESTS_VERBOSE"))


# --------------------------------------------------------------------------- registry

class Fail(Exception):
    pass


class Ignore(Exception):
    pass


TESTS = []  # (name, func, module file, line)


def test(func):
    code = func.__code__
    TESTS.append((func.__name__, func, code.co_filename, code.co_firstlineno))
    return func


def add_test(name, func, filename, line):
    """A generated test (one case of a table): its failures are reported at the case's line."""
    func.case_line = line
    TESTS.append((name, func, filename, line))


def fail(msg):
    raise Fail(msg)


def ignore(msg):
    raise Ignore(msg)


def check(cond, msg):
    if not cond:
        raise Fail(msg)


def eq(got, want, what):
    if got != want:
        raise Fail("%s: expected %r, got %r" % (what, want, got))


def log(*a):
    if VERBOSE:
        print("  ..", *a, file=sys.stderr, flush=True)


def need_shared(*names):
    """Paths of shared models, or Ignore naming what is missing (never a silent pass)."""
    if not os.path.isdir(SHARED):
        ignore("needs ../shared/models (ARBOR_SHARED_MODELS=%s not found)" % SHARED)
    out = []
    for n in names:
        p = os.path.join(SHARED, n)
        if not os.path.exists(p):
            ignore("needs %s (not in %s)" % (n, SHARED))
        out.append(p)
    return out


def our(name):
    return os.path.join(OUR_MODELS, name)


# --------------------------------------------------------------------------- http

class Resp:
    def __init__(self, status, reason, headers, body, req):
        self.status = status
        self.reason = reason
        self.headers = headers  # list of (name, value)
        self.body = body
        self.req = req
        self._json = None

    def header(self, name, default=None):
        name = name.lower()
        for k, v in self.headers:
            if k.lower() == name:
                return v
        return default

    def json(self):
        if self._json is None:
            try:
                self._json = json.loads(self.body.decode("utf-8"))
            except Exception as e:
                raise Fail("%s: answer %d is not JSON (%s): %r" % (self.req, self.status, e, self.body[:300]))
        return self._json

    def short(self):
        b = self.body[:400]
        try:
            b = b.decode("utf-8")
        except UnicodeDecodeError:
            b = repr(b[:80]) + "..."
        return "%d %s" % (self.status, b)


def request(port, method, path, body=None, headers=None, js=None, host="127.0.0.1", timeout=120):
    hdrs = dict(headers or {})
    if js is not None:
        body = json.dumps(js).encode()
        hdrs.setdefault("Content-Type", "application/json")
    if isinstance(body, str):
        body = body.encode()
    conn = http.client.HTTPConnection(host, port, timeout=timeout)
    try:
        conn.request(method, path, body=body, headers=hdrs)
        r = conn.getresponse()
        data = r.read()
        desc = "%s %s" % (method, path)
        if body is not None and len(body) < 300:
            try:
                desc += " " + body.decode()
            except UnicodeDecodeError:
                pass
        return Resp(r.status, r.reason, r.getheaders(), data, desc)
    finally:
        conn.close()


def raw_request(port, raw, host="127.0.0.1", timeout=30):
    """Send raw bytes (or a list of them, each its own write 50 ms after the last, as TCP may deliver
    them), read until close; returns Resp (status 0 when no HTTP answer)."""
    s = socket.create_connection((host, port), timeout=timeout)
    try:
        s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        for i, piece in enumerate(raw if isinstance(raw, list) else [raw]):
            if i > 0:
                time.sleep(0.05)
            s.sendall(piece)
        chunks = []
        while True:
            try:
                c = s.recv(65536)
            except socket.timeout:
                break
            if not c:
                break
            chunks.append(c)
            data = b"".join(chunks)
            # stop when a full response with Content-Length has arrived
            if b"\r\n\r\n" in data:
                head, rest = data.split(b"\r\n\r\n", 1)
                m = re.search(rb"(?im)^content-length:\s*(\d+)", head)
                if m and len(rest) >= int(m.group(1)):
                    break
    finally:
        s.close()
    data = b"".join(chunks)
    what = repr(raw[0][:100] if isinstance(raw, list) else raw[:100])
    if b"\r\n\r\n" not in data:
        return Resp(0, "", [], data, what)
    head, rest = data.split(b"\r\n\r\n", 1)
    lines = head.decode("latin-1").split("\r\n")
    parts = lines[0].split(" ", 2)
    status = int(parts[1]) if len(parts) > 1 and parts[1].isdigit() else 0
    hdrs = []
    for ln in lines[1:]:
        if ":" in ln:
            k, v = ln.split(":", 1)
            hdrs.append((k.strip(), v.strip()))
    return Resp(status, parts[2] if len(parts) > 2 else "", hdrs, rest, what)


def expect_error(r, status, code, contains=None):
    """The API's error shape: status, application/json, {"error":{"code","message"}}."""
    if r.status != status:
        fail("%s: expected %d %s, got %s" % (r.req, status, code, r.short()))
    ct = r.header("Content-Type", "")
    check(ct.startswith("application/json"), "%s: error Content-Type %r, expected application/json" % (r.req, ct))
    j = r.json()
    check(isinstance(j, dict) and isinstance(j.get("error"), dict),
          "%s: body is not {\"error\":{...}}: %r" % (r.req, r.body[:300]))
    e = j["error"]
    eq(e.get("code"), code, "%s: error.code" % r.req)
    check(isinstance(e.get("message"), str) and e["message"],
          "%s: error.message missing or empty: %r" % (r.req, j))
    if contains is not None:
        pats = contains if isinstance(contains, (list, tuple)) else [contains]
        for p in pats:
            if isinstance(p, re.Pattern):
                check(p.search(e["message"]), "%s: message %r does not match /%s/" % (r.req, e["message"], p.pattern))
            else:
                check(p.lower() in e["message"].lower(), "%s: message %r does not name %r" % (r.req, e["message"], p))
    check(r.header("X-Request-Id"), "%s: no X-Request-Id" % r.req)
    return e


def expect_ok(r, status=200):
    if r.status != status:
        fail("%s: expected %d, got %s" % (r.req, status, r.short()))
    return r


def expect_json(r, status=200):
    expect_ok(r, status)
    ct = r.header("Content-Type", "")
    check(ct.startswith("application/json"), "%s: Content-Type %r, expected application/json" % (r.req, ct))
    return r.json()


# --------------------------------------------------------------------------- daemon

def free_port(host="127.0.0.1"):
    s = socket.socket()
    s.bind((host, 0))
    p = s.getsockname()[1]
    s.close()
    return p


ALL_DAEMONS = []

# What ASan, LSan, UBSan and TSan print at a report (make test SAN=...), and
# the reports found in stopped daemons' stderr, for run.py to fail the test.
SANITIZER_REPORT = re.compile(r"(ERROR|WARNING): \w+Sanitizer|runtime error:")
SANITIZER_REPORTS = []


class Daemon:
    """arbord serve on a free port over a temp --models dir of symlinks.

    models: list of paths (symlinked; a .mtl beside an .obj is linked too) or
    (name, path) pairs; copy=True copies instead (for models that get deleted).
    """

    def __init__(self, models=(), args=(), bind="127.0.0.1", copy=False, wait_ready=True,
                 models_dir=None, name="daemon", ready_timeout=120, default_web=False, env=None):
        self.tmp = tempfile.mkdtemp(prefix="arbor-http-")
        self.models_dir = models_dir or os.path.join(self.tmp, "models")
        os.makedirs(self.models_dir, exist_ok=True)
        for m in models:
            if isinstance(m, tuple):
                dst_name, src = m
            else:
                src, dst_name = m, os.path.basename(m)
            self._place(src, dst_name, copy)
            if src.endswith(".obj"):
                mtl = src[:-4] + ".mtl"
                if os.path.exists(mtl):
                    self._place(mtl, dst_name[:-4] + ".mtl", copy)
        self.bind = bind
        self.host = bind if bind not in ("0.0.0.0",) else "127.0.0.1"
        self.args = list(args)
        # the repository's web/ explicitly, so that only the test of the default depends on how
        # the binary finds it (a build folder other than build/ may not find it)
        if not default_web and "--web" not in self.args:
            self.args += ["--web", os.path.join(REPO, "web")]
        self.name = name
        self.proc = None
        self.stderr_path = os.path.join(self.tmp, "stderr.log")
        self.exit_code = None
        for attempt in range(5):
            self.port = free_port(self.host)
            cmd = [ARBORD, "serve", "--bind", bind, "--port", str(self.port),
                   "--models", self.models_dir] + self.args
            self.cmd = cmd
            log("start", " ".join(cmd))
            self.errf = open(self.stderr_path, "wb")
            self.proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=self.errf,
                                         stdin=subprocess.DEVNULL, env=dict(os.environ, **(env or {})))
            ALL_DAEMONS.append(self)
            if self._wait_listening(30):
                break
            rc = self.proc.poll()
            if rc == 2 and "bind" in self.stderr().lower() or rc == 2 and "use" in self.stderr().lower():
                continue  # the port was taken meanwhile: try another
            raise Fail("%s did not start (exit %s): %s" % (" ".join(cmd), rc, self.stderr()[-2000:]))
        if wait_ready:
            self.wait_ready(ready_timeout)

    def _place(self, src, dst_name, copy):
        dst = os.path.join(self.models_dir, dst_name)
        if copy:
            shutil.copyfile(src, dst)
        else:
            os.symlink(os.path.abspath(src), dst)

    def _wait_listening(self, timeout):
        end = time.time() + timeout
        while time.time() < end:
            if self.proc.poll() is not None:
                return False
            try:
                r = self.get("/healthz", timeout=5)
                if r.status == 200:
                    return True
            except OSError:
                pass
            time.sleep(0.02)
        return False

    def wait_ready(self, timeout=120):
        end = time.time() + timeout
        last = None
        while time.time() < end:
            if self.proc.poll() is not None:
                fail("daemon exited (%s) before ready: %s" % (self.proc.returncode, self.stderr()[-2000:]))
            try:
                last = self.get("/readyz", timeout=5)
                if last.status == 200:
                    return
            except OSError as e:
                last = e
            time.sleep(0.05)
        fail("daemon not ready after %ds: last /readyz %s" % (timeout, last.short() if isinstance(last, Resp) else last))

    def stderr(self):
        try:
            with open(self.stderr_path, "rb") as f:
                return f.read().decode("utf-8", "replace")
        except OSError:
            return ""

    def req(self, method, path, **kw):
        return request(self.port, method, path, host=self.host, **kw)

    def get(self, path, **kw):
        return self.req("GET", path, **kw)

    def post(self, path, js=None, **kw):
        return self.req("POST", path, js=js, **kw)

    def raw(self, data, **kw):
        return raw_request(self.port, data, host=self.host, **kw)

    def alive(self):
        return self.proc is not None and self.proc.poll() is None

    def stop(self, sig=signal.SIGTERM, timeout=30):
        """Stop; returns the exit status (None if it had to be killed)."""
        if self.proc is None:
            return self.exit_code
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
                self.exit_code = None
                self._close()
                return None
        self.exit_code = self.proc.returncode
        self._close()
        return self.exit_code

    def _close(self):
        try:
            self.errf.close()
        except Exception:
            pass
        if self in ALL_DAEMONS:
            ALL_DAEMONS.remove(self)
        self.proc_done = True

    def stop_clean(self, timeout=30):
        """Stop with SIGTERM and fail unless exit status 0 and no sanitizer report."""
        rc = self.stop(timeout=timeout)
        err = self.stderr()
        check(rc == 0, "%s: SIGTERM -> exit %s, expected 0; stderr tail: %s" % (self.name, rc, err[-1500:]))
        check("Sanitizer" not in err, "%s: sanitizer report: %s" % (self.name, err[err.find("Sanitizer") - 200:][:2000]))

    def cleanup(self):
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        self._close()
        # Every daemon's stderr is read for sanitizer reports before it goes,
        # whether or not its test stopped it cleanly: run.py fails the test.
        m = SANITIZER_REPORT.search(self.stderr())
        if m:
            err = self.stderr()
            SANITIZER_REPORTS.append("%s: %s" % (self.name, err[max(0, m.start() - 200):][:2000]))
        shutil.rmtree(self.tmp, ignore_errors=True)

    # -- API shortcuts
    def model(self, name):
        return expect_json(self.get("/api/models/" + name))

    def tree(self, name, accel, builder):
        for t in self.model(name)["trees"]:
            if t.get("accel") == accel and t.get("builder") == builder:
                return t
        fail("model %s has no tree %s:%s in its MODEL" % (name, accel, builder))

    def metrics(self):
        r = self.get("/metrics")
        expect_ok(r)
        return parse_metrics(r.body.decode())


def kill_all_daemons():
    for d in list(ALL_DAEMONS):
        try:
            d.cleanup()
        except Exception:
            pass


_SHARED = {}


def shared(key, factory):
    """One daemon per key, reused by the tests that take no special flags."""
    d = _SHARED.get(key)
    if d is None or not d.alive():
        d = factory()
        _SHARED[key] = d
    return d


def shared_daemons():
    return _SHARED


# --------------------------------------------------------------------------- metrics

def parse_metrics(text):
    """{sample name: [(labels dict, value)]} via prometheus_client's parser; also family names."""
    from prometheus_client.parser import text_string_to_metric_families
    samples = {}
    families = {}
    for fam in text_string_to_metric_families(text):
        families[fam.name] = fam
        for s in fam.samples:
            samples.setdefault(s.name, []).append((dict(s.labels), s.value))
    return samples, families


def metric_value(samples, name, **labels):
    total = None
    for lab, v in samples.get(name, []):
        if all(lab.get(k) == v2 for k, v2 in labels.items()):
            total = (total or 0) + v
    return total


# --------------------------------------------------------------------------- PNG

def png_decode(data):
    """-> (width, height, channels, rows) where rows is a list of bytes (unfiltered)."""
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        raise Fail("not a PNG: %r" % data[:16])
    pos = 8
    idat = []
    ihdr = None
    while pos < len(data):
        if pos + 8 > len(data):
            raise Fail("PNG truncated at %d" % pos)
        ln, typ = struct.unpack(">I4s", data[pos:pos + 8])
        chunk = data[pos + 8:pos + 8 + ln]
        crc = struct.unpack(">I", data[pos + 8 + ln:pos + 12 + ln])[0]
        if zlib.crc32(typ + chunk) & 0xffffffff != crc:
            raise Fail("PNG chunk %r has a bad CRC" % typ)
        if typ == b"IHDR":
            ihdr = struct.unpack(">IIBBBBB", chunk)
        elif typ == b"IDAT":
            idat.append(chunk)
        elif typ == b"IEND":
            break
        pos += 12 + ln
    if ihdr is None:
        raise Fail("PNG without IHDR")
    w, h, depth, ctype, comp, filt, interlace = ihdr
    if depth != 8 or ctype not in (0, 2, 6) or interlace != 0:
        raise Fail("PNG is not 8-bit gray/RGB/RGBA non-interlaced: depth %d type %d interlace %d"
                   % (depth, ctype, interlace))
    ch = {0: 1, 2: 3, 6: 4}[ctype]
    raw = zlib.decompress(b"".join(idat))
    stride = w * ch
    if len(raw) != h * (stride + 1):
        raise Fail("PNG data is %d bytes, expected %d for %dx%d" % (len(raw), h * (stride + 1), w, h))
    rows = []
    prev = bytearray(stride)
    for y in range(h):
        ft = raw[y * (stride + 1)]
        line = bytearray(raw[y * (stride + 1) + 1:(y + 1) * (stride + 1)])
        if ft == 0:
            pass
        elif ft == 1:
            for i in range(ch, stride):
                line[i] = (line[i] + line[i - ch]) & 255
        elif ft == 2:
            for i in range(stride):
                line[i] = (line[i] + prev[i]) & 255
        elif ft == 3:
            for i in range(stride):
                left = line[i - ch] if i >= ch else 0
                line[i] = (line[i] + ((left + prev[i]) >> 1)) & 255
        elif ft == 4:
            for i in range(stride):
                a = line[i - ch] if i >= ch else 0
                b = prev[i]
                c = prev[i - ch] if i >= ch else 0
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                if pa <= pb and pa <= pc:
                    pr = a
                elif pb <= pc:
                    pr = b
                else:
                    pr = c
                line[i] = (line[i] + pr) & 255
        else:
            raise Fail("PNG row %d has filter type %d" % (y, ft))
        rows.append(bytes(line))
        prev = line
    return w, h, ch, rows


def png_of(r, what=None):
    what = what or r.req
    if r.status != 200:
        fail("%s: expected 200 image/png, got %s" % (what, r.short()))
    ct = r.header("Content-Type", "")
    check(ct.startswith("image/png"), "%s: Content-Type %r, expected image/png" % (what, ct))
    return png_decode(r.body)


# --------------------------------------------------------------------------- truth tables

def shared_readme_counts():
    """{file: (triangles, vertices, bmin, bmax)} from ../shared/models/README.md."""
    path = os.path.join(SHARED, "README.md")
    out = {}
    with open(path, encoding="utf-8") as f:
        for line in f:
            m = re.match(r"\|\s*`([^`]+)`\s*\|\s*([\d,]+)\s*\|\s*([\d,]+)\s*\|\s*[\d,]+\s*\|\s*\(([^)]*)\)\s*→\s*\(([^)]*)\)", line)
            if m:
                tri = int(m.group(2).replace(",", ""))
                ver = int(m.group(3).replace(",", ""))
                bmin = [float(x) for x in m.group(4).split(",")]
                bmax = [float(x) for x in m.group(5).split(",")]
                out[m.group(1)] = (tri, ver, bmin, bmax)
    return out


def our_readme_counts():
    """{file: (triangles, vertices)} from models/README.md."""
    out = {}
    with open(os.path.join(OUR_MODELS, "README.md"), encoding="utf-8") as f:
        for line in f:
            m = re.match(r"\|\s*(\S+\.obj)[^|]*\|\s*([\d,]+)\s*\|\s*([\d,]+)\s*\|", line)
            if m:
                out[m.group(1)] = (int(m.group(2).replace(",", "")), int(m.group(3).replace(",", "")))
    return out


# --------------------------------------------------------------------------- misc

def parallel(n, fn, barrier=True):
    """Run fn(i) on n threads started together; returns the results (exceptions as values)."""
    results = [None] * n
    b = threading.Barrier(n) if barrier else None

    def run(i):
        try:
            if b:
                b.wait()
            results[i] = fn(i)
        except BaseException as e:  # keep the exception as the result
            results[i] = e

    ts = [threading.Thread(target=run, args=(i,), daemon=True) for i in range(n)]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    return results


def run_cli(args, timeout=120):
    p = subprocess.run([ARBORD] + args, capture_output=True, timeout=timeout)
    return p.returncode, p.stdout.decode("utf-8", "replace"), p.stderr.decode("utf-8", "replace")


def multipart(parts, boundary="arborBoundary7MA4YWxkTrZu0gW"):
    """parts: list of (field, filename, content-type, bytes) -> (body, content-type)."""
    out = []
    for field, filename, ctype, data in parts:
        out.append(b"--" + boundary.encode() + b"\r\n")
        disp = 'form-data; name="%s"' % field
        if filename:
            disp += '; filename="%s"' % filename
        out.append(("Content-Disposition: %s\r\n" % disp).encode())
        out.append(("Content-Type: %s\r\n\r\n" % ctype).encode())
        out.append(data)
        out.append(b"\r\n")
    out.append(b"--" + boundary.encode() + b"--\r\n")
    return b"".join(out), "multipart/form-data; boundary=" + boundary


# --------------------------------------------------------------------------- the shared daemons

def main_models():
    """Our small models, plus castle, galleon and bunny when ../shared/models has them."""
    ms = [our("cornell.obj"), our("sphere.obj"), our("menger.obj")]
    for n in ("castle.obj", "galleon.obj", "bunny.obj"):
        p = os.path.join(SHARED, n)
        if os.path.exists(p):
            ms.append(p)
    return ms


def main_daemon():
    """Default flags but --threads 2: most success paths and the plain failures."""
    return shared("main", lambda: Daemon(main_models(), ["--threads", "2"], name="main daemon"))


def default_web_daemon():
    """No --web: the repository's web/ found from the binary's place."""
    return shared("default-web", lambda: Daemon([our("cornell.obj")], ["--threads", "1"], default_web=True,
                                                name="default-web daemon"))


def limits_daemon():
    """Small limits for the limit failures: --max-pixels 100000, --max-body 4K, --max-upload 64K."""
    return shared("limits", lambda: Daemon([our("cornell.obj"), our("sphere.obj")],
                                           ["--threads", "2", "--max-pixels", "100000",
                                            "--max-body", "4K", "--max-upload", "64K"],
                                           name="limits daemon"))
