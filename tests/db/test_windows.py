"""Reading a whole window table into arrays (app/db/windows.py, app/db/rows.py), on a real
SQLite file and a real PostgreSQL server."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from sqlalchemy import Engine, select

from app.db import clips as clip_db
from app.db import rows as rows_db
from app.db import windows as window_db
from app.db.models import ClipWindow
from app.db.session import create_db_engine, read_sessions, write_sessions
from tests.db.test_repository import new_clip

KEY = window_db.WindowKey("motion", 3, 6, 1.0)


def fill(engine: Engine, clips: int) -> None:
    """``clips`` clips of 5 one-second windows each (and 2 of two seconds, another key)."""
    rng = np.random.default_rng(7)
    with write_sessions(engine).begin() as session:
        for n in range(clips):
            windows = tuple(
                window_db.NewWindows(
                    name="motion",
                    version=3,
                    lengths=np.full(count, length),
                    starts=np.arange(count) * 30,
                    stops=np.arange(count) * 30 + 60,
                    vectors=rng.normal(size=(count, 6)).astype(np.float32),
                )
                for length, count in ((1.0, 5), (2.0, 2))
            )
            clip_db.insert_clip(
                session, dataclasses.replace(new_clip(f"w{n}", seed=n), windows=windows)
            )


def everything(engine: Engine) -> tuple[np.ndarray, np.ndarray]:
    """The windows of KEY read the simple way: every row, then their bytes."""
    query = select(ClipWindow.id, ClipWindow.vector).where(
        (ClipWindow.name == KEY.name)
        & (ClipWindow.version == KEY.version)
        & (ClipWindow.length == KEY.length)
    )
    with read_sessions(engine)() as session:
        rows = session.execute(query.order_by(ClipWindow.id)).all()
    return rows_db.vector_arrays(rows, KEY.dimension)


def check_streamed(engine: Engine, monkeypatch: pytest.MonkeyPatch) -> None:
    ids, vectors = everything(engine)
    assert ids.size == 35 and np.all(np.diff(ids) > 0)
    monkeypatch.setattr(rows_db, "STREAM_ROWS", 4)  # many fetches, the last one short
    with read_sessions(engine)() as session:
        got_ids, got = window_db.load_windows(session, KEY)
        np.testing.assert_array_equal(got_ids, ids)
        np.testing.assert_array_equal(got, vectors)
        assert got.dtype == np.float32 and got.flags.c_contiguous and got.shape == (35, 6)
        # A count taken before rows came or went: the arrays grow, or are cut to the rows.
        query = select(ClipWindow.id, ClipWindow.vector).where(
            (ClipWindow.name == KEY.name) & (ClipWindow.length == KEY.length)
        )
        for expected in (None, 0, 1, 10, 34, 36, 100):
            got_ids, got = rows_db.streamed_vector_arrays(
                session, query.order_by(ClipWindow.id), KEY.dimension, expected
            )
            np.testing.assert_array_equal(got_ids, ids)
            np.testing.assert_array_equal(got, vectors)
            assert got.flags.c_contiguous


def test_whole_table_read_in_fetches_sqlite(
    engine: Engine, monkeypatch: pytest.MonkeyPatch
) -> None:
    fill(engine, 7)
    check_streamed(engine, monkeypatch)


def test_whole_table_read_in_fetches_postgres(
    postgres_url: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    engine = create_db_engine(postgres_url)
    try:
        fill(engine, 7)
        check_streamed(engine, monkeypatch)
    finally:
        engine.dispose()
