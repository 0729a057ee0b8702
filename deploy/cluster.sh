#!/usr/bin/env bash
# deploy/cluster.sh - N arbord daemons behind Debian's nginx on this machine
# (make cluster N=4; tests/cluster). See docs/SCALE.md.
#
# Each daemon is a host of its own: a network namespace made here, joined to
# this machine by a veth pair holding a /30 of 10.77.X.0/24, X a subnet no
# interface or route here uses yet. Where namespaces cannot be made (not
# root, or a container that forbids it) the daemons listen on loopback
# ports instead. nginx (Debian's package, installed when missing) listens on
# 127.0.0.1:PORT and spreads requests over them with
# deploy/nginx.conf.template. Every daemon serves one models folder,
# STATE/models (seeded with copies of the repository's models/: the loader
# refuses a material library that resolves outside the model's folder, so
# links would lose their .mtl), as hosts would share one over NFS.
#
# A daemon that exits is started again, as systemd's Restart= does, so a
# node that is killed rejoins. Ctrl-C (SIGINT) or SIGTERM stops every
# daemon and nginx and removes every namespace and link made here.
#
#   deploy/cluster.sh [-n N] [--port P] [--threads T] [--state DIR] [--loopback]
#                     [--prebuild LIST] [--models-from DIR]
#
# ARBORD names the binary (default build/arbord). Once every node is ready it
# prints the URL; STATE/nodes then lists "index address port pid namespace"
# per daemon (updated when one restarts) and STATE/nginx/access.log shows which
# node answered each request.
set -uo pipefail

repo=$(cd "$(dirname "$0")/.." && pwd)
n=4
port=8080
threads=1
state="$repo/build/cluster-state"
mode=auto
prebuild=bvh:sah
seed="$repo/models"
arbord=${ARBORD:-$repo/build/arbord}

usage() {
    sed -n '2,/^set -uo/p' "$0" | sed '$d; s/^# \{0,1\}//'
}

while [ $# -gt 0 ]; do
    case "$1" in
        -n) n=$2; shift 2 ;;
        --port) port=$2; shift 2 ;;
        --threads) threads=$2; shift 2 ;;
        --state) state=$2; shift 2 ;;
        --loopback) mode=loopback; shift ;;
        --prebuild) prebuild=$2; shift 2 ;;
        --models-from) seed=$2; shift 2 ;;
        -h|--help) usage; exit 0 ;;
        *) echo "cluster.sh: unknown option '$1' (see --help)" >&2; exit 2 ;;
    esac
done
case "$n" in ''|*[!0-9]*) echo "cluster.sh: -n takes 1..60, not '$n'" >&2; exit 2 ;; esac
[ "$n" -ge 1 ] && [ "$n" -le 60 ] || { echo "cluster.sh: -n takes 1..60, not '$n'" >&2; exit 2; }
[ -x "$arbord" ] || { echo "cluster.sh: no executable $arbord (make first, or set ARBORD)" >&2; exit 2; }

say() { echo "arbor cluster: $*"; }

# ---- nginx, installed when missing

nginx=/usr/sbin/nginx
if [ ! -x "$nginx" ]; then
    [ "$(id -u)" = 0 ] || { echo "cluster.sh: nginx is not installed (as root: apt-get install nginx)" >&2; exit 2; }
    say "installing Debian's nginx"
    DEBIAN_FRONTEND=noninteractive apt-get install -y -q nginx >/dev/null ||
        { echo "cluster.sh: apt-get install nginx failed" >&2; exit 2; }
fi

# ---- names, addresses, the shared folder

tag="arb$(($$ % 100000))"
mkdir -p "$state/models" "$state/nginx"
state=$(cd "$state" && pwd)
if [ -z "$(ls -A "$state/models")" ]; then
    for f in "$seed"/*.obj "$seed"/*.obj.gz "$seed"/*.ply "$seed"/*.ply.gz "$seed"/*.mtl; do
        [ -e "$f" ] && cp "$f" "$state/models/"
    done
fi
[ -s "$state/token" ] || (umask 077 && head -c 18 /dev/urandom | base64 | tr -d '/+=' >"$state/token")

if [ "$mode" = auto ]; then
    mode=loopback
    if [ "$(id -u)" = 0 ] && ip netns add "$tag-probe" 2>/dev/null; then
        ip netns del "$tag-probe"
        mode=netns
    fi
fi

# A 10.77.X.0/24 that no address or route of this machine touches.
pick_subnet() {
    local used x
    used=$( (ip -4 addr show; ip -4 route show) 2>/dev/null)
    for x in $(seq $(($$ % 200 + 20)) 254) $(seq 1 $(($$ % 200 + 19))); do
        if ! grep -q "10\.77\.$x\." <<<"$used"; then
            echo "$x"
            return 0
        fi
    done
    return 1
}

if [ "$mode" = netns ]; then
    subnet=$(pick_subnet) || { echo "cluster.sh: no free 10.77.X.0/24 subnet" >&2; exit 2; }
fi

# Node i: its address and port, as nginx and the tests reach it.
node_addr() { if [ "$mode" = netns ]; then echo "10.77.$subnet.$((4 * $1 + 2))"; else echo 127.0.0.1; fi; }
node_port() { if [ "$mode" = netns ]; then echo 8080; else echo $((port + 1 + $1)); fi; }
node_ns() { echo "$tag-n$1"; }

pids=()
nginx_pid=
stopping=

# ---- stopping: every process and every namespace made here

cleanup() {
    trap - INT TERM EXIT
    stopping=1
    local i p deadline
    [ -n "$nginx_pid" ] && kill -QUIT "$nginx_pid" 2>/dev/null
    for p in "${pids[@]}"; do kill -TERM "$p" 2>/dev/null; done
    deadline=$((SECONDS + 10))
    for p in "${pids[@]}" $nginx_pid; do
        while kill -0 "$p" 2>/dev/null && [ $SECONDS -lt $deadline ]; do sleep 0.1; done
        kill -KILL "$p" 2>/dev/null
    done
    if [ "$mode" = netns ]; then
        for ((i = 0; i < n; i++)); do
            for p in $(ip netns pids "$(node_ns $i)" 2>/dev/null); do kill -KILL "$p" 2>/dev/null; done
            ip link del "${tag}v$i" 2>/dev/null
            ip netns del "$(node_ns $i)" 2>/dev/null
        done
    fi
    wait 2>/dev/null
    rm -f "$state/nodes"
    say "stopped"
}
trap 'cleanup; exit 0' INT TERM
trap cleanup EXIT

# ---- the hosts

make_host() {
    local i=$1 ns host_if="${tag}v$1"
    ns=$(node_ns "$i")
    ip netns add "$ns" &&
        ip link add "$host_if" type veth peer name eth0 netns "$ns" &&
        ip addr add "10.77.$subnet.$((4 * i + 1))/30" dev "$host_if" &&
        ip link set "$host_if" up &&
        ip -n "$ns" link set lo up &&
        ip -n "$ns" addr add "$(node_addr "$i")/30" dev eth0 &&
        ip -n "$ns" link set eth0 up
}

write_nodes() {
    local i
    for ((i = 0; i < n; i++)); do
        echo "$i $(node_addr $i) $(node_port $i) ${pids[$i]} $([ "$mode" = netns ] && node_ns $i || echo -)"
    done >"$state/nodes.tmp" && mv "$state/nodes.tmp" "$state/nodes"
}

start_node() {
    local i=$1 cmd=()
    [ "$mode" = netns ] && cmd=(ip netns exec "$(node_ns "$i")")
    cmd+=("$arbord" serve --bind "$(node_addr "$i")" --port "$(node_port "$i")" --models "$state/models"
          --web "$repo/web" --threads "$threads" --prebuild "$prebuild" --token-file "$state/token")
    "${cmd[@]}" >>"$state/node$i.log" 2>&1 </dev/null &
    pids[$i]=$!
}

status_of() {
    curl -s -o /dev/null -w '%{http_code}' --max-time 2 "http://$1/$2" 2>/dev/null
}

for ((i = 0; i < n; i++)); do
    if [ "$mode" = netns ]; then
        make_host "$i" || { echo "cluster.sh: cannot make host $i's namespace and link" >&2; exit 1; }
    fi
    : >"$state/node$i.log"
    start_node "$i"
done
write_nodes

servers=$(for ((i = 0; i < n; i++)); do
    echo "        server $(node_addr $i):$(node_port $i) max_fails=1 fail_timeout=3s;"
done)
printf '%s\n' "$servers" >"$state/nginx/servers"
sed -e '/^#/d' -e "s|@PREFIX@|$state/nginx|g" -e "s|@LISTEN@|127.0.0.1:$port|g" \
    -e "s|@LOCAL_AUTH@|Bearer $(cat "$state/token")|g" \
    -e "/^[[:space:]]*@SERVERS@[[:space:]]*\$/{
r $state/nginx/servers
d
}" "$repo/deploy/nginx.conf.template" >"$state/nginx/nginx.conf"
"$nginx" -c "$state/nginx/nginx.conf" -p "$state/nginx" -g 'daemon off;' >>"$state/nginx/error.log" 2>&1 &
nginx_pid=$!

# ---- ready: every node's /readyz, and nginx answering

deadline=$((SECONDS + 300))
for ((i = 0; i < n; i++)); do
    while [ "$(status_of "$(node_addr $i):$(node_port $i)" readyz)" != 200 ]; do
        kill -0 "${pids[$i]}" 2>/dev/null || { echo "cluster.sh: node $i exited; its log:" >&2; tail -5 "$state/node$i.log" >&2; exit 1; }
        [ $SECONDS -lt $deadline ] || { echo "cluster.sh: node $i not ready after 300 s" >&2; exit 1; }
        sleep 0.2
    done
done
while [ "$(status_of "127.0.0.1:$port" healthz)" != 200 ]; do
    kill -0 "$nginx_pid" 2>/dev/null || { echo "cluster.sh: nginx exited:" >&2; tail -5 "$state/nginx/error.log" >&2; exit 1; }
    sleep 0.2
done
where=$([ "$mode" = netns ] && echo "hosts 10.77.$subnet.x in network namespaces" || echo "loopback ports")
say "$n daemons ($where, --threads $threads) behind nginx: open http://127.0.0.1:$port/ (Ctrl-C stops it)"

# ---- watching: a daemon that exits starts again (it rejoins once ready)

while :; do
    kill -0 "$nginx_pid" 2>/dev/null || { echo "cluster.sh: nginx exited" >&2; exit 1; }
    for ((i = 0; i < n; i++)); do
        if [ -z "$stopping" ] && ! kill -0 "${pids[$i]}" 2>/dev/null; then
            say "node $i ($(node_addr $i):$(node_port $i)) exited; starting it again"
            start_node "$i"
            write_nodes
        fi
    done
    sleep 0.3 &
    wait $! 2>/dev/null
done
