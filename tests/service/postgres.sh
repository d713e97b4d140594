#!/usr/bin/env bash
# The PostgreSQL 15 the service suites' "pg." variants run on (a ctest fixture): a cluster made
# with initdb in a temporary folder and started with pg_ctl on a free loopback port, as an
# unprivileged user (postgres, when run as root: initdb refuses root).
#
#   postgres.sh start STATE   writes the cluster's admin URL to STATE (and its folder to STATE.dir)
#   postgres.sh stop STATE    stops the cluster and removes its folder
#   postgres.sh kill STATE    stops it at once, as a crash would (pg_ctl -m immediate), keeping it
#   postgres.sh resume STATE  starts a killed cluster again on its port
set -euo pipefail
cmd="${1:?usage: postgres.sh start|stop|kill|resume STATE}"
state="${2:?usage: postgres.sh start|stop|kill|resume STATE}"
BIN="$(ls -d /usr/lib/postgresql/*/bin 2>/dev/null | sort -V | tail -n 1)"
[[ -x "$BIN/initdb" ]] || { echo "postgres.sh: no PostgreSQL server (apt-get install postgresql-15)" >&2; exit 2; }
as_user() {
  if [[ $(id -u) == 0 ]]; then runuser -u postgres -- "$@"; else "$@"; fi
}
stop() {
  [[ -f "$state.dir" ]] || return 0
  local dir
  dir="$(cat "$state.dir")"
  as_user "$BIN/pg_ctl" -D "$dir/cluster" -m fast -w stop >/dev/null 2>&1 || true
  rm -rf "$dir" "$state" "$state.dir" "$state.port"
}
serve() {  # $1: the cluster's folder, $2: its port
  # fsync off: a test cluster that dies is made again; 300 connections: brenierds of parallel tests.
  as_user "$BIN/pg_ctl" -D "$1/cluster" -l "$1/server.log" -w -t 60 \
    -o "-p $2 -k $1 -c listen_addresses=127.0.0.1 -c fsync=off -c max_connections=300" start > /dev/null ||
    { cat "$1/server.log" >&2; exit 1; }
}
case "$cmd" in
  start)
    stop
    mkdir -p "$(dirname "$state")"
    dir="$(mktemp -d /tmp/brenier-pg-XXXXXX)"
    echo "$dir" > "$state.dir"
    [[ $(id -u) == 0 ]] && chown postgres "$dir"
    as_user "$BIN/initdb" -D "$dir/cluster" -U brenier -A trust --no-sync -E UTF8 > "$dir/initdb.log" 2>&1 ||
      { cat "$dir/initdb.log" >&2; exit 1; }
    port="$(/usr/bin/python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')"
    serve "$dir" "$port"
    echo "$port" > "$state.port"
    echo "postgresql://brenier@127.0.0.1:$port/postgres" > "$state"
    echo "PostgreSQL on port $port ($dir)"
    ;;
  stop) stop ;;
  kill) as_user "$BIN/pg_ctl" -D "$(cat "$state.dir")/cluster" -m immediate -w stop > /dev/null ;;
  resume) serve "$(cat "$state.dir")" "$(cat "$state.port")" ;;
  *) echo "postgres.sh: start, stop, kill or resume, not '$cmd'" >&2; exit 2 ;;
esac
