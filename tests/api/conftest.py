"""API fixtures: every test that uses ``settings`` (and so ``client`` and ``fake_client``) runs
twice, on SQLite and on PostgreSQL (a fresh database of the session's throwaway server,
see tests/postgres.py); a client on the fake motion core (exact, fast)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import create_engine, select

from app.config import Settings
from app.db.models import Blob
from app.main import create_app
from tests.conftest import new_sqlite_settings
from tests.services.fakes import FakeDescriber


@pytest.fixture(params=["sqlite", "postgresql"])
def settings(request: pytest.FixtureRequest, tmp_path: Path) -> Settings:
    """Settings on a fresh temporary data directory, with a SQLite file there or a fresh
    PostgreSQL database."""
    if request.param == "postgresql":
        url = request.getfixturevalue("postgres_url")
        return Settings(data_dir=tmp_path / "data", database_url=url)
    return new_sqlite_settings(tmp_path / "data", request.getfixturevalue("migrated_sqlite_file"))


def stored_blobs(settings: Settings) -> list[str]:
    """The sha256 of every stored upload file, wherever the backend keeps them."""
    if settings.database_url:
        engine = create_engine(settings.database_url)
        try:
            with engine.connect() as connection:
                return sorted(connection.scalars(select(Blob.sha256)))
        finally:
            engine.dispose()
    return sorted(p.name for p in settings.files_dir.rglob("*") if p.is_file())


@pytest.fixture
def fake_client(settings: Settings) -> Iterator[TestClient]:
    """The real app and storage, with vectors chosen by the test (see tests/services/fakes.py)."""
    with TestClient(create_app(settings, describer=FakeDescriber())) as client:
        yield client
