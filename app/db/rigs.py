"""SQL for the ``rigs`` table: characters' skeletons to retarget onto.

Like :mod:`app.db.clips`, functions take a session, return frozen records and never
commit. The skeleton and mapping are JSON text; :mod:`app.services.rigs` turns them into the
motion core's objects.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

from sqlalchemy import delete, func, select
from sqlalchemy.orm import Session

from app.db.models import Rig


@dataclass(frozen=True)
class NewRig:
    name: str
    format: str
    filename: str
    joint_count: int
    skeleton_family: str
    length_unit: str
    metres_per_unit: float
    skeleton: dict[str, Any]
    joint_mapping: dict[str, Any]


@dataclass(frozen=True)
class RigRecord(NewRig):
    """A stored rig: what was stored, its id and when."""

    id: int
    created_at: datetime


def _record(row: Rig) -> RigRecord:
    created = row.created_at
    if created.tzinfo is None:  # SQLite keeps no time zone: the value was written in UTC
        created = created.replace(tzinfo=UTC)
    return RigRecord(
        id=row.id,
        name=row.name,
        format=row.format,
        filename=row.filename,
        joint_count=row.joint_count,
        skeleton_family=row.skeleton_family,
        length_unit=row.length_unit,
        metres_per_unit=row.metres_per_unit,
        skeleton=json.loads(row.skeleton),
        joint_mapping=json.loads(row.joint_mapping),
        created_at=created,
    )


def insert_rig(session: Session, new: NewRig) -> int:
    row = Rig(
        name=new.name,
        format=new.format,
        filename=new.filename,
        joint_count=new.joint_count,
        skeleton_family=new.skeleton_family,
        length_unit=new.length_unit,
        metres_per_unit=new.metres_per_unit,
        skeleton=json.dumps(new.skeleton, allow_nan=False),
        joint_mapping=json.dumps(new.joint_mapping, allow_nan=False),
        created_at=datetime.now(UTC),
    )
    session.add(row)
    session.flush()
    return row.id


def get_rig(session: Session, rig_id: int) -> RigRecord | None:
    row = session.get(Rig, rig_id)
    return None if row is None else _record(row)


def list_rigs(session: Session, *, limit: int, offset: int) -> tuple[list[RigRecord], int]:
    """One page of rigs in id order and how many there are."""
    rows = session.scalars(select(Rig).order_by(Rig.id).limit(limit).offset(offset)).all()
    total = session.scalar(select(func.count()).select_from(Rig)) or 0
    return [_record(row) for row in rows], int(total)


def delete_rig(session: Session, rig_id: int) -> bool:
    """Delete a rig; False when there was none."""
    result = session.execute(delete(Rig).where(Rig.id == rig_id))
    return bool(getattr(result, "rowcount", 0))


__all__ = ["NewRig", "RigRecord", "delete_rig", "get_rig", "insert_rig", "list_rigs"]
