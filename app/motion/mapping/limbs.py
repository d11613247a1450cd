"""Legs and arms along their chains: the hip and shoulder, knee and elbow, ankle and wrist,
by the straight runs, the turns and a person's proportions (and the clip's frames where
the rest pose leaves joints in one line)."""

from __future__ import annotations

import math

import numpy as np

from app.motion.mapping.hypotheses import _NotHumanoid
from app.motion.mapping.runs import _ARM, _LEG, _LimbKind, _RunRules
from app.motion.mapping.state import _EFFECTOR_COS, _Limb
from app.motion.mapping.tree import _branches_below, _farthest_descendant, _is_thumb
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
# Bones from the arms' branch point to the wrist, at least: upper arm, forearm and the first
# bone off the spine (a collar, or the upper arm itself).
_WRIST_DEPTH = 3


class _LimbRules(_RunRules):
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
        the frames show which)."""
        parts, ratio, what = kind.parts[:2], kind.upper, kind.what
        top, middle = (self.named(above[1:-1], part) for part in parts)
        if top is not None and middle is not None and above.index(top) < above.index(middle):
            for part, joint in zip(parts, (top, middle), strict=True):
                limb.joints[part], limb.how[part] = joint, "name"
            return
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
        limb.joints[parts[0]] = self.deepest_coincident(above[start], above)
        limb.joints[parts[1]] = self.deepest_coincident(above[split], above)
        limb.how[parts[0]] = f"geometry: top of the straight {what}"
        limb.how[parts[1]] = f"geometry: middle of the {what}"

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

    def map_leg(self, foot: int) -> _Limb:
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
                    "geometry: where the foot turns forward",
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
        limb = self.best_ankle(chain, ankles)
        ankle = limb["ankle"]
        ankle_i = chain.index(ankle)
        result, how = limb.joints, limb.how

        below = chain[ankle_i + 1 :]
        toe_joint = next(
            (j for j in below if not tree.skeleton.end_site[j] and not self.same_place(j, ankle)),
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

    def map_arm(self, hand: int) -> _Limb:
        tree = self.tree
        chain = tree.chain(self.body.chest, hand)
        named_wrist = self.named(chain[1:], "wrist")
        if named_wrist is not None:
            wrists = [(named_wrist, "name")]
        else:
            # Where the fingers branch (the last branching joint first: a twist bone beside
            # the upper arm branches too), the joint before the hand's end, the arm's end (a
            # rig without hand bones, glTF and FBX joints being points without tails): the
            # one whose arm comes nearest human proportions.
            wrists = [
                (j, f"{_FINGERS_BRANCH} branch")
                for j in chain[-2:0:-1]
                if sum(1 for c in tree.children[j] if tree.lengths[c] > 0 or tree.children[c]) >= 2
            ]
            # Fingers may also start from sibling joints at one place (a palm bone per finger).
            wrists += [
                (j, f"{_FINGERS_BRANCH} start together")
                for j in chain[-2:1:-1]
                if tree.children[j]
                and any(
                    s != j and tree.children[s] and self.same_place(s, j)
                    for s in tree.children[int(tree.parents[j])]
                )
            ]
            last = len(chain) - 1
            while last > 1 and tree.lengths[chain[last]] == 0:
                last -= 1
            if not wrists:
                # Nothing branches: the hand (if any) is one chain of bones.
                one_chain = self.one_chain_wrist(chain, last)
                if one_chain is not None:
                    wrists.append((chain[one_chain], _ONE_CHAIN))
            # (Two before it: a hand bone closed by an End Site, as SMPL exports write it.)
            wrists += [
                (chain[i], "structure: the joint before the hand's end")
                for i in range(last - 1, max(last - 3, 1), -1)
            ]
            wrists.append((chain[last], "structure: the arm's end, no hand"))
        options: list[tuple[float, _Limb]] = []
        limb = self.best_limb(chain, wrists, _ARM, options)
        self.arm_options[hand] = (chain, options)
        return self.with_hand_tip(limb)

    def one_chain_wrist(self, chain: list[int], last: int) -> int | None:
        """Index in ``chain`` (the arms' branch point to the hand's end, ``chain[last]``
        its last bone's end) of the wrist of a hand that is one chain of bones (a single
        finger, as some exports keep), or None.

        A hand (wrist to fingertip, 0.108 of the height) is shorter than the upper arm
        (0.186), while forearm and hand together (0.254) are longer than any bone above the
        elbow (upper arm, collar): the wrist is the highest joint at least
        :data:`_WRIST_DEPTH` bones below the branch point whose reach (the chain below it)
        is no longer than the longest bone above its parent, with at least two bones below
        it (a hand of one chain; the joint above a single hand bone, or an arm's end with no
        hand, is no such wrist)."""
        tree = self.tree
        longest = 0.0  # the longest bone above chain[i]'s parent
        bones = 0  # bones of non-zero length from the branch point to chain[i]
        for i in range(1, last - 1):
            bones += bool(tree.lengths[chain[i]] > 0)
            if bones >= _WRIST_DEPTH and 0 < tree.reach[chain[i]] <= longest:
                return i
            longest = max(longest, float(tree.lengths[chain[i]]))
        return None

    def with_hand_tip(self, limb: _Limb) -> _Limb:
        """``limb`` (an arm) with its hand tip: the farthest point beyond the wrist."""
        result, how = dict(limb.joints), dict(limb.how)
        result["hand_tip"] = _farthest_descendant(self.tree, limb["wrist"], skip=_is_thumb)
        how["hand_tip"] = "derived: farthest point beyond the wrist"
        return _Limb(result, how)

    def part_lengths(self, limb: _Limb, kind: _LimbKind) -> tuple[float, float]:
        """The limb's upper and lower part lengths along the bones (thigh and shin, upper
        arm and forearm)."""
        path = self.tree.path
        top, middle, end = (limb[part] for part in kind.parts)
        return float(path[middle] - path[top]), float(path[end] - path[middle])

    def unlike(self, a: _Limb, b: _Limb, kind: _LimbKind) -> float:
        """How far two limbs of a pair are from one length: the largest ``|log|`` ratio of
        their upper and of their lower parts."""
        return max(
            abs(math.log(max(x, 1e-12) / max(y, 1e-12)))
            for x, y in zip(self.part_lengths(a, kind), self.part_lengths(b, kind), strict=True)
        )

    def alike_arms(self, arms: list[_Limb], hands: tuple[int, int]) -> list[_Limb]:
        """The two arms, each found on its own, made a pair: a person's left and right
        upper arms (forearms) are one length, so when the two found differ by more than
        :data:`_ALIKE` and one arm's other choices hold one as long as the arm found on the
        other side (part for part), that one is taken — the cheapest in proportions over the
        pair when several are. An arm found a joint too high on one side (the collar taken for
        the shoulder) or too low (its end on a fingertip) is set right by the other side; two
        arms found alike, or no alike choice, stay as they are."""
        if self.unlike(arms[0], arms[1], _ARM) <= _ALIKE:
            return arms
        best: tuple[float, int, _Limb] | None = None
        for keep in (0, 1):
            other = 1 - keep
            chain, options = self.arm_options[hands[other]]
            kept_cost = self.limb_proportions(arms[keep], _ARM)
            for cost, option in options:
                if option.joints == {p: arms[other][p] for p in _ARM.parts}:
                    continue
                if self.unlike(arms[keep], option, _ARM) > _ALIKE:
                    continue
                if self.motion() and self.limb_bends(chain, option, _ARM):
                    continue  # the frames show a joint inside it: no arm
                if best is None or cost + kept_cost < best[0]:
                    best = (cost + kept_cost, other, option)
        if best is None:
            return arms
        _, other, option = best
        how = {part: f"{option.how[part]} (as long as the other arm)" for part in _ARM.parts}
        paired = list(arms)
        paired[other] = self.with_hand_tip(_Limb(dict(option.joints), how))
        return paired
