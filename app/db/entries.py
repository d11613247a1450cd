"""What a search shows of each clip (:class:`ClipEntry`), read for the in-memory catalogue
(:mod:`app.index.catalogue`): when it is rebuilt, every clip; when the change feed names some,
those.

A million clips are read in a few seconds: three ordered statements per batch of ids (the
clips' columns, their labels, their file names) on the driver's own cursor, merged in id
order. The joint mapping and the files' hashes, which no search shows, are not read.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from datetime import datetime
from typing import Any, NamedTuple

import orjson
from sqlalchemy import Connection
from sqlalchemy.orm import Session

from app.db.clips import AnimationRecord, ClipRecord, decode_animations
from app.db.rows import Executor, chunks, utc
from app.labels import label_key

BATCH = 20_000  # clips per batch of a full read


class ClipEntry(NamedTuple):
    """What a search shows of a clip: a :class:`~app.db.clips.ClipRecord` without its joint
    mapping and its files' roles, hashes and sizes. (A named tuple: a search builds a dozen,
    and a frozen dataclass costs several times as much to build.)"""

    id: int
    name: str
    format: str
    filenames: tuple[str, ...]
    skeleton_family: str
    labels: tuple[str, ...]
    frame_count: int
    frame_time: float
    duration: float
    source: str | None
    licence: str | None
    content_hash: str
    joint_count: int
    lead_in_frames: int
    warnings: tuple[str, ...]
    animations: tuple[AnimationRecord, ...] | None
    created_at: datetime

    @classmethod
    def of(cls, clip: ClipRecord) -> ClipEntry:
        return cls(
            id=clip.id,
            name=clip.name,
            format=clip.format,
            filenames=tuple(clip.filenames),
            skeleton_family=clip.skeleton_family,
            labels=clip.labels,
            frame_count=clip.frame_count,
            frame_time=clip.frame_time,
            duration=clip.duration,
            source=clip.source,
            licence=clip.licence,
            content_hash=clip.content_hash,
            joint_count=clip.joint_count,
            lead_in_frames=clip.lead_in_frames,
            warnings=clip.warnings,
            animations=clip.animations,
            created_at=clip.created_at,
        )

    @property
    def fps(self) -> float:
        """Frames per second."""
        return 1.0 / self.frame_time if self.frame_time > 0 else 0.0

    def label_keys(self) -> set[str]:
        """The labels as filters compare them (:func:`app.labels.label_key`)."""
        return {label_key(label) for label in self.labels}


_COLUMNS = (
    "id, name, format, content_hash, frame_count, frame_time, duration, joint_count, "
    "skeleton_family, lead_in_frames, created_at, source, licence, animations, warnings"
)


def _timestamp(value: Any) -> datetime:
    # SQLite keeps SQLAlchemy's ISO text without a time zone (we write UTC); psycopg gives
    # datetimes.
    return utc(value if isinstance(value, datetime) else datetime.fromisoformat(value))


def _warnings(text: str | None) -> tuple[str, ...]:
    return () if not text or text == "[]" else tuple(orjson.loads(text))


def _grouped(rows: Iterable[tuple[Any, Any]]) -> dict[int, list[Any]]:
    grouped: dict[int, list[Any]] = {}
    for clip_id, value in rows:
        grouped.setdefault(int(clip_id), []).append(value)
    return grouped


def _entries(cursor: Any, mark: str, where: str, params: Sequence[Any]) -> list[ClipEntry]:
    """The clips of ``WHERE <where>`` (on ``id`` for the clips, ``clip_id`` for their
    labels and files), in id order."""
    cursor.execute(f"SELECT {_COLUMNS} FROM clips WHERE {where.format(c='id')} ORDER BY id", params)
    rows = cursor.fetchall()
    cursor.execute(
        f"SELECT clip_id, label FROM clip_labels WHERE {where.format(c='clip_id')} "
        "ORDER BY clip_id, position",
        params,
    )
    labels = _grouped(cursor.fetchall())
    cursor.execute(
        f"SELECT clip_id, filename FROM clip_files WHERE {where.format(c='clip_id')} "
        "ORDER BY clip_id, position",
        params,
    )
    files = _grouped(cursor.fetchall())
    return [
        ClipEntry(
            id=int(row[0]),
            name=row[1],
            format=row[2],
            filenames=tuple(files.get(int(row[0]), ())),
            skeleton_family=row[8],
            labels=tuple(labels.get(int(row[0]), ())),
            frame_count=int(row[4]),
            frame_time=float(row[5]),
            duration=float(row[6]),
            source=row[11],
            licence=row[12],
            content_hash=row[3],
            joint_count=int(row[7]),
            lead_in_frames=int(row[9]),
            warnings=_warnings(row[14]),
            animations=decode_animations(row[13]),
            created_at=_timestamp(row[10]),
        )
        for row in rows
    ]


def clip_entries(executor: Executor, clip_ids: Iterable[int] | None = None) -> Iterator[ClipEntry]:
    """The entries of the clips ``clip_ids`` that exist (every clip when ``None``), in id
    order, read in batches on the driver's own cursor (in the executor's transaction)."""
    connection = executor.connection() if isinstance(executor, Session) else executor
    assert isinstance(connection, Connection)
    mark = "?" if connection.dialect.paramstyle == "qmark" else "%s"
    cursor = connection.connection.driver_connection.cursor()  # type: ignore[union-attr]
    try:
        if clip_ids is not None:
            for chunk in chunks(sorted({int(i) for i in clip_ids})):
                marks = ",".join([mark] * len(chunk))
                yield from _entries(cursor, mark, f"{{c}} IN ({marks})", chunk)
            return
        after = 0
        while True:
            cursor.execute(
                f"SELECT max(id) FROM (SELECT id FROM clips WHERE id > {mark} "
                f"ORDER BY id LIMIT {BATCH}) AS batch",
                (after,),
            )
            last = cursor.fetchone()[0]
            if last is None:
                return
            yield from _entries(cursor, mark, f"{{c}} > {mark} AND {{c}} <= {mark}", (after, last))
            after = int(last)
    finally:
        cursor.close()
