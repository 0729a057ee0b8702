#!/usr/bin/env bash
# make loadtest: arbord serve saturated by wrk (Debian's package) posting 256x256 frames
# (tests/load/frames.lua) for LOAD_SECONDS at 2*(threads+queue) connections, twice.
# Prints frames/s, p50/p99 latency, answers by status, socket errors and the daemon's RSS
# before, between and after. Fails on any status but 200 and 503, any socket error, a dead
# daemon, RSS grown by more than 10% from the first run to the second, or an unclean exit.
#
# Env: ARBORD (build/arbord), LOAD_SECONDS (30), LOAD_THREADS (render workers: nproc),
#      LOAD_QUEUE (16), LOAD_MODELS (dir, default the repo's models/), LOAD_WRK_THREADS (2),
#      LOAD_BACKOFF_MS (0: a 503 is re-sent at once; N: wait N ms after a 503, see frames.lua).
set -u
cd "$(dirname "$0")/../.."
ARBORD=${ARBORD:-build/arbord}
SECS=${LOAD_SECONDS:-30}
THREADS=${LOAD_THREADS:-$(nproc)}
QUEUE=${LOAD_QUEUE:-16}
MODELS=${LOAD_MODELS:-models}
WRK_THREADS=${LOAD_WRK_THREADS:-2}
CONNS=$(( 2 * (THREADS + QUEUE) ))
PY=/usr/bin/python3

command -v wrk >/dev/null || { echo "loadtest: wrk not found (apt-get install wrk)"; exit 1; }
[ -x "$ARBORD" ] || { echo "loadtest: no $ARBORD (make first)"; exit 1; }
[ "$CONNS" -ge "$WRK_THREADS" ] || WRK_THREADS=$CONNS

tmp=$(mktemp -d)
pid=
cleanup() {
    [ -n "$pid" ] && kill -0 "$pid" 2>/dev/null && kill -KILL "$pid" 2>/dev/null
    rm -rf "$tmp"
}
trap cleanup EXIT

port=$($PY -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')
"$ARBORD" serve --port "$port" --threads "$THREADS" --queue "$QUEUE" --models "$MODELS" \
    2>"$tmp/stderr.log" &
pid=$!
url="http://127.0.0.1:$port"

# wait for /readyz, then list the models
models=$($PY - "$url" <<'EOF'
import json, sys, time, urllib.request
url = sys.argv[1]
end = time.time() + 120
while time.time() < end:
    try:
        with urllib.request.urlopen(url + "/readyz", timeout=5) as r:
            if r.status == 200:
                break
    except Exception:
        time.sleep(0.1)
else:
    sys.exit("daemon not ready after 120 s")
with urllib.request.urlopen(url + "/api/models", timeout=10) as r:
    print(" ".join(m["name"] for m in json.load(r)["models"]))
EOF
) || { echo "loadtest: the daemon did not become ready"; tail -n 20 "$tmp/stderr.log"; exit 1; }

rss() { awk '/^VmRSS:/ {print $2}' "/proc/$pid/status" 2>/dev/null; }
alive() {
    kill -0 "$pid" 2>/dev/null && $PY -c 'import sys,urllib.request; urllib.request.urlopen(sys.argv[1]+"/healthz", timeout=10)' "$url" 2>/dev/null
}

echo "loadtest: $ARBORD serve --threads $THREADS --queue $QUEUE, models: $models"
echo "loadtest: wrk -t$WRK_THREADS -c$CONNS -d${SECS}s, 256x256 frames, twice (backoff after 503: ${LOAD_BACKOFF_MS:-0} ms)"
fail=0
rss0=$(rss)
echo "RSS before:  ${rss0} kB"

declare -A RSS_AFTER
for run in 1 2; do
    out="$tmp/wrk$run.txt"
    wrk -t"$WRK_THREADS" -c"$CONNS" -d"${SECS}s" --timeout 60s -s tests/load/frames.lua "$url" -- $models >"$out" 2>&1
    rc=$?
    echo "-- run $run (wrk exit $rc)"
    if [ "$rc" -ne 0 ] || ! grep -q '^LOAD ' "$out"; then
        echo "FAIL: wrk run $run did not complete:"; cat "$out"; fail=1
    fi
    fps=$(awk '/^LOAD frames_per_s/ {print $3}' "$out")
    p50=$(awk '/^LOAD p50_ms/ {print $3}' "$out")
    p99=$(awk '/^LOAD p99_ms/ {print $3}' "$out")
    echo "frames/s: ${fps:-?}   latency of every answer (wrk): p50 ${p50:-?} ms  p99 ${p99:-?} ms   requests: $(awk '/^LOAD requests/ {print $3}' "$out")"
    awk '/^LOAD frame_server_ms/ {printf "200 frames, in the daemon (Server-Timing queue+build+render+encode): p50 %s ms  p99 %s ms\n", $4, $6}' "$out"
    awk '/^LOAD frame_render_ms/ {printf "200 frames, render alone: p50 %s ms\n", $4}' "$out"
    awk '/^LOAD status/ {printf "status %s: %s\n", $3, $4}' "$out"
    bad=$(awk '/^LOAD status/ && $3 != 200 && $3 != 503 {printf "%s(%s) ", $3, $4}' "$out")
    [ -n "$bad" ] && { echo "FAIL: run $run answered statuses other than 200/503: $bad"; fail=1; }
    [ "$(awk '/^LOAD status 200/ {print $4}' "$out")" ] || { echo "FAIL: run $run rendered no frame"; fail=1; }
    sock=$(awk '/^LOAD socket_errors/ {print $3}' "$out")
    echo "socket errors: $(awk '/^LOAD socket_errors/ {print $3 " (connect " $5 ", read " $7 ", write " $9 ", timeout " $11 ")"}' "$out")"
    [ "${sock:-1}" != 0 ] && { echo "FAIL: run $run had socket errors"; fail=1; }
    if ! alive; then
        echo "FAIL: the daemon is dead or does not answer /healthz after run $run"
        tail -n 20 "$tmp/stderr.log"
        exit 1
    fi
    RSS_AFTER[$run]=$(rss)
    [ "$run" = 1 ] && echo "RSS between: ${RSS_AFTER[1]} kB" || echo "RSS after:   ${RSS_AFTER[2]} kB"
done

r1=${RSS_AFTER[1]}
r2=${RSS_AFTER[2]}
growth=$(awk -v a="$r1" -v b="$r2" 'BEGIN {printf "%.1f", (b - a) * 100.0 / a}')
echo "RSS growth from run 1 to run 2: ${growth}%"
awk -v a="$r1" -v b="$r2" 'BEGIN {exit !(b > a * 1.10)}' && { echo "FAIL: RSS grew by more than 10%"; fail=1; }

kill -TERM "$pid"
wait "$pid"
rc=$?
pid=
echo "daemon exit after SIGTERM: $rc"
[ "$rc" -ne 0 ] && { echo "FAIL: the daemon exited $rc after SIGTERM"; tail -n 20 "$tmp/stderr.log"; fail=1; }

if [ "$fail" -ne 0 ]; then echo "loadtest: FAILED"; exit 1; fi
echo "loadtest: OK"
