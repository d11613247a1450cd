"""Clip descriptor vectors (``clip_descriptors``): what the clip indexes are built from.

Vectors are ``(D,)`` float32 in memory; batches ``(N, D)`` float32 with ``(N,)`` int64 clip
ids (see :mod:`app.db.rows`).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from sqlalchemy import delete, func, select
from sqlalchemy.orm import Session

from app.db.models import Clip, ClipDescriptor
from app.db.rows import (
    Executor,
    decode_vector,
    encode_vector,
    select_in,
    streamed_vector_arrays,
    vector_arrays,
)


@dataclass(frozen=True)
class StoredVector:
    """A descriptor vector as stored: ``vector`` is ``(dimension,)`` float32."""

    version: int
    vector: np.ndarray


# Every column, in the models' order: the order of the tuples inserted by insert_values.
VECTOR_COLUMNS = tuple(ClipDescriptor.__table__.columns.keys())  # clip_id, name, ... vector


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
    return streamed_vector_arrays(session, query.order_by(ClipDescriptor.clip_id), dimension)


def load_vectors_of(
    session: Executor, name: str, version: int, dimension: int, clip_ids: Iterable[int]
) -> tuple[np.ndarray, np.ndarray]:
    """Like :func:`load_vectors`, for the given clips only (those that have such a vector)."""
    query = select(ClipDescriptor.clip_id, ClipDescriptor.vector).where(
        _vector_filter(name, version, dimension)
    )
    return vector_arrays(select_in(session, query, ClipDescriptor.clip_id, clip_ids), dimension)


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
    for clip_id in session.scalars(select(Clip.id).order_by(Clip.id)):
        stored = have.get(clip_id, {})
        missing = [n for n, v in current.items() if stored.get(n) != v]
        if missing:
            needing[clip_id] = missing
    return needing
