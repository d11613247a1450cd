#!/usr/bin/env bash
# Install what the PostgreSQL tests need, idempotently: Debian's PostgreSQL 15 server
# binaries (/usr/lib/postgresql/15/bin) with apt-get, when they are missing. The tests start
# their own throwaway server in a temporary directory; this script never starts one, and
# stops the cluster the Debian package may create at install time.
#
# The Python driver (psycopg 3) comes with `pip install -e '.[dev]'` (the `postgres` extra).
# Usage: scripts/install_postgres.sh     Non-interactive; safe to run again.
set -euo pipefail

BIN=/usr/lib/postgresql/15/bin
if [[ -x "$BIN/initdb" && -x "$BIN/pg_ctl" ]]; then
    echo "install_postgres: PostgreSQL 15 already installed ($BIN)"
    exit 0
fi

SUDO=()
if [[ $(id -u) -ne 0 ]]; then
    if command -v sudo >/dev/null 2>&1; then SUDO=(sudo -n); else
        echo "install_postgres: not root and no sudo; install postgresql-15 by hand" >&2
        exit 1
    fi
fi
echo "install_postgres: apt-get install postgresql-15"
export DEBIAN_FRONTEND=noninteractive
"${SUDO[@]}" apt-get update -q
"${SUDO[@]}" apt-get install -y -q --no-install-recommends postgresql-15
# The package may start a system cluster (where services start); the tests do not use it.
if command -v pg_ctlcluster >/dev/null 2>&1; then
    "${SUDO[@]}" pg_ctlcluster 15 main stop 2>/dev/null || true
fi
"$BIN/initdb" --version
