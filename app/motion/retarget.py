"""One humanoid's motion on another's skeleton, through the canonical joints both map to.

The structural mapping (:mod:`app.motion.skeleton_map`) says, for both skeletons, which joint
is the pelvis, each hip, knee, shoulder... That is all retargeting needs.

**Rotations, aligned by the two reference poses.** Each skeleton has a reference pose: its
rest pose, or for a rig whose rest pose is not a standing figure the pose the mapper read it
from. A driven target joint (one per canonical bone: pelvis, spine, chest, neck, head,
clavicles, upper arms, forearms, hands, thighs, shins, feet, toes where both have them)
turns as its source joint turned since the source's reference pose::

    G_target(f) = W^T · G_source(f) · Q_source^T · A · Q_target

``Q`` are the joints' world rotations in the reference poses, ``A`` takes the target's
reference bone onto the source's: first the whole body (``B_source B_target^T`` from the
two bodies' lateral/up/forward axes), then the smallest rotation bringing the bone's
direction onto the source bone's. So a T-pose rig driven by an A-pose capture lifts its arms
to where the capture's are, and since the smallest rotation has no twist about the bone, a
bone's roll never twists. ``W`` changes world axes from the source's up to the target's
(Y-up capture on a Z-up rig), a quarter turn or none.

**Head and hand.** The head joint turns as the source's head joint does, whatever lies
beyond either (a head-top end effector on one rig, nothing on the other): a chain's end is
only aimed at, and before this the head of such a pair stayed at rest on its neck, so the
re-uploaded clip's head had no motion at all (``kinetic``'s head DOFs 0). Its reference
alignment takes its up (head joint -> top of the head, or neck -> head) onto the source
head's. The hand's orientation is carried by the palm — the first joint past the wrist
where the fingers branch, or the joint the hand tip hangs from — which is driven by the
source's palm, so a rig that bends the hand below its wrist joint (wrist -> hand ->
fingers) passes that bend on.

**Directions exact.** Where the source has joints the target lacks between two canonical
joints (a spine of five against one of three), the transferred rotation alone would point
the target's bone a little off; a last per-frame swing turns each driven bone (except the
hand, whose direction depends on the fingers) onto the source bone's world direction.
A limb bone both split into as many pieces (twist joints at other points) then turns as one,
so the bone from mapped joint to mapped joint points as the source's (:func:`_turn_split_limbs`).

**Everything else at rest.** Unmapped target joints (fingers, face, twist bones, a static
root above the pelvis) keep their reference-pose local rotation; offsets are the rig's own,
so bone lengths are exactly the rig's.

**Root.** The pelvis travels as the source's pelvis, scaled about the world origin by the
ratio of the legs' bone paths (hip -> knee -> ankle), then moved up or down per frame so that
the target's foot points that are on the floor in the source (the standing foot) are where
the source's are (scaled), and nothing is below the source's lowest point: feet on the
source's floor, neither sinking nor floating, and a swinging foot that is lower on the rig
(a longer shin) does not lift the standing one off the floor. At frames with no point on
the floor (a jump) the lowest points match. A pelvis below a static top joint gets the
travel as per-frame offsets.

**Planted feet.** Where the legs' proportions differ from the source's (a longer shin, wider
hips), the same directions and the scaled travel move a planted foot over the floor. The
pelvis's horizontal path is corrected instead of the legs: at each frame where foot points
(ankles, toes) are on the floor in both (within :data:`ON_FLOOR` of the body height), the path
takes the mean of how much farther they moved over the floor than the source's (scaled) did
back, so a foot on the floor moves as the source's moves — not at all when the source's
stands, a slide where the source slides. Every bone keeps the source's direction; the
target travels as far as its own legs carry it.

What the pelvis cannot hold (two points down that disagree: both feet, or the heel and
toe of a long foot) the legs take up: each planted foot (contact from the source) is held
where the source's stands by turning its leg about the hip, by at most a few degrees so
limb directions stay within the quality bar (:mod:`app.motion.retarget_feet`).

**Swinging feet clear the floor.** A foot long for its leg (a toe tip where the source has
the ball of its foot) points its toe lower than the source's when it swings toe-down; where
the source's toe is off the floor and the target's is lower, the foot is pitched up about
the ankle until the toe is as high as the source's (then the pelvis goes back on the floor).

A capture with left-handed geometry (``SkeletonMap.mirrored``) is first reflected as the
describer reflects it, so left stays left.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from app.motion.body import body_height
from app.motion.ground import FOOT_POINTS, ON_FLOOR, body_frame, snap_axis
from app.motion.kinematics import forward_kinematics
from app.motion.model import Motion, Skeleton
from app.motion.retarget_feet import Pose, hold_planted_feet
from app.motion.skeleton_map import CANONICAL_INDEX, SkeletonMap
from app.motion.transforms import reflect

# Canonical bones whose base joint the retarget drives: (base, aim) canonical names.
# ``None`` aims: the joint's rotation is transferred, its direction not corrected.
# Canonical chains whose joints the retarget drives, top first: (base, end) canonical names.
# Joints between the two are driven too when both skeletons have as many there (a spine of
# three against three); ``None``: the base's rotation is transferred, its direction not
# corrected (the pelvis, whose children go three ways; the hand, whose direction depends on
# the fingers, which stay at rest).
_CHAINS: tuple[tuple[str, str | None], ...] = (
    ("pelvis", None),
    ("pelvis", "spine"),
    ("spine", "chest"),
    ("chest", "neck"),
    ("neck", "head"),
    *(
        pair
        for side in ("l", "r")
        for pair in (
            ("chest", f"{side}_shoulder"),
            (f"{side}_shoulder", f"{side}_elbow"),
            (f"{side}_elbow", f"{side}_wrist"),
            (f"{side}_wrist", None),
            ("pelvis", f"{side}_hip"),
            (f"{side}_hip", f"{side}_knee"),
            (f"{side}_knee", f"{side}_ankle"),
            (f"{side}_ankle", f"{side}_toe"),
        )
    ),
)
# The limbs' long bones: one rigid bone in the body however many pieces a rig splits it
# into (twist joints), so it turns as one (:func:`_turn_split_limbs`). The spine's pieces are
# a chain that bends by design and keep their own directions.
_LIMB_BONES = frozenset(
    (f"{side}_{top}", f"{side}_{end}")
    for side in ("l", "r")
    for top, end in (("shoulder", "elbow"), ("elbow", "wrist"), ("hip", "knee"), ("knee", "ankle"))
)
_TINY = 1e-9


@dataclass(frozen=True)
class _Driven:
    """One driven target joint and where its rotation comes from."""

    target: int
    source: int
    target_aim: int | None  # target joint the bone points at (None: no direction fix)
    source_aim: int | None
    align_like: int | None = None  # target joint whose reference alignment this one shares
    # Bones (target from, to, source from, to) aligned in the reference poses, for a joint
    # whose direction is not fixed per frame (the head: its up onto the source head's up).
    align_bones: tuple[int, int, int, int] | None = None


@dataclass(frozen=True)
class _Limb:
    """A limb bone both skeletons split into as many pieces (twist joints), whose
    pieces are driven one by one: ``pieces`` the target joints from the bone's base, down to
    the target joint ``end``; ``source_base`` -> ``source_end`` the source's bone."""

    pieces: tuple[int, ...]
    end: int
    source_base: int
    source_end: int


def swing(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``(..., 3, 3)`` smallest rotations taking directions ``a`` onto ``b`` (``(..., 3)``,
    any length; the identity where either is zero, a half turn about a perpendicular where
    they are opposite)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    na = np.linalg.norm(a, axis=-1, keepdims=True)
    nb = np.linalg.norm(b, axis=-1, keepdims=True)
    zero = (na[..., 0] < _TINY) | (nb[..., 0] < _TINY)
    a = a / np.where(na < _TINY, 1.0, na)
    b = b / np.where(nb < _TINY, 1.0, nb)
    axis = np.cross(a, b)
    cos = np.clip(np.sum(a * b, axis=-1), -1.0, 1.0)
    sin = np.linalg.norm(axis, axis=-1)
    opposite = (cos < 0) & (sin < 1e-8)
    if np.any(opposite):
        # Any axis perpendicular to a: the coordinate axis least along a, crossed with it.
        least = np.argmin(np.abs(a), axis=-1)
        helper = np.eye(3)[least]
        perpendicular = np.cross(a, helper)
        perpendicular /= np.linalg.norm(perpendicular, axis=-1, keepdims=True)
        axis = np.where(opposite[..., None], perpendicular, axis)
        sin = np.where(opposite, 1.0, sin)
        # The half turn: rotation angle pi about the unit perpendicular.
    unit = axis / np.where(sin[..., None] < 1e-15, 1.0, sin[..., None])
    angle = np.arctan2(np.where(opposite, 0.0, sin), cos)
    angle = np.where(opposite, np.pi, angle)
    # Rodrigues, I + s K + (1 - c) K^2 with K^2 = u u^T - |u|^2 I, entry by entry (no
    # per-rotation matrix product).
    s, versed = np.sin(angle), 1.0 - np.cos(angle)
    x, y, z = unit[..., 0], unit[..., 1], unit[..., 2]
    scaled = versed[..., None] * unit
    out = scaled[..., :, None] * unit[..., None, :]
    diagonal = 1.0 - np.sum(scaled * unit, axis=-1)
    for i in range(3):
        out[..., i, i] += diagonal
    out[..., 0, 1] -= s * z
    out[..., 0, 2] += s * y
    out[..., 1, 0] += s * z
    out[..., 1, 2] -= s * x
    out[..., 2, 0] -= s * y
    out[..., 2, 1] += s * x
    out[zero] = np.eye(3)
    return out


def axis_change(up_from: np.ndarray, up_to: np.ndarray) -> np.ndarray:
    """``(3, 3)`` the quarter turn (or none, or a half turn) about a coordinate axis taking
    the signed coordinate axis ``up_from`` onto ``up_to``."""
    return np.rint(swing(up_from, up_to))


def reference_frame(mapping: SkeletonMap) -> int | None:
    """The frame the mapper read the skeleton from (``None``: the rest pose)."""
    if mapping.pose.startswith("frame "):
        try:
            return int(mapping.pose.split()[1])
        except (IndexError, ValueError):
            return 0
    return None


def reference_pose(motion: Motion, mapping: SkeletonMap) -> Motion:
    """A rig made of ``motion``'s skeleton: one frame holding its reference pose, the rest
    pose (identity rotations) or, when the mapper read the skeleton from a frame because the
    rest pose is not a standing figure, that frame's rotations. Per-frame offsets are dropped:
    a rig's bones are its offsets."""
    frame = reference_frame(mapping)
    count = motion.skeleton.joint_count
    if frame is None or motion.frame_count == 0:
        rotations = np.broadcast_to(np.eye(3), (1, count, 3, 3)).copy()
        frame = 0
    else:
        frame = min(max(frame, 0), motion.frame_count - 1)
        rotations = motion.local_rotations[frame : frame + 1].copy()
    root = (
        motion.root_translation[frame : frame + 1].copy()
        if motion.frame_count
        else motion.skeleton.offsets[None, 0].copy()
    )
    return Motion(
        skeleton=motion.skeleton,
        frame_time=motion.frame_time,
        root_translation=root,
        local_rotations=rotations,
        source_format=motion.source_format,
        length_unit=motion.length_unit,
    )


def _path_length(motion: Motion, top: int, bottom: int) -> float:
    """Summed bone lengths from joint ``bottom`` up to its ancestor ``top``."""
    parents = motion.skeleton.parents
    offsets = motion.skeleton.offsets
    total, j = 0.0, bottom
    while j != top and j > 0:
        total += float(np.linalg.norm(offsets[j]))
        j = int(parents[j])
    return total


def leg_length(motion: Motion, mapping: SkeletonMap) -> float:
    """Mean bone path hip -> ankle of the two legs, in the skeleton's units."""
    lengths = [
        _path_length(
            motion,
            int(mapping.joints[CANONICAL_INDEX[f"{s}_hip"]]),
            int(mapping.joints[CANONICAL_INDEX[f"{s}_ankle"]]),
        )
        for s in ("l", "r")
    ]
    return float(np.mean(lengths))


def _between(parents: np.ndarray, top: int, bottom: int) -> list[int]:
    """Joints strictly between ``bottom`` and its ancestor ``top``, bottom first."""
    out, j = [], int(parents[bottom])
    while j != top and j >= 0:
        out.append(j)
        j = int(parents[j])
    return out if j == top else []


def _palm(skeleton: Skeleton, wrist: int, tip: int) -> int:
    """The joint that carries the hand's orientation: on the path from ``wrist`` to the hand
    tip, the first joint where the hand branches (into fingers), else the joint the tip hangs
    from (the wrist itself when there is nothing between)."""
    if tip == wrist:
        return wrist
    path = [wrist, *_between(skeleton.parents, wrist, tip)[::-1], tip]
    for joint in path[:-1]:
        if len(skeleton.children(joint)) > 1:
            return joint
    return path[-2]


def _driven(
    source: Motion, source_map: SkeletonMap, target: Motion, target_map: SkeletonMap
) -> tuple[list[_Driven], list[_Limb]]:
    """The driven target joints, each with its source joint and the joints they aim at (see
    :data:`_CHAINS`); the head joint is a chain end of its own where the head point is an end
    effector beyond it. Target-first wins: a joint is driven by the first chain naming it.
    Also the limb bones both split into as many pieces, driven piece by piece."""
    s_parents, t_parents = source.skeleton.parents, target.skeleton.parents
    out: list[_Driven] = []
    limbs: list[_Limb] = []
    seen: set[int] = set()

    def add(t: int, s: int, t_aim: int | None, s_aim: int | None, like: int | None) -> None:
        if t in seen or target.skeleton.end_site[t] or source.skeleton.end_site[s]:
            return
        if t_aim is not None and (t_aim == t or s_aim == s or s_aim is None):
            t_aim = s_aim = None
        seen.add(t)
        out.append(_Driven(t, s, t_aim, s_aim, like))

    def joints(mapping: SkeletonMap, name: str) -> list[int]:
        """The canonical joint ``name`` as one or two joints (neck -> head joint -> head)."""
        j = int(mapping.joints[CANONICAL_INDEX[name]])
        if name == "head" and 0 <= mapping.head_joint != j:
            return [mapping.head_joint, j]
        return [j]

    for base, end in _CHAINS:
        t_base, s_base = joints(target_map, base)[-1], joints(source_map, base)[-1]
        if end is None:
            # The hand turns with the forearm's alignment: its own direction depends on
            # how the fingers are held, which differs between any two reference poses.
            like = None
            if base.endswith("_wrist"):
                like = int(target_map.joints[CANONICAL_INDEX[base.replace("wrist", "elbow")]])
                # The palm (where the fingers branch) carries the hand's orientation; a rig
                # may turn the hand there rather than at the wrist (wrist -> hand -> fingers).
                tip = CANONICAL_INDEX[base.replace("wrist", "hand_tip")]
                add(
                    _palm(target.skeleton, t_base, int(target_map.joints[tip])),
                    _palm(source.skeleton, s_base, int(source_map.joints[tip])),
                    None,
                    None,
                    like,
                )
            add(t_base, s_base, None, None, like)
            continue
        t_stops, s_stops = [t_base, *joints(target_map, end)], [s_base, *joints(source_map, end)]
        if len(t_stops) != len(s_stops):
            # One has a head joint with an end effector beyond it, the other a head joint
            # only: the joints pair up (the neck aims at the head joint).
            t_stops, s_stops = t_stops[:2], s_stops[:2]
        t_path, s_path = [t_stops[0]], [s_stops[0]]
        for i in range(1, len(t_stops)):
            t_mid = _between(t_parents, t_stops[i - 1], t_stops[i])[::-1]
            s_mid = _between(s_parents, s_stops[i - 1], s_stops[i])[::-1]
            if t_mid and len(t_mid) == len(s_mid):
                if (base, end) in _LIMB_BONES:
                    limbs.append(
                        _Limb((t_stops[i - 1], *t_mid), t_stops[i], s_stops[i - 1], s_stops[i])
                    )
                t_path.extend(t_mid)
                s_path.extend(s_mid)
            t_path.append(t_stops[i])
            s_path.append(s_stops[i])
        for i in range(len(t_path) - 1):
            add(t_path[i], s_path[i], t_path[i + 1], s_path[i + 1], None)
    # The head joint turns as the other's head joint does (a chain's end is only aimed at,
    # and a head joint with no end effector beyond it ends the chain): it carries the face,
    # whatever points lie beyond it. Its reference alignment takes its up (head joint -> top
    # of the head, or neck -> head where nothing lies beyond) onto the source head's up.
    t_head, s_head = joints(target_map, "head"), joints(source_map, "head")
    t_neck = int(target_map.joints[CANONICAL_INDEX["neck"]])
    s_neck = int(source_map.joints[CANONICAL_INDEX["neck"]])
    t_up = (t_head[0], t_head[1]) if len(t_head) > 1 else (t_neck, t_head[0])
    s_up = (s_head[0], s_head[1]) if len(s_head) > 1 else (s_neck, s_head[0])
    before = len(out)
    add(t_head[0], s_head[0], None, None, t_neck)
    if len(out) > before:
        out[-1] = replace(out[-1], align_bones=(*t_up, *s_up))
    return out, limbs


def retarget(
    source: Motion,
    source_map: SkeletonMap,
    target: Motion,
    target_map: SkeletonMap,
    *,
    hold_feet: bool = True,
) -> Motion:
    """``source``'s motion on ``target``'s skeleton (see the module docstring).

    Parameters
    ----------
    source:
        The clip (``F`` frames, ``J_s`` joints) and ``source_map`` its mapping.
    target:
        The rig: its skeleton and, in frame 0, its reference pose (local rotations; the
        identity for a rig whose rest pose is a standing figure); ``target_map`` its mapping.
    hold_feet:
        Whether the legs hold planted feet (:mod:`app.motion.retarget_feet`); off, only the
        pelvis's path does.

    Returns
    -------
    Motion
        ``F`` frames at the source's rate on ``target.skeleton`` (same names, parents,
        offsets, end sites), in the target's units and world axes.
    """
    if target_map.mirrored:
        mirrored = retarget(
            source,
            source_map,
            reflect(target, axis=target_map.mirror_axis),
            _unmirrored(target_map),
            hold_feet=hold_feet,
        )
        return reflect(mirrored, axis=target_map.mirror_axis)
    if source_map.mirrored:
        source = reflect(source, axis=source_map.mirror_axis)

    driven, limbs = _driven(source, source_map, target, target_map)
    # Only the source joints the retarget reads: driven, aimed at, canonical.
    s_needed = {int(j) for j in source_map.joints}
    for d in driven:
        s_needed.update(j for j in (d.source, d.source_aim) if j is not None)
        if d.align_bones is not None:
            s_needed.update(d.align_bones[2:])
    s_rot, s_pos = forward_kinematics(source, joints=sorted(s_needed))  # (F, Js, 3, 3), (F, Js, 3)
    s_ref = reference_frame(source_map)
    if s_ref is None:
        s_ref_rot = np.broadcast_to(np.eye(3), s_rot.shape[1:])
        _, rest = forward_kinematics(_rest_of(source))
        s_ref_pos = rest[0]
    else:
        s_ref = min(max(s_ref, 0), source.frame_count - 1)
        s_ref_rot, s_ref_pos = s_rot[s_ref], s_pos[s_ref]
    t_ref_motion = target.slice_frames(0, 1)
    t_ref_motion = Motion(
        skeleton=target.skeleton,
        frame_time=target.frame_time,
        root_translation=t_ref_motion.root_translation,
        local_rotations=t_ref_motion.local_rotations,
    )
    t_ref_rot_all, t_ref_pos_all = forward_kinematics(t_ref_motion)
    t_ref_rot, t_ref_pos = t_ref_rot_all[0], t_ref_pos_all[0]

    s_canon = s_pos[:, source_map.joints]  # (F, C, 3)
    b_source = body_frame(s_ref_pos[source_map.joints])
    b_target = body_frame(t_ref_pos[target_map.joints])
    body = b_source @ b_target.T  # target reference body -> source reference body
    s_up_vec = s_canon[:, CANONICAL_INDEX["neck"]] - s_canon[:, CANONICAL_INDEX["pelvis"]]
    s_up = snap_axis(
        (s_up_vec / np.maximum(np.linalg.norm(s_up_vec, axis=1, keepdims=True), _TINY)).mean(axis=0)
    )
    t_up = snap_axis(b_target[:, 1])
    world = axis_change(t_up, s_up)  # target world axes -> source world axes
    world_t = world.T

    frames = source.frame_count
    count = target.skeleton.joint_count
    parents = target.skeleton.parents
    # Constant per driven joint: C = Q_source^T · A · Q_target, so G = W^T · G_source · C.
    aligned: dict[int, np.ndarray] = {}
    constants = np.empty((len(driven), 3, 3))
    for i, d in enumerate(driven):
        align = aligned.get(d.align_like, body) if d.align_like is not None else body
        if d.align_bones is not None:
            t_from, t_to, s_from, s_to = d.align_bones
            t_bone = t_ref_pos[t_to] - t_ref_pos[t_from]
            s_bone = s_ref_pos[s_to] - s_ref_pos[s_from]
            align = swing(body @ t_bone, s_bone) @ body
        if d.target_aim is not None and d.source_aim is not None:
            t_bone = t_ref_pos[d.target_aim] - t_ref_pos[d.target]
            s_bone = s_ref_pos[d.source_aim] - s_ref_pos[d.source]
            align = swing(body @ t_bone, s_bone) @ body
        aligned[d.target] = align
        constants[i] = s_ref_rot[d.source].T @ align @ t_ref_rot[d.target]
    targets = np.array([d.target for d in driven], dtype=np.int64)
    sources = np.array([d.source for d in driven], dtype=np.int64)
    rotation = s_rot[:, sources] @ constants  # (F, D, 3, 3)
    if not np.array_equal(world_t, np.eye(3)):  # a quarter turn between the up axes
        rotation = world_t @ rotation
    # Directions exact: one swing per frame and driven bone, all at once.
    fixed = [i for i, d in enumerate(driven) if d.target_aim is not None]
    if fixed:
        t_aims = np.array([driven[i].target_aim for i in fixed], dtype=np.int64)
        s_aims = np.array([driven[i].source_aim for i in fixed], dtype=np.int64)
        t_bones = t_ref_pos[t_aims] - t_ref_pos[targets[fixed]]  # (K, 3) in the reference
        local_bones = np.swapaxes(t_ref_rot[targets[fixed]], -1, -2) @ t_bones[:, :, None]
        now = (rotation[:, fixed] @ local_bones)[..., 0]  # (F, K, 3)
        wanted = (s_pos[:, s_aims] - s_pos[:, sources[fixed]]) @ world
        rotation[:, fixed] = swing(now, wanted) @ rotation[:, fixed]
    _turn_split_limbs(limbs, driven, rotation, t_ref_rot, t_ref_pos, s_pos, world)

    # Every other joint keeps its reference local rotation (its world rotation is its
    # nearest driven ancestor's times the constant reference rotation between the two), so
    # only the driven joints' local rotations change per frame.
    anchor = np.full(count, -1, dtype=np.int64)
    slot = {int(t): i for i, t in enumerate(targets)}
    for j in range(count):
        if j in slot:
            anchor[j] = j
        elif parents[j] >= 0:
            anchor[j] = anchor[parents[j]]
    up_index = np.where(parents < 0, 0, parents)
    ref_local = np.swapaxes(t_ref_rot[up_index], -1, -2) @ t_ref_rot
    ref_local[0] = t_ref_rot[0]
    local = np.empty((frames, count, 3, 3))
    local[:] = ref_local

    def world_of(joints: np.ndarray) -> np.ndarray:
        """``(F, K, 3, 3)`` world rotations of target ``joints`` ``(K,)``."""
        out = np.empty((frames, len(joints), 3, 3))
        is_driven = np.array([int(j) in slot for j in joints], dtype=bool)
        carried = (anchor[joints] >= 0) & ~is_driven
        floating = anchor[joints] < 0  # above every driven joint: at the reference
        out[:, is_driven] = rotation[:, [slot[int(j)] for j in joints[is_driven]]]
        if carried.any():
            anchors = anchor[joints[carried]]
            between = np.swapaxes(t_ref_rot[anchors], -1, -2) @ t_ref_rot[joints[carried]]
            out[:, carried] = rotation[:, [slot[int(a)] for a in anchors]] @ between
        out[:, floating] = t_ref_rot[joints[floating]]
        return out

    # A driven joint's local rotation: its parent's world rotation (a driven parent's as it
    # is, no copy) undone.
    up_slot = np.array([slot.get(int(parents[t]), -1) for t in targets], dtype=np.int64)
    by_driven = up_slot >= 0
    other = ~by_driven & (parents[targets] >= 0)
    top = parents[targets] < 0
    local[:, targets[top]] = rotation[:, top]
    if by_driven.any():
        local[:, targets[by_driven]] = (
            np.swapaxes(rotation[:, up_slot[by_driven]], -1, -2) @ rotation[:, by_driven]
        )
    if other.any():
        above = world_of(parents[targets[other]])
        local[:, targets[other]] = np.swapaxes(above, -1, -2) @ rotation[:, other]
    pelvis = int(target_map.joints[CANONICAL_INDEX["pelvis"]])
    # A pelvis below a static top joint: the world rotation its per-frame offset is in.
    above_pelvis = None if pelvis <= 0 else world_of(parents[[pelvis]])[:, 0]

    # The pelvis's path: the source's, scaled by the legs.
    scale = leg_length(target, target_map) / max(leg_length(source, source_map), _TINY)
    s_pelvis = s_canon[:, CANONICAL_INDEX["pelvis"]]
    pelvis_at = scale * s_pelvis @ world  # (F, 3)
    feet = target_map.joints[list(FOOT_POINTS)]
    feet_s = scale * s_canon[:, list(FOOT_POINTS)] @ world
    near = ON_FLOOR * body_height(target, target_map.joints, head_joint=target_map.head_joint)

    def assemble(pelvis_at: np.ndarray) -> Motion:
        return _assemble(
            target, source.frame_time, local, above_pelvis, pelvis, pelvis_at, t_ref_pos
        )

    pelvis_rot = world_of(np.array([pelvis]))[:, 0]

    # The legs' joints the feet's passes read (hips, ankles, toes and the hips' and ankles'
    # parents): their kinematics, with the pelvis at the origin, computed once, and again
    # only after a pass changes a leg's rotations.
    leg_joints = sorted(
        {
            int(j)
            for side in ("l", "r")
            for name in ("hip", "ankle", "toe")
            for j in (
                target_map.joints[CANONICAL_INDEX[f"{side}_{name}"]],
                parents[target_map.joints[CANONICAL_INDEX[f"{side}_{name}"]]],
            )
            if j >= 0
        }
    )
    origin = np.zeros((frames, 3))
    posed: list[Pose] = []

    def refresh() -> None:
        try:
            pose = _below(
                parents, target.skeleton.offsets, local, pelvis, pelvis_rot, origin, leg_joints
            )
        except ValueError:  # a leg joint not below the pelvis: the whole rig's kinematics
            rot, pos = forward_kinematics(assemble(origin), joints=leg_joints)
            pose = ({j: rot[:, j] for j in leg_joints}, {j: pos[:, j] for j in leg_joints})
        posed[:] = [pose]

    def legs(joints: Sequence[int], at: np.ndarray) -> Pose:
        """World rotations and positions of the target's ``joints`` (legs' joints) for the
        current ``local`` rotations, with the pelvis at ``at`` ``(F, 3)``."""
        rotations, positions = posed[0]
        return rotations, {int(j): positions[int(j)] + at for j in joints}

    refresh()

    def foot_points(at: np.ndarray) -> np.ndarray:
        """``(F, P, 3)`` the foot points with the pelvis at ``at``."""
        positions = legs([int(j) for j in feet], at)[1]
        return np.stack([positions[int(j)] for j in feet], axis=1)

    def onto(points: np.ndarray, stance: np.ndarray) -> np.ndarray:
        """``(F,)`` how far to move the pelvis up so that the lowest of the foot points
        ``points`` ``(F, P, 3)`` marked in ``stance`` ``(F, P)`` is where the source's
        lowest of them is (the pelvis's translation carries every joint below it)."""
        lowest = np.where(stance, points @ t_up, np.inf).min(axis=1)
        return np.where(stance, s_heights, np.inf).min(axis=1) - lowest

    # The standing foot sets the body's height: the target's foot points that are on the
    # floor in the source (within ``near`` of its floor) are put where the source's are, so
    # a swinging foot lower on the rig (a longer shin, a long foot's toe tip) does not lift
    # the standing one off the floor; the swinging toe is then raised (below). At frames
    # with no point on the floor (a jump) the lowest points match.
    s_heights = feet_s @ t_up  # (F, P)
    stance = s_heights - s_heights.min() < near
    stance[~stance.any(axis=1)] = True
    feet_t = foot_points(pelvis_at)
    lift = onto(feet_t, stance)
    pelvis_at = pelvis_at + lift[:, None] * t_up
    feet_t = feet_t + lift[:, None, None] * t_up
    # A swinging foot clears the floor as the source's does (a long foot points its toe lower).
    if _clear_swinging_toes(
        lambda joints: legs(joints, pelvis_at), target_map, parents, local, feet_s, t_up, near
    ):
        refresh()
        feet_t = foot_points(pelvis_at)
    # Then the lowest point is the source's lowest (feet neither sinking nor floating): this
    # moves only frames where a swinging foot could not clear the floor, or a jump's.
    lift = onto(feet_t, np.ones_like(stance))
    pelvis_at = pelvis_at + lift[:, None] * t_up
    feet_t = feet_t + lift[:, None, None] * t_up
    pelvis_at = pelvis_at + planted_feet_offsets(feet_t, feet_s, t_up, near)
    if hold_feet:
        held = hold_planted_feet(
            lambda joints: legs(joints, pelvis_at),
            target_map,
            parents,
            local,
            source.frame_time,
            feet_s,
            t_up,
            near,
            near / ON_FLOOR,
        )
        if held is not None:
            # A leg turned about its hip raises or lowers its foot a little: the standing
            # foot goes back onto the floor, and nothing sinks below the source's lowest.
            lift = onto(held, stance)
            lift = lift + onto(held + lift[:, None, None] * t_up, np.ones_like(stance))
            pelvis_at = pelvis_at + lift[:, None] * t_up
    return assemble(pelvis_at)


def _turn_split_limbs(
    limbs: Sequence[_Limb],
    driven: Sequence[_Driven],
    rotation: np.ndarray,
    t_ref_rot: np.ndarray,
    t_ref_pos: np.ndarray,
    s_pos: np.ndarray,
    world: np.ndarray,
) -> None:
    """Turn each split limb bone's pieces together (``rotation`` ``(F, D, 3, 3)``, the driven
    joints' world rotations, changed in place) so the bone, base to end, points as the
    source's does. Each piece points as its source piece, but where the source's pieces are
    bent against each other (a twist joint that also bends, a rest pose not in line), pieces
    split at other points than the source's add up to another direction: a thigh split at a
    quarter against a source's split at a fifth and bent 20 degrees points 8 degrees off.
    One turn for the whole bone keeps the bend between its pieces. ``t_ref_rot``
    ``(J, 3, 3)`` and ``t_ref_pos`` ``(J, 3)`` are the target's reference pose, ``s_pos``
    ``(F, J_s, 3)`` the source's positions, ``world`` the source-to-target axes change."""
    slot = {d.target: i for i, d in enumerate(driven)}
    for limb in limbs:
        if any(p not in slot or driven[slot[p]].target_aim is None for p in limb.pieces):
            continue  # a piece driven by another chain (none of the limbs' are)
        ends = [*limb.pieces[1:], limb.end]
        bone = np.zeros((rotation.shape[0], 3))
        for piece, end in zip(limb.pieces, ends, strict=True):
            local = t_ref_rot[piece].T @ (t_ref_pos[end] - t_ref_pos[piece])
            bone += rotation[:, slot[piece]] @ local
        wanted = (s_pos[:, limb.source_end] - s_pos[:, limb.source_base]) @ world
        turn = swing(bone, wanted)  # (F, 3, 3)
        for piece in limb.pieces:
            rotation[:, slot[piece]] = turn @ rotation[:, slot[piece]]


def _clear_swinging_toes(
    kinematics: Callable[[Sequence[int]], Pose],
    mapping: SkeletonMap,
    parents: np.ndarray,
    local: np.ndarray,
    source_feet: np.ndarray,
    up: np.ndarray,
    near: float,
) -> bool:
    """Pitch each foot up about its ankle (``local`` ``(F, J, 3, 3)`` changed in place)
    at frames where the source's toe is off the floor (``near`` or more above the lowest any
    source foot point gets) but the target's toe is lower than the source's: on a foot
    longer for its leg than the source's (a toe tip against a ball of the foot), the same
    foot direction puts the toe of a swinging foot on the floor, where it skims. The toe is
    raised to the source toe's height (or as near as the foot reaches); the foot keeps its
    heading. ``kinematics`` gives the legs' joints' world rotations and positions for the
    current ``local``; ``source_feet`` ``(F, P, 3)`` are the source's foot points (scaled,
    target axes, :data:`FOOT_POINTS` order) at the target's heights. Returns whether
    anything changed."""
    source_floor = float((source_feet @ up).min())
    changed = False
    for side in ("l", "r"):
        ankle = int(mapping.joints[CANONICAL_INDEX[f"{side}_ankle"]])
        toe = int(mapping.joints[CANONICAL_INDEX[f"{side}_toe"]])
        if ankle == toe or (not _between(parents, ankle, toe) and parents[toe] != ankle):
            continue
        rot, pos = kinematics([ankle, toe, int(parents[ankle])])
        wanted = source_feet[:, FOOT_POINTS.index(CANONICAL_INDEX[f"{side}_toe"])] @ up
        bone = pos[toe] - pos[ankle]  # (F, 3)
        length = np.linalg.norm(bone, axis=1)
        flat = bone - (bone @ up)[:, None] * up
        flat_length = np.linalg.norm(flat, axis=1)
        low = (
            (wanted - source_floor >= near)
            & (pos[toe] @ up < wanted)
            & (flat_length > 1e-6 * np.maximum(length, _TINY))
        )
        if not low.any():
            continue
        rise = np.clip((wanted[low] - pos[ankle][low] @ up) / length[low], -1.0, 1.0)
        heading = flat[low] / flat_length[low, None]
        raised = length[low, None] * (
            np.sqrt(1.0 - rise**2)[:, None] * heading + rise[:, None] * up
        )
        turn = swing(bone[low], raised)  # about the horizontal axis across the foot
        above = rot[int(parents[ankle])][low]
        local[low, ankle] = np.swapaxes(above, -1, -2) @ turn @ above @ local[low, ankle]
        changed = True
    return changed


def _below(
    parents: np.ndarray,
    offsets: np.ndarray,
    local: np.ndarray,
    top: int,
    top_rotation: np.ndarray,
    top_position: np.ndarray,
    joints: Sequence[int],
) -> Pose:
    """Forward kinematics of the joints between ``top`` and ``joints`` (all below it), from
    ``top``'s world rotation ``(F, 3, 3)`` and position ``(F, 3)``: world rotations
    ``(F, 3, 3)`` and positions ``(F, 3)`` by joint. Only these few joints are computed
    (a leg's, against a rig of 70 joints with fingers)."""
    needed: set[int] = set()
    for start in joints:
        j = int(start)
        while j != top and j not in needed:
            if j < 0:
                raise ValueError(f"joint {start} is not below joint {top}")
            needed.add(j)
            j = int(parents[j])
    rotations, positions = {top: top_rotation}, {top: top_position}
    for j in sorted(needed):  # parents before children
        parent = int(parents[j])
        rotations[j] = rotations[parent] @ local[:, j]
        positions[j] = positions[parent] + rotations[parent] @ offsets[j]
    return rotations, positions


def planted_feet_offsets(
    feet: np.ndarray, source_feet: np.ndarray, up: np.ndarray, near: float
) -> np.ndarray:
    """``(F, 3)`` horizontal offsets to add to the pelvis's path so that the foot points
    ``feet`` ``(F, P, 3)`` move over the floor as ``source_feet`` ``(F, P, 3)`` (the source's,
    scaled, in the same axes) do while both are on it: within ``near`` of the lowest any of
    their own points gets, at both ends of a frame step (a swinging foot that skims the floor
    in one of them is not planted). A step with planted foot points moves the path back by
    the mean of their extra horizontal movement; a step with none (in the air) leaves it."""

    def on_floor(points: np.ndarray) -> np.ndarray:
        heights = points @ up  # (F, P)
        near_floor = heights - heights.min() < near
        return near_floor[1:] & near_floor[:-1]

    planted = on_floor(feet) & on_floor(source_feet)  # (F - 1, P)
    extra = np.diff(feet, axis=0) - np.diff(source_feet, axis=0)  # (F - 1, P, 3)
    extra = extra - (extra @ up)[..., None] * up
    count = planted.sum(axis=1)
    step = -(extra * planted[..., None]).sum(axis=1) / np.maximum(count, 1)[:, None]
    offsets = np.zeros((feet.shape[0], 3))
    offsets[1:] = np.cumsum(step, axis=0)
    return offsets


def _assemble(
    target: Motion,
    frame_time: float,
    local: np.ndarray,
    above_pelvis: np.ndarray | None,
    pelvis: int,
    pelvis_at: np.ndarray,
    ref_pos: np.ndarray,
) -> Motion:
    """The output motion with the pelvis at ``pelvis_at`` ``(F, 3)`` (the top joint's
    translation, or the pelvis's per-frame offset under a static top joint)."""
    skeleton = target.skeleton
    frames = local.shape[0]
    if pelvis == 0:
        root = pelvis_at
        translations = None
    else:
        root = np.broadcast_to(ref_pos[0], (frames, 3)).copy()
        # Joints above the pelvis are at their reference pose: their positions are fixed.
        assert above_pelvis is not None  # the pelvis's parent's world rotation, (F, 3, 3)
        parent = int(skeleton.parents[pelvis])
        translations = np.broadcast_to(skeleton.offsets, (frames, *skeleton.offsets.shape)).copy()
        translations[:, 0] = root
        translations[:, pelvis] = (
            np.swapaxes(above_pelvis, -1, -2) @ (pelvis_at - ref_pos[parent])[:, :, None]
        )[:, :, 0]
    return Motion(
        skeleton=skeleton,
        frame_time=frame_time,
        root_translation=root,
        local_rotations=local,
        local_translations=translations,
        source_format=target.source_format,
        length_unit=target.length_unit,
        notes={},
    )


def _rest_of(motion: Motion) -> Motion:
    """A one-frame motion of ``motion``'s rest pose (identity rotations, root at origin)."""
    count = motion.skeleton.joint_count
    return Motion(
        skeleton=motion.skeleton,
        frame_time=motion.frame_time,
        root_translation=np.zeros((1, 3)),
        local_rotations=np.broadcast_to(np.eye(3), (1, count, 3, 3)).copy(),
    )


def _unmirrored(mapping: SkeletonMap) -> SkeletonMap:
    return replace(mapping, mirrored=False)


__all__ = [
    "axis_change",
    "leg_length",
    "reference_frame",
    "reference_pose",
    "retarget",
    "swing",
]
