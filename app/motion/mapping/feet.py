"""Heel or toe: a game rig's heel bone (a chain from the ankle, or from the knee beside the
foot, pointing back) may reach farther along the bones and lower than the toes, so the
leaf taken for the foot is the heel's. A person's foot points forward, the way the knee
bends: where the pose or the clip's frames bend the knee, a toe pointing against that bend
is a heel, and a leaf below the knee pointing with it is the toe (issue 20)."""

from __future__ import annotations

import numpy as np

from app.motion.mapping.hypotheses import _NotHumanoid
from app.motion.mapping.state import _Limb, _MapperState
from app.motion.mapping.vectors import _length, _unit_rows

# A knee bent this much (sine of the angle between thigh and shin, 10 degrees) shows which
# way is forward for its leg.
_BENT = np.sin(np.radians(10))
# Mean cosine between a foot (ankle to toe) and the front of its shin: below minus this the
# foot points back (a heel), above it forward (a toe). A person's foot leaves the shin at
# 90 degrees give or take the ankle's flex (50 degrees down, 20 up): cosines of 0.6 and
# more; a heel bone leaves it backwards.
_POINTS = 0.3
# A person's foot reaches from the ankle to the toe tip about 0.6 of the shin's length (0.152
# against 0.246 of the height); a heel sticks out behind the ankle by a quarter of the foot
# (0.15 of the shin). A foot's only branch shorter than this and pointing back is a heel;
# a branch beside it pointing forward is the toes' only when longer.
_HEEL_SHIN = 0.35
# How the toe reads when the foot's only branch is a heel: the ankle stands for the toe.
HEEL_ONLY = "derived: the ankle (the foot's only branch points back against the knee's bend)"


class _FootRules(_MapperState):
    """Chooses the foot's branch that points forward."""

    def leg_to(self, foot: int) -> _Limb:
        """The leg ending at the leaf ``foot`` (:class:`~app.motion.mapping.limbs._LimbRules`)."""
        raise NotImplementedError

    def knee_fronts(self, limb: _Limb) -> tuple[np.ndarray, np.ndarray]:
        """``(P, J, 3)`` poses where ``limb``'s knee is bent and ``(P, 3)`` the front of the
        shin in each: the thigh's direction off the shin's line. The knee folds the shin
        back behind the thigh only, so in the shin's own frame the thigh leans to its front,
        the side a person's toes point to at any flex of the ankle, however the body lies
        (standing, crouching, kneeling). This pose when it bends the knee, else the clip's
        frames that do."""
        hip, knee, ankle = limb["hip"], limb["knee"], limb["ankle"]
        poses = self.pose[None]
        for attempt in range(2):
            if attempt:
                frames = self.motion()
                if not frames:
                    break
                poses = np.stack(frames)
            thigh = poses[:, knee] - poses[:, hip]  # (P, 3)
            shin = poses[:, ankle] - poses[:, knee]
            sine = np.linalg.norm(np.cross(thigh, shin), axis=1)
            bent = sine > _BENT * np.linalg.norm(thigh, axis=1) * np.linalg.norm(shin, axis=1)
            if bent.any():
                along = _unit_rows(shin[bent])
                front = thigh[bent] - np.sum(thigh[bent] * along, axis=1, keepdims=True) * along
                return poses[bent], _unit_rows(front)
        return np.zeros((0, *self.pose.shape)), np.zeros((0, 3))

    @staticmethod
    def pointing(poses: np.ndarray, fronts: np.ndarray, ankle: int, toe: int) -> float:
        """Mean cosine between the foot ``ankle`` -> ``toe`` and the shin's ``fronts``
        over ``poses`` (0 for a toe at the ankle)."""
        foot = _unit_rows(poses[:, toe] - poses[:, ankle])  # (P, 3)
        return float(np.mean(np.sum(foot * fronts, axis=1)))

    def foot_long(self, limb: _Limb, toe: int | None = None) -> bool:
        """Whether ``toe`` (``limb``'s own by default) lies as far from ``limb``'s ankle as
        a person's toes do, for the shin (:data:`_HEEL_SHIN`): farther than a heel sticks
        out behind."""
        ankle = self.pose[limb["ankle"]]
        shin = _length(ankle - self.pose[limb["knee"]])
        reach = _length(self.pose[limb["toe"] if toe is None else toe] - ankle)
        return reach >= _HEEL_SHIN * shin

    def toe_points_back(self, limb: _Limb) -> tuple[np.ndarray, np.ndarray] | None:
        """:meth:`knee_fronts` of ``limb`` where its toe points back against the knee's
        bend in them (a heel), else None (it points with it, or no pose bends the knee)."""
        poses, fronts = self.knee_fronts(limb)
        if not len(poses) or self.pointing(poses, fronts, limb["ankle"], limb["toe"]) >= -_POINTS:
            return None
        return poses, fronts

    def forward_foot(self, limb: _Limb, foot: int) -> _Limb:
        """``limb`` (the leg ending at the leaf ``foot``), or, when its toe points back
        against the knee's bend (a heel), the leg ending at another leaf below the knee
        whose toe points with it; with none, a branch short as a heel is no toe and the
        ankle holds (:data:`HEEL_ONLY`). A knee that never bends shows no front: ``limb``
        stands. Asked only where the foot's structure makes it a question (a foot-long
        leaf beside the foot, or a foot short as a heel): an ordinary foot reads no frame."""
        ankle, toe = limb["ankle"], limb["toe"]
        if toe == ankle:
            return limb
        if limb.how["toe"].startswith("derived"):
            # No bone of the foot: End Sites on the ankle, which a writer may point
            # anywhere. One alone tells nothing of a heel; of several (a heel's and a
            # toe's), the one pointing with the knee's bend is the toe.
            return self.forward_end(limb)
        tree = self.tree
        own = set(tree.chain(limb["knee"], foot))
        # Leaves below the knee beside the foot reaching as far as toes from the ankle: a
        # small bone (a helper, a face-like nub) on the foot is no toe.
        beside = [
            leaf
            for leaf in tree.leaves
            if leaf not in own
            and tree.is_ancestor(limb["knee"], leaf)
            and self.foot_long(limb, leaf)
        ]
        if not beside and self.foot_long(limb):
            return limb
        bent = self.toe_points_back(limb)
        if bent is None:
            return limb
        poses, fronts = bent
        best: tuple[float, _Limb] | None = None
        for leaf in beside:
            try:
                other = self.leg_to(leaf)
            except _NotHumanoid:
                continue
            if (other["hip"], other["knee"]) != (limb["hip"], limb["knee"]):
                continue
            if not self.foot_long(other):
                continue
            score = self.pointing(poses, fronts, other["ankle"], other["toe"])
            if score > _POINTS and (best is None or score > best[0]):
                best = (score, other)
        if best is not None:
            return best[1]
        if not self.foot_long(limb):
            # Short as a heel, too: no toe. (A foot as long as a person's stands: knees
            # bending backwards in a take are the take's artefact, not a heel.)
            limb.joints["toe"], limb.how["toe"] = ankle, HEEL_ONLY
        return limb

    def forward_end(self, limb: _Limb) -> _Limb:
        """``limb`` with its derived toe (the farthest End Site beyond the ankle) swapped
        for another End Site on the ankle, as far as toes reach, that points with the
        knee's bend where the toe points against it (a heel's and a toe's End Site, alike
        in length: which one the farthest is was the file's order)."""
        ankle, toe = limb["ankle"], limb["toe"]
        tree = self.tree
        ends = [
            leaf
            for leaf in tree.children[ankle]
            if leaf != toe and tree.skeleton.end_site[leaf] and self.foot_long(limb, leaf)
        ]
        if not ends or not self.foot_long(limb):
            return limb
        bent = self.toe_points_back(limb)
        if bent is None:
            return limb
        poses, fronts = bent
        scores = [(self.pointing(poses, fronts, ankle, leaf), leaf) for leaf in ends]
        score, leaf = max(scores)
        if score > _POINTS:
            limb.joints["toe"] = leaf
            limb.how["toe"] = "derived: the End Site beyond the ankle pointing with the knee"
        return limb
