#!/usr/bin/env bash
# Runs test binaries (Unity or any program that ends with Unity's summary
# "N Tests M Failures K Ignored"), shows the output of those that fail, and
# prints as its last line "N passed, M failed" summed over all of them.
# A binary that dies without a summary counts as one failure.
set -u
passed=0
failed=0
for bin in "$@"; do
    log=$(mktemp)
    start=$(date +%s)
    # Say what is running: the accel tests take minutes and silence looks like a hang.
    echo "run  $(basename "$bin") ..."
    "$bin" >"$log" 2>&1
    rc=$?
    secs=$(( $(date +%s) - start ))
    summary=$(grep -E '^[0-9]+ Tests [0-9]+ Failures [0-9]+ Ignored' "$log" | tail -n 1)
    if [ -n "$summary" ]; then
        n=$(echo "$summary" | awk '{print $1}')
        f=$(echo "$summary" | awk '{print $3}')
    else
        n=1
        f=1
    fi
    [ "$rc" -ne 0 ] && [ "$f" -eq 0 ] && f=1
    passed=$((passed + n - f))
    failed=$((failed + f))
    if [ "$f" -ne 0 ]; then
        echo "FAIL $(basename "$bin") (exit $rc, ${secs}s):"
        grep -E ':FAIL|Segmentation|Assert|error|rror:' "$log" | head -n 40
        [ -z "$summary" ] && tail -n 20 "$log"
    else
        echo "ok   $(basename "$bin"): $n tests (${secs}s)"
    fi
    rm -f "$log"
done
echo "$passed passed, $failed failed"
[ "$failed" -eq 0 ]
