"""What the mapper knows while it places the joints of one hypothesis, and the small
questions every rule asks (same place, names, how the clip's frames move a limb)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from app.motion.mapping.hypotheses import _Body
from app.motion.mapping.tree import COINCIDENT, _farthest_descendant, _Tree
from app.motion.mapping.vectors import _length, _unit_rows
from app.motion.skeleton_names import SIDED_PARTS

# An end effector continues its joint's direction (up for the head, forward for the toes)
# within this cosine (45 degrees): a helper nub pointing elsewhere is not the toe tip.
_EFFECTOR_COS = 0.7
# Fractions of the pose's extent (its bounding-box diagonal, about body height).
_HEAD_END_MIN = 0.005  # an end effector is at least this far from its joint
# Degrees a joint inside one limb part may turn over the clip's frames: a bone does not bend
# (twist and helper joints inside it keep their angle), while a joint of the limb (a collar
# in line with a T-posed arm, a wrist, a finger) turns tens of degrees in almost any motion.
_RIGID_DEG = 15.0


@dataclass
class _Limb:
    """One arm or leg: part (``hip``, ``knee``...) -> source joint, and how each was found."""

    joints: dict[str, int]
    how: dict[str, str]

    def __getitem__(self, part: str) -> int:
        return self.joints[part]


class _MapperState:
    """The pose, the hypothesis (head, hands, feet) and what has been placed so far."""

    def __init__(
        self,
        tree: _Tree,
        pose: np.ndarray,
        extent: float,
        body: _Body,
        label: str,
        others: Callable[[], list[np.ndarray]] = list,
    ):
        self.tree = tree
        self.others = others
        self.pose = pose
        self.extent = extent
        self.body = body
        self.rest = label == "rest pose"
        self.label = label
        self.found: dict[str, int] = {}
        self.how: dict[str, str] = {}
        self.derived: list[str] = []
        self.warnings: list[str] = []
        # The rest pose showed no side: the clip's frames chose (so it is not kept per rig).
        self.sides_open = False
        # Limb joints in line in the rest pose that the clip's frames would choose among.
        self.limbs_open = False
        self._frames: list[np.ndarray] | None = None
        self._moving: np.ndarray | None = None
        self._bent: dict[tuple[int, int, tuple[int, ...]], bool] = {}
        # Hand leaf -> (chain from the chest, the arm choices best_limb chose among).
        self.arm_options: dict[int, tuple[list[int], list[tuple[float, _Limb]]]] = {}
        # Half the distance between the hip joints (0 until the legs are mapped).
        self.hip_half_gap = 0.0

    # -- small helpers -------------------------------------------------------------------

    def same_place(self, a: int, b: int) -> bool:
        return _length(self.pose[a] - self.pose[b]) <= COINCIDENT * self.extent

    def deepest_coincident(self, joint: int, chain: list[int]) -> int:
        """The last joint of ``chain`` at ``joint``'s position from ``joint`` on (dummies)."""
        i = chain.index(joint)
        while i + 1 < len(chain) and self.same_place(chain[i + 1], joint):
            i += 1
        return chain[i]

    def named(self, chain: Sequence[int], part: str) -> int | None:
        """The joint of ``chain`` whose name says ``part`` best; on ties, for a limb's part,
        one that sits apart from its parent before one on its parent's place; then the one
        nearest the root.

        A limb's joints sit apart from the trunk and from each other: writers that give each
        limb a connector at the trunk's point (``Pelvis_L_Hip`` at the pelvis, then ``L_Hip``
        where the thigh starts) name both after the part, and the joint where the part starts
        is the one set apart (a twist bone on its limb joint's place loses to that joint
        alike). On the trunk's line joints do share places: a neck that starts at the top of
        the chest (``Neck`` on ``Spine1``'s place, then ``Neck1``) is the first."""
        best: tuple[int, bool, int] | None = None
        tree = self.tree
        limb = part in SIDED_PARTS
        for i, j in enumerate(chain):
            rank = tree.hints[j].parts.get(part)
            if rank is None:
                continue
            on_parent = limb and bool(tree.parents[j] >= 0 and tree.lengths[j] == 0)
            if best is None or (rank, on_parent) < best[:2]:
                best = (rank, on_parent, i)
        return None if best is None else chain[best[2]]

    def motion(self) -> list[np.ndarray]:
        """The clip's other poses (``(J, 3)`` each) that show how the limbs move; none when
        the clip offers none (the rest pose's mapping is then left open for each clip's
        frames to decide, :attr:`SkeletonMap.limbs_open`)."""
        if self._frames is None:
            self._frames = self.others()
        if not self._frames:
            self.limbs_open = self.rest
        return self._frames

    def bends(self, chain: Sequence[int], start: int, end: int) -> bool:
        """Whether a joint strictly between ``chain[start]`` and ``chain[end]`` (one limb
        part: upper arm, forearm, thigh, shin) turns by more than :data:`_RIGID_DEG` from
        its angle in this pose in some pose of :meth:`motion`: such a joint is a joint of
        the limb, not one inside a bone."""
        a, b = chain[start], chain[end]
        inner = tuple(
            chain[i]
            for i in range(start + 1, end)
            if not self.same_place(chain[i], a) and not self.same_place(chain[i], b)
        )
        if not inner:
            return False
        key = (a, b, inner)
        if key not in self._bent:
            if self._moving is None:  # this pose first, then the clip's: (P, J, 3)
                self._moving = np.stack([self.pose, *self.motion()])
            at = self._moving
            into = _unit_rows(at[:, inner] - at[:, [a]])
            out = _unit_rows(at[:, [b]] - at[:, inner])
            angles = np.arccos(np.clip(np.sum(into * out, axis=-1), -1.0, 1.0))  # (P, K)
            self._bent[key] = bool(np.any(np.abs(angles[1:] - angles[0]) > np.radians(_RIGID_DEG)))
        return self._bent[key]

    def off_midline(self, joint: int) -> float:
        """How far ``joint`` lies from the spine's line (through the pelvis, along up)."""
        step = self.pose[joint] - self.pose[self.body.pelvis]
        return _length(step - (step @ self.body.up) * self.body.up)

    def put(self, canonical: str, joint: int, how: str) -> None:
        self.found[canonical] = joint
        self.how[canonical] = how

    def effector(self, joint: int, *, along: np.ndarray | None) -> int | None:
        """The first point of the single unbranched chain beyond ``joint`` that lies at least
        :data:`_HEAD_END_MIN` away (an End Site, a leaf bone such as ``HeadTop_End``, or the
        next joint when converters append an End Site beyond that leaf: the same point in a
        BVH and in the FBX it came from) and, if ``along`` is given, in that direction more
        than sideways."""
        tree = self.tree
        j = joint
        step = np.zeros(3)
        distance = 0.0
        while distance < _HEAD_END_MIN * self.extent:
            children = tree.children[j]
            if along is not None:
                # A branch whose far end hangs below ``joint`` (hair from the skull, a hood's
                # tail) does not reach towards the end: no rival of the head's top.
                children = [c for c in children if not self._hangs(joint, c, along)]
            reaches = sorted(((tree.lengths[c] + tree.reach[c], c) for c in children), reverse=True)
            if not reaches or reaches[0][0] == 0:
                return None
            # Side nubs (twist bones, helpers) shorter than half the main branch do not make
            # a branching; two comparable branches (face joints beside the skull) do.
            if len(reaches) > 1 and reaches[1][0] >= 0.5 * reaches[0][0]:
                return None
            j = reaches[0][1]
            step = self.pose[j] - self.pose[joint]
            distance = _length(step)
        if along is not None and float(step @ along) < _EFFECTOR_COS * distance:
            return None
        return j

    def _hangs(self, joint: int, child: int, along: np.ndarray) -> bool:
        """Whether the branch from ``joint`` through ``child`` ends (its farthest joint along
        the bones) behind ``joint`` along ``along``."""
        tip = _farthest_descendant(self.tree, child)
        return float((self.pose[tip] - self.pose[joint]) @ along) < 0
