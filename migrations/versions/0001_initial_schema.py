"""Initial schema: clips, their files, labels and descriptor vectors.

Revision ID: 0001
Revises:
Create Date: 2026-11-22
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0001"
down_revision: str | Sequence[str] | None = None
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "clips",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("name", sa.String(length=255), nullable=False),
        sa.Column("format", sa.String(length=16), nullable=False),
        sa.Column("content_hash", sa.String(length=64), nullable=False),
        sa.Column("frame_count", sa.Integer(), nullable=False),
        sa.Column("frame_time", sa.Float(), nullable=False),
        sa.Column("duration", sa.Float(), nullable=False),
        sa.Column("joint_count", sa.Integer(), nullable=False),
        sa.Column("skeleton_family", sa.String(length=64), nullable=False),
        sa.Column("lead_in_frames", sa.Integer(), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_clips")),
        sa.UniqueConstraint("content_hash", name=op.f("uq_clips_content_hash")),
        sqlite_autoincrement=True,
    )
    op.create_table(
        "clip_files",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("clip_id", sa.Integer(), nullable=False),
        sa.Column("position", sa.Integer(), nullable=False),
        sa.Column("role", sa.String(length=16), nullable=False),
        sa.Column("filename", sa.String(length=255), nullable=False),
        sa.Column("sha256", sa.String(length=64), nullable=False),
        sa.Column("size", sa.Integer(), nullable=False),
        sa.ForeignKeyConstraint(
            ["clip_id"],
            ["clips.id"],
            name=op.f("fk_clip_files_clip_id_clips"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_clip_files")),
        sa.UniqueConstraint("clip_id", "role", name=op.f("uq_clip_files_clip_id_role")),
    )
    op.create_index(op.f("ix_clip_files_clip_id"), "clip_files", ["clip_id"])
    op.create_index(op.f("ix_clip_files_sha256"), "clip_files", ["sha256"])
    op.create_table(
        "clip_labels",
        sa.Column("clip_id", sa.Integer(), nullable=False),
        sa.Column("label", sa.String(length=100), nullable=False),
        sa.Column("position", sa.Integer(), nullable=False),
        sa.ForeignKeyConstraint(
            ["clip_id"],
            ["clips.id"],
            name=op.f("fk_clip_labels_clip_id_clips"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("clip_id", "label", name=op.f("pk_clip_labels")),
    )
    op.create_index("ix_clip_labels_label_clip_id", "clip_labels", ["label", "clip_id"])
    op.create_table(
        "clip_descriptors",
        sa.Column("clip_id", sa.Integer(), nullable=False),
        sa.Column("name", sa.String(length=64), nullable=False),
        sa.Column("version", sa.Integer(), nullable=False),
        sa.Column("dimension", sa.Integer(), nullable=False),
        sa.Column("vector", sa.LargeBinary(), nullable=False),
        sa.ForeignKeyConstraint(
            ["clip_id"],
            ["clips.id"],
            name=op.f("fk_clip_descriptors_clip_id_clips"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("clip_id", "name", name=op.f("pk_clip_descriptors")),
    )
    op.create_index("ix_clip_descriptors_name_version", "clip_descriptors", ["name", "version"])


def downgrade() -> None:
    op.drop_table("clip_descriptors")
    op.drop_table("clip_labels")
    op.drop_table("clip_files")
    op.drop_table("clips")
