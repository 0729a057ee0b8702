#!/usr/bin/env bash
# tests/cli/run.sh - arbord and the scripts as a user meets them: output
# errors fail every subcommand, render refuses names it would not honour and
# never removes what it did not make, options given twice are refused,
# --threads 0 is documented, the JSON keys scripts read stay put, bench checks
# the Embree ISA it is given, bench_tables.py
# reads bench's output, and scripts/deps.sh finds deb entries in both apt
# source formats. Ends with Unity's summary line, for tests/run.sh.
#
#   ARBORD=build/arbord tests/cli/run.sh      (ARBORD defaults to build/arbord)
set -u
root=$(cd "$(dirname "$0")/../.." && pwd)
arbord=${ARBORD:-$root/build/arbord}
case "$arbord" in /*) ;; *) arbord=$root/$arbord ;; esac
model=$root/models/cornell.obj
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
tests=0
failures=0

# check NAME COMMAND...: runs the command; a non-zero status is a failure.
check() {
    local name=$1
    shift
    tests=$((tests + 1))
    if "$@" >"$tmp/out" 2>"$tmp/err"; then
        echo "tests/cli/run.sh:$name:PASS"
    else
        failures=$((failures + 1))
        echo "tests/cli/run.sh:$name:FAIL"
        sed 's/^/    /' "$tmp/err" | head -n 10
    fi
}

fail() {
    echo "$*" >&2
    return 1
}

# Runs arbord with stdout on /dev/full: must exit non-zero and say so.
full_fails() {
    local rc=0
    "$arbord" "$@" >/dev/full 2>"$tmp/full.err" || rc=$?
    [ "$rc" -ne 0 ] || fail "arbord $* > /dev/full exited 0"
    grep -q "cannot write to standard output" "$tmp/full.err" || fail "no message: $(cat "$tmp/full.err")"
}

output_errors_fail() {
    full_fails stats --model "$model" --builder sah &&
        full_fails stats --model "$model" --builder sah --json &&
        full_fails render --model "$model" --width 32 --height 24 -o "$tmp/o.png" &&
        full_fails bench --parse --model "$model" --runs 1 &&
        full_fails gen sphere --level 1 -o "$tmp/s.obj" &&
        full_fails render --help &&
        full_fails --help
}

# usage_fails ARGS...: exit status 2, nothing written to $tmp/never.*
usage_fails() {
    local rc=0
    "$arbord" "$@" >/dev/null 2>"$tmp/usage.err" || rc=$?
    [ "$rc" -eq 2 ] || fail "arbord $*: exit $rc, not 2"
    ! ls "$tmp"/never.* >/dev/null 2>&1 || fail "arbord $* wrote a file"
}

render_refuses_other_extensions() {
    usage_fails render --model "$model" -o "$tmp/never.jpg" &&
        usage_fails render --model "$model" -o "$tmp/never" &&
        grep -q "must end in .png" "$tmp/usage.err" &&
        "$arbord" render --model "$model" --width 16 --height 16 -o "$tmp/upper.PNG" >/dev/null &&
        [ -s "$tmp/upper.PNG" ]
}

one_value_options_refuse_a_second() {
    usage_fails render --model "$model" --model "$model" -o "$tmp/never.png" &&
        grep -q -- "--model given twice" "$tmp/usage.err" &&
        usage_fails render --model "$model" -o "$tmp/never.png" -o "$tmp/never2.png" &&
        usage_fails stats --model "$model" --model "$model" &&
        grep -q -- "--model given twice" "$tmp/usage.err" &&
        usage_fails gen sphere -o "$tmp/never.obj" -o "$tmp/never2.obj" &&
        usage_fails render --model "$model" -o "$tmp/never.png" --mode shaded --mode heat &&
        grep -q -- "--mode given twice" "$tmp/usage.err" &&
        usage_fails render --model "$model" --output "$tmp/never.png" -o "$tmp/never2.png" &&
        usage_fails stats --model "$model" --accel bvh --accel kd &&
        usage_fails gen sphere --level 2 --level 3 -o "$tmp/never.obj" &&
        usage_fails bench --model "$model" --runs 1 --runs 2 &&
        usage_fails serve --port 0 --port 1 --models "$root/models"
}

# render takes what the daemon's API takes (docs/API.md's ranges), a bad
# --url and gen's -o of another extension are usage errors, and the heat
# scale a frame prints gives that frame again when passed back.
ranges_are_the_apis() {
    usage_fails gen sphere -o "$tmp/never.txt" && grep -q "must end in .obj" "$tmp/usage.err" &&
        usage_fails gen sphere -o "$tmp/never.OBJ" &&
        usage_fails render --url 127.0.0.1:9 --model cornell -o "$tmp/never.png" &&
        grep -q "http://" "$tmp/usage.err" &&
        usage_fails render --model "$model" --seed 1.5 -o "$tmp/never.png" &&
        usage_fails render --model "$model" --seed 9007199254740992 -o "$tmp/never.png" &&
        usage_fails render --model "$model" --pitch 89.95 -o "$tmp/never.png" &&
        "$arbord" render --model "$model" --width 8 --height 8 --pitch -89.9 --distance 0.0001 \
            --seed 9007199254740991 -o "$tmp/edge.png" >/dev/null || fail "render at the API's edges failed"
    "$arbord" render --model "$model" --width 48 --height 32 --spp 3 --mode heat -o "$tmp/heat.png" \
        >"$tmp/heat.out" || fail "heat render failed"
    local scale
    scale=$(sed -n 's/^heat scale: \([^ ]*\) .*/\1/p' "$tmp/heat.out")
    [ -n "$scale" ] || fail "no heat scale in: $(cat "$tmp/heat.out")"
    "$arbord" render --model "$model" --width 48 --height 32 --spp 3 --mode heat --heat-scale "$scale" \
        -o "$tmp/heat2.png" >/dev/null || fail "heat render with --heat-scale $scale failed"
    cmp -s "$tmp/heat.png" "$tmp/heat2.png" || fail "--heat-scale $scale, as printed, gives another frame"
}

# A --web folder that cannot be read would serve the viewer's page as a 404.
serve_refuses_a_web_folder_it_cannot_read() {
    usage_fails serve --port 0 --web "$tmp/never.web" && grep -q "cannot read --web" "$tmp/usage.err"
}

# "all" names every tree kind and builder in bench as in stats.
all_is_every_name() {
    local rows
    rows=$("$arbord" bench --model "$model" --accel all --builder all --runs 1 --format json 2>/dev/null |
        grep -c '"builder"') || fail "bench --accel all --builder all failed"
    [ "$rows" -eq 8 ] || fail "bench --accel all --builder all: $rows rows, not 8"
    rows=$("$arbord" stats --model "$model" --accel all --builder all --json 2>/dev/null | grep -c '"layout":"binary"')
    [ "$rows" -eq 8 ] || fail "stats --accel all --builder all: $rows binary rows, not 8"
}

# A failed write leaves what was at the path: a device stays a device, an
# existing image stays whole when the folder cannot take a new one.
render_never_removes_what_it_did_not_make() {
    local rc=0
    "$arbord" render --model "$model" --width 64 --height 64 -o /dev/full >/dev/null 2>"$tmp/dev.err" || rc=$?
    [ "$rc" -ne 0 ] || fail "render -o /dev/full exited 0"
    [ -c /dev/full ] || fail "/dev/full is no longer a character device"
    rc=0
    "$arbord" render --model "$model" --width 16 --height 16 -o "$tmp/nodir/x.png" >/dev/null 2>&1 || rc=$?
    [ "$rc" -eq 1 ] || fail "render into a missing folder: exit $rc"
    [ "$(ls -A "$tmp" | grep -c '\.png\.')" -eq 0 ] || fail "a temporary file was left behind"
}

threads_zero_is_documented() {
    local cmd
    for cmd in render stats bench; do
        "$arbord" "$cmd" --help | grep -q -- "--threads N.*0 = one per core" ||
            fail "arbord $cmd --help does not say --threads 0 means one per core"
    done
    grep -q -- "--threads 0" "$root/README.md" || fail "README.md does not document --threads 0"
}

# Embree says nothing of an ISA it does not know, so bench checks the name;
# a known one is Embree's row's kernel (where arbord has Embree).
embree_isa_is_checked_and_reported() {
    usage_fails bench --model "$model" --embree-isa avx3 &&
        grep -q -- "--embree-isa must be sse2, sse4.2, avx, avx2 or avx512, not 'avx3'" "$tmp/usage.err" || return 1
    "$arbord" bench --model "$model" --accel bvh --builder sah --runs 1 --embree-isa sse2 --format json \
        > "$tmp/isa.json" 2>"$tmp/isa.err" || { grep -q "built without Embree" "$tmp/isa.err"; return; }
    python3 - "$tmp/isa.json" <<'EOF'
import json, sys
rows = [json.loads(l) for l in open(sys.argv[1])]
assert [r["accel"] for r in rows] == ["bvh", "embree"], rows
assert rows[1]["kernel"] == "sse2", rows[1]
assert rows[1]["primary_hits"] == rows[0]["primary_hits"] > 0, rows
EOF
}

# --embree-robust alone asks for Embree's row, in its robust mode, which
# scripts/bench_tables.py names and takes the build ratio to.
embree_robust_row() {
    "$arbord" bench --model "$model" --accel bvh --builder sah --runs 1 --embree-robust --format json \
        > "$tmp/robust.json" 2>"$tmp/robust.err" || { grep -q "built without Embree" "$tmp/robust.err"; return; }
    python3 - "$tmp/robust.json" <<'EOF' || return 1
import json, sys
rows = [json.loads(l) for l in open(sys.argv[1])]
assert [(r["accel"], r["builder"]) for r in rows] == [("bvh", "sah"), ("embree", "robust")], rows
assert rows[1]["primary_hits"] == rows[0]["primary_hits"] > 0, rows
EOF
    "$arbord" stats --model "$model" --accel kd --builder sah --json > "$tmp/kd.json" &&
        python3 "$root/scripts/bench_tables.py" "$tmp/robust.json" "$tmp/robust.json" "$tmp/kd.json" > "$tmp/robust.md" &&
        grep -q "| cornell | 36 | Embree (robust) |" "$tmp/robust.md" &&
        ! grep -q "| cornell | 36 | bvh sah | [^|]* | [^|]* | [^|]* | [^|]* | [^|]* | [^|]* | [^|]* | - |" "$tmp/robust.md"
}

# The keys scripts/bench_tables.py and users' scripts read.
json_keys_stay() {
    "$arbord" stats --model "$model" --accel kd --builder sah --json > "$tmp/stats.json" &&
        "$arbord" bench --model "$model" --accel bvh --builder sah --runs 1 --format json > "$tmp/bench.json" 2>/dev/null &&
        python3 - "$tmp/stats.json" "$tmp/bench.json" <<'EOF'
import json, sys
stats = [json.loads(l) for l in open(sys.argv[1])]
bench = [json.loads(l) for l in open(sys.argv[2])]
want_stats = ["model", "triangles", "accel", "builder", "layout", "build_ms", "nodes", "leaves", "empty_leaves",
              "max_depth", "mean_leaf_depth", "mean_tris_per_leaf", "refs", "bytes", "sah_cost"]
want_bench = ["model", "scale", "triangles", "accel", "builder", "kernel", "threads", "build_ms", "mean_leaf_depth",
              "mean_tris_per_leaf", "sah_cost", "bytes_per_tri", "render_ms", "primary_mrays", "diffuse_mrays", "shadow_mrays",
              "primary_hits", "primary_tsum", "primary_nodes_per_ray", "primary_tris_per_ray", "diffuse_nodes_per_ray",
              "diffuse_tris_per_ray", "shadow_nodes_per_ray", "shadow_tris_per_ray"]
assert len(stats) == 1 and list(stats[0]) == want_stats, list(stats[0])
assert stats[0]["layout"] == "binary", stats[0]
assert len(bench) == 1 and list(bench[0]) == want_bench, list(bench[0])
assert bench[0]["accel"] == "bvh" and bench[0]["builder"] == "sah" and bench[0]["primary_hits"] > 0
assert bench[0]["kernel"] in ("avx2", "sse2"), bench[0]["kernel"]
EOF
}

bench_tables_read_bench_output() {
    "$arbord" bench --model "$model" --runs 1 --format json > "$tmp/all.json" 2>/dev/null &&
        "$arbord" stats --model "$model" --accel kd --builder sah --json > "$tmp/kd.json" &&
        python3 "$root/scripts/bench_tables.py" "$tmp/all.json" "$tmp/all.json" "$tmp/kd.json" > "$tmp/tables.md" &&
        grep -q "## Ray sets, all cores" "$tmp/tables.md" &&
        grep -q "| cornell | 36 | bvh sah |" "$tmp/tables.md"
}

# scripts/deps.sh's deb-src entries from each apt source format.
deps_reads_both_apt_formats() {
    cat > "$tmp/sources.list" <<'EOF'
# debootstrap's default
deb http://deb.debian.org/debian bookworm main
deb [arch=amd64 signed-by=/usr/share/keyrings/x.gpg] http://deb.debian.org/debian-security bookworm-security main contrib # note
deb-src http://deb.debian.org/debian bookworm main
#deb http://example.org/disabled bookworm main
EOF
    cat > "$tmp/debian.sources" <<'EOF'
Types: deb
URIs: http://deb.debian.org/debian
Suites: bookworm bookworm-updates
Components: main
Signed-By: /usr/share/keyrings/debian-archive-keyring.gpg

# a disabled stanza
Types: deb
URIs: http://example.org/off
Suites: bookworm
Components: main
Enabled: no

Types: deb-src
URIs: http://example.org/sources-only
Suites: bookworm
Components: main

types: deb deb-src
uris: http://mirror.example.org/debian
suites: trixie
components: main non-free
signed-by:
 -----BEGIN PGP PUBLIC KEY BLOCK-----
 .
 -----END PGP PUBLIC KEY BLOCK-----
EOF
    cat > "$tmp/want.list" <<'EOF'
deb-src http://deb.debian.org/debian bookworm main
deb-src [arch=amd64 signed-by=/usr/share/keyrings/x.gpg] http://deb.debian.org/debian-security bookworm-security main contrib
EOF
    cat > "$tmp/want.sources" <<'EOF'
deb-src [signed-by=/usr/share/keyrings/debian-archive-keyring.gpg] http://deb.debian.org/debian bookworm main
deb-src [signed-by=/usr/share/keyrings/debian-archive-keyring.gpg] http://deb.debian.org/debian bookworm-updates main
deb-src http://mirror.example.org/debian trixie main non-free
EOF
    (. "$root/scripts/deps.sh" && deb_src_entries "$tmp/sources.list") > "$tmp/got.list" &&
        (. "$root/scripts/deps.sh" && deb_src_entries "$tmp/debian.sources") > "$tmp/got.sources" &&
        diff "$tmp/want.list" "$tmp/got.list" >&2 &&
        diff "$tmp/want.sources" "$tmp/got.sources" >&2
}

# A model too large (or small) for single-precision ray tests is warned of;
# bench refuses a --scale that makes one (every ray would miss, silently).
sizes_out_of_range_are_said() {
    printf 'v 0 0 0\nv 1e13 0 0\nv 0 1e13 0\nf 1 2 3\n' > "$tmp/huge.obj"
    "$arbord" stats --model "$tmp/huge.obj" --builder sah 2>"$tmp/huge.err" >/dev/null || fail "stats of huge.obj failed"
    grep -q "outside .* where single-precision ray tests stay exact" "$tmp/huge.err" ||
        fail "no warning for a model 1.4e13 across: $(cat "$tmp/huge.err")"
    "$arbord" stats --model "$model" --builder sah 2>"$tmp/cornell.err" >/dev/null || fail "stats of cornell failed"
    ! grep -q "single-precision" "$tmp/cornell.err" || fail "cornell warned of: $(cat "$tmp/cornell.err")"
    local rc=0
    "$arbord" bench --model "$model" --accel bvh --builder sah --runs 1 --scale 17592186044416 \
        >"$tmp/scaled.out" 2>"$tmp/scaled.err" || rc=$?
    [ "$rc" -ne 0 ] || fail "bench --scale 2^44 exited 0: $(cat "$tmp/scaled.out")"
    grep -q "single-precision" "$tmp/scaled.err" || fail "bench --scale 2^44 said: $(cat "$tmp/scaled.err")"
}

# A model's file name may hold any bytes: JSON stays UTF-8, CSV stays one
# cell per field.
odd_names_stay_machine_readable() {
    local odd
    odd="$tmp/$(printf 'a,b"c\377')".obj
    cp "$model" "$odd"
    "$arbord" stats --model "$odd" --builder sah --json 2>/dev/null > "$tmp/odd.json" || fail "stats --json failed"
    "$arbord" bench --model "$odd" --accel bvh --builder sah --runs 1 --format csv 2>/dev/null > "$tmp/odd.csv" ||
        fail "bench --format csv failed"
    python3 - "$tmp/odd.json" "$tmp/odd.csv" <<'EOF'
import csv, json, sys
rows = [json.loads(l) for l in open(sys.argv[1], encoding="utf-8", errors="strict") if l.strip()]
assert rows and all("a,b\"c?" in r["model"] for r in rows), rows
table = list(csv.reader(open(sys.argv[2], encoding="utf-8", errors="replace")))
assert len(table) == 2 and len(table[1]) == len(table[0]) and table[1][0].startswith('a,b"c'), table
EOF
}

# A model that cannot be loaded among several: said, the others measured and
# printed, exit 1.
bench_reports_the_models_it_could() {
    local rc=0
    "$arbord" bench --model "$tmp/no-such.obj" --model "$model" --accel bvh --builder sah --runs 1 --format csv \
        >"$tmp/some.csv" 2>"$tmp/some.err" || rc=$?
    [ "$rc" -eq 1 ] || fail "exit $rc, expected 1"
    grep -q "no-such.obj" "$tmp/some.err" || fail "the failing model is not named: $(cat "$tmp/some.err")"
    [ "$(grep -c '^cornell.obj,' "$tmp/some.csv")" -eq 1 ] || fail "cornell's row missing: $(cat "$tmp/some.csv")"
}

# gen on a full disk: exit 1, and neither half a model nor a material
# library without its model left behind (needs root for a small tmpfs).
gen_on_a_full_disk_leaves_nothing() {
    local mnt=$tmp/full rc=0
    mkdir -p "$mnt"
    mount -t tmpfs -o size=16k tmpfs "$mnt" || fail "cannot mount a tmpfs"
    "$arbord" gen menger --level 3 -o "$mnt/m.obj" 2>"$tmp/gen.err" || rc=$?
    local left
    left=$(ls -A "$mnt")
    umount "$mnt"
    [ "$rc" -eq 1 ] || fail "gen on a full disk exited $rc"
    grep -q "No space left" "$tmp/gen.err" || fail "gen said: $(cat "$tmp/gen.err")"
    [ -z "$left" ] || fail "gen left on the full disk: $left"
}

[ -x "$arbord" ] || { echo "tests/cli/run.sh: no arbord at $arbord (set ARBORD)"; echo "1 Tests 1 Failures 0 Ignored"; exit 1; }
check output_errors_fail output_errors_fail
check render_refuses_other_extensions render_refuses_other_extensions
check one_value_options_refuse_a_second one_value_options_refuse_a_second
check render_never_removes_what_it_did_not_make render_never_removes_what_it_did_not_make
check ranges_are_the_apis ranges_are_the_apis
check all_is_every_name all_is_every_name
check serve_refuses_a_web_folder_it_cannot_read serve_refuses_a_web_folder_it_cannot_read
check threads_zero_is_documented threads_zero_is_documented
check json_keys_stay json_keys_stay
check embree_isa_is_checked_and_reported embree_isa_is_checked_and_reported
check embree_robust_row embree_robust_row
check bench_tables_read_bench_output bench_tables_read_bench_output
check deps_reads_both_apt_formats deps_reads_both_apt_formats
check sizes_out_of_range_are_said sizes_out_of_range_are_said
check odd_names_stay_machine_readable odd_names_stay_machine_readable
check bench_reports_the_models_it_could bench_reports_the_models_it_could
ignored=0
if [ "$(id -u)" -eq 0 ]; then
    check gen_on_a_full_disk_leaves_nothing gen_on_a_full_disk_leaves_nothing
else
    tests=$((tests + 1)) ignored=$((ignored + 1))
    echo "tests/cli/run.sh:gen_on_a_full_disk_leaves_nothing:IGNORE (needs root to mount a tmpfs)"
fi
echo
echo "-----------------------"
echo "$tests Tests $failures Failures $ignored Ignored"
[ "$failures" -eq 0 ]
