#!/usr/bin/env bash
# tests/fuzz/run.sh SECONDS BUILD TARGET... - runs each libFuzzer target
# (BUILD/fuzzers/fuzz_TARGET, built by make fuzz) for SECONDS, one after the
# other (the machine's cores are shared), and prints one line per target.
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
failed=0
mkdir -p "$build/crashes" "$build/logs"
for t in "$@"; do
    corpus=$build/corpus/$t
    mkdir -p "$corpus"
    args=(-max_total_time="$seconds" -timeout=10 -rss_limit_mb=2048 -print_final_stats=1
          -artifact_prefix="$build/crashes/$t-")
    case "$t" in
        obj) args+=(-dict="$here/obj.dict" -max_len=16384) ;;
        ply) args+=(-max_len=16384) ;;
        render_request) args+=(-dict="$here/json.dict") ;;
        static) args+=(-dict="$here/static.dict") ;;
        upload) args+=(-dict="$here/obj.dict" -max_len=16384) ;;
    esac
    log=$build/logs/$t.log
    start=$(date +%s)
    "$build/fuzzers/fuzz_$t" "${args[@]}" "$corpus" "$here/corpus/$t" >"$log" 2>&1
    rc=$?
    secs=$(( $(date +%s) - start ))
    runs=$(grep -oE 'stat::number_of_executed_units: [0-9]+' "$log" | awk '{print $2}')
    cov=$(grep -oE 'cov: [0-9]+' "$log" | tail -n 1 | awk '{print $2}')
    if [ "$rc" -eq 0 ]; then
        echo "fuzz $t: ok, ${runs:-?} inputs in ${secs}s, coverage ${cov:-?}, corpus $(ls "$corpus" | wc -l) found"
    else
        failed=1
        echo "fuzz $t: FAILED (exit $rc after ${secs}s); log $log:"
        grep -E 'ERROR|WARNING|check failed|runtime error|SUMMARY|Test unit written|^    #[0-9]+ ' "$log" | head -n 40
    fi
done
exit "$failed"
