#!/usr/bin/env bash
# Every figure of docs/BENCH.md, measured in one go on the models of
# ../shared/models: OBJ parse speed, every kind and builder at all cores, the
# sah trees at one thread, and the k-d SAH trees' reference counts. Raw
# output goes to build/bench/, the Markdown tables to build/bench/tables.md.
#
#   scripts/bench.sh [--embree] [--embree-isa ISA] [--runs N]
#
# --embree-isa caps the kernels Embree may use (arbord bench --help), e.g.
# avx2 to compare with arbor's AVX2 kernels on a CPU that has AVX-512.
set -euo pipefail
cd "$(dirname "$0")/.."
arbord=build/arbord
out=build/bench
shared=${SHARED:-../shared}
embree=()
runs=5
while [ $# -gt 0 ]; do
    case "$1" in
        --embree) embree=(--embree) ;;
        --embree-isa) embree=(--embree-isa "$2"); shift ;;
        --runs) runs=$2; shift ;;
        *) echo "bench.sh: unknown option '$1' (--embree, --embree-isa ISA, --runs N)" >&2; exit 2 ;;
    esac
    shift
done
models=()
for m in "$shared"/models/*.obj "$shared"/models/*.obj.gz; do
    [ -e "$m" ] && models+=(--model "$m")
done
[ ${#models[@]} -gt 0 ] || { echo "bench.sh: no models in $shared/models" >&2; exit 1; }
mkdir -p "$out"

echo "== machine" | tee "$out/machine.txt"
{ lscpu | grep -E 'Model name|^CPU\(s\)|Thread|MHz' ; free -h | head -2; uname -srm; } | tee -a "$out/machine.txt"
echo "== parse ($runs runs)"
$arbord bench --parse --runs "$runs" "${models[@]}" | tee "$out/parse.md"
echo "== every kind and builder, all cores ($runs runs)"
$arbord bench "${embree[@]}" --runs "$runs" --format json "${models[@]}" > "$out/all.json"
echo "== sah, one thread ($runs runs)"
$arbord bench "${embree[@]}" --runs "$runs" --threads 1 --builder sah --format json "${models[@]}" > "$out/one.json"
echo "== k-d sah references"
: > "$out/kdstats.json"
for ((i = 1; i < ${#models[@]}; i += 2)); do
    $arbord stats --model "${models[i]}" --accel kd --builder sah --json 2>/dev/null >> "$out/kdstats.json"
done
python3 scripts/bench_tables.py "$out/all.json" "$out/one.json" "$out/kdstats.json" | tee "$out/tables.md"
