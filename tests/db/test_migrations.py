"""The schema comes only from the Alembic migrations, and they agree with the models."""

from __future__ import annotations

from alembic.autogenerate import compare_metadata
from alembic.runtime.migration import MigrationContext
from sqlalchemy import Engine, inspect, text

from app.config import Settings
from app.db.migrate import current_revision, downgrade, head_revision, upgrade
from app.db.models import Base
from app.db.session import create_db_engine


def test_fresh_database_is_migrated_to_head(engine: Engine) -> None:
    assert current_revision(engine) == head_revision()
    tables = set(inspect(engine).get_table_names())
    assert {"clips", "clip_files", "clip_labels", "clip_descriptors"} <= tables


def test_models_match_migrations(engine: Engine) -> None:
    with engine.connect() as connection:
        diff = compare_metadata(MigrationContext.configure(connection), Base.metadata)
    assert diff == []


def test_upgrade_is_idempotent_and_downgrade_works(settings: Settings) -> None:
    engine = create_db_engine(settings.sqlalchemy_url)
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
