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
the pelvis above the ankles) names another axis than the take's mean up, the one whose
lowest point keeps its height clearly better is the vertical. A take that stands, walks or
jumps keeps its own axis (its floor is steadier along it, whatever a rest pose says: writers
that turn a Y-up rest into a Z-up world at the root), and so does a take with no floor to
read (one frame, a still pose, a flight: both floors steady, or both moving).

Shapes: canonical positions ``(F, C, 3)`` as :data:`~app.motion.skeleton_map.CANONICAL_JOINTS`.
"""

from __future__ import annotations

import numpy as np

from app.motion.model import Skeleton
from app.motion.skeleton_map import CANONICAL_INDEX, rest_pose

# The rest pose's axis wins only when its floor moves at most this share of the take's: the
# takes read on their side move their floor 6-30 times as much along the take's axis, a
# take that stands moves it 5 times as much along the rest's, or more.
STEADIER = 0.5
# ... and the take's floor moves more than this (body heights; a walk's lowest point rises
# and falls with the toes by ~0.015): a floor that barely moves along either axis is no
# reading (a still pose, a turn on the spot).
MOVING_FLOOR = 0.02


def floor_spread(positions: np.ndarray, up: np.ndarray, height: float) -> float:
    """How much the body's lowest point along ``up`` ``(3,)`` moves over the ``(F, C, 3)``
    frames: its standard deviation, in body heights."""
    return float(np.std((positions @ up).min(axis=1))) / height


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


def resting_up(
    take_up: np.ndarray, standing_up: np.ndarray | None, positions: np.ndarray, height: float
) -> np.ndarray:
    """The world's vertical: ``take_up`` (the axis of the take's mean body up), or the
    standing rest pose's axis ``standing_up`` where the body's lowest point keeps its height
    clearly better along it (see the module docstring)."""
    if standing_up is None or np.array_equal(standing_up, take_up) or len(positions) < 2:
        return take_up
    along_take = floor_spread(positions, take_up, height)
    if along_take > MOVING_FLOOR and floor_spread(positions, standing_up, height) <= (
        STEADIER * along_take
    ):
        return standing_up
    return take_up


__all__ = ["MOVING_FLOOR", "STEADIER", "floor_spread", "rest_up", "resting_up"]
