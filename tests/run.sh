#!/usr/bin/env bash
# Runs test programs (Unity binaries, or any program that ends with Unity's
# summary "N Tests M Failures K Ignored": the CLI, HTTP and browser suites),
# shows the output of those that fail, and prints as its last line
# "N passed, M failed, K skipped" summed over all of them. Ignored tests
# count as skipped, never as passed. A program that dies without a summary
# counts as one failure.
#
# A skip whose reason names the shared models folder (ARBOR_SHARED_MODELS,
# or "shared/models") while that folder exists is printed as a line
# "SKIP-SHARED: PROGRAM: REASON" before the summary: the test could have run
# and did not. It still counts as skipped here; .ci/run fails on such lines.
set -u
shared_dir=${ARBOR_SHARED_MODELS:-}
passed=0
failed=0
skipped=0
# A suite's runner is named by its folder (tests/http/run.py is http), a Unity binary by itself.
name_of() {
    case "$1" in
        */run.*) basename "$(dirname "$1")" ;;
        *) basename "$1" ;;
    esac
}
for bin in "$@"; do
    log=$(mktemp)
    start=$(date +%s)
    # Say what is running: some suites take minutes and silence looks like a hang.
    echo "run  $(name_of "$bin") ..."
    "$bin" >"$log" 2>&1
    rc=$?
    secs=$(( $(date +%s) - start ))
    summary=$(grep -E '^[0-9]+ Tests [0-9]+ Failures [0-9]+ Ignored' "$log" | tail -n 1)
    if [ -n "$summary" ]; then
        n=$(echo "$summary" | awk '{print $1}')
        f=$(echo "$summary" | awk '{print $3}')
        k=$(echo "$summary" | awk '{print $5}')
    else
        n=1
        f=1
        k=0
    fi
    [ "$rc" -ne 0 ] && [ "$f" -eq 0 ] && f=1 && [ "$n" -eq 0 ] && n=1
    passed=$((passed + n - f - k))
    failed=$((failed + f))
    skipped=$((skipped + k))
    if [ "$f" -ne 0 ]; then
        echo "FAIL $(name_of "$bin") (exit $rc, ${secs}s):"
        grep -E ':FAIL|Segmentation|Assert|error|rror:|^not ok' "$log" | head -n 40
        [ -z "$summary" ] && tail -n 20 "$log"
    else
        echo "ok   $(name_of "$bin"): $n tests, $k skipped (${secs}s)"
    fi
    if [ "$k" -ne 0 ]; then
        grep -E ':IGNORE|SKIP|skipped' "$log" | head -n 10
        # Unity and the HTTP suite print ":IGNORE: reason", node "# SKIP reason".
        if [ -n "$shared_dir" ] && [ -d "$shared_dir" ]; then
            grep -E ':IGNORE|# SKIP' "$log" | grep -F -e "$shared_dir" -e "shared/models" |
                sed "s|^|SKIP-SHARED: $(basename "$bin"): |"
        fi
    fi
    rm -f "$log"
done
echo "$passed passed, $failed failed, $skipped skipped"
[ "$failed" -eq 0 ]
