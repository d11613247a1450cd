"""Label filters in SQL: the ids of the clips carrying every label asked for (any case)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from sqlalchemy import Select, exists, func, select
from sqlalchemy.orm import aliased

from app.db.models import Clip, ClipLabel
from app.db.rows import Executor
from app.labels import label_filter, label_key

LabelFilter = str | Sequence[str] | None
"""A ``label`` filter as :func:`app.labels.label_filter` reads it: clips carrying all of
the labels (any case); ``None``, ``""`` or ``[]`` = no filter."""

# Rows counted per label when choosing which label drives an all-of filter: enough to tell a
# rare label from a common one, cheap (an index range) even when millions carry it.
_COUNT_CAP = 10_000


def _label_keys(executor: Executor, labels: LabelFilter) -> list[str]:
    """The keys of the labels asked for, the rarest first (each counted up to _COUNT_CAP)."""
    keys = list(dict.fromkeys(label_key(label) for label in label_filter(labels)))
    if len(keys) < 2:
        return keys
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
    return sorted(keys, key=lambda k: counts[k] or 0)


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


def label_conditions(executor: Executor, labels: LabelFilter) -> list[Any]:
    """``[Clip.id IN (ids carrying every label)]``, or ``[]`` for no filter."""
    keys = _label_keys(executor, labels)
    return [Clip.id.in_(_labelled_ids(keys))] if keys else []


def clip_ids_with_label(session: Executor, label: LabelFilter) -> np.ndarray:
    """``(N,)`` int64 ids of the clips carrying every label of ``label`` (any case)."""
    keys = _label_keys(session, label)
    if not keys:
        return np.zeros(0, dtype=np.int64)
    query = _labelled_ids(keys).order_by(ClipLabel.clip_id)
    return np.fromiter(session.scalars(query), dtype=np.int64)


def clip_ids_with_labels(session: Executor, labels: LabelFilter) -> list[int]:
    """Ids (ascending) of the clips carrying every label of ``labels``; every clip when the
    filter is empty."""
    return list(
        session.scalars(select(Clip.id).where(*label_conditions(session, labels)).order_by(Clip.id))
    )
