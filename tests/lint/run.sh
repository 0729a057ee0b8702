#!/usr/bin/env bash
# tests/lint/run.sh - make lint: cppcheck and clang-tidy on src/, each with a
# short list of checks that find bugs rather than style; any finding fails.
# Then the portable build (make MARCH=), which every other stage skips.
#
#   cppcheck   --enable=warning,portability (plus its default error checks:
#              leaks, out-of-bounds, null dereferences, undefined behaviour);
#              suppressions with their reasons in tests/lint/cppcheck.supp
#   clang-tidy the checks of .clang-tidy at the repository's root, where
#              each group says why it is on or off
set -u
root=$(cd "$(dirname "$0")/../.." && pwd)
cd "$root"
# ACCEL_KERNEL: the traversal kernels (KERNEL_SRC in the Makefile) are
# compiled once per kernel; lint reads them as the SSE2 one, whose code
# paths every build has.
flags=(-std=c11 -D_POSIX_C_SOURCE=200809L -DACCEL_KERNEL=sse2 -Iinclude -pthread)
failed=0

start=$(date +%s)
if cppcheck -q -j2 --std=c11 --enable=warning,portability -D_POSIX_C_SOURCE=200809L -DACCEL_KERNEL=sse2 -Iinclude \
        --suppress=missingIncludeSystem --suppressions-list=tests/lint/cppcheck.supp --inline-suppr \
        --error-exitcode=1 src/; then
    echo "lint cppcheck: clean ($(( $(date +%s) - start ))s)"
else
    echo "lint cppcheck: FAILED"
    failed=1
fi

start=$(date +%s)
out=$(mktemp)
# Two files at a time (the machine's cores are shared); WarningsAsErrors
# in .clang-tidy makes every finding an error.
find src -name '*.c' | sort | xargs -P2 -n6 sh -c 'clang-tidy --quiet "$@" -- '"${flags[*]}" clang-tidy >"$out" 2>&1
rc=$?
if [ "$rc" -eq 0 ] && ! grep -q 'error:' "$out"; then
    echo "lint clang-tidy: clean ($(( $(date +%s) - start ))s)"
else
    echo "lint clang-tidy: FAILED"
    grep -E 'error:|warning:' "$out" | sed "s|$root/||" | sort -u | head -n 40
    failed=1
fi

# The portable build: without -march=native only the kernels' own flags
# enable AVX, so code that needs it elsewhere (eight-lane vectors outside a
# kernel) fails to compile here, not on a user's machine.
start=$(date +%s)
if make --no-print-directory BUILD=build/portable MARCH= -j2 build/portable/arbord >"$out" 2>&1; then
    echo "lint portable: builds ($(( $(date +%s) - start ))s)"
else
    echo "lint portable: FAILED (make BUILD=build/portable MARCH=)"
    grep -E 'error:|warning:' "$out" | sed "s|$root/||" | sort -u | head -n 40
    failed=1
fi
rm -f "$out"
exit "$failed"
