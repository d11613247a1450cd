"""Case-insensitive labels: clip_labels.label_key (the case-folded label) and a unique
(label_key, clip_id) index, so label filters compare keys through an index and a clip carries
one spelling of each label.

Existing rows get their key in Python (``str.casefold``, as the service computes it; SQL's
lower() folds only ASCII on SQLite); a clip holding a label in two spellings keeps the first.

Revision ID: 0005
Revises: 0003
Create Date: 2026-11-22
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0005"
down_revision: str | Sequence[str] | None = "0003"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

_BATCH = 5000


def upgrade() -> None:
    with op.batch_alter_table("clip_labels") as batch:
        batch.add_column(sa.Column("label_key", sa.String(length=100), nullable=True))
    labels = sa.table(
        "clip_labels",
        sa.column("clip_id", sa.Integer),
        sa.column("label", sa.String),
        sa.column("label_key", sa.String),
        sa.column("position", sa.Integer),
    )
    bind = op.get_bind()
    rows = bind.execute(
        sa.select(labels.c.clip_id, labels.c.label).order_by(labels.c.clip_id, labels.c.position)
    ).all()
    seen: set[tuple[int, str]] = set()
    keys: list[dict[str, object]] = []
    duplicates: list[dict[str, object]] = []
    for clip_id, label in rows:
        key = label.strip().casefold()
        if (clip_id, key) in seen:
            duplicates.append({"c": clip_id, "l": label})
        else:
            seen.add((clip_id, key))
            keys.append({"c": clip_id, "l": label, "k": key})
    match = (labels.c.clip_id == sa.bindparam("c")) & (labels.c.label == sa.bindparam("l"))
    for start in range(0, len(duplicates), _BATCH):
        bind.execute(labels.delete().where(match), duplicates[start : start + _BATCH])
    for start in range(0, len(keys), _BATCH):
        bind.execute(
            labels.update().where(match).values(label_key=sa.bindparam("k")),
            keys[start : start + _BATCH],
        )
    with op.batch_alter_table("clip_labels") as batch:
        batch.alter_column("label_key", existing_type=sa.String(length=100), nullable=False)
        batch.create_index(
            "ix_clip_labels_label_key_clip_id", ["label_key", "clip_id"], unique=True
        )


def downgrade() -> None:
    with op.batch_alter_table("clip_labels") as batch:
        batch.drop_index("ix_clip_labels_label_key_clip_id")
        batch.drop_column("label_key")
