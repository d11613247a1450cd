"""The one motion model every format is read into.

Conventions (shared by every module of :mod:`app.motion`):

* A skeleton is a tree of ``J`` joints stored in depth-first order, so ``parents[j] < j`` and
  the root is joint 0 with ``parents[0] == -1``. End sites (BVH ``End Site``, ASF leaf-bone
  tips) are joints too, flagged in ``end_site``; they carry an offset but never rotate.
* ``offsets[j]`` is joint ``j``'s rest position relative to its parent, expressed in the
  parent's local frame, in the file's own length unit (a joint's local frame is the world
  frame rotated by the product of its ancestors' and its own local rotations).
* A motion has ``F`` frames sampled every ``frame_time`` seconds. ``local_rotations[f, j]`` is the
  rotation of joint ``j`` relative to its parent as a 3x3 matrix acting on column vectors.
  Position channels on any joint replace that joint's offset for that frame
  (``local_translations``), which is how BVH files with 6 channels per joint are read.

Nothing here imports web, database or index code.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np

from app.errors import DescribeTimeout


@dataclass(frozen=True)
class ParseLimits:
    """Upper bounds a parser enforces while reading, so hostile files cost bounded time/memory.

    ``None`` means unlimited. The service passes its configured limits; tests and tools may
    use the defaults.

    ``deadline`` is a :func:`time.monotonic` instant by which reading must be over: the
    readers call :meth:`check_time` between bounded chunks of work (every few thousand lines,
    around each C reader call), so a read that runs too long stops with
    :class:`~app.errors.DescribeTimeout` and frees its thread; the process goes on. It takes
    no part in comparisons, so limits that differ only in their deadline are equal (the BVH
    reader remembers hierarchies by their limits).
    """

    max_frames: int | None = 1_000_000
    max_joints: int | None = 1_000
    max_depth: int | None = 256
    max_values: int | None = 200_000_000
    deadline: float | None = field(default=None, compare=False)

    def within(self, seconds: float | None) -> ParseLimits:
        """These limits with a deadline ``seconds`` from now (unchanged for ``None``)."""
        if seconds is None:
            return self
        return dataclasses.replace(self, deadline=time.monotonic() + seconds)

    def check_time(self) -> None:
        """:class:`~app.errors.DescribeTimeout` once the deadline has passed."""
        if self.deadline is not None and time.monotonic() > self.deadline:
            raise DescribeTimeout("reading the file took longer than its time limit")

    def frame_budget_problem(self, frame_count: int, columns: int, joint_count: int) -> str | None:
        """Why ``frame_count`` frames of ``columns`` numbers for ``joint_count`` joints are too
        many, or None. Checked before allocating: the values read and the rotation matrices
        produced (nine numbers per joint and frame) both count, whichever is more.

        The count is what the clip's frames become in memory, so it bounds one upload's
        memory whatever its size in bytes: describing a clip peaks at about 21 bytes per
        counted value (the motion's rotations, forward kinematics of every joint, the body
        and its descriptors; measured in bench/README.md), plus the upload's bytes twice
        (the file and its text)."""
        if self.max_frames is not None and frame_count > self.max_frames:
            return f"{frame_count} frames is more than the limit of {self.max_frames}"
        produced = frame_count * max(columns, 9 * joint_count)
        if self.max_values is not None and produced > self.max_values:
            return (
                f"{frame_count} frames of {joint_count} joints and {columns} channels need "
                f"{produced} values, more than the limit of {self.max_values}"
            )
        return None


@dataclass(frozen=True, eq=False)
class Skeleton:
    """Joint hierarchy with rest offsets.

    Attributes
    ----------
    names:
        ``(J,)`` joint names, unique. End sites are named ``"<parent>_end"`` (BVH) or
        ``"<bone>_end"`` (ASF) unless the file names them.
    parents:
        ``(J,)`` int64, index of each joint's parent, ``-1`` for the root; ``parents[j] < j``.
    offsets:
        ``(J, 3)`` float64 rest offset of each joint from its parent in the parent's frame.
    end_site:
        ``(J,)`` bool, True where the joint is an end site (no channels of its own).
    """

    names: tuple[str, ...]
    parents: np.ndarray
    offsets: np.ndarray
    end_site: np.ndarray

    def __post_init__(self) -> None:
        j = len(self.names)
        if (
            self.parents.shape != (j,)
            or self.offsets.shape != (j, 3)
            or self.end_site.shape != (j,)
        ):
            raise ValueError("skeleton arrays disagree on the number of joints")

    @property
    def joint_count(self) -> int:
        """Number of joints including end sites."""
        return len(self.names)

    def index(self, name: str) -> int:
        """Index of the joint called ``name`` (exact match)."""
        return self.names.index(name)

    def children(self, joint: int) -> list[int]:
        """Indices of the direct children of ``joint``."""
        return [int(c) for c in np.flatnonzero(self.parents == joint)]


@dataclass(frozen=True, eq=False)
class Motion:
    """A clip: skeleton plus per-frame root translation and local joint rotations.

    Attributes
    ----------
    skeleton:
        The joint hierarchy (``J`` joints).
    frame_time:
        Seconds between frames, > 0.
    root_translation:
        ``(F, 3)`` float64 world position of the root joint per frame, in file units.
    local_rotations:
        ``(F, J, 3, 3)`` float64 rotation of each joint relative to its parent; identity at
        end sites and joints without rotation channels.
    local_translations:
        ``(F, J, 3)`` float64 per-frame offsets of every joint, or ``None`` when only the root
        has position channels (then ``skeleton.offsets`` apply to every frame). Row 0 (the
        root) is ignored in favour of ``root_translation``.
    source_format:
        ``"bvh"`` or ``"asf/amc"``.
    length_unit:
        Words describing the file's length unit after any ``:units`` multiplier (for humans).
    """

    skeleton: Skeleton
    frame_time: float
    root_translation: np.ndarray
    local_rotations: np.ndarray
    local_translations: np.ndarray | None = None
    source_format: str = "bvh"
    length_unit: str = "file units"
    notes: dict[str, object] = field(default_factory=dict)

    @property
    def frame_count(self) -> int:
        return int(self.root_translation.shape[0])

    @property
    def duration(self) -> float:
        """Seconds covered by the clip (``frame_count * frame_time``)."""
        return self.frame_count * self.frame_time

    def slice_frames(self, start: int, stop: int | None = None) -> Motion:
        """The same clip restricted to frames ``start:stop`` (views, no copy)."""
        return Motion(
            skeleton=self.skeleton,
            frame_time=self.frame_time,
            root_translation=self.root_translation[start:stop],
            local_rotations=self.local_rotations[start:stop],
            local_translations=None
            if self.local_translations is None
            else self.local_translations[start:stop],
            source_format=self.source_format,
            length_unit=self.length_unit,
            notes=dict(self.notes),
        )
