"""Clip updates on the change feed: a renamed, relabelled or re-licensed clip gets a feed row.

Revision ID: 0009
Revises: 0008
Create Date: 2026-11-25

The change feed (0003) recorded clips inserted and deleted and vectors updated: enough for
the indexes, which hold vectors. The in-memory catalogue of issue 23 holds what a search shows
of each clip (name, labels, source, licence, ...), so every process must also learn when those
change. Triggers, as in 0003, so no writer can forget it: an UPDATE of a clip's row, and a
label added to or removed from a clip (``clip_labels`` rows; a relabel deletes and inserts
them). A clip inserted with labels gets a row per label besides its own, and a deleted clip
one per label: the feed names clips, and readers apply each named clip once per poll.
"""

from __future__ import annotations

from collections.abc import Sequence

from alembic import op

revision: str = "0009"
down_revision: str | Sequence[str] | None = "0008"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

# (trigger, table, event, the changed clip's id)
TRIGGERS = (
    ("clip_changes_clip_updated", "clips", "UPDATE", "NEW.id"),
    ("clip_changes_label_added", "clip_labels", "INSERT", "NEW.clip_id"),
    ("clip_changes_label_removed", "clip_labels", "DELETE", "OLD.clip_id"),
)


def upgrade() -> None:
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
