"""The schema comes only from the Alembic migrations, and they agree with the models — on
SQLite and on PostgreSQL (a fresh database of the session's throwaway server)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from alembic.autogenerate import compare_metadata
from alembic.runtime.migration import MigrationContext
from sqlalchemy import Engine, inspect, text

from app.config import Settings
from app.db.migrate import current_revision, downgrade, head_revision, upgrade
from app.db.models import Base
from app.db.session import create_db_engine
from tests.postgres import Cluster

TABLES = {"clips", "clip_files", "clip_labels", "clip_descriptors", "clip_changes", "blobs"}


@pytest.fixture(params=["sqlite", "postgresql"])
def empty_url(request: pytest.FixtureRequest, settings: Settings) -> str:
    """The URL of a database without any table, on each backend."""
    if request.param == "postgresql":
        cluster: Cluster = request.getfixturevalue("postgres_cluster")
        return cluster.new_database(migrated=False)
    return settings.sqlalchemy_url


@pytest.fixture
def migrated(empty_url: str) -> Iterator[Engine]:
    engine = create_db_engine(empty_url)
    upgrade(engine)
    yield engine
    engine.dispose()


def test_fresh_database_is_migrated_to_head(migrated: Engine) -> None:
    assert current_revision(migrated) == head_revision()
    assert set(inspect(migrated).get_table_names()) >= TABLES


def test_models_match_migrations(migrated: Engine) -> None:
    with migrated.connect() as connection:
        diff = compare_metadata(MigrationContext.configure(connection), Base.metadata)
    assert diff == []


def test_upgrade_is_idempotent_and_downgrade_works(empty_url: str) -> None:
    engine = create_db_engine(empty_url)
    try:
        upgrade(engine)
        upgrade(engine)  # a second start-up changes nothing
        downgrade(engine, "base")
        assert set(inspect(engine).get_table_names()) <= {"alembic_version"}
        upgrade(engine)
        assert current_revision(engine) == head_revision()
    finally:
        engine.dispose()


def test_sqlite_pragmas(engine: Engine) -> None:
    # SQLite only: PostgreSQL has no such settings to make.
    with engine.connect() as connection:
        assert connection.exec_driver_sql("PRAGMA journal_mode").scalar() == "wal"
        assert connection.exec_driver_sql("PRAGMA foreign_keys").scalar() == 1
        assert connection.exec_driver_sql("PRAGMA busy_timeout").scalar() == 30000


def test_transactions_roll_back_selects_and_writes(engine: Engine) -> None:
    # With the driver's legacy mode a rolled-back transaction could keep DDL; ours keeps nothing.
    with engine.connect() as connection, connection.begin() as tx:
        connection.execute(text("CREATE TABLE scratch (x INTEGER)"))
        tx.rollback()
    assert "scratch" not in inspect(engine).get_table_names()


def test_replicas_starting_together_migrate_one_after_the_other(
    postgres_cluster: Cluster,
) -> None:
    # Two replicas starting at once on an empty PostgreSQL database: both come up at head.
    import threading

    url = postgres_cluster.new_database(migrated=False)
    engines = [create_db_engine(url) for _ in range(3)]
    errors: list[BaseException] = []

    def start(engine: Engine) -> None:
        try:
            upgrade(engine)
        except BaseException as exc:
            errors.append(exc)

    threads = [threading.Thread(target=start, args=(engine,)) for engine in engines]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=120)
    try:
        assert not errors, errors
        assert current_revision(engines[0]) == head_revision()
    finally:
        for engine in engines:
            engine.dispose()
