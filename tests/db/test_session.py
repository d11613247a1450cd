"""SQLite sessions: every commit the service acknowledges is on disk (``synchronous=FULL``),
unless ``MOCAP_SQLITE_SYNCHRONOUS=NORMAL`` trades that for speed."""

from __future__ import annotations

from pathlib import Path

import pytest
from sqlalchemy import text

from app.config import Settings
from app.db.session import create_db_engine, write_sessions
from app.services.library import open_library

FULL, NORMAL = 2, 1  # PRAGMA synchronous values


def synchronous_of(engine) -> tuple[int, str]:  # type: ignore[no-untyped-def]
    """What a write session's connection runs with: synchronous level and journal mode."""
    with write_sessions(engine).begin() as session:
        level = session.execute(text("PRAGMA synchronous")).scalar_one()
        journal = session.execute(text("PRAGMA journal_mode")).scalar_one()
    return int(level), str(journal)


def test_commits_are_fsynced_by_default(tmp_path: Path) -> None:
    engine = create_db_engine(f"sqlite:///{tmp_path / 'db.sqlite3'}")
    try:
        assert synchronous_of(engine) == (FULL, "wal")
    finally:
        engine.dispose()


def test_the_library_the_service_opens_is_durable(settings: Settings) -> None:
    library = open_library(settings)
    try:
        assert synchronous_of(library.engine) == (FULL, "wal")
    finally:
        library.close()
    faster = Settings(data_dir=settings.data_dir, sqlite_synchronous="normal")
    library = open_library(faster)
    try:
        assert synchronous_of(library.engine) == (NORMAL, "wal")
    finally:
        library.close()


def test_only_full_or_normal(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="FULL, NORMAL"):
        create_db_engine(f"sqlite:///{tmp_path / 'db.sqlite3'}", synchronous="OFF")
    with pytest.raises(ValueError):
        Settings(data_dir=tmp_path, sqlite_synchronous="off")
