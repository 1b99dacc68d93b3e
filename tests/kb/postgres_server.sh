#!/bin/sh
# A throw-away PostgreSQL server for the tests (kb suite on the PostgreSQL back end, concurrency tests).
#
#   postgres_server.sh start DIR   initdb into DIR/data, start on a free loopback port with the unix
#                                  socket in DIR; writes DIR/url (postgresql://formloop@127.0.0.1:PORT/postgres)
#   postgres_server.sh stop DIR    pg_ctl stop -m fast, then removes DIR
#
# initdb and the server refuse to run as root. As root (CI containers) they run as the unprivileged
# `postgres` user that Debian's postgresql package creates, through runuser(1); DIR is handed to that
# user. As any other user they run as that user. Trust authentication on loopback and the socket only:
# the server is private to the test run and gone afterwards. fsync is off (a test server's data need
# not survive a power cut).
set -eu
command=${1:?usage: postgres_server.sh start|stop DIR}
dir=$(realpath -m "${2:?usage: postgres_server.sh start|stop DIR}")
bin=${FORMLOOP_PG_BIN:-/usr/lib/postgresql/15/bin}

as_server_user() {
  if [ "$(id -u)" = 0 ]; then runuser -u postgres -- "$@"; else "$@"; fi
}

case "$command" in
  start)
    if [ -f "$dir/url" ] && as_server_user "$bin/pg_ctl" -D "$dir/data" status >/dev/null 2>&1; then
      exit 0  # already running (a rerun of the fixture)
    fi
    rm -rf "$dir"
    mkdir -p "$dir"
    if [ "$(id -u)" = 0 ]; then
      chown postgres "$dir"
      # The server user must reach DIR (and its socket) through every parent folder.
      if ! runuser -u postgres -- test -x "$dir"; then
        echo "postgres_server.sh: the postgres user cannot enter $dir (a parent folder is not searchable)" >&2
        exit 1
      fi
    fi
    as_server_user "$bin/initdb" -D "$dir/data" -U formloop --auth=trust --no-sync -E UTF8 --locale=C \
      >"$dir/initdb.log" 2>&1 || { cat "$dir/initdb.log" >&2; exit 1; }
    # A free port: bind to port 0 and ask the kernel which one it gave. Retried if another process takes
    # it between here and the server's bind.
    for attempt in 1 2 3 4 5; do
      port=$(python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
      if as_server_user "$bin/pg_ctl" -D "$dir/data" -l "$dir/server.log" -w -t 60 \
        -o "-p $port -k $dir -c listen_addresses=127.0.0.1 -c fsync=off -c synchronous_commit=off -c max_connections=100" \
        start >/dev/null; then
        echo "postgresql://formloop@127.0.0.1:$port/postgres" >"$dir/url.tmp"
        mv "$dir/url.tmp" "$dir/url"
        exit 0
      fi
    done
    cat "$dir/server.log" >&2
    exit 1
    ;;
  stop)
    if [ -d "$dir/data" ]; then as_server_user "$bin/pg_ctl" -D "$dir/data" -m fast -w stop >/dev/null 2>&1 || true; fi
    rm -rf "$dir"
    ;;
  *)
    echo "usage: postgres_server.sh start|stop DIR" >&2
    exit 2
    ;;
esac
