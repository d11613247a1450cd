"""The trunk's chords from the pelvis: the rig's spine bent so they point as the source's.

The pelvis joint carries the bone to the first spine joint: that bone turns with the pelvis
and is never aimed. Where the rig's is long (a spine joint a third of the way up the trunk)
and the source bends its lower back below that height, the bend has nowhere to go: each
spine bone above points as the source's, but the rig's chest and neck sit where a straight
lower back puts them, and the trunk (pelvis -> neck, as the describer reads it in the
pelvis's frame) leans less than the source's. So, after the per-bone aiming, the rig's
spine joint is turned about itself by the smallest rotation (no twist about the chain) that
puts the chest on the source's pelvis -> chest direction, then the chest joint the same way
for the neck. The spine bones above the pelvis bone take the lower back's bend; every other
driven joint keeps its world rotation, so the neck, head, clavicles and limbs point as
before. Where the rig's spine is split as the source's, the chords already match and the
turns are the identity (to float noise).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from app.motion.retarget_joints import Driven
from app.motion.retarget_reference import swing
from app.motion.skeleton_map import CANONICAL_INDEX, SkeletonMap

_TRUNK = ("pelvis", "spine", "chest", "neck")
# (pivot, chord's end, only where the neck was not reached): each chord from the pelvis is
# aimed by turning the canonical joint below its end. Where the chest joint's bone is too
# short to bring the neck onto its chord (a deep bend on a rig whose lower back is one long
# bone), the spine joint turns the chest and neck together: the neck's chord, which the
# describer reads, before the chest's.
_TURNS = (("spine", "chest", False), ("chest", "neck", False), ("spine", "neck", True))


def bend_trunk(
    driven: Sequence[Driven],
    rotation: np.ndarray,
    parents: np.ndarray,
    t_ref_rot: np.ndarray,
    t_ref_pos: np.ndarray,
    s_pos: np.ndarray,
    source_map: SkeletonMap,
    target_map: SkeletonMap,
    world: np.ndarray,
) -> None:
    """Turn the rig's spine and chest joints so its pelvis -> chest and pelvis -> neck point
    as the source's (``rotation`` ``(F, D, 3, 3)``, the ``driven`` joints' world rotations,
    changed in place). ``parents`` ``(J,)``, ``t_ref_rot`` ``(J, 3, 3)`` and ``t_ref_pos``
    ``(J, 3)`` are the rig's hierarchy and reference pose, ``s_pos`` ``(F, J_s, 3)`` the
    source's positions, ``world`` ``(3, 3)`` the rig's world axes onto the source's."""
    slot = {d.target: i for i, d in enumerate(driven)}
    t_joint = {n: int(target_map.joints[CANONICAL_INDEX[n]]) for n in _TRUNK}
    s_joint = {n: int(source_map.joints[CANONICAL_INDEX[n]]) for n in _TRUNK}
    missed = np.ones(rotation.shape[0], dtype=bool)
    for pivot_name, end_name, only_missed in _TURNS:
        pivot, end = t_joint[pivot_name], t_joint[end_name]
        chain = _path(parents, t_joint["pelvis"], end)
        if chain is None or pivot not in chain[1:-1] or pivot not in slot:
            continue  # the canonical joints coincide or are not one chain: nothing to bend
        if s_joint[end_name] == s_joint["pelvis"]:
            continue
        frames = missed.copy() if only_missed else np.ones_like(missed)
        if not frames.any():
            continue
        positions = _chain_positions(chain, slot, rotation[frames], parents, t_ref_rot, t_ref_pos)
        at = chain.index(pivot)
        pelvis_at, pivot_at, end_at = positions[:, 0], positions[:, at], positions[:, -1]
        wanted = (s_pos[frames, s_joint[end_name]] - s_pos[frames, s_joint["pelvis"]]) @ world
        radius = np.linalg.norm(end_at - pivot_at, axis=1)
        target, reached = _on_ray(pelvis_at, wanted, pivot_at, radius)
        if end_name == "neck" and not only_missed:
            missed[frames] = ~reached
        turn = swing(end_at - pivot_at, target - pivot_at)  # (F', 3, 3)
        # The driven joints from the pivot up to (not including) the chain's end turn with
        # it; those beyond keep their world rotations (their bones' directions).
        for joint in chain[at:-1]:
            if joint in slot:
                rotation[frames, slot[joint]] = turn @ rotation[frames, slot[joint]]


def _path(parents: np.ndarray, top: int, joint: int) -> list[int] | None:
    """The joints from ``top`` down to ``joint``, or None if ``top`` is not its ancestor."""
    path = [joint]
    while path[-1] != top:
        up = int(parents[path[-1]])
        if up < 0:
            return None
        path.append(up)
    return path[::-1]


def _chain_positions(
    chain: list[int],
    slot: dict[int, int],
    rotation: np.ndarray,
    parents: np.ndarray,
    t_ref_rot: np.ndarray,
    t_ref_pos: np.ndarray,
) -> np.ndarray:
    """``(F, K, 3)`` positions of the ``chain`` joints (top first, the top at the origin):
    each bone turns with its nearest driven ancestor-or-self, as the rig's reference bone
    relative to that joint."""
    frames = rotation.shape[0]
    out = np.zeros((frames, len(chain), 3))
    for i in range(1, len(chain)):
        anchor = chain[i - 1]
        while anchor not in slot:
            anchor = int(parents[anchor])
        bone = t_ref_rot[anchor].T @ (t_ref_pos[chain[i]] - t_ref_pos[chain[i - 1]])
        out[:, i] = out[:, i - 1] + rotation[:, slot[anchor]] @ bone
    return out


def _on_ray(
    origin: np.ndarray, direction: np.ndarray, centre: np.ndarray, radius: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``(F, 3)`` the far point where the ray ``origin + t·direction`` (``(F, 3)``) meets the
    sphere about ``centre`` ``(F, 3)`` of ``radius`` ``(F,)``; where it misses, the ray's
    point nearest the centre (the chord as close as the bone can bring it); and ``(F,)``
    whether the ray met the sphere."""
    unit = direction / np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-12)
    offset = origin - centre
    along = np.sum(unit * offset, axis=1)
    room = along**2 - np.sum(offset * offset, axis=1) + radius**2
    t = -along + np.sqrt(np.maximum(room, 0.0))
    return origin + t[:, None] * unit, room >= 0.0


__all__ = ["bend_trunk"]
