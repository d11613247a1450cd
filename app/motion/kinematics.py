"""Forward kinematics: local joint rotations and offsets -> world rotations and positions.

For joint ``j`` with parent ``p`` (column-vector convention)::

    G[j] = G[p] @ L[j]                 world rotation of j's frame
    x[j] = x[p] + G[p] @ offset[j]     world position of j

with ``x[root] = root_translation`` and ``G[root] = L[root]``. Positions are in the file's own
length unit. The loop runs over joints and is vectorised over frames.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from app.motion.model import Motion


def ancestors_closure(parents: np.ndarray, joints: Iterable[int]) -> np.ndarray:
    """Sorted indices of ``joints`` plus all of their ancestors, shape ``(K,)``."""
    needed: set[int] = set()
    for start in joints:
        j = int(start)
        while j >= 0 and j not in needed:
            needed.add(j)
            j = int(parents[j])
    return np.array(sorted(needed), dtype=np.int64)


def forward_kinematics(
    motion: Motion, *, joints: Iterable[int] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """World rotations and positions of the joints of ``motion``.

    Parameters
    ----------
    motion:
        The clip (``F`` frames, ``J`` joints).
    joints:
        Only these joints (and, necessarily, their ancestors) are computed; the others are
        left as NaN. ``None`` computes every joint, end sites included.

    Returns
    -------
    rotations:
        ``(F, J, 3, 3)`` world rotation of each joint's frame.
    positions:
        ``(F, J, 3)`` world position of each joint.
    """
    skeleton = motion.skeleton
    parents = skeleton.parents
    frames, joint_count = motion.frame_count, skeleton.joint_count
    order = np.arange(joint_count) if joints is None else ancestors_closure(parents, joints)

    rotations = np.full((frames, joint_count, 3, 3), np.nan)
    positions = np.full((frames, joint_count, 3), np.nan)
    local_rot = motion.local_rotations
    local_off = motion.local_translations
    for j in order:
        p = int(parents[j])
        if p < 0:
            rotations[:, j] = local_rot[:, j]
            positions[:, j] = motion.root_translation
            continue
        offset = skeleton.offsets[j] if local_off is None else local_off[:, j]
        parent_rot = rotations[:, p]
        rotations[:, j] = parent_rot @ local_rot[:, j]
        if offset.ndim == 1:
            positions[:, j] = positions[:, p] + parent_rot @ offset
        else:
            positions[:, j] = positions[:, p] + (parent_rot @ offset[:, :, None])[:, :, 0]
    return rotations, positions


def rotation_log(rotations: np.ndarray) -> np.ndarray:
    """Rotation vectors (axis times angle, radians) of ``(..., 3, 3)`` rotation matrices.

    Vectorised closed form, several times faster than scipy's ``Rotation`` round trip on
    the short rotations between nearby frames; angles near 180 degrees, where the closed
    form loses precision, are handed to scipy.

    Returns
    -------
    ``(..., 3)`` rotation vectors.
    """
    r = rotations
    cos_angle = np.clip((np.trace(r, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    angle = np.arccos(cos_angle)
    skew = np.stack(
        [r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]],
        axis=-1,
    )
    sin_angle = np.sin(angle)
    # angle / sin(angle) -> 1 as the angle -> 0; use its series there to avoid 0/0.
    small = angle < 1e-4
    factor = np.where(small, 1.0 + angle**2 / 6.0, angle / np.where(small, 1.0, sin_angle))
    out = 0.5 * factor[..., None] * skew
    near_pi = angle > np.pi - 1e-3
    if np.any(near_pi):
        from scipy.spatial.transform import Rotation

        out[near_pi] = Rotation.from_matrix(r[near_pi]).as_rotvec()
    return out


def rest_positions(motion: Motion) -> np.ndarray:
    """World positions of every joint in the rest pose (all local rotations identity).

    Uses the per-frame offsets of frame 0 when the file has position channels on joints.

    Returns
    -------
    ``(J, 3)`` positions with the root at the origin.
    """
    skeleton = motion.skeleton
    offsets = (
        skeleton.offsets if motion.local_translations is None else motion.local_translations[0]
    )
    out = np.zeros((skeleton.joint_count, 3))
    for j in range(1, skeleton.joint_count):
        out[j] = out[skeleton.parents[j]] + offsets[j]
    return out


def bone_lengths(motion: Motion) -> np.ndarray:
    """Length of the bone from each joint's parent to the joint, frame 0, shape ``(J,)``.

    The root's entry is 0. Per-frame position channels are honoured.
    """
    skeleton = motion.skeleton
    offsets = (
        skeleton.offsets if motion.local_translations is None else motion.local_translations[0]
    )
    lengths = np.linalg.norm(offsets, axis=1)
    lengths[0] = 0.0
    return lengths
