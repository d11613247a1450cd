"""Legs and arms along their chains: the hip and shoulder, knee and elbow, ankle and wrist,
by the straight runs, the turns and a person's proportions (and the clip's frames where
the rest pose leaves joints in one line)."""

from __future__ import annotations

import math

import numpy as np

from app.motion.mapping.feet import _FootRules
from app.motion.mapping.hypotheses import _NotHumanoid
from app.motion.mapping.named import NAMES_NOT_FOLLOWED, _NamedRules
from app.motion.mapping.runs import _ARM, _FOOT_TO_SHIN, _LEG, _LimbKind
from app.motion.mapping.state import _EFFECTOR_COS, _Limb
from app.motion.mapping.tree import _branches_below, _farthest_descendant
from app.motion.mapping.vectors import _length, _unit

# A later limb top must fit the proportions this much better (log ratio) to be taken.
_PROPORTION_MARGIN = 0.3
# The foot turns away from the shin by at least this much at the ankle, degrees.
_ANKLE_TURN_DEG = 25.0
# Left and right limbs of a pair are one length: their upper (lower) parts differ by at most
# this ``|log|`` ratio. People differ by a few per cent side to side; the rigs of the dev data
# by at most 0.09 (mocap solvers, a 3ds Max capture), an asymmetric robot 0.13. A limb taken
# one joint too high or low changes a part by a bone: a collar, a hand (0.4 and more).
_ALIKE = 0.15
# How a wrist found where the fingers part begins.
_FINGERS_BRANCH = "structure: where the fingers"
# How a wrist found where a hand of one chain begins.
_ONE_CHAIN = "structure: where a hand of one chain starts"
# A joint nearer the ankle than this share of the shin is still at the ankle (a metatarsal
# pivot, as DAZ Genesis writes one just behind and below it), no toe: a heel sticks out
# behind the ankle by 0.15 of the shin, the ball of the foot lies 0.4 and more ahead of it.
_AT_ANKLE = 0.1
# How an ankle found where the foot turns forward.
_TURNS_FORWARD = "geometry: where the foot turns forward"


class _LimbRules(_NamedRules, _FootRules):
    """Places the joints of one leg or arm."""

    def check_share(self, limb: _Limb, kind: _LimbKind, trunk: int) -> None:
        """Raise _NotHumanoid when ``limb`` does not make its share of the way from the trunk
        joint it hangs from (:meth:`far_from_trunk`)."""
        problem = self.far_from_trunk(tuple(limb[part] for part in kind.parts), kind, trunk)
        if problem is not None:
            raise _NotHumanoid(problem)

    def far_from_trunk(self, joints: tuple[int, ...], kind: _LimbKind, trunk: int) -> str | None:
        """Why the limb ``joints`` (top, middle, end: straight lines in the pose) is none of a
        person, or None: a limb makes at least ``kind.share`` of the way from the trunk joint
        it hangs from to its end; a chain whose top hangs far from the trunk for its length
        (a creature's fingers, the feathers on its head) is not a person's leg or arm."""
        at = [self.pose[joint] for joint in joints]
        length = _length(at[1] - at[0]) + _length(at[2] - at[1])
        hang = _length(at[0] - self.pose[trunk])
        if length >= kind.share * (length + hang):
            return None
        return (
            f"the {kind.what} {self.tree.names[joints[0]]!r} .. "
            f"{self.tree.names[joints[2]]!r} hangs {hang / max(length, 1e-12):.1f} "
            f"of its length away from the {'pelvis' if kind is _LEG else 'chest'}: "
            f"not a {kind.what} of a person"
        )

    def upper_and_middle(self, limb: _Limb, above: list[int], kind: _LimbKind) -> None:
        """Put the limb's top joint (hip, shoulder) and middle joint (knee, elbow) on the
        chain ``above`` that ends at the ankle or wrist: by name when both names are there
        in order, else the straight run's start and its split nearest the ``kind``'s
        upper : lower ratio (among those whose parts do not bend in the clip's frames, when
        the frames show which). Names that make no person's limb (:meth:`no_person`: names
        shifted one joint down it) give way to that geometric reading when it makes one,
        and the top's ``how`` says they were not followed."""
        parts = kind.parts[:2]
        named = self.named_pair(above, kind)
        wrong = None if named is None else self.no_person(*named, above[-1], kind)
        if named is not None and wrong is None:
            self.place(limb, parts, named, ("name", "name"))
            return
        found: tuple[int, int]
        try:
            top, middle = self.straight_split(above, kind)
            found = (
                self.deepest_coincident(above[top], above),
                self.deepest_coincident(above[middle], above),
            )
        except _NotHumanoid:
            if named is None:
                raise
            found = named  # no middle joint by the geometry: the names stand
        if named is not None and self.no_person(*found, above[-1], kind) is not None:
            # The geometric reading is no person's limb either: the names stand.
            found, wrong = named, None
        if found is named:
            self.place(limb, parts, named, ("name", "name"))
            return
        note = "" if wrong is None else f" ({NAMES_NOT_FOLLOWED}: {wrong})"
        hows = (
            f"geometry: top of the straight {kind.what}{note}",
            f"geometry: middle of the {kind.what}",
        )
        self.place(limb, parts, found, hows)

    @staticmethod
    def joints(limb: _Limb, kind: _LimbKind) -> tuple[int, int, int]:
        """The limb's top, middle and end joints."""
        top, middle, end = kind.parts
        return limb[top], limb[middle], limb[end]

    @staticmethod
    def place(
        limb: _Limb, parts: tuple[str, ...], joints: tuple[int, ...], hows: tuple[str, ...]
    ) -> None:
        """Put ``joints`` as the limb's ``parts``, found as ``hows`` say."""
        for part, joint, how in zip(parts, joints, hows, strict=True):
            limb.joints[part], limb.how[part] = joint, how

    def straight_split(self, above: list[int], kind: _LimbKind) -> tuple[int, int]:
        """Indices in ``above`` of the limb's top and middle joints read from the geometry
        (:meth:`upper_and_middle`); _NotHumanoid when the chain holds no middle joint."""
        parts, ratio, what = kind.parts[:2], kind.upper, kind.what
        end = len(above) - 1
        # The top joint is never at the trunk joint's own place (a zero-length clavicle).
        first = next((i for i in range(1, end) if not self.same_place(above[i], above[0])), 1)
        straight = max(self.straight_run_start(above, end), first)
        if kind is _LEG:
            straight = self.thigh_top(above, straight, end, first)
        # A collar bone nearly in line with a T-posed arm passes for straight: among the tops
        # of the straight run and the joints below it, the one whose split comes nearest the
        # limb's proportions wins.
        options: list[tuple[float, int, int]] = []
        for start in range(straight, end - 1):
            split = self.split(above, start, end, kind)
            if split is None:
                continue
            path = self.tree.path
            upper = path[above[split]] - path[above[start]]
            lower = path[above[end]] - path[above[split]]
            options.append(
                (abs(np.log(max(upper, 1e-12) / max(lower, 1e-12)) - np.log(ratio)), start, split)
            )
        if kind is _ARM and len(options) > 1:
            # A person's shoulders sit wider apart than the hip joints (0.26 against about
            # 0.1-0.2 of the height): a top joint nearer the spine's line than a hip is to
            # the pelvis is where a collar bone starts, not the shoulder.
            wide = [
                option
                for option in options
                if self.off_midline(above[option[1]]) >= self.hip_half_gap
            ]
            if not wide and self.motion():
                # Arms raised along the spine leave every top near its line: the shoulder is
                # wide of it in some pose of the clip, where the collar's root never is.
                wide = [option for option in options if self.wide_in_motion(above[option[1]])]
            options = wide or options
        if len(options) > 1 and self.motion():
            # The motion tells what the rest pose cannot: a top joint with a joint inside its
            # upper part that turns in the clip (the shoulder below a collar bone in line
            # with it) is no top of the limb; nor is one that leaves a limb too short for its
            # distance from the trunk (the last finger bones, which never bend inside).
            rigid = [
                option
                for option in options
                if not self.bends(above, option[1], option[2])
                and not self.bends(above, option[2], end)
                and self.far_from_trunk(
                    (above[option[1]], above[option[2]], above[end]), kind, above[0]
                )
                is None
            ]
            options = rigid or options
        best: tuple[float, int, int | None] | None = None
        for option in options:
            if best is None or option[0] < best[0] - _PROPORTION_MARGIN:
                best = option
        if kind is _ARM and best is not None and straight > first:
            best = self.forearm_only(above, best, straight) or best
        # A run too short to hold a middle joint: the limb bends in the rest pose (no T-pose)
        # and its top is the nearest joint above the run.
        for start in range(straight - 1, first - 1, -1):
            if best is not None:
                break
            split = self.split(above, start, end, kind)
            if split is not None:
                best = (0.0, start, split)
        if best is None and first > 1:
            # Nothing below the trunk's place fits: the top joint sits there itself (hip
            # joints at the pelvis, the legs parting only at the knees).
            split = self.split(above, first - 1, end, kind)
            if split is not None:
                best = (0.0, first - 1, split)
        start, split = (straight, None) if best is None else best[1:]
        if split is None:
            raise _NotHumanoid(
                f"the {what} ending at {self.tree.names[above[-1]]!r} has no {parts[1]} between "
                f"its {parts[0]} and its end"
            )
        return start, split

    def wide_in_motion(self, joint: int) -> bool:
        """Whether ``joint`` lies as far from the spine's line as a hip from the pelvis in
        some pose of :meth:`motion` (the spine's line through the pelvis, along up)."""
        up, pelvis = self.body.up, self.body.pelvis
        for pose in self.motion():
            step = pose[joint] - pose[pelvis]
            if _length(step - (step @ up) * up) >= self.hip_half_gap:
                return True
        return False

    def best_limb(
        self,
        chain: list[int],
        ends: list[tuple[int, str]],
        kind: _LimbKind,
        seen: list[tuple[float, _Limb]] | None = None,
    ) -> _Limb:
        """The limb along ``chain`` (trunk joint first) ending at the one of ``ends`` (joint,
        how it was found) that leaves room for its top and middle joints and comes nearest
        a person's proportions (the first on ties); else the first end's _NotHumanoid.

        When that limb bends inside its upper or lower part in the clip's frames (its end
        on a fingertip: the wrist turns inside the "forearm"), the nearest to proportions
        of the limbs that do not bend and make their share of the way from the trunk
        (:meth:`check_share`) is taken instead."""
        limbs: list[tuple[float, _Limb]] = []
        problem: _NotHumanoid | None = None
        for end, end_how in dict(ends).items():
            limb = _Limb({kind.parts[2]: end}, {kind.parts[2]: end_how})
            try:
                self.upper_and_middle(limb, chain[: chain.index(end) + 1], kind)
            except _NotHumanoid as why:
                problem = problem or why
                continue
            limbs.append((self.limb_proportions(limb, kind), limb))
        if not limbs:
            assert problem is not None
            raise problem
        if kind is _ARM:
            # An arm makes its share of the way from the chest (:meth:`check_share`): a
            # wrist whose arm does not (three finger bones of the hand taken for the arm) is
            # not the wrist. (A leg keeps its one verdict: a creature's toes are no legs.)
            sharing = [
                option
                for option in limbs
                if self.far_from_trunk(tuple(option[1][p] for p in kind.parts), kind, chain[0])
                is None
            ]
            limbs = sharing or limbs
            # Shoulders sit nearer the spine's line than an arm is long (half the shoulder
            # breadth, 0.13 of the height, against 0.33 for upper arm and forearm): an arm
            # whose top lies farther out than its own length has an elbow for its shoulder.
            path = self.tree.path
            narrow = [
                option
                for option in limbs
                if self.off_midline(option[1][kind.parts[0]])
                < path[option[1][kind.parts[2]]] - path[option[1][kind.parts[0]]]
            ]
            limbs = narrow or limbs
            # An arm's top is never at the chest's own place, and its first joint below the
            # chest — where a collar bone starts, or a rig without collars hangs the
            # shoulder — is its top only when it sits wider of the spine's line than a hip
            # joint of the pelvis (a person's shoulders are wider apart than the hip joints;
            # so among one wrist's choices, :meth:`upper_and_middle`): else it is the collar,
            # upper arm and forearm taken one joint high, which a hand of one bone or none
            # (SMPL's, a game rig's) makes look nearer a person's proportions than the arm
            # itself. A joint lower down hangs at the end of a bone of the arm (the collar),
            # so it is no collar's root, and the hips' gap says nothing of it: a heavy figure's
            # hip joints, or a rest standing legs apart, may lie wider than its shoulders.
            first = chain[1]
            wide = [
                option
                for option in limbs
                if not self.same_place(option[1][kind.parts[0]], chain[0])
                and (
                    option[1][kind.parts[0]] != first
                    or self.off_midline(first) >= self.hip_half_gap
                )
            ]
            limbs = wide or limbs
        limbs.sort(key=lambda option: option[0])  # stable: the first on ties
        if seen is not None:
            seen.extend(limbs)
        # Where the fingers branch is the hand's own structure, the other ends only a count
        # of joints from the chain's end: a branching wrist stands unless another end's
        # proportions are clearly nearer a person's (a twist bone may branch, too).
        branching = [
            option
            for option in limbs
            if option[1].how[kind.parts[2]].startswith((_FINGERS_BRANCH, _ONE_CHAIN))
        ]
        if branching and branching[0][0] <= limbs[0][0] + _PROPORTION_MARGIN:
            limbs.remove(branching[0])
            limbs.insert(0, branching[0])
        best = limbs[0][1]
        if len(limbs) > 1 and self.motion() and self.limb_bends(chain, best, kind):
            for _, limb in limbs[1:]:
                whole = self.far_from_trunk(tuple(limb[p] for p in kind.parts), kind, chain[0])
                if whole is None and not self.limb_bends(chain, limb, kind):
                    return limb
        return best

    def limb_bends(self, chain: list[int], limb: _Limb, kind: _LimbKind) -> bool:
        """Whether a joint inside the limb's upper or lower part turns in the clip (an end
        on a fingertip bends at the wrist, a wrist on a finger at the knuckles)."""
        top, middle, end = (chain.index(limb[part]) for part in kind.parts)
        return self.bends(chain, top, middle) or self.bends(chain, middle, end)

    def limb_proportions(self, limb: _Limb, kind: _LimbKind) -> float:
        """How far a limb's upper : lower : end part lengths (along the bones; the end part
        is the longest path beyond the limb's end: hand, foot) are from a person's, as the
        sum of ``|log|`` of each ratio's error; an end part with no bones costs as much as
        one twice too long or too short, and so, at most, does a hand too short on an arm
        where nothing branches (a hand drawn in part)."""
        path = self.tree.path
        top, middle, end = (limb[part] for part in kind.parts)
        upper = path[middle] - path[top]
        lower = max(path[end] - path[middle], 1e-12)
        beyond = self.tree.reach[end]
        cost = abs(math.log(max(upper, 1e-12) / lower / kind.upper))
        if beyond > 0:
            off = math.log(beyond / lower / kind.beyond)  # < 0: shorter than a person's
            if off < 0 and kind is _ARM and not _branches_below(self.tree, top):
                # A hand shorter than a person's, on an arm where no fingers branch, is a
                # hand drawn in part (SMPL's hand joint, a game rig's short hand bone, one
                # finger joint kept): no worse a sign than no hand, so it costs at most as
                # much. (Where fingers branch, the hand's structure shows the wrist.)
                return cost + min(-off, math.log(2.0))
            return cost + abs(off)
        return cost + math.log(2.0)

    def doubles_back(self, chain: list[int], i: int) -> bool:
        """Whether the leaf ``chain[i]`` turns back up (within 45 degrees of the spine's
        direction) from a bone that came down: a toe tip points forward, so such an end
        point (a writer's fixed End Site offset on a foot that points down in the rest pose)
        is not where the foot goes, however little it rises."""
        if i < 2 or self.tree.children[chain[i]]:
            return False
        step = self.pose[chain[i]] - self.pose[chain[i - 1]]
        came = self.pose[chain[i - 1]] - self.pose[chain[i - 2]]
        up = self.body.up
        return float(step @ up) > _EFFECTOR_COS * _length(step) and float(came @ up) < 0

    def best_ankle(self, chain: list[int], ankles: list[tuple[int, str]]) -> _Limb:
        """The leg along ``chain`` ending at the best of ``ankles`` (:meth:`best_limb`); a
        joint above the turn of the foot (the last of two geometric choices) only when its
        leg's proportions are clearly nearer a person's (:data:`_PROPORTION_MARGIN`)."""
        if len(ankles) != 2 or not ankles[1][1].startswith("geometry: above the ball"):
            return self.best_limb(chain, ankles, _LEG)
        options = []
        for ankle in ankles:
            try:
                limb = self.best_limb(chain, [ankle], _LEG)
            except _NotHumanoid:
                continue
            options.append((self.limb_proportions(limb, _LEG), limb))
        if not options:
            return self.best_limb(chain, ankles[:1], _LEG)  # the turn's own reason
        if len(options) == 2 and options[1][0] < options[0][0] - _PROPORTION_MARGIN:
            return options[1][1]
        return options[0][1]

    def turned_leg(
        self, chain: list[int], turned: int | None, ankles: list[tuple[int, str]]
    ) -> _Limb:
        """The leg along ``chain`` ending at the best of ``ankles`` (:meth:`best_ankle`),
        unless they are where the foot turns forward and that reading puts the leg's hip at
        or above where the two legs part, while reading the leg as a foot that never turns
        (its last joints) gives it a hip of its own.

        A leg with no foot bones (it ends at the ankle: an End Site there, or a tool's
        invented tails dropped) has no turn towards the toes; a knee bent so that the shin
        lies more level than an upright thigh (kneeling, a crouch with the shin swung back)
        then turns as an ankle does. Read as the ankle, that knee puts the knee at the
        thigh's top and the hip one joint above it, at the joint both legs hang from. Two
        legs never share their hip: the turn was the knee's bend. (A turn whose reading
        finds no knee at all keeps its reason: a creature's chains turn anywhere, and that
        alone says nothing of a knee taken for an ankle.)"""
        limb = self.best_ankle(chain, ankles)
        if turned is None or ankles[0][1] != _TURNS_FORWARD or self.own_hip(limb):
            return limb
        try:
            level: _Limb | None = self.best_ankle(chain, self.ankles(chain, None, []))
        except _NotHumanoid:
            level = None
        if level is not None and self.own_hip(level):
            level.how["ankle"] += (
                f" (the turn at {self.tree.names[chain[turned]]!r} is a knee's bend: "
                "no foot turns on this leg)"
            )
            return level
        return limb

    def own_hip(self, limb: _Limb) -> bool:
        """Whether the leg ``limb``'s hip lies below where the two legs' chains part (two
        legs never share their hip: :meth:`turned_leg`, and the mapper's check of both)."""
        fork = self.tree.lca(*self.body.feet)
        return limb["hip"] != fork and self.tree.is_ancestor(fork, limb["hip"])

    def ankles(
        self, chain: list[int], turned: int | None, named_ankles: list[int]
    ) -> list[tuple[int, str]]:
        """The ankle choices on the leg's ``chain`` (pelvis to sole; ``turned``: index where
        the foot turns forward, if it does; ``named_ankles``: indices of joints named as
        the ankle), each with how it was found, for :meth:`best_ankle`."""
        tree = self.tree
        near = [i for i in named_ankles if turned is not None and abs(i - turned) <= 1]
        if turned is not None and near:
            ankles = [(chain[min(near, key=lambda i: (abs(i - turned), i))], "name")]
        elif turned is None and named_ankles:
            named = min(named_ankles, key=lambda i: (tree.hints[chain[i]].parts["ankle"], i))
            ankles = [(chain[named], "name")]
        elif turned is not None:
            ankles = [
                (
                    self.deepest_coincident(chain[turned], chain),
                    _TURNS_FORWARD,
                )
            ]
            # A foot that points down in the rest pose (a Blender A-pose, feet extended)
            # turns forward only at the ball, where the toes start: the joint above the turn
            # is then the ankle, when the leg's proportions say so clearly.
            above = next(
                (
                    i
                    for i in range(turned - 1, 0, -1)
                    if not self.same_place(chain[i], chain[turned])
                ),
                None,
            )
            if above is not None:
                ankles.append(
                    (
                        self.deepest_coincident(chain[above], chain),
                        "geometry: above the ball of a foot pointing down",
                    )
                )
        else:
            # The foot never turns in this pose (it points down, or there is none): the leg's
            # last joints, the one whose thigh, shin and foot come nearest human proportions.
            last = len(chain) - 1
            while last > 1 and (
                tree.skeleton.end_site[chain[last]] or tree.lengths[chain[last]] == 0
            ):
                last -= 1
            ankles = [
                (
                    self.deepest_coincident(chain[i], chain),
                    "structure: the leg's last joint"
                    if i == last
                    else "geometry: above the foot's bones",
                )
                for i in range(last, max(last - 3, 0), -1)
            ]
            # A leg with no foot bones ends at the ankle itself (an End Site: the 3-joint
            # legs of pose generators), as an arm may end at the wrist. Its last bone is then
            # the shin, longer than any person's foot could be for the bone above it (a foot
            # pointing down is shorter: ankle to toe tip 0.62 of the shin); offered last, so
            # the proportions take it only where it makes the nearer person.
            end = chain[-1]
            if (
                last == len(chain) - 2
                and tree.skeleton.end_site[end]
                and tree.lengths[end] > _FOOT_TO_SHIN * tree.lengths[chain[last]] > 0
            ):
                ankles.append((end, "structure: the leg's end, no foot"))
        return ankles

    def map_leg(self, foot: int) -> _Limb:
        """The leg ending at the leaf ``foot``, or beside it where that foot is a heel
        (:meth:`forward_foot`)."""
        return self.forward_foot(self.leg_to(foot), foot)

    def leg_to(self, foot: int) -> _Limb:
        tree, pose, up = self.tree, self.pose, self.body.up
        chain = tree.chain(self.body.pelvis, foot)
        # The sole: points after the lowest one that rise again are end sites pointing
        # nowhere in particular (SMPL exports), not the foot.
        heights = pose[chain] @ up
        sole = len(chain) - 1
        while sole > 1 and (
            heights[sole] > heights.min() + 0.03 * self.extent or self.doubles_back(chain, sole)
        ):
            sole -= 1
        foot = chain[sole]
        chain = chain[: sole + 1]
        # Ankle: where the chain, having come down the leg, turns most towards the toes.
        turned: int | None = None
        best_turn = np.radians(_ANKLE_TURN_DEG)
        previous = 0
        for i in range(1, len(chain) - 1):
            incoming = _unit(pose[chain[i]] - pose[chain[previous]])
            if not _length(incoming):
                continue
            previous = i
            outgoing = _unit(pose[foot] - pose[chain[i]])
            # Coming down the leg, leaving more level than it came.
            if float(incoming @ up) > -0.5 or float(outgoing @ up) < float(incoming @ up) + 0.2:
                continue
            turn = float(np.arccos(np.clip(incoming @ outgoing, -1.0, 1.0)))
            if turn > best_turn:
                turned, best_turn = i, turn
        # Names choose among the joints next to the geometric ankle (``foot`` is the ankle in
        # most rigs and the ball of the foot in some), or alone when the foot never turns.
        named_ankles = [i for i, j in enumerate(chain) if i > 0 and "ankle" in tree.hints[j].parts]
        by_name = self.ankles(chain, turned, named_ankles)
        # Names along the leg that make no person's leg (shifted one joint down it) name no
        # ankle either: the structure finds it, the names standing only where it finds none.
        wrong = None
        if by_name[0][1] == "name":
            wrong = self.misnamed_end(chain, by_name[0][0], _LEG)
        limb: _Limb | None = None
        if wrong is not None:
            try:
                limb = self.best_ankle(chain, self.ankles(chain, turned, []))
            except _NotHumanoid:
                limb = None
            if limb is not None and self.no_person(*self.joints(limb, _LEG), _LEG) is None:
                limb.how["ankle"] += f" ({NAMES_NOT_FOLLOWED}: {wrong})"
            else:
                limb = None
        if limb is None:
            limb = self.turned_leg(chain, turned, by_name)
        ankle = limb["ankle"]
        ankle_i = chain.index(ankle)
        result, how = limb.joints, limb.how

        below = chain[ankle_i + 1 :]
        near = _AT_ANKLE * _length(pose[ankle] - pose[result["knee"]])
        toe_joint = next(
            (
                j
                for j in below
                if not tree.skeleton.end_site[j]
                and not self.same_place(j, ankle)
                and _length(pose[j] - pose[ankle]) > near
            ),
            None,
        )
        forward = pose[foot] - pose[ankle]
        forward = _unit(forward - (forward @ up) * up)
        if toe_joint is not None:
            tip = self.effector(toe_joint, along=forward if _length(forward) else None)
            if tip is None:
                # A foot pointing down (a frame at toe-off, a rest pose with feet extended):
                # the toe tip continues the foot's own line, ankle to toe joint.
                tip = self.effector(toe_joint, along=_unit(pose[toe_joint] - pose[ankle]))
            if tip is not None:
                result["toe"], how["toe"] = tip, "end effector beyond the toe joint"
            else:
                result["toe"], how["toe"] = toe_joint, "structure: first joint past the ankle"
        else:
            result["toe"] = _farthest_descendant(tree, ankle)
            how["toe"] = "derived: farthest point beyond the ankle"
        return _Limb(result, how)
