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
    palm (a palm bone per finger, three or more at one place, leaves the branching joint).
    Only branches of the hand count (:func:`_hand_branches`): small bones hung at a joint do
    not make it branch, so a rig with extra helper or accessory bones has the same palm."""
    if tip == wrist:
        return wrist
    path = [wrist, *between(skeleton.parents, wrist, tip)[::-1], tip]
    rest = _rest_positions(skeleton)
    for step, joint in enumerate(path[:-1]):
        children = _hand_branches(skeleton, rest, joint, path[step + 1], tip)
        if len(children) > 1:
            if len(children) == 2 and _one_place(skeleton, joint, children):
                return path[step + 1]
            return joint
    return path[-2]


# A branch of the hand (a finger, the thumb) reaches from its joint at least this share of the
# way the hand tip does: fingers and the thumb span most of the hand, where the small bones
# rigs also hang there (twist and helper bones, markers, accessories, a Blender finger's end
# bone) stay near their joint.
_BRANCH_REACH = 0.5


def _hand_branches(
    skeleton: Skeleton, rest: np.ndarray, joint: int, on_path: int, tip: int
) -> list[int]:
    """The children of ``joint`` that are branches of the hand: the one on the path to the
    hand tip, and those whose bones reach from ``joint`` at least :data:`_BRANCH_REACH` of
    the tip's distance in the rest pose ``rest`` (``(J, 3)``)."""
    span = float(np.linalg.norm(rest[tip] - rest[joint]))
    branches = []
    for child in skeleton.children(joint):
        if child == on_path:
            branches.append(child)
            continue
        below = [child, *_descendants(skeleton, child)]
        reach = float(np.linalg.norm(rest[below] - rest[joint], axis=1).max())
        if reach >= _BRANCH_REACH * span:
            branches.append(child)
    return branches


def _descendants(skeleton: Skeleton, joint: int) -> list[int]:
    out, stack = [], list(skeleton.children(joint))
    while stack:
        j = stack.pop()
        out.append(j)
        stack.extend(skeleton.children(j))
    return out


def _rest_positions(skeleton: Skeleton) -> np.ndarray:
    """``(J, 3)`` joint positions of the rest pose (offsets summed down the tree)."""
    rest = np.zeros((skeleton.joint_count, 3))
    for j in range(skeleton.joint_count):
        parent = int(skeleton.parents[j])
        rest[j] = skeleton.offsets[j] + (rest[parent] if parent >= 0 else 0.0)
    return rest


def _one_place(skeleton: Skeleton, joint: int, children: list[int]) -> bool:
    """The children start at one place in the rest pose (offsets from ``joint`` within
    :data:`COINCIDENT` of the bone into ``joint``, or all at the joint itself)."""
    starts = skeleton.offsets[children]
    scale = float(np.linalg.norm(skeleton.offsets[joint]))
    spread = float(np.linalg.norm(np.ptp(starts, axis=0)))
    return spread <= COINCIDENT * max(scale, float(np.linalg.norm(starts, axis=1).max()))
