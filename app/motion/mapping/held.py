"""Limb ends that IK holds without hanging from them (a game rig's foot bone under the
root, kept at the end of the shin): found in the frames, and hung from their limb."""

from __future__ import annotations

import numpy as np

from app.motion.mapping.tree import _Tree
from app.motion.model import Skeleton

# A joint whose distance from a limb's last joint stays within this fraction of itself over
# the frames (IK reaching its target: Quaternius robots stay within 5e-4)...
_HELD_SPREAD = 0.01
# ...while its distance from the limb's joint above changes by at least this fraction (the
# limb bends: a still or rigid clip shows nothing), ten times what the held one does.
_HELD_MOVES = 0.01
_HELD_CONTRAST = 10.0


def _held_ends(tree: _Tree, poses: list[np.ndarray]) -> dict[int, int]:
    """Joints that hang from a limb's line above it (the root, the pelvis) but move with the
    limb's last joint as if they hung from it: joint -> that last joint. Read from ``poses``
    (``(J, 3)`` frames); a still clip shows none."""
    if len(poses) < 3:
        return {}
    at = np.stack(poses)
    found: dict[int, tuple[float, int]] = {}
    for leaf in tree.limb_leaves:
        line = set(tree.chain(0, leaf))
        above = int(tree.parents[leaf])
        for joint in range(1, len(tree.names)):
            if joint in line or tree.void[joint] or int(tree.parents[joint]) not in line:
                continue
            gap = np.linalg.norm(at[:, joint] - at[:, leaf], axis=1)
            mean = float(gap.mean())
            if not mean > 0 or float(np.ptp(gap)) > _HELD_SPREAD * mean:
                continue
            spread = float(np.ptp(gap)) / mean
            reach = np.linalg.norm(at[:, joint] - at[:, above], axis=1)
            bend = float(np.ptp(reach)) / max(float(reach.mean()), 1e-300)
            if bend < max(_HELD_MOVES, _HELD_CONTRAST * spread):
                continue
            if joint not in found or spread < found[joint][0]:
                found[joint] = (spread, leaf)
    return {joint: leaf for joint, (_, leaf) in found.items()}


def _rehung(
    skeleton: Skeleton, rest: np.ndarray, held: dict[int, int]
) -> tuple[np.ndarray, Skeleton] | None:
    """``skeleton`` with each held joint hung from its limb's last joint, its joints in a new
    order (parents first), and ``order``: the original index of each new joint (None when
    the held joints would hang from one another in a loop)."""
    parents = skeleton.parents.copy()
    for joint, leaf in held.items():
        parents[joint] = leaf
    children: list[list[int]] = [[] for _ in range(skeleton.joint_count)]
    for j in range(1, skeleton.joint_count):
        children[int(parents[j])].append(j)
    order_list: list[int] = []
    stack = [0]
    while stack:
        j = stack.pop()
        order_list.append(j)
        stack.extend(reversed(children[j]))
    if len(order_list) != skeleton.joint_count:
        return None
    order = np.array(order_list, dtype=np.int64)
    position = np.empty_like(order)
    position[order] = np.arange(len(order))
    new_parents = np.array([-1] + [int(position[parents[j]]) for j in order[1:]])
    offsets = rest[order] - rest[order[np.maximum(new_parents, 0)]]
    offsets[0] = 0.0
    names = tuple(skeleton.names[j] for j in order)
    return order, Skeleton(names, new_parents, offsets, skeleton.end_site[order])
