"""The canonical-joint view of a clip that every descriptor reads.

``build_body`` maps the source skeleton to :data:`~app.motion.skeleton_map.CANONICAL_JOINTS`,
drops rest-pose lead-in frames that file converters add, runs forward kinematics for the
canonical joints only, and works out from the skeleton itself:

* ``height`` — body height in file units: the leg's bone path (hip -> knee -> ankle, the two
  sides averaged) plus the trunk's (pelvis -> ... -> head). It is a property of the skeleton
  and so the same in every frame, and independent of units once positions are divided by it.
* ``pelvis_frames`` — per frame an orthonormal body frame fixed to the pelvis, columns
  (lateral = subject's left, up, forward) in world coordinates. Miura et al. (2013): "The
  position of each joint is described in the coordinate system fixed to the pelvis". The
  frame is the pelvis joint's world rotation times one constant basis per *skeleton*, found
  in the rest pose (where every local rotation is the identity, so rest-pose directions are
  the pelvis joint's own coordinates): lateral from the right hip to the left hip, up from
  the pelvis toward the neck (orthogonalised), forward = lateral x up. It depends on the
  pelvis alone — never on the clip's other frames — so every clip of one skeleton has the
  same axes, and a frame's features are the same whether computed from the whole clip or a
  part of it (only a rig whose rest pose shows no side at all, or is no pose of the body,
  reads them from the frames: :mod:`app.motion.body_axes`).
  Neither the file's up axis, its units nor the facing direction matter.
* ``world_up`` — the world's vertical axis, needed to split root speed into horizontal and
  vertical parts: the coordinate axis (with sign) nearest to the clip's mean body-up
  direction. Motion-capture files are authored with a coordinate axis up, and a body that
  leans (a dash leans 30-40 degrees on average) must not tilt the floor. A take that mostly
  lies along the floor (a crawl, a fall) has its mean body up along the floor: there
  another axis (a standing rest pose's, or one the body stands along for a part of the
  take) is the vertical where the body's lowest point keeps its height clearly better along
  it (:mod:`app.motion.gravity`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np

from app.errors import ParseError, SkeletonMappingError
from app.motion.body_axes import (
    frames_basis,
    frames_from_positions,
    pelvis_carries,
    pelvis_turns_with_hips,
    pose_basis,
)
from app.motion.formats.scene import OTHER_SKELETONS
from app.motion.gravity import clip_vertical
from app.motion.hand import palm
from app.motion.joint_copies import folded_copies
from app.motion.kinematics import bone_lengths, forward_kinematics
from app.motion.lead_in import count_lead_in_frames, implausible_frames, plausible_span
from app.motion.model import Motion
from app.motion.skeleton_map import (
    CANONICAL_INDEX,
    CANONICAL_JOINTS,
    SkeletonMap,
    map_skeleton,
    rest_pose,
)
from app.motion.transforms import reflect

T = TypeVar("T")

# Frames offered to the skeleton mapper when the rest pose is not a standing figure; the
# first that shows a humanoid is used (a leg kicked high in one frame is not in the next).
_POSE_FRAMES = 12
# The rest pose is a pose of this body when some frame shows its up and lateral within 30
# degrees each, seen from the pelvis (a body turns its pelvis further from the trunk only
# lying or bent double; a bone axis convention turns it by 90 or 180).
_REST_SHOWN = float(np.cos(np.radians(30.0)))
# ...in at least this share of those frames: a rest pose of the body is the pose the take
# keeps its trunk near, while a rest pose that is no pose (bones in random axes) points the
# trunk anywhere and one frame of a dozen, in a take that bends or turns the trunk, can
# agree with it by chance.
_REST_SHARE = 0.5


@dataclass(frozen=True, eq=False)
class Body:
    """Canonical joints of one clip after lead-in frames are dropped.

    Attributes
    ----------
    positions:
        ``(F, C, 3)`` world positions of the canonical joints, file units.
    rotations:
        ``(F, C, 3, 3)`` world rotations of the canonical joints' frames (for derived end
        points the frame of the joint they hang from; for ``hand_tip`` the palm's,
        :func:`app.motion.hand.palm`).
    frame_time:
        Seconds between frames.
    height:
        Body height in file units (> 0).
    pelvis_frames:
        ``(F, 3, 3)`` body frame per frame; columns lateral (left), up, forward.
    world_up:
        ``(3,)`` unit vertical axis of the world.
    skeleton_family:
        Naming convention of the source skeleton.
    lead_in_frames:
        Frames dropped from the start of the clip: converter lead-in (rest pose) frames and
        implausible frames (:func:`~app.motion.lead_in.implausible_frames`). Implausible
        frames dropped from the end are only reported in ``warnings``.
    mapping:
        How the source skeleton's joints became the canonical ones.
    warnings:
        Short sentences about what had to be decided or repaired (mirrored capture, derived
        joints, parser repairs recorded in ``Motion.notes["warnings"]``).
    """

    positions: np.ndarray
    rotations: np.ndarray
    frame_time: float
    height: float
    pelvis_frames: np.ndarray
    world_up: np.ndarray
    skeleton_family: str
    lead_in_frames: int
    mapping: SkeletonMap | None = None
    warnings: tuple[str, ...] = ()
    _memo: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)

    def memo(self, key: str, compute: Callable[[], T]) -> T:
        """``compute()`` once per body: descriptors share intermediate results this way."""
        if key not in self._memo:
            self._memo[key] = compute()
        return self._memo[key]

    @property
    def frame_count(self) -> int:
        return int(self.positions.shape[0])

    def joint(self, name: str) -> np.ndarray:
        """``(F, 3)`` world positions of canonical joint ``name``."""
        return self.positions[:, CANONICAL_INDEX[name]]

    def local_positions(self) -> np.ndarray:
        """``(F, C, 3)`` joint positions in the pelvis frame divided by body height.

        Axis 0 points to the subject's left, 1 up, 2 forward; the pelvis is the origin.
        """
        relative = self.positions - self.positions[:, CANONICAL_INDEX["pelvis"], None, :]
        return (relative @ self.pelvis_frames) / self.height


def build_body(motion: Motion) -> Body:
    """Canonical-joint view of ``motion`` (see the module docstring).

    Raises
    ------
    SkeletonMappingError
        If the skeleton lacks required joints.
    ParseError
        If the skeleton is degenerate (zero height, coincident hips) or no frame remains.
    """
    # A joint's turn written on each of its children is the joint's (the positions are the
    # same; the pelvis's frame is not).
    motion = folded_copies(motion)
    try:
        mapping = map_skeleton(motion.skeleton, poses=_frame_poses(motion))
    except SkeletonMappingError as refused:
        left_out = motion.notes.get(OTHER_SKELETONS)
        if not left_out:
            raise
        # A writer that split the rig (assimp's FBX of a BVH: the legs a tree of their own)
        # leaves the body's missing part in the skeleton not read: say so.
        raise SkeletonMappingError(f"{refused.detail}; {left_out}") from None
    warnings = [str(w) for w in motion.notes.get("warnings", ())]  # type: ignore[attr-defined]
    warnings.extend(mapping.warnings)
    if mapping.mirrored:
        # Left-handed geometry: describe the clip as it would be seen un-mirrored.
        motion = reflect(motion, axis=mapping.mirror_axis)
    rotations, positions = forward_kinematics(motion, joints=mapping.joints)
    canon_rot = rotations[:, mapping.joints]
    canon_pos = positions[:, mapping.joints]
    # Derived end points (end sites) have no frame of their own: use their parent's.
    for c, j in enumerate(mapping.joints):
        if motion.skeleton.end_site[j]:
            canon_rot[:, c] = rotations[:, motion.skeleton.parents[j]]
    # The hand turns at the palm, the joint the retarget drives: the hand tip (an end site or
    # a finger's last joint) takes the palm's frame. A finger joint's frame adds the fingers'
    # own curl, which the retarget keeps at rest and a rig without fingers cannot show.
    for side in ("l", "r"):
        wrist = int(mapping.joints[CANONICAL_INDEX[f"{side}_wrist"]])
        tip = CANONICAL_INDEX[f"{side}_hand_tip"]
        canon_rot[:, tip] = rotations[:, palm(motion.skeleton, wrist, int(mapping.joints[tip]))]
    if not np.all(np.isfinite(canon_pos)) or not np.all(np.isfinite(canon_rot)):
        raise ParseError("forward kinematics produced non-finite joint positions")

    height = body_height(motion, mapping.joints, head_joint=mapping.head_joint, held=mapping.held)
    if not height > 0:
        raise ParseError(
            "the skeleton has zero height (all bones between ankle and head are empty)"
        )
    if not np.isfinite(height):
        # A bone longer than any float (1e308 in an offset or a position channel): every
        # check made in body heights would pass, and the descriptors overflow.
        with np.errstate(over="ignore", invalid="ignore"):
            lengths = bone_lengths(motion)
        longest = int(np.argmax(np.nan_to_num(lengths, nan=np.inf)))
        size = float(lengths[longest])
        amount = f"{size:.3g} units long" if np.isfinite(size) else "longer than any number"
        raise ParseError(
            f"the bone to joint {motion.skeleton.names[longest]!r} is {amount} in the first "
            "frame, so the body's height is no finite number: an overflowed value (such as "
            "1e308) in its offset or position channel"
        )
    # Implausible frames (sentinel values, a teleporting root) at either end go like lead-in
    # frames; in the middle they are kept and reported.
    implausible = implausible_frames(canon_pos, height)
    start, stop = plausible_span(implausible)
    if start or stop < len(implausible):
        motion = motion.slice_frames(start, stop)
    lead_in = count_lead_in_frames(motion)
    canon_pos = canon_pos[start + lead_in : stop]
    canon_rot = canon_rot[start + lead_in : stop]
    middle = int(implausible[start:stop].sum())
    if start:
        warnings.append(f"{start} implausible frames at the start dropped")
    if stop < len(implausible):
        warnings.append(f"{len(implausible) - stop} implausible frames at the end dropped")
    if middle:
        warnings.append(
            f"{middle} frames in the middle look implausible (joints far from the body or the "
            "root jumping); kept"
        )
    lead_in += start
    frames = _pelvis_frames(
        motion, mapping.joints, canon_rot, rest_is_a_figure=mapping.pose == "rest pose"
    )
    if _holds_one_pose(canon_pos):
        # A rig saved with frames that all hold one pose, or a pose saved as a clip: stored,
        # as what it is.
        held = "one frame" if len(canon_pos) == 1 else f"all {len(canon_pos)} frames the same"
        warnings.append(f"a still pose ({held}): no motion, stored as a pose")
    carried = carried_frames(frames, canon_pos)
    if carried is not frames:
        frames = carried
        warnings.append(
            "the pelvis joint's rotation does not carry the hips (joints at the pelvis turn "
            "them back): the body's axes are read from the joints' positions"
        )
    return Body(
        positions=canon_pos,
        rotations=canon_rot,
        frame_time=motion.frame_time,
        height=height,
        pelvis_frames=frames,
        world_up=clip_vertical(
            _world_up(frames), motion.skeleton, mapping, canon_pos, height, frames[:, :, 1]
        ),
        skeleton_family=mapping.family,
        lead_in_frames=lead_in,
        mapping=mapping,
        warnings=tuple(warnings),
    )


def carried_frames(frames: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """The ``(F, 3, 3)`` pelvis frames, or where the pelvis joint's rotation does not carry
    the hips in the ``(F, C, 3)`` canonical positions (its children turn it back), the
    frames read from the positions (:func:`~app.motion.body_axes.pelvis_turns_with_hips`,
    each within 30 degrees in most frames, as the rest pose is asked)."""
    if pelvis_turns_with_hips(frames, positions, within=_REST_SHOWN, share=_REST_SHARE):
        return frames
    return frames_from_positions(positions, frames)


def _holds_one_pose(positions: np.ndarray) -> bool:
    """Whether every frame of ``(F, C, 3)`` canonical positions is the first (to a
    millionth of the body's extent: what float32 text files round to); one frame too."""
    extent = float(np.ptp(positions[0], axis=0).max())
    return bool(np.all(np.abs(positions - positions[:1]) <= 1e-6 * max(extent, 1e-300)))


def _spread_frames(motion: Motion, count: int = _POSE_FRAMES) -> tuple[list[int], Motion]:
    """Up to ``count`` frames evenly spread over the clip (first and last included), and the
    clip cut down to them."""
    total = motion.frame_count
    frames = sorted({round(i * (total - 1) / (count - 1)) for i in range(count)})
    picked = dataclasses.replace(
        motion,
        root_translation=motion.root_translation[frames],
        local_rotations=motion.local_rotations[frames],
        local_translations=None
        if motion.local_translations is None
        else motion.local_translations[frames],
    )
    return frames, picked


def _frame_poses(motion: Motion) -> Iterator[tuple[str, np.ndarray]]:
    """``(J, 3)`` world positions at a few frames across the clip, for rigs whose rest pose
    is not a standing figure (joint orientation in rotations). Computed when the mapper
    first asks, all in one pass: it maps from one and lets several vote on the sides."""
    frames, picked = _spread_frames(motion)
    _, positions = forward_kinematics(picked)
    for f, pose in zip(frames, positions, strict=True):
        yield f"frame {f}", pose


def body_height(
    motion: Motion,
    canonical: np.ndarray,
    *,
    head_joint: int = -1,
    held: tuple[tuple[int, int, float], ...] = (),
) -> float:
    """Leg plus trunk bone-path length in file units (see module docstring).

    The trunk ends at the head *joint* (``head_joint`` when given): an end effector beyond
    it (the top of the head) does not count, so the height means the same with or without.
    ``held``: ``(joint, limb end, distance)`` for joints that IK holds at a limb's end
    (:attr:`~app.motion.skeleton_map.SkeletonMap.held`): their bone is that distance.
    """
    lengths = bone_lengths(motion).copy()
    parents = motion.skeleton.parents.copy()
    for joint, end, distance in held:
        parents[joint], lengths[joint] = end, distance

    def path_length(top: str, bottom: str) -> float:
        j, stop, total = (
            int(canonical[CANONICAL_INDEX[bottom]]),
            int(canonical[CANONICAL_INDEX[top]]),
            0.0,
        )
        if bottom == "head" and head_joint >= 0:
            j = head_joint
        while j != stop and j >= 0:
            total += float(lengths[j])
            j = int(parents[j])
        return total

    legs = [path_length(f"{s}_hip", f"{s}_ankle") for s in ("l", "r")]
    return float(np.mean(legs)) + path_length("pelvis", "head")


def _pelvis_frames(
    motion: Motion, canonical: np.ndarray, rotations: np.ndarray, *, rest_is_a_figure: bool
) -> np.ndarray:
    """``(F, 3, 3)`` pelvis-fixed body frames; columns lateral (left), up, forward.

    ``canonical`` is the ``(C,)`` source joint index per canonical joint and ``rotations`` the
    ``(F, C, 3, 3)`` world rotations of the canonical joints; ``rest_is_a_figure``: the
    mapping was read from the rest pose (see :func:`pelvis_basis`).
    """
    basis = pelvis_basis(motion, canonical, rest_is_a_figure=rest_is_a_figure)
    return rotations[:, CANONICAL_INDEX["pelvis"]] @ basis


def pelvis_basis(motion: Motion, canonical: np.ndarray, *, rest_is_a_figure: bool) -> np.ndarray:
    """``(3, 3)`` body axes (columns lateral, up, forward) in the pelvis joint's coordinates.

    From the rest pose (:func:`rest_pelvis_basis`), unless the mapper found no figure there
    (``rest_is_a_figure`` False: it read the take's frames) and fewer than half of a dozen
    frames spread over the clip show the rest pose's axes, seen from the pelvis (up and
    lateral each within 30 degrees): then the rest pose is no pose of this body at all — a
    writer whose bones lie along odd axes, all-zero rotations meaning some other pose, as
    pose estimators write — and the axes are the frames' own (:func:`frames_basis`: up
    from the world's up seen from the pelvis when most frames stand, else from the
    trunk). A rest pose most
    frames agree with is kept, so a standing rig that merely starts seated reads as before;
    one frame agreeing is not enough (a rest pose in random axes points the trunk anywhere,
    and a take that bends or turns the trunk meets it in some frame by chance). Nor are the
    frames asked where the bones the pelvis carries show the rest pose's axes
    (:func:`~app.motion.body_axes.pelvis_carries`): every frame then shows them by its
    pelvis, and a take whose trunk leans throughout (a sneak, a bow, a copy of a leaning
    walk on such a rig) is read in the same axes as the skeleton's other takes.
    """
    rest = rest_pelvis_basis(motion, canonical)
    if rest_is_a_figure or pelvis_carries(motion.skeleton, canonical, rest, within=_REST_SHOWN):
        return rest
    _, picked = _spread_frames(motion)
    rotations, positions = forward_kinematics(picked, joints=canonical)
    pelvis = rotations[:, canonical[CANONICAL_INDEX["pelvis"]]]
    try:
        shown = [pose_basis(positions[[i]], pelvis[[i]], canonical) for i in range(len(positions))]
        agreeing = sum(
            float(rest[:, 0] @ axes[:, 0]) >= _REST_SHOWN
            and float(rest[:, 1] @ axes[:, 1]) >= _REST_SHOWN
            for axes in shown
        )
        if agreeing >= _REST_SHARE * len(shown) and _rest_trunk_across(motion, canonical, rest):
            return rest
        return frames_basis(positions, pelvis, canonical)
    except ParseError:  # some frame shows no body: the rest pose's axes, as before
        return rest


def _rest_trunk_across(motion: Motion, canonical: np.ndarray, rest: np.ndarray) -> bool:
    """Whether the rest pose's trunk (pelvis -> neck) stands across its hips: not within the
    vote's 30 degrees (:data:`_REST_SHOWN`) of the ``rest`` basis's lateral. A figure's trunk
    does; a rest pose whose every bone lies along one axis (joint-orient writers: each OFFSET
    along its bone's own x) puts the trunk along the hips, and the up read from what is left
    of it (a spine bone's small sideways part) is no up at all: then the frames tell it."""
    at = rest_pose(motion.skeleton)
    trunk = at[canonical[CANONICAL_INDEX["neck"]]] - at[canonical[CANONICAL_INDEX["pelvis"]]]
    return abs(float(trunk @ rest[:, 0])) <= _REST_SHOWN * float(np.linalg.norm(trunk))


def rest_axes_hold(motion: Motion, canonical: np.ndarray, *, rest_is_a_figure: bool) -> bool:
    """Whether :func:`pelvis_basis` reads every take of ``motion``'s skeleton in its rest
    pose's axes, whatever the take's frames do (the rest pose is a figure, or the bones the
    pelvis carries show its axes); ``canonical`` ``(C,)`` the joint per canonical joint."""
    if rest_is_a_figure:
        return True
    rest = rest_pelvis_basis(motion, canonical)
    return pelvis_carries(motion.skeleton, canonical, rest, within=_REST_SHOWN)


def rest_pelvis_basis(motion: Motion, canonical: np.ndarray) -> np.ndarray:
    """``(3, 3)`` body axes (columns lateral, up, forward) in the pelvis joint's coordinates.

    Found in the rest pose of the skeleton's offsets; a rig whose offsets are empty and whose
    shape lives in per-frame position channels uses those of its first frame instead; a rig
    whose rest pose shows no side at all (joint orientation in the rotations and both hips
    at the pelvis: the legs coincide) takes the directions, seen from the pelvis, averaged
    over a dozen frames of the clip.
    """
    skeleton = motion.skeleton
    candidates = [skeleton.offsets]
    if motion.local_translations is not None:
        candidates.append(motion.local_translations[0])
    problem = ""
    for offsets in candidates:
        rest = np.zeros((skeleton.joint_count, 3))
        for j in range(1, skeleton.joint_count):
            rest[j] = rest[skeleton.parents[j]] + offsets[j]
        try:
            return pose_basis(rest[None], np.eye(3)[None], canonical)
        except ParseError as why:
            problem = str(why)
    # Joint orientation in the rotations and both hips at the pelvis: the rest pose's legs
    # coincide. Where the legs part in the frames, seen from the pelvis, tells the sides.
    _, picked = _spread_frames(motion)
    rotations, positions = forward_kinematics(picked, joints=canonical)
    try:
        return pose_basis(positions, rotations[:, canonical[CANONICAL_INDEX["pelvis"]]], canonical)
    except ParseError:
        raise ParseError(problem) from None


def _world_up(pelvis_frames: np.ndarray) -> np.ndarray:
    """``(3,)`` vertical axis of the world (see module docstring)."""
    mean_up = pelvis_frames[:, :, 1].mean(axis=0)
    norm = np.linalg.norm(mean_up)
    if norm < 1e-9:
        return np.array([0.0, 1.0, 0.0])
    axis = int(np.argmax(np.abs(mean_up)))
    snapped = np.zeros(3)
    snapped[axis] = np.sign(mean_up[axis])
    return snapped


__all__ = ["CANONICAL_JOINTS", "Body", "build_body", "carried_frames"]
