"""Browsing the library (the web UI's list, label counts and map): reads over every clip."""

from __future__ import annotations

from dataclasses import dataclass

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from app.db.label_filters import LabelFilter, label_conditions
from app.db.models import Clip, ClipLabel


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
    conditions = label_conditions(session, label)
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


def licence_counts(session: Session) -> list[tuple[str, int]]:
    """Every licence in use (one spelling per licence compared as filters compare them:
    trimmed, any case) with its number of clips, most used first; clips without one are not
    counted."""
    key = func.lower(func.trim(Clip.licence))
    rows = session.execute(
        select(func.min(func.trim(Clip.licence)), func.count())
        .where(Clip.licence.is_not(None), key != "")
        .group_by(key)
        .order_by(func.count().desc(), key)
    ).all()
    return [(str(licence), int(count)) for licence, count in rows]
