"""Change feed (clip_changes, filled by triggers) and stored files in the database (blobs).

Revision ID: 0003
Revises: 0002
Create Date: 2026-11-22

``clip_changes`` gets a row for every clip inserted or deleted and every vector updated, from
triggers, so every writer (any process, any code path, cascades included) feeds it; see
``app/db/changes.py`` for how readers follow it. On PostgreSQL each row carries the writing
transaction's id. ``blobs`` holds uploaded files on PostgreSQL (created on SQLite too, where it
stays empty, so both databases have one schema).
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0003"
down_revision: str | Sequence[str] | None = "0002"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

# (trigger, table, event, the changed clip's id)
TRIGGERS = (
    ("clip_changes_clip_inserted", "clips", "INSERT", "NEW.id"),
    ("clip_changes_clip_deleted", "clips", "DELETE", "OLD.id"),
    ("clip_changes_vector_updated", "clip_descriptors", "UPDATE", "NEW.clip_id"),
)


def upgrade() -> None:
    op.create_table(
        "clip_changes",
        sa.Column("seq", sa.BigInteger().with_variant(sa.Integer(), "sqlite"), nullable=False),
        sa.Column("clip_id", sa.Integer(), nullable=False),
        sa.Column("txid", sa.BigInteger(), nullable=True),
        sa.PrimaryKeyConstraint("seq", name=op.f("pk_clip_changes")),
        sqlite_autoincrement=True,
    )
    op.create_index("ix_clip_changes_txid", "clip_changes", ["txid"])
    op.create_table(
        "blobs",
        sa.Column("sha256", sa.String(length=64), nullable=False),
        sa.Column("size", sa.Integer(), nullable=False),
        sa.Column("data", sa.LargeBinary(), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("sha256", name=op.f("pk_blobs")),
    )
    if op.get_context().dialect.name == "postgresql":
        for name, table, event, clip_id in TRIGGERS:
            op.execute(
                f"CREATE FUNCTION {name}() RETURNS trigger LANGUAGE plpgsql AS $$ BEGIN "
                f"INSERT INTO clip_changes (clip_id, txid) "
                f"VALUES ({clip_id}, pg_current_xact_id()::text::bigint); RETURN NULL; END $$"
            )
            op.execute(
                f"CREATE TRIGGER {name} AFTER {event} ON {table} "
                f"FOR EACH ROW EXECUTE FUNCTION {name}()"
            )
    else:
        for name, table, event, clip_id in TRIGGERS:
            op.execute(
                f"CREATE TRIGGER {name} AFTER {event} ON {table} FOR EACH ROW BEGIN "
                f"INSERT INTO clip_changes (clip_id) VALUES ({clip_id}); END"
            )


def downgrade() -> None:
    postgres = op.get_context().dialect.name == "postgresql"
    for name, table, _, _ in TRIGGERS:
        op.execute(f"DROP TRIGGER {name} ON {table}" if postgres else f"DROP TRIGGER {name}")
        if postgres:
            op.execute(f"DROP FUNCTION {name}()")
    op.drop_table("blobs")
    op.drop_index("ix_clip_changes_txid", table_name="clip_changes")
    op.drop_table("clip_changes")
