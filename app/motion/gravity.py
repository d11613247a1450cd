"""Which way is up when the take does not stand: the floor the body rests on (issue 20).

Mocap files are authored with a coordinate axis up, and the describer takes it as the signed
axis nearest the body's mean up over the take (:func:`app.motion.body.build_body`'s
``world_up``). That reads a take that mostly stands. A take that mostly lies along the floor
(a crawl, a fall and what follows it, a breakdance flair spinning on the hands) has its mean
body up along a horizontal axis, and the take was stored on its side: its travel read as
vertical speed, its preview lying down.

Gravity tells the two apart. A body rests on a floor, so along the true up its lowest point
keeps one height from frame to frame (a foot, a knee, a hand, the back: whatever touches the
floor); along a horizontal axis the lowest point is the body's rearmost or leftmost part,
which moves as the body turns, bends and travels. Where a standing rest pose (the head above
the pelvis above the ankles) names another axis than the take's mean up, or the body itself
stands up along another axis for a part of the take (the start of a fall, the end of a
get-up: a writer's rest pose may lie or be no figure at all), the axis the body rests on (its
lowest point on the floor in most frames, and moving clearly less) is the vertical. A take
that stands, walks or jumps keeps its own axis (it rests on its floor along it, whatever a
rest pose says: writers that turn a Y-up rest into a Z-up world at the root), and so does a
take with no floor to read (one frame, a still pose, a flight).

Shapes: canonical positions ``(F, C, 3)`` as :data:`~app.motion.skeleton_map.CANONICAL_JOINTS`.
"""

from __future__ import annotations

import numpy as np

from app.motion.model import Skeleton
from app.motion.skeleton_map import CANONICAL_INDEX, SkeletonMap, rest_pose

# Body heights: the lowest point of a frame this near the take's lowest is on the floor (a
# foot flat on it reaches the ankle at ~0.04).
ON_FLOOR = 0.05
# A body rests on its floor in most frames: the take's axis is left when its lowest point is
# on its floor in fewer than this share of the frames and the rest pose's is in at least it.
RESTS = 0.5
# ... and the lowest point along the rest pose's axis moves at most this share of what it
# moves along the take's.
STEADIER = 0.5
# The body stands along an axis in a frame where its pelvis -> neck is within 30 degrees of
# it, and stands along it for a part of the take in at least this share of the frames (a fall
# starts standing, a get-up ends so); the floor then decides, as for a rest pose's axis.
STANDS_WITHIN = float(np.cos(np.radians(30.0)))
STANDS = 0.1
# ... but more than this (body heights): a coordinate held exactly in every frame is a
# writer's frozen value (a pose estimator's depth), not a floor, which a contact's roll moves.
HELD = 1e-3


def floor_spread(positions: np.ndarray, up: np.ndarray, height: float) -> tuple[float, float]:
    """Along ``up`` ``(3,)``, how much the body's lowest point moves over the ``(F, C, 3)``
    frames (its standard deviation, in body heights) and the share of the frames in which it
    is on the floor (within :data:`ON_FLOOR` of the take's lowest)."""
    lowest = (positions @ up).min(axis=1)
    on_floor = float(np.mean(lowest - lowest.min() <= ON_FLOOR * height))
    return float(np.std(lowest)) / height, on_floor


def rest_up(skeleton: Skeleton, joints: np.ndarray) -> np.ndarray | None:
    """``(3,)`` the signed coordinate axis nearest the ankles -> head of the rest pose (the
    skeleton's offsets), or None where the rest pose is no standing figure along it (the head
    above the pelvis above the ankles). ``joints``: the mapping's canonical joints ``(C,)``."""
    rest = rest_pose(skeleton)
    head, pelvis = (rest[int(joints[CANONICAL_INDEX[name]])] for name in ("head", "pelvis"))
    ankles = np.mean([rest[int(joints[CANONICAL_INDEX[f"{s}_ankle"]])] for s in "lr"], axis=0)
    direction = head - ankles
    if not np.any(np.abs(direction) > 1e-12):
        return None
    axis = int(np.argmax(np.abs(direction)))
    up = np.zeros(3)
    up[axis] = np.sign(direction[axis])
    if not (head - pelvis) @ up > 0 < (pelvis - ankles) @ up:
        return None
    return up


def standing_axes(body_ups: np.ndarray, take_up: np.ndarray) -> list[np.ndarray]:
    """The signed coordinate axes across ``take_up`` ``(3,)`` along which the body stands in
    at least :data:`STANDS` of the frames; ``body_ups`` ``(F, 3)``: the pelvis -> neck unit
    direction of each frame."""
    return [
        axis
        for axis in np.concatenate([np.eye(3), -np.eye(3)])
        if abs(float(axis @ take_up)) < 0.5 and np.mean(body_ups @ axis >= STANDS_WITHIN) >= STANDS
    ]


def resting_up(
    take_up: np.ndarray,
    standing_up: np.ndarray | None,
    positions: np.ndarray,
    height: float,
    body_ups: np.ndarray,
) -> np.ndarray:
    """The world's vertical: ``take_up`` (the axis of the take's mean body up), or another
    axis the body rests on a floor along, and not along ``take_up``: the standing rest
    pose's axis ``standing_up``, or one along which the body stands in a part of the take
    (``body_ups`` ``(F, 3)``, see :func:`standing_axes`); see the module docstring. Never the
    opposite of ``take_up``: a body upside down in a whole take is read as its frames show
    it."""
    if len(positions) < 2:
        return take_up
    candidates = standing_axes(body_ups, take_up)
    if (
        standing_up is not None
        and abs(float(standing_up @ take_up)) < 0.5
        and not any(np.array_equal(standing_up, axis) for axis in candidates)
    ):
        candidates.insert(0, standing_up)
    if not candidates:
        return take_up
    take_spread, take_rests = floor_spread(positions, take_up, height)
    best, best_spread = take_up, np.inf
    for axis in candidates:
        spread, rests = floor_spread(positions, axis, height)
        steadier = HELD < spread <= STEADIER * take_spread and spread < best_spread
        if steadier and rests >= RESTS > take_rests:
            best, best_spread = axis, spread
    return best


def clip_vertical(
    take_up: np.ndarray,
    skeleton: Skeleton,
    mapping: SkeletonMap,
    positions: np.ndarray,
    height: float,
    body_ups: np.ndarray,
) -> np.ndarray:
    """:func:`resting_up` of a mapped clip, the rest pose's axis read where the mapping comes
    from the rest pose: the one reading of the describer (app/motion/body.py) and of the
    retarget and exports (app/motion/retarget.py ``world_up``), which must agree."""
    standing = rest_up(skeleton, mapping.joints) if mapping.pose == "rest pose" else None
    return resting_up(take_up, standing, positions, height, body_ups)


__all__ = [
    "HELD",
    "ON_FLOOR",
    "RESTS",
    "STANDS",
    "STEADIER",
    "clip_vertical",
    "floor_spread",
    "rest_up",
    "resting_up",
    "standing_axes",
]
