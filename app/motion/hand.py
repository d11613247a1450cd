"""Where a skeleton's hand turns: the palm joint below the wrist.

Rigs split the hand over one to three joints (``Hand``; ``lwrist`` -> ``lhand`` ->
``lfingers``; ``LeftHand`` -> ``LeftFingerBase`` -> ``LeftHandIndex1``). :func:`palm` finds
the one that carries the whole hand's orientation, from the structure and the rest geometry
alone. Both the canonical body (:func:`app.motion.body.build_body`, whose hand tip takes the
palm's frame) and the retarget (:mod:`app.motion.retarget_joints`, which drives the palm) read
the hand there, so what one measures is what the other moves.
"""

from __future__ import annotations

import numpy as np

from app.motion.model import Skeleton
from app.motion.skeleton_map import COINCIDENT


def between(parents: np.ndarray, top: int, bottom: int) -> list[int]:
    """Joints strictly between ``bottom`` and its ancestor ``top``, bottom first.

    ``parents`` is the skeleton's ``(J,)`` parent indices (-1 at a root); ``[]`` when ``top``
    is not an ancestor of ``bottom`` or nothing lies between them."""
    out, j = [], int(parents[bottom])
    while j != top and j >= 0:
        out.append(j)
        j = int(parents[j])
    return out if j == top else []


def palm(skeleton: Skeleton, wrist: int, tip: int) -> int:
    """The joint that carries the hand's orientation: on the path from ``wrist`` to the hand
    tip, the first joint where the hand branches (into fingers), else the joint the tip hangs
    from (the wrist itself when there is nothing between).

    Where it branches into exactly two joints starting at one place, a hand and a thumb
    (CMU's ``rwrist`` -> ``rhand``, ``rthumb``; MotionBuilder's ``RightHand`` ->
    ``RightFingerBase``, ``RThumb``), the branching joint only twists the forearm's end and
    the hand turns at the child on the path: its frame, not the branching joint's, bends the
    palm (a palm bone per finger, three or more at one place, leaves the branching joint)."""
    if tip == wrist:
        return wrist
    path = [wrist, *between(skeleton.parents, wrist, tip)[::-1], tip]
    for step, joint in enumerate(path[:-1]):
        children = skeleton.children(joint)
        if len(children) > 1:
            if len(children) == 2 and _one_place(skeleton, joint, children):
                return path[step + 1]
            return joint
    return path[-2]


def _one_place(skeleton: Skeleton, joint: int, children: list[int]) -> bool:
    """The children start at one place in the rest pose (offsets from ``joint`` within
    :data:`COINCIDENT` of the bone into ``joint``, or all at the joint itself)."""
    starts = skeleton.offsets[children]
    scale = float(np.linalg.norm(skeleton.offsets[joint]))
    spread = float(np.linalg.norm(np.ptp(starts, axis=0)))
    return spread <= COINCIDENT * max(scale, float(np.linalg.norm(starts, axis=1).max()))
