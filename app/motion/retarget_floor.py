"""The retarget's pelvis path and feet: on the source's floor, planted where it stands.

The pelvis travels as the source's pelvis, scaled about the world origin by the ratio of the
legs' bone paths, then moved up or down per frame so the target's foot points that are on
the floor in the source (the standing foot) are where the source's are, and nothing is
below the source's lowest point. A planted foot longer for its legs than the source's first
rolls over its toe as the source's does (:mod:`app.motion.retarget_stride`). A swinging
foot whose toe would skim the floor is pitched up about its ankle
(:func:`clear_swinging_toes`); the path's horizontal part is corrected so a planted foot
moves over the floor as the source's does, and goes back toward the scaled source's where
no foot is on the floor (:func:`planted_feet_offsets`); what that cannot hold the legs take
up (:mod:`app.motion.retarget_feet`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from app.motion.body import body_height
from app.motion.ground import FOOT_POINTS, ON_FLOOR
from app.motion.kinematics import forward_kinematics
from app.motion.lead_in import count_lead_in_frames
from app.motion.model import Motion
from app.motion.retarget_feet import FeetInputs, Pose, hold_planted_feet, planted_steps
from app.motion.retarget_joints import between
from app.motion.retarget_reference import leg_length, swing
from app.motion.retarget_stride import fit_planted_roll
from app.motion.skeleton_map import CANONICAL_INDEX, CANONICAL_JOINTS, SkeletonMap

_TINY = 1e-9


def place_pelvis(
    source: Motion,
    source_map: SkeletonMap,
    target: Motion,
    target_map: SkeletonMap,
    s_canon: np.ndarray,
    world: np.ndarray,
    t_up: np.ndarray,
    local: np.ndarray,
    pelvis_rot: np.ndarray,
    assemble: Callable[[np.ndarray], Motion],
    *,
    hold_feet: bool,
) -> np.ndarray:
    """``(F, 3)`` the target pelvis's world position per frame (see the module docstring).

    ``s_canon`` ``(F, C, 3)`` are the source's canonical joints' positions, ``world``
    ``(3, 3)`` the target's world axes onto the source's, ``t_up`` ``(3,)`` the target's up;
    ``local`` ``(F, J, 3, 3)`` the target's local rotations (the feet's passes change the
    legs' in place), ``pelvis_rot`` ``(F, 3, 3)`` the target pelvis's world rotations;
    ``assemble`` builds the output motion for a pelvis path (the kinematics of a rig whose
    legs do not hang below the pelvis); ``hold_feet`` whether the legs hold planted feet."""
    frames = local.shape[0]
    parents = target.skeleton.parents
    pelvis = int(target_map.joints[CANONICAL_INDEX["pelvis"]])
    # The pelvis's path: the source's, scaled by the legs.
    scale = leg_length(target, target_map) / max(leg_length(source, source_map), _TINY)
    s_pelvis = s_canon[:, CANONICAL_INDEX["pelvis"]]
    pelvis_at = scale * s_pelvis @ world  # (F, 3)
    feet = target_map.joints[list(FOOT_POINTS)]
    feet_s = scale * s_canon[:, list(FOOT_POINTS)] @ world
    near = ON_FLOOR * body_height(target, target_map.joints, head_joint=target_map.head_joint)

    # The legs' joints the feet's passes read (hips, ankles, toes and the hips' and ankles'
    # parents): their kinematics, with the pelvis at the origin, computed once, and again
    # only after a pass changes a leg's rotations.
    leg_joints = sorted(
        {
            int(j)
            for side in ("l", "r")
            for name in ("hip", "ankle", "toe")
            for j in (
                target_map.joints[CANONICAL_INDEX[f"{side}_{name}"]],
                parents[target_map.joints[CANONICAL_INDEX[f"{side}_{name}"]]],
            )
            if j >= 0
        }
    )
    origin = np.zeros((frames, 3))
    posed: list[Pose] = []

    def refresh() -> None:
        try:
            pose = below(
                parents, target.skeleton.offsets, local, pelvis, pelvis_rot, origin, leg_joints
            )
        except ValueError:  # a leg joint not below the pelvis: the whole rig's kinematics
            rot, pos = forward_kinematics(assemble(origin), joints=leg_joints)
            pose = ({j: rot[:, j] for j in leg_joints}, {j: pos[:, j] for j in leg_joints})
        posed[:] = [pose]

    def legs(joints: Sequence[int], at: np.ndarray) -> Pose:
        """World rotations and positions of the target's ``joints`` (legs' joints) for the
        current ``local`` rotations, with the pelvis at ``at`` ``(F, 3)``."""
        rotations, positions = posed[0]
        return rotations, {int(j): positions[int(j)] + at for j in joints}

    refresh()
    # A foot longer for its legs than the source's rolls over its toe as the source's does,
    # so a walk's stride is the source's scaled (app.motion.retarget_stride).
    passes = FeetInputs(target_map, parents, local, source.frame_time, feet_s, t_up, near)
    if hold_feet and fit_planted_roll(
        lambda joints: legs(joints, origin), passes, _reference_legs(target, leg_joints)
    ):
        refresh()

    def foot_points(at: np.ndarray) -> np.ndarray:
        """``(F, P, 3)`` the foot points with the pelvis at ``at``."""
        positions = legs([int(j) for j in feet], at)[1]
        return np.stack([positions[int(j)] for j in feet], axis=1)

    def onto(points: np.ndarray, stance: np.ndarray) -> np.ndarray:
        """``(F,)`` how far to move the pelvis up so that the lowest of the foot points
        ``points`` ``(F, P, 3)`` marked in ``stance`` ``(F, P)`` is where the source's
        lowest of them is (the pelvis's translation carries every joint below it)."""
        lowest = np.where(stance, points @ t_up, np.inf).min(axis=1)
        return np.where(stance, s_heights, np.inf).min(axis=1) - lowest

    # The standing foot sets the body's height: the target's foot points that are on the
    # floor in the source (within ``near`` of its floor) are put where the source's are, so
    # a swinging foot lower on the rig (a longer shin, a long foot's toe tip) does not lift
    # the standing one off the floor; the swinging toe is then raised (below). At frames
    # with no point on the floor (a jump) the lowest points match.
    s_heights = feet_s @ t_up  # (F, P)
    stance = s_heights - s_heights.min() < near
    stance[~stance.any(axis=1)] = True
    feet_t = foot_points(pelvis_at)
    lift = onto(feet_t, stance)
    pelvis_at = pelvis_at + lift[:, None] * t_up
    feet_t = feet_t + lift[:, None, None] * t_up
    # A swinging foot clears the floor as the source's does (a long foot points its toe lower).
    if clear_swinging_toes(lambda joints: legs(joints, pelvis_at), passes):
        refresh()
        feet_t = foot_points(pelvis_at)
    # Then the lowest point is the source's lowest (feet neither sinking nor floating): this
    # moves only frames where a swinging foot could not clear the floor, or a jump's.
    lift = onto(feet_t, np.ones_like(stance))
    pelvis_at = pelvis_at + lift[:, None] * t_up
    feet_t = feet_t + lift[:, None, None] * t_up
    # Held over the floor: only the foot points the rig has (a rig with no toe stands on
    # its ankles, which move as the source's ankles do).
    points = rig_foot_points(target_map)
    pelvis_at = pelvis_at + planted_feet_offsets(
        feet_t[:, points], feet_s[:, points], t_up, near, lead_in=count_lead_in_frames(source)
    )
    if hold_feet:
        held = hold_planted_feet(lambda joints: legs(joints, pelvis_at), passes, near / ON_FLOOR)
        if held is not None:
            # A leg turned about its hip raises or lowers its foot a little: the standing
            # foot goes back onto the floor, and nothing sinks below the source's lowest.
            lift = onto(held, stance)
            lift = lift + onto(held + lift[:, None, None] * t_up, np.ones_like(stance))
            pelvis_at = pelvis_at + lift[:, None] * t_up
    return pelvis_at


def rig_foot_points(mapping: SkeletonMap) -> list[int]:
    """Indices into :data:`~app.motion.ground.FOOT_POINTS` of the foot points the skeleton
    mapped as ``mapping`` has: both ankles, and each toe unless it is the ankle itself.

    A rig with no toe joint (a video pose's 17 joints end each leg at the ankle) has its
    canonical toe on the ankle. Held against the source's toe, that ankle was kept still
    while the source's heel rose and its ankle rolled forward over the toe, every step:
    the body lost the roll's travel (an in-place-looking walk, the pelvis up to 3 leg
    lengths per second off the source's) and the ankle, measured as the rig's "toe", slid
    on the way back. The rig's ankle is held as the source's ankle instead."""
    out = []
    for index, canonical in enumerate(FOOT_POINTS):
        name = CANONICAL_JOINTS[canonical]
        if name.endswith("_toe"):
            ankle = CANONICAL_INDEX[name.replace("_toe", "_ankle")]
            if mapping.joints[canonical] == mapping.joints[ankle]:
                continue
        out.append(index)
    return out


def _reference_legs(target: Motion, joints: Sequence[int]) -> Pose:
    """World rotations ``(3, 3)`` and positions ``(3,)`` of the rig's ``joints`` in its
    reference pose (frame 0 of ``target``)."""
    rot, pos = forward_kinematics(target.slice_frames(0, 1), joints=list(joints))
    return {int(j): rot[0, j] for j in joints}, {int(j): pos[0, j] for j in joints}


def clear_swinging_toes(kinematics: Callable[[Sequence[int]], Pose], passes: FeetInputs) -> bool:
    """Pitch each foot up about its ankle (``local`` ``(F, J, 3, 3)`` changed in place)
    at frames where the source's toe is off the floor (``near`` or more above the lowest any
    source foot point gets) but the target's toe is not: on a foot longer for its leg than
    the source's (a toe tip against a ball of the foot), the same foot direction puts the
    toe of a swinging foot on the floor, where it skims. The toe is raised until it is off
    the floor too (``near`` above it, or the source toe's height if that is lower; as near
    as the foot reaches); the foot keeps its heading. ``kinematics`` gives the legs' joints'
    world rotations and positions for the current ``local``; ``passes`` the feet passes' shared
    inputs (:class:`~app.motion.retarget_feet.FeetInputs`). Returns whether anything changed.

    Until 2026-11-27 the toe was raised to the source toe's height: the source's clearance,
    which on a foot long for its leg took a 30-50 degree pitch coming in within one frame at
    every toe-off (the rig's foot then points nearly straight down). ``kinetic``'s ankle
    terms, the energy a re-upload is described by, doubled: walks and runs retargeted onto
    the Mixamo and Xsens rigs were 0.6-1.0 from their source, about two thirds of it the
    ankles (docs/export.md, "The round trip's misses")."""
    mapping, parents, local, _, source_feet, up, near = passes
    source_floor = float((source_feet @ up).min())
    changed = False
    for side in ("l", "r"):
        ankle = int(mapping.joints[CANONICAL_INDEX[f"{side}_ankle"]])
        toe = int(mapping.joints[CANONICAL_INDEX[f"{side}_toe"]])
        if ankle == toe or (not between(parents, ankle, toe) and parents[toe] != ankle):
            continue
        rot, pos = kinematics([ankle, toe, int(parents[ankle])])
        source_toe = source_feet[:, FOOT_POINTS.index(CANONICAL_INDEX[f"{side}_toe"])] @ up
        # Off the floor as the contact bands define it, not as high as the source's toe.
        wanted = np.minimum(source_toe, source_floor + near)
        bone = pos[toe] - pos[ankle]  # (F, 3)
        length = np.linalg.norm(bone, axis=1)
        flat = bone - (bone @ up)[:, None] * up
        flat_length = np.linalg.norm(flat, axis=1)
        low = (
            (source_toe - source_floor >= near)
            & (pos[toe] @ up < wanted)
            & (flat_length > 1e-6 * np.maximum(length, _TINY))
        )
        if not low.any():
            continue
        rise = np.clip((wanted[low] - pos[ankle][low] @ up) / length[low], -1.0, 1.0)
        heading = flat[low] / flat_length[low, None]
        raised = length[low, None] * (
            np.sqrt(1.0 - rise**2)[:, None] * heading + rise[:, None] * up
        )
        turn = swing(bone[low], raised)  # about the horizontal axis across the foot
        above = rot[int(parents[ankle])][low]
        local[low, ankle] = np.swapaxes(above, -1, -2) @ turn @ above @ local[low, ankle]
        changed = True
    return changed


def below(
    parents: np.ndarray,
    offsets: np.ndarray,
    local: np.ndarray,
    top: int,
    top_rotation: np.ndarray,
    top_position: np.ndarray,
    joints: Sequence[int],
) -> Pose:
    """Forward kinematics of the joints between ``top`` and ``joints`` (all below it), from
    ``top``'s world rotation ``(F, 3, 3)`` and position ``(F, 3)``: world rotations
    ``(F, 3, 3)`` and positions ``(F, 3)`` by joint. Only these few joints are computed
    (a leg's, against a rig of 70 joints with fingers)."""
    needed: set[int] = set()
    for start in joints:
        j = int(start)
        while j != top and j not in needed:
            if j < 0:
                raise ValueError(f"joint {start} is not below joint {top}")
            needed.add(j)
            j = int(parents[j])
    rotations, positions = {top: top_rotation}, {top: top_position}
    for j in sorted(needed):  # parents before children
        parent = int(parents[j])
        rotations[j] = rotations[parent] @ local[:, j]
        positions[j] = positions[parent] + rotations[parent] @ offsets[j]
    return rotations, positions


def planted_feet_offsets(
    feet: np.ndarray, source_feet: np.ndarray, up: np.ndarray, near: float, *, lead_in: int = 0
) -> np.ndarray:
    """``(F, 3)`` horizontal offsets to add to the pelvis's path so that the foot points
    ``feet`` ``(F, P, 3)`` move over the floor as ``source_feet`` ``(F, P, 3)`` (the source's,
    scaled, in the same axes) do while the source's are on it: within ``near`` of the lowest
    any of them gets, at both ends of a frame step (:func:`planted_steps`). A step with
    planted foot points moves the path back by the mean of their extra horizontal movement;
    a step with none (in the air) gives back what the steps on the floor gathered
    (:func:`_given_back`) — in the air also by the floor of the frames after the first
    ``lead_in`` (a converter's rest-pose frames, :func:`~app.motion.lead_in.count_lead_in_frames`,
    whose feet can sit below every later contact and make the contact bands call a standing
    foot's steps in the air; measured on CMU MotionBuilder takes); the lead-in's own
    corrections stay as they are. Contact is the source's
    alone, as for the legs' hold: until 2026-11-27 a point also had to be near the target's
    own floor, and a rig whose ankle or toe joint sits higher in its foot than the source's
    left out steps where the source's foot stood, so its foot slid there (docs/export.md
    "Rigs we have not seen")."""
    planted = planted_steps(source_feet, up, near)  # (F - 1, P)
    extra = np.diff(feet, axis=0) - np.diff(source_feet, axis=0)  # (F - 1, P, 3)
    extra = extra - (extra @ up)[..., None] * up
    count = planted.sum(axis=1)
    step = -(extra * planted[..., None]).sum(axis=1) / np.maximum(count, 1)[:, None]
    # The lead-in is not the take: its steps' corrections (a jump out of the rest pose) sum
    # as before and stay, a constant under the rest; the take's own are given back.
    start = min(max(lead_in, 0), len(step))
    offsets = np.zeros((feet.shape[0], 3))
    offsets[1 : start + 1] = np.cumsum(step[:start], axis=0)
    touching = np.any(planted_steps(source_feet[start:], up, near), axis=1)
    offsets[start:] = offsets[start] + _given_back(step[start:], count[start:] > 0, touching)
    return offsets


def _given_back(
    step: np.ndarray, on_floor: np.ndarray, touching: np.ndarray | None = None
) -> np.ndarray:
    """``(F, 3)`` the path's offsets from its per-step corrections ``step`` ``(F - 1, 3)``,
    summed over the steps marked ``on_floor`` ``(F - 1,)``; over the other steps (no foot
    point on the floor) the sum goes back toward zero evenly over the gap, per step by at
    most the largest correction of the last run of steps on the floor — except at steps
    marked ``touching`` ``(F - 1,)`` (by another estimate of the floor a foot is on it),
    where it stays.

    Why: on a rig whose legs and feet are of other proportions, the same limb directions
    move a standing foot over the floor by a little more (or less) than the source's every
    contact — a foot rolling over a longer toe, a longer shin sweeping — and in the swing
    the difference goes back with no correction. Summed over the take that was travel the
    source never had (an in-place run: 0.27 leg lengths per second on the Mixamo rig,
    docs/export.md "In-place travel"), against the contract "travel scaled by the ratio of
    leg lengths". In the air no foot is on the floor, so the pelvis can return there
    without any foot sliding; no faster than the holds already moved it, so a brief gap in a
    long contact does not snap the body back; and evenly, so a step the contact bands call
    in the air but a foot still touches (a take whose first frame, a rest pose, sets the
    floor's height) moves as little as the gap allows."""
    offsets = np.zeros((step.shape[0] + 1, 3))
    if not len(step):  # a single frame: nothing to correct
        return offsets
    current = np.zeros(3)
    rate = 0.0  # the largest correction per step in the last run on the floor
    changes = np.flatnonzero(np.diff(on_floor.astype(np.int8))) + 1
    for start, end in zip(
        np.concatenate([[0], changes]), np.concatenate([changes, [len(step)]]), strict=True
    ):
        if on_floor[start]:
            values = current + np.cumsum(step[start:end], axis=0)
            rate = float(np.linalg.norm(step[start:end], axis=1).max())
        else:  # shrinks toward zero along its direction, evenly over the gap
            size = float(np.linalg.norm(current))
            moving = np.ones(end - start, dtype=bool)
            if touching is not None:
                moving = ~touching[start:end]
            per_step = min(rate, size / max(int(moving.sum()), 1))
            left = np.maximum(size - per_step * np.cumsum(moving), 0.0)
            values = current * (left / max(size, _TINY))[:, None]
        offsets[start + 1 : end + 1] = values
        current = values[-1]
    return offsets


__all__ = [
    "below",
    "clear_swinging_toes",
    "place_pelvis",
    "planted_feet_offsets",
    "rig_foot_points",
]
