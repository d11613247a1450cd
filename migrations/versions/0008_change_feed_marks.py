"""Change feed retention: marks of where the feed stood when, so old change rows can go.

``clip_changes`` grew forever. Now every server records, now and then, a *mark*: the feed's
position (``app.db.changes.horizon``) and the time. Change rows older than the newest mark
past the retention (``MOCAP_CHANGE_RETENTION_HOURS``) are deleted, and that mark is flagged
``pruned``: a reader (a replica, an index file) whose position is before it may have missed
changes and rebuilds its indexes from the database instead of following the feed.

Revision ID: 0008
Revises: 0007
Create Date: 2026-11-25
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0008"
down_revision: str | Sequence[str] | None = "0007"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "clip_change_marks",
        sa.Column("position", sa.BigInteger(), autoincrement=False, nullable=False),
        sa.Column("recorded_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("pruned", sa.Boolean(), server_default=sa.false(), nullable=False),
        sa.PrimaryKeyConstraint("position", name=op.f("pk_clip_change_marks")),
    )


def downgrade() -> None:
    op.drop_table("clip_change_marks")
