"""A planted foot's roll fitted to the rig's foot, so a walk's stride is the source's scaled.

A foot on the floor by its toe rolls over it: as the heel rises the ankle comes forward over
the toe by ``L (1 - cos pitch)``, ``L`` the ankle -> toe length. Copying the source foot's
direction onto a rig whose toe point lies farther from the ankle for its legs (a toe tip
where the source has the ball of its foot: ankle -> toe 0.33 of the leg on the Mixamo and
Xsens rigs against the Bandai capture's 0.15) rolls the body farther over the toe in every
step, and since a walk is always on a foot, the pelvis path that keeps planted feet from
sliding carries that on as travel: the Bandai walk went 12 % farther than its scaled source
on those rigs (docs/export.md, "A walk's stride on a long foot").

So while the source's toe is on the floor, the rig's foot is pitched so that its ankle moves
over the toe, along the floor, as the source's does (scaled): each contact starts from the
rig's own foot (the pitch the copied directions give it when the toe lands), and from there
the ankle comes forward over the toe by the source's distance, not more. A longer foot then
pitches less than the source's as the heel rises, and its ankle rises less than the same
pitch would lift it. Only the foot turns (about the ankle, heading and sideways lean kept):
thigh, shin and everything above keep the source's rotations, and the pitch fades in and
out over :data:`~app.motion.retarget_feet.BLEND` around each contact so the foot does not
pop. A rig whose foot is as long as the source's (scaled) or shorter is left alone: its toe
rolls as the source's does or less, and the pelvis path holds it.

A first version gave each contact the source's distance plus the constant difference of the
two feet's lengths, which also flattened the rig's standing foot wherever the source's
stood; on stances that shift their weight (punches, martial arts) that moved the feet the
pelvis path and the holds balance, and the sliding bar lost as many clips as it gained.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from app.motion.ground import FOOT_POINTS
from app.motion.retarget_feet import BLEND, FeetInputs, Pose
from app.motion.retarget_reference import swing
from app.motion.skeleton_map import CANONICAL_INDEX

_TINY = 1e-9


def contact_weights(on_floor: np.ndarray, blend_frames: int) -> np.ndarray:
    """``(F,)`` 1 at frames marked ``on_floor`` ``(F,)``, fading to 0 (smoothstep) over
    ``blend_frames`` frames before and after each run of them."""
    frames = len(on_floor)
    index = np.arange(frames)
    marked = np.flatnonzero(on_floor)
    if not len(marked):
        return np.zeros(frames)
    # Distance to the nearest marked frame, in frames.
    position = np.searchsorted(marked, index)
    before = np.abs(index - marked[np.maximum(position - 1, 0)])
    after = np.abs(marked[np.minimum(position, len(marked) - 1)] - index)
    distance = np.minimum(before, after)
    x = np.clip(1.0 - distance / (blend_frames + 1), 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _contact_starts(on_floor: np.ndarray) -> np.ndarray:
    """``(F,)`` per frame the first frame of the run of ``on_floor`` ``(F,)`` frames nearest
    to it (its own run's, or the nearer of the runs around a frame off the floor)."""
    frames = len(on_floor)
    index = np.arange(frames)
    marked = np.flatnonzero(on_floor)
    if not len(marked):
        return index
    first = np.flatnonzero(on_floor & ~np.concatenate([[False], on_floor[:-1]]))
    run_start = first[np.searchsorted(first, marked, side="right") - 1]  # per marked frame
    position = np.searchsorted(marked, index)
    before = np.maximum(position - 1, 0)
    after = np.minimum(position, len(marked) - 1)
    nearer = np.where(
        np.abs(index - marked[before]) <= np.abs(marked[after] - index), before, after
    )
    return run_start[nearer]


def fit_planted_roll(
    kinematics: Callable[[Sequence[int]], Pose], passes: FeetInputs, reference: Pose
) -> bool:
    """Pitch each foot about its ankle (``local`` ``(F, J, 3, 3)`` changed in place) while
    the source's toe is on the floor, so that from the start of each contact the ankle
    moves over the toe, along the floor, as the source's does (the module docstring).

    ``kinematics`` gives the legs' joints' world rotations ``(F, 3, 3)`` and positions
    ``(F, 3)`` for the current ``local``; ``passes`` the feet passes' shared inputs
    (:class:`~app.motion.retarget_feet.FeetInputs`); ``reference`` the legs' joints' world
    rotations ``(3, 3)`` and positions ``(3,)`` in the rig's reference pose (a standing
    figure). Returns whether anything changed.

    The ankle's distance behind the toe is signed, along the foot's heading: the direction
    across the foot (the hips' axis in the reference pose, carried by the ankle's rotation)
    turned a quarter about the up axis. A foot rolled past vertical at toe-off (the source's
    toe behind its ankle) then keeps its sign; measured from the foot's own horizontal
    direction the heading flipped there, and the rig's ankle jumped by twice the feet's
    difference in length in one frame."""
    mapping, parents, local, frame_time, source_feet, up, near = passes
    heights = source_feet @ up  # (F, P)
    floor = float(heights.min())
    blend_frames = max(1, round(BLEND / frame_time))
    ref_rot, ref_pos = reference
    hips = [int(mapping.joints[CANONICAL_INDEX[f"{side}_hip"]]) for side in ("l", "r")]
    across = ref_pos[hips[0]] - ref_pos[hips[1]]
    across = across - (across @ up) * up
    changed = False
    for side in ("l", "r"):
        ankle = int(mapping.joints[CANONICAL_INDEX[f"{side}_ankle"]])
        toe = int(mapping.joints[CANONICAL_INDEX[f"{side}_toe"]])
        if ankle == toe or ankle <= 0 or np.linalg.norm(across) < _TINY:
            continue
        a_index = FOOT_POINTS.index(CANONICAL_INDEX[f"{side}_ankle"])
        t_index = FOOT_POINTS.index(CANONICAL_INDEX[f"{side}_toe"])
        on_floor = heights[:, t_index] - floor < near
        weight = contact_weights(on_floor, blend_frames)
        moving = np.flatnonzero(weight > 0.0)
        if not len(moving):
            continue
        rot, pos = kinematics([ankle, toe, int(parents[ankle])])
        foot = (pos[toe] - pos[ankle])[moving]  # (M, 3)
        source_foot = (source_feet[:, t_index] - source_feet[:, a_index])[moving]
        length = np.linalg.norm(foot, axis=1)
        longer = float(np.median(length)) - float(np.median(np.linalg.norm(source_foot, axis=1)))
        if longer <= 0.0:  # the rig's toe rolls as the source's does, or less
            continue
        # The foot's heading: across the foot (fixed to the ankle) turned about the up axis.
        forward = np.cross(up, across)
        sign = 1.0 if forward @ (ref_pos[toe] - ref_pos[ankle]) >= 0.0 else -1.0
        lateral = rot[ankle][moving] @ (ref_rot[ankle].T @ across)  # (M, 3)
        heading = sign * np.cross(up, lateral)
        heading = heading - (heading @ up)[:, None] * up
        heading_length = np.linalg.norm(heading, axis=1)
        ok = heading_length > _TINY * np.maximum(length, _TINY)
        heading = heading / np.maximum(heading_length, _TINY)[:, None]
        behind = np.sum(foot * heading, axis=1)  # signed, along the heading
        source_behind = np.sum(source_foot * heading, axis=1)
        # Each contact starts from the rig's own foot; from there its ankle moves over the
        # toe as the source's does.
        start = _contact_starts(on_floor)[moving]
        at_start = np.searchsorted(moving, start)
        wanted_behind = source_behind + (behind - source_behind)[at_start]
        side_part = foot - (foot @ up)[:, None] * up - behind[:, None] * heading
        span = np.sqrt(np.maximum(length**2 - np.sum(side_part**2, axis=1), 0.0))
        share = weight[moving]  # blended in over the fade
        reach = np.clip(share * wanted_behind + (1.0 - share) * behind, -span, span)
        ok &= np.abs(reach - behind) > _TINY * np.maximum(length, _TINY)
        if not ok.any():
            continue
        drop = np.sqrt(np.maximum(span**2 - reach**2, 0.0))
        drop = np.where(foot @ up < 0.0, -drop, drop)  # the toe stays below (or above) the ankle
        wanted = reach[:, None] * heading + drop[:, None] * up + side_part
        turn = swing(foot[ok], wanted[ok])  # about the axis across the foot
        at = moving[ok]
        above = rot[int(parents[ankle])][at]
        local[at, ankle] = np.swapaxes(above, -1, -2) @ turn @ above @ local[at, ankle]
        changed = True
    return changed


__all__ = ["contact_weights", "fit_planted_roll"]
