"""Arms: the wrist (by name, where the fingers part, where a hand of one chain starts, or
the arm's end), the arm along its chain, and the two arms made a pair."""

from __future__ import annotations

import math

from app.motion.mapping.hypotheses import _NotHumanoid
from app.motion.mapping.limbs import _ALIKE, _FINGERS_BRANCH, _ONE_CHAIN, _LimbRules
from app.motion.mapping.named import NAMES_NOT_FOLLOWED
from app.motion.mapping.runs import _ARM, _LimbKind
from app.motion.mapping.state import _Limb
from app.motion.mapping.tree import _farthest_descendant, _is_thumb

# Bones from the arms' branch point to the wrist, at least: upper arm, forearm and the first
# bone off the spine (a collar, or the upper arm itself).
_WRIST_DEPTH = 3


class _ArmRules(_LimbRules):
    """Places the joints of the arms."""

    def map_arm(self, hand: int) -> _Limb:
        tree = self.tree
        # From where the two arms part: the chest, or the shoulders' own bone beside it.
        chain = tree.chain(tree.lca(*self.body.hands), hand)
        named_wrist = self.named(chain[1:], "wrist")
        # Names along the arm that make no person's arm (shifted one joint down it) name no
        # wrist either: the hand's structure finds it, the names standing only where it
        # finds none.
        wrong = None if named_wrist is None else self.misnamed_end(chain, named_wrist, _ARM)
        wrists: list[tuple[int, str]]
        if named_wrist is not None and wrong is None:
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
        try:
            limb = self.best_limb(chain, wrists, _ARM, options)
            if wrong is not None:
                if self.no_person(*self.joints(limb, _ARM), _ARM):
                    raise _NotHumanoid(wrong)
                limb.how["wrist"] += f" ({NAMES_NOT_FOLLOWED}: {wrong})"
        except _NotHumanoid:
            if wrong is None or named_wrist is None:
                raise
            # The structure finds no person's arm either: the names stand.
            options.clear()
            limb = self.best_limb(chain, [(named_wrist, "name")], _ARM, options)
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
        """``limb`` (an arm) with its hand tip: the farthest point beyond the wrist no
        farther along the bones than the arm above it (shoulder to wrist). A hand (0.108 of
        the height) is a third of that arm (0.332), a cartoon's big hand up to about 0.7 of
        it: a branch reaching farther is something held (a prop joint, as Xsens MVN writes
        one at the wrist), not the hand."""
        result, how = dict(limb.joints), dict(limb.how)
        path = self.tree.path
        arm = float(path[limb["wrist"]] - path[limb["shoulder"]])
        result["hand_tip"] = _farthest_descendant(
            self.tree, limb["wrist"], skip=_is_thumb, within=arm if arm > 0 else math.inf
        )
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
