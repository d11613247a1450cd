"""A limb's straight runs in one pose: where the run ending at an ankle or wrist starts,
the joint that splits it (knee, elbow), and what a rest pose with bent limbs leaves to read
(a thigh's first bone turned forward; a forearm alone, split by a twist bone)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from app.motion.mapping.state import _MapperState
from app.motion.mapping.vectors import _length, _unit

# Degrees: bones of a straight limb in the rest pose (frame poses bend at knee and elbow).
_STRAIGHT_REST_DEG = 12.0
_STRAIGHT_FRAME_DEG = 50.0
# A joint bends a straight-looking limb when its chain turns by more than this, degrees.
_BEND_DEG = 8.0
# A knee splits its leg into comparable parts: thigh : shin within this ``|log|`` of a
# person's ratio (a factor of two; the dev rigs' named legs stay within 0.49).
_COMPARABLE = math.log(2.0)
# Upper arm : forearm and thigh : shin (Drillis & Contini's segment table).
_UPPER_TO_FORE = 1.27
_THIGH_TO_SHIN = 1.0
# Hand (wrist to fingertip) : forearm, same table (0.108 and 0.146 of height).
_HAND_TO_FORE = 0.74
# Foot (ankle to toe tip) : shin, same table (0.152 and 0.246 of height).
_FOOT_TO_SHIN = 0.62
# The share of a limb (top, middle and end joints, in straight lines) in the way from the
# trunk joint it hangs from to its end. A person's hip sits half a hip width (~0.1 of the
# height) from the pelvis, against a leg of ~0.49: 0.83; the shortest-legged cartoon of the
# dev data (Mixamo's Mousey) 0.69; a leg shorter than its hip's distance from the pelvis
# (under 0.5) is not one. An arm hangs a clavicle and some spine from the arms' branch
# point: 0.55 to 0.83 in the dev data; under a third, the arm is shorter than half that way.
_LEG_SHARE = 0.5
_ARM_SHARE = 1 / 3


@dataclass(frozen=True)
class _LimbKind:
    """A leg or an arm: its three joints, a person's upper : lower and (what lies beyond its
    end) : lower length ratios, and the least share of the way from the trunk joint to its
    end that the limb makes (:meth:`_Mapper.check_share`)."""

    what: str
    parts: tuple[str, str, str]
    upper: float
    beyond: float
    share: float


_LEG = _LimbKind("leg", ("hip", "knee", "ankle"), _THIGH_TO_SHIN, _FOOT_TO_SHIN, _LEG_SHARE)
_ARM = _LimbKind("arm", ("shoulder", "elbow", "wrist"), _UPPER_TO_FORE, _HAND_TO_FORE, _ARM_SHARE)


class _RunRules(_MapperState):
    """Straight runs along a limb's chain and the joint that splits one."""

    def straight_run_start(self, chain: list[int], end: int) -> int:
        """Index in ``chain`` where the straight run of bones ending at ``chain[end]`` starts."""
        limit = np.cos(np.radians(_STRAIGHT_REST_DEG if self.rest else _STRAIGHT_FRAME_DEG))
        start = end - 1
        while start > 1:
            candidate = start - 1
            whole = _unit(self.pose[chain[end]] - self.pose[chain[candidate]])
            segment = _unit(self.pose[chain[start]] - self.pose[chain[candidate]])
            if _length(segment) == 0:
                start = candidate
                continue
            if float(segment @ whole) < limit:
                break
            start = candidate
        return start

    def split(self, chain: list[int], start: int, end: int, kind: _LimbKind) -> int | None:
        """Index of the middle joint (knee, elbow) between ``chain[start]`` and ``chain[end]``:
        a rest-pose bend (for a knee, one between comparable parts), else the joint nearest
        the ``kind``'s upper : lower ratio."""
        pose, ratio = self.pose, kind.upper
        inner = [
            i
            for i in range(start + 1, end)
            if not self.same_place(chain[i], chain[start])
            and not self.same_place(chain[i], chain[end])
        ]
        if not inner:
            return None
        distance = self.tree.path
        scores = [
            abs(
                np.log(
                    max(distance[chain[i]] - distance[chain[start]], 1e-12)
                    / max(distance[chain[end]] - distance[chain[i]], 1e-12)
                )
                - np.log(ratio)
            )
            for i in inner
        ]
        # A knee bends between comparable parts: in a rest pose, a bend that leaves the thigh
        # less than half or more than twice the shin is a short bone's angle (a rig's first
        # thigh bone), not the knee. In a frame the knee bends as it will, and a bend there
        # tells a leg from a chain that is none. Not for arms: an arm's end is one of several
        # candidates judged by the proportions its split gives, and a finger's bend kept as
        # its "elbow" is what makes a candidate on a fingertip lose (legs end where the foot
        # turns, found before).
        bends = []
        for i, score in zip(inner, scores, strict=True):
            a = _unit(pose[chain[i]] - pose[chain[start]])
            b = _unit(pose[chain[end]] - pose[chain[i]])
            bend = float(np.degrees(np.arccos(np.clip(a @ b, -1.0, 1.0))))
            knee = kind is _ARM or not self.rest or score <= _COMPARABLE
            bends.append(bend if knee else 0.0)
        if max(bends) > _BEND_DEG:
            return inner[int(np.argmax(bends))]
        return inner[int(np.argmin(scores))]

    def thigh_top(self, above: list[int], straight: int, end: int, first: int) -> int:
        """Index in ``above`` where a leg's straight run (starting at ``straight``) starts when
        taken up through bones that turn from it forward or back but not outward.

        The hip joint is where the leg leaves the pelvis: the pelvis's bone to it runs
        outward from the spine's line. A bone above the run that runs no farther outward
        than the run itself does (for their lengths, within a straight limb's tolerance)
        and turns less than a limb in a frame is still the thigh (a rig's first thigh bone,
        flexed forward in the rest pose), however much it turns forward or back."""
        pose = self.pose
        tolerance = math.sin(math.radians(_STRAIGHT_REST_DEG))
        limit = math.cos(math.radians(_STRAIGHT_FRAME_DEG))

        def outward(a: int, b: int) -> float:
            """How far ``b`` lies farther from the spine's line than ``a``, per length."""
            step = pose[b] - pose[a]
            return (self.off_midline(b) - self.off_midline(a)) / max(_length(step), 1e-12)

        run_outward = outward(above[straight], above[end])
        while straight > first:
            candidate = above[straight - 1]
            bone = pose[above[straight]] - pose[candidate]
            run = pose[above[end]] - pose[above[straight]]
            if not _length(bone) or float(_unit(bone) @ _unit(run)) < limit:
                break
            if outward(candidate, above[straight]) > max(run_outward, 0.0) + tolerance:
                break
            straight -= 1
        return straight

    def forearm_only(
        self, above: list[int], best: tuple[float, int, int | None], straight: int
    ) -> tuple[float, int, int] | None:
        """The arm's top and middle (indices in ``above``) when the straight run ending at
        the wrist is the forearm alone, else None.

        A person's shoulder lies nearer the spine's line than the arm is long (half the
        shoulder breadth, 0.13 of the height, against 0.33 for upper arm and forearm). A
        straight run whose top lies farther out than the run is long ends, in a rest pose
        with bent elbows, at the elbow: a joint inside it is a twist bone splitting the
        forearm, not the elbow (when nothing branches off it: fingers would make it a hand).
        The top is then where the straight run ending at that bend starts, and the bend the
        middle."""
        tree = self.tree
        path = tree.path
        end = len(above) - 1
        top = above[best[1]]
        if self.off_midline(top) <= path[above[end]] - path[top]:
            return None
        # A twist bone carries the forearm on and nothing else; a joint inside the run with
        # bones branching off (fingers) is a hand, and the run more than a forearm.
        inside = above[best[1] + 1 : end]
        if any(sum(1 for c in tree.children[j] if tree.lengths[c] > 0) > 1 for j in inside):
            return None
        start = self.straight_run_start(above, straight)
        if self.same_place(above[start], above[0]):
            return None
        split = self.split(above, start, end, _ARM)
        if split != straight:
            return None  # the bend is no clear elbow: the run stands
        return (0.0, start, split)
