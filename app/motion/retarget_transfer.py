"""Per-joint rotation transfer: the driven target joints' rotations, frame by frame.

A driven target joint turns as its source joint turned since the source's reference pose::

    G_target(f) = W^T · G_source(f) · Q_source^T · A · Q_target

``Q`` are the joints' world rotations in the reference poses, ``A`` takes the target's
reference bone onto the source's (the whole body, then the bone's smallest rotation), ``W``
the world axes from the source's up to the target's. Then a swing per frame turns each
aimed bone onto the source bone's world direction, and a limb bone split into as many pieces
in both turns as one (:func:`turn_split_limbs`). Every other joint keeps its reference local
rotation (:class:`TargetRotations`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from app.motion.retarget_joints import Driven, Limb
from app.motion.retarget_reference import swing


def driven_rotations(
    driven: Sequence[Driven],
    limbs: Sequence[Limb],
    s_rot: np.ndarray,
    s_pos: np.ndarray,
    s_ref_rot: np.ndarray,
    s_ref_pos: np.ndarray,
    t_ref_rot: np.ndarray,
    t_ref_pos: np.ndarray,
    body: np.ndarray,
    world: np.ndarray,
) -> np.ndarray:
    """``(F, D, 3, 3)`` the ``driven`` target joints' world rotations, in the target's axes.

    ``s_rot`` ``(F, J_s, 3, 3)`` and ``s_pos`` ``(F, J_s, 3)`` are the source's world
    rotations and positions, ``s_ref_rot`` ``(J_s, 3, 3)`` and ``s_ref_pos`` ``(J_s, 3)`` its
    reference pose, ``t_ref_rot`` ``(J, 3, 3)`` and ``t_ref_pos`` ``(J, 3)`` the target's;
    ``body`` ``(3, 3)`` takes the target's reference body axes onto the source's, ``world``
    ``(3, 3)`` the target's world axes onto the source's."""
    world_t = world.T
    # Constant per driven joint: C = Q_source^T · A · Q_target, so G = W^T · G_source · C.
    aligned: dict[int, np.ndarray] = {}
    constants = np.empty((len(driven), 3, 3))
    for i, d in enumerate(driven):
        align = aligned.get(d.align_like, body) if d.align_like is not None else body
        if d.align_bones is not None:
            t_from, t_to, s_from, s_to = d.align_bones
            t_bone = t_ref_pos[t_to] - t_ref_pos[t_from]
            s_bone = s_ref_pos[s_to] - s_ref_pos[s_from]
            align = swing(body @ t_bone, s_bone) @ body
        if d.target_aim is not None and d.source_aim is not None:
            t_bone = t_ref_pos[d.target_aim] - t_ref_pos[d.target]
            s_bone = s_ref_pos[d.source_aim] - s_ref_pos[d.source]
            align = swing(body @ t_bone, s_bone) @ body
        aligned[d.target] = align
        constants[i] = s_ref_rot[d.source].T @ align @ t_ref_rot[d.target]
    targets = np.array([d.target for d in driven], dtype=np.int64)
    sources = np.array([d.source for d in driven], dtype=np.int64)
    rotation = s_rot[:, sources] @ constants  # (F, D, 3, 3)
    if not np.array_equal(world_t, np.eye(3)):  # a quarter turn between the up axes
        rotation = world_t @ rotation
    # Directions exact: one swing per frame and driven bone, all at once.
    fixed = [i for i, d in enumerate(driven) if d.target_aim is not None]
    if fixed:
        t_aims = np.array([driven[i].target_aim for i in fixed], dtype=np.int64)
        s_aims = np.array([driven[i].source_aim for i in fixed], dtype=np.int64)
        t_bones = t_ref_pos[t_aims] - t_ref_pos[targets[fixed]]  # (K, 3) in the reference
        local_bones = np.swapaxes(t_ref_rot[targets[fixed]], -1, -2) @ t_bones[:, :, None]
        now = (rotation[:, fixed] @ local_bones)[..., 0]  # (F, K, 3)
        wanted = (s_pos[:, s_aims] - s_pos[:, sources[fixed]]) @ world
        rotation[:, fixed] = swing(now, wanted) @ rotation[:, fixed]
    turn_split_limbs(limbs, driven, rotation, t_ref_rot, t_ref_pos, s_pos, world)
    return rotation


@dataclass(frozen=True)
class TargetRotations:
    """The target's rotations: the driven joints' world rotations ``rotation``
    ``(F, D, 3, 3)`` (``slot`` maps a driven joint to its index in them), every joint's local
    rotations ``local`` ``(F, J, 3, 3)``; each joint's nearest driven ancestor-or-self
    ``anchor`` ``(J,)`` (-1: none) and the reference world rotations ``reference``
    ``(J, 3, 3)``."""

    rotation: np.ndarray
    slot: dict[int, int]
    anchor: np.ndarray
    reference: np.ndarray
    local: np.ndarray

    def world_of(self, joints: np.ndarray) -> np.ndarray:
        """``(F, K, 3, 3)`` world rotations of target ``joints`` ``(K,)``."""
        rotation, slot, anchor, t_ref_rot = self.rotation, self.slot, self.anchor, self.reference
        frames = rotation.shape[0]
        out = np.empty((frames, len(joints), 3, 3))
        is_driven = np.array([int(j) in slot for j in joints], dtype=bool)
        carried = (anchor[joints] >= 0) & ~is_driven
        floating = anchor[joints] < 0  # above every driven joint: at the reference
        out[:, is_driven] = rotation[:, [slot[int(j)] for j in joints[is_driven]]]
        if carried.any():
            anchors = anchor[joints[carried]]
            between = np.swapaxes(t_ref_rot[anchors], -1, -2) @ t_ref_rot[joints[carried]]
            out[:, carried] = rotation[:, [slot[int(a)] for a in anchors]] @ between
        out[:, floating] = t_ref_rot[joints[floating]]
        return out


def target_rotations(
    driven: Sequence[Driven], rotation: np.ndarray, t_ref_rot: np.ndarray, parents: np.ndarray
) -> TargetRotations:
    """Every target joint's local rotations from the ``driven`` joints' world rotations
    ``rotation`` ``(F, D, 3, 3)``, the target's reference world rotations ``t_ref_rot``
    ``(J, 3, 3)`` and ``parents`` ``(J,)``."""
    frames = rotation.shape[0]
    count = len(parents)
    targets = np.array([d.target for d in driven], dtype=np.int64)
    # Every other joint keeps its reference local rotation (its world rotation is its
    # nearest driven ancestor's times the constant reference rotation between the two), so
    # only the driven joints' local rotations change per frame.
    anchor = np.full(count, -1, dtype=np.int64)
    slot = {int(t): i for i, t in enumerate(targets)}
    for j in range(count):
        if j in slot:
            anchor[j] = j
        elif parents[j] >= 0:
            anchor[j] = anchor[parents[j]]
    up_index = np.where(parents < 0, 0, parents)
    ref_local = np.swapaxes(t_ref_rot[up_index], -1, -2) @ t_ref_rot
    ref_local[0] = t_ref_rot[0]
    local = np.empty((frames, count, 3, 3))
    local[:] = ref_local
    rotations = TargetRotations(rotation, slot, anchor, t_ref_rot, local)

    # A driven joint's local rotation: its parent's world rotation (a driven parent's as it
    # is, no copy) undone.
    up_slot = np.array([slot.get(int(parents[t]), -1) for t in targets], dtype=np.int64)
    by_driven = up_slot >= 0
    other = ~by_driven & (parents[targets] >= 0)
    top = parents[targets] < 0
    local[:, targets[top]] = rotation[:, top]
    if by_driven.any():
        local[:, targets[by_driven]] = (
            np.swapaxes(rotation[:, up_slot[by_driven]], -1, -2) @ rotation[:, by_driven]
        )
    if other.any():
        above = rotations.world_of(parents[targets[other]])
        local[:, targets[other]] = np.swapaxes(above, -1, -2) @ rotation[:, other]
    return rotations


def turn_split_limbs(
    limbs: Sequence[Limb],
    driven: Sequence[Driven],
    rotation: np.ndarray,
    t_ref_rot: np.ndarray,
    t_ref_pos: np.ndarray,
    s_pos: np.ndarray,
    world: np.ndarray,
) -> None:
    """Turn each split limb bone's pieces together (``rotation`` ``(F, D, 3, 3)``, the driven
    joints' world rotations, changed in place) so the bone, base to end, points as the
    source's does. Each piece points as its source piece, but where the source's pieces are
    bent against each other (a twist joint that also bends, a rest pose not in line), pieces
    split at other points than the source's add up to another direction: a thigh split at a
    quarter against a source's split at a fifth and bent 20 degrees points 8 degrees off.
    One turn for the whole bone keeps the bend between its pieces. ``t_ref_rot``
    ``(J, 3, 3)`` and ``t_ref_pos`` ``(J, 3)`` are the target's reference pose, ``s_pos``
    ``(F, J_s, 3)`` the source's positions, ``world`` the source-to-target axes change."""
    slot = {d.target: i for i, d in enumerate(driven)}
    for limb in limbs:
        if any(p not in slot or driven[slot[p]].target_aim is None for p in limb.pieces):
            continue  # a piece driven by another chain (none of the limbs' are)
        ends = [*limb.pieces[1:], limb.end]
        bone = np.zeros((rotation.shape[0], 3))
        for piece, end in zip(limb.pieces, ends, strict=True):
            local = t_ref_rot[piece].T @ (t_ref_pos[end] - t_ref_pos[piece])
            bone += rotation[:, slot[piece]] @ local
        wanted = (s_pos[:, limb.source_end] - s_pos[:, limb.source_base]) @ world
        turn = swing(bone, wanted)  # (F, 3, 3)
        for piece in limb.pieces:
            rotation[:, slot[piece]] = turn @ rotation[:, slot[piece]]


__all__ = ["TargetRotations", "driven_rotations", "target_rotations", "turn_split_limbs"]
