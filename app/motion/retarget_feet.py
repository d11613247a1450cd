"""Planted feet held by the legs: foot contact from the source, leg IK on the target.

Copying bone directions onto legs of other proportions (a longer shin, a foot that ends at
the toe tip where the capture's ends at the ball) moves a planted foot over the floor. The
retarget first corrects the pelvis's path (:func:`app.motion.retarget_floor.planted_feet_offsets`),
which holds one planted point exactly but not two that disagree (both feet, or the heel and
toe of a long foot rolling over its tip). What is left is taken up here, leg by leg:

* **Contact, from the source.** A frame step is planted for a foot when one of its source
  points (the toe first, else the ankle: the point the foot rolls over) is within ``near``
  of the source's floor at both ends, however fast it moves: a foot on the floor moves as
  the source's does, standing or sliding. (Until 2026-11-27 steps faster than 0.5 body
  heights per second were left out; those are a walk's push-off and landing, where a foot
  longer for its leg than the source's moved up to 0.05 body heights per second faster
  over the floor than the source's: see docs/export.md "Rigs we have not seen".)
* **Where the foot should be.** Over a run of planted steps the target's same point must
  move over the floor as the source's does (not at all while it stands): the correction is
  the running sum of the difference, minus its mean over the run (the least change that
  holds it), horizontal only. Over :data:`BLEND` seconds before and after a run it fades in
  and out (smoothstep), so the foot does not pop; a gap between two runs shorter than both
  fades passes from one run's correction to the next's.
* **The leg reaches for it.** The ankle is brought toward its corrected place by turning the
  whole leg about the hip (the smallest rotation taking hip -> ankle onto hip -> goal): the
  knee keeps its bend and keeps pointing where the retargeted pose pointed it, the foot
  keeps its world orientation (so the toe moves with the ankle), and only rotations change,
  so bones keep the rig's lengths. The turn is limited to :data:`MAX_TURN` degrees, which
  keeps thigh and shin within the quality bar's 5 degrees of the source's directions; a foot
  that would need more is held only that far.

Why not the full two-bone solve (hip fixed, the knee bending until hip -> ankle has the
goal's length, so the ankle keeps its height exactly): with the legs near straight in
stance, a correction of 2-8 % of the leg bends the knee by 10-30 degrees (the distance of a
straight leg changes with the square of the bend), and measured on the development clips
it put the thigh or shin more than 5 degrees off in over 1 % of frames for 6-35 % of clips
(Mixamo, Xsens, CMU ASF rigs). Turning the leg as a whole changes both bones by the turn's
angle only and lifts the ankle by under 0.3 % of the leg at the limit.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import NamedTuple

import numpy as np

from app.motion.skeleton_map import CANONICAL_INDEX, SkeletonMap

BLEND = 0.1  # seconds over which a hold fades in before a contact and out after it
MAX_TURN = 4.5  # degrees: the most a hold turns a leg (the quality bar allows 5)
_TINY = 1e-12

# World rotations (F, 3, 3) and positions (F, 3) of a few joints, by joint.
Pose = tuple[dict[int, np.ndarray], dict[int, np.ndarray]]
_FAR = np.iinfo(np.int64).max // 4


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n < _TINY, 1.0, n)


def turn_toward(a: np.ndarray, b: np.ndarray, max_angle: float) -> np.ndarray:
    """``(N, 3, 3)`` the smallest rotations taking directions ``a`` toward ``b`` ``(N, 3)``,
    by at most ``max_angle`` radians (the identity where either is zero or they agree)."""
    a, b = _unit(a), _unit(b)
    axis = np.cross(a, b)
    sin = np.linalg.norm(axis, axis=-1)
    unit = axis / np.where(sin < _TINY, 1.0, sin)[:, None]
    angle = np.where(
        sin < _TINY, 0.0, np.minimum(np.arctan2(sin, np.sum(a * b, axis=-1)), max_angle)
    )
    x, y, z = unit[:, 0], unit[:, 1], unit[:, 2]
    k = np.zeros((len(a), 3, 3))
    k[:, 0, 1], k[:, 0, 2] = -z, y
    k[:, 1, 0], k[:, 1, 2] = z, -x
    k[:, 2, 0], k[:, 2, 1] = -y, x
    sin, cos = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    return np.eye(3) + sin * k + (1 - cos) * (k @ k)


def planted_steps(points: np.ndarray, up: np.ndarray, near: float) -> np.ndarray:
    """``(F - 1, P)`` whether each point of ``points`` ``(F, P, 3)`` is planted over each
    frame step: within ``near`` of the lowest any of them gets at both ends."""
    heights = points @ up
    low = heights - heights.min() < near
    return low[1:] & low[:-1]


def _smooth(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def hold_corrections(extra: np.ndarray, planted: np.ndarray, blend_frames: int) -> np.ndarray:
    """``(F, 3)`` corrections to add to a foot, given ``extra`` ``(F - 1, 3)``: per frame
    step, how much farther its source point moved than its own. Over each run of
    ``planted`` ``(F - 1,)`` steps the corrections make the foot's point move as the
    source's, with the least change (zero mean over the run); around each run they fade in
    and out over ``blend_frames`` frames, and are zero farther away."""
    frames = len(extra) + 1
    extra = np.where(planted[:, None], extra, 0.0)
    edges = np.diff(np.concatenate([[0], planted.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)  # steps [s, e)
    correction = np.zeros((frames, 3))
    if not len(starts):
        return correction
    held = np.zeros(frames, dtype=bool)
    total = np.concatenate([np.zeros((1, 3)), np.cumsum(extra, axis=0)])  # (F, 3)
    for s, e in zip(starts, ends, strict=True):  # runs: frames s .. e (steps s .. e - 1)
        part = total[s : e + 1] - total[s]
        correction[s : e + 1] = part - part.mean(axis=0)
        held[s : e + 1] = True
    if held.all():
        return correction
    # Frames outside the runs: the nearest runs' end values, faded by the distance to them.
    index = np.arange(frames)
    before = np.maximum.accumulate(np.where(held, index, -1))
    after = np.minimum.accumulate(np.where(held, index, frames)[::-1])[::-1]
    free = ~held
    fb, fa, at = before[free], after[free], index[free]
    value_b = np.where((fb >= 0)[:, None], correction[np.maximum(fb, 0)], 0.0)
    value_a = np.where((fa < frames)[:, None], correction[np.minimum(fa, frames - 1)], 0.0)
    span = blend_frames + 1
    db = np.where(fb >= 0, at - fb, _FAR)
    da = np.where(fa < frames, fa - at, _FAR)
    gap = db + da
    bridged = gap <= 2 * span  # both fades overlap: pass from one run's value to the next's
    share = np.where(bridged, da / np.maximum(gap, 1), 0.0)[:, None]
    faded = (
        _smooth(1.0 - db / span)[:, None] * value_b + _smooth(1.0 - da / span)[:, None] * value_a
    )
    correction[free] = np.where(bridged[:, None], share * value_b + (1.0 - share) * value_a, faded)
    return correction


class FeetInputs(NamedTuple):
    """What the feet passes of a retarget share (:func:`hold_planted_feet`,
    :func:`~app.motion.retarget_stride.fit_planted_roll`,
    :func:`~app.motion.retarget_floor.clear_swinging_toes`): the target's mapping and
    ``(J,)`` parents, its ``(F, J, 3, 3)`` local rotations (each pass changes them in place),
    the seconds a frame, the source's foot points ``(F, 4, 3)`` (scaled, in the target's
    axes, :data:`~app.motion.ground.FOOT_POINTS` order), the target's ``(3,)`` up axis and
    the on-floor distance, in the target's units."""

    mapping: SkeletonMap
    parents: np.ndarray
    local: np.ndarray
    frame_time: float
    source_feet: np.ndarray
    up: np.ndarray
    near: float


def hold_planted_feet(
    kinematics: Callable[[Sequence[int]], Pose], passes: FeetInputs, height: float
) -> np.ndarray | None:
    """Hold each planted foot of the retarget where the source's stands (see the module
    docstring), changing its ``local`` rotations ``(F, J, 3, 3)`` in place.

    Parameters
    ----------
    kinematics:
        World rotations ``(F, 3, 3)`` and positions ``(F, 3)`` of the given joints (and
        those between them and the pelvis), by joint, for the current ``local``.
    passes:
        The feet passes' shared inputs (:class:`FeetInputs`).
    height:
        The body height, in the target's units.

    Returns
    -------
    ``(F, 4, 3)`` the target's foot points after the hold (in ``source_feet``'s order; a
    turned leg moves its ankle a little up or down), or ``None`` when nothing changed.
    """
    mapping, parents, local, frame_time, source_feet, up, near = passes
    frames = local.shape[0]
    if frames < 3:
        return None
    legs = []
    for side in ("l", "r"):
        hip, knee, ankle, toe = (
            int(mapping.joints[CANONICAL_INDEX[f"{side}_{name}"]])
            for name in ("hip", "knee", "ankle", "toe")
        )
        if hip > 0 and len({hip, knee, ankle}) == 3:
            legs.append((side, hip, ankle, toe))
    if len(legs) < 2:
        return None
    rotations, positions = kinematics(
        [j for _, hip, ankle, toe in legs for j in (hip, ankle, toe, parents[hip], parents[ankle])]
    )
    planted = planted_steps(source_feet, up, near)
    blend_frames = max(1, round(BLEND / frame_time))
    feet = np.stack([positions[j] for _, _, ankle, toe in legs for j in (ankle, toe)], axis=1)
    changed = False
    for leg_index, (side, hip, ankle, toe) in enumerate(legs):
        a_index, t_index = (0, 1) if side == "l" else (2, 3)
        on_toe = planted[:, t_index] & (toe != ankle)
        steps = on_toe | planted[:, a_index]
        if not steps.any():
            continue
        # Per step the pivot's motion: the toe where it is planted, else the ankle.
        point = np.where(on_toe[:, None], t_index, a_index)
        own = np.where(
            on_toe[:, None], np.diff(positions[toe], axis=0), np.diff(positions[ankle], axis=0)
        )
        source_step = np.take_along_axis(np.diff(source_feet, axis=0), point[:, :, None], axis=1)
        extra = source_step[:, 0] - own
        extra = extra - (extra @ up)[:, None] * up  # over the floor: heights stay
        correction = hold_corrections(extra, steps, blend_frames)
        moved = np.flatnonzero(np.linalg.norm(correction, axis=1) > 1e-9 * height)
        if not len(moved):
            continue
        leg = positions[ankle][moved] - positions[hip][moved]
        turn = turn_toward(leg, leg + correction[moved], np.radians(MAX_TURN))
        # The hip turns the leg; the foot keeps its world orientation.
        hip_world = turn @ rotations[hip][moved]
        ankle_parent = turn @ rotations[int(parents[ankle])][moved]
        local[moved, hip] = np.swapaxes(rotations[int(parents[hip])][moved], -1, -2) @ hip_world
        local[moved, ankle] = np.swapaxes(ankle_parent, -1, -2) @ rotations[ankle][moved]
        # The foot moves with its ankle (it keeps its orientation).
        shift = (turn @ leg[:, :, None])[:, :, 0] - leg
        feet[moved, 2 * leg_index : 2 * leg_index + 2] += shift[:, None]
        changed = True
    if not changed:
        return None
    return feet


__all__ = [
    "BLEND",
    "MAX_TURN",
    "FeetInputs",
    "Pose",
    "hold_corrections",
    "hold_planted_feet",
    "planted_steps",
    "turn_toward",
]
