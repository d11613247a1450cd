"""Clips with their files and labels (``clips``, ``clip_files``, ``clip_labels``): the
records the service passes around, and their reads and writes.

Inserting a clip also inserts its vectors and windows (one multi-row statement per table).
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

from sqlalchemy import Select, delete, func, insert, select
from sqlalchemy.orm import Session, selectinload

from app.db.clip_filters import MAX_ID, ClipFilter, clip_conditions
from app.db.label_filters import LabelFilter
from app.db.models import Clip, ClipDescriptor, ClipFile, ClipLabel, ClipWindow
from app.db.rows import Executor, chunks, encode_vector, insert_values, utc
from app.db.vectors import VECTOR_COLUMNS, StoredVector
from app.db.windows import WINDOW_COLUMNS, NewWindows, window_rows
from app.labels import label_key


@dataclass(frozen=True)
class FileRecord:
    """One uploaded part of a clip, stored as ``files/<sha256[:2]>/<sha256>``."""

    role: str  # "file" (BVH) | "skeleton" (ASF) | "motion" (AMC)
    filename: str
    sha256: str
    size: int


@dataclass(frozen=True)
class AnimationRecord:
    """One animation of a multi-animation file (FBX, glTF); ``selected``: the clip's own."""

    name: str
    frame_count: int
    duration: float
    selected: bool


def encode_animations(animations: Sequence[AnimationRecord] | None) -> str | None:
    # "seconds": the frames' cover (frame_count / rate), as a clip's duration counts; rows
    # written before it have "duration", first to last key (see decode_animations).
    if animations is None:
        return None
    return json.dumps(
        [
            {"name": a.name, "frame_count": a.frame_count, "seconds": a.duration}
            | ({"selected": True} if a.selected else {})
            for a in animations
        ]
    )


def _covered_seconds(animation: Mapping[str, Any]) -> float:
    """An animation's seconds as a clip's ``duration`` counts them: ``frame_count / rate``.
    Older rows kept ``(frame_count - 1) / rate`` (first to last key), which disagreed with
    the clip's own duration: scaled by ``n / (n - 1)`` (a lone frame's rate is unknown)."""
    if "seconds" in animation:
        return float(animation["seconds"])
    frames, first_to_last = int(animation["frame_count"]), float(animation["duration"])
    return first_to_last * frames / (frames - 1) if frames > 1 else first_to_last


def decode_animations(text: str | None) -> tuple[AnimationRecord, ...] | None:
    if text is None:
        return None
    return tuple(
        AnimationRecord(
            str(a["name"]), int(a["frame_count"]), _covered_seconds(a), bool(a.get("selected"))
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


def json_warnings(text: str | None) -> tuple[str, ...]:
    """The stored warnings (JSON text, ``'[]'`` by default) as a tuple."""
    return tuple(json.loads(text)) if text else ()


def json_mapping(text: str | None) -> dict[str, object] | None:
    """The stored joint mapping (JSON text or NULL for clips described before #10)."""
    return json.loads(text) if text else None


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
    for chunk in chunks(ids):
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
            created_at=utc(row[10]),
            labels=tuple(labels.get(int(row[0]), ())),
            files=tuple(files.get(int(row[0]), ())),
            source=row[11],
            licence=row[12],
            animations=decode_animations(row[13]),
            warnings=json_warnings(row[14]),
            joint_mapping=json_mapping(row[15]),
        )
        for row in rows
    }


def get_clip(session: Executor, clip_id: int) -> ClipRecord | None:
    if not 0 < clip_id <= MAX_ID:  # names no clip, and no database driver can send it
        return None
    rows = session.execute(_clip_rows().where(Clip.id == clip_id)).all()
    return _records(session, rows).get(clip_id)


def get_clips(session: Executor, clip_ids: Iterable[int]) -> dict[int, ClipRecord]:
    """The clips among ``clip_ids`` that exist, by id (an id past the databases' signed 64
    bits names none, and no driver can send it)."""
    ids = sorted({int(i) for i in clip_ids if 0 < int(i) <= MAX_ID})
    rows: list[Any] = []
    for chunk in chunks(ids):
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
    for chunk in chunks(wanted):
        rows = session.execute(
            select(Clip.content_hash, Clip.id).where(Clip.content_hash.in_(chunk))
        )
        found.update({h: i for h, i in rows})
    return found


# What a list may be sorted by (``-`` in front: descending); ties go by id.
SORT_KEYS: dict[str, Any] = {
    "id": Clip.id,
    "name": func.lower(Clip.name),
    "created_at": Clip.created_at,
    "duration": Clip.duration,
    "frame_count": Clip.frame_count,
}


def list_clips(
    session: Session,
    *,
    selection: ClipFilter | None = None,
    label: LabelFilter = None,
    sort: str = "id",
    limit: int,
    offset: int,
) -> tuple[list[ClipRecord], int]:
    """One page of the clips ``selection`` keeps (or those carrying every label of
    ``label``), ordered by ``sort`` (a key of :data:`SORT_KEYS`, ``-`` in front for
    descending, then by id), and how many match in total."""
    if selection is None:
        selection = ClipFilter.of(label=label)
    descending = sort.startswith("-")
    key = SORT_KEYS[sort.removeprefix("-")]
    order = [key.desc() if descending else key.asc()]
    if key is not Clip.id:
        order.append(Clip.id.desc() if descending else Clip.id.asc())
    conditions = clip_conditions(session, selection)
    query = _clip_rows().where(*conditions).order_by(*order)
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
    insert_values(
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
    insert_values(
        connection,
        ClipWindow,
        WINDOW_COLUMNS,
        [
            row
            for clip_id, new in zip(ids, clips, strict=True)
            for row in window_rows(clip_id, new.windows)
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


def content_hashes(session: Session, clip_ids: Sequence[int]) -> list[str]:
    """The content hashes of the clips ``clip_ids`` (those that exist)."""
    hashes: list[str] = []
    for chunk in chunks(sorted({int(i) for i in clip_ids})):
        hashes.extend(session.scalars(select(Clip.content_hash).where(Clip.id.in_(chunk))))
    return hashes


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


def delete_clips(session: Session, clip_ids: Sequence[int]) -> list[str]:
    """Delete clips (files, labels and vectors cascade); returns their files' sha256s."""
    shas: list[str] = []
    for chunk in chunks(sorted({int(i) for i in clip_ids})):
        shas.extend(session.scalars(select(ClipFile.sha256).where(ClipFile.clip_id.in_(chunk))))
        session.execute(delete(Clip).where(Clip.id.in_(chunk)))
    return shas


def referenced_blobs(session: Session, shas: Iterable[str]) -> set[str]:
    """The sha256s among ``shas`` still used by some clip."""
    wanted = sorted(set(shas))
    if not wanted:
        return set()
    return set(session.scalars(select(ClipFile.sha256).where(ClipFile.sha256.in_(wanted))))
