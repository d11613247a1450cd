"""Clip windows: vectors of overlapping windows of each clip, for moments search.

Revision ID: 0004
Revises: 0005
Create Date: 2026-11-22

A window's id is ``clip id << 20 | ordinal`` (``app.db.repository.WINDOW_ID_BITS``), set by
the writer. Windows come and go with their clip, which the change feed (0003) already records;
the trigger here adds a feed row when a clip's windows are written again (``mocap-index
reindex`` rewrites them from ordinal 0), so every process's window indexes follow that too.
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0004"
down_revision: str | Sequence[str] | None = "0005"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

TRIGGER = "clip_changes_windows_written"
FIRST_WINDOW = "(NEW.id & 1048575) = 0"  # ordinal 0: once per clip's windows written


def upgrade() -> None:
    op.create_table(
        "clip_windows",
        sa.Column("id", sa.BigInteger().with_variant(sa.Integer(), "sqlite"), nullable=False),
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
    if op.get_context().dialect.name == "postgresql":
        op.execute(
            f"CREATE FUNCTION {TRIGGER}() RETURNS trigger LANGUAGE plpgsql AS $$ BEGIN "
            "INSERT INTO clip_changes (clip_id, txid) "
            "VALUES (NEW.clip_id, pg_current_xact_id()::text::bigint); RETURN NULL; END $$"
        )
        op.execute(
            f"CREATE TRIGGER {TRIGGER} AFTER INSERT ON clip_windows FOR EACH ROW "
            f"WHEN ({FIRST_WINDOW}) EXECUTE FUNCTION {TRIGGER}()"
        )
    else:
        op.execute(
            f"CREATE TRIGGER {TRIGGER} AFTER INSERT ON clip_windows FOR EACH ROW "
            f"WHEN {FIRST_WINDOW} BEGIN INSERT INTO clip_changes (clip_id) "
            "VALUES (NEW.clip_id); END"
        )


def downgrade() -> None:
    if op.get_context().dialect.name == "postgresql":
        op.execute(f"DROP TRIGGER {TRIGGER} ON clip_windows")
        op.execute(f"DROP FUNCTION {TRIGGER}()")
    else:
        op.execute(f"DROP TRIGGER {TRIGGER}")
    op.drop_table("clip_windows")
