"""Clip details: reading warnings, joint mapping, source and licence, animation list.

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-22
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0002"
down_revision: str | Sequence[str] | None = "0001"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    # batch mode: SQLite cannot ALTER a table in place beyond adding plain columns.
    with op.batch_alter_table("clips") as batch:
        batch.add_column(sa.Column("warnings", sa.Text(), server_default="[]", nullable=False))
        batch.add_column(sa.Column("joint_mapping", sa.Text(), nullable=True))
        batch.add_column(sa.Column("source", sa.String(length=500), nullable=True))
        batch.add_column(sa.Column("licence", sa.String(length=500), nullable=True))
        batch.add_column(sa.Column("animations", sa.Text(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("clips") as batch:
        for column in ("animations", "licence", "source", "joint_mapping", "warnings"):
            batch.drop_column(column)
