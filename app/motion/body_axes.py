"""The body's axes (lateral, up, forward) in the pelvis joint's coordinates, read from poses.

:mod:`app.motion.body` reads them from the rest pose when it is a figure of the body; the
functions here read them from any ``(F, J, 3)`` poses with the pelvis's ``(F, 3, 3)`` world
rotations in them: :func:`pose_basis` the legs' line and the trunk, :func:`frames_basis` the
same for a take whose rest pose is no pose of the body, up then from the world's up when the
take stands; :func:`pelvis_carries` tells whether the bones the pelvis carries show a
rest pose's axes, the same in every frame; :func:`pelvis_turns_with_hips` whether the pelvis
joint's rotation moves the body at all, and :func:`frames_from_positions` the body's frames
from the joints alone where it does not.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from app.errors import ParseError
from app.motion.model import Skeleton
from app.motion.skeleton_map import CANONICAL_INDEX, COINCIDENT

# A pose stands when its trunk is upright, within 35 degrees of the world's up (the angle
# the bent-take reading of mapping/take.py calls upright)...
_UPRIGHT = float(np.cos(np.radians(35.0)))
# ...and an ankle is below the pelvis by this share of the leg (hip -> knee -> ankle) at
# least: a stance leg bent at the knee by up to ~50 degrees (a run's stance bends ~40, a
# walk's ~20), where a seated body's ankles are only a shin (~0.5) below...
_STANDING_DROP = 0.8
# ...and the world's up tells the pelvis's up when most poses of the take stand (a
# majority, as the take's vote).
_STANDING_SHARE = 0.5


# The joints the axes are read from: the trunk's two ends and each leg's.
_TRUNK_AND_LEGS = ("pelvis", "neck", *(f"{s}_{p}" for s in "lr" for p in ("hip", "knee", "ankle")))


def _trunk_and_legs(positions: np.ndarray, canonical: np.ndarray) -> dict[str, np.ndarray]:
    """Name -> ``(F, 3)`` positions of the :data:`_TRUNK_AND_LEGS` joints in the poses."""
    return {name: positions[:, canonical[CANONICAL_INDEX[name]]] for name in _TRUNK_AND_LEGS}


def pose_basis(positions: np.ndarray, pelvis: np.ndarray, canonical: np.ndarray) -> np.ndarray:
    """``(3, 3)`` body axes in the pelvis joint's coordinates from ``(F, J, 3)`` poses and the
    ``(F, 3, 3)`` pelvis rotations in them (directions averaged over the poses)."""
    return _basis(_trunk_and_legs(positions, canonical), positions, pelvis, canonical)


def _basis(
    at: dict[str, np.ndarray], positions: np.ndarray, pelvis: np.ndarray, canonical: np.ndarray
) -> np.ndarray:
    """:func:`pose_basis` from the poses' trunk-and-legs positions ``at`` already read."""
    size = float(np.ptp(positions[:, canonical], axis=1).max())
    local = np.swapaxes(pelvis, -1, -2)
    across = _legs_across(
        lambda part: np.einsum("fab,fb->fa", local, at[f"l_{part}"] - at[f"r_{part}"]),
        size,
        np.min,  # every pose must show the sides
    )
    if across is None:
        raise ParseError("the left and right legs coincide; cannot tell left from right")
    lateral = (across / np.linalg.norm(across, axis=1, keepdims=True)).sum(axis=0)
    x = lateral / np.linalg.norm(lateral)
    up = np.einsum("fab,fb->a", local, at["neck"] - at["pelvis"])
    up = up - np.dot(up, x) * x
    up_norm = float(np.linalg.norm(up))
    if up_norm < 1e-9 * max(size, 1e-300):
        raise ParseError("the neck is level with the hips; cannot find the body's up direction")
    y = up / up_norm
    return np.stack([x, y, np.cross(x, y)], axis=1)


def frames_basis(positions: np.ndarray, pelvis: np.ndarray, canonical: np.ndarray) -> np.ndarray:
    """``(3, 3)`` body axes (columns lateral, up, forward) in the pelvis joint's coordinates
    read from ``(F, J, 3)`` poses of the take and the ``(F, 3, 3)`` pelvis rotations in them,
    for a rig whose rest pose is no pose of the body.

    Lateral comes from the legs (:func:`pose_basis`: exact, the hips hang from the pelvis).
    Up should be where a standing rest pose puts it, and the take's trunk (pelvis -> neck,
    seen from the pelvis) is a biased reading of it: it carries the spine's bend, which the
    activity sets (a walk leaning into its steps, a hunched walk, a one-pose clip bent at
    the spine), by up to 30 degrees and more. A standing person carries the pelvis near
    level whatever the spine does, so when most poses stand (:data:`_UPRIGHT`,
    :data:`_STANDING_DROP`), up is the world's up seen from the pelvis, averaged over the
    standing poses. The world's up is the coordinate axis nearest the trunk's mean
    direction (files are authored with an axis up, as ``app.motion.body`` finds the world's
    up). A take that mostly does not stand (lying, flying, seated, tumbling) tells nothing
    of the pelvis through gravity and keeps the trunk's up.
    """
    at = _trunk_and_legs(positions, canonical)
    axes = _basis(at, positions, pelvis, canonical)
    trunk = at["neck"] - at["pelvis"]
    trunk = trunk / np.maximum(np.linalg.norm(trunk, axis=1, keepdims=True), 1e-300)
    world_up = _snapped(trunk.mean(axis=0))
    leg = np.mean(
        [
            np.linalg.norm(at[f"{s}_hip"] - at[f"{s}_knee"], axis=1)
            + np.linalg.norm(at[f"{s}_knee"] - at[f"{s}_ankle"], axis=1)
            for s in "lr"
        ]
    )
    drop = np.max([(at["pelvis"] - at[f"{s}_ankle"]) @ world_up for s in "lr"], axis=0)
    standing = (trunk @ world_up >= _UPRIGHT) & (drop >= _STANDING_DROP * leg)
    if not standing.any() or standing.sum() < _STANDING_SHARE * len(standing):
        return axes
    x = axes[:, 0]
    up = np.einsum("fba,b->a", pelvis[standing], world_up)
    up = up - np.dot(up, x) * x
    up_norm = float(np.linalg.norm(up))
    if up_norm < 1e-9:  # the pelvis lies sideways in every standing pose: no reading
        return axes
    y = up / up_norm
    return np.stack([x, y, np.cross(x, y)], axis=1)


def pelvis_carries(
    skeleton: Skeleton, canonical: np.ndarray, rest: np.ndarray, *, within: float
) -> bool:
    """Whether the bones the pelvis itself carries show the rest pose's ``(3, 3)`` axes
    (columns lateral, up, forward, in the pelvis joint's coordinates) in every frame.

    A joint's offset from the pelvis is fixed in the pelvis's coordinates, whatever the
    writer's bone axes and whatever a frame does: where both hips hang from the pelvis and
    the rest pose's trunk is one straight line along the pelvis's own bone toward the neck
    (every bone of the chain along it, and the rest's lateral and up each within ``within``,
    a cosine, of the hips' line and that bone), the rest pose's axes are read from bones
    every frame carries as the rest does, so every frame shows them by its pelvis, however
    the spine bends above it (a trunk that leans throughout). A rest pose that is no figure
    of the body does not pass: in random axes the chain above the pelvis's bone points
    anywhere, and its chord can lie near that bone by chance, but not every bone of it.
    """
    parents, offsets = skeleton.parents, skeleton.offsets
    pelvis = int(canonical[CANONICAL_INDEX["pelvis"]])
    hips = [int(canonical[CANONICAL_INDEX[f"{side}_hip"]]) for side in "lr"]
    if any(int(parents[hip]) != pelvis for hip in hips):
        return False  # a hip below another joint: its line turns with that joint's axes
    chain = [int(canonical[CANONICAL_INDEX["neck"]])]  # neck up to the pelvis's child
    while chain[-1] >= 0 and int(parents[chain[-1]]) != pelvis:
        chain.append(int(parents[chain[-1]]))
    if chain[-1] < 0:
        return False
    size = float(np.linalg.norm(offsets, axis=1).max())
    across = offsets[hips[0]] - offsets[hips[1]]
    bone = offsets[chain[-1]]
    lengths = np.linalg.norm(offsets[chain], axis=1)
    if min(float(np.linalg.norm(across)), float(lengths[-1])) <= COINCIDENT * max(size, 1e-300):
        return False  # hips or the pelvis's bone at the pelvis: they show no direction
    along = offsets[chain] @ (bone / lengths[-1])
    if not np.all(along >= within * lengths):
        return False  # the rest's trunk bends above the pelvis's bone
    x = across / np.linalg.norm(across)
    up = bone - np.dot(bone, x) * x
    if not float(np.linalg.norm(up)) > COINCIDENT * size:
        return False  # the pelvis's bone lies along the hips' line
    y = up / np.linalg.norm(up)
    return float(rest[:, 0] @ x) >= within and float(rest[:, 1] @ y) >= within


def _legs_across(
    across: Callable[[str], np.ndarray],
    size: float,
    statistic: Callable[[np.ndarray], np.floating[Any]],
) -> np.ndarray | None:
    """``(F, 3)`` right to left across the legs: ``across(part)`` for the first of hip, knee
    and ankle whose ``statistic`` of the ``(F,)`` lengths is above ``COINCIDENT`` x ``size``,
    or None. Some rigs put both hip joints at the pelvis and separate the legs only at the
    next joint down: the legs then show the sides where they part."""
    for part in ("hip", "knee", "ankle"):
        line = across(part)
        if float(statistic(np.linalg.norm(line, axis=1))) > COINCIDENT * size:
            return line
    return None


def _hips_line(positions: np.ndarray) -> np.ndarray:
    """``(F, 3)`` right to left across the legs of ``(F, C, 3)`` canonical positions: the
    hips, or where the legs part when both hip joints sit at the pelvis (zero where none)."""
    size = float(np.ptp(positions, axis=1).max())
    across = _legs_across(
        lambda part: (
            positions[:, CANONICAL_INDEX[f"l_{part}"]] - positions[:, CANONICAL_INDEX[f"r_{part}"]]
        ),
        max(size, 1e-300),
        np.median,  # most frames must show the sides
    )
    return np.zeros((len(positions), 3)) if across is None else across


def pelvis_turns_with_hips(
    frames: np.ndarray, positions: np.ndarray, *, within: float, share: float
) -> bool:
    """Whether the ``(F, 3, 3)`` pelvis frames turn with the hips in the ``(F, C, 3)`` poses.

    The pelvis joint's rotation is the body's only when it moves the body: its lateral
    axis then follows the line across the hips, exactly where the hips hang from it and
    within a few degrees where a hip joint between them turns a little. A writer that puts
    every child of the pelvis at the pelvis and gives each its own rotation can turn the
    pelvis anywhere and turn the children back (a pose network's output: the pelvis turned
    90 degrees while the body stands): its rotation moves no bone, and its lateral axis and
    the hips' line part by more than ``within`` (a cosine) in more than ``share`` of the
    frames. Only the hips are asked: the trunk bends away from the pelvis by the take's own
    lean, and where both hips sit at the pelvis the line where the legs part swings with the
    knees — no landmark of the pelvis (its rotation is then kept).
    """
    size = float(np.ptp(positions, axis=1).max())
    hips = positions[:, CANONICAL_INDEX["l_hip"]] - positions[:, CANONICAL_INDEX["r_hip"]]
    length = np.linalg.norm(hips, axis=1)
    seen = length > COINCIDENT * max(size, 1e-300)
    if not seen.sum() > 0.5 * len(seen):
        return True
    across = np.einsum("fa,fa->f", frames[seen, :, 0], hips[seen]) / length[seen]
    return float(np.mean(across >= within)) >= share


def _trunk_up(positions: np.ndarray) -> np.ndarray:
    """``(F, 3)`` pelvis -> neck of ``(F, C, 3)`` canonical positions, without its part along
    the hips' line (zero where the legs show no line)."""
    lateral = _hips_line(positions)
    length = np.linalg.norm(lateral, axis=1, keepdims=True)
    x = np.where(length > 0, lateral / np.maximum(length, 1e-300), 0.0)
    trunk = positions[:, CANONICAL_INDEX["neck"]] - positions[:, CANONICAL_INDEX["pelvis"]]
    return trunk - np.einsum("fa,fa->f", trunk, x)[:, None] * x


def frames_from_positions(positions: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """``(F, 3, 3)`` body frames from ``(F, C, 3)`` canonical positions alone: lateral across
    the hips (or where the legs part), up from the pelvis toward the neck (orthogonalised),
    forward = lateral x up; a frame where they are parallel or missing keeps ``fallback``.

    Up then carries the spine's bend, which the pelvis's own axes do not: the reading for a
    pelvis whose rotation carries nothing, not a better one for the others."""
    lateral, up = _hips_line(positions), _trunk_up(positions)
    lateral_length = np.linalg.norm(lateral, axis=1, keepdims=True)
    up_length = np.linalg.norm(up, axis=1, keepdims=True)
    x = lateral / np.maximum(lateral_length, 1e-300)
    y = up / np.maximum(up_length, 1e-300)
    frames = np.stack([x, y, np.cross(x, y)], axis=2)
    size = float(np.ptp(positions, axis=1).max())
    good = (lateral_length[:, 0] > 0) & (up_length[:, 0] > 1e-9 * max(size, 1e-300))
    return np.where(good[:, None, None], frames, fallback)


def _snapped(vector: np.ndarray) -> np.ndarray:
    """``(3,)`` the signed coordinate axis nearest to ``vector`` (``+Y`` for a zero vector)."""
    snapped = np.zeros(3)
    if not float(np.linalg.norm(vector)) > 1e-9:
        snapped[1] = 1.0
        return snapped
    axis = int(np.argmax(np.abs(vector)))
    snapped[axis] = np.sign(vector[axis])
    return snapped


__all__ = [
    "frames_basis",
    "frames_from_positions",
    "pelvis_carries",
    "pelvis_turns_with_hips",
    "pose_basis",
]
