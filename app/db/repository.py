"""All SQL of the service, as functions over a :class:`~sqlalchemy.orm.Session`.

Functions return plain frozen records (never ORM objects), so callers may use them after the
session is closed. Transactions are the caller's: nothing here commits.

Vectors are stored as little-endian float32 bytes; in memory they are ``(D,)`` float32 arrays,
and batches are ``(N, D)`` float32 C-contiguous with ``(N,)`` int64 clip ids.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime

import numpy as np
from sqlalchemy import Select, func, select
from sqlalchemy.orm import Session, selectinload

from app.db.models import Clip, ClipDescriptor, ClipFile, ClipLabel

VECTOR_DTYPE = np.dtype("<f4")


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

    @property
    def filenames(self) -> list[str]:
        return [f.filename for f in self.files]


def encode_vector(vector: np.ndarray) -> bytes:
    return np.ascontiguousarray(vector, dtype=VECTOR_DTYPE).tobytes()


def decode_vector(blob: bytes) -> np.ndarray:
    """``(D,)`` float32 (native byte order, writable) from stored bytes."""
    return np.frombuffer(blob, dtype=VECTOR_DTYPE).astype(np.float32)


def _utc(value: datetime) -> datetime:
    # SQLite keeps no time zone; every timestamp we write is UTC.
    return value if value.tzinfo is not None else value.replace(tzinfo=UTC)


def _record(clip: Clip) -> ClipRecord:
    return ClipRecord(
        id=clip.id,
        name=clip.name,
        format=clip.format,
        content_hash=clip.content_hash,
        frame_count=clip.frame_count,
        frame_time=clip.frame_time,
        duration=clip.duration,
        joint_count=clip.joint_count,
        skeleton_family=clip.skeleton_family,
        lead_in_frames=clip.lead_in_frames,
        created_at=_utc(clip.created_at),
        labels=tuple(label.label for label in clip.labels),
        files=tuple(FileRecord(f.role, f.filename, f.sha256, f.size) for f in clip.files),
    )


def _clips() -> Select[Clip]:
    return select(Clip).options(selectinload(Clip.labels), selectinload(Clip.files))


def _with_label(label: str) -> Select[int]:
    return select(ClipLabel.clip_id).where(ClipLabel.label == label)


# -- clips --------------------------------------------------------------------------------


def get_clip(session: Session, clip_id: int) -> ClipRecord | None:
    clip = session.scalars(_clips().where(Clip.id == clip_id)).one_or_none()
    return None if clip is None else _record(clip)


def get_clips(session: Session, clip_ids: Iterable[int]) -> dict[int, ClipRecord]:
    """The clips among ``clip_ids`` that exist, by id."""
    ids = sorted({int(i) for i in clip_ids})
    found: dict[int, ClipRecord] = {}
    for start in range(0, len(ids), 500):  # stay far below any backend's parameter limit
        chunk = ids[start : start + 500]
        for clip in session.scalars(_clips().where(Clip.id.in_(chunk))):
            found[clip.id] = _record(clip)
    return found


def get_clip_by_hash(session: Session, content_hash: str) -> ClipRecord | None:
    clip = session.scalars(_clips().where(Clip.content_hash == content_hash)).one_or_none()
    return None if clip is None else _record(clip)


def clip_ids_by_hash(session: Session, hashes: Iterable[str]) -> dict[str, int]:
    """``content_hash -> id`` for the hashes already stored."""
    wanted = sorted(set(hashes))
    found: dict[str, int] = {}
    for start in range(0, len(wanted), 500):
        rows = session.execute(
            select(Clip.content_hash, Clip.id).where(
                Clip.content_hash.in_(wanted[start : start + 500])
            )
        )
        found.update({h: i for h, i in rows})
    return found


def list_clips(
    session: Session, *, label: str | None, limit: int, offset: int
) -> tuple[list[ClipRecord], int]:
    """One page of clips in id order, and how many match in total."""
    query = _clips().order_by(Clip.id)
    count = select(func.count()).select_from(Clip)
    if label is not None:
        query = query.where(Clip.id.in_(_with_label(label)))
        count = count.where(Clip.id.in_(_with_label(label)))
    total = session.scalar(count) or 0
    clips = session.scalars(query.limit(limit).offset(offset)).all()
    return [_record(c) for c in clips], total


def count_clips(session: Session) -> int:
    return session.scalar(select(func.count()).select_from(Clip)) or 0


def all_clip_ids(session: Session) -> list[int]:
    return list(session.scalars(select(Clip.id).order_by(Clip.id)))


def insert_clip(session: Session, new: NewClip) -> int:
    """Add a clip with its files, labels and vectors; returns the new id (flushed)."""
    clip = Clip(
        name=new.name,
        format=new.format,
        content_hash=new.content_hash,
        frame_count=new.frame_count,
        frame_time=new.frame_time,
        duration=new.duration,
        joint_count=new.joint_count,
        skeleton_family=new.skeleton_family,
        lead_in_frames=new.lead_in_frames,
        created_at=new.created_at,
    )
    clip.files = [
        ClipFile(position=i, role=f.role, filename=f.filename, sha256=f.sha256, size=f.size)
        for i, f in enumerate(new.files)
    ]
    clip.labels = [ClipLabel(label=label, position=i) for i, label in enumerate(new.labels)]
    clip.descriptors = [
        ClipDescriptor(
            name=name,
            version=stored.version,
            dimension=int(stored.vector.shape[0]),
            vector=encode_vector(stored.vector),
        )
        for name, stored in new.vectors.items()
    ]
    session.add(clip)
    session.flush()
    return clip.id


def update_clip(
    session: Session,
    clip_id: int,
    *,
    name: str | None = None,
    labels: Sequence[str] | None = None,
    analysis: Mapping[str, object] | None = None,
) -> bool:
    """Change a clip's name, labels and/or measured fields; False when it does not exist."""
    clip = session.get(Clip, clip_id, options=[selectinload(Clip.labels)])
    if clip is None:
        return False
    if name is not None:
        clip.name = name
    if labels is not None:
        clip.labels = []
        session.flush()  # delete the old rows before inserting ones with the same key
        clip.labels = [ClipLabel(label=label, position=i) for i, label in enumerate(labels)]
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


def referenced_blobs(session: Session, shas: Iterable[str]) -> set[str]:
    """The sha256s among ``shas`` still used by some clip."""
    wanted = sorted(set(shas))
    if not wanted:
        return set()
    return set(session.scalars(select(ClipFile.sha256).where(ClipFile.sha256.in_(wanted))))


# -- labels -------------------------------------------------------------------------------


def clip_ids_with_label(session: Session, label: str) -> np.ndarray:
    """``(N,)`` int64 ids of the clips carrying ``label``."""
    return np.fromiter(session.scalars(_with_label(label)), dtype=np.int64)


# -- vectors ------------------------------------------------------------------------------


def get_vectors(session: Session, clip_id: int) -> dict[str, StoredVector]:
    """Every stored vector of a clip, by descriptor name."""
    rows = session.scalars(
        select(ClipDescriptor)
        .where(ClipDescriptor.clip_id == clip_id)
        .order_by(ClipDescriptor.name)
    )
    return {r.name: StoredVector(r.version, decode_vector(r.vector)) for r in rows}


def get_vector(session: Session, clip_id: int, name: str) -> StoredVector | None:
    row = session.get(ClipDescriptor, (clip_id, name))
    return None if row is None else StoredVector(row.version, decode_vector(row.vector))


def vector_ids(session: Session, name: str, version: int, dimension: int) -> np.ndarray:
    """``(N,)`` int64 sorted ids of the clips whose ``name`` vector :func:`load_vectors`
    returns (that ``version`` and ``dimension``)."""
    ids = session.scalars(
        select(ClipDescriptor.clip_id)
        .where(
            ClipDescriptor.name == name,
            ClipDescriptor.version == version,
            ClipDescriptor.dimension == dimension,
        )
        .order_by(ClipDescriptor.clip_id)
    )
    return np.fromiter(ids, dtype=np.int64)


def load_vectors(
    session: Session, name: str, version: int, dimension: int
) -> tuple[np.ndarray, np.ndarray]:
    """All ``name`` vectors of ``version``: ids ``(N,)`` int64 and vectors ``(N, D)`` float32.

    Rows whose stored dimension differs from ``dimension`` are skipped (they can only come from
    an older descriptor and are recomputed by ``mocap-index reindex``).
    """
    rows = session.execute(
        select(ClipDescriptor.clip_id, ClipDescriptor.vector)
        .where(
            ClipDescriptor.name == name,
            ClipDescriptor.version == version,
            ClipDescriptor.dimension == dimension,
        )
        .order_by(ClipDescriptor.clip_id)
    ).all()
    ids = np.fromiter((r[0] for r in rows), dtype=np.int64, count=len(rows))
    vectors = np.empty((len(rows), dimension), dtype=np.float32)
    for i, row in enumerate(rows):
        vectors[i] = np.frombuffer(row[1], dtype=VECTOR_DTYPE)
    return ids, vectors


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
