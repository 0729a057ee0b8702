#!/usr/bin/env bash
# tests/fuzz/run.sh SECONDS BUILD TARGET... - runs each libFuzzer target
# (BUILD/fuzzers/fuzz_TARGET, built by make fuzz) for SECONDS, and prints
# one line per target, in the order given. ARBOR_FUZZ_JOBS targets (1 when
# unset) run at once: each fuzzer is one process on one core, so on two
# cores two of them each get as many inputs per second as one alone.
#
# Inputs: the committed seeds and regression inputs in
# tests/fuzz/corpus/TARGET (libFuzzer runs every one of them first), and
# BUILD/corpus/TARGET, where the inputs it finds are kept between runs
# (never in the repository). Dictionaries: tests/fuzz/obj.dict for the OBJ
# reader and the upload, tests/fuzz/json.dict for the render requests,
# tests/fuzz/static.dict for the static path resolver (its trap names).
#
# A crash, a failed check, a sanitizer report, a leak, a timeout (10 s on
# one input) or running out of memory (2 GB) fails the target: its input is
# saved as BUILD/crashes/TARGET-*, the log's tail is printed, and the run
# exits 1. Every such input belongs in tests/fuzz/corpus/TARGET once fixed,
# where make test replays it.
set -u
seconds=$1
build=$2
shift 2
here=$(cd "$(dirname "$0")" && pwd)
. "$here/../parallel.sh"
jobs=${ARBOR_FUZZ_JOBS:-1}
failed=0
mkdir -p "$build/crashes" "$build/logs"

# Runs target $1 for $seconds into its log; its exit status and seconds into $build/logs/$1.rc.
fuzz_one() {
    local t=$1 corpus=$build/corpus/$1 start rc
    local args=(-max_total_time="$seconds" -timeout=10 -rss_limit_mb=2048 -print_final_stats=1
                -artifact_prefix="$build/crashes/$t-")
    case "$t" in
        obj) args+=(-dict="$here/obj.dict" -max_len=16384) ;;
        ply) args+=(-max_len=16384) ;;
        render_request) args+=(-dict="$here/json.dict") ;;
        static) args+=(-dict="$here/static.dict") ;;
        upload) args+=(-dict="$here/obj.dict" -max_len=16384) ;;
    esac
    mkdir -p "$corpus"
    start=$(date +%s)
    "$build/fuzzers/fuzz_$t" "${args[@]}" "$corpus" "$here/corpus/$t" >"$build/logs/$t.log" 2>&1
    rc=$?
    echo "$rc $(( $(date +%s) - start ))" >"$build/logs/$t.rc"
}

# Says how target $1 went (fuzz_one has finished it).
report() {
    local t=$1 corpus=$build/corpus/$1 log=$build/logs/$1.log rc secs runs cov
    read -r rc secs <"$build/logs/$t.rc"
    runs=$(grep -oE 'stat::number_of_executed_units: [0-9]+' "$log" | awk '{print $2}')
    cov=$(grep -oE 'cov: [0-9]+' "$log" | tail -n 1 | awk '{print $2}')
    if [ "$rc" -eq 0 ]; then
        echo "fuzz $t: ok, ${runs:-?} inputs in ${secs}s, coverage ${cov:-?}, corpus $(ls "$corpus" | wc -l) found"
    else
        failed=1
        echo "fuzz $t: FAILED (exit $rc after ${secs}s); log $log:"
        grep -E 'ERROR|WARNING|check failed|runtime error|SUMMARY|Test unit written|^    #[0-9]+ ' "$log" | head -n 40
    fi
}

run_in_order "$jobs" fuzz_one report "$@"
exit "$failed"
