#!/usr/bin/env bash
# Runs test programs (Unity binaries, or any program that ends with Unity's
# summary "N Tests M Failures K Ignored": the CLI, HTTP and browser suites),
# shows the output of those that fail, and prints as its last line
# "N passed, M failed, K skipped" summed over all of them. Ignored tests
# count as skipped, never as passed. A program that dies without a summary
# counts as one failure.
#
# Unity binaries run ARBOR_TEST_JOBS at a time (1 when unset): each is one
# process with no daemon, port or timing of its own, and most spend their
# time on one core (brute force against the real models), so on two cores
# two of them take about the time of one. The suites (a folder's run.sh or
# run.py: a real daemon, a real browser) run after them, one at a time, with
# the machine to themselves. Results print in the order given either way.
#
# A skip whose reason names the shared models folder (ARBOR_SHARED_MODELS,
# or "shared/models") while that folder exists is printed as a line
# "SKIP-SHARED: PROGRAM: REASON" before the summary: the test could have run
# and did not. It still counts as skipped here; .ci/run fails on such lines.
set -u
. "$(dirname "$0")/parallel.sh"
shared_dir=${ARBOR_SHARED_MODELS:-}
jobs=${ARBOR_TEST_JOBS:-1}
passed=0
failed=0
skipped=0
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

is_suite() { case "$1" in */run.*) return 0 ;; *) return 1 ;; esac; }
# A suite's runner is named by its folder (tests/http/run.py is http), a Unity binary by itself.
name_of() {
    if is_suite "$1"; then basename "$(dirname "$1")"; else basename "$1"; fi
}

# Runs program $1 into $work/NAME.log, its exit status and seconds into $work/NAME.rc;
# says what starts, since some take minutes and silence looks like a hang.
run_one() {
    local bin=$1 name start rc
    name=$(name_of "$bin")
    echo "run  $name ..."
    start=$(date +%s)
    "$bin" >"$work/$name.log" 2>&1
    rc=$?
    echo "$rc $(( $(date +%s) - start ))" >"$work/$name.rc"
}

# Adds program $1's results (run_one has run it) to the sums and says how it went.
report() {
    local bin=$1 name log rc secs summary n f k
    name=$(name_of "$bin")
    log=$work/$name.log
    read -r rc secs <"$work/$name.rc"
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
        echo "FAIL $name (exit $rc, ${secs}s):"
        if grep -q '^TAP version' "$log"; then
            # node's TAP: a failure's message (and the daemon's log tail) follow its "not ok", up to "  ..."
            awk '/^not ok/ { p = 1 } p { print } /^  \.\.\.$/ { p = 0 }' "$log" | head -n 80
        else
            grep -E ':FAIL|Segmentation|Assert|error|rror:|^not ok' "$log" | head -n 40
        fi
        [ -z "$summary" ] && tail -n 20 "$log"
    else
        echo "ok   $name: $n tests, $k skipped (${secs}s)"
    fi
    if [ "$k" -ne 0 ]; then
        grep -E ':IGNORE|SKIP|skipped' "$log" | head -n 10
        # Unity and the HTTP suite print ":IGNORE: reason", node "# SKIP reason".
        if [ -n "$shared_dir" ] && [ -d "$shared_dir" ]; then
            grep -E ':IGNORE|# SKIP' "$log" | grep -F -e "$shared_dir" -e "shared/models" |
                sed "s|^|SKIP-SHARED: $(basename "$bin"): |"
        fi
    fi
}

units=()
suites=()
for bin in "$@"; do
    if is_suite "$bin"; then suites+=("$bin"); else units+=("$bin"); fi
done
# The Unity binaries, jobs at a time, then the suites alone.
run_in_order "$jobs" run_one report "${units[@]}"
run_in_order 1 run_one report "${suites[@]}"
echo "$passed passed, $failed failed, $skipped skipped"
[ "$failed" -eq 0 ]
