"""Clip windows (``clip_windows``): the vectors and frames of moments search's window indexes."""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from sqlalchemy import delete, func, select
from sqlalchemy.orm import Session

from app.db.models import Clip, ClipFile, ClipWindow
from app.db.rows import (
    VECTOR_DTYPE,
    Executor,
    insert_values,
    select_in,
    streamed_vector_arrays,
    vector_arrays,
)


@dataclass(frozen=True)
class NewWindows:
    """One descriptor's windows of a clip: ``lengths`` ``(W,)`` seconds, ``starts`` and
    ``stops`` ``(W,)`` frames of the file ``[start, stop)``, ``vectors`` ``(W, D)`` float32."""

    name: str
    version: int
    lengths: np.ndarray
    starts: np.ndarray
    stops: np.ndarray
    vectors: np.ndarray


@dataclass(frozen=True)
class WindowKey:
    """Which windows one window index holds: descriptor ``name`` of ``version`` (whose
    vectors have ``dimension`` numbers: a version fixes it), windows of ``length`` seconds."""

    name: str
    version: int
    dimension: int
    length: float


WINDOW_COLUMNS = tuple(ClipWindow.__table__.columns.keys())  # id, clip_id, ..., end_frame, vector


def _window_filter(key: WindowKey) -> Any:
    return (
        (ClipWindow.name == key.name)
        & (ClipWindow.version == key.version)
        & (ClipWindow.length == key.length)
    )


def _window_arrays(
    rows: Sequence[Any], dimension: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Starts, stops and vectors of (start, stop, vector bytes) rows."""
    starts = np.fromiter((r[0] for r in rows), dtype=np.int64, count=len(rows))
    stops = np.fromiter((r[1] for r in rows), dtype=np.int64, count=len(rows))
    return starts, stops, vector_arrays([(0, r[2]) for r in rows], dimension)[1]


def _place_arrays(rows: Sequence[Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ids, starts and stops ``(W,)`` int64 of (id, start, stop) rows."""
    # Not np.array(rows): it reads SQLAlchemy rows through the sequence protocol, 60 times
    # slower (7 s for 690,000 rows).
    flat = (value for row in rows for value in row)
    array = np.fromiter(flat, dtype=np.int64, count=3 * len(rows)).reshape(-1, 3)
    return array[:, 0].copy(), array[:, 1].copy(), array[:, 2].copy()


def count_windows(session: Executor, key: WindowKey) -> int:
    return int(session.scalar(select(func.count()).where(_window_filter(key))) or 0)


def window_ids(session: Executor, key: WindowKey) -> np.ndarray:
    """``(N,)`` int64 sorted ids of the windows :func:`load_windows` returns."""
    ids = session.scalars(select(ClipWindow.id).where(_window_filter(key)).order_by(ClipWindow.id))
    return np.fromiter(ids, dtype=np.int64)


def load_windows(session: Executor, key: WindowKey) -> tuple[np.ndarray, np.ndarray]:
    """Window ids ``(N,)`` int64 and vectors ``(N, D)`` float32 of ``key``, in id order."""
    query = select(ClipWindow.id, ClipWindow.vector).where(_window_filter(key))
    return streamed_vector_arrays(session, query.order_by(ClipWindow.id), key.dimension)


def load_windows_of(
    session: Executor, key: WindowKey, ids: Iterable[int]
) -> tuple[np.ndarray, np.ndarray]:
    """Like :func:`load_windows`, for the given window ids only."""
    query = select(ClipWindow.id, ClipWindow.vector).where(_window_filter(key))
    return vector_arrays(select_in(session, query, ClipWindow.id, ids), key.dimension)


def load_windows_of_clips(
    session: Executor, key: WindowKey, clip_ids: Iterable[int]
) -> tuple[np.ndarray, np.ndarray]:
    """Like :func:`load_windows`, for the windows of the given clips only."""
    query = select(ClipWindow.id, ClipWindow.vector).where(_window_filter(key))
    rows = sorted(select_in(session, query, ClipWindow.clip_id, clip_ids))
    return vector_arrays(rows, key.dimension)


def load_window_places(
    session: Executor, key: WindowKey
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ids, start and stop frames ``(N,)`` int64 of every ``key`` window, in id order (read
    from the covering index ``ix_clip_windows_places``, not the rows)."""
    # On the driver's own cursor (plain tuples, in this transaction): SQLAlchemy's rows cost
    # three times the time at 700,000 windows, a server's start-up at 100 hours of windows.
    connection = session.connection() if isinstance(session, Session) else session
    mark = "?" if connection.dialect.paramstyle == "qmark" else "%s"
    cursor = connection.connection.driver_connection.cursor()  # type: ignore[union-attr]
    try:
        cursor.execute(
            "SELECT id, start_frame, end_frame FROM clip_windows "
            f"WHERE name = {mark} AND version = {mark} AND length = {mark} ORDER BY id",
            (key.name, key.version, key.length),
        )
        rows = cursor.fetchall()
    finally:
        cursor.close()
    return _place_arrays(rows)


def window_places_of_clips(
    session: Executor, key: WindowKey, clip_ids: Iterable[int]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Like :func:`load_window_places`, for the windows of the given clips only."""
    query = select(ClipWindow.id, ClipWindow.start_frame, ClipWindow.end_frame).where(
        _window_filter(key)
    )
    rows = sorted(select_in(session, query, ClipWindow.clip_id, clip_ids))
    return _place_arrays(rows)


def window_ids_of_clips(session: Executor, key: WindowKey, clip_ids: Iterable[int]) -> np.ndarray:
    """``(N,)`` int64 sorted ids of the ``key`` windows of the given clips."""
    query = select(ClipWindow.id).where(_window_filter(key))
    rows = select_in(session, query, ClipWindow.clip_id, clip_ids)
    return np.sort(np.fromiter((r[0] for r in rows), dtype=np.int64, count=len(rows)))


def load_window_rows(
    session: Executor, key: WindowKey, clip_ids: Iterable[int]
) -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The ``key`` windows of some clips: clip id -> starts ``(W,)``, stops ``(W,)``, vectors
    ``(W, D)`` float32, in id order (benchmark fills)."""
    query = select(
        ClipWindow.clip_id, ClipWindow.start_frame, ClipWindow.end_frame, ClipWindow.vector
    ).where(_window_filter(key))
    rows: dict[int, list[Any]] = {}
    for row in select_in(session, query, ClipWindow.clip_id, clip_ids):
        rows.setdefault(int(row[0]), []).append(row)
    return {
        clip_id: _window_arrays([r[1:] for r in group], key.dimension)
        for clip_id, group in rows.items()
    }


# A clip's windows have the ids ``clip id << WINDOW_ID_BITS | ordinal`` (ordinal 0, 1, ...
# over all its windows): a window index finds a clip's windows without the database (the
# change feed names clips, and a deleted clip's rows are gone), and a clip's windows keep their
# ids when recomputed. 2**20 windows cover a take of over 70 hours.
WINDOW_ID_BITS = 20


def clips_of_windows(ids: np.ndarray) -> np.ndarray:
    """The clip ids ``(N,)`` of window ids ``(N,)``."""
    return ids >> WINDOW_ID_BITS


def window_rows(clip_id: int, groups: Sequence[NewWindows]) -> list[tuple[Any, ...]]:
    """The ``clip_windows`` rows of a clip's windows, tuples in :data:`WINDOW_COLUMNS` order
    (ids: the clip id, then the window's ordinal)."""
    count = sum(len(group.starts) for group in groups)
    if count > 1 << WINDOW_ID_BITS:
        raise ValueError(f"a clip has at most {1 << WINDOW_ID_BITS} windows, not {count}")
    ordinals = itertools.count(clip_id << WINDOW_ID_BITS)
    return [
        (next(ordinals), clip_id, group.name, group.version, length, start, stop, vector.tobytes())
        for group in groups
        for length, start, stop, vector in zip(
            group.lengths.tolist(),
            group.starts.tolist(),
            group.stops.tolist(),
            np.ascontiguousarray(group.vectors, dtype=VECTOR_DTYPE),
            strict=True,
        )
    ]


def put_windows(session: Session, clip_id: int, windows: Sequence[NewWindows]) -> None:
    """Replace every window of a clip by ``windows`` (reindex; pass the windows of every
    windowed descriptor: the ids restart at ordinal 0). Inserting ordinal 0 puts the clip on
    the change feed (trigger, migration 0004), so every process's window indexes follow."""
    session.execute(delete(ClipWindow).where(ClipWindow.clip_id == clip_id))
    insert_values(session.connection(), ClipWindow, WINDOW_COLUMNS, window_rows(clip_id, windows))


def clips_needing_windows(session: Session, current: Mapping[str, int]) -> dict[int, list[str]]:
    """Clips with a stored file lacking windows of the current version of a descriptor in
    ``current`` (name -> version), with those names."""
    versions: dict[tuple[int, str], set[int]] = {}
    for clip_id, name, version in session.execute(
        select(ClipWindow.clip_id, ClipWindow.name, ClipWindow.version).distinct()
    ):
        versions.setdefault((clip_id, name), set()).add(version)
    with_files = set(session.scalars(select(ClipFile.clip_id).distinct()))
    needing: dict[int, list[str]] = {}
    for clip_id in session.scalars(select(Clip.id).order_by(Clip.id)):
        if clip_id not in with_files:
            continue
        missing = [n for n, v in current.items() if versions.get((clip_id, n)) != {v}]
        if missing:
            needing[clip_id] = missing
    return needing
