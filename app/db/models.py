"""Database tables. The schema is created and changed only by the Alembic migrations in
``migrations/``; ``tests/db`` checks that these models and the migrations agree.

Tables
------
clips
    One row per stored clip: what was uploaded and what the motion core measured.
    Besides the measured facts it keeps, as JSON text, the reading warnings, the joint
    mapping and a multi-animation file's animation list, and the uploader's source/licence.
clip_files
    The uploaded parts of a clip (one for BVH; skeleton + motion for ASF/AMC), each kept as a
    content-addressed file named by its sha256.
clip_labels
    Free-form tags, one row per (clip, label), with ``label_key`` the case-folded label
    (``app.labels.label_key``): filters compare keys, through the unique (key, clip) index,
    which also keeps one spelling of a label per clip.
clip_descriptors
    The descriptor vectors (float32 bytes) with the descriptor version that produced them.
    The FAISS indexes are rebuilt from this table.
clip_windows
    Vectors of overlapping windows of a clip (moments search), one row per (descriptor,
    window): its length in seconds and its frames ``[start_frame, end_frame)`` of the file as
    uploaded (lead-in included). The window indexes are rebuilt from this table; a window's id
    is ``clip id << 20 | ordinal`` (see ``app.db.windows.WINDOW_ID_BITS``), so an index finds a
    clip's windows by their ids.
clip_changes
    The change feed the indexes of every process follow: one row per clip inserted, updated
    or deleted (and per vector updated), written by database triggers (migration 0003), with
    the writing transaction's id on PostgreSQL. See :mod:`app.db.changes`.
clip_change_marks
    Where the change feed stood when (recorded now and then by every server), so change rows
    older than the retention can be deleted; the mark they were deleted up to is ``pruned``.
    See :mod:`app.db.changes`.
rigs
    Characters' skeletons clips can be retargeted onto (``GET /clips/{id}/file?rig=``): the
    skeleton and its reference pose as JSON (names, parents, offsets, end sites, rotations),
    its joint mapping and length unit. Not in any index: nothing searches rigs.
blobs
    The uploaded files themselves, by sha256, when the database is PostgreSQL (so a replica
    on another machine needs nothing but the database); SQLite keeps them in a directory.
"""

from __future__ import annotations

from datetime import datetime

from sqlalchemy import (
    BigInteger,
    Boolean,
    DateTime,
    Float,
    ForeignKey,
    Index,
    Integer,
    LargeBinary,
    MetaData,
    String,
    Text,
    UniqueConstraint,
    false,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column, relationship

# Deterministic constraint names, so migrations can refer to them on every backend.
NAMING_CONVENTION = {
    "ix": "ix_%(column_0_label)s",
    "uq": "uq_%(table_name)s_%(column_0_N_name)s",
    "ck": "ck_%(table_name)s_%(constraint_name)s",
    "fk": "fk_%(table_name)s_%(column_0_name)s_%(referred_table_name)s",
    "pk": "pk_%(table_name)s",
}


class Base(DeclarativeBase):
    metadata = MetaData(naming_convention=NAMING_CONVENTION)


class Clip(Base):
    __tablename__ = "clips"
    # AUTOINCREMENT on SQLite: ids of deleted clips are never handed out again.
    __table_args__ = ({"sqlite_autoincrement": True},)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    name: Mapped[str] = mapped_column(String(255))
    format: Mapped[str] = mapped_column(String(16))
    content_hash: Mapped[str] = mapped_column(String(64), unique=True)
    frame_count: Mapped[int] = mapped_column(Integer)
    frame_time: Mapped[float] = mapped_column(Float)
    duration: Mapped[float] = mapped_column(Float)
    joint_count: Mapped[int] = mapped_column(Integer)
    skeleton_family: Mapped[str] = mapped_column(String(64))
    lead_in_frames: Mapped[int] = mapped_column(Integer)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))
    # JSON text: what reading the file noticed ("3 lines after the last frame ignored", ...).
    warnings: Mapped[str] = mapped_column(Text, server_default="[]")
    # JSON text: canonical joint -> source joint, and how each was found; NULL for clips
    # stored before it was recorded (and for synthetic clips).
    joint_mapping: Mapped[str | None] = mapped_column(Text, nullable=True)
    # Where the clip comes from and under which terms it may be used, as the uploader said.
    source: Mapped[str | None] = mapped_column(String(500), nullable=True)
    licence: Mapped[str | None] = mapped_column(String(500), nullable=True)
    # JSON text: the animations a multi-animation file (FBX, glTF) holds; NULL for others.
    animations: Mapped[str | None] = mapped_column(Text, nullable=True)

    files: Mapped[list[ClipFile]] = relationship(
        back_populates="clip",
        cascade="all, delete-orphan",
        passive_deletes=True,
        order_by="ClipFile.position",
    )
    labels: Mapped[list[ClipLabel]] = relationship(
        back_populates="clip",
        cascade="all, delete-orphan",
        passive_deletes=True,
        order_by="ClipLabel.position",
    )
    descriptors: Mapped[list[ClipDescriptor]] = relationship(
        back_populates="clip", cascade="all, delete-orphan", passive_deletes=True
    )
    windows: Mapped[list[ClipWindow]] = relationship(
        cascade="all, delete-orphan", passive_deletes=True
    )


class ClipFile(Base):
    __tablename__ = "clip_files"
    __table_args__ = (UniqueConstraint("clip_id", "role"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    clip_id: Mapped[int] = mapped_column(ForeignKey("clips.id", ondelete="CASCADE"), index=True)
    position: Mapped[int] = mapped_column(Integer)
    role: Mapped[str] = mapped_column(String(16))  # "file" | "skeleton" | "motion"
    filename: Mapped[str] = mapped_column(String(255))
    sha256: Mapped[str] = mapped_column(String(64), index=True)
    size: Mapped[int] = mapped_column(Integer)

    clip: Mapped[Clip] = relationship(back_populates="files")


class ClipLabel(Base):
    __tablename__ = "clip_labels"
    __table_args__ = (
        Index("ix_clip_labels_label_clip_id", "label", "clip_id"),
        Index("ix_clip_labels_label_key_clip_id", "label_key", "clip_id", unique=True),
    )

    clip_id: Mapped[int] = mapped_column(
        ForeignKey("clips.id", ondelete="CASCADE"), primary_key=True
    )
    label: Mapped[str] = mapped_column(String(100), primary_key=True)
    label_key: Mapped[str] = mapped_column(String(100))
    position: Mapped[int] = mapped_column(Integer)

    clip: Mapped[Clip] = relationship(back_populates="labels")


class ClipDescriptor(Base):
    __tablename__ = "clip_descriptors"
    __table_args__ = (Index("ix_clip_descriptors_name_version", "name", "version"),)

    clip_id: Mapped[int] = mapped_column(
        ForeignKey("clips.id", ondelete="CASCADE"), primary_key=True
    )
    name: Mapped[str] = mapped_column(String(64), primary_key=True)
    version: Mapped[int] = mapped_column(Integer)
    dimension: Mapped[int] = mapped_column(Integer)
    vector: Mapped[bytes] = mapped_column(LargeBinary)  # (dimension,) little-endian float32

    clip: Mapped[Clip] = relationship(back_populates="descriptors")


class ClipWindow(Base):
    __tablename__ = "clip_windows"
    __table_args__ = (
        # Where every window of one index lies, in id order, from the index alone (a process
        # keeps that in memory for moments search: app.index.places).
        Index(
            "ix_clip_windows_places",
            "name",
            "version",
            "length",
            "id",
            "start_frame",
            "end_frame",
        ),
        # A clip's windows of one length in order (placing moments; cascade deletes).
        Index(
            "ix_clip_windows_clip_id_name_length",
            "clip_id",
            "name",
            "version",
            "length",
            "start_frame",
            "end_frame",
        ),
    )

    # Set by the writer (not a sequence); INTEGER on SQLite: the rowid itself (64 bits).
    id: Mapped[int] = mapped_column(
        BigInteger().with_variant(Integer, "sqlite"), primary_key=True, autoincrement=False
    )
    clip_id: Mapped[int] = mapped_column(ForeignKey("clips.id", ondelete="CASCADE"))
    name: Mapped[str] = mapped_column(String(64))
    version: Mapped[int] = mapped_column(Integer)
    length: Mapped[float] = mapped_column(Float)  # nominal window length, seconds
    start_frame: Mapped[int] = mapped_column(Integer)
    end_frame: Mapped[int] = mapped_column(Integer)  # exclusive
    vector: Mapped[bytes] = mapped_column(LargeBinary)  # (D,) little-endian float32


class ClipChange(Base):
    """A clip that changed (rows written by triggers only). ``txid`` is the id of the writing
    transaction on PostgreSQL (``pg_current_xact_id()``), NULL on SQLite, whose single writer
    commits in ``seq`` order."""

    __tablename__ = "clip_changes"
    __table_args__ = (
        Index("ix_clip_changes_txid", "txid"),
        {"sqlite_autoincrement": True},
    )

    seq: Mapped[int] = mapped_column(BigInteger().with_variant(Integer, "sqlite"), primary_key=True)
    clip_id: Mapped[int] = mapped_column(Integer)
    txid: Mapped[int | None] = mapped_column(BigInteger, nullable=True)


class ClipChangeMark(Base):
    """The change feed's position (the coordinate of :class:`ClipChange` rows: txid or seq)
    at ``recorded_at``; ``pruned``: the change rows before it were deleted."""

    __tablename__ = "clip_change_marks"

    position: Mapped[int] = mapped_column(BigInteger, primary_key=True, autoincrement=False)
    recorded_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))
    pruned: Mapped[bool] = mapped_column(Boolean, server_default=false())


class Blob(Base):
    """An uploaded file's bytes, content-addressed (PostgreSQL deployments only)."""

    __tablename__ = "blobs"

    sha256: Mapped[str] = mapped_column(String(64), primary_key=True)
    size: Mapped[int] = mapped_column(Integer)
    data: Mapped[bytes] = mapped_column(LargeBinary)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))


class Rig(Base):
    """A character's skeleton to retarget onto (see :mod:`app.db.rigs`)."""

    __tablename__ = "rigs"
    __table_args__ = ({"sqlite_autoincrement": True},)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    name: Mapped[str] = mapped_column(String(255))
    format: Mapped[str] = mapped_column(String(16))
    filename: Mapped[str] = mapped_column(String(255))
    joint_count: Mapped[int] = mapped_column(Integer)
    skeleton_family: Mapped[str] = mapped_column(String(64))
    length_unit: Mapped[str] = mapped_column(String(64))
    metres_per_unit: Mapped[float] = mapped_column(Float)
    # JSON text: {"names", "parents", "offsets", "end_site", "rotations", "root", "frame_time"}.
    skeleton: Mapped[str] = mapped_column(Text)
    # JSON text, the shape of a clip's joint_mapping.
    joint_mapping: Mapped[str] = mapped_column(Text)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))
