#!/usr/bin/env bash
# Runs the browser tests (node --test, playwright-core driving Debian's
# chromium) against arbord serve and ends with one line in Unity's format,
# "N Tests M Failures K Ignored", for tests/run.sh's summary; exits non-zero
# when a test fails. ARBORD (default build/arbord) and ARBOR_SHARED_MODELS
# (default ../shared/models) may point elsewhere; screenshots go to build/e2e/.
set -u
here=$(cd "$(dirname "$0")" && pwd)
repo=$(cd "$here/../.." && pwd)
cd "$repo"
export ARBORD=$(realpath -m "${ARBORD:-build/arbord}")
export ARBOR_SHARED_MODELS=$(realpath -m "${ARBOR_SHARED_MODELS:-../shared/models}")

if [ ! -d "$here/node_modules/playwright-core" ] || [ ! -x /usr/bin/chromium ]; then
    "$repo/scripts/deps-e2e.sh" || { echo "1 Tests 1 Failures 0 Ignored"; exit 1; }
fi
mkdir -p "$repo/build/e2e"

log=$(mktemp)
# one test file at a time; each test starts its own daemon on a free port
(cd "$here" && node --test --test-reporter=tap --test-concurrency=1 ./*.test.mjs) 2>&1 | tee "$log"
rc=${PIPESTATUS[0]}

count() { grep -E "^# $1 [0-9]+" "$log" | tail -n 1 | awk '{print $3}'; }
pass=$(count pass); fail=$(count fail); skipped=$(count skipped); todo=$(count todo); cancelled=$(count cancelled)
rm -f "$log"
pass=${pass:-0}; fail=${fail:-0}; skipped=${skipped:-0}; todo=${todo:-0}; cancelled=${cancelled:-0}
fail=$((fail + cancelled))
ignored=$((skipped + todo))
total=$((pass + fail + ignored))
if [ "$total" -eq 0 ] || { [ "$rc" -ne 0 ] && [ "$fail" -eq 0 ]; }; then
    # node itself failed (no summary, or an error outside any test)
    fail=$((fail + 1)); total=$((total + 1))
fi
echo "$total Tests $fail Failures $ignored Ignored"
[ "$fail" -eq 0 ]
