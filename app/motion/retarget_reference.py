"""The reference poses a retarget aligns two skeletons by, and the rotation that aligns them.

Each skeleton has a reference pose (:func:`reference_pose`): its rest pose, or for a rig
whose rest pose is not a standing figure the frame the mapper read it from. Bones are
aligned between the two reference poses by the smallest rotation taking one direction onto
another (:func:`swing`: no twist about the bone), and world axes by a quarter turn
(:func:`axis_change`). The legs' bone paths (:func:`leg_length`) scale the travel.
"""

from __future__ import annotations

import numpy as np

from app.motion.model import Motion
from app.motion.skeleton_map import CANONICAL_INDEX, SkeletonMap

_TINY = 1e-9


def swing(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``(..., 3, 3)`` smallest rotations taking directions ``a`` onto ``b`` (``(..., 3)``,
    any length; the identity where either is zero, a half turn about a perpendicular where
    they are opposite)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    na = np.linalg.norm(a, axis=-1, keepdims=True)
    nb = np.linalg.norm(b, axis=-1, keepdims=True)
    zero = (na[..., 0] < _TINY) | (nb[..., 0] < _TINY)
    a = a / np.where(na < _TINY, 1.0, na)
    b = b / np.where(nb < _TINY, 1.0, nb)
    axis = np.cross(a, b)
    cos = np.clip(np.sum(a * b, axis=-1), -1.0, 1.0)
    sin = np.linalg.norm(axis, axis=-1)
    opposite = (cos < 0) & (sin < 1e-8)
    if np.any(opposite):
        # Any axis perpendicular to a: the coordinate axis least along a, crossed with it.
        least = np.argmin(np.abs(a), axis=-1)
        helper = np.eye(3)[least]
        perpendicular = np.cross(a, helper)
        perpendicular /= np.linalg.norm(perpendicular, axis=-1, keepdims=True)
        axis = np.where(opposite[..., None], perpendicular, axis)
        sin = np.where(opposite, 1.0, sin)
        # The half turn: rotation angle pi about the unit perpendicular.
    unit = axis / np.where(sin[..., None] < 1e-15, 1.0, sin[..., None])
    angle = np.arctan2(np.where(opposite, 0.0, sin), cos)
    angle = np.where(opposite, np.pi, angle)
    # Rodrigues, I + s K + (1 - c) K^2 with K^2 = u u^T - |u|^2 I, entry by entry (no
    # per-rotation matrix product).
    s, versed = np.sin(angle), 1.0 - np.cos(angle)
    x, y, z = unit[..., 0], unit[..., 1], unit[..., 2]
    scaled = versed[..., None] * unit
    out = scaled[..., :, None] * unit[..., None, :]
    diagonal = 1.0 - np.sum(scaled * unit, axis=-1)
    for i in range(3):
        out[..., i, i] += diagonal
    out[..., 0, 1] -= s * z
    out[..., 0, 2] += s * y
    out[..., 1, 0] += s * z
    out[..., 1, 2] -= s * x
    out[..., 2, 0] -= s * y
    out[..., 2, 1] += s * x
    out[zero] = np.eye(3)
    return out


def axis_change(up_from: np.ndarray, up_to: np.ndarray) -> np.ndarray:
    """``(3, 3)`` the quarter turn (or none, or a half turn) about a coordinate axis taking
    the signed coordinate axis ``up_from`` onto ``up_to``."""
    return np.rint(swing(up_from, up_to))


def reference_frame(mapping: SkeletonMap) -> int | None:
    """The frame the mapper read the skeleton from (``None``: the rest pose)."""
    if mapping.pose.startswith("frame "):
        try:
            return int(mapping.pose.split()[1])
        except (IndexError, ValueError):
            return 0
    return None


def reference_pose(motion: Motion, mapping: SkeletonMap) -> Motion:
    """A rig made of ``motion``'s skeleton: one frame holding its reference pose, the rest
    pose (identity rotations) or, when the mapper read the skeleton from a frame because the
    rest pose is not a standing figure, that frame's rotations. Per-frame offsets are dropped:
    a rig's bones are its offsets."""
    frame = reference_frame(mapping)
    count = motion.skeleton.joint_count
    if frame is None or motion.frame_count == 0:
        rotations = np.broadcast_to(np.eye(3), (1, count, 3, 3)).copy()
        frame = 0
    else:
        frame = min(max(frame, 0), motion.frame_count - 1)
        rotations = motion.local_rotations[frame : frame + 1].copy()
    root = (
        motion.root_translation[frame : frame + 1].copy()
        if motion.frame_count
        else motion.skeleton.offsets[None, 0].copy()
    )
    return Motion(
        skeleton=motion.skeleton,
        frame_time=motion.frame_time,
        root_translation=root,
        local_rotations=rotations,
        source_format=motion.source_format,
        length_unit=motion.length_unit,
    )


def path_length(motion: Motion, top: int, bottom: int) -> float:
    """Summed bone lengths from joint ``bottom`` up to its ancestor ``top``."""
    parents = motion.skeleton.parents
    offsets = motion.skeleton.offsets
    total, j = 0.0, bottom
    while j != top and j > 0:
        total += float(np.linalg.norm(offsets[j]))
        j = int(parents[j])
    return total


def leg_length(motion: Motion, mapping: SkeletonMap) -> float:
    """Mean bone path hip -> ankle of the two legs, in the skeleton's units."""
    lengths = [
        path_length(
            motion,
            int(mapping.joints[CANONICAL_INDEX[f"{s}_hip"]]),
            int(mapping.joints[CANONICAL_INDEX[f"{s}_ankle"]]),
        )
        for s in ("l", "r")
    ]
    return float(np.mean(lengths))


def rest_of(motion: Motion) -> Motion:
    """A one-frame motion of ``motion``'s rest pose (identity rotations, root at origin)."""
    count = motion.skeleton.joint_count
    return Motion(
        skeleton=motion.skeleton,
        frame_time=motion.frame_time,
        root_translation=np.zeros((1, 3)),
        local_rotations=np.broadcast_to(np.eye(3), (1, count, 3, 3)).copy(),
    )


__all__ = [
    "axis_change",
    "leg_length",
    "path_length",
    "reference_frame",
    "reference_pose",
    "rest_of",
    "swing",
]
