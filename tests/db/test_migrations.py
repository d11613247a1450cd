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


def test_0005_keys_existing_labels_and_drops_case_duplicates(settings: Settings) -> None:
    engine = create_db_engine(settings.sqlalchemy_url)
    try:
        upgrade(engine, "0002")
        with engine.begin() as db:
            db.execute(
                text(
                    "INSERT INTO clips (id, name, format, content_hash, frame_count, frame_time, "
                    "duration, joint_count, skeleton_family, lead_in_frames, created_at) VALUES "
                    "(1, 'a', 'bvh', 'h1', 1, 0.1, 0.1, 1, 'x', 0, '2026-01-01 00:00:00')"
                )
            )
            db.execute(
                text(
                    "INSERT INTO clip_labels (clip_id, label, position) VALUES "
                    "(1, 'Walk', 0), (1, 'Straße', 1), (1, 'walk', 2), (1, 'STRASSE', 3)"
                )
            )
        upgrade(engine, "0005")
        with engine.connect() as db:
            rows = db.execute(
                text("SELECT label, label_key FROM clip_labels ORDER BY position")
            ).all()
        assert [tuple(r) for r in rows] == [("Walk", "walk"), ("Straße", "strasse")]
    finally:
        engine.dispose()
