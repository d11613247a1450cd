"""Root motion for game engines: a clip in place, or its travel and facing on a ``root`` joint.

* :func:`in_place` removes the pelvis's horizontal travel (its height and every rotation
  kept): the pelvis stays over the world origin, a walk cycle walks on the spot. The shift
  goes on the joint that carries the pelvis's translation — the top joint, or the pelvis
  itself when the file moves it with position channels under a static root — so nothing
  that did not move starts moving.
* :func:`extract_root` adds a new top joint named ``root`` at floor level under the pelvis
  carrying the horizontal travel and the body's facing (yaw about the up axis, measured from
  the rest pose's facing); the old top joint hangs under it with the rest, re-expressed so
  every joint's world position is exactly what it was. A joint already called ``root`` keeps
  its place under the new one, renamed ``root_source``.

"Horizontal" and "floor" come from :mod:`app.motion.ground`; "up" is the world's vertical as
the describer reads it (:func:`app.motion.retarget.world_up`: the floor's axis for a take done
on the floor, not its trunk's mean), unless the caller gives it.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from app.motion.ground import (
    body_frame,
    canonical_positions,
    facing,
    floor_height,
    horizontal,
    sample_frames,
    yaw_matrices,
)
from app.motion.kinematics import forward_kinematics, rest_positions
from app.motion.model import Motion, Skeleton
from app.motion.retarget import world_up
from app.motion.skeleton_map import CANONICAL_INDEX, SkeletonMap

ROOT_NAME = "root"
RENAMED_ROOT = "root_source"


def translation_carrier(motion: Motion, joint: int) -> int:
    """The joint whose per-frame translation moves ``joint``: the nearest joint at or above
    it with position data of its own (the top joint when none has)."""
    parents = motion.skeleton.parents
    if motion.local_translations is not None:
        spread = np.ptp(motion.local_translations, axis=0).max(axis=1)  # (J,)
        size = float(np.abs(motion.skeleton.offsets).max(initial=0.0)) or 1.0
        j = joint
        while j > 0:
            if spread[j] > 1e-9 * size:
                return j
            j = int(parents[j])
    return 0


def shift_joint(motion: Motion, joint: int, shift: np.ndarray) -> Motion:
    """``motion`` with the ``(F, 3)`` world displacement ``shift`` added to ``joint``'s
    per-frame translation (the top joint's ``root_translation``, else its local one)."""
    if joint == 0:
        return replace(motion, root_translation=motion.root_translation + shift)
    assert motion.local_translations is not None
    rotations, _ = forward_kinematics(motion, joints=[int(motion.skeleton.parents[joint])])
    parent = rotations[:, int(motion.skeleton.parents[joint])]
    local = motion.local_translations.copy()
    local[:, joint] += (np.swapaxes(parent, -1, -2) @ shift[:, :, None])[:, :, 0]
    return replace(motion, local_translations=local)


def vertical(motion: Motion, mapping: SkeletonMap) -> np.ndarray:
    """``(3,)`` the world's up in ``motion`` as the describer reads it, from sampled frames."""
    return world_up(sample_frames(motion), mapping)


def in_place(motion: Motion, mapping: SkeletonMap, up: np.ndarray | None = None) -> Motion:
    """``motion`` without the pelvis's horizontal travel (see the module docstring); ``up``
    ``(3,)``: the world's vertical, :func:`vertical` when not given."""
    canonical = canonical_positions(motion, mapping)
    up = vertical(motion, mapping) if up is None else up
    pelvis = canonical[:, CANONICAL_INDEX["pelvis"]]
    carrier = translation_carrier(motion, int(mapping.joints[CANONICAL_INDEX["pelvis"]]))
    return shift_joint(motion, carrier, -horizontal(pelvis, up))


def _rest_facing(motion: Motion, mapping: SkeletonMap, up: np.ndarray) -> np.ndarray:
    """``(3,)`` horizontal unit forward of the skeleton's rest pose (the first frame's when
    the rest pose is not a standing figure)."""
    if mapping.pose == "rest pose":
        pose = rest_positions(motion)[mapping.joints]
    else:
        pose = canonical_positions(motion.slice_frames(0, 1), mapping)[0]
    forward = horizontal(body_frame(pose)[:, 2], up)
    norm = float(np.linalg.norm(forward))
    if norm < 1e-9:
        forward = horizontal(np.roll(up, 1), up)
        norm = float(np.linalg.norm(forward))
    return forward / norm


def extract_root(motion: Motion, mapping: SkeletonMap, up: np.ndarray | None = None) -> Motion:
    """``motion`` under a new ``root`` joint carrying travel and facing (see the module
    docstring; ``up`` as for :func:`in_place`). The result has one joint more than
    ``motion``."""
    canonical = canonical_positions(motion, mapping)
    up = vertical(motion, mapping) if up is None else up
    floor = floor_height(canonical, up)
    pelvis = canonical[:, CANONICAL_INDEX["pelvis"]]
    root_at = horizontal(pelvis, up) + floor * up  # (F, 3)
    reference = _rest_facing(motion, mapping, up)
    forward = facing(canonical, up)
    angles = np.arctan2(np.cross(reference, forward) @ up, forward @ reference)
    yaw = yaw_matrices(np.unwrap(angles), up)  # (F, 3, 3)
    yaw_t = np.swapaxes(yaw, -1, -2)

    skeleton = motion.skeleton
    frames, count = motion.frame_count, skeleton.joint_count
    old_names = [RENAMED_ROOT if name.lower() == ROOT_NAME else name for name in skeleton.names]
    while RENAMED_ROOT in old_names and old_names.count(RENAMED_ROOT) > 1:  # pragma: no cover
        old_names[old_names.index(RENAMED_ROOT)] = f"{RENAMED_ROOT}_2"
    top_local = (yaw_t @ (motion.root_translation - root_at)[:, :, None])[:, :, 0]  # (F, 3)
    offsets = np.vstack([np.zeros((1, 3)), skeleton.offsets])
    offsets[1] = top_local[0]
    new_skeleton = Skeleton(
        names=(ROOT_NAME, *old_names),
        parents=np.concatenate([[-1], np.where(skeleton.parents < 0, 0, skeleton.parents + 1)]),
        offsets=offsets,
        end_site=np.concatenate([[False], skeleton.end_site]),
    )
    rotations = np.empty((frames, count + 1, 3, 3))
    rotations[:, 0] = yaw
    rotations[:, 1:] = motion.local_rotations
    rotations[:, 1] = yaw_t @ motion.local_rotations[:, 0]
    local = np.empty((frames, count + 1, 3))
    local[:, 0] = root_at
    if motion.local_translations is None:
        local[:, 1:] = skeleton.offsets
    else:
        local[:, 1:] = motion.local_translations
    local[:, 1] = top_local
    return replace(
        motion,
        skeleton=new_skeleton,
        root_translation=root_at,
        local_rotations=rotations,
        local_translations=local,
    )


__all__ = [
    "ROOT_NAME",
    "extract_root",
    "in_place",
    "shift_joint",
    "translation_carrier",
    "vertical",
]
