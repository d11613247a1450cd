"""Rigs: characters' skeletons that clips are retargeted onto on download.

Revision ID: 0007
Revises: 0006
Create Date: 2026-11-25
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0007"
down_revision: str | Sequence[str] | None = "0006"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "rigs",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("name", sa.String(length=255), nullable=False),
        sa.Column("format", sa.String(length=16), nullable=False),
        sa.Column("filename", sa.String(length=255), nullable=False),
        sa.Column("joint_count", sa.Integer(), nullable=False),
        sa.Column("skeleton_family", sa.String(length=64), nullable=False),
        sa.Column("length_unit", sa.String(length=64), nullable=False),
        sa.Column("metres_per_unit", sa.Float(), nullable=False),
        sa.Column("skeleton", sa.Text(), nullable=False),
        sa.Column("joint_mapping", sa.Text(), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_rigs")),
        sqlite_autoincrement=True,
    )


def downgrade() -> None:
    op.drop_table("rigs")
