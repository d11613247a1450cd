"""The reads of a search, from one database snapshot.

A search answers from four small queries (the query clip with its vector, the hits, their
labels, their files). Through the ORM they cost ~2 ms; here, on SQLite, they run as plain
SQL on one DBAPI connection per thread, kept open (~10 us each), inside one read
transaction, so a search sees one snapshot. On PostgreSQL, where every statement is a round
trip to the server, they run as two statements (the clip with its files; the hits' names
with their labels) on one psycopg connection per thread in autocommit mode: no pool
checkout, ping, BEGIN or ROLLBACK around them. A clip deleted between the two is skipped by
the search, as one deleted between the index search and the rows. Other databases go through
the Core reads of :mod:`app.db.clips` and :mod:`app.db.vectors` on a pooled connection.
"""

from __future__ import annotations

import contextlib
import queue
import sqlite3
import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import datetime
from typing import Any, Protocol

import numpy as np
from sqlalchemy import Connection, Engine, select

from app.db.clip_filters import licence_condition, licence_sql
from app.db.clips import (
    ClipRecord,
    FileRecord,
    decode_animations,
    get_clip,
    get_clips,
    json_mapping,
    json_warnings,
)
from app.db.label_filters import LabelFilter, clip_ids_with_label, label_keys, labelled_sql
from app.db.models import Clip
from app.db.rows import chunks, decode_vector, utc
from app.db.vectors import StoredVector, get_vector
from app.licences import LicenceFilter

_SQLITE_CLIP_COLUMNS = (
    "c.id, c.name, c.format, c.content_hash, c.frame_count, c.frame_time, c.duration, "
    "c.joint_count, c.skeleton_family, c.lead_in_frames, c.created_at, c.source, c.licence, "
    "c.animations, c.warnings, c.joint_mapping"
)


def _parse_timestamp(value: Any) -> datetime:
    # SQLAlchemy stores SQLite DATETIMEs as ISO text without a time zone (we write UTC).
    if isinstance(value, datetime):
        return utc(value)
    return utc(datetime.fromisoformat(value))


@dataclass(frozen=True, slots=True)
class ClipName:
    """What a search result shows of a clip: enough to tell same-named clips apart."""

    id: int
    name: str
    labels: tuple[str, ...]
    format: str = ""
    filenames: tuple[str, ...] = ()
    skeleton_family: str = ""


class SearchSnapshot(Protocol):
    """The reads of one search, all from one database snapshot."""

    def clip(self, clip_id: int, *, labels: bool = True) -> ClipRecord | None:
        """The clip (``labels=False``: without its labels, e.g. when :meth:`names` fetches
        them with the hits), or ``None``."""
        ...

    def vector(self, clip_id: int, name: str) -> StoredVector | None: ...

    def names(self, clip_ids: Sequence[int]) -> dict[int, ClipName]: ...

    def clip_ids_with_label(self, label: LabelFilter) -> np.ndarray:
        """Ids of the clips carrying every label of ``label`` (any case)."""
        ...

    def clip_ids_with_licence(self, licence: LicenceFilter) -> np.ndarray:
        """Ids (ascending) of the clips ``licence`` allows."""
        ...

    def frame_times(self, clip_ids: Sequence[int]) -> dict[int, tuple[str, float, int]]:
        """``(format, frame_time, frame_count)`` of the clips that exist, by id."""
        ...


class _SqliteSnapshot:
    def __init__(self, connection: sqlite3.Connection) -> None:
        self._db: sqlite3.Connection | _Placeholders = connection

    def clip(self, clip_id: int, *, labels: bool = True) -> ClipRecord | None:
        rows = self._db.execute(
            f"SELECT {_SQLITE_CLIP_COLUMNS}, f.role, f.filename, f.sha256, f.size FROM clips c "
            "LEFT JOIN clip_files f ON f.clip_id = c.id WHERE c.id = ? ORDER BY f.position",
            (int(clip_id),),
        ).fetchall()
        if not rows:
            return None
        row = rows[0]
        tags: tuple[str, ...] = ()
        if labels:
            tags = tuple(
                r[0]
                for r in self._db.execute(
                    "SELECT label FROM clip_labels WHERE clip_id = ? ORDER BY position",
                    (int(clip_id),),
                )
            )
        return ClipRecord(
            id=int(row[0]),
            name=row[1],
            format=row[2],
            content_hash=row[3],
            frame_count=row[4],
            frame_time=row[5],
            duration=row[6],
            joint_count=row[7],
            skeleton_family=row[8],
            lead_in_frames=row[9],
            created_at=_parse_timestamp(row[10]),
            labels=tags,
            files=tuple(FileRecord(r[16], r[17], r[18], r[19]) for r in rows if r[16] is not None),
            source=row[11],
            licence=row[12],
            animations=decode_animations(row[13]),
            warnings=json_warnings(row[14]),
            joint_mapping=json_mapping(row[15]),
        )

    def vector(self, clip_id: int, name: str) -> StoredVector | None:
        row = self._db.execute(
            "SELECT version, vector FROM clip_descriptors WHERE clip_id = ? AND name = ?",
            (int(clip_id), name),
        ).fetchone()
        return None if row is None else StoredVector(row[0], decode_vector(row[1]))

    def names(self, clip_ids: Sequence[int]) -> dict[int, ClipName]:
        ids = [int(i) for i in clip_ids]
        names: dict[int, tuple[str, str, str]] = {}
        labels: dict[int, list[str]] = {}
        files: dict[int, list[str]] = {}
        for chunk in chunks(ids):
            marks = ",".join("?" * len(chunk))
            names.update(
                (i, (name, fmt, family))
                for i, name, fmt, family in self._db.execute(
                    f"SELECT id, name, format, skeleton_family FROM clips WHERE id IN ({marks})",
                    chunk,
                )
            )
            for clip_id, _, filename in sorted(
                self._db.execute(
                    "SELECT clip_id, position, filename FROM clip_files "
                    f"WHERE clip_id IN ({marks})",
                    chunk,
                )
            ):
                files.setdefault(clip_id, []).append(filename)
            # Sorted here: cheaper than a temporary B-tree for ORDER BY.
            for clip_id, _, label in sorted(
                self._db.execute(
                    f"SELECT clip_id, position, label FROM clip_labels WHERE clip_id IN ({marks})",
                    chunk,
                )
            ):
                labels.setdefault(clip_id, []).append(label)
        return {
            i: ClipName(i, name, tuple(labels.get(i, ())), fmt, tuple(files.get(i, ())), family)
            for i, (name, fmt, family) in names.items()
        }

    def clip_ids_with_label(self, label: LabelFilter) -> np.ndarray:
        keys = label_keys(self._db, label)
        if not keys:
            return np.zeros(0, dtype=np.int64)
        rows = self._db.execute(labelled_sql(keys) + " ORDER BY l.clip_id", keys)
        return np.fromiter((r[0] for r in rows), dtype=np.int64)

    def clip_ids_with_licence(self, licence: LicenceFilter) -> np.ndarray:
        sql, params = licence_sql(licence)
        rows = self._db.execute(sql + " ORDER BY id", params)
        return np.fromiter((r[0] for r in rows), dtype=np.int64)

    def frame_times(self, clip_ids: Sequence[int]) -> dict[int, tuple[str, float, int]]:
        found: dict[int, tuple[str, float, int]] = {}
        for chunk in chunks([int(i) for i in clip_ids]):
            marks = ",".join("?" * len(chunk))
            for clip_id, fmt, frame_time, frames in self._db.execute(
                f"SELECT id, format, frame_time, frame_count FROM clips WHERE id IN ({marks})",
                chunk,
            ):
                found[int(clip_id)] = (fmt, float(frame_time), int(frames))
        return found


class _PostgresSnapshot(_SqliteSnapshot):
    """The same reads with PostgreSQL's placeholders, names and labels in one statement."""

    def __init__(self, connection: Any) -> None:
        self._db = _Placeholders(connection)

    def names(self, clip_ids: Sequence[int]) -> dict[int, ClipName]:
        ids = [int(i) for i in clip_ids]
        rows = self._db.execute(
            "SELECT c.id, c.name, c.format, c.skeleton_family, "
            "coalesce(array_agg(l.label ORDER BY l.position) "
            "FILTER (WHERE l.label IS NOT NULL), '{}') FROM clips c "
            "LEFT JOIN clip_labels l ON l.clip_id = c.id WHERE c.id = ANY(?) GROUP BY c.id",
            (ids,),
        )
        files: dict[int, list[str]] = {}
        for clip_id, filename in self._db.execute(
            "SELECT clip_id, filename FROM clip_files WHERE clip_id = ANY(?) "
            "ORDER BY clip_id, position",
            (ids,),
        ):
            files.setdefault(int(clip_id), []).append(filename)
        return {
            int(i): ClipName(int(i), name, tuple(labels), fmt, tuple(files.get(int(i), ())), family)
            for i, name, fmt, family, labels in rows
        }


class _Placeholders:
    """A psycopg connection taking the ``?`` placeholders of the SQLite statements."""

    def __init__(self, connection: Any) -> None:
        self._connection = connection

    def execute(self, sql: str, params: Sequence[Any] = ()) -> Any:
        return self._connection.execute(sql.replace("?", "%s"), params)


class _CoreSnapshot:
    def __init__(self, connection: Connection) -> None:
        self._db = connection

    def clip(self, clip_id: int, *, labels: bool = True) -> ClipRecord | None:
        return get_clip(self._db, clip_id)

    def vector(self, clip_id: int, name: str) -> StoredVector | None:
        return get_vector(self._db, clip_id, name)

    def names(self, clip_ids: Sequence[int]) -> dict[int, ClipName]:
        return {
            i: ClipName(
                i, clip.name, clip.labels, clip.format, tuple(clip.filenames), clip.skeleton_family
            )
            for i, clip in get_clips(self._db, clip_ids).items()
        }

    def clip_ids_with_label(self, label: LabelFilter) -> np.ndarray:
        return clip_ids_with_label(self._db, label)

    def clip_ids_with_licence(self, licence: LicenceFilter) -> np.ndarray:
        query = select(Clip.id).where(*licence_condition(licence)).order_by(Clip.id)
        return np.fromiter(self._db.scalars(query), dtype=np.int64)

    def frame_times(self, clip_ids: Sequence[int]) -> dict[int, tuple[str, float, int]]:
        found: dict[int, tuple[str, float, int]] = {}
        for chunk in chunks(sorted({int(i) for i in clip_ids})):
            for clip_id, fmt, frame_time, frames in self._db.execute(
                select(Clip.id, Clip.format, Clip.frame_time, Clip.frame_count).where(
                    Clip.id.in_(chunk)
                )
            ):
                found[int(clip_id)] = (fmt, float(frame_time), int(frames))
        return found


class SearchReads:
    """Opens :class:`SearchSnapshot` s for the search path (see above)."""

    CACHE_KIB = 2048  # page cache per connection (SQLite's default)

    def __init__(self, engine: Engine) -> None:
        self._engine = engine
        self._path = engine.url.database if engine.dialect.name == "sqlite" else None
        self._postgres = engine.dialect.name == "postgresql"
        self._idle: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._local = threading.local()
        self._opened: list[Any] = []
        self._lock = threading.Lock()

    def _connection(self) -> sqlite3.Connection:
        connection: sqlite3.Connection | None = getattr(self._local, "connection", None)
        if connection is None:
            assert self._path is not None
            connection = sqlite3.connect(
                self._path, timeout=30, isolation_level=None, check_same_thread=False
            )
            connection.execute("PRAGMA query_only=ON")
            connection.execute(f"PRAGMA cache_size=-{self.CACHE_KIB}")
            self._local.connection = connection
            with self._lock:
                self._opened.append(connection)
        return connection

    @contextmanager
    def _postgres_snapshot(self) -> Iterator[SearchSnapshot]:
        """A connection of the idle ones (or a new one) for one search, then back: as many
        connections as searches ever ran at once (not one per thread of the pool)."""
        import psycopg  # the postgres extra; only imported for a PostgreSQL URL
        from sqlalchemy.exc import OperationalError

        try:
            connection = self._idle.get_nowait()
        except queue.Empty:
            url = self._engine.url.set(drivername="postgresql")
            try:
                connection = psycopg.connect(
                    url.render_as_string(hide_password=False), autocommit=True
                )
            except psycopg.OperationalError as exc:
                raise OperationalError("search read", None, exc) from exc
            with self._lock:
                self._opened.append(connection)
        try:
            yield _PostgresSnapshot(connection)
        except psycopg.OperationalError as exc:  # the server went away: a new one next time
            connection.close()
            raise OperationalError("search read", None, exc) from exc
        finally:
            if not connection.closed:
                self._idle.put(connection)

    @contextmanager
    def snapshot(self) -> Iterator[SearchSnapshot]:
        if self._postgres:
            with self._postgres_snapshot() as snapshot:
                yield snapshot
            return
        if self._path is None:
            with self._engine.connect() as core:
                yield _CoreSnapshot(core)
            return
        db = self._connection()
        db.execute("BEGIN")
        try:
            yield _SqliteSnapshot(db)
        finally:
            db.execute("COMMIT")

    def close(self) -> None:
        with self._lock:
            opened, self._opened = self._opened, []
        for connection in opened:
            with contextlib.suppress(Exception):
                connection.close()
