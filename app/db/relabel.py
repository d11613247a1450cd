"""Adding and removing labels on many clips at once (``POST /clips/labels``).

Set-based: one INSERT ... SELECT per label added and one DELETE for those removed, over the
clips a :class:`~app.db.clip_filters.ClipFilter` keeps, whatever their number; the caller's
transaction makes it all or nothing.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from sqlalchemy import delete, exists, func, insert, literal, select
from sqlalchemy.orm import Session, aliased

from app.db.clip_filters import ClipFilter, clip_conditions
from app.db.models import Clip, ClipLabel
from app.errors import InvalidInput
from app.labels import MAX_LABELS, label_key


@dataclass(frozen=True)
class Relabelled:
    matched: int  # clips the selection kept
    changed: int  # of those, clips whose labels changed


def relabel(
    session: Session, selection: ClipFilter, *, add: Sequence[str], remove: Sequence[str]
) -> Relabelled:
    """Add the labels ``add`` (normalised; each at the end of a clip's labels, unless the clip
    carries it in some case already) and remove ``remove`` (any case) on every clip
    ``selection`` keeps.

    Raises
    ------
    InvalidInput
        A clip would carry more than :data:`~app.labels.MAX_LABELS` labels.
    """
    # Not correlated with the statements it is used in, which read ``clips`` themselves.
    chosen = (
        select(Clip.id)
        .where(*clip_conditions(session, selection))
        .correlate(None)
        .scalar_subquery()
    )
    matched = session.scalar(select(func.count()).where(Clip.id.in_(chosen))) or 0
    changed: set[int] = set()
    drop = sorted({label_key(label) for label in remove})
    if drop:
        gone = session.execute(
            delete(ClipLabel)
            .where(ClipLabel.clip_id.in_(chosen), ClipLabel.label_key.in_(drop))
            .returning(ClipLabel.clip_id)
        )
        changed.update(int(i) for i in gone.scalars())
    for label in add:
        key = label_key(label)
        if key in drop:
            continue
        carried = aliased(ClipLabel)
        last = aliased(ClipLabel)
        position = select(func.coalesce(func.max(last.position) + 1, 0)).where(
            last.clip_id == Clip.id
        )
        rows = (
            select(Clip.id, literal(label), literal(key), position.scalar_subquery())
            .where(Clip.id.in_(chosen))
            .where(~exists().where(carried.clip_id == Clip.id, carried.label_key == key))
        )
        added = session.execute(
            insert(ClipLabel)
            .from_select(["clip_id", "label", "label_key", "position"], rows)
            .returning(ClipLabel.clip_id)
        )
        changed.update(int(i) for i in added.scalars())
    crowded = session.scalar(
        select(ClipLabel.clip_id)
        .where(ClipLabel.clip_id.in_(chosen))
        .group_by(ClipLabel.clip_id)
        .having(func.count() > MAX_LABELS)
        .limit(1)
    )
    if crowded is not None:
        raise InvalidInput(f"add: clip {crowded} would carry more than {MAX_LABELS} labels")
    return Relabelled(matched=int(matched), changed=len(changed))
