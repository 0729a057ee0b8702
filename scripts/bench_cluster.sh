#!/usr/bin/env bash
# scripts/bench_cluster.sh - the measured figures of docs/SCALE.md, on this machine:
# for one daemon without nginx (--threads 1, then --threads 2) and for N = 1, 2, 4
# single-thread daemons behind nginx (deploy/cluster.sh):
#   - 256x256 frames per second with wrk, 1 connection (and its median latency) and 8
#     connections, SECS seconds each;
#   - the time to a 2048x2048 frame asked as 16 regions over 8 connections
#     (arbord render --url --split 16), the median of REPS runs.
# One markdown table row per setup on stdout; raw wrk and render output in
# build/bench-cluster/. MODEL (default menger), SECS (10), REPS (5), PORT (18480).
set -u
repo=$(cd "$(dirname "$0")/.." && pwd)
arbord=${ARBORD:-$repo/build/arbord}
model=${MODEL:-menger}
secs=${SECS:-10}
reps=${REPS:-5}
port=${PORT:-18480}
out="$repo/build/bench-cluster"
mkdir -p "$out"
frame="/api/render?model=$model&width=256&height=256"

# wrk's "50%  7.61ms" as milliseconds.
wrk_ms() {
    awk '$1 == "50%" { v = $2; u = v; sub(/[0-9.]+/, "", u); sub(/[a-z]+$/, "", v);
          print (u == "us" ? v / 1000 : u == "s" ? v * 1000 : v) }' "$1"
}
wrk_rps() { awk '/^Requests\/sec:/ { print $2 }' "$1"; }

median() { sort -n | awk '{ a[NR] = $1 } END { print a[int((NR + 1) / 2)] }'; }

measure() {
    local base=$1 label=$2 tag=$3 r
    wrk -t1 -c1 -d"${secs}s" --latency "$base$frame" >"$out/$tag-c1.txt" 2>&1
    wrk -t2 -c8 -d"${secs}s" --latency "$base$frame" >"$out/$tag-c8.txt" 2>&1
    : >"$out/$tag-2048.txt"
    for ((r = 0; r < reps; r++)); do
        "$arbord" render --url "$base" --model "$model" --width 2048 --height 2048 --split 16 --connections 8 \
            -o "$out/$tag-2048.png" >>"$out/$tag-2048.txt" 2>&1
    done
    local big
    big=$(sed -n 's/.* in \([0-9.]*\) ms,.*/\1/p' "$out/$tag-2048.txt" | median)
    printf '| %s | %s | %s | %s | %s |\n' "$label" "$(wrk_rps "$out/$tag-c1.txt")" "$(wrk_ms "$out/$tag-c1.txt")" \
        "$(wrk_rps "$out/$tag-c8.txt")" "$big"
}

wait_ok() {
    local i
    for ((i = 0; i < 600; i++)); do
        [ "$(curl -s -o /dev/null -w '%{http_code}' "$1")" = 200 ] && return 0
        sleep 0.1
    done
    return 1
}

echo "load average before: $(cut -d' ' -f1-3 /proc/loadavg)" >&2
echo "| setup | frames/s, 1 conn | median ms, 1 conn | frames/s, 8 conns | 2048x2048 in 16 regions, median ms |"
echo "| --- | --- | --- | --- | --- |"
for t in 1 2; do
    "$arbord" serve --port "$port" --threads "$t" --models "$repo/models" --web "$repo/web" 2>"$out/direct$t.log" &
    pid=$!
    wait_ok "http://127.0.0.1:$port/readyz" && measure "http://127.0.0.1:$port" "1 daemon --threads $t, no nginx" "direct$t"
    kill -TERM "$pid"
    wait "$pid"
done
for n in 1 2 4; do
    ARBORD=$arbord "$repo/deploy/cluster.sh" -n "$n" --port "$port" --threads 1 --state "$out/state$n" \
        >"$out/cluster$n.log" 2>&1 &
    pid=$!
    for ((i = 0; i < 600; i++)); do grep -q "open http" "$out/cluster$n.log" && break; sleep 0.1; done
    measure "http://127.0.0.1:$port" "$n x --threads 1 behind nginx" "nginx$n"
    # TERM, not INT: a shell script's background jobs ignore SIGINT.
    kill -TERM "$pid"
    wait "$pid"
done
echo "load average after: $(cut -d' ' -f1-3 /proc/loadavg)" >&2
