#!/usr/bin/env bash
# Installs what arbor needs to build and test on Debian (run as root):
# the -dev packages it links against, and Unity, the C unit test framework,
# unpacked from Debian's cJSON source package (Unity is not packaged as a
# library). Quick and silent when everything is already present.
#
#   scripts/deps.sh            build + test dependencies
#   scripts/deps.sh --embree   also Intel Embree, the benchmark peer
set -euo pipefail

root=$(cd "$(dirname "$0")/.." && pwd)
unity_dir="$root/build/deps/unity"
pkgs=(build-essential pkg-config libmicrohttpd-dev libcjson-dev libpng-dev zlib1g-dev)
want_embree=0
for arg in "$@"; do
    case "$arg" in
        --embree) want_embree=1 ;;
        *) echo "deps.sh: unknown option '$arg' (use --embree)" >&2; exit 2 ;;
    esac
done
[ "$want_embree" = 1 ] && pkgs+=(libembree-dev)

missing=()
for p in "${pkgs[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done

apt_updated=0
apt_update() {
    [ "$apt_updated" = 1 ] && return
    echo "deps: apt-get update"
    apt-get update -qq
    apt_updated=1
}

if [ "${#missing[@]}" -gt 0 ]; then
    if [ "$(id -u)" != 0 ]; then
        echo "deps: missing packages ${missing[*]}; run scripts/deps.sh as root" >&2
        exit 1
    fi
    apt_update
    echo "deps: installing ${missing[*]}"
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null
fi

# Unity: Debian's cjson source package carries it in tests/unity/src. Fetch the
# source with a private sources list (deb-src of the system's own suites) so the
# system's apt configuration is left untouched.
if [ ! -f "$unity_dir/src/unity.c" ] || [ ! -f "$unity_dir/examples/unity_config.h" ]; then
    work="$root/build/deps/apt-src"
    rm -rf "$work"
    mkdir -p "$work/sources.list.d" "$work/lists/partial" "$work/get"
    sed 's/^Types:.*/Types: deb-src/' /etc/apt/sources.list.d/debian.sources \
        > "$work/sources.list.d/debian-src.sources"
    : > "$work/empty.list"
    opts=(-o "Dir::Etc::SourceList=$work/empty.list"
          -o "Dir::Etc::SourceParts=$work/sources.list.d"
          -o "Dir::State::Lists=$work/lists")
    echo "deps: fetching Unity from Debian's cjson source package"
    apt-get "${opts[@]}" update -qq
    # apt warns that it downloads unsandboxed as root; that is expected here
    (cd "$work/get" && apt-get "${opts[@]}" source --download-only -qq cjson 2>&1 >/dev/null |
        grep -v 'unsandboxed as root' >&2 || true)
    orig=$(ls "$work"/get/cjson_*.orig.tar.gz | head -n 1)
    rm -rf "$unity_dir"
    mkdir -p "$unity_dir"
    # unity_internals.h includes ../examples/unity_config.h, so keep both folders
    tar -xzf "$orig" -C "$unity_dir" --strip-components=3 --wildcards \
        '*/tests/unity/src/*' '*/tests/unity/examples/unity_config.h'
    rm -rf "$work"
    echo "deps: Unity in ${unity_dir#$root/}"
fi
