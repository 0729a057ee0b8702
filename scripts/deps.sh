#!/usr/bin/env bash
# Installs what arbor needs to build and test on Debian (run as root):
# the -dev packages it links against, the tools the HTTP, load and cluster
# tests use (nginx among them), and Unity, the C unit test framework,
# unpacked from Debian's cJSON source package (Unity is not packaged as a
# library). Quick and silent when everything is already present.
#
#   scripts/deps.sh            build + test dependencies
#   scripts/deps.sh --embree   also Intel Embree, the benchmark peer
#   scripts/deps.sh --fuzz     also clang and its libFuzzer runtime (make fuzz)
#   scripts/deps.sh --lint     also cppcheck and clang-tidy (make lint)
#
# Sourced (. scripts/deps.sh) it only defines its functions, for the tests.

# Prints a deb-src line ("deb-src [signed-by=K] URI SUITE COMPONENTS") for
# every deb entry of an apt sources file, in either format apt reads: the
# one-line format of /etc/apt/sources.list and *.list ("deb [opts] URI
# suite comps", '#' starting a comment), or the deb822 stanzas of *.sources
# (Types, URIs, Suites, Components, Signed-By, Enabled), the default since
# Debian 12 where debootstrap still writes the classic sources.list. A
# Signed-By that is an inline key block rather than a keyring path is left
# out (apt then checks against its trusted keyrings).
deb_src_entries() {
    case "$1" in
        *.sources) awk '
            function flush(   i, j, nu, ns, u, su, opt) {
                if (types ~ /(^|[ \t])deb([ \t]|$)/ && tolower(enabled) != "no") {
                    nu = split(uris, u, /[ \t]+/)
                    ns = split(suites, su, /[ \t]+/)
                    opt = signed != "" ? "[signed-by=" signed "] " : ""
                    for (i = 1; i <= nu; i++)
                        for (j = 1; j <= ns; j++)
                            if (u[i] != "" && su[j] != "")
                                print "deb-src " opt u[i] " " su[j] (comps != "" ? " " comps : "")
                }
                types = uris = suites = comps = signed = enabled = ""
            }
            /^[ \t]*#/ { next }
            /^[ \t]*$/ { flush(); next }
            /^[ \t]/ { next }  # a continuation line: part of an inline key
            {
                colon = index($0, ":")
                key = tolower(substr($0, 1, colon - 1))
                val = substr($0, colon + 1)
                gsub(/^[ \t]+|[ \t]+$/, "", val)
                if (key == "types") types = val
                else if (key == "uris") uris = val
                else if (key == "suites") suites = val
                else if (key == "components") comps = val
                else if (key == "enabled") enabled = val
                else if (key == "signed-by") signed = val ~ /^\// ? val : ""
            }
            END { flush() }' "$1" ;;
        *) awk '{ sub(/#.*/, "") } $1 == "deb" { $1 = "deb-src"; print }' "$1" ;;
    esac
}

# deb-src entries for everything apt is configured with, in both formats.
apt_deb_src_entries() {
    local f
    for f in /etc/apt/sources.list /etc/apt/sources.list.d/*.list /etc/apt/sources.list.d/*.sources; do
        [ -f "$f" ] && deb_src_entries "$f"
    done | sort -u
}

main() {
    set -euo pipefail

    root=$(cd "$(dirname "$0")/.." && pwd)
    unity_dir="$root/build/deps/unity"
    # build, then the HTTP tests (python3, prometheus client, curl), load tests (wrk)
    # and cluster tests (nginx in front, network namespaces by ip: tests/cluster)
    pkgs=(build-essential pkg-config libmicrohttpd-dev libcjson-dev libpng-dev zlib1g-dev
          python3 python3-prometheus-client curl wrk nginx iproute2)
    for arg in "$@"; do
        case "$arg" in
            --embree) pkgs+=(libembree-dev) ;;
            --fuzz) pkgs+=(clang libclang-rt-14-dev) ;;
            --lint) pkgs+=(cppcheck clang-tidy) ;;
            *) echo "deps.sh: unknown option '$arg' (use --embree, --fuzz or --lint)" >&2; exit 2 ;;
        esac
    done

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
    # source with a private sources list (deb-src of the system's own entries) so the
    # system's apt configuration is left untouched.
    if [ ! -f "$unity_dir/src/unity.c" ] || [ ! -f "$unity_dir/examples/unity_config.h" ]; then
        work="$root/build/deps/apt-src"
        rm -rf "$work"
        mkdir -p "$work/sources.list.d" "$work/lists/partial" "$work/get"
        apt_deb_src_entries > "$work/sources.list"
        if [ ! -s "$work/sources.list" ]; then
            echo "deps: no deb entries in /etc/apt/sources.list or /etc/apt/sources.list.d; cannot fetch Unity" >&2
            exit 1
        fi
        opts=(-o "Dir::Etc::SourceList=$work/sources.list"
              -o "Dir::Etc::SourceParts=$work/sources.list.d"
              -o "Dir::State::Lists=$work/lists")
        echo "deps: fetching Unity from Debian's cjson source package"
        # A third-party repository without sources fails its part of the update;
        # Debian's own suites are what matter, and apt-get source says if cjson is missing.
        apt-get "${opts[@]}" update -qq || echo "deps: some deb-src indexes could not be fetched; trying anyway" >&2
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
}

if [ "${BASH_SOURCE[0]}" = "$0" ]; then
    main "$@"
fi
