"""Index helpers over one skeleton's tree: children, depths, bone path lengths, name hints,
and the leaves far apart along the bones that may be the limb ends."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from app.motion.mapping.canonical import rest_pose
from app.motion.model import Skeleton
from app.motion.skeleton_names import (
    ARM_PARTS,
    LEG_PARTS,
    NameHint,
    name_hint,
    name_side,
    normalise_name,
)

# Bones of non-zero length between the root and a limb's end, at least.
_MIN_LIMB_BONES = 2
# Fractions of the pose's extent (its bounding-box diagonal, about body height).
COINCIDENT = 1e-4  # joints closer than this share a position
# Relative difference under which an End Site's length copies its parent bone's (a tail an
# exporter invented, not a measured point): float32 rounding of the two is under 1e-6.
_TAIL_COPY = 1e-4


class _Tree:
    """Index helpers over one skeleton: children, depths, bone path lengths, name hints."""

    def __init__(self, skeleton: Skeleton) -> None:
        self.skeleton = skeleton
        self.names = skeleton.names
        self.parents = skeleton.parents
        count = skeleton.joint_count
        self.lengths = np.linalg.norm(skeleton.offsets, axis=1)
        self.lengths[0] = 0.0
        # A bone shorter than the mapper's "same place" is no bone: a file that went through
        # another tool (an FBX export's float rounding) keeps a joint that sat on its parent
        # a hair away from it, and must map as the original did.
        extent = float(np.linalg.norm(np.ptp(rest_pose(skeleton), axis=0))) if count else 0.0
        self.lengths[self.lengths <= COINCIDENT * extent] = 0.0
        # An End Site exactly as long as the bone it ends is a tail a writer invented for a
        # leaf *joint* (Blender gives a leaf bone its parent's length and exports that tail
        # as the End Site): the joint is the point, as in the FBX or glTF the rig came from,
        # and a measured End Site (a head top, a fingertip) is never that exact a copy.
        parent_lengths = self.lengths[np.maximum(skeleton.parents, 0)]
        invented = (
            skeleton.end_site
            & (skeleton.parents > 0)
            & (parent_lengths > 0)
            & (np.abs(self.lengths - parent_lengths) <= _TAIL_COPY * parent_lengths)
        )
        self.lengths[invented] = 0.0
        # Leaves that add no point of their own (a zero-length End Site, or a chain of them):
        # a BVH writer appends one to every leaf joint of an FBX or glTF rig, and the same
        # rig must map the same with or without them, so the mapper does not see them.
        self.void = np.zeros(count, dtype=bool)
        has_point = np.zeros(count, dtype=bool)
        for j in range(count - 1, 0, -1):
            if self.lengths[j] > 0 or has_point[j]:
                has_point[int(self.parents[j])] = True
            else:
                self.void[j] = True
        self.children: list[list[int]] = [[] for _ in range(count)]
        for j in range(1, count):
            if not self.void[j]:
                self.children[int(self.parents[j])].append(j)
        self.depth = np.zeros(count, dtype=np.int64)
        self.path = np.zeros(count)  # bone path length from the root
        for j in range(1, count):
            p = int(self.parents[j])
            self.depth[j] = self.depth[p] + 1
            self.path[j] = self.path[p] + self.lengths[j]
        self.leaves = [j for j in range(count) if not self.children[j] and not self.void[j]]
        self.bones = np.zeros(count, dtype=np.int64)  # non-zero bones from the root
        for j in range(1, count):
            self.bones[j] = self.bones[self.parents[j]] + (self.lengths[j] > 0)
        self.limb_leaves = [j for j in self.leaves if self.bones[j] >= _MIN_LIMB_BONES]
        # The body proper, whose bounding box gives the pose's scale: not shallow leaves (IK
        # targets, props on the root), nor a root with a single child (a floor-level
        # "joint_Root" that may stay at the origin while the body runs off).
        shallow = set(self.leaves) - set(self.limb_leaves) | set(np.flatnonzero(self.void))
        if len(self.children[0]) == 1:
            shallow.add(0)
        # (Every joint of a rig too small to have a body proper: a bone or two.)
        body = [j for j in range(count) if j not in shallow] or list(range(count))
        self.body_joints = np.array(body, dtype=np.int64)
        self.reach = np.zeros(count)  # longest bone path from a joint down to a descendant
        for j in range(count - 1, 0, -1):
            p = int(self.parents[j])
            self.reach[p] = max(self.reach[p], self.reach[j] + self.lengths[j])
        self.hints: list[NameHint] = [name_hint(n) for n in skeleton.names]
        self.sides: list[str | None] = [name_side(n) for n in skeleton.names]
        # The hypotheses ask the same few pairs thousands of times.
        self._lca: dict[tuple[int, int], int] = {}
        self._ancestor: dict[tuple[int, int], bool] = {}

    def lca(self, a: int, b: int) -> int:
        key = (a, b)
        found = self._lca.get(key)
        if found is None:
            while a != b:
                if self.depth[a] >= self.depth[b]:
                    a = int(self.parents[a])
                else:
                    b = int(self.parents[b])
            found = self._lca[key] = a
        return found

    def is_ancestor(self, top: int, joint: int) -> bool:
        """``top`` is ``joint`` or one of its ancestors."""
        key = (top, joint)
        found = self._ancestor.get(key)
        if found is None:
            found = False
            while joint >= 0 and self.depth[joint] >= self.depth[top]:
                if joint == top:
                    found = True
                    break
                joint = int(self.parents[joint])
            self._ancestor[key] = found
        return found

    def chain(self, top: int, bottom: int) -> list[int]:
        """Joints from ``top`` down to ``bottom`` inclusive (``top`` is an ancestor)."""
        out = [bottom]
        while out[-1] != top:
            out.append(int(self.parents[out[-1]]))
        return out[::-1]

    def geodesic(self, start: int) -> np.ndarray:
        """``(J,)`` bone path length from ``start`` to every joint."""
        out = np.full(len(self.names), -1.0)
        out[start] = 0.0
        stack = [start]
        while stack:
            j = stack.pop()
            neighbours = list(self.children[j])
            if self.parents[j] >= 0:
                neighbours.append(int(self.parents[j]))
            for n in neighbours:
                if out[n] < 0:
                    step = self.lengths[n] if self.parents[n] == j else self.lengths[j]
                    out[n] = out[j] + step
                    stack.append(n)
        return out

    def descendants(self, joint: int) -> list[int]:
        out, stack = [], [joint]
        while stack:
            j = stack.pop()
            out.append(j)
            stack.extend(self.children[j])
        return out

    def role_words(self, joints: Sequence[int]) -> set[str]:
        """Which of ``arm``/``leg``/``head`` the names along ``joints`` say."""
        words: set[str] = set()
        for j in joints:
            parts = set(self.hints[j].parts)
            if parts & ARM_PARTS:
                words.add("arm")
            if parts & LEG_PARTS:
                words.add("leg")
            if parts & {"head", "neck"}:
                words.add("head")
        return words


def _extremity_candidates(tree: _Tree, count: int = 8) -> list[int]:
    """Up to ``count`` leaves, each the farthest (along bones) from those before.

    Only leaves at least :data:`_MIN_LIMB_BONES` bones of non-zero length below the root
    count: a limb has at least a thigh and a shin (its hip may sit at the pelvis itself); an
    IK target or prop hanging from the root by one bone does not.
    """
    leaves = np.array(tree.limb_leaves or tree.leaves)
    chosen = [int(leaves[int(np.argmax(tree.path[leaves]))])]
    nearest = tree.geodesic(chosen[0])
    while len(chosen) < min(count, len(leaves)):
        gaps = nearest[leaves]
        best = int(np.argmax(gaps))
        if gaps[best] <= 0:
            break
        chosen.append(int(leaves[best]))
        nearest = np.minimum(nearest, tree.geodesic(chosen[-1]))
    return chosen


def _is_thumb(name: str) -> bool:
    # Only steers the hand-tip search away from thumbs; canonical matching stays whole-name.
    return "thumb" in normalise_name(name)


def _farthest_descendant(tree: _Tree, start: int, skip: Callable[[str], bool] | None = None) -> int:
    """Descendant of ``start`` (inclusive) with the longest bone path from it."""
    best, best_distance = start, 0.0
    stack = [(start, 0.0)]
    while stack:
        joint, distance = stack.pop()
        if distance > best_distance:
            best, best_distance = joint, distance
        for child in tree.children[joint]:
            if skip is not None and skip(tree.names[child]):
                continue
            stack.append((child, distance + float(tree.lengths[child])))
    return best
