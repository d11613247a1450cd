"""Where the floor is, which way is up and where the body faces, from a clip's canonical joints.

Exports and retargeting need the world as a person sees it: the vertical axis (mocap files
are authored with a coordinate axis up, so it is the signed coordinate axis nearest to the
body's mean pelvis->neck direction), the floor (the lowest point the feet reach) and the
body's facing (the horizontal part of ``left hip - right hip`` turned a quarter about up).
Everything here reads ``(F, C, 3)`` canonical positions (see
:data:`~app.motion.skeleton_map.CANONICAL_JOINTS`), so it works on any rig the mapper maps.
"""

from __future__ import annotations

import numpy as np

from app.motion.body import _frame_poses
from app.motion.kinematics import forward_kinematics
from app.motion.model import Motion
from app.motion.skeleton_map import CANONICAL_INDEX, SkeletonMap, map_skeleton

SAMPLED_FRAMES = 240  # enough frames to find the up axis of a clip of any length

# Of body height: a foot point this near the floor is on it (the retarget holds such points
# as the source's move; the quality measure counts their sliding).
ON_FLOOR = 0.02
FOOT_POINTS = tuple(CANONICAL_INDEX[f"{s}_{p}"] for s in ("l", "r") for p in ("ankle", "toe"))


def canonical_positions(motion: Motion, mapping: SkeletonMap) -> np.ndarray:
    """``(F, C, 3)`` world positions of the canonical joints of ``motion`` (file units)."""
    _, positions = forward_kinematics(motion, joints=mapping.joints)
    return positions[:, mapping.joints]


def map_clip(motion: Motion) -> SkeletonMap:
    """The skeleton's mapping as :func:`~app.motion.body.build_body` finds it (the rest pose,
    else a few frames), without the clip's forward kinematics."""
    return map_skeleton(motion.skeleton, poses=_frame_poses(motion))


def sample_frames(motion: Motion, count: int = SAMPLED_FRAMES) -> Motion:
    """At most ``count`` frames of ``motion`` spread over it (for clip-wide facts like the up
    axis, which do not need every frame)."""
    if motion.frame_count <= count:
        return motion
    picked = np.linspace(0, motion.frame_count - 1, count).round().astype(np.int64)
    return Motion(
        skeleton=motion.skeleton,
        frame_time=motion.frame_time,
        root_translation=motion.root_translation[picked],
        local_rotations=motion.local_rotations[picked],
        local_translations=None
        if motion.local_translations is None
        else motion.local_translations[picked],
    )


def snap_axis(vector: np.ndarray) -> np.ndarray:
    """``(3,)`` the signed coordinate axis nearest to ``vector`` (``+Y`` for a zero vector)."""
    v = np.asarray(vector, dtype=np.float64)
    out = np.zeros(3)
    if not np.any(np.abs(v) > 1e-12):
        out[1] = 1.0
        return out
    axis = int(np.argmax(np.abs(v)))
    out[axis] = 1.0 if v[axis] > 0 else -1.0
    return out


def foot_heights(canonical: np.ndarray, up: np.ndarray) -> np.ndarray:
    """``(F,)`` height of the lowest foot point (ankles, toes) along ``up`` per frame."""
    return (canonical[:, FOOT_POINTS] @ up).min(axis=1)


def floor_height(canonical: np.ndarray, up: np.ndarray) -> float:
    """The floor along ``up``: the lowest any foot point gets over the clip."""
    return float(foot_heights(canonical, up).min())


def horizontal(vectors: np.ndarray, up: np.ndarray) -> np.ndarray:
    """``(..., 3)`` vectors with their component along the unit ``up`` removed."""
    return vectors - (vectors @ up)[..., None] * up


def facing(canonical: np.ndarray, up: np.ndarray) -> np.ndarray:
    """``(F, 3)`` unit horizontal forward direction of the body per frame (from the hips;
    a frame whose hip line is vertical keeps the previous frame's facing)."""
    lateral = horizontal(
        canonical[:, CANONICAL_INDEX["l_hip"]] - canonical[:, CANONICAL_INDEX["r_hip"]], up
    )
    forward = np.cross(lateral, up)
    norms = np.linalg.norm(forward, axis=1)
    good = norms > 1e-9 * max(float(norms.max(initial=0.0)), 1e-12)
    if not good.any():
        fallback = np.roll(up, 1)
        return np.broadcast_to(horizontal(fallback, up) / np.linalg.norm(fallback), forward.shape)
    index = np.maximum.accumulate(np.where(good, np.arange(len(good)), -1))
    index = np.where(index < 0, int(np.flatnonzero(good)[0]), index)
    forward = forward[index]
    return forward / np.linalg.norm(forward, axis=1, keepdims=True)


def body_frame(pose: np.ndarray) -> np.ndarray:
    """``(3, 3)`` body axes of one ``(C, 3)`` canonical pose, columns lateral (left), up,
    forward (the convention of :mod:`app.motion.body`)."""
    lateral = pose[CANONICAL_INDEX["l_hip"]] - pose[CANONICAL_INDEX["r_hip"]]
    x = lateral / max(float(np.linalg.norm(lateral)), 1e-12)
    up = pose[CANONICAL_INDEX["neck"]] - pose[CANONICAL_INDEX["pelvis"]]
    up = up - np.dot(up, x) * x
    y = up / max(float(np.linalg.norm(up)), 1e-12)
    return np.stack([x, y, np.cross(x, y)], axis=1)


def yaw_matrices(angles: np.ndarray, up: np.ndarray) -> np.ndarray:
    """``(F, 3, 3)`` rotations by ``angles`` (radians) about the unit axis ``up``."""
    k = np.array([[0, -up[2], up[1]], [up[2], 0, -up[0]], [-up[1], up[0], 0]])
    s = np.sin(angles)[:, None, None]
    c = np.cos(angles)[:, None, None]
    return np.eye(3) + s * k + (1 - c) * (k @ k)


__all__ = [
    "FOOT_POINTS",
    "body_frame",
    "canonical_positions",
    "facing",
    "floor_height",
    "foot_heights",
    "horizontal",
    "map_clip",
    "sample_frames",
    "snap_axis",
    "yaw_matrices",
]
