"""The trunk's chord from the pelvis: the rig's spine turned so pelvis -> neck points as the
source's.

``motion`` reads the trunk as one chord, pelvis -> neck, in the pelvis's frame
(:mod:`app.motion.descriptors.motion`). The per-bone aiming gives every spine bone the
source's direction for the bone of the same canonical name, but where the canonical spine,
chest and neck joints sit at other heights on the two skeletons (the rig's pelvis -> spine
bone a third of the trunk, turning with the pelvis; the source bending right above its
pelvis), bones of equal direction add up to another chord: the rig's trunk leaned 5-10
degrees less than the source's in the median frame of a bent trunk.

So, after the per-bone aiming, the rig's spine joint turns by the smallest rotation (no
twist about the bone) that puts the neck on the source's pelvis -> neck direction, or as
near it as the spine's bone can bring it; driven joints between the spine and the chest
turn with it. The chest and everything hanging from it (neck, head, clavicles, arms) keep
their world rotations: their bones point as the source's, they move only with the spine's
end. The spine joint is the one trunk joint ``motion`` does not read a rotation of (its
``energy`` and ``parts`` blocks read the chest's rotation relative to the pelvis, the neck's
and the shoulders' relative to the chest), so the turn changes the chord and nothing else
the descriptor reads. Where the chords already match, the turn is the identity (to float
noise). The chest's own chord is not aimed: where the two chests sit at other heights it is
another chord.

What was tried first and why not (``docs/export.md``, "The trunk's neck chord"): turning the
chest joint for the neck, or the spine and chest as one piece. Either turns the chest,
whose rotation ``motion`` reads: a game character's short chest -> neck bone (0.14 of the
trunk) needed 50-75 degree turns, and even the rigid piece gave the re-upload's chest and
shoulders kinetic energy the source's do not have (four Bandai bows on that character,
distance to the source: 0.017-0.031 on ``main``, 0.22-0.71 turning the chest, 0.024-0.105
turning spine and chest as one; three of them 0.006-0.024 turning the spine alone).

Not on a rig whose re-upload takes its body's axes from its frames (its rest pose no
standing figure, and not shown by the bones its pelvis carries:
:func:`app.motion.body.rest_axes_hold`): there a leaning trunk passed on is read as
upright (measured on the Bandai rig before its pelvis's bones were read: the biovision
sample 0.136 -> 0.545 from its source, a CMU trial 0.174 -> 0.507). The Bandai rig's rest
is no figure, but its trunk is one straight line along the bone its pelvis carries, so its
re-uploads keep the rest's axes and the chord is aimed there too ("The Bandai rig's trunk
chord" in ``docs/export.md``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from app.motion.retarget_joints import Driven
from app.motion.retarget_reference import swing
from app.motion.skeleton_map import CANONICAL_INDEX, SkeletonMap


def aim_trunk_chord(
    driven: Sequence[Driven],
    rotation: np.ndarray,
    parents: np.ndarray,
    t_ref_rot: np.ndarray,
    t_ref_pos: np.ndarray,
    s_pos: np.ndarray,
    source_map: SkeletonMap,
    target_map: SkeletonMap,
    world: np.ndarray,
    *,
    rest_axes: bool,
) -> None:
    """Turn the rig's spine joint (with any driven joint between it and the chest) so its
    pelvis -> neck points as the source's, or as near as the spine's bone can bring it
    (``rotation`` ``(F, D, 3, 3)``, the ``driven`` joints' world rotations, changed in
    place). ``parents`` ``(J,)``, ``t_ref_rot`` ``(J, 3, 3)`` and ``t_ref_pos`` ``(J, 3)`` are
    the rig's hierarchy and reference pose, ``s_pos`` ``(F, J_s, 3)`` the source's
    positions, ``world`` ``(3, 3)`` the rig's world axes onto the source's; ``rest_axes``:
    the rig's takes are read in its rest pose's axes, whatever their frames do."""
    if not rest_axes:
        return  # read back from its frames (module docstring): the bend is not passed on
    slot = {d.target: i for i, d in enumerate(driven)}
    t_pelvis, t_spine, t_chest, t_neck = (
        int(target_map.joints[CANONICAL_INDEX[n]]) for n in ("pelvis", "spine", "chest", "neck")
    )
    s_pelvis, s_neck = (int(source_map.joints[CANONICAL_INDEX[n]]) for n in ("pelvis", "neck"))
    chain = _path(parents, t_pelvis, t_neck)
    if chain is None or s_neck == s_pelvis or t_spine not in chain[1:-1] or t_spine not in slot:
        return  # no spine joint between pelvis and neck: nothing to turn
    at = chain.index(t_spine)
    # The piece that turns ends below the chest (the first joint `motion` reads above the
    # pelvis), or below the neck where the chest is not above the spine on this chain.
    top = chain.index(t_chest) if t_chest in chain[at + 1 : -1] else len(chain) - 1
    positions = _chain_positions(chain, slot, rotation, parents, t_ref_rot, t_ref_pos)
    pelvis_at, spine_at, top_at = positions[:, 0], positions[:, at], positions[:, top]
    above = positions[:, -1] - top_at  # (F, 3) top -> neck, which keeps its direction
    wanted = (s_pos[:, s_neck] - s_pos[:, s_pelvis]) @ world  # (F, 3), rig's world axes
    # The neck on the chord from the pelvis <=> the top on the same chord from the pelvis
    # moved back by top -> neck; the top can reach the sphere about the spine.
    radius = np.linalg.norm(top_at - spine_at, axis=1)
    target = _on_ray(pelvis_at - above, wanted, spine_at, radius)
    # A source frame with the neck on the pelvis has no chord: that frame keeps the aiming.
    target = np.where(np.linalg.norm(wanted, axis=1, keepdims=True) > 1e-12, target, top_at)
    turn = swing(top_at - spine_at, target - spine_at)  # (F, 3, 3)
    for joint in chain[at:top]:
        if joint in slot:
            rotation[:, slot[joint]] = turn @ rotation[:, slot[joint]]


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
) -> np.ndarray:
    """``(F, 3)`` the far point where the ray ``origin + t·direction`` (``(F, 3)``) meets the
    sphere about ``centre`` ``(F, 3)`` of ``radius`` ``(F,)`` (the one point for an origin
    inside the sphere; continuous with a straight chain); where it misses, the ray's point
    nearest the centre (aimed at, it puts the bone's end as near the ray as it can reach)."""
    unit = direction / np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-12)
    offset = origin - centre
    along = np.sum(unit * offset, axis=1)
    room = along**2 - np.sum(offset * offset, axis=1) + radius**2
    t = -along + np.sqrt(np.maximum(room, 0.0))
    return origin + t[:, None] * unit


__all__ = ["aim_trunk_chord"]
