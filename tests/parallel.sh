# tests/parallel.sh - sourced by tests/run.sh and tests/fuzz/run.sh: runs a
# list of jobs some at a time and reports them in the order given.
#
# run_in_order JOBS RUN REPORT ITEM... calls "RUN ITEM" for each item in
# the background, at most JOBS at once, and "REPORT ITEM" in the calling
# shell (so it may add to the caller's sums) for each item, in the
# given order, as soon as that item and every one before it have finished.
# RUN keeps its results in files of its own for REPORT to read: it runs in
# a subshell.
run_in_order() {
    local jobs=$1 run=$2 report=$3
    shift 3
    local items=("$@") finished i next=0 running=0
    finished=$(mktemp -d)
    for i in "${!items[@]}"; do
        if [ "$running" -ge "$jobs" ]; then
            wait -n
            running=$((running - 1))
            while [ "$next" -lt "$i" ] && [ -f "$finished/$next" ]; do
                "$report" "${items[$next]}"
                next=$((next + 1))
            done
        fi
        ( "$run" "${items[$i]}"; touch "$finished/$i" ) &
        running=$((running + 1))
    done
    wait
    while [ "$next" -lt "${#items[@]}" ]; do
        "$report" "${items[$next]}"
        next=$((next + 1))
    done
    rm -rf "$finished"
}
