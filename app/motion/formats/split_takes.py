"""One take written as several animations, one per animated object: which ones to join.

Blender's FBX exporter with "all actions" (its default) writes an animation stack per object
and action, each moving only that object: a character whose armature hangs from an animated
empty (a 3ds Max Biped's root, a root-motion null) comes out as one stack that carries the
travel and another that turns the bones, and every action whose curves fit another object is
also written on that object (the empty's action played by the armature). Read alone, no stack
is the take: the body walks on the spot, or a still figure glides.

The rule reads the motion itself, not the stacks' names: animations of the same span are one
take when each moves a different part of the skeleton (no node moved by two of them), leaving
out those that move nothing and those that repeat another's motion on a second node (the same
curves under a fixed offset: an action written on an object it was not made for). When two of
the rest move the same node, they are different takes (a walk and a run of one length), and
nothing is joined.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.motion.formats.scene import quaternion_matrices

# Baked keys are float32 curves resampled: a node still to within this is still. Rotations in
# radians, translations and scales relative to the figure's size (its longest rest offset).
_STILL_ANGLE = 1e-3
_STILL_SHARE = 1e-4
# A repeated action's fixed offset, to within float32 curves resampled.
_SAME_ANGLE = 1e-4
_SAME_SHARE = 1e-4
_REPEAT_FRAMES = 64


@dataclass(frozen=True)
class TakeTracks:
    """One animation's baked local transforms of a skeleton's ``N`` nodes over ``F`` frames.

    Attributes
    ----------
    translation, rotation, scale:
        ``(F, N, 3)``, ``(F, N, 4)`` quaternions ``(x, y, z, w)``, ``(F, N, 3)``; a node the
        animation has no curves for holds its rest transform.
    """

    translation: np.ndarray
    rotation: np.ndarray
    scale: np.ndarray


def moving_nodes(tracks: TakeTracks, size: float) -> np.ndarray:
    """``(N,)`` bools: the nodes whose transform changes over the take (by more than baking's
    noise; ``size`` is the figure's size in the file's units)."""
    first = tracks.rotation[:1]
    turned = _angle(tracks.rotation, first).max(axis=0) > _STILL_ANGLE
    tolerance = _STILL_SHARE * max(size, 1e-9)
    moved = np.abs(tracks.translation - tracks.translation[:1]).max(axis=(0, 2)) > tolerance
    scaled = np.abs(tracks.scale - tracks.scale[:1]).max(axis=(0, 2)) > _STILL_SHARE
    return turned | moved | scaled


def joined_take(takes: list[TakeTracks], size: float, depths: np.ndarray) -> list[int]:
    """Indices (in file order) of the animations of one span that together are one take, or
    ``[]`` when they are not (fewer than two move a part of their own, or two move the same
    node). ``takes`` share one skeleton and one frame count; ``size`` as for
    :func:`moving_nodes`; ``depths`` ``(N,)`` each node's number of ancestors.

    Of animations that repeat one motion on several nodes, the one on the node nearest the
    top of the tree is kept (an action is written on objects below the one it was made for
    as well, such as a root null's travel on the armature it carries)."""
    moving = [moving_nodes(take, size) for take in takes]
    # A fixed offset holds at every frame: frames spread over the take show a repeat as
    # well as all of them, at a bounded cost for long takes.
    frames = np.unique(np.linspace(0, len(takes[0].rotation) - 1, _REPEAT_FRAMES).astype(int))
    sampled = [
        TakeTracks(t.translation[frames], t.rotation[frames], t.scale[frames]) for t in takes
    ]
    live = [i for i in range(len(takes)) if moving[i].any()]
    # the most moving first, then the highest in the tree, then in file order
    live.sort(key=lambda i: (-int(moving[i].sum()), int(depths[moving[i]].min()), i))
    kept: list[int] = []
    for i in live:
        if not any(_repeats(sampled[i], moving[i], sampled[j], moving[j], size) for j in kept):
            kept.append(i)
    if len(kept) < 2:
        return []
    counts = np.sum([moving[i] for i in kept], axis=0)
    if counts.max() > 1:
        return []
    return sorted(kept)


def join(parts: list[TakeTracks], size: float) -> TakeTracks:
    """The one take the ``parts`` are (see :func:`joined_take`): every node as the part that
    moves it has it; a node none moves as the part that moves most has it."""
    moving = [moving_nodes(part, size) for part in parts]
    main = max(range(len(parts)), key=lambda i: (int(moving[i].sum()), -i))
    translation = parts[main].translation.copy()
    rotation = parts[main].rotation.copy()
    scale = parts[main].scale.copy()
    for i, take in enumerate(parts):
        if i == main:
            continue
        nodes = moving[i]
        translation[:, nodes] = take.translation[:, nodes]
        rotation[:, nodes] = take.rotation[:, nodes]
        scale[:, nodes] = take.scale[:, nodes]
    return TakeTracks(translation, rotation, scale)


def _repeats(
    take: TakeTracks, moving: np.ndarray, other: TakeTracks, other_moving: np.ndarray, size: float
) -> bool:
    """Whether every node ``take`` moves moves as some node ``other`` moves, up to a fixed
    transform applied before it (``T(f) = C T'(f)``, the parent-inverse of an object the
    action was written on as well)."""
    candidates = np.flatnonzero(other_moving)
    for node in np.flatnonzero(moving):
        if not any(
            _same_motion(take, int(node), other, int(m), size) for m in candidates if m != node
        ):
            return False
    return True


def _same_motion(a: TakeTracks, i: int, b: TakeTracks, j: int, size: float) -> bool:
    """Whether node ``i`` of ``a`` moves as node ``j`` of ``b`` up to a fixed transform ``C``:
    ``R_a = R_c R_b`` and ``t_a = t_c + R_c t_b`` at every frame."""
    ra = quaternion_matrices(a.rotation[:, i])  # (F, 3, 3)
    rb = quaternion_matrices(b.rotation[:, j])
    offset = ra @ np.swapaxes(rb, 1, 2)  # R_c at every frame
    if np.abs(offset - offset[:1]).max() > _SAME_ANGLE:
        return False
    shifted = a.translation[:, i] - b.translation[:, j] @ offset[0].T
    tolerance = _SAME_SHARE * max(size, 1e-9)
    return bool(np.abs(shifted - shifted[:1]).max() <= tolerance)


def _angle(q: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Angle in radians between unit quaternions (broadcast over leading axes)."""
    dot = np.abs(np.sum(q * r, axis=-1))
    return 2.0 * np.arccos(np.clip(dot, 0.0, 1.0))
