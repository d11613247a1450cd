"""Engine and session factories.

SQLite gets the settings it needs to serve a threaded web app from one file: WAL (readers do
not block the writer), foreign keys (``ON DELETE CASCADE``), a busy timeout, and real
transactions — the ``sqlite3`` driver's legacy mode would not BEGIN before SELECT or DDL, so
SQLAlchemy emits BEGIN itself (the recipe of the SQLAlchemy SQLite documentation). Write
sessions begin with ``BEGIN IMMEDIATE`` so they take the write lock up front instead of failing
when a read transaction is upgraded.

Durability: ``synchronous=FULL`` by default, so the WAL is fsynced at every commit and a write
the service acknowledged (a 201, a 204) survives an OS crash or a power cut; the stored files'
renames ride in the same file-system journal commit (``app.services.blobs``). ``NORMAL``
(``MOCAP_SQLITE_SYNCHRONOUS``) syncs only at checkpoints: faster, but the last commits before a
power loss can roll back (bench/README.md measures the difference on the import).

PostgreSQL goes through psycopg 3 (the ``postgres`` extra): a plain ``postgresql://`` URL
means ``postgresql+psycopg://``. The pool holds at most 20 connections per process (searches
read no SQL: they answer from memory), so a handful of replicas fit in PostgreSQL's default
``max_connections`` of 100.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from sqlalchemy import Engine, create_engine, event
from sqlalchemy.engine import make_url
from sqlalchemy.orm import Session, sessionmaker

SQLITE_BUSY_TIMEOUT_MS = 30_000
POOL_SIZE = 5
POOL_OVERFLOW = 15
SYNCHRONOUS_MODES = ("FULL", "NORMAL")


def create_db_engine(url: str, *, synchronous: str = "FULL") -> Engine:
    """An engine for ``url``; for SQLite the parent directory of the file is created and
    ``synchronous`` (``FULL`` or ``NORMAL``) is SQLite's commit durability."""
    parsed = make_url(url)
    if parsed.drivername == "postgresql":
        parsed = parsed.set(drivername="postgresql+psycopg")
    if parsed.get_backend_name() != "sqlite":
        return create_engine(
            parsed, pool_pre_ping=True, pool_size=POOL_SIZE, max_overflow=POOL_OVERFLOW
        )

    database = parsed.database or ""
    if database in ("", ":memory:") or database.startswith("file:"):
        raise ValueError(
            "use a SQLite file (in-memory databases are per connection and lose the schema)"
        )
    mode = synchronous.upper()
    if mode not in SYNCHRONOUS_MODES:
        raise ValueError(f"synchronous: one of {', '.join(SYNCHRONOUS_MODES)}, not {synchronous!r}")
    Path(database).parent.mkdir(parents=True, exist_ok=True)
    engine = create_engine(
        url, connect_args={"check_same_thread": False, "timeout": SQLITE_BUSY_TIMEOUT_MS / 1000}
    )

    @event.listens_for(engine, "connect")
    def _on_connect(dbapi_connection: Any, _record: Any) -> None:
        dbapi_connection.isolation_level = None  # we emit BEGIN ourselves, below
        cursor = dbapi_connection.cursor()
        cursor.execute("PRAGMA journal_mode=WAL")
        cursor.execute("PRAGMA foreign_keys=ON")
        cursor.execute(f"PRAGMA busy_timeout={SQLITE_BUSY_TIMEOUT_MS}")
        cursor.execute(f"PRAGMA synchronous={mode}")  # FULL: every commit reaches the disk
        cursor.close()

    @event.listens_for(engine, "begin")
    def _on_begin(connection: Any) -> None:
        mode = connection.get_execution_options().get("sqlite_begin", "DEFERRED")
        connection.exec_driver_sql(f"BEGIN {mode}")

    return engine


def read_sessions(engine: Engine) -> sessionmaker[Session]:
    """Sessions for requests that only read (many may run at once)."""
    return sessionmaker(bind=engine, expire_on_commit=False)


def write_sessions(engine: Engine) -> sessionmaker[Session]:
    """Sessions for writes: on SQLite they take the database write lock when they begin."""
    bind = engine.execution_options(sqlite_begin="IMMEDIATE")
    return sessionmaker(bind=bind, expire_on_commit=False)


def checkpoint(engine: Engine) -> None:
    """SQLite: fold the write-ahead log into the database file (after a bulk load, so the next
    readers do not wade through a large log). Nothing elsewhere. Runs outside a transaction."""
    if engine.dialect.name != "sqlite":
        return
    raw = engine.raw_connection()
    try:
        cursor = raw.cursor()
        cursor.execute("PRAGMA wal_checkpoint(TRUNCATE)")
        cursor.close()
    finally:
        raw.close()
