"""How good a retarget is, measured against its source (the figures docs/export.md reports).

Each measure compares the source clip with its retargeted copy through the canonical joints
both skeletons map to, in the target's world axes (the source's are turned by the same
quarter turn the retarget used) and in body heights of each skeleton:

* ``bone_error``: largest difference between a bone's length in any frame and the rig's;
* ``left_ok``: fraction of frames where the target's left hip and shoulder lie on the
  same side as the source's;
* ``feet_error``: largest per-frame difference of the feet's lowest point above the floor;
* ``slide`` / ``source_slide``: mean horizontal speed of the foot points (ankles, toes)
  over the frame steps where the source's point is within 2 % of the source's floor at
  both ends (the foot contact the retarget holds), body heights per second, both over the
  same (step, point) pairs. Until 2026-11-27 each was measured over its own contacts; that
  compared means over different sets: a rig whose ankle or toe joint sits at another
  height in the foot has other steps within 2 % of its floor (a cartwheel's slow standing
  steps dropped, fast landing ones added), which failed retargets moving every planted
  point as the source's and passed walks whose feet slid more than the source's;
  since 2026-11-28 only over the points the rig has: a rig with no toe joint (its toe
  point is its ankle) is measured at its ankles against the source's ankles, not its
  ankle against the source's toe (a point it does not have, which rolls while the ankle
  rises);
(the source measured at the retarget's scale, the ratio of the legs, in the target's body
heights: the retarget scales travel and height by that ratio, as the issue asks);
* ``travel`` / ``source_travel``: the pelvis's net horizontal displacement, first frame to
  last, in leg lengths (hip -> knee -> ankle) per second of each skeleton: the contract
  "the root's travel is scaled by the ratio of leg lengths" makes them equal (added
  2026-11-27, when an in-place run travelled 0.27 leg lengths per second on the Mixamo rig);
* ``finite``: no NaN or infinity anywhere;
* ``direction_ok``: over the limb bones (upper arms, forearms, thighs, shins), the smallest
  fraction of frames where the bone's world direction is within 5 degrees of the source's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.motion.body import body_height
from app.motion.ground import (
    FOOT_POINTS,
    ON_FLOOR,
    foot_heights,
    horizontal,
)
from app.motion.kinematics import forward_kinematics
from app.motion.model import Motion
from app.motion.retarget import axis_change, leg_length, world_up
from app.motion.retarget_floor import rig_foot_points
from app.motion.skeleton_map import CANONICAL_INDEX, SkeletonMap
from app.motion.transforms import reflect

LIMB_BONES = tuple(
    (f"{s}_{a}", f"{s}_{b}")
    for s in ("l", "r")
    for a, b in (("shoulder", "elbow"), ("elbow", "wrist"), ("hip", "knee"), ("knee", "ankle"))
)
CONTACT = ON_FLOOR  # of body height: a foot point this near the floor is on it
DIRECTION_DEG = 5.0


@dataclass(frozen=True)
class RetargetQuality:
    bone_error: float
    left_ok: float
    feet_error: float
    slide: float
    source_slide: float
    finite: bool
    direction_ok: float
    travel: float = 0.0
    source_travel: float = 0.0

    def passes(self) -> bool:
        """The issue's bar: exact bones, left stays left, feet within 2 %, sliding within
        the source's plus 1 % per second, finite, limb directions within 5 degrees in 99 %
        of frames."""
        return (
            self.bone_error <= 1e-9
            and self.left_ok == 1.0
            and self.feet_error <= 0.02
            and self.slide <= self.source_slide + 0.01
            and self.finite
            and self.direction_ok >= 0.99
        )


def _on_floor(
    canonical: np.ndarray, up: np.ndarray, height: float, points: list[int]
) -> np.ndarray:
    """``(F - 1, P)`` whether each foot point ``points`` (indices into ``FOOT_POINTS``) of
    ``canonical`` ``(F, C, 3)`` is within :data:`CONTACT` body heights of the lowest any of
    them gets, at both ends of a step."""
    heights = canonical[:, [FOOT_POINTS[p] for p in points]] @ up  # (F, P)
    near = heights - heights.min() < CONTACT * height
    return near[1:] & near[:-1]


def _slide(
    canonical: np.ndarray,
    up: np.ndarray,
    height: float,
    frame_time: float,
    steps: np.ndarray,
    points: list[int],
) -> float:
    """Mean horizontal speed (body heights / s) of the foot ``points`` (indices into
    ``FOOT_POINTS``) of ``canonical`` ``(F, C, 3)`` over the (step, point) pairs marked in
    ``steps`` ``(F - 1, P)``."""
    feet = canonical[:, [FOOT_POINTS[p] for p in points]]  # (F, P, 3)
    speed = np.linalg.norm(horizontal(np.diff(feet, axis=0), up), axis=2) / frame_time
    if not steps.any():
        return 0.0
    return float(speed[steps].mean() / height)


def retarget_quality(
    source: Motion,
    source_map: SkeletonMap,
    result: Motion,
    result_map: SkeletonMap,
    *,
    skip: int = 0,
) -> RetargetQuality:
    """Measure ``result`` (a retarget of ``source`` onto a rig mapped as ``result_map``),
    leaving out the first ``skip`` frames (a converter's rest-pose lead-in, which the
    descriptors leave out too: its jump into the motion is no foot slide)."""
    if source_map.mirrored:
        source = reflect(source, axis=source_map.mirror_axis)
    if 0 < skip < source.frame_count - 1:
        source = source.slice_frames(skip)
        result = result.slice_frames(skip)
    finite = bool(
        np.isfinite(result.local_rotations).all() and np.isfinite(result.root_translation).all()
    )
    # Forward kinematics once per clip: the canonical joints, the pelvis rotations for the
    # world's up, and (the result's, every joint) the bone lengths.
    s_rotations, s_positions = forward_kinematics(source, joints=source_map.joints)
    rotations, positions = forward_kinematics(result)
    s = s_positions[:, source_map.joints]
    t = positions[:, result_map.joints]
    # Up as the retarget and the describer read it (the pelvis frame's): the trunk's mean
    # direction is the forward axis in a clip bent over for most of its frames.
    s_pelvis = int(source_map.joints[CANONICAL_INDEX["pelvis"]])
    t_pelvis = int(result_map.joints[CANONICAL_INDEX["pelvis"]])
    s_up = world_up(source, source_map, s_rotations[:, s_pelvis], s)
    t_up = world_up(result, result_map, rotations[:, t_pelvis], t)
    world = axis_change(t_up, s_up)
    s = s @ world  # the source in the target's axes
    t_height = body_height(result, result_map.joints, head_joint=result_map.head_joint)

    parents = result.skeleton.parents
    lengths = np.linalg.norm(positions[:, 1:] - positions[:, parents[1:]], axis=2)
    rig = np.linalg.norm(result.skeleton.offsets[1:], axis=1)
    movable = np.ones(len(rig), dtype=bool)
    movable[t_pelvis - 1] = t_pelvis == 0  # the pelvis's own offset carries the travel
    bone_error = float(np.abs(lengths[:, movable] - rig[movable]).max(initial=0.0) / t_height)

    def side(points: np.ndarray, name: str) -> np.ndarray:
        return points[:, CANONICAL_INDEX[f"l_{name}"]] - points[:, CANONICAL_INDEX[f"r_{name}"]]

    agree = np.ones(len(s), dtype=bool)
    for name in ("hip", "shoulder"):
        agree &= np.sum(side(s, name) * side(t, name), axis=1) > 0
    # The retarget scales the source by the legs' ratio: compare in that scale.
    scale = leg_length(result, result_map) / max(leg_length(source, source_map), 1e-12)
    s_feet = foot_heights(s, t_up) * scale
    t_feet = foot_heights(t, t_up)
    feet_error = float(np.abs((t_feet - t_feet.min()) - (s_feet - s_feet.min())).max() / t_height)
    worst = 1.0
    for a, b in LIMB_BONES:
        sb = s[:, CANONICAL_INDEX[b]] - s[:, CANONICAL_INDEX[a]]
        tb = t[:, CANONICAL_INDEX[b]] - t[:, CANONICAL_INDEX[a]]
        cos = np.sum(sb * tb, axis=1) / np.maximum(
            np.linalg.norm(sb, axis=1) * np.linalg.norm(tb, axis=1), 1e-12
        )
        worst = min(worst, float(np.mean(cos >= np.cos(np.radians(DIRECTION_DEG)))))
    # Sliding: both over the same steps, where the source has the point on its floor; only
    # the points the rig has (a rig with no toe: its ankles, against the source's ankles).
    points = rig_foot_points(result_map)
    contact = _on_floor(s * scale, t_up, t_height, points)
    return RetargetQuality(
        bone_error=bone_error,
        left_ok=float(agree.mean()),
        feet_error=feet_error,
        slide=_slide(t, t_up, t_height, result.frame_time, contact, points),
        source_slide=_slide(s * scale, t_up, t_height, source.frame_time, contact, points),
        finite=finite,
        direction_ok=worst,
        travel=_travel(t, t_up, leg_length(result, result_map), result.frame_time),
        source_travel=_travel(s, t_up, leg_length(source, source_map), source.frame_time),
    )


def _travel(canonical: np.ndarray, up: np.ndarray, leg: float, frame_time: float) -> float:
    """The pelvis's net horizontal displacement in ``canonical`` ``(F, C, 3)``, first frame
    to last, in leg lengths ``leg`` per second (0 for a single frame)."""
    pelvis = canonical[:, CANONICAL_INDEX["pelvis"]]
    seconds = frame_time * (len(pelvis) - 1)
    if seconds <= 0 or leg <= 0:
        return 0.0
    return float(np.linalg.norm(horizontal(pelvis[-1] - pelvis[0], up)) / leg / seconds)


__all__ = ["LIMB_BONES", "RetargetQuality", "retarget_quality"]
