"""The schema comes only from the Alembic migrations, and they agree with the models — on
SQLite and on PostgreSQL (a fresh database of the session's throwaway server)."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from alembic.autogenerate import compare_metadata
from alembic.runtime.migration import MigrationContext
from sqlalchemy import Engine, inspect, text

from app.config import Settings
from app.db.migrate import current_revision, downgrade, head_in_files, head_revision, upgrade
from app.db.models import Base
from app.db.session import create_db_engine
from tests.conftest import REPO_ROOT
from tests.postgres import Cluster

TABLES = {"clips", "clip_files", "clip_labels", "clip_descriptors", "clip_changes", "blobs"}


@pytest.fixture
def settings(tmp_path: Path) -> Settings:
    """A data directory without a database (not the usual copy of a migrated one): these
    tests migrate from nothing, step by step."""
    return Settings(data_dir=tmp_path / "data")


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


def test_replicas_starting_together_migrate_one_after_the_other(
    postgres_cluster: Cluster, tmp_path: Path
) -> None:
    # Three processes migrating an empty PostgreSQL database at once, as replicas starting
    # together do: all succeed (without the advisory lock the later ones fail creating tables).
    url = postgres_cluster.new_database(migrated=False)
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOCAP_")}
    command = [sys.executable, "-m", "app.cli", "migrate", "--database-url", url]
    processes = [
        subprocess.Popen(
            [*command, "--data-dir", str(tmp_path / str(n))],
            cwd=REPO_ROOT,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
        )
        for n in range(3)
    ]
    outputs = [process.communicate(timeout=120)[0].decode() for process in processes]
    assert [process.returncode for process in processes] == [0, 0, 0], outputs
    engine = create_db_engine(url)
    try:
        assert current_revision(engine) == head_revision()
    finally:
        engine.dispose()


def test_newest_revision_read_from_the_files_is_alembics() -> None:
    # upgrade() skips Alembic when the stored revision is this one: it must be Alembic's head.
    assert head_in_files() == head_revision()


def test_up_to_date_database_starts_without_alembic(settings: Settings) -> None:
    # A start of an up-to-date library leaves Alembic unimported (a new process: the tests
    # have imported it already); one revision behind is still migrated to the newest.
    engine = create_db_engine(settings.sqlalchemy_url)
    try:
        upgrade(engine)
        script = (
            "import sys; from app.db.migrate import upgrade; "
            "from app.db.session import create_db_engine; "
            f"upgrade(create_db_engine({settings.sqlalchemy_url!r})); "
            "print(sorted({m.split('.')[0] for m in sys.modules} & {'alembic'}))"
        )
        env = {k: v for k, v in os.environ.items() if not k.startswith("MOCAP_")}
        run = subprocess.run(
            [sys.executable, "-c", script], cwd=REPO_ROOT, env=env, capture_output=True, text=True
        )
        assert run.returncode == 0, run.stderr
        assert run.stdout.strip() == "[]"
        previous = _revision_before(head_revision())
        downgrade(engine, previous)
        assert current_revision(engine) == previous
        upgrade(engine)
        assert current_revision(engine) == head_revision()
    finally:
        engine.dispose()


def _revision_before(revision: str | None) -> str:
    from alembic.script import ScriptDirectory

    from app.db.migrate import alembic_config

    script = ScriptDirectory.from_config(alembic_config()).get_revision(revision)
    assert isinstance(script.down_revision, str)
    return script.down_revision
