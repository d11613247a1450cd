"""All SQL of the service, as functions over a :class:`~sqlalchemy.orm.Session`.

Functions return plain frozen records (never ORM objects), so callers may use them after the
session is closed. Transactions are the caller's: nothing here commits.

Vectors are stored as little-endian float32 bytes; in memory they are ``(D,)`` float32 arrays,
and batches are ``(N, D)`` float32 C-contiguous with ``(N,)`` int64 clip ids.
"""

from __future__ import annotations

import contextlib
import functools
import itertools
import json
import queue
import sqlite3
import threading
from collections.abc import Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any, Protocol

import numpy as np
from sqlalchemy import Connection, Engine, Select, delete, exists, func, insert, select
from sqlalchemy.orm import Session, aliased, selectinload

from app.db.models import Clip, ClipDescriptor, ClipFile, ClipLabel, ClipWindow
from app.labels import label_filter, label_key

VECTOR_DTYPE = np.dtype("<f4")
IN_CHUNK = 500  # ids per IN (...) list: far below any backend's parameter limit

Executor = Session | Connection
"""Read functions take an ORM session or a Core connection (cheaper per query: the search
path uses one connection per request)."""


@dataclass(frozen=True)
class FileRecord:
    """One uploaded part of a clip, stored as ``files/<sha256[:2]>/<sha256>``."""

    role: str  # "file" (BVH) | "skeleton" (ASF) | "motion" (AMC)
    filename: str
    sha256: str
    size: int


@dataclass(frozen=True)
class StoredVector:
    """A descriptor vector as stored: ``vector`` is ``(dimension,)`` float32."""

    version: int
    vector: np.ndarray


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
class AnimationRecord:
    """One animation of a multi-animation file (FBX, glTF); ``selected``: the clip's own."""

    name: str
    frame_count: int
    duration: float
    selected: bool


def encode_animations(animations: Sequence[AnimationRecord] | None) -> str | None:
    if animations is None:
        return None
    return json.dumps(
        [
            {"name": a.name, "frame_count": a.frame_count, "duration": a.duration}
            | ({"selected": True} if a.selected else {})
            for a in animations
        ]
    )


def decode_animations(text: str | None) -> tuple[AnimationRecord, ...] | None:
    if text is None:
        return None
    return tuple(
        AnimationRecord(
            str(a["name"]), int(a["frame_count"]), float(a["duration"]), bool(a.get("selected"))
        )
        for a in json.loads(text)
    )


@dataclass(frozen=True)
class NewClip:
    """Everything needed to insert a clip (the database assigns ``id``)."""

    name: str
    format: str
    content_hash: str
    frame_count: int
    frame_time: float
    duration: float
    joint_count: int
    skeleton_family: str
    lead_in_frames: int
    labels: tuple[str, ...]
    files: tuple[FileRecord, ...]
    vectors: Mapping[str, StoredVector]
    created_at: datetime = field(default_factory=lambda: datetime.now(UTC))
    source: str | None = None
    licence: str | None = None
    # FBX/glTF: every animation of the file, the clip's own marked ``selected``; else None.
    animations: tuple[AnimationRecord, ...] | None = None
    warnings: tuple[str, ...] = ()
    joint_mapping: Mapping[str, object] | None = None
    windows: tuple[NewWindows, ...] = ()


@dataclass(frozen=True)
class ClipRecord:
    """A stored clip as the rest of the service sees it."""

    id: int
    name: str
    format: str
    content_hash: str
    frame_count: int
    frame_time: float
    duration: float
    joint_count: int
    skeleton_family: str
    lead_in_frames: int
    created_at: datetime
    labels: tuple[str, ...]
    files: tuple[FileRecord, ...]
    source: str | None = None
    licence: str | None = None
    animations: tuple[AnimationRecord, ...] | None = None
    warnings: tuple[str, ...] = ()
    joint_mapping: Mapping[str, object] | None = None

    @property
    def animation(self) -> str | None:
        """The animation of the file this clip holds (FBX/glTF), else None."""
        for animation in self.animations or ():
            if animation.selected:
                return animation.name
        return None

    @property
    def filenames(self) -> list[str]:
        return [f.filename for f in self.files]


def _json_warnings(text: str | None) -> tuple[str, ...]:
    """The stored warnings (JSON text, ``'[]'`` by default) as a tuple."""
    return tuple(json.loads(text)) if text else ()


def _json_mapping(text: str | None) -> dict[str, object] | None:
    """The stored joint mapping (JSON text or NULL for clips described before #10)."""
    return json.loads(text) if text else None


def encode_vector(vector: np.ndarray) -> bytes:
    return np.ascontiguousarray(vector, dtype=VECTOR_DTYPE).tobytes()


def decode_vector(blob: bytes) -> np.ndarray:
    """``(D,)`` float32 (native byte order, writable) from stored bytes."""
    return np.frombuffer(blob, dtype=VECTOR_DTYPE).astype(np.float32)


def _utc(value: datetime) -> datetime:
    # SQLite keeps no time zone; every timestamp we write is UTC.
    return value if value.tzinfo is not None else value.replace(tzinfo=UTC)


LabelFilter = str | Sequence[str] | None
"""A ``label`` filter as :func:`app.labels.label_filter` reads it: clips carrying all of
the labels (any case); ``None``, ``""`` or ``[]`` = no filter."""


# Rows counted per label when choosing which label drives an all-of filter: enough to tell a
# rare label from a common one, cheap (an index range) even when millions carry it.
_COUNT_CAP = 10_000


def _label_keys(
    executor: Executor | sqlite3.Connection | _Placeholders, labels: LabelFilter
) -> list[str]:
    """The keys of the labels asked for, the rarest first (each counted up to _COUNT_CAP)."""
    keys = list(dict.fromkeys(label_key(label) for label in label_filter(labels)))
    if len(keys) < 2:
        return keys
    sql = "SELECT count(*) FROM (SELECT 1 FROM clip_labels WHERE label_key = ? LIMIT ?) AS hits"
    if isinstance(executor, sqlite3.Connection | _Placeholders):  # the raw search path
        counts = {k: executor.execute(sql, (k, _COUNT_CAP)).fetchone()[0] for k in keys}
    else:
        counts = {
            k: executor.scalar(
                select(func.count()).select_from(
                    select(ClipLabel.clip_id)
                    .where(ClipLabel.label_key == k)
                    .limit(_COUNT_CAP)
                    .subquery()
                )
            )
            for k in keys
        }
    return sorted(keys, key=lambda k: counts[k])


def _labelled_ids(keys: Sequence[str]) -> Select[Any]:
    """Ids of the clips carrying every key: the rarest key's index range, each row checked
    against the others' (label_key, clip_id) index, never a scan of a common label."""
    query = select(ClipLabel.clip_id).where(ClipLabel.label_key == keys[0])
    for key in keys[1:]:
        other = aliased(ClipLabel)
        query = query.where(
            exists().where(other.clip_id == ClipLabel.clip_id, other.label_key == key)
        )
    return query


def _labelled_sql(keys: Sequence[str]) -> str:
    """:func:`_labelled_ids` as SQL text for the raw search path (one ``?`` per key)."""
    return "SELECT l.clip_id FROM clip_labels l WHERE l.label_key = ?" + "".join(
        " AND EXISTS (SELECT 1 FROM clip_labels o WHERE o.clip_id = l.clip_id AND o.label_key = ?)"
        for _ in keys[1:]
    )


def _label_conditions(executor: Executor, labels: LabelFilter) -> list[Any]:
    """``[Clip.id IN (ids carrying every label)]``, or ``[]`` for no filter."""
    keys = _label_keys(executor, labels)
    return [Clip.id.in_(_labelled_ids(keys))] if keys else []


def _chunks(values: Sequence[Any], size: int = IN_CHUNK) -> Iterable[Sequence[Any]]:
    for start in range(0, len(values), size):
        yield values[start : start + size]


# Reads below use Core statements (one row tuple per clip, one query per child table for a
# whole batch of clips): about 10x cheaper than loading ORM objects, and the same records.
_CLIP_COLUMNS = (
    Clip.id,
    Clip.name,
    Clip.format,
    Clip.content_hash,
    Clip.frame_count,
    Clip.frame_time,
    Clip.duration,
    Clip.joint_count,
    Clip.skeleton_family,
    Clip.lead_in_frames,
    Clip.created_at,
    Clip.source,
    Clip.licence,
    Clip.animations,
    Clip.warnings,
    Clip.joint_mapping,
)


def _clip_rows() -> Select[Any]:
    return select(*_CLIP_COLUMNS)  # type: ignore[return-value]


def _records(executor: Executor, rows: Sequence[Any]) -> dict[int, ClipRecord]:
    """ClipRecords (with labels and files) for clip rows of :func:`_clip_rows`, by id."""
    if not rows:
        return {}
    ids = [int(row[0]) for row in rows]
    labels: dict[int, list[str]] = {}
    files: dict[int, list[FileRecord]] = {}
    for chunk in _chunks(ids):
        for clip_id, label in executor.execute(
            select(ClipLabel.clip_id, ClipLabel.label)
            .where(ClipLabel.clip_id.in_(chunk))
            .order_by(ClipLabel.clip_id, ClipLabel.position)
        ):
            labels.setdefault(clip_id, []).append(label)
        for clip_id, role, filename, sha256, size in executor.execute(
            select(
                ClipFile.clip_id, ClipFile.role, ClipFile.filename, ClipFile.sha256, ClipFile.size
            )
            .where(ClipFile.clip_id.in_(chunk))
            .order_by(ClipFile.clip_id, ClipFile.position)
        ):
            files.setdefault(clip_id, []).append(FileRecord(role, filename, sha256, size))
    return {
        int(row[0]): ClipRecord(
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
            created_at=_utc(row[10]),
            labels=tuple(labels.get(int(row[0]), ())),
            files=tuple(files.get(int(row[0]), ())),
            source=row[11],
            licence=row[12],
            animations=decode_animations(row[13]),
            warnings=_json_warnings(row[14]),
            joint_mapping=_json_mapping(row[15]),
        )
        for row in rows
    }


# -- clips --------------------------------------------------------------------------------


def get_clip(session: Executor, clip_id: int) -> ClipRecord | None:
    rows = session.execute(_clip_rows().where(Clip.id == clip_id)).all()
    return _records(session, rows).get(clip_id)


def get_clips(session: Executor, clip_ids: Iterable[int]) -> dict[int, ClipRecord]:
    """The clips among ``clip_ids`` that exist, by id."""
    ids = sorted({int(i) for i in clip_ids})
    rows: list[Any] = []
    for chunk in _chunks(ids):
        rows.extend(session.execute(_clip_rows().where(Clip.id.in_(chunk))).all())
    return _records(session, rows)


def get_clip_by_hash(session: Executor, content_hash: str) -> ClipRecord | None:
    rows = session.execute(_clip_rows().where(Clip.content_hash == content_hash)).all()
    found = _records(session, rows)
    return next(iter(found.values()), None)


def clip_ids_by_hash(session: Executor, hashes: Iterable[str]) -> dict[str, int]:
    """``content_hash -> id`` for the hashes already stored."""
    wanted = sorted(set(hashes))
    found: dict[str, int] = {}
    for chunk in _chunks(wanted):
        rows = session.execute(
            select(Clip.content_hash, Clip.id).where(Clip.content_hash.in_(chunk))
        )
        found.update({h: i for h, i in rows})
    return found


def list_clips(
    session: Session, *, label: LabelFilter, limit: int, offset: int
) -> tuple[list[ClipRecord], int]:
    """One page of clips in id order (those carrying every label of ``label``), and how many
    match in total."""
    conditions = _label_conditions(session, label)
    query = _clip_rows().where(*conditions).order_by(Clip.id)
    count = select(func.count()).select_from(Clip).where(*conditions)
    total = session.scalar(count) or 0
    rows = session.execute(query.limit(limit).offset(offset)).all()
    records = _records(session, rows)
    return [records[int(row[0])] for row in rows], total


def count_clips(session: Executor) -> int:
    return session.scalar(select(func.count()).select_from(Clip)) or 0


def max_clip_id(session: Executor) -> int:
    """The largest clip id (0 when there is none). Not a way to follow other writers: on
    PostgreSQL ids can commit out of order, and deletes leave no id; the indexes follow the
    change feed (:mod:`app.db.changes`)."""
    return int(session.scalar(select(func.max(Clip.id))) or 0)


def all_clip_ids(session: Session) -> list[int]:
    return list(session.scalars(select(Clip.id).order_by(Clip.id)))


def insert_clip(session: Session, new: NewClip) -> int:
    """Add a clip with its files, labels and vectors; returns the new id."""
    return insert_clips(session, [new])[0]


# Every column, in the models' order: the order of the tuples inserted by _insert_values.
VECTOR_COLUMNS = tuple(ClipDescriptor.__table__.columns.keys())  # clip_id, name, ... vector
WINDOW_COLUMNS = tuple(ClipWindow.__table__.columns.keys())  # id, clip_id, ..., end_frame, vector


@functools.lru_cache(maxsize=16)
def _insert_statement(table: Any, columns: tuple[str, ...], dialect: Any) -> str:
    compiled = insert(table).compile(dialect=dialect, column_keys=list(columns))
    if dialect.positional and tuple(compiled.positiontup or ()) != columns:
        raise AssertionError(f"unexpected parameter order {compiled.positiontup}")
    return str(compiled)


def _insert_values(
    connection: Connection, table: Any, columns: tuple[str, ...], values: list[tuple[Any, ...]]
) -> None:
    """INSERT ``values`` (tuples in ``columns`` order, values the driver takes as they are)
    in one executemany through the driver."""
    if not values:
        return
    dialect = connection.dialect
    statement = _insert_statement(table, columns, dialect)
    params: Any = (
        values if dialect.positional else [dict(zip(columns, v, strict=True)) for v in values]
    )
    connection.exec_driver_sql(statement, params)


def insert_clips(session: Session, clips: Sequence[NewClip]) -> list[int]:
    """Add clips with their files, labels and vectors in a few multi-row statements (one per
    table); returns the new ids in the order of ``clips``."""
    if not clips:
        return []
    connection = session.connection()
    ids = [
        int(i)
        for i in connection.scalars(
            insert(Clip).returning(Clip.id, sort_by_parameter_order=True),
            [
                {
                    "name": new.name,
                    "format": new.format,
                    "content_hash": new.content_hash,
                    "frame_count": new.frame_count,
                    "frame_time": new.frame_time,
                    "duration": new.duration,
                    "joint_count": new.joint_count,
                    "skeleton_family": new.skeleton_family,
                    "lead_in_frames": new.lead_in_frames,
                    "created_at": new.created_at,
                    "source": new.source,
                    "licence": new.licence,
                    "animations": encode_animations(new.animations),
                    "warnings": json.dumps(list(new.warnings)),
                    "joint_mapping": None
                    if new.joint_mapping is None
                    else json.dumps(new.joint_mapping),
                }
                for new in clips
            ],
        )
    ]
    files = [
        {
            "clip_id": clip_id,
            "position": i,
            "role": f.role,
            "filename": f.filename,
            "sha256": f.sha256,
            "size": f.size,
        }
        for clip_id, new in zip(ids, clips, strict=True)
        for i, f in enumerate(new.files)
    ]
    labels = [
        {"clip_id": clip_id, "label": label, "label_key": label_key(label), "position": i}
        for clip_id, new in zip(ids, clips, strict=True)
        for i, label in enumerate(new.labels)
    ]
    for table, rows in ((ClipFile, files), (ClipLabel, labels)):
        if rows:
            connection.execute(insert(table), rows)
    # The many rows (a vector per descriptor, ~20 windows per clip) go to the driver as
    # plain tuples: SQLAlchemy's per-row parameter processing cost more than SQLite's insert.
    _insert_values(
        connection,
        ClipDescriptor,
        VECTOR_COLUMNS,
        [
            (
                clip_id,
                name,
                stored.version,
                int(stored.vector.shape[0]),
                encode_vector(stored.vector),
            )
            for clip_id, new in zip(ids, clips, strict=True)
            for name, stored in new.vectors.items()
        ],
    )
    _insert_values(
        connection,
        ClipWindow,
        WINDOW_COLUMNS,
        [
            row
            for clip_id, new in zip(ids, clips, strict=True)
            for row in _window_rows(clip_id, new)
        ],
    )
    return ids


# Fields of a clip that ``update_clip`` may set to ``None`` (clear): pass UNSET to keep them.
UNSET: Any = object()


def update_clip(
    session: Session,
    clip_id: int,
    *,
    name: str | None = None,
    labels: Sequence[str] | None = None,
    analysis: Mapping[str, object] | None = None,
    source: str | None = UNSET,
    licence: str | None = UNSET,
) -> bool:
    """Change a clip's name, labels (already normalised: no two with one key), source,
    licence and/or measured fields; False when it does not exist."""
    clip = session.get(Clip, clip_id, options=[selectinload(Clip.labels)])
    if clip is None:
        return False
    if name is not None:
        clip.name = name
    if source is not UNSET:
        clip.source = source
    if licence is not UNSET:
        clip.licence = licence
    if labels is not None:
        clip.labels = []
        session.flush()  # delete the old rows before inserting ones with the same key
        clip.labels = [
            ClipLabel(label=label, label_key=label_key(label), position=i)
            for i, label in enumerate(labels)
        ]
    for key, value in (analysis or {}).items():
        setattr(clip, key, value)
    session.flush()
    return True


def delete_clip(session: Session, clip_id: int) -> list[str] | None:
    """Delete a clip (files, labels and vectors cascade); returns its files' sha256s, or
    ``None`` when there was no such clip."""
    clip = session.get(Clip, clip_id)
    if clip is None:
        return None
    shas = list(session.scalars(select(ClipFile.sha256).where(ClipFile.clip_id == clip_id)))
    session.delete(clip)  # children go by ON DELETE CASCADE (passive_deletes)
    session.flush()
    return shas


def clip_ids_with_labels(session: Executor, labels: LabelFilter) -> list[int]:
    """Ids (ascending) of the clips carrying every label of ``labels``; every clip when the
    filter is empty."""
    return list(
        session.scalars(
            select(Clip.id).where(*_label_conditions(session, labels)).order_by(Clip.id)
        )
    )


def delete_clips(session: Session, clip_ids: Sequence[int]) -> list[str]:
    """Delete clips (files, labels and vectors cascade); returns their files' sha256s."""
    shas: list[str] = []
    for chunk in _chunks(sorted({int(i) for i in clip_ids})):
        shas.extend(session.scalars(select(ClipFile.sha256).where(ClipFile.clip_id.in_(chunk))))
        session.execute(delete(Clip).where(Clip.id.in_(chunk)))
    return shas


def referenced_blobs(session: Session, shas: Iterable[str]) -> set[str]:
    """The sha256s among ``shas`` still used by some clip."""
    wanted = sorted(set(shas))
    if not wanted:
        return set()
    return set(session.scalars(select(ClipFile.sha256).where(ClipFile.sha256.in_(wanted))))


# -- labels -------------------------------------------------------------------------------


def clip_ids_with_label(session: Executor, label: LabelFilter) -> np.ndarray:
    """``(N,)`` int64 ids of the clips carrying every label of ``label`` (any case)."""
    keys = _label_keys(session, label)
    if not keys:
        return np.zeros(0, dtype=np.int64)
    query = _labelled_ids(keys).order_by(ClipLabel.clip_id)
    return np.fromiter(session.scalars(query), dtype=np.int64)


# -- vectors ------------------------------------------------------------------------------


def get_vectors(session: Session, clip_id: int) -> dict[str, StoredVector]:
    """Every stored vector of a clip, by descriptor name."""
    rows = session.scalars(
        select(ClipDescriptor)
        .where(ClipDescriptor.clip_id == clip_id)
        .order_by(ClipDescriptor.name)
    )
    return {r.name: StoredVector(r.version, decode_vector(r.vector)) for r in rows}


def get_vector(session: Executor, clip_id: int, name: str) -> StoredVector | None:
    row = session.execute(
        select(ClipDescriptor.version, ClipDescriptor.vector).where(
            ClipDescriptor.clip_id == clip_id, ClipDescriptor.name == name
        )
    ).first()
    return None if row is None else StoredVector(row[0], decode_vector(row[1]))


def _vector_filter(name: str, version: int, dimension: int) -> Any:
    return (
        (ClipDescriptor.name == name)
        & (ClipDescriptor.version == version)
        & (ClipDescriptor.dimension == dimension)
    )


def vector_ids(session: Executor, name: str, version: int, dimension: int) -> np.ndarray:
    """``(N,)`` int64 sorted ids of the clips whose ``name`` vector :func:`load_vectors`
    returns (that ``version`` and ``dimension``)."""
    ids = session.scalars(
        select(ClipDescriptor.clip_id)
        .where(_vector_filter(name, version, dimension))
        .order_by(ClipDescriptor.clip_id)
    )
    return np.fromiter(ids, dtype=np.int64)


def count_vectors(session: Executor, name: str, version: int) -> int:
    """How many ``name`` vectors of ``version`` are stored (answered from the (name, version)
    index alone, so it stays cheap at a million clips)."""
    return int(
        session.scalar(
            select(func.count()).where(
                ClipDescriptor.name == name, ClipDescriptor.version == version
            )
        )
        or 0
    )


def _window_arrays(
    rows: Sequence[Any], dimension: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Starts, stops and vectors of (start, stop, vector bytes) rows."""
    starts = np.fromiter((r[0] for r in rows), dtype=np.int64, count=len(rows))
    stops = np.fromiter((r[1] for r in rows), dtype=np.int64, count=len(rows))
    return starts, stops, _vector_arrays([(0, r[2]) for r in rows], dimension)[1]


def _place_arrays(rows: Sequence[Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ids, starts and stops ``(W,)`` int64 of (id, start, stop) rows."""
    # Not np.array(rows): it reads SQLAlchemy rows through the sequence protocol, 60 times
    # slower (7 s for 690,000 rows).
    flat = (value for row in rows for value in row)
    array = np.fromiter(flat, dtype=np.int64, count=3 * len(rows)).reshape(-1, 3)
    return array[:, 0].copy(), array[:, 1].copy(), array[:, 2].copy()


def count_outdated_vectors(session: Executor, name: str, version: int) -> int:
    """How many ``name`` vectors of a version older than ``version`` are stored (written by
    an earlier release; ``mocap-index reindex`` replaces them)."""
    return int(
        session.scalar(
            select(func.count()).where(
                ClipDescriptor.name == name, ClipDescriptor.version < version
            )
        )
        or 0
    )


def delete_vectors(session: Session, clip_id: int, names: Iterable[str]) -> None:
    """Drop the clip's vectors of the descriptors ``names`` (e.g. outdated ones that cannot
    be recomputed)."""
    session.execute(
        delete(ClipDescriptor).where(
            ClipDescriptor.clip_id == clip_id, ClipDescriptor.name.in_(list(names))
        )
    )


def _vector_arrays(rows: Sequence[Any], dimension: int) -> tuple[np.ndarray, np.ndarray]:
    ids = np.fromiter((r[0] for r in rows), dtype=np.int64, count=len(rows))
    data = b"".join([r[1] for r in rows])
    vectors = np.frombuffer(data, dtype=VECTOR_DTYPE).astype(np.float32).reshape(-1, dimension)
    return ids, vectors


def load_vectors(
    session: Executor,
    name: str,
    version: int,
    dimension: int,
    *,
    after: int = 0,
    upto: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The ``name`` vectors of ``version``: ids ``(N,)`` int64 and vectors ``(N, D)`` float32,
    in id order; only clips with ``after < id <= upto`` when those are given.

    Rows whose stored dimension differs from ``dimension`` are skipped (they can only come from
    an older descriptor and are recomputed by ``mocap-index reindex``).
    """
    query = select(ClipDescriptor.clip_id, ClipDescriptor.vector).where(
        _vector_filter(name, version, dimension)
    )
    if after:
        query = query.where(ClipDescriptor.clip_id > after)
    if upto is not None:
        query = query.where(ClipDescriptor.clip_id <= upto)
    rows = session.execute(query.order_by(ClipDescriptor.clip_id)).all()
    return _vector_arrays(rows, dimension)


def load_vectors_of(
    session: Executor, name: str, version: int, dimension: int, clip_ids: Iterable[int]
) -> tuple[np.ndarray, np.ndarray]:
    """Like :func:`load_vectors`, for the given clips only (those that have such a vector)."""
    query = select(ClipDescriptor.clip_id, ClipDescriptor.vector).where(
        _vector_filter(name, version, dimension)
    )
    return _vector_arrays(_select_in(session, query, ClipDescriptor.clip_id, clip_ids), dimension)


def _select_in(session: Executor, query: Any, column: Any, ids: Iterable[int]) -> list[Any]:
    """The rows of ``query`` whose ``column`` is among ``ids``, ordered by it (in chunks)."""
    rows: list[Any] = []
    for chunk in _chunks(sorted({int(i) for i in ids})):
        rows.extend(session.execute(query.where(column.in_(chunk)).order_by(column)).all())
    return rows


def put_vectors(session: Session, clip_id: int, vectors: Mapping[str, StoredVector]) -> None:
    """Insert or replace some of a clip's vectors."""
    for name, stored in vectors.items():
        row = session.get(ClipDescriptor, (clip_id, name))
        if row is None:
            row = ClipDescriptor(clip_id=clip_id, name=name)
            session.add(row)
        row.version = stored.version
        row.dimension = int(stored.vector.shape[0])
        row.vector = encode_vector(stored.vector)
    session.flush()


def clips_needing_vectors(session: Session, current: Mapping[str, int]) -> dict[int, list[str]]:
    """Clips lacking a vector of the current version, with the descriptor names to compute.

    ``current`` maps descriptor name -> the version the code produces now.
    """
    have: dict[int, dict[str, int]] = {}
    for clip_id, name, version in session.execute(
        select(ClipDescriptor.clip_id, ClipDescriptor.name, ClipDescriptor.version)
    ):
        have.setdefault(clip_id, {})[name] = version
    needing: dict[int, list[str]] = {}
    for clip_id in all_clip_ids(session):
        stored = have.get(clip_id, {})
        missing = [n for n, v in current.items() if stored.get(n) != v]
        if missing:
            needing[clip_id] = missing
    return needing


# -- windows (moments search) ----------------------------------------------------------------


@dataclass(frozen=True)
class WindowKey:
    """Which windows one window index holds: descriptor ``name`` of ``version`` (whose
    vectors have ``dimension`` numbers: a version fixes it), windows of ``length`` seconds."""

    name: str
    version: int
    dimension: int
    length: float


def _window_filter(key: WindowKey) -> Any:
    return (
        (ClipWindow.name == key.name)
        & (ClipWindow.version == key.version)
        & (ClipWindow.length == key.length)
    )


def count_windows(session: Executor, key: WindowKey) -> int:
    return int(session.scalar(select(func.count()).where(_window_filter(key))) or 0)


def window_ids(session: Executor, key: WindowKey) -> np.ndarray:
    """``(N,)`` int64 sorted ids of the windows :func:`load_windows` returns."""
    ids = session.scalars(select(ClipWindow.id).where(_window_filter(key)).order_by(ClipWindow.id))
    return np.fromiter(ids, dtype=np.int64)


def load_windows(session: Executor, key: WindowKey) -> tuple[np.ndarray, np.ndarray]:
    """Window ids ``(N,)`` int64 and vectors ``(N, D)`` float32 of ``key``, in id order."""
    query = select(ClipWindow.id, ClipWindow.vector).where(_window_filter(key))
    rows = session.execute(query.order_by(ClipWindow.id)).all()
    return _vector_arrays(rows, key.dimension)


def load_windows_of(
    session: Executor, key: WindowKey, ids: Iterable[int]
) -> tuple[np.ndarray, np.ndarray]:
    """Like :func:`load_windows`, for the given window ids only."""
    query = select(ClipWindow.id, ClipWindow.vector).where(_window_filter(key))
    return _vector_arrays(_select_in(session, query, ClipWindow.id, ids), key.dimension)


def load_windows_of_clips(
    session: Executor, key: WindowKey, clip_ids: Iterable[int]
) -> tuple[np.ndarray, np.ndarray]:
    """Like :func:`load_windows`, for the windows of the given clips only."""
    query = select(ClipWindow.id, ClipWindow.vector).where(_window_filter(key))
    rows = sorted(_select_in(session, query, ClipWindow.clip_id, clip_ids))
    return _vector_arrays(rows, key.dimension)


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
    rows = sorted(_select_in(session, query, ClipWindow.clip_id, clip_ids))
    return _place_arrays(rows)


def window_ids_of_clips(session: Executor, key: WindowKey, clip_ids: Iterable[int]) -> np.ndarray:
    """``(N,)`` int64 sorted ids of the ``key`` windows of the given clips."""
    query = select(ClipWindow.id).where(_window_filter(key))
    rows = _select_in(session, query, ClipWindow.clip_id, clip_ids)
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
    for row in _select_in(session, query, ClipWindow.clip_id, clip_ids):
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


def _window_rows(clip_id: int, windows: NewClip | Sequence[NewWindows]) -> list[tuple[Any, ...]]:
    """The ``clip_windows`` rows of a clip's windows, tuples in :data:`WINDOW_COLUMNS` order
    (ids: the clip id, then the window's ordinal)."""
    groups = windows.windows if isinstance(windows, NewClip) else windows
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
    _insert_values(session.connection(), ClipWindow, WINDOW_COLUMNS, _window_rows(clip_id, windows))


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
    for clip_id in all_clip_ids(session):
        if clip_id not in with_files:
            continue
        missing = [n for n, v in current.items() if versions.get((clip_id, n)) != {v}]
        if missing:
            needing[clip_id] = missing
    return needing


# -- maintenance --------------------------------------------------------------------------


def checkpoint(engine: Engine) -> None:
    """SQLite: fold the write-ahead log into the database file (after a bulk load, so the next
    readers do not wade through a large log). Nothing elsewhere. Runs outside a transaction."""
    if engine.dialect.name != "sqlite":
        return
    raw = engine.raw_connection()
    try:
        cursor = raw.cursor()
        cursor.execute("PRAGMA wal_checkpoint(TRUNCATE)")
        cursor.close()
    finally:
        raw.close()


# -- the search path ----------------------------------------------------------------------
#
# A search answers from four small queries (the query clip with its vector, the hits, their
# labels, their files). Through the ORM they cost ~2 ms; here, on SQLite, they run as plain
# SQL on one DBAPI connection per thread, kept open (~10 us each), inside one read
# transaction, so a search sees one snapshot. On PostgreSQL, where every statement is a round
# trip to the server, they run as two statements (the clip with its files; the hits' names
# with their labels) on one psycopg connection per thread in autocommit mode: no pool
# checkout, ping, BEGIN or ROLLBACK around them. A clip deleted between the two is skipped by
# the search, as one deleted between the index search and the rows. Other databases go through
# the Core functions above on a pooled connection.

_SQLITE_CLIP_COLUMNS = (
    "c.id, c.name, c.format, c.content_hash, c.frame_count, c.frame_time, c.duration, "
    "c.joint_count, c.skeleton_family, c.lead_in_frames, c.created_at, c.source, c.licence, "
    "c.animations, c.warnings, c.joint_mapping"
)


def _parse_timestamp(value: Any) -> datetime:
    # SQLAlchemy stores SQLite DATETIMEs as ISO text without a time zone (we write UTC).
    if isinstance(value, datetime):
        return _utc(value)
    return _utc(datetime.fromisoformat(value))


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
            warnings=_json_warnings(row[14]),
            joint_mapping=_json_mapping(row[15]),
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
        for chunk in _chunks(ids):
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
        keys = _label_keys(self._db, label)
        if not keys:
            return np.zeros(0, dtype=np.int64)
        rows = self._db.execute(_labelled_sql(keys) + " ORDER BY l.clip_id", keys)
        return np.fromiter((r[0] for r in rows), dtype=np.int64)

    def frame_times(self, clip_ids: Sequence[int]) -> dict[int, tuple[str, float, int]]:
        found: dict[int, tuple[str, float, int]] = {}
        for chunk in _chunks([int(i) for i in clip_ids]):
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

    def frame_times(self, clip_ids: Sequence[int]) -> dict[int, tuple[str, float, int]]:
        found: dict[int, tuple[str, float, int]] = {}
        for chunk in _chunks(sorted({int(i) for i in clip_ids})):
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


# -- browsing (the web UI's list, label counts and map) ---------------------------------------


@dataclass(frozen=True)
class ClipSummary:
    """The few columns the library map shows per clip."""

    id: int
    name: str
    format: str
    duration: float
    frame_count: int
    labels: tuple[str, ...]


def clip_summaries(session: Session) -> list[ClipSummary]:
    """Every clip in id order with its labels, in two queries."""
    rows = session.execute(
        select(Clip.id, Clip.name, Clip.format, Clip.duration, Clip.frame_count).order_by(Clip.id)
    ).all()
    labels: dict[int, list[str]] = {}
    for clip_id, label in session.execute(
        select(ClipLabel.clip_id, ClipLabel.label).order_by(ClipLabel.clip_id, ClipLabel.position)
    ):
        labels.setdefault(clip_id, []).append(label)
    return [
        ClipSummary(
            id=clip_id,
            name=name,
            format=fmt,
            duration=duration,
            frame_count=frames,
            labels=tuple(labels.get(clip_id, ())),
        )
        for clip_id, name, fmt, duration, frames in rows
    ]


def _contains_pattern(text: str) -> str:
    """A LIKE pattern matching ``text`` anywhere, with % and _ taken literally."""
    escaped = text.replace("\\", "\\\\").replace("%", "\\%").replace("_", "\\_")
    return f"%{escaped}%"


def find_clip_ids(
    session: Session, *, name_contains: str | None, label: LabelFilter, limit: int, offset: int
) -> tuple[list[int], int]:
    """One page (id order) of the ids of clips whose name contains ``name_contains``
    (case-insensitive) and that carry every label of ``label``; and how many match in total."""
    conditions = _label_conditions(session, label)
    if name_contains:
        pattern = _contains_pattern(name_contains.lower())
        conditions.append(func.lower(Clip.name).like(pattern, escape="\\"))
    total = session.scalar(select(func.count()).select_from(Clip).where(*conditions)) or 0
    page = session.scalars(
        select(Clip.id).where(*conditions).order_by(Clip.id).limit(limit).offset(offset)
    )
    return list(page), int(total)


def label_counts(session: Session) -> list[tuple[str, int]]:
    """Every label in use (one spelling per case-insensitive label: the first in sort order)
    with its number of clips, most used first."""
    rows = session.execute(
        select(func.min(ClipLabel.label), func.count())
        .group_by(ClipLabel.label_key)
        .order_by(func.count().desc(), ClipLabel.label_key)
    ).all()
    return [(str(label), int(count)) for label, count in rows]
