"""Which leaves are head, hands and feet: the choices the tree allows (kept per skeleton)
and the ones a pose shows as a standing humanoid."""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from app.motion.mapping.canonical import SkeletonMap
from app.motion.mapping.tree import _BUNDLE, COINCIDENT, _extremity_candidates, _Tree
from app.motion.mapping.vectors import _length, _unit

# The shorter limb of a pair is at least this fraction of the longer one's bone path.
_LIMB_PARTNER = 0.6
# Fractions of the pose's extent (its bounding-box diagonal, about body height).
_MIN_LEG = 0.15  # a leg chain is at least this long
_MIN_ARM = 0.15  # an arm chain is at least this long
# A person's arm, collar to fingertip, is about 0.75 of the leg, hip to toe tip, along the
# bones (0.1 + 0.44 against 0.1 + 0.53 + 0.1 of the height, Drillis & Contini); under half,
# the "arms" are face bones or fingers and the "legs" arms.
_ARM_TO_LEG = 0.5
# Feet lie below the pelvis by at least this fraction of the leg chain's length.
_LEG_DROP_RATIO = 0.5
# ...but when a person stands on one leg (read only when no pose shows two feet down: see
# :mod:`.skeleton`), the other foot is lifted (a kick, a knee raised, a flying or fighting
# pose): up to about the height of the hips (a kick level with them points the toes a little
# above the pelvis), not much higher: a foot a quarter of its leg or more above the pelvis
# is a high kick's, a cartwheel's or a handstand's, which one pose does not tell apart.
_LIFTED_FOOT_DROP = -0.25
# cos of the smallest angle between the spine and the legs of a standing biped (120 deg).
_LEGS_OPPOSITE_SPINE = -0.5
# How far :func:`_check_pose` gets with a choice refused as four-legged.
_FOUR_LEGGED = 3
# cos of the widest angle between one of four legs an animal stands on and their mean.
_ONE_WAY = 0.5


class _NotHumanoid(Exception):
    """Why one pose does not show a humanoid (turned into SkeletonMappingError at the end)."""


# A structurally valid choice: (head, hands, feet, chest, pelvis, leg and arm lengths along
# the bones, cost terms from the names in the order they are added).
_Choice = tuple[
    int, tuple[int, int], tuple[int, int], int, int, list[float], list[float], tuple[float, ...]
]


@dataclass
class _Known:
    """What one skeleton's structure decides, whatever the pose: kept per skeleton."""

    tree: _Tree
    candidates: list[int]
    # Head/hands/feet choices that pass the structural checks, in the order they are tried.
    choices: list[_Choice]
    # Why the other choices fail, and how far the best got, for the message when no choice
    # passes the geometry.
    reason: str
    progress: int
    rest: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    rest_result: SkeletonMap | str = ""


@dataclass
class _Body:
    """One hypothesis: which leaves are head, hands and feet, and what follows from it."""

    head: int
    hands: tuple[int, int]
    feet: tuple[int, int]
    chest: int
    pelvis: int
    up: np.ndarray
    cost: float
    # The foot a body standing on one leg lifts (a leaf of ``feet``), else None.
    lifted: int | None = None


def _structure(tree: _Tree, count: int) -> _Known:
    """Every head/hands/feet choice among up to ``count`` candidate leaves that the tree
    allows, and the best reason a rejected one gave (for the error message)."""
    candidates = _extremity_candidates(tree, count)
    found = ", ".join(tree.names[c] for c in candidates)
    if len(candidates) < 5:
        reason = (
            f"found only {len(candidates)} limb ends ({found}) where a body has five (head, "
            "two hands, two feet): missing legs, arms or head"
        )
    else:
        reason = (
            f"found {len(candidates)} limb ends ({found}) but missing a pelvis with two legs "
            "going down and a spine going up to a head between two arms"
        )
    # Enumerated by hands first, so that a pair whose branch point carries no head, or the
    # feet below it, cuts every choice with them at once; kept in the order of the plain
    # enumeration (five candidates, a head among them, two feet among the rest), which
    # breaks ties between equally cheap choices.
    order = {c: i for i, c in enumerate(candidates)}
    keyed: list[tuple[tuple[int, ...], _Choice]] = []
    alike_failed = False
    headless: int | None = None  # a branch point of two arms, legs below, and no head
    for hands in itertools.combinations(candidates, 2):
        chest = tree.lca(*hands)
        if chest in hands:
            continue
        others = [c for c in candidates if c not in hands]
        # The neck leaves the trunk at the arms' branch point, apart from both arms: a leaf
        # on an arm's own chain (a finger of that hand) is no head.
        heads = [
            h
            for h in others
            if h != chest
            and tree.is_ancestor(chest, h)
            and all(tree.lca(h, hand) == chest for hand in hands)
        ]
        if not heads:
            # The shoulders on a bone of their own beside the neck: the head leaves the
            # spine at the joint that carries that bone (the bone's other branch), which is
            # then the chest.
            top = _girdle_top(tree, chest, hands, candidates)
            if top is not None:
                heads = [
                    h for h in others if tree.is_ancestor(top, h) and not tree.is_ancestor(chest, h)
                ]
                if heads:
                    chest = top
        lower = [c for c in others if not tree.is_ancestor(chest, c)]
        if not heads:
            if headless is None and _two_legs_below(tree, chest, hands, lower):
                headless = chest
            continue
        for feet in itertools.combinations(lower, 2):
            hips = tree.lca(*feet)
            if hips in feet:
                continue
            if not _pairs_alike(tree, chest, hands, hips, feet):
                alike_failed = True
                continue
            for head in heads:
                five = sorted((head, *hands, *feet), key=order.__getitem__)
                rest = [c for c in five if c != head]
                key = (
                    *(order[c] for c in five),
                    five.index(head),
                    rest.index(feet[0]),
                    rest.index(feet[1]),
                )
                keyed.append((key, _choice(tree, head, hands, feet, chest, hips)))
    choices = [choice for _, choice in sorted(keyed, key=lambda item: item[0])]
    best_partial = -1
    if alike_failed:
        best_partial, reason = 1, _NOT_ALIKE
    elif headless is not None and not choices:
        best_partial = 1
        reason = (
            "no head: nothing but the two arms leaves the joint where they branch off "
            f"({tree.names[headless]}): missing head"
        )
    else:
        first = _first_misfit(tree, candidates)
        if first is not None:
            best_partial, reason = 0, first
    return _Known(tree, candidates, choices, reason, best_partial)


_NOT_ALIKE = "no two limbs of a pair alike: missing legs or arms"


def _girdle_top(
    tree: _Tree, branch: int, hands: tuple[int, int], candidates: list[int]
) -> int | None:
    """The spine joint carrying the shoulders' own bone, where the two arms ``hands`` part
    at ``branch`` and nothing else leaves it (a few rigs hang their collars from a joint
    beside the neck's): the first joint above ``branch`` where the tree branches, if the
    bones from it to ``branch`` are shorter than either arm below ``branch`` and the limb
    ends (``candidates``) below it lie on two branches only, the shoulders' and the
    neck's; else None (the chain above two fingers of one hand is the arm itself, longer
    than they are; a hand's joint carries several fingers)."""
    top = int(tree.parents[branch])
    while top >= 0 and len(tree.children[top]) < 2:
        top = int(tree.parents[top])
    if top < 0:
        return None
    arms = min(tree.path[h] - tree.path[branch] for h in hands)
    if tree.path[branch] - tree.path[top] >= arms:
        return None
    below = {tree.chain(top, c)[1] for c in candidates if c != top and tree.is_ancestor(top, c)}
    return top if len(below) == 2 else None


def _two_legs_below(tree: _Tree, chest: int, hands: tuple[int, int], lower: list[int]) -> bool:
    """Whether two of the limb ends ``lower`` (not below ``chest``) make a pair of legs with
    the arms ``hands`` as the tree allows (their own hips, limbs alike) and as a person's
    proportions do (arms at least :data:`_ARM_TO_LEG` of the legs: two fingers of one hand
    are no arms)."""
    arms = min(tree.path[h] - tree.path[chest] for h in hands)
    for feet in itertools.combinations(lower, 2):
        hips = tree.lca(*feet)
        pelvis = tree.lca(hips, chest)
        legs = max(tree.path[f] - tree.path[pelvis] for f in feet)
        if (
            hips not in feet
            and arms >= _ARM_TO_LEG * legs
            and _pairs_alike(tree, chest, hands, hips, feet)
        ):
            return True
    return False


def _first_misfit(tree: _Tree, candidates: list[int]) -> str | None:
    """Why the first choice (in the plain enumeration) that the tree refuses is refused; or,
    where every limb end leaves one joint by a branch of its own (a lone hand's fingers), that
    (a body's ends part at two joints: the legs at the hips, the arms and head at the chest)."""
    if len(candidates) >= 5:
        fork = candidates[0]
        for end in candidates[1:]:
            fork = tree.lca(fork, end)
        branches = {tree.chain(fork, end)[1] for end in candidates if end != fork}
        if fork not in candidates and len(branches) == len(candidates):
            return (
                f"every limb end leaves one joint ({tree.names[fork]}) by a branch of its own "
                "(as a hand's fingers do), where a body's legs part from its arms and head at "
                "two joints"
            )
    for five in itertools.combinations(candidates, 5):
        for head in five:
            rest = [c for c in five if c != head]
            for feet in itertools.combinations(rest, 2):
                hands = tuple(c for c in rest if c not in feet)
                chest = tree.lca(*hands)
                if chest in hands or not tree.is_ancestor(chest, head) or head == chest:
                    return "no joint carries two arms and a head"
                if any(tree.is_ancestor(chest, f) for f in feet):
                    return "the legs hang from the arms' branch point"
                hips = tree.lca(*feet)
                if hips in feet:
                    return "one leg hangs from the other"
                if not _pairs_alike(tree, chest, hands, hips, feet):  # type: ignore[arg-type]
                    return _NOT_ALIKE
                if any(tree.lca(head, hand) != chest for hand in hands):
                    return "the head hangs from an arm"
    return None


def _pairs_alike(
    tree: _Tree, chest: int, hands: tuple[int, int], hips: int, feet: tuple[int, int]
) -> bool:
    """A limb has at least two bones of its own (thigh and shin, upper arm and forearm) and
    its partner is about as long: not a twist bone beside the other leg's knee."""
    for top, ends in ((hips, feet), (chest, hands)):
        own = [tree.bones[e] - tree.bones[top] for e in ends]
        reach = [tree.path[e] - tree.path[top] for e in ends]
        if min(own) < 2 or min(reach) < _LIMB_PARTNER * max(reach):
            return False
    return True


def _choice(
    tree: _Tree,
    head: int,
    hands: tuple[int, int],
    feet: tuple[int, int],
    chest: int,
    hips: int,
) -> _Choice:
    """A structurally valid choice with its lengths and name costs (see :data:`_Choice`)."""
    pelvis = tree.lca(hips, chest)
    leg_lengths = [float(tree.path[f] - tree.path[pelvis]) for f in feet]
    arm_lengths = [float(tree.path[h] - tree.path[chest]) for h in hands]
    cost: list[float] = []
    roles: list[tuple[str, tuple[int, ...], int]] = [
        ("arm", hands, chest),
        ("leg", feet, pelvis),
        ("head", (head,), chest),
    ]
    for role, ends, top in roles:
        for end in ends:
            words = tree.words_below(top, end)
            if words and role not in words:
                cost.append(3.0)
            elif role in words:
                cost.append(-0.5)
    return (head, hands, feet, chest, pelvis, leg_lengths, arm_lengths, tuple(cost))


def _hypotheses(
    known: _Known, pose: np.ndarray, extent: float, lifted: bool = False
) -> tuple[list[_Body], str]:
    """Every valid head/hands/feet choice in ``pose``, and the best reason a rejected one
    gave (for the error message); ``lifted``: one foot may be lifted (see
    :data:`_LIFTED_FOOT_DROP`)."""
    valid: list[_Body] = []
    reason, best_partial = known.reason, known.progress
    # The choices share heads, chests, pelvises and feet: what the pose says of each is read
    # once for all of them.
    facts = _PoseFacts(pose, extent, known.tree)
    four_legged: list[tuple[_Choice, str]] = []
    for choice in known.choices:
        body, why, progress = _check_pose(
            known.tree, pose, extent, *choice, lifted=lifted, facts=facts
        )
        if body is not None:
            valid.append(body)
        else:
            if _animal(pose, choice, progress):
                four_legged.append((choice, why))
            elif progress == _FOUR_LEGGED:
                # Limbs that point every way are no animal's stance: say what failed.
                why = (
                    "the legs do not reach down from the pelvis away from the spine "
                    f"({known.tree.limb_names((*choice[2], *choice[1]))}): no upright body"
                )
            if progress > best_partial:
                best_partial, reason = progress, why
    if four_legged and best_partial == _FOUR_LEGGED:
        reason = four_legged[0][1]  # an animal's stance, where one choice shows it
    if four_legged and valid:
        overruled = [_on_shorter_limbs(known.tree, b, four_legged) for b in valid]
        kept = [b for b, why in zip(valid, overruled, strict=True) if why is None]
        if not kept:
            reason = overruled[0] or reason
        valid = kept
    return valid, reason


def _four_legged_choices(
    known: _Known, pose: np.ndarray, extent: float
) -> list[tuple[_Choice, str]]:
    """The choices ``pose`` shows as a four-legged animal (the spine level, the limbs
    hanging down), each with that reason."""
    facts = _PoseFacts(pose, extent, known.tree)
    found = []
    for choice in known.choices:
        _, why, progress = _check_pose(known.tree, pose, extent, *choice, facts=facts)
        if _animal(pose, choice, progress):
            found.append((choice, why))
    return found


def _animal(pose: np.ndarray, choice: _Choice, progress: int) -> bool:
    """Whether ``choice``, refused in ``pose`` (``(J, 3)``) after ``progress`` steps of
    :func:`_check_pose`, was refused as four-legged with its four limbs (legs from the
    pelvis, arms from the chest) all hanging one way, each within 60 degrees of their mean,
    as an animal's four legs stand (props or IK chains pointing anywhere do not)."""
    if progress != _FOUR_LEGGED:
        return False
    _, hands, feet, chest, pelvis = choice[:5]
    ways = np.array(
        [_unit(pose[f] - pose[pelvis]) for f in feet]
        + [_unit(pose[h] - pose[chest]) for h in hands]
    )
    mean = _unit(ways.sum(axis=0))
    return bool(_length(mean) > 0 and (ways @ mean > _ONE_WAY).all())


def _on_shorter_limbs(
    tree: _Tree, body: _Body, four_legged: list[tuple[_Choice, str]]
) -> str | None:
    """The four-legged reason that overrules ``body``, else None. A person stands on the
    longest limbs hanging from the pelvis; where a choice from the same pelvis, on legs that
    do not hang from the chest and are both longer than either leg of ``body``, is read as
    four-legged (the spine level, those limbs hanging down), ``body`` stands on shorter
    chains (two tails pointing back from an animal's hips pass for legs opposite its level
    spine): the animal reading wins. Copies of the legs are as long, not longer, and do not
    overrule this way. The reason named is that of the likeliest animal (:func:`pair_cost`)."""
    legs = max(tree.path[f] - tree.path[body.pelvis] for f in body.feet)
    against = [
        (pair_cost(choice[5], choice[6], choice[7]), why)
        for choice, why in four_legged
        if choice[4] == body.pelvis
        and not any(tree.is_ancestor(body.chest, f) for f in choice[2])
        and min(choice[5]) > legs
    ]
    return min(against)[1] if against else None


class _PoseFacts:
    """What one ``(J, 3)`` pose says of the parts the choices share (a trunk's up, a foot's
    drop, a pair of legs' direction), each computed on first use, with the arithmetic
    :func:`_check_pose` does for a single choice (so the same bits), and kept for the next
    choice with the same parts."""

    def __init__(self, pose: np.ndarray, extent: float, tree: _Tree) -> None:
        self.pose = pose
        self.extent = extent
        self.tree = tree
        # (head, chest, pelvis) -> (up, it has a length, the head's top above the chest,
        # above the pelvis).
        self._trunks: dict[tuple[int, int, int], tuple[np.ndarray, bool, float, float]] = {}
        self._drops: dict[tuple[int, int, int, int], float] = {}  # (trunk, foot) -> drop
        self._legs: dict[tuple[int, int], np.ndarray] = {}  # (pelvis, foot) -> unit leg
        self._legs_up: dict[tuple[int, int, int, int, int], float] = {}  # (trunk, feet) -> cos

    def trunk(self, head: int, chest: int, pelvis: int) -> tuple[np.ndarray, bool, float, float]:
        """The trunk's ``(3,)`` up (:func:`trunk_up`), whether it has a length, and how far
        the head's top is above the chest and above the pelvis along it.

        The head's top is :func:`head_top`."""
        key = (head, chest, pelvis)
        found = self._trunks.get(key)
        if found is None:
            pose = self.pose
            up = trunk_up(self.tree, pose, self.extent, head, chest, pelvis)
            up.setflags(write=False)  # shared by the bodies of every choice with this trunk
            top = head_top(self.tree, pose, head, chest, up)
            found = self._trunks[key] = (
                up,
                _length(up) > 0,
                float((pose[top] - pose[chest]) @ up),
                float((pose[top] - pose[pelvis]) @ up),
            )
        return found

    def drop(self, head: int, chest: int, pelvis: int, foot: int, up: np.ndarray) -> float:
        """How far ``foot`` is below the pelvis along the trunk's ``up``."""
        key = (head, chest, pelvis, foot)
        found = self._drops.get(key)
        if found is None:
            found = self._drops[key] = float((self.pose[pelvis] - self.pose[foot]) @ up)
        return found

    def legs_up(
        self, head: int, chest: int, pelvis: int, feet: tuple[int, int], up: np.ndarray
    ) -> float:
        """cos of the angle between the two legs' mean direction and the trunk's ``up``."""
        key = (head, chest, pelvis, *feet)
        found = self._legs_up.get(key)
        if found is None:
            legs = [self._leg(pelvis, f) for f in feet]
            found = self._legs_up[key] = float(_unit(legs[0] + legs[1]) @ up)
        return found

    def _leg(self, pelvis: int, foot: int) -> np.ndarray:
        key = (pelvis, foot)
        found = self._legs.get(key)
        if found is None:
            found = self._legs[key] = _unit(self.pose[foot] - self.pose[pelvis])
        return found


def head_top(tree: _Tree, pose: np.ndarray, head: int, chest: int, up: np.ndarray) -> int:
    """The top of the head: the ``head`` leaf, or a joint between it and ``chest`` that
    more than a pair of branches hang from (:data:`_BUNDLE`: a skull with its strands of
    hair, its eyes and jaw) where that joint is higher along ``up`` in ``pose``. A strand
    taken for the head's leaf ends below the skull, which is still the top of the body; a
    joint with one or two branches (a shoulder, its twist bone) is no skull."""
    skulls = [j for j in tree.chain(chest, head)[1:-1] if len(tree.children[j]) >= _BUNDLE]
    return max([head, *skulls], key=lambda j: float(pose[j] @ up))


def trunk_up(
    tree: _Tree, pose: np.ndarray, extent: float, head: int, chest: int, pelvis: int
) -> np.ndarray:
    """``(3,)`` the unit direction pelvis -> chest in ``pose`` (pelvis -> head when the two
    coincide); of zero length when the trunk has none.

    Where the chest joint (the arms' branch point) sits where the legs leave the pelvis (at
    the place of another branch of the pelvis), the trunk runs on to the neck's first joint:
    a rig whose spine is one bone from the hips to the neck and whose arms' first bones are
    as long (a sign-language tool's skeleton) branches its arms at the hips, and the pelvis
    -> chest line there is the pelvis's own offset to the hips, which no pose turns."""
    spine = pose[chest] - pose[pelvis]
    if head != chest and tree.parents[chest] == pelvis:
        hips = [c for c in tree.children[pelvis] if c != chest]
        at_hips = any(_length(pose[c] - pose[chest]) <= COINCIDENT * extent for c in hips)
        if at_hips:
            spine = pose[tree.chain(chest, head)[1]] - pose[pelvis]
    if _length(spine) < COINCIDENT * extent:
        spine = pose[head] - pose[pelvis]
    return _unit(spine)


def pair_cost(
    leg_lengths: list[float], arm_lengths: list[float], name_cost: tuple[float, ...]
) -> float:
    """A choice's cost before the pose's own terms: how unlike its two legs and its two arms
    are, plus what the names say (added one by one, as the names were read)."""
    cost = abs(leg_lengths[0] - leg_lengths[1]) / max(leg_lengths) + abs(
        arm_lengths[0] - arm_lengths[1]
    ) / max(arm_lengths)
    for term in name_cost:
        cost += term
    return cost


def _check_pose(
    tree: _Tree,
    pose: np.ndarray,
    extent: float,
    head: int,
    hands: tuple[int, int],
    feet: tuple[int, int],
    chest: int,
    pelvis: int,
    leg_lengths: list[float],
    arm_lengths: list[float],
    name_cost: tuple[float, ...],
    *,
    lifted: bool = False,
    facts: _PoseFacts | None = None,
) -> tuple[_Body | None, str, int]:
    """The geometric half: a hypothesis if the choice is a humanoid in ``pose``, else (None,
    why, how far it got); ``lifted``: the body may stand on one foot, the other lifted up to
    about the height of the hips (:data:`_LIFTED_FOOT_DROP`); ``facts``: what ``pose`` says
    of the parts, kept across the choices of one pose."""
    if facts is None:
        facts = _PoseFacts(pose, extent, tree)
    up, has_length, head_over_chest, head_height = facts.trunk(head, chest, pelvis)
    if not has_length:
        return None, "the spine has no length", 1
    if min(leg_lengths) < _MIN_LEG * extent:
        return None, "no two legs reach down from the pelvis: missing legs", 2
    if facts.legs_up(head, chest, pelvis, feet, up) > _LEGS_OPPOSITE_SPINE:
        names = tree.limb_names((*feet, *hands))
        return (
            None,
            "the spine is horizontal with the limbs hanging down "
            f"({names}): a four-legged animal, not a humanoid",
            _FOUR_LEGGED,
        )
    ratios = [
        facts.drop(head, chest, pelvis, f, up) / length
        for f, length in zip(feet, leg_lengths, strict=True)
    ]
    lower, higher = sorted(ratios)
    if higher < _LEG_DROP_RATIO or lower < (_LIFTED_FOOT_DROP if lifted else _LEG_DROP_RATIO):
        if lower <= 0:  # a limb ending above the pelvis is no leg at all
            return None, "no two legs reach down from the pelvis: missing legs", 2
        # Two limbs below the pelvis that fall short: which, and how far they reach, so that
        # a user whose figure has legs sees why they were not taken for a person's (a
        # cartoon's short legs under long feet).
        return (
            None,
            "no two legs reach down from the pelvis: missing legs (the limbs ending at "
            f"{tree.limb_names(feet)} reach down {ratios[0]:.3f} and {ratios[1]:.3f} of "
            f"their length; a leg at least {_LEG_DROP_RATIO:g})",
            2,
        )
    if head_over_chest <= 0:
        return None, "no head above the arms: missing head", 2
    shoulders = tree.lca(*hands)
    if shoulders != chest and float((pose[head] - pose[shoulders]) @ up) <= 0:
        # The shoulders on a bone of their own (:func:`_girdle_top`): the head still rises
        # above them, whichever spine joint its neck leaves (a tail from the back does not).
        return None, "no head above the arms: missing head", 2
    if min(arm_lengths) < _MIN_ARM * extent:
        return None, "no two arms branch off the spine: missing arms", 2
    cost = pair_cost(leg_lengths, arm_lengths, name_cost)
    # Prefer the highest head and the longest limbs among otherwise equal choices (a leaf at
    # the knee is a marker joint, not the foot).
    cost -= 0.1 * head_height / extent
    cost -= 0.5 * (sum(leg_lengths) + sum(arm_lengths)) / extent
    # A foot short of the standing drop (allowed only with ``lifted``) is the lifted one.
    raised = feet[int(np.argmin(ratios))] if lower < _LEG_DROP_RATIO else None
    return _Body(head, hands, feet, chest, pelvis, up, cost, raised), "", 4
