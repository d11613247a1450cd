"""A server's start leaves the comparison of its window indexes with the database's windows
to its verifier thread (``Library.check_window_counts``): an index that disagrees is still
rebuilt, after the start instead of during it; the CLI's opening (``verify_later=False``)
compares at once, as before.

Real app, real SQLite file, real FAISS; the clips are the Bandai fixture stretched.
"""

from __future__ import annotations

import logging
import sqlite3
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from app.config import Settings
from app.db import windows as window_db
from app.main import create_app
from app.services.library import Library, open_library
from tests.conftest import FIXTURES_DIR
from tests.hardening.live import stretched_bvh

BANDAI = (FIXTURES_DIR / "bandai_walk_normal_001_first40.bvh").read_text()
FPS = 30


@pytest.fixture
def settings(tmp_path: Path) -> Settings:
    """A library of three clips of 6-10 s with their windows."""
    settings = Settings(data_dir=tmp_path / "data", index_type="flat")
    with TestClient(create_app(settings)) as client:
        for n in range(3):
            body = stretched_bvh(int((6 + 2 * n) * FPS), n + 1, BANDAI)
            response = client.post("/clips", files={"file": (f"walk_{n}.bvh", body)})
            assert response.status_code == 201, response.text
    return settings


def drop_windows_behind_the_feed(settings: Settings, clip_id: int) -> None:
    """Delete a clip's windows without a change row (no trigger on deleting windows): the
    window indexes' files then hold more windows than the database."""
    with sqlite3.connect(settings.data_dir / "mocap-index.sqlite3") as db:
        assert db.execute("DELETE FROM clip_windows WHERE clip_id = ?", (clip_id,)).rowcount
    db.close()


def sizes_agree(library: Library) -> bool:
    with library.reads() as session:
        return all(
            window_db.count_windows(session, key) == library.window_indexes[name].size
            for name, key in library.window_keys.items()
        )


def test_a_server_rebuilds_disagreeing_window_indexes_after_its_start(
    settings: Settings, caplog: pytest.LogCaptureFixture
) -> None:
    drop_windows_behind_the_feed(settings, 2)
    with caplog.at_level(logging.WARNING), TestClient(create_app(settings)) as client:
        library: Library = client.app.state.library  # type: ignore[attr-defined]
        assert library.verifier is not None
        library.verifier.join()
        assert sizes_agree(library)
        assert "disagree with the database's windows: rebuilding" in caplog.text
        response = client.get("/search/moments", params={"clip": 1, "k": 5})
        assert response.status_code == 200, response.text
        assert 2 not in {moment["id"] for moment in response.json()["results"]}


def test_an_unchanged_library_is_not_rebuilt(settings: Settings) -> None:
    library = open_library(settings, verify_later=True)
    try:
        assert library.verifier is not None
        library.verifier.join()
        assert library.check_window_counts() == []
        assert sizes_agree(library)
    finally:
        library.close()


def test_the_cli_opening_compares_at_once(settings: Settings) -> None:
    drop_windows_behind_the_feed(settings, 3)
    library = open_library(settings)  # no verifier thread: repaired while opening
    try:
        assert library.verifier is None
        assert sizes_agree(library)
    finally:
        library.close()
