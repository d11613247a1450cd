"""Clip windows: vectors of overlapping windows of each clip, for moments search.

Revision ID: 0004
Revises: 0002
Create Date: 2026-11-22
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0004"
down_revision: str | Sequence[str] | None = "0002"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "clip_windows",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("clip_id", sa.Integer(), nullable=False),
        sa.Column("name", sa.String(length=64), nullable=False),
        sa.Column("version", sa.Integer(), nullable=False),
        sa.Column("length", sa.Float(), nullable=False),
        sa.Column("start_frame", sa.Integer(), nullable=False),
        sa.Column("end_frame", sa.Integer(), nullable=False),
        sa.Column("vector", sa.LargeBinary(), nullable=False),
        sa.ForeignKeyConstraint(
            ["clip_id"],
            ["clips.id"],
            name=op.f("fk_clip_windows_clip_id_clips"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_clip_windows")),
        sqlite_autoincrement=True,
    )
    op.create_index(
        "ix_clip_windows_clip_id_name_length",
        "clip_windows",
        ["clip_id", "name", "version", "length", "start_frame", "end_frame"],
    )
    op.create_index(
        "ix_clip_windows_name_version_length", "clip_windows", ["name", "version", "length"]
    )
    op.create_index(
        "ix_clip_windows_span",
        "clip_windows",
        ["id", "clip_id", "start_frame", "end_frame", "length"],
    )


def downgrade() -> None:
    op.drop_table("clip_windows")
