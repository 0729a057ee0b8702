#!/usr/bin/python3
"""arbord's HTTP tests: the daemon started on free ports and driven over real HTTP.

    tests/http/run.py [-k SUBSTRING]... [-v] [--list]

Env: ARBORD (the binary, default build/arbord), ARBOR_SHARED_MODELS (default ../shared/models),
HTTP_TESTS_VERBOSE=1 (say what runs). Prints Unity's lines: file:line:test:FAIL|IGNORE (and PASS
on a terminal or with -v), and last "N Tests M Failures K Ignored"; exit status 1 on any failure.
"""
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import traceback

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.dont_write_bytecode = True

import harness  # noqa: E402
from harness import Fail, Ignore  # noqa: E402

MODULES = ["test_endpoints", "test_errors", "test_static", "test_models", "test_concurrency",
           "test_memory", "test_security", "test_bench", "test_lifecycle", "test_abuse"]
PER_TEST_LIMIT = int(os.environ.get("HTTP_TEST_LIMIT", "150"))


class Timeout(Exception):
    pass


def on_alarm(signum, frame):
    raise Timeout("test ran past %d s" % PER_TEST_LIMIT)


def rel(path):
    try:
        return os.path.relpath(path, harness.REPO)
    except ValueError:
        return path


def where(exc, filename, line):
    """file:line of the deepest frame in a test module (else the test's def)."""
    best = None
    for fr in traceback.extract_tb(exc.__traceback__):
        base = os.path.basename(fr.filename)
        if base.startswith("test_") and base.endswith(".py"):
            best = (fr.filename, fr.lineno)
    return best or (filename, line)


def one_line(s):
    return " ".join(str(s).split())


def main(argv):
    filters = []
    listing = False
    # PASS lines on a terminal or with -v; under tests/run.sh only FAIL/IGNORE lines and the
    # summary (its grep for "error" would otherwise list every test_error_* that passed)
    show_pass = sys.stdout.isatty() or bool(os.environ.get("HTTP_TESTS_VERBOSE"))
    i = 0
    while i < len(argv):
        if argv[i] == "-k" and i + 1 < len(argv):
            filters.append(argv[i + 1])
            i += 2
        elif argv[i] == "--list":
            listing = True
            i += 1
        elif argv[i] == "-v":
            show_pass = True
            i += 1
        else:
            print("usage: run.py [-k SUBSTRING]... [-v] [--list]", file=sys.stderr)
            return 2
    for m in MODULES:
        __import__(m)
    tests = [t for t in harness.TESTS if not filters or any(f in t[0] for f in filters)]
    if listing:
        for name, _, fn, line in tests:
            print("%s:%d:%s" % (rel(fn), line, name))
        return 0

    # Without a daemon, every test fails with the one reason.
    probe = None
    if not os.access(harness.ARBORD, os.X_OK):
        probe = "no executable %s (set ARBORD or build it)" % harness.ARBORD
    else:
        try:
            p = subprocess.run([harness.ARBORD, "serve", "--help"], capture_output=True, timeout=20)
            out = (p.stdout + p.stderr).decode("utf-8", "replace")
            if "not implemented" in out:
                probe = "%s serve: %s" % (harness.ARBORD, one_line(out))
        except Exception as e:
            probe = "%s serve --help: %s" % (harness.ARBORD, e)

    signal.signal(signal.SIGALRM, on_alarm)
    # Every temp file and folder the run makes (each daemon's --models, token
    # files, web roots) and the daemons make (uploads on their way in) goes
    # under one folder, removed when the run ends, so that no test leaves
    # anything behind in /tmp however it ends; a stopped daemon's stderr
    # stays readable until then. The daemons inherit TMPDIR, so the tests
    # that look for their leftovers (tempfile.gettempdir()) look there.
    run_tmp = tempfile.mkdtemp(prefix="arbor-http-run-")
    tempfile.tempdir = run_tmp
    os.environ["TMPDIR"] = run_tmp
    failures = ignored = 0
    start_all = time.time()
    try:
        for name, func, filename, line in tests:
            t0 = time.time()
            if probe:
                print("%s:%d:%s:FAIL: %s" % (rel(filename), line, name, probe), flush=True)
                failures += 1
                continue
            harness.log("run", name)
            signal.alarm(PER_TEST_LIMIT)
            try:
                func()
                signal.alarm(0)
                if harness.SANITIZER_REPORTS:
                    raise Fail("sanitizer report: " + harness.SANITIZER_REPORTS.pop())
                if show_pass:
                    print("%s:%d:%s:PASS (%.1fs)" % (rel(filename), line, name, time.time() - t0), flush=True)
            except Ignore as e:
                signal.alarm(0)
                ignored += 1
                print("%s:%d:%s:IGNORE: %s" % (rel(filename), line, name, one_line(e)), flush=True)
            except BaseException as e:  # Fail, Timeout, any bug in the test or the daemon's answers
                signal.alarm(0)
                if isinstance(e, KeyboardInterrupt):
                    raise
                failures += 1
                f, ln = (filename, line) if hasattr(func, "case_line") else where(e, filename, line)
                if isinstance(e, Fail):
                    msg = str(e)
                else:
                    tb = traceback.extract_tb(e.__traceback__)
                    msg = "%s: %s (at %s:%d)" % (type(e).__name__, e, rel(tb[-1].filename), tb[-1].lineno) \
                        if tb else "%s: %s" % (type(e).__name__, e)
                print("%s:%d:%s:FAIL: %s" % (rel(f), ln, name, one_line(msg)), flush=True)
            del harness.SANITIZER_REPORTS[:]
    finally:
        signal.alarm(0)
        harness.kill_all_daemons()
        shutil.rmtree(run_tmp, ignore_errors=True)
    # Daemons still running at the end (none, when the lifecycle tests ran)
    # count as one more test that fails on a sanitizer report.
    if harness.SANITIZER_REPORTS:
        print("tests/http/run.py:1:daemons_left_running:FAIL: sanitizer report: %s"
              % one_line(harness.SANITIZER_REPORTS[0]), flush=True)
        tests.append(None)
        failures += 1
    print("(%.1f s)" % (time.time() - start_all))
    print("-----------------------")
    print("%d Tests %d Failures %d Ignored" % (len(tests), failures, ignored), flush=True)
    return 1 if failures else 0


if __name__ == "__main__":
    rc = main(sys.argv[1:])
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(rc)  # do not wait for threads a failed test left behind
