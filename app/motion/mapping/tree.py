"""Index helpers over one skeleton's tree: children, depths, bone path lengths, name hints,
and the leaves far apart along the bones that may be the limb ends."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from app.motion.mapping.along import _twist_leaves
from app.motion.mapping.canonical import rest_pose
from app.motion.model import Skeleton
from app.motion.skeleton_names import (
    ARM_PARTS,
    LEG_PARTS,
    SIDED_PARTS,
    NameHint,
    name_hint,
    name_side,
    normalise_name,
)

# Bones of non-zero length between the root and a limb's end, at least.
_MIN_LIMB_BONES = 2
# Fractions of the pose's extent (its bounding-box diagonal, about body height).
COINCIDENT = 1e-4  # joints closer than this share a position
# Joints whose names the tree contradicts (:func:`contradicted_names`) from which a rig's
# names are not read at all: no named dev rig has one; one odd name alone is tolerated.
_LYING_NAMES = 2
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
        self.rest = rest_pose(skeleton)  # (J, 3)
        extent = float(np.linalg.norm(np.ptp(self.rest, axis=0))) if count else 0.0
        self.extent = extent
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
        self.void |= _twist_leaves(
            skeleton.parents, self.rest, self.lengths, has_point, skeleton.end_site
        )
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
        # A leaf *joint* exactly as long as the bone it ends: the same invented tail as such
        # an End Site, written as a node (Blender's FBX export adds a ``_end`` leaf bone at
        # the tail of every leaf bone, whose length it took from the parent). It is kept
        # (a hand's or a toe's farthest point may be one, as in the rig it came from), but
        # the head's top is not read from it (:meth:`_Mapper.map_head`).
        self.tail_copy = np.zeros(count, dtype=bool)
        for j in self.leaves:
            if skeleton.end_site[j] or j == 0:
                continue
            parent_length = self.lengths[int(self.parents[j])]
            if parent_length > 0 and abs(self.lengths[j] - parent_length) <= (
                _TAIL_COPY * parent_length
            ):
                self.tail_copy[j] = True
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
        # (Every joint of a rig too small to have a body proper: a bone or two, or a root
        # with only short leaves, whose one joint would make a pose of no size.)
        body = [j for j in range(count) if j not in shallow]
        if len(body) < 2:
            body = list(range(count))
        self.body_joints = np.array(body, dtype=np.int64)
        self.reach = np.zeros(count)  # longest bone path from a joint down to a descendant
        for j in range(count - 1, 0, -1):
            p = int(self.parents[j])
            self.reach[p] = max(self.reach[p], self.reach[j] + self.lengths[j])
        hints = [name_hint(n) for n in skeleton.names]
        # Names the tree contradicts in more than one place lie (shuffled, or a rig renamed
        # wrongly): the rig is mapped as if it had none, never worse than without names.
        self.names_trusted = contradicted_names(skeleton.parents, hints) < _LYING_NAMES
        self.hints: list[NameHint] = (
            _chain_hints(skeleton.parents, hints, self.lengths == 0)
            if self.names_trusted
            else [NameHint(None, {})] * count
        )
        self.sides: list[str | None] = (
            [name_side(n) for n in skeleton.names] if self.names_trusted else [None] * count
        )
        # The hypotheses ask the same few pairs thousands of times (the tree does not change
        # while it is mapped, so each answer is kept).
        self._lca: dict[tuple[int, int], int] = {}
        self._ancestor: dict[tuple[int, int], bool] = {}
        self._chain: dict[tuple[int, int], tuple[int, ...]] = {}
        self._words_below: dict[tuple[int, int], frozenset[str]] = {}
        self._geodesic: dict[int, np.ndarray] = {}
        self._walk: tuple[list[int], list[float]] | None = None  # parents, lengths
        self._limb_names: dict[tuple[int, ...], str] = {}
        # What :mod:`.take` reads of a leg from the bones alone: (pelvis, foot) -> (knee,
        # ankle), and (pelvis, foot, foot) -> the two legs are mirror images.
        self.lower_legs: dict[tuple[int, int], tuple[int, int]] = {}
        self.mirror_legs: dict[tuple[int, int, int], bool] = {}

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
        key = (top, bottom)
        found = self._chain.get(key)
        if found is None:
            out = [bottom]
            while out[-1] != top:
                out.append(int(self.parents[out[-1]]))
            found = self._chain[key] = tuple(out[::-1])
        return list(found)  # a fresh list: callers may change theirs

    def geodesic(self, start: int) -> np.ndarray:
        """``(J,)`` bone path length from ``start`` to every joint."""
        found = self._geodesic.get(start)
        if found is None:
            found = self._geodesic[start] = self._walk_from(start)
            found.setflags(write=False)
        return found.copy()  # a fresh array: callers may change theirs

    def _walk_from(self, start: int) -> np.ndarray:
        """``(J,)`` bone path length from ``start`` to every joint, walked along the bones
        (on Python floats and lists, cheaper than numpy scalars: the same sums in the same
        order, so the same bits)."""
        if self._walk is None:
            self._walk = (self.parents.tolist(), self.lengths.tolist())
        parents, lengths = self._walk
        children = self.children
        out = [-1.0] * len(self.names)
        out[start] = 0.0
        stack = [start]
        while stack:
            j = stack.pop()
            neighbours = list(children[j])
            if parents[j] >= 0:
                neighbours.append(parents[j])
            for n in neighbours:
                if out[n] < 0:
                    step = lengths[n] if parents[n] == j else lengths[j]
                    out[n] = out[j] + step
                    stack.append(n)
        return np.array(out)

    def descendants(self, joint: int) -> list[int]:
        out, stack = [], [joint]
        while stack:
            j = stack.pop()
            out.append(j)
            stack.extend(self.children[j])
        return out

    def limb_names(self, joints: tuple[int, ...]) -> str:
        """The names of ``joints``, comma-separated (for messages; kept per tuple)."""
        found = self._limb_names.get(joints)
        if found is None:
            found = self._limb_names[joints] = ", ".join(self.names[j] for j in joints)
        return found

    def words_below(self, top: int, end: int) -> frozenset[str]:
        """:meth:`role_words` of the chain below ``top`` down to ``end`` (kept per pair)."""
        key = (top, end)
        found = self._words_below.get(key)
        if found is None:
            found = self._words_below[key] = frozenset(self.role_words(self.chain(top, end)[1:]))
        return found

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


def _chain_hints(
    parents: np.ndarray, hints: list[NameHint], on_parent: np.ndarray
) -> list[NameHint]:
    """``hints`` without the part a joint's name shares with an ancestor's that names it as
    well or better: two joints of one chain are not both the ankle (SMPL's ``L_Ankle`` above
    ``L_Foot``, Kinect's ``WristLeft`` above ``HandLeft``: the lower one is the bone beyond
    the joint), and a twist or bend segment below its limb bone (``upperleg02``,
    ``DEF-forearm.L.001``) is not the joint either. An ancestor on its own parent's place
    (``on_parent`` ``(J,)``: a bone of no length) claims nothing for the joints below it: a
    connector a writer puts at the trunk's point for each limb (``Pelvis_L_Hip`` at the
    pelvis above ``L_Hip``) bears the part's name without being where the part starts
    (:meth:`~app.motion.mapping.state._MapperState.named` then prefers the joint set apart)."""
    above: list[dict[str, int]] = []  # part -> best rank among a joint's ancestors
    out = []
    for j, hint in enumerate(hints):
        p = int(parents[j])
        inherited = above[p] if p >= 0 else {}
        kept = {
            part: rank
            for part, rank in hint.parts.items()
            if part not in SIDED_PARTS or inherited.get(part, rank + 1) > rank
        }
        out.append(hint if len(kept) == len(hint.parts) else NameHint(hint.side, kept))
        sided = {part: rank for part, rank in hint.parts.items() if part in SIDED_PARTS}
        if sided and not (p >= 0 and on_parent[j]):
            inherited = dict(inherited)
            for part, rank in sided.items():
                inherited[part] = min(rank, inherited.get(part, rank))
        above.append(inherited)
    return out


# Stage of each limb part from the trunk outwards: a name of a later stage above one of an
# earlier stage of the same kind of limb (a "hand" above an "elbow") contradicts the tree.
_STAGES = {
    **{part: ("arm", i) for i, part in enumerate(("clavicle", "shoulder", "elbow", "wrist"))},
    **{part: ("leg", i) for i, part in enumerate(("hip", "knee", "ankle", "toe"))},
}


def contradicted_names(parents: np.ndarray, hints: list[NameHint]) -> int:
    """How many joints' names the tree contradicts: a limb part below a part of the other
    kind of limb (a leg below an arm), below a later part of its own limb (an elbow below a
    hand), below the other side's limb, or the head, neck or pelvis below a limb part. A
    person's parts come in this order along the bones whatever the exporter calls them;
    names shuffled among the joints break it everywhere."""
    # Per joint, the limb parts named above it: (kind, earliest stage, side) of each.
    above: list[tuple[tuple[str, int, str | None], ...]] = []
    count = 0
    for j, hint in enumerate(hints):
        p = int(parents[j])
        inherited = above[p] if p >= 0 else ()
        mine = [_STAGES[part] for part in hint.parts if part in _STAGES]
        if inherited and hint.parts:
            if not mine:  # head, neck, pelvis below a limb
                count += 1
            else:
                kind = mine[0][0]
                latest = max(stage for _, stage in mine)
                if any(
                    k != kind or stage > latest or (side and hint.side and side != hint.side)
                    for k, stage, side in inherited
                ):
                    count += 1
        if mine:
            entry = (mine[0][0], min(stage for _, stage in mine), hint.side)
            inherited = (*inherited, entry) if entry not in inherited else inherited
        above.append(inherited)
    return count


def _extremity_candidates(tree: _Tree, count: int = 8, copies_last: bool = True) -> list[int]:
    """Up to ``count`` leaves, each the farthest (along bones) from those before.

    Only leaves at least :data:`_MIN_LIMB_BONES` bones of non-zero length below the root
    count: a limb has at least a thigh and a shin (its hip may sit at the pelvis itself); an
    IK target or prop hanging from the root by one bone does not.

    Copies are one end (``copies_last``; off only to show what they crowd out): a rig
    exported with copies of its limbs (control and deform chains on the same places, a whole
    Rigify export) and chains of one shape in a bundle (hair strands, a skirt's pleats) are
    each read as one end, or the farthest-leaf choice fills with them and keeps the body's
    own ends out. Of leaves at one place in the rest pose, or of one bundle
    (:func:`_strands`), the one nearest along the bones to the ends chosen before (the copy
    of the same body) is taken and the others not; a leaf where another branch's joint
    carries on (a control chain stopping at the wrist of a hand with fingers) is a copy of a
    joint, not an end, and comes only after every other leaf.
    """
    leaves = tree.limb_leaves or tree.leaves
    if not copies_last:
        return _farthest_leaves(tree, [leaves], count, {})
    twins, stopped = _rest_copies(tree, leaves)
    ends = [j for j in leaves if j not in stopped]
    return _farthest_leaves(tree, [ends, [j for j in leaves if j in stopped]], count, twins)


def _farthest_leaves(
    tree: _Tree, tiers: list[list[int]], count: int, twins: dict[int, list[int]]
) -> list[int]:
    """Greedy farthest leaves of ``tiers`` in turn (a later tier only once an earlier one
    has no leaf left apart from the chosen); a chosen leaf's ``twins`` are taken with it."""
    chosen: list[int] = []
    taken: set[int] = set()
    nearest = np.full(len(tree.names), np.inf)
    for tier in tiers:
        while len(chosen) < count:
            pool = np.array([j for j in tier if j not in taken], dtype=np.int64)
            if not len(pool):
                break
            if chosen:
                gaps = nearest[pool]
                best = int(pool[int(np.argmax(gaps))])
                if nearest[best] <= 0:
                    break
            else:
                best = int(pool[int(np.argmax(tree.path[pool]))])
            group = [best, *twins.get(best, [])]
            # Of copies at one place, the one of the body already chosen: nearest to it.
            pick = min(group, key=lambda j: (nearest[j], j)) if chosen else min(group)
            chosen.append(pick)
            taken.update(group)
            nearest = np.minimum(nearest, tree.geodesic(pick))
    return chosen


# Chains of one shape hanging from one joint that make a bundle, not limbs: a body hangs at
# most two limbs of one shape (a pair) from a joint.
_BUNDLE = 3
# Bones of its own below a chain's first that give it a shape: a single one is often a tail
# an exporter writes alike on every leaf (a head top's and the eyes' End Sites).
_SHAPE_BONES = 2


def _rest_copies(tree: _Tree, leaves: list[int]) -> tuple[dict[int, list[int]], set[int]]:
    """Of ``leaves``: each one's twins (the others where more than a pair of leaves share a
    place in the rest pose, or of its bundle), and those at the place of a joint of another
    branch that carries on (no leaf)."""
    same = COINCIDENT * tree.extent
    at = tree.rest[np.array(leaves, dtype=np.int64)]  # (L, 3)
    close = np.linalg.norm(at[:, None] - at[None], axis=2) <= same  # (L, L)
    inner = np.array(
        [j for j in range(len(tree.names)) if tree.children[j] and not tree.void[j]],
        dtype=np.int64,
    )
    on_inner = np.linalg.norm(at[:, None] - tree.rest[inner][None], axis=2) <= same  # (L, I)
    strands = _strands(tree, leaves)
    twins: dict[int, list[int]] = {}
    stopped: set[int] = set()
    for i, leaf in enumerate(leaves):
        # A pair at one place may be the two sides folded onto one line by a rest pose that
        # is no figure (joint orientation): only more than a pair are copies.
        others = [leaves[k] for k in np.flatnonzero(close[i]) if k != i]
        if len(others) < _BUNDLE - 1:
            others = []
        others += [j for j in strands.get(leaf, []) if j not in others]
        if others:
            twins[leaf] = others
        if any(not tree.is_ancestor(int(j), leaf) for j in inner[on_inner[i]]):
            stopped.add(leaf)
    return twins, stopped


def _strands(tree: _Tree, leaves: list[int]) -> dict[int, list[int]]:
    """Per leaf, the other leaves of its bundle: :data:`_BUNDLE` or more unbranched chains
    hanging from one joint with the same bone lengths below their first bone (hair strands,
    a skirt's pleats; the first bone, from the joint, only says where each hangs)."""
    same = COINCIDENT * tree.extent
    hung: dict[int, list[tuple[int, np.ndarray]]] = {}
    for leaf in leaves:
        chain = [leaf]
        while len(tree.children[int(tree.parents[chain[-1]])]) == 1:
            chain.append(int(tree.parents[chain[-1]]))
            if tree.parents[chain[-1]] < 0:
                break
        shape = tree.lengths[chain[-2::-1]]  # the bones below the first, from the top
        if np.count_nonzero(shape) < _SHAPE_BONES or tree.parents[chain[-1]] < 0:
            continue  # too few bones to have a shape; a chain from the root is the body
        hung.setdefault(int(tree.parents[chain[-1]]), []).append((leaf, shape))
    out: dict[int, list[int]] = {}
    for chains in hung.values():
        for leaf, shape in chains:
            alike = [
                other
                for other, lengths in chains
                if len(lengths) == len(shape) and np.all(np.abs(lengths - shape) <= same)
            ]
            if len(alike) >= _BUNDLE:
                out[leaf] = [j for j in alike if j != leaf]
    return out


def _branches_below(tree: _Tree, joint: int) -> bool:
    """Whether some joint below ``joint`` parts into two or more bones (fingers, or a twist
    bone beside a limb bone; zero-length leaves are no bones)."""
    frontier = list(tree.children[joint])
    while frontier:
        j = frontier.pop()
        kids = tree.children[j]
        if sum(1 for c in kids if tree.lengths[c] > 0 or tree.children[c]) >= 2:
            return True
        frontier.extend(kids)
    return False


def _is_thumb(name: str) -> bool:
    # Only steers the hand-tip search away from thumbs; canonical matching stays whole-name.
    return "thumb" in normalise_name(name)


def _farthest_descendant(
    tree: _Tree,
    start: int,
    skip: Callable[[str], bool] | None = None,
    within: float = math.inf,
) -> int:
    """Descendant of ``start`` (inclusive) with the longest bone path from it, among those
    no farther along the bones than ``within``."""
    if not tree.names_trusted:
        skip = None  # a thumb's name, among names that lie, says nothing either
    best, best_distance = start, 0.0
    stack = [(start, 0.0)]
    while stack:
        joint, distance = stack.pop()
        if distance > within:
            continue  # nor anything beyond it
        if distance > best_distance:
            best, best_distance = joint, distance
        for child in tree.children[joint]:
            if skip is not None and skip(tree.names[child]):
                continue
            stack.append((child, distance + float(tree.lengths[child])))
    return best
