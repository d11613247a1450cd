"""Source skeleton -> the canonical joints every descriptor uses, by the body's structure.

A humanoid is a tree with a pelvis from which two legs go down and a spine goes up to the
head, with two arms branching off the upper spine. That shape is visible in a standing pose
(the rest pose of the offsets, or a frame of the motion when the rest pose is not a standing
figure, as in rigs that bake joint orientation into rotations) whatever the up axis, units,
facing, naming or extra joints (fingers, face, twist bones, props, IK targets, dummies).

0. **Points, not joints.** Leaves that add no point (zero-length End Sites, which a BVH
   writer appends to every leaf joint of an FBX or glTF rig) are not seen at all; nor is an
   End Site exactly as long as its bone (a tail Blender invents for a leaf joint).
1. **Extremities.** Leaves at least two bones below the root (thigh and shin, upper arm and
   forearm: a hip may sit at the pelvis itself) and far apart along bones are found
   greedily (the farthest leaf from the ones already chosen, up to :data:`_CANDIDATES`);
   every choice of five of them as head,
   two hands and two feet is checked: the arms' branch point (chest) must carry the head
   and not the feet, the feet must lie well below the pelvis (the branch point of legs and
   spine) along the pelvis->chest direction, and the legs must point opposite the spine
   (a horizontal spine over four limbs is a quadruped). The cheapest valid choice wins;
   costs are left/right chain-length differences and names that contradict a role (an arm
   chain whose joints are called leg names).
2. **Chains.** Along each limb chain: the ankle is where the chain turns forward (the
   rest of the chain drops little for its length; or the joint above that turn when a foot
   pointing down turns only at the ball and the leg's proportions say so clearly; a leaf
   turning back up from a foot coming down is no toe), else named, else the one of the
   leg's last joints nearest human proportions (a foot that points down); the hip and shoulder
   start the straight run ending at the ankle or wrist (or the joint above it when the run
   leaves no room for a middle joint, or the joint at the trunk's own place when hips sit at
   the pelvis); the knee and elbow split that run (a rest-pose bend decides when there is
   one, otherwise the split nearest human proportions); the wrist is named, or else, among
   where the fingers branch (a joint with several, or sibling palm joints at one place), the
   two joints before the hand's end and the arm's last joint (a rig without hand bones), the
   one whose upper arm, forearm and hand come nearest human proportions (where the fingers
   branch standing unless another is clearly nearer, and never a wrist whose arm would not
   make its share of the way from the chest); the ankle likewise
   when the foot does not turn forward; two legs never share their hip, and each limb makes
   most of the way from the trunk to its end (a creature's claws hanging at the end of its
   legs are no person's legs). A game rig whose feet are IK bones under the root (legs
   ending at the knees) is mapped, when nothing else maps, with each foot hung from the knee
   it stays at one distance from while the knee bends (:attr:`SkeletonMap.held`). Names
   whole-matched by :mod:`app.motion.skeleton_names` choose among joints when they name one
   in the chain. Where the rest pose leaves joints in one line to choose among (a collar
   bone in line with a T-posed arm, whose long forearm makes the proportions prefer it; a
   wrist among a straight hand's joints), the clip's frames decide: a bone does not bend,
   so a joint that turns inside the upper or lower part of the chosen limb is a joint of
   the limb (the shoulder below the collar, the wrist above a finger), and the nearest to
   proportions of the choices with no such joint is taken
   (:attr:`SkeletonMap.limbs_open`).
3. **End effectors** (Miura et al.: "end effectors are hereafter regarded as joints"): the
   canonical ``head`` point is the first point of non-zero length on the single chain
   beyond the head joint (an End Site, or a ``HeadTop``-like leaf bone: a BVH converted
   from FBX appends an End Site after that bone, and both files then map the same point)
   when there is one, else the head joint (a leaf *joint* one joint above the arms is
   the head on its neck, not the top of a head sitting on the shoulders: a person has a
   neck); ``toe`` likewise beyond the toe joint (else the toe joint, else the farthest
   point beyond the ankle); ``hand_tip`` is the farthest point
   beyond the wrist, thumbs skipped (the wrist itself on a rig without hand bones).
   :attr:`SkeletonMap.head_joint` keeps the head *joint* for body height.
4. **Sides.** Left is where bent knees' hinge axes (thigh x shin) point, else ``up x
   forward`` (forward from the feet, else the knees' bend). Names saying left/right on both
   limb pairs decide which is which; when both pairs disagree with the geometry, the capture
   is mirrored (:attr:`SkeletonMap.mirrored`: the caller reflects the motion); when only one
   pair disagrees, geometry wins with a warning. Rigs without side names get sides from
   geometry alone. When the mapping comes from frames (no standing rest pose), the sides are
   read from the hips and shoulders only (knees and hands cross in a side step or a slash)
   and several frames vote, so every clip of a rig — and every part of a clip, cut out and
   searched with — gets the same sides. A standing rest pose that shows no side (straight
   knees, no feet) lets the clip's frames vote likewise (:attr:`SkeletonMap.sides_open`).

What the tree alone decides (the candidate limb ends, the choices it allows) and, when the
rest pose shows a standing figure, the whole mapping are kept per skeleton: every clip of a
rig after the first is mapped without redoing them.

Whatever is not a whole humanoid (quadruped, hand, face, upper body only, all-zero offsets)
is refused with :class:`~app.errors.SkeletonMappingError` saying what was found and what is
missing.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import math
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from functools import partial

import numpy as np

from app.errors import SkeletonMappingError
from app.motion.model import Skeleton
from app.motion.skeleton_names import (
    ARM_PARTS,
    LEG_PARTS,
    NameHint,
    name_hint,
    name_side,
    normalise_name,
)

SIDES = ("l", "r")

# Canonical joint names in a fixed order: descriptors index into this tuple.
CANONICAL_JOINTS: tuple[str, ...] = (
    "pelvis",
    "spine",
    "chest",
    "neck",
    "head",
    *(
        f"{side}_{part}"
        for side in SIDES
        for part in (
            "shoulder",
            "elbow",
            "wrist",
            "hand_tip",
            "hip",
            "knee",
            "ankle",
            "toe",
        )
    ),
)
CANONICAL_INDEX: dict[str, int] = {name: i for i, name in enumerate(CANONICAL_JOINTS)}

# Parent of each canonical joint in the canonical tree (for bones and relative rotations).
CANONICAL_PARENT: dict[str, str | None] = {
    "pelvis": None,
    "spine": "pelvis",
    "chest": "spine",
    "neck": "chest",
    "head": "neck",
}
for _side in SIDES:
    CANONICAL_PARENT.update(
        {
            f"{_side}_shoulder": "chest",
            f"{_side}_elbow": f"{_side}_shoulder",
            f"{_side}_wrist": f"{_side}_elbow",
            f"{_side}_hand_tip": f"{_side}_wrist",
            f"{_side}_hip": "pelvis",
            f"{_side}_knee": f"{_side}_hip",
            f"{_side}_ankle": f"{_side}_knee",
            f"{_side}_toe": f"{_side}_ankle",
        }
    )

# Canonical bones as (parent, child) index pairs, for drawing stick figures.
CANONICAL_BONES: tuple[tuple[int, int], ...] = tuple(
    (CANONICAL_INDEX[parent], CANONICAL_INDEX[child])
    for child, parent in CANONICAL_PARENT.items()
    if parent is not None
)

# The same joint on the other side (identity for the midline), for mirroring.
MIRROR_INDEX: np.ndarray = np.array(
    [
        CANONICAL_INDEX[
            "r" + name[1:]
            if name.startswith("l_")
            else "l" + name[1:]
            if name.startswith("r_")
            else name
        ]
        for name in CANONICAL_JOINTS
    ]
)

# Bones of non-zero length between the root and a limb's end, at least.
_MIN_LIMB_BONES = 2
# The shorter limb of a pair is at least this fraction of the longer one's bone path.
_LIMB_PARTNER = 0.6
# An end effector continues its joint's direction (up for the head, forward for the toes)
# within this cosine (45 degrees): a helper nub pointing elsewhere is not the toe tip.
_EFFECTOR_COS = 0.7
# Head/hands/feet choices walked, cheapest first, before giving up on a pose.
_TRIED_CHOICES = 12
# Leaves considered as extremities (head, hands, feet and up to three props/IK targets),
# and, when none of their choices is a humanoid, up to seven.
_CANDIDATES = 8
_MORE_CANDIDATES = 12
# ...read in the rest pose and this many frames (their choices are many more to check).
_MORE_FRAMES = 3
# Fractions of the pose's extent (its bounding-box diagonal, about body height).
COINCIDENT = 1e-4  # joints closer than this share a position
_BENT_KNEE = np.sin(np.radians(10))  # a knee bent this much shows its hinge axis
_MIN_LEG = 0.15  # a leg chain is at least this long
_MIN_ARM = 0.15  # an arm chain is at least this long
_HEAD_END_MIN = 0.005  # an end effector is at least this far from its joint
# Relative difference under which an End Site's length copies its parent bone's (a tail an
# exporter invented, not a measured point): float32 rounding of the two is under 1e-6.
_TAIL_COPY = 1e-4
# Degrees: bones of a straight limb in the rest pose (frame poses bend at knee and elbow).
_STRAIGHT_REST_DEG = 12.0
_STRAIGHT_FRAME_DEG = 50.0
# A joint bends a straight-looking limb when its chain turns by more than this, degrees.
_BEND_DEG = 8.0
# A later limb top must fit the proportions this much better (log ratio) to be taken.
_PROPORTION_MARGIN = 0.3
# Degrees a joint inside one limb part may turn over the clip's frames: a bone does not bend
# (twist and helper joints inside it keep their angle), while a joint of the limb (a collar
# in line with a T-posed arm, a wrist, a finger) turns tens of degrees in almost any motion.
_RIGID_DEG = 15.0
# Upper arm : forearm and thigh : shin (Drillis & Contini's segment table).
_UPPER_TO_FORE = 1.27
_THIGH_TO_SHIN = 1.0
# Hand (wrist to fingertip) : forearm, same table (0.108 and 0.146 of height).
_HAND_TO_FORE = 0.74
# The foot turns away from the shin by at least this much at the ankle, degrees.
_ANKLE_TURN_DEG = 25.0
# Foot (ankle to toe tip) : shin, same table (0.152 and 0.246 of height).
_FOOT_TO_SHIN = 0.62
# Feet lie below the pelvis by at least this fraction of the leg chain's length.
_LEG_DROP_RATIO = 0.5
# cos of the smallest angle between the spine and the legs of a standing biped (120 deg).
_LEGS_OPPOSITE_SPINE = -0.5
# The share of a limb (top, middle and end joints, in straight lines) in the way from the
# trunk joint it hangs from to its end. A person's hip sits half a hip width (~0.1 of the
# height) from the pelvis, against a leg of ~0.49: 0.83; the shortest-legged cartoon of the
# dev data (Mixamo's Mousey) 0.69; a leg shorter than its hip's distance from the pelvis
# (under 0.5) is not one. An arm hangs a clavicle and some spine from the arms' branch
# point: 0.55 to 0.83 in the dev data; under a third, the arm is shorter than half that way.
_LEG_SHARE = 0.5
_ARM_SHARE = 1 / 3

FAMILY_NAMES = (
    "cmu-asf",
    "motionbuilder",
    "3dsmax",
    "daz",
    "bandai",
    "mixamo",
    "biped",
    "generic",
)


@dataclass(frozen=True)
class SkeletonMap:
    """Where each canonical joint lives in a source skeleton.

    Attributes
    ----------
    joints:
        ``(C,)`` int64 source joint index per canonical joint, ``C = len(CANONICAL_JOINTS)``.
    family:
        The naming convention recognised (informational, see :data:`FAMILY_NAMES`).
    derived:
        Canonical joints placed by a rule rather than found as their own joint (``spine``,
        ``chest``, a neck taken from the head's parent, ``hand_tip``, a toe from the ankle).
    end_sites:
        Canonical points that are end effectors (End Sites or leaves without a frame of
        their own): ``head``, ``*_toe``, ``*_hand_tip`` where the rig has them.
    head_joint:
        Source index of the head *joint* (the head point's parent when the head point is an
        end effector); body height is measured to it.
    how:
        Canonical joint -> how it was found (``"name"``, ``"structure"``, ``"geometry"``,
        ``"end effector"``, ``"derived: ..."``).
    mirrored:
        The geometry is left-handed (the limbs called left lie on the subject's right): the
        motion must be reflected across ``mirror_axis`` before it is described.
    mirror_axis:
        World axis (0, 1, 2) nearest the body's lateral direction, to reflect across.
    pose:
        Which pose the geometry was read from: ``"rest pose"`` or ``"frame N"``.
    sides_open:
        The rest pose shows no side (straight knees, no feet): the clip's frames chose left
        and right, so the mapping is made again for every clip of the rig.
    limbs_open:
        The rest pose left a limb's joints to choose among joints in one straight line (a
        collar bone in line with a T-posed arm, a wrist among the hand's joints): the clip's
        frames chose (the joints inside one limb part stay in line when it moves), so the
        mapping is made again for every clip of the rig.
    held:
        ``(joint, limb end, distance)`` for mapped joints that do not hang from the limb
        they end (a foot bone under the root that IK keeps at the end of the shin): in the
        mapping they hang from that limb end, at that rest-pose distance.
    warnings:
        Short sentences for the user about what the mapping had to decide.
    """

    joints: np.ndarray
    family: str
    derived: tuple[str, ...]
    end_sites: tuple[str, ...] = ()
    head_joint: int = -1
    how: dict[str, str] = field(default_factory=dict)
    mirrored: bool = False
    mirror_axis: int = 0
    pose: str = "rest pose"
    sides_open: bool = False
    limbs_open: bool = False
    held: tuple[tuple[int, int, float], ...] = ()
    warnings: tuple[str, ...] = ()

    def describe(self, names: Sequence[str]) -> dict[str, dict[str, str]]:
        """Canonical joint -> ``{"joint": source name, "how": ...}`` for people to read."""
        return {
            canonical: {"joint": names[int(j)], "how": self.how.get(canonical, "structure")}
            for canonical, j in zip(CANONICAL_JOINTS, self.joints, strict=True)
        }


def detect_family(names: tuple[str, ...]) -> str:
    """A short name for the skeleton's naming convention (informational)."""
    normal = {normalise_name(n) for n in names}
    if any(n.lower().startswith("mixamorig") for n in names):
        return "mixamo"
    if {"lhumerus", "lfemur", "ltibia"} <= normal:
        return "cmu-asf"
    if {"lhipjoint", "leftupleg", "leftfingerbase"} <= normal:
        return "motionbuilder"
    if {"lhipjoint", "lefthip", "leftcollar"} <= normal:
        return "3dsmax"
    if {"lshldr", "lthigh", "abdomen"} <= normal:
        return "daz"
    if {"upperlegl", "upperarml", "jointroot"} <= normal:
        return "bandai"
    if {"leftupleg", "leftarm", "leftforearm"} <= normal:
        return "biped"
    return "generic"


def rest_pose(skeleton: Skeleton) -> np.ndarray:
    """``(J, 3)`` joint positions of the rest pose (offsets only), root at the origin."""
    out = np.zeros((skeleton.joint_count, 3))
    for j in range(1, skeleton.joint_count):
        out[j] = out[skeleton.parents[j]] + skeleton.offsets[j]
    return out


class _NotHumanoid(Exception):
    """Why one pose does not show a humanoid (turned into SkeletonMappingError at the end)."""


def map_skeleton(skeleton: Skeleton, poses: Iterable[tuple[str, np.ndarray]] = ()) -> SkeletonMap:
    """Find every canonical joint in ``skeleton``.

    Parameters
    ----------
    skeleton:
        The source skeleton.
    poses:
        Further ``(label, (J, 3) world positions)`` poses to read the geometry from when
        the rest pose is not a standing figure (frames of the motion); consumed lazily, only
        as far as needed.

    Raises
    ------
    SkeletonMappingError
        The skeleton is not a whole humanoid; the message says what was found and missing.
    """
    stream = _Lookahead(poses)
    try:
        return _map_tree(skeleton, stream)
    except _NotHumanoid as reason:
        problem = SkeletonMappingError(str(reason))
    # Limb ends that IK holds without hanging from them (a game rig's foot bone under the
    # root, kept at the end of the shin): the frames show them, and the rig is mapped with
    # each hung from the limb it moves with.
    known = _known(skeleton, _CANDIDATES)
    held = _held_ends(known.tree, stream.after(-1, _POSES))
    if not held:
        raise problem
    rehung = _rehung(skeleton, known.rest, held)
    if rehung is None:
        raise problem
    order, virtual = rehung
    moved = _Lookahead((label, pose[order]) for label, pose in stream)
    try:
        mapping = _map_tree(virtual, moved)
    except _NotHumanoid:
        raise problem from None
    joints = order[mapping.joints]
    ends = ", ".join(
        f"{skeleton.names[joint]!r} with {skeleton.names[leaf]!r}"
        for joint, leaf in held.items()
        if joint in joints
    )
    if not ends:
        return dataclasses.replace(
            mapping, joints=joints, head_joint=int(order[mapping.head_joint])
        )
    return dataclasses.replace(
        mapping,
        joints=joints,
        head_joint=int(order[mapping.head_joint]),
        held=tuple(
            (joint, leaf, float(np.linalg.norm(known.rest[joint] - known.rest[leaf])))
            for joint, leaf in held.items()
            if joint in joints
        ),
        warnings=(*mapping.warnings, f"limb ends held by IK, not by their limbs: {ends}"),
    )


def _map_tree(skeleton: Skeleton, stream: _Lookahead) -> SkeletonMap:
    """The mapping of ``skeleton`` as its tree stands (see :func:`map_skeleton`); else the
    rest pose's reason (_NotHumanoid)."""
    known = _known(skeleton, _CANDIDATES)
    try:
        return _map_known(known, stream)
    except _NotHumanoid:
        if len(known.candidates) < _CANDIDATES:
            raise
        # Many long leaves (IK targets, props, hair, long fingers) may have kept a hand or a
        # foot out of the candidates: look at more before refusing.
        try:
            return _map_known(_known(skeleton, _MORE_CANDIDATES), stream, _MORE_FRAMES)
        except _NotHumanoid:
            pass
        raise


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


def _map_known(known: _Known, stream: _Lookahead, frames: int | None = None) -> SkeletonMap:
    """The mapping of ``known``'s rig in its rest pose, else in the first of the offered
    poses (the first ``frames`` of them) that shows a humanoid; else the rest pose's reason
    (_NotHumanoid)."""
    rest_result = known.rest_result
    if isinstance(rest_result, SkeletonMap):
        if not rest_result.sides_open and not rest_result.limbs_open:
            return rest_result  # the rest pose decided: the same for every clip of the rig
        # The rest pose placed every joint but showed no side, or left limb joints in line
        # to choose among: the clip's frames vote.
        try:
            return _map_pose(
                known, known.rest, "rest pose", others=partial(stream.after, -1, _POSES)
            )
        except _NotHumanoid:
            return rest_result  # the frames only choose: what the rest pose found stands
    if not known.choices:
        raise _NotHumanoid(rest_result)  # the tree alone refuses: no pose can help
    read = 0
    for index, (label, pose) in enumerate(stream):
        if frames is not None and index >= frames:
            break
        read += 1
        try:
            return _map_pose(
                known, pose, label, others=partial(stream.after, index, _SIDE_VOTES - 1)
            )
        except _NotHumanoid:
            continue
    if read:
        raise _NotHumanoid(f"{rest_result} (in the rest pose, and in none of {read} frames)")
    raise _NotHumanoid(rest_result)


# Poses whose geometry votes on left and right when the mapping comes from the frames: one
# frame can mislead (legs crossing in a side step, feet pointing back at a toe-off), and the
# same rig must get the same sides in every clip — and in every part of one.
_SIDE_VOTES = 5
# Frames that vote on the sides of a rig whose rest pose shows none: all that are offered
# (the caller offers a dozen across the clip).
_POSES = 64


class _Lookahead:
    """The offered poses, read lazily once and kept: mapping tries them in turn; the side
    vote looks at those after the one being mapped."""

    def __init__(self, poses: Iterable[tuple[str, np.ndarray]]) -> None:
        self._source = iter(poses)
        self._read: list[tuple[str, np.ndarray]] = []

    def _reach(self, count: int) -> None:
        while len(self._read) < count:
            try:
                self._read.append(next(self._source))
            except StopIteration:
                return

    def __iter__(self) -> Iterator[tuple[str, np.ndarray]]:
        index = 0
        while True:
            self._reach(index + 1)
            if index >= len(self._read):
                return
            yield self._read[index]
            index += 1

    def after(self, index: int, count: int) -> list[np.ndarray]:
        self._reach(index + 1 + count)
        return [pose for _, pose in self._read[index + 1 : index + 1 + count]]


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


_KNOWN: OrderedDict[bytes, _Known] = OrderedDict()
_KNOWN_SIZE = 64  # skeletons remembered (a library holds few distinct rigs at a time)
_KNOWN_LOCK = threading.Lock()


def _skeleton_key(skeleton: Skeleton) -> bytes:
    digest = hashlib.blake2b(digest_size=20)
    digest.update("\x00".join(skeleton.names).encode("utf-8", "surrogatepass"))
    for array, kind in (
        (skeleton.parents, np.int64),
        (skeleton.offsets, np.float64),
        (skeleton.end_site, np.bool_),
    ):
        digest.update(b"|")
        digest.update(np.ascontiguousarray(array, dtype=kind).tobytes())
    return digest.digest()


def _known(skeleton: Skeleton, candidates: int) -> _Known:
    """The structural facts and the rest-pose result of ``skeleton`` with up to
    ``candidates`` limb ends (memoised: every clip of one rig shares them, so importing many
    clips maps the rig once)."""
    key = _skeleton_key(skeleton) + candidates.to_bytes(2, "little")
    with _KNOWN_LOCK:
        known = _KNOWN.get(key)
        if known is not None:
            _KNOWN.move_to_end(key)
            return known
    tree = _Tree(skeleton)
    rest = rest_pose(skeleton)
    if float(np.linalg.norm(np.ptp(rest, axis=0))) <= 0.0 or not np.any(tree.lengths > 0):
        raise SkeletonMappingError(
            "every OFFSET is 0: the skeleton has no shape to map "
            f"({skeleton.joint_count} joints collapse to one point)"
        )
    known = _structure(tree, candidates)
    known.rest = rest
    try:
        known.rest_result = _map_pose(known, rest, "rest pose")
    except _NotHumanoid as reason:
        known.rest_result = str(reason)
    if isinstance(known.rest_result, SkeletonMap):
        known.rest_result.joints.setflags(write=False)  # shared by every caller
    with _KNOWN_LOCK:
        _KNOWN[key] = known
        while len(_KNOWN) > _KNOWN_SIZE:
            _KNOWN.popitem(last=False)
    return known


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


@dataclass
class _Limb:
    """One arm or leg: part (``hip``, ``knee``...) -> source joint, and how each was found."""

    joints: dict[str, int]
    how: dict[str, str]

    def __getitem__(self, part: str) -> int:
        return self.joints[part]


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


# How a wrist found where the fingers part begins.
_FINGERS_BRANCH = "structure: where the fingers"

_LEG = _LimbKind("leg", ("hip", "knee", "ankle"), _THIGH_TO_SHIN, _FOOT_TO_SHIN, _LEG_SHARE)
_ARM = _LimbKind("arm", ("shoulder", "elbow", "wrist"), _UPPER_TO_FORE, _HAND_TO_FORE, _ARM_SHARE)


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


def _unit(v: np.ndarray) -> np.ndarray:
    n = _length(v)
    return v / n if n > 0 else v


# The mapper works on single 3-vectors, where numpy's general norm and cross cost 3-10 us a
# call; these do the same arithmetic (so give the same bits) in well under one.


def _length(v: np.ndarray) -> float:
    """Euclidean length of the 3-vector ``v`` (what ``np.linalg.norm`` computes)."""
    return math.sqrt(float(v @ v))


def _unit_rows(v: np.ndarray) -> np.ndarray:
    """``(..., 3)`` vectors ``v`` scaled to length 1 (zero vectors stay zero)."""
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.divide(v, n, out=np.zeros_like(v), where=n > 0)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a x b`` for 3-vectors (what ``np.cross`` computes)."""
    a0, a1, a2 = a.tolist()
    b0, b1, b2 = b.tolist()
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


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
    for hands in itertools.combinations(candidates, 2):
        chest = tree.lca(*hands)
        if chest in hands:
            continue
        others = [c for c in candidates if c not in hands]
        heads = [h for h in others if h != chest and tree.is_ancestor(chest, h)]
        lower = [c for c in others if not tree.is_ancestor(chest, c)]
        if not heads:
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
    else:
        first = _first_misfit(tree, candidates)
        if first is not None:
            best_partial, reason = 0, first
    return _Known(tree, candidates, choices, reason, best_partial)


_NOT_ALIKE = "no two limbs of a pair alike: missing legs or arms"


def _first_misfit(tree: _Tree, candidates: list[int]) -> str | None:
    """Why the first choice (in the plain enumeration) that the tree refuses is refused."""
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
            words = tree.role_words(tree.chain(top, end)[1:])
            if words and role not in words:
                cost.append(3.0)
            elif role in words:
                cost.append(-0.5)
    return (head, hands, feet, chest, pelvis, leg_lengths, arm_lengths, tuple(cost))


def _hypotheses(known: _Known, pose: np.ndarray, extent: float) -> tuple[list[_Body], str]:
    """Every valid head/hands/feet choice in ``pose``, and the best reason a rejected one
    gave (for the error message)."""
    valid: list[_Body] = []
    reason, best_partial = known.reason, known.progress
    for choice in known.choices:
        body, why, progress = _check_pose(known.tree, pose, extent, *choice)
        if body is not None:
            valid.append(body)
        elif progress > best_partial:
            best_partial, reason = progress, why
    return valid, reason


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
) -> tuple[_Body | None, str, int]:
    """The geometric half: a hypothesis if the choice is a humanoid in ``pose``, else (None,
    why, how far it got)."""
    spine = pose[chest] - pose[pelvis]
    if _length(spine) < COINCIDENT * extent:
        spine = pose[head] - pose[pelvis]
    up = _unit(spine)
    if not _length(up) > 0:
        return None, "the spine has no length", 1
    drops = [float((pose[pelvis] - pose[f]) @ up) for f in feet]
    legs = [_unit(pose[f] - pose[pelvis]) for f in feet]
    leg_dir = _unit(legs[0] + legs[1])
    if min(leg_lengths) < _MIN_LEG * extent:
        return None, "no two legs reach down from the pelvis: missing legs", 2
    if float(leg_dir @ up) > _LEGS_OPPOSITE_SPINE:
        names = ", ".join(tree.names[j] for j in (*feet, *hands))
        return (
            None,
            "the spine is horizontal with the limbs hanging down "
            f"({names}): a four-legged animal, not a humanoid",
            3,
        )
    if min(d / length for d, length in zip(drops, leg_lengths, strict=True)) < _LEG_DROP_RATIO:
        return None, "no two legs reach down from the pelvis: missing legs", 2
    if float((pose[head] - pose[chest]) @ up) <= 0:
        return None, "no head above the arms: missing head", 2
    if min(arm_lengths) < _MIN_ARM * extent:
        return None, "no two arms branch off the spine: missing arms", 2
    cost = abs(leg_lengths[0] - leg_lengths[1]) / max(leg_lengths) + abs(
        arm_lengths[0] - arm_lengths[1]
    ) / max(arm_lengths)
    for term in name_cost:  # added one by one, as the names were read
        cost += term
    # Prefer the highest head and the longest limbs among otherwise equal choices (a leaf at
    # the knee is a marker joint, not the foot).
    cost -= 0.1 * float((pose[head] - pose[pelvis]) @ up) / extent
    cost -= 0.5 * (sum(leg_lengths) + sum(arm_lengths)) / extent
    return _Body(head, hands, feet, chest, pelvis, up, cost), "", 4


def _map_pose(
    known: _Known,
    pose: np.ndarray,
    label: str,
    others: Callable[[], list[np.ndarray]] = list,
) -> SkeletonMap:
    """The mapping ``pose`` shows (``others``: more poses of the clip, which vote on the
    sides with it)."""
    tree = known.tree
    extent = float(np.linalg.norm(np.ptp(pose[tree.body_joints], axis=0)))
    if not extent > 0:
        raise _NotHumanoid("every joint of the pose is at one point: no shape to map")
    valid, reason = _hypotheses(known, pose, extent)
    if not valid:
        raise _NotHumanoid(f"not a whole humanoid: {reason}")
    # The cheapest choice whose limbs have knees and elbows (an IK target hanging from the
    # root may pass for a leg until its chain is walked).
    first: _NotHumanoid | None = None
    for body in sorted(valid, key=lambda b: b.cost)[:_TRIED_CHOICES]:
        try:
            return _Mapper(tree, pose, extent, body, label, others).run()
        except _NotHumanoid as problem:
            first = first or problem
    assert first is not None
    raise first


class _Mapper:
    """Places every canonical joint once head, hands and feet are known."""

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
        """The joint of ``chain`` whose name says ``part`` best (nearest the root on ties)."""
        best: tuple[int, int] | None = None
        for i, j in enumerate(chain):
            rank = self.tree.hints[j].parts.get(part)
            if rank is not None and (best is None or rank < best[0]):
                best = (rank, i)
        return None if best is None else chain[best[1]]

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
            reaches = sorted(
                ((tree.lengths[c] + tree.reach[c], c) for c in tree.children[j]), reverse=True
            )
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

    # -- the body ------------------------------------------------------------------------

    def run(self) -> SkeletonMap:
        tree, body = self.tree, self.body
        self.put("pelvis", body.pelvis, "structure: where the legs and the spine meet")
        self.put("chest", body.chest, "structure: where the arms branch off the spine")
        self.derived.append("chest")
        self.map_head()
        self.map_spine()
        legs = [self.map_leg(f) for f in body.feet]
        # Each leg is its own chain from the hip down: a hip at or above the point where the
        # two leg chains part is one limb forking (fingers of one hand), not two legs.
        fork = tree.lca(*body.feet)
        if any(leg["hip"] == fork or not tree.is_ancestor(fork, leg["hip"]) for leg in legs):
            raise _NotHumanoid(
                "the two legs share their hip: no two separate legs below the pelvis"
            )
        self.hip_half_gap = 0.5 * _length(self.pose[legs[0]["hip"]] - self.pose[legs[1]["hip"]])
        arms = [self.map_arm(h) for h in body.hands]
        for limbs, kind, trunk in ((legs, _LEG, body.pelvis), (arms, _ARM, body.chest)):
            for limb in limbs:
                self.check_share(limb, kind, trunk)
        mirrored, axis = self.assign_sides(legs, arms)
        joints = np.array([self.found[name] for name in CANONICAL_JOINTS], dtype=np.int64)
        end_sites = tuple(
            name
            for name in CANONICAL_JOINTS
            if self.how[name].startswith("end effector") or tree.skeleton.end_site[self.found[name]]
        )
        return SkeletonMap(
            joints=joints,
            family=detect_family(tree.names),
            derived=tuple(self.derived),
            end_sites=end_sites,
            head_joint=self.head_joint,
            how=self.how,
            mirrored=mirrored,
            mirror_axis=axis,
            pose=self.label,
            sides_open=self.sides_open,
            limbs_open=self.limbs_open,
            warnings=tuple(self.warnings),
        )

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

    def map_head(self) -> None:
        tree, body = self.tree, self.body
        chain = tree.chain(body.chest, body.head)
        named = self.named(chain[1:], "head")
        if named is not None:
            head_joint, how = named, "name"
        else:
            # The leaf itself, or its parent when the last bone is a skull-long end effector.
            leaf = body.head
            while tree.lengths[leaf] == 0 and tree.parents[leaf] != body.chest:
                leaf = int(tree.parents[leaf])
            parent = int(tree.parents[leaf])
            long_end = tree.lengths[leaf] >= 2 * _HEAD_END_MIN * self.extent
            # A person has a neck: a leaf *joint* (not an End Site) one joint above the arms
            # is the head on its neck, not the top of a head sitting on the shoulders.
            on_neck = tree.skeleton.end_site[leaf] or tree.parents[parent] != body.chest
            head_joint = parent if long_end and parent != body.chest and on_neck else leaf
            how = "structure: top of the spine chain"
            # The skull carries the face (eyes, jaw): where the chain to the top of the head
            # first branches above the neck is the head joint, as a named rig's "head" is.
            above_neck = chain[2 : chain.index(leaf)]
            skull = next((j for j in above_neck if len(tree.children[j]) > 1), None)
            if skull is not None:
                head_joint, how = skull, "structure: where the face branches off the head"
        self.head_joint = head_joint
        tip = self.effector(head_joint, along=body.up)
        if tip is None and head_joint != body.chest:
            # A head bowed or tilted against the spine (a frame, not a standing rest pose):
            # the top of the head continues the neck's own line.
            neck_line = self.pose[head_joint] - self.pose[int(tree.parents[head_joint])]
            tip = self.effector(head_joint, along=_unit(neck_line))
        if tip is not None:
            self.put("head", tip, "end effector beyond the head joint")
        else:
            self.put("head", head_joint, how)
        between = chain[1 : chain.index(head_joint)]
        neck = self.named(between, "neck")
        if neck is not None:
            self.put("neck", neck, "name")
        elif between:
            self.put("neck", between[0], "structure: first joint above the arms")
        else:
            self.put("neck", body.chest, "derived: the head's parent")
            self.derived.append("neck")
            self.warnings.append("neck derived from the head's parent")

    def map_spine(self) -> None:
        chain = self.tree.chain(self.body.pelvis, self.found["neck"])
        spine = next((j for j in chain[1:] if self.tree.lengths[j] > 0), self.body.chest)
        if not self.tree.is_ancestor(spine, self.body.chest):
            spine = self.body.chest
        self.put("spine", spine, "structure: first bone above the pelvis")
        self.derived.append("spine")

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

    def split(self, chain: list[int], start: int, end: int, ratio: float) -> int | None:
        """Index of the middle joint (knee, elbow) between ``chain[start]`` and ``chain[end]``."""
        pose = self.pose
        inner = [
            i
            for i in range(start + 1, end)
            if not self.same_place(chain[i], chain[start])
            and not self.same_place(chain[i], chain[end])
        ]
        if not inner:
            return None
        bends = []
        for i in inner:
            a = _unit(pose[chain[i]] - pose[chain[start]])
            b = _unit(pose[chain[end]] - pose[chain[i]])
            bends.append(np.degrees(np.arccos(np.clip(a @ b, -1.0, 1.0))))
        if max(bends) > _BEND_DEG:
            return inner[int(np.argmax(bends))]
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
        return inner[int(np.argmin(scores))]

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
        # A collar bone nearly in line with a T-posed arm passes for straight: among the tops
        # of the straight run and the joints below it, the one whose split comes nearest the
        # limb's proportions wins.
        options: list[tuple[float, int, int]] = []
        for start in range(straight, end - 1):
            split = self.split(above, start, end, ratio)
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
        # A run too short to hold a middle joint: the limb bends in the rest pose (no T-pose)
        # and its top is the nearest joint above the run.
        for start in range(straight - 1, first - 1, -1):
            if best is not None:
                break
            split = self.split(above, start, end, ratio)
            if split is not None:
                best = (0.0, start, split)
        if best is None and first > 1:
            # Nothing below the trunk's place fits: the top joint sits there itself (hip
            # joints at the pelvis, the legs parting only at the knees).
            split = self.split(above, first - 1, end, ratio)
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

    def best_limb(self, chain: list[int], ends: list[tuple[int, str]], kind: _LimbKind) -> _Limb:
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
        limbs.sort(key=lambda option: option[0])  # stable: the first on ties
        # Where the fingers branch is the hand's own structure, the other ends only a count
        # of joints from the chain's end: a branching wrist stands unless another end's
        # proportions are clearly nearer a person's (a twist bone may branch, too).
        branching = [
            option for option in limbs if option[1].how[kind.parts[2]].startswith(_FINGERS_BRANCH)
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
        one twice too long or too short."""
        path = self.tree.path
        top, middle, end = (limb[part] for part in kind.parts)
        upper = path[middle] - path[top]
        lower = max(path[end] - path[middle], 1e-12)
        beyond = self.tree.reach[end]
        cost = abs(math.log(max(upper, 1e-12) / lower / kind.upper))
        if beyond > 0:
            return cost + abs(math.log(beyond / lower / kind.beyond))
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
            # (Two before it: a hand bone closed by an End Site, as SMPL exports write it.)
            wrists += [
                (chain[i], "structure: the joint before the hand's end")
                for i in range(last - 1, max(last - 3, 1), -1)
            ]
            wrists.append((chain[last], "structure: the arm's end, no hand"))
        limb = self.best_limb(chain, wrists, _ARM)
        wrist = limb["wrist"]
        result, how = limb.joints, limb.how
        result["hand_tip"] = _farthest_descendant(tree, wrist, skip=_is_thumb)
        how["hand_tip"] = "derived: farthest point beyond the wrist"
        return _Limb(result, how)

    # -- sides ---------------------------------------------------------------------------

    def left(self, pose: np.ndarray, up: np.ndarray, legs: list[_Limb]) -> np.ndarray:
        """The subject's left in ``pose`` (zero when it shows none).

        A bent knee's hinge axis, thigh x shin, points to the subject's left whichever way
        the subject faces and whatever the feet do (the shin folds back); in a mirrored
        capture it points to the mirror image's left, as ``up x forward`` does. Knees too
        straight to show it leave ``up x forward``, forward from the feet, else the knees'
        bend."""
        hinge = np.zeros(3)
        for leg in legs:
            thigh = pose[leg["knee"]] - pose[leg["hip"]]
            shin = pose[leg["ankle"]] - pose[leg["knee"]]
            axis = _cross(thigh, shin)
            if _length(axis) > _BENT_KNEE * _length(thigh) * _length(shin):
                hinge += axis / _length(axis)
        hinge -= (hinge @ up) * up
        if _length(hinge) > 0.5:  # at least one knee bent and the two agree
            return _unit(hinge)
        forward = np.zeros(3)
        for leg in legs:
            step = pose[leg["toe"]] - pose[leg["ankle"]]
            forward += step - (step @ up) * up
        if _length(forward) < 0.02 * self.extent:
            for leg in legs:
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
        voters = [(pose, left, keys)]
        # The clip's other poses vote with this one: always when the mapping comes from a frame
        # (one frame can mislead); from the rest pose, only when it shows no side at all
        # (straight knees, no feet: the motion's bent knees do).
        if not self.rest or not _length(left):
            self.sides_open = self.rest
            for other in self.others():
                spine = other[self.body.chest] - other[self.body.pelvis]
                if _length(spine) < COINCIDENT * self.extent:
                    spine = other[self.body.head] - other[self.body.pelvis]
                other_up = _unit(spine)
                if _length(other_up) > 0:
                    voters.append((other, self.left(other, other_up, legs), (hips, ("shoulder",))))
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
            votes = 0
            for voter, voter_left, voter_keys in voters:
                lateral = (
                    sum(
                        float((voter[pair[0][k]] - voter[pair[1][k]]) @ voter_left)
                        for k in voter_keys[limb]
                    )
                    if _length(voter_left)
                    else 0.0
                )
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


__all__ = [
    "CANONICAL_BONES",
    "CANONICAL_INDEX",
    "CANONICAL_JOINTS",
    "CANONICAL_PARENT",
    "MIRROR_INDEX",
    "SkeletonMap",
    "map_skeleton",
    "normalise_name",
    "rest_pose",
]
