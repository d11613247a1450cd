"""The public entry: :func:`map_skeleton`, trying the rest pose, then the clip's frames, then
limb ends held by IK, then the take read as a person bent at the hips and knees (no pose
standing), then as a person standing on one leg; what one rig's structure decides is kept
per skeleton."""

from __future__ import annotations

import dataclasses
import hashlib
import threading
from collections import OrderedDict
from collections.abc import Iterable, Iterator
from functools import partial

import numpy as np

from app.errors import SkeletonMappingError
from app.motion.mapping.canonical import SkeletonMap
from app.motion.mapping.held import _held_ends, _rehung
from app.motion.mapping.hypotheses import _Known, _NotHumanoid, _structure
from app.motion.mapping.mapper import _map_pose
from app.motion.mapping.take import map_on_one_leg, map_take
from app.motion.mapping.tree import _Tree
from app.motion.model import Skeleton

# Leaves considered as extremities (head, hands, feet and up to three props/IK targets),
# and, when none of their choices is a humanoid, up to seven.
_CANDIDATES = 8
_MORE_CANDIDATES = 12
# ...read in the rest pose and this many frames (their choices are many more to check).
_MORE_FRAMES = 3


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
    rehung = _rehung(skeleton, known.rest, held) if held else None
    if rehung is None:
        return _bent_take(skeleton, stream, problem)
    order, virtual = rehung
    moved = _Lookahead((label, pose[order]) for label, pose in stream)
    try:
        mapping = _map_tree(virtual, moved)
    except _NotHumanoid:
        return _bent_take(skeleton, stream, problem)
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


def _bent_take(
    skeleton: Skeleton, stream: _Lookahead, problem: SkeletonMappingError
) -> SkeletonMap:
    """The body the take shows bent at the hips and knees when no pose shows it standing
    (:func:`~app.motion.mapping.take.map_take`); else ``problem``, the standing search's
    reason (only the first limb ends are read: see :mod:`~app.motion.mapping.take`)."""
    known = _known(skeleton, _CANDIDATES)
    if not known.choices:
        raise problem
    try:
        return map_take(known, [("rest pose, bent", known.rest), *stream.labelled(_POSES)])
    except _NotHumanoid:
        pass
    # A person at rest stands on both feet: a rest pose on one leg is a pose of the take.
    try:
        return map_on_one_leg(
            known, [("rest pose, on one leg", known.rest), *stream.labelled(_POSES)]
        )
    except _NotHumanoid:
        raise problem from None


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

    def labelled(self, count: int) -> list[tuple[str, np.ndarray]]:
        """The first ``count`` poses with their labels."""
        self._reach(count)
        return self._read[:count]


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


# Fewer joints under the root than this are no body written as points (a prop's pivot and
# its parts): the body's five limb ends alone are five points.
_FREE_POINTS = 5


def _free_points(skeleton: Skeleton) -> str:
    """Why ``skeleton`` is keypoints rather than a skeleton, or ``""``: every joint (End
    Sites aside) hangs from the root directly, with no bone between two of them, as
    "positional" BVH from pose estimators writes keypoints (each moved by position channels
    alone). A body's limbs are chains; points hung side by side have none to follow."""
    parents, kept = skeleton.parents, np.flatnonzero(~skeleton.end_site)
    roots = kept[parents[kept] < 0]
    if len(roots) != 1:
        return ""
    root = int(roots[0])
    below = [int(j) for j in kept if parents[j] >= 0]
    if len(below) < _FREE_POINTS or any(parents[j] != root for j in below):
        return ""
    return (
        f"the {len(below)} joints all hang from the root {skeleton.names[root]!r} directly, "
        "with no bone between any two of them: keypoints, not a skeleton (no limbs to "
        "follow). Write them as a chained skeleton (root, spine, limbs) and upload that"
    )


def _known(skeleton: Skeleton, candidates: int) -> _Known:
    """The structural facts and the rest-pose result of ``skeleton`` with up to
    ``candidates`` limb ends (memoised: every clip of one rig shares them, so importing many
    clips maps the rig once)."""
    rig = _skeleton_key(skeleton)
    key = rig + candidates.to_bytes(2, "little")
    with _KNOWN_LOCK:
        known = _KNOWN.get(key)
        if known is not None:
            _KNOWN.move_to_end(key)
            return known
        # The same rig read with another number of limb ends has the same tree: its index
        # helpers and what they keep (chains, geodesics) serve this one too.
        seen = (
            _KNOWN.get(rig + other.to_bytes(2, "little"))
            for other in (_CANDIDATES, _MORE_CANDIDATES)
        )
        tree = next((other.tree for other in seen if other is not None), None)
    if tree is None:
        tree = _Tree(skeleton)
    rest = tree.rest.copy()  # what rest_pose(skeleton) gives: the tree computed it
    if float(np.linalg.norm(np.ptp(rest, axis=0))) <= 0.0 or not np.any(tree.lengths > 0):
        raise SkeletonMappingError(
            "every joint sits at one point (in a BVH: every OFFSET is 0; in FBX or glTF: "
            "every bone's translation is 0): the skeleton has no shape to map "
            f"({skeleton.joint_count} joints collapse to one point)"
        )
    star = _free_points(skeleton)
    if star:
        raise SkeletonMappingError(star)
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
