#!/usr/bin/env bash
# The PostgreSQL 15 the service suites' "pg." variants run on (a ctest fixture): a cluster made
# with initdb in a temporary folder and started with pg_ctl on a free loopback port, as an
# unprivileged user (postgres, when run as root: initdb refuses root).
#
#   postgres.sh start STATE   writes the cluster's admin URL to STATE (and its folder to STATE.dir)
#   postgres.sh stop STATE    stops the cluster and removes its folder
set -euo pipefail
cmd="${1:?usage: postgres.sh start|stop STATE}"
state="${2:?usage: postgres.sh start|stop STATE}"
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
  rm -rf "$dir" "$state" "$state.dir"
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
    # fsync off: a test cluster that dies is made again; 300 connections: brenierds of parallel tests.
    as_user "$BIN/pg_ctl" -D "$dir/cluster" -l "$dir/server.log" -w -t 60 \
      -o "-p $port -k $dir -c listen_addresses=127.0.0.1 -c fsync=off -c max_connections=300" start > /dev/null ||
      { cat "$dir/server.log" >&2; exit 1; }
    echo "postgresql://brenier@127.0.0.1:$port/postgres" > "$state"
    echo "PostgreSQL on port $port ($dir)"
    ;;
  stop) stop ;;
  *) echo "postgres.sh: start or stop, not '$cmd'" >&2; exit 2 ;;
esac
