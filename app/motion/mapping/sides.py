"""Left and right: bent knees' hinge axes, else up x forward, read in the pose (and the
clip's frames when one pose can mislead); the names decide a mirrored capture."""

from __future__ import annotations

import math

import numpy as np

from app.motion.mapping.canonical import SIDES
from app.motion.mapping.state import _Limb, _MapperState
from app.motion.mapping.tree import COINCIDENT
from app.motion.mapping.vectors import _cross, _length, _unit

_BENT_KNEE = np.radians(10)  # a knee bent this much shows its hinge axis
_HINGE_ACROSS = np.cos(np.radians(45))  # ...when that axis lies this near the hips' line


class _SideRules(_MapperState):
    """Puts the mapped limbs on their sides."""

    @staticmethod
    def knee_bend(pose: np.ndarray, leg: _Limb) -> float:
        """The knee's bend in ``pose``: radians between thigh and shin (0: straight)."""
        thigh = pose[leg["knee"]] - pose[leg["hip"]]
        shin = pose[leg["ankle"]] - pose[leg["knee"]]
        return math.atan2(_length(_cross(thigh, shin)), float(thigh @ shin))

    def knee_hinge(
        self, pose: np.ndarray, up: np.ndarray, legs: list[_Limb], least: float = _BENT_KNEE
    ) -> np.ndarray:
        """``(3,)`` the unit hinge axis (thigh x shin, across ``up``) of the knees bent in
        ``pose`` more than ``least`` radians, when at least one is and the two agree; else
        zero."""
        hinge = np.zeros(3)
        across = pose[legs[0]["hip"]] - pose[legs[1]["hip"]]
        across -= (across @ up) * up
        for leg in legs:
            thigh = pose[leg["knee"]] - pose[leg["hip"]]
            shin = pose[leg["ankle"]] - pose[leg["knee"]]
            axis = _cross(thigh, shin)
            if math.atan2(_length(axis), float(thigh @ shin)) <= least:  # the knee's bend
                continue
            # A knee bends about the line across the hips (turned by the hip's rotation, a
            # toe-out); a shin bent out or in of the thigh's line (knock-knees, legs apart,
            # a twisted or noisy leg) turns about the forward axis and shows no side.
            if (
                _length(across) > COINCIDENT * self.extent
                and abs(float(_unit(axis) @ _unit(across))) < _HINGE_ACROSS
            ):
                continue
            hinge += axis / _length(axis)
        hinge -= (hinge @ up) * up
        return _unit(hinge) if _length(hinge) > 0.5 else np.zeros(3)

    def left(
        self, pose: np.ndarray, up: np.ndarray, legs: list[_Limb], least: float = _BENT_KNEE
    ) -> np.ndarray:
        """The subject's left in ``pose`` (zero when it shows none).

        A bent knee's hinge axis, thigh x shin, points to the subject's left whichever way
        the subject faces and whatever the feet do (the shin folds back); in a mirrored
        capture it points to the mirror image's left, as ``up x forward`` does. Knees too
        straight to show it leave ``up x forward``, forward from the feet, else the knees'
        bend. Knees bent ``least`` radians or less show no hinge."""
        hinge = self.knee_hinge(pose, up, legs, least)
        if _length(hinge):
            return hinge
        forward = np.zeros(3)
        for leg in legs:
            step = pose[leg["toe"]] - pose[leg["ankle"]]
            forward += step - (step @ up) * up
        if _length(forward) < 0.02 * self.extent:
            for leg in legs:
                if self.knee_bend(pose, leg) <= _BENT_KNEE:
                    continue  # a knee this straight says nothing of front and back (a rest
                    # pose's knee sits a little ahead or behind its leg's line by the rig)
                mid = 0.5 * (pose[leg["hip"]] + pose[leg["ankle"]])
                step = pose[leg["knee"]] - mid
                forward += step - (step @ up) * up
        if _length(forward) <= COINCIDENT * self.extent:
            return np.zeros(3)  # straight knees, no feet: only rounding errors point anywhere
        return _unit(_cross(up, _unit(forward)))

    def assign_sides(self, legs: list[_Limb], arms: list[_Limb]) -> tuple[bool, int]:
        """Put the limbs on their sides; returns (mirrored, lateral world axis)."""
        tree, pose, up = self.tree, self.pose, self.body.up
        left = self.left(pose, up, legs)
        # In a frame, knees, elbows and hands cross (side steps, a slash, folded arms); hips
        # (or, where both hips sit at the pelvis, the knees below them) and shoulders, fixed
        # to the trunk, do not.
        hips = ("hip",) if not self.same_place(legs[0]["hip"], legs[1]["hip"]) else ("knee",)
        keys = (
            (("hip", "knee"), ("shoulder", "elbow", "wrist"))
            if self.rest
            else (hips, ("shoulder",))
        )
        voters = [(pose, left, keys, up)]
        # The clip's other poses vote with this one: always when the mapping comes from a frame
        # (one frame can mislead); from the rest pose when it shows no side at all (straight
        # knees, no feet: the motion's bent knees do), or shows it by bent knees: a person at
        # rest stands on straight knees, so a rest pose with bent knees is a pose of the take
        # (a pose estimator's first frame), and one such pose can mislead as a frame can.
        posed = bool(_length(self.knee_hinge(pose, up, legs)))
        if not self.rest or not _length(left) or posed:
            self.sides_open = self.rest
            others = []
            for other in self.others():
                spine = other[self.body.chest] - other[self.body.pelvis]
                if _length(spine) < COINCIDENT * self.extent:
                    spine = other[self.body.head] - other[self.body.pelvis]
                other_up = _unit(spine)
                if _length(other_up) > 0:
                    others.append((other, other_up))
            # A knee bends one way, and far (a lifted or folded leg: 60-140 degrees); it
            # straightens to a little past straight at most. Mild bends the other way (a
            # depth tracker's stance, a rig whose shin does not fit the data) must not
            # outvote the take's deep ones: a pose whose knees bend less than half the
            # take's deepest shows its side by the feet.
            deepest = max(self.knee_bend(p, leg) for p, _ in [(pose, up), *others] for leg in legs)
            least = max(_BENT_KNEE, deepest / 2)
            if least > _BENT_KNEE:  # else this pose's left, read above, stands
                left = self.left(pose, up, legs, least)
            voters = [(pose, left, keys, up)]
            voters += [
                (other, self.left(other, other_up, legs, least), (hips, ("shoulder",)), other_up)
                for other, other_up in others
            ]
        axis = next((int(np.argmax(np.abs(v[1]))) for v in voters if _length(v[1])), 0)

        def name_of(limb: _Limb, top: int) -> str | None:
            votes = [
                tree.sides[j]
                for j in tree.chain(top, limb["ankle" if "ankle" in limb.joints else "wrist"])[1:]
                if tree.sides[j] is not None
            ]
            if not votes:
                return None
            return (
                max(set(votes), key=votes.count)
                if votes.count(votes[0]) * 2 != len(votes)
                else None
            )

        def order(pair: list[_Limb], limb: int, top: int) -> tuple[list[_Limb], bool | None, bool]:
            """(pair as [left, right] by geometry, names agree?, geometry known?)"""
            named = {name_of(one, top) for one in pair} == {"l", "r"}
            votes = 0
            for voter, voter_left, voter_keys, voter_up in voters:
                if not _length(voter_left):
                    continue
                apart = sum(voter[pair[0][k]] - voter[pair[1][k]] for k in voter_keys[limb])
                lateral = float(apart @ voter_left)
                # A person's hips and shoulders, fixed to the trunk, lie side by side (knees
                # and hands part front to back in a stride or a swing): a named pair whose
                # hips or shoulders are set apart more front to back than across (a rest
                # pose in bone-local axes that passed for a standing figure) shows no side,
                # whatever its small sideways part says, and its names break the tie.
                # Without names it is still the only reading there is.
                base_key = voter_keys[limb][0]
                if named and base_key in ("hip", "shoulder"):
                    base = voter[pair[0][base_key]] - voter[pair[1][base_key]]
                    across = base - (base @ voter_left) * voter_left
                    ahead = float(_length(across - (across @ voter_up) * voter_up))
                    if ahead > abs(float(base @ voter_left)):
                        continue
                if abs(lateral) > COINCIDENT * self.extent:
                    votes += 1 if lateral > 0 else -1
            known = votes != 0  # a tie tells nothing
            by_geometry = pair if votes >= 0 else pair[::-1]
            sides = [name_of(limb, top) for limb in by_geometry]
            if sides == ["l", "r"]:
                return by_geometry, True, known
            if sides == ["r", "l"]:
                return by_geometry, False, known
            return by_geometry, None, known

        legs_lr, legs_agree, legs_known = order(legs, 0, self.body.pelvis)
        arms_lr, arms_agree, arms_known = order(arms, 1, self.body.chest)
        mirrored = False
        if not (legs_known and arms_known):
            # No usable geometry: names alone (or the file's order) decide.
            if legs_agree is False:
                legs_lr = legs_lr[::-1]
            if arms_agree is False:
                arms_lr = arms_lr[::-1]
            if legs_agree is None or arms_agree is None:
                self.warnings.append("left and right could not be told apart; sides are a guess")
        elif legs_agree is False and arms_agree is False:
            mirrored = True
            legs_lr, arms_lr = legs_lr[::-1], arms_lr[::-1]
            self.warnings.append("mirrored capture: stored un-mirrored")
        elif legs_agree is False or arms_agree is False:
            which = "legs" if legs_agree is False else "arms"
            self.warnings.append(
                f"the joint names put the {which} on the other side from the geometry; "
                "sides taken from the geometry"
            )
        for side, leg, arm in zip(SIDES, legs_lr, arms_lr, strict=True):
            for part, joint in leg.joints.items():
                self.put(f"{side}_{part}", joint, leg.how[part])
            for part, joint in arm.joints.items():
                self.put(f"{side}_{part}", joint, arm.how[part])
            self.derived.append(f"{side}_hand_tip")
            if self.how[f"{side}_toe"].startswith("derived"):
                self.derived.append(f"{side}_toe")
        return mirrored, axis
