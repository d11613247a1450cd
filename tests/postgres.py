"""A throwaway PostgreSQL 15 server for the tests: ``initdb`` in a temporary directory,
``pg_ctl`` on a free loopback port, removed when the session ends.

The server runs as an unprivileged user when the tests run as root (PostgreSQL refuses to run
as root): Debian's ``postgres`` user, which the ``postgresql-15`` package creates. Durability is
switched off (``fsync``, ``synchronous_commit``, ``full_page_writes``): a test database never
outlives a crash of the machine, and the suite is faster.

Where PostgreSQL is missing (``make test`` installs it with apt-get:
``scripts/install_postgres.sh``) the tests that need it skip with the reason, unless
``MOCAP_REQUIRE_POSTGRES=1`` or ``CI=true``: then they fail, so CI cannot go green without them.
"""

from __future__ import annotations

import contextlib
import itertools
import os
import pwd
import shutil
import socket
import subprocess
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from sqlalchemy import create_engine, text

VERSION = "15"
SERVICE_USER = "postgres"
TEMPLATE = "mocap_template"


def required() -> bool:
    """Whether a missing PostgreSQL fails the tests instead of skipping them (CI)."""
    return (
        os.environ.get("MOCAP_REQUIRE_POSTGRES") == "1"
        or os.environ.get("CI", "").lower() == "true"
    )


def unavailable(reason: str) -> None:
    if required():
        pytest.fail(f"{reason} (CI / MOCAP_REQUIRE_POSTGRES=1: the PostgreSQL tests must run)")
    pytest.skip(reason)


def bin_dir() -> Path | None:
    """Where ``initdb`` and ``pg_ctl`` of PostgreSQL 15 are (``$MOCAP_PG_BIN`` overrides)."""
    candidates = [os.environ.get("MOCAP_PG_BIN", ""), f"/usr/lib/postgresql/{VERSION}/bin"]
    for candidate in candidates:
        if candidate and (Path(candidate) / "initdb").is_file():
            return Path(candidate)
    return None


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@dataclass
class Cluster:
    """A running PostgreSQL server; :meth:`new_database` hands out fresh databases."""

    bin_dir: Path
    root: Path
    port: int = 0
    user: str | None = None  # the OS user the server runs as (None: this process's)
    _counter: itertools.count[int] = field(default_factory=lambda: itertools.count(1))

    @property
    def data(self) -> Path:
        return self.root / "data"

    def url(self, database: str = "postgres") -> str:
        return f"postgresql+psycopg://postgres@127.0.0.1:{self.port}/{database}"

    def _run(self, *args: str) -> None:
        result = subprocess.run(
            [str(self.bin_dir / args[0]), *args[1:]],
            user=self.user,
            capture_output=True,
            text=True,
            timeout=120,
            cwd=self.root,
        )
        if result.returncode != 0:
            log = self.root / "server.log"
            tail = log.read_text(errors="replace")[-3000:] if log.is_file() else ""
            raise RuntimeError(f"{args[0]} failed: {result.stdout}{result.stderr}\n{tail}")

    def start(self) -> None:
        self.port = _free_port()
        # A throwaway cluster (fsync is off below too): nothing to flush to disk at creation.
        self._run(
            "initdb", "--no-sync", "-D", str(self.data), "-U", "postgres", "--auth=trust",
            "-E", "UTF8",
        )  # fmt: skip
        options = (
            f"-p {self.port} -k {self.root} -c listen_addresses=127.0.0.1 -c fsync=off "
            "-c synchronous_commit=off -c full_page_writes=off -c max_connections=300 "
            "-c shared_buffers=64MB"
        )
        self._run("pg_ctl", "-D", str(self.data), "-l", str(self.root / "server.log"),
                  "-o", options, "-w", "-t", "60", "start")  # fmt: skip
        self._migrate_template()

    def _migrate_template(self) -> None:
        """A database at the newest revision that test databases are copied from (a copy is
        much faster than running the migrations for every test)."""
        from app.db.migrate import upgrade
        from app.db.session import create_db_engine

        self.execute(f"CREATE DATABASE {TEMPLATE}")
        engine = create_db_engine(self.url(TEMPLATE))
        try:
            upgrade(engine)
        finally:
            engine.dispose()

    def execute(self, statement: str) -> None:
        """Run ``statement`` outside a transaction (CREATE/DROP DATABASE) as the superuser."""
        engine = create_engine(self.url(), isolation_level="AUTOCOMMIT", poolclass=None)
        try:
            with engine.connect() as connection:
                connection.execute(text(statement))
        finally:
            engine.dispose()

    def new_database(self, *, migrated: bool = True) -> str:
        """The URL of a new, empty database: at the newest schema revision, or without any
        table (``migrated=False``)."""
        name = f"test_{os.getpid()}_{next(self._counter)}"
        template = TEMPLATE if migrated else "template0"
        self.execute(f"CREATE DATABASE {name} TEMPLATE {template}")
        return self.url(name)

    def stop(self) -> None:
        with contextlib.suppress(Exception):
            self._run("pg_ctl", "-D", str(self.data), "-m", "immediate", "-w", "stop")
        shutil.rmtree(self.root, ignore_errors=True)


def start_cluster() -> Cluster:
    """Start a throwaway server, or skip (fail in CI) saying why it cannot be started."""
    binaries = bin_dir()
    if binaries is None:
        unavailable(
            f"PostgreSQL {VERSION} not found in /usr/lib/postgresql/{VERSION}/bin (install "
            "it with scripts/install_postgres.sh, or set MOCAP_PG_BIN)"
        )
        raise AssertionError("unreachable")
    user = None
    if os.geteuid() == 0:
        try:
            pwd.getpwnam(SERVICE_USER)
        except KeyError:
            unavailable(f"running as root and there is no {SERVICE_USER!r} user to run as")
        user = SERVICE_USER
    root = Path(tempfile.mkdtemp(prefix="mocap-pg-"))
    if user is not None:
        entry = pwd.getpwnam(user)
        os.chown(root, entry.pw_uid, entry.pw_gid)
    cluster = Cluster(binaries, root, user=user)
    try:
        cluster.start()
    except Exception as exc:
        cluster.stop()
        unavailable(f"could not start PostgreSQL: {exc}")
    return cluster
