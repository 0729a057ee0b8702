#!/usr/bin/env bash
# Installs what the browser tests (tests/e2e) need on Debian bookworm, as root:
# Debian's chromium (and a font), node and npm (Debian's nodejs + npm, only when `node` or
# `npm` is not already on PATH), and the pinned npm packages of tests/e2e
# (`npm ci`, when node_modules is missing or older than package-lock.json).
# Quiet: prints nothing when everything is already present. Never downloads a
# browser through npm (playwright-core has no browser of its own).
set -euo pipefail

root=$(cd "$(dirname "$0")/.." && pwd)
e2e="$root/tests/e2e"

missing=()
have_pkg() { dpkg-query -W -f='${Status}' "$1" 2>/dev/null | grep -q "install ok installed"; }
[ -x /usr/bin/chromium ] || missing+=(chromium)
# a font for the page's text in screenshots (chromium only recommends one)
have_pkg fonts-liberation || have_pkg fonts-dejavu-core || missing+=(fonts-liberation)
command -v node >/dev/null 2>&1 || missing+=(nodejs)
command -v npm >/dev/null 2>&1 || missing+=(npm)

if [ "${#missing[@]}" -gt 0 ]; then
    if [ "$(id -u)" != 0 ]; then
        echo "deps-e2e: missing ${missing[*]}; run scripts/deps-e2e.sh as root" >&2
        exit 1
    fi
    echo "deps-e2e: installing ${missing[*]}"
    log=$(mktemp)
    if ! { DEBIAN_FRONTEND=noninteractive apt-get update -qq &&
           DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}"; } \
           >"$log" 2>&1; then
        cat "$log" >&2
        rm -f "$log"
        echo "deps-e2e: apt-get install ${missing[*]} failed" >&2
        exit 1
    fi
    rm -f "$log"
fi

# npm ci when node_modules is missing or older than the lockfile.
stamp="$e2e/node_modules/.package-lock.json"
if [ ! -d "$e2e/node_modules/playwright-core" ] || [ ! -f "$stamp" ] || [ "$e2e/package-lock.json" -nt "$stamp" ]; then
    echo "deps-e2e: npm ci in tests/e2e"
    (cd "$e2e" && PLAYWRIGHT_SKIP_BROWSER_DOWNLOAD=1 npm ci --no-audit --no-fund --loglevel=error >/dev/null) || {
        echo "deps-e2e: npm ci in tests/e2e failed" >&2
        exit 1
    }
    touch "$stamp"
fi
