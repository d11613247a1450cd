"""What the industry rigs of issue 20 are built with (:mod:`tests.motion.industry_rigs`):
a 1.75 m human's landmarks, a rig's rows, the driving from a capture, the exports.

Each rig is written from what the tool documents (or ships as its default skeleton), never
from a dev-set file: its joint names and tree, its typical extra bones (twist, roll, IK,
face, hair, footsteps), its rest pose (T or A), length unit and up axis. Joints sit on a
1.75 m human's landmarks (:data:`LANDMARKS`, metres, Y up, +X the subject's left, +Z
forward). Certainty of each rig's hierarchy is in :data:`CERTAINTY`.

:func:`drive` animates a rig from a fixture capture with the rig's known truth (which joint
is the pelvis, the left knee...): every joint of a body segment takes that segment's world
turn in the capture (limb directions copied, the trunk's frame copied), extra bones stay at
rest under their parent, and IK bones follow the hand or foot they control (as Unreal's do).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from app.motion import transforms
from app.motion.kinematics import forward_kinematics
from app.motion.model import Motion, Skeleton

_T = np.array  # shorthand for landmark points


def _finger_points() -> dict[str, np.ndarray]:
    """Left-hand finger joints relative to the wrist, T-pose (+X along the arm)."""
    out: dict[str, np.ndarray] = {}
    spread = {"thumb": 0.035, "index": 0.025, "middle": 0.008, "ring": -0.01, "pinky": -0.026}
    for finger, z in spread.items():
        if finger == "thumb":
            base, step, down = _T([0.02, -0.01, 0.025]), _T([0.028, -0.008, 0.018]), 0.0
        else:
            base, step, down = _T([0.01, 0.0, z * 0.6]), _T([0.028, 0.0, 0.0]), 0.0
            base = base + _T([0.0, down, 0.0])
        knuckle = base + (_T([0.075, 0.0, z - base[2]]) if finger != "thumb" else step)
        out[f"{finger}0"] = base
        for k in range(1, 4):
            out[f"{finger}{k}"] = knuckle + step * (k - 1)
        out[f"{finger}4"] = knuckle + step * 3
    return out


# Landmarks of the left side and the midline (metres, T-pose); the right side mirrors x.
LANDMARKS: dict[str, np.ndarray] = {
    "ground": _T([0.0, 0.0, 0.0]),
    "pelvis": _T([0.0, 0.98, 0.0]),
    "spine": _T([0.0, 1.10, -0.01]),
    "chest": _T([0.0, 1.30, -0.02]),
    "neck": _T([0.0, 1.50, -0.02]),
    "head": _T([0.0, 1.60, 0.0]),
    "head_top": _T([0.0, 1.75, 0.01]),
    "jaw": _T([0.0, 1.62, 0.04]),
    "chin": _T([0.0, 1.57, 0.10]),
    "eye": _T([0.032, 1.66, 0.08]),
    "clav": _T([0.03, 1.44, 0.03]),
    "shoulder": _T([0.18, 1.44, -0.02]),
    "elbow": _T([0.47, 1.44, -0.03]),
    "wrist": _T([0.73, 1.44, -0.02]),
    "hand_tip": _T([0.92, 1.44, -0.02]),
    "hip": _T([0.09, 0.93, 0.0]),
    "knee": _T([0.095, 0.50, 0.01]),
    "ankle": _T([0.10, 0.08, -0.02]),
    "ball": _T([0.11, 0.02, 0.12]),
    "toe_tip": _T([0.11, 0.0, 0.19]),
    "hair": _T([0.0, 1.70, -0.10]),
    "skirt": _T([0.12, 0.85, 0.05]),
}
_ARM = ("elbow", "wrist", "hand_tip")
for _name, _offset in _finger_points().items():
    LANDMARKS[_name] = LANDMARKS["wrist"] + _offset


def point(place: str, side: str, arm_down: float) -> np.ndarray:
    """The ``(3,)`` metres of ``place`` on ``side`` ("l"/"r"/""): a landmark, ``a@b:t``
    (``t`` of the way from a to b) or ``a+dx,dy,dz``; arms turned ``arm_down`` degrees
    down about the shoulder (an A-pose)."""
    if "+" in place:
        a, delta = place.split("+")
        shift = np.array([float(v) for v in delta.split(",")])
        return point(a, side, arm_down) + shift * (-1 if side == "r" else 1, 1, 1)
    if "@" in place:
        a, rest = place.split("@")
        b, t = rest.split(":")
        return (1 - float(t)) * point(a, side, arm_down) + float(t) * point(b, side, arm_down)
    p = LANDMARKS[place].copy()
    on_arm = place in _ARM or place[:-1] in ("thumb", "index", "middle", "ring", "pinky")
    if arm_down and on_arm:  # an A-pose: the arm turned down about the shoulder
        pivot = LANDMARKS["shoulder"]
        turn = transforms.rotation_about(np.array([0.0, 0.0, 1.0]), -arm_down)
        p = pivot + turn @ (p - pivot)
    if side == "r":
        p[0] = -p[0]
    return p


@dataclass
class Rig:
    """A rig under construction: rows of (name, parent, rest point, segment, truth)."""

    name: str
    pose: str = "T"  # "T" or "A"
    unit: float = 100.0  # file units per metre
    z_up: bool = False
    bone_axis: int = 0  # the local axis the tool lays along a bone (0 = x, 1 = y)
    names: list[str] = field(default_factory=list)
    parents: list[int] = field(default_factory=list)
    points: list[np.ndarray] = field(default_factory=list)
    segments: list[str | None] = field(default_factory=list)
    follows: dict[int, str] = field(default_factory=dict)
    truth: dict[str, set[str]] = field(default_factory=dict)

    @property
    def arm_down(self) -> float:
        return 45.0 if self.pose == "A" else 0.0

    def add(
        self,
        name: str,
        parent: str | None,
        place: str,
        segment: str | None = None,
        *,
        side: str = "",
        truth: str | None = None,
        follows: str | None = None,
    ) -> str:
        """Add joint ``name`` under ``parent`` at ``place``; ``segment`` (``s_`` = this side)
        it turns with; ``truth`` the canonical joint it is; ``follows`` a joint it copies."""
        self.names.append(name)
        self.parents.append(-1 if parent is None else self.names.index(parent))
        self.points.append(point(place, side, self.arm_down))
        seg = None if segment is None else segment.replace("s_", f"{side}_")
        self.segments.append(seg)
        if follows is not None:
            self.follows[len(self.names) - 1] = follows
        if truth is not None:
            self.truth.setdefault(truth.replace("s_", f"{side}_"), set()).add(name)
        return name

    def skeleton(self) -> Skeleton:
        """The rig's skeleton in metres, Y up, world-axis offsets (identity rest frames)."""
        points = np.array(self.points)
        parents = np.array(self.parents)
        offsets = points - points[np.maximum(parents, 0)]
        offsets[0] = 0.0
        return Skeleton(tuple(self.names), parents, offsets, np.zeros(len(self.names), dtype=bool))


# ---------------------------------------------------------------- driving from a capture

# Fixture joint -> landmark, per fixture's naming (the fixtures' truth, read from their files).
SOURCE_TRUTH: dict[str, dict[str, str]] = {
    "cmu": {
        "pelvis": "Hips",
        "spine": "Spine",
        "chest": "Spine1",
        "neck": "Neck1",  # CMU's Neck sits on Spine1
        "head": "Head",
        **{
            f"{s}_{part}": f"{side}{joint}"
            for s, side in (("l", "Left"), ("r", "Right"))
            for part, joint in (
                ("clav", "Shoulder"),
                ("shoulder", "Arm"),
                ("elbow", "ForeArm"),
                ("wrist", "Hand"),
                ("hand_tip", "HandIndex1"),
                ("hip", "UpLeg"),
                ("knee", "Leg"),
                ("ankle", "Foot"),
                ("ball", "ToeBase"),
            )
        },
    },
    "bandai": {
        "pelvis": "Hips",
        "spine": "Spine",
        "chest": "Chest",
        "neck": "Neck",
        "head": "Head",
        **{
            f"{s}_{part}": f"{joint}_{s.upper()}"
            for s in ("l", "r")
            for part, joint in (
                ("clav", "Shoulder"),
                ("shoulder", "UpperArm"),
                ("elbow", "LowerArm"),
                ("wrist", "Hand"),
                ("hip", "UpperLeg"),
                ("knee", "LowerLeg"),
                ("ankle", "Foot"),
                ("ball", "Toes"),
            )
        },
    },
}

# Limb segment -> (its start landmark, its end landmark, parent segment).
_LIMBS = {
    "clav": ("clav", "shoulder", "chest"),
    "upper": ("shoulder", "elbow", "s_clav"),
    "fore": ("elbow", "wrist", "s_upper"),
    "hand": ("wrist", "hand_tip", "s_fore"),
    "thigh": ("hip", "knee", "pelvis"),
    "shin": ("knee", "ankle", "s_thigh"),
    "foot": ("ankle", "ball", "s_shin"),
}
# Trunk segment -> (lower landmark, upper landmark, the lateral pair's part).
_TRUNK = {
    "pelvis": ("pelvis", "chest", "hip"),
    "abdomen": ("spine", "chest", "shoulder"),
    "chest": ("chest", "neck", "shoulder"),
    "neck": ("neck", "head", "shoulder"),
    "head": ("neck", "head", "shoulder"),
}


def _frame(up: np.ndarray, lateral: np.ndarray) -> np.ndarray:
    """``(..., 3, 3)`` columns left, up, forward from ``(..., 3)`` up and lateral vectors."""
    up = up / np.linalg.norm(up, axis=-1, keepdims=True)
    left = lateral - (lateral * up).sum(-1, keepdims=True) * up
    left /= np.linalg.norm(left, axis=-1, keepdims=True)
    return np.stack([left, up, np.cross(left, up)], axis=-1)


def _swing(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``(F, 3, 3)`` shortest turns taking unit ``(F, 3)`` ``a`` onto ``b``."""
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    v, c = np.cross(a, b), (a * b).sum(-1)
    k = np.zeros((len(a), 3, 3))
    k[:, 0, 1], k[:, 0, 2], k[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    k -= np.transpose(k, (0, 2, 1))
    return np.eye(3) + k + k @ k / (1.0 + c)[:, None, None]


def _landmark(points: dict[str, np.ndarray], name: str) -> np.ndarray:
    if name == "hand_tip" or name.endswith("_hand_tip"):
        if name in points:
            return points[name]
        side = name[0]  # no hand bone: the hand goes on along the forearm
        return 2 * points[f"{side}_wrist"] - points[f"{side}_elbow"]
    return points[name]


def segment_turns(
    points: dict[str, np.ndarray], rest: dict[str, np.ndarray]
) -> dict[str, np.ndarray]:
    """Segment -> ``(F, 3, 3)`` world turn of the rig's segment whose rest landmarks are
    ``rest`` (``(3,)`` each) so that it lies as the capture's, landmarks ``points`` (``(F, 3)``)."""
    frames = len(points["pelvis"])
    turns: dict[str, np.ndarray] = {}
    for seg, (low, high, pair) in _TRUNK.items():
        now = _frame(points[high] - points[low], points[f"l_{pair}"] - points[f"r_{pair}"])
        then = _frame(rest[high] - rest[low], rest[f"l_{pair}"] - rest[f"r_{pair}"])
        turns[seg] = now @ then.T
    for side in ("l", "r"):
        for seg, (start, end, parent) in _LIMBS.items():
            parent_turn = turns[parent.replace("s_", f"{side}_")]
            rest_dir = np.broadcast_to(rest[f"{side}_{end}"] - rest[f"{side}_{start}"], (frames, 3))
            now_dir = _landmark(points, f"{side}_{end}") - points[f"{side}_{start}"]
            carried = (parent_turn @ rest_dir[:, :, None])[:, :, 0]
            turns[f"{side}_{seg}"] = _swing(carried, now_dir) @ parent_turn
    return turns


def _rig_landmarks(rig: Rig) -> dict[str, np.ndarray]:
    out = {}
    for name in LANDMARKS:
        if name in ("pelvis", "spine", "chest", "neck", "head"):
            out[name] = point(name, "", rig.arm_down)
        else:
            for side in ("l", "r"):
                out[f"{side}_{name}"] = point(name, side, rig.arm_down)
    return out


def drive(rig: Rig, source: Motion, family: str) -> Motion:
    """The rig, metres Y up, moving as ``source`` (a fixture of naming ``family``) moves."""
    skeleton = rig.skeleton()
    _, positions = forward_kinematics(source)
    names = source.skeleton.names
    points = {k: positions[:, names.index(v)] for k, v in SOURCE_TRUTH[family].items()}
    turns = segment_turns(points, _rig_landmarks(rig))
    frames, count = source.frame_count, skeleton.joint_count
    parents = skeleton.parents
    world = np.zeros((frames, count, 3, 3))
    where = np.zeros((frames, count, 3))
    rest = np.array(rig.points)
    for j in range(count):
        p = int(parents[j])
        seg = rig.segments[j]
        world[:, j] = turns[seg] if seg is not None else (np.eye(3) if p < 0 else world[:, p])
        if p >= 0:
            where[:, j] = where[:, p] + (world[:, p] @ skeleton.offsets[j])
    for j, target in rig.follows.items():  # IK bones sit on what they control
        t = rig.names.index(target)
        world[:, j], where[:, j] = world[:, t], where[:, t]
    # The pelvis travels as the capture's, scaled by leg length.
    pelvis = rig.names.index(sorted(rig.truth["pelvis"], key=rig.names.index)[0])
    leg = np.linalg.norm(points["l_hip"][0] - points["l_knee"][0]) + np.linalg.norm(
        points["l_knee"][0] - points["l_ankle"][0]
    )
    scale = 0.85 / leg
    goal = rest[pelvis] + (points["pelvis"] - points["pelvis"][0]) * scale
    shift = goal - where[:, pelvis]
    where += shift[:, None]
    local = np.empty_like(world)
    local[:, 0] = world[:, 0]
    local[:, 1:] = np.einsum("fjba,fjbc->fjac", world[:, parents[1:]], world[:, 1:])
    translations = None
    if rig.follows:
        translations = np.broadcast_to(skeleton.offsets, (frames, count, 3)).copy()
        for j in rig.follows:
            p = int(parents[j])
            translations[:, j] = np.einsum("fba,fb->fa", world[:, p], where[:, j] - where[:, p])
    return Motion(
        skeleton=skeleton,
        frame_time=source.frame_time,
        root_translation=where[:, 0],
        local_rotations=local,
        local_translations=translations,
        length_unit="metres",
    )


_Z_UP = transforms.rotation_about(np.array([1.0, 0.0, 0.0]), 90.0)  # Y up -> Z up, facing -Y


def as_exported(rig: Rig, motion: Motion) -> tuple[Motion, np.ndarray]:
    """``motion`` (metres, Y up) in the rig's units and up axis, with the ``(3, 3)`` world
    change from the capture's coordinates to the file's."""
    world = _Z_UP if rig.z_up else np.eye(3)
    return transforms.rescale(transforms.change_basis(motion, world), rig.unit), world


def bone_axes(motion: Motion, axis: int) -> Motion:
    """``motion`` with every joint's local ``axis`` (0 = x, 1 = y) along its bone to its first
    child, as FBX/Maya/Unreal (x) and Blender (y) orient joints, baked into the channels the
    way FBX-to-BVH converters write them: the offsets lie along that axis, the rest pose of
    the offsets is no figure."""
    from tests.motion.test_mapping_probes import rebased

    skeleton = motion.skeleton
    count = skeleton.joint_count
    frames = np.tile(np.eye(3), (count, 1, 1))
    for j in range(count):
        children = skeleton.children(j)
        bone = skeleton.offsets[children[0]] if children else np.zeros(3)
        if np.linalg.norm(bone) < 1e-9:  # a leaf or a joint on its child: its parent's axes
            frames[j] = frames[int(skeleton.parents[j])] if j else np.eye(3)
            continue
        along = bone / np.linalg.norm(bone)
        helper = np.array([0.0, 0.0, 1.0]) if abs(along[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        side = np.cross(along, helper)
        side /= np.linalg.norm(side)
        other = np.cross(along, side) if axis == 0 else np.cross(side, along)
        columns = [along, side, other] if axis == 0 else [side, along, other]
        frames[j] = np.stack(columns, axis=1)
        if np.linalg.det(frames[j]) < 0:
            frames[j][:, 2] *= -1
    return rebased(motion, frames)


def nameless(motion: Motion) -> Motion:
    """``motion`` with its joints called ``j000``, ``j001``... (structure alone)."""
    import dataclasses

    names = tuple(f"j{j:03d}" for j in range(motion.skeleton.joint_count))
    return dataclasses.replace(motion, skeleton=dataclasses.replace(motion.skeleton, names=names))


def bvh_name(name: str) -> str:
    """A joint's name as the BVH writer writes it (spaces and braces to ``_``)."""
    return re.sub(r"[\s{}]+", "_", name)


RIGS: dict[str, Callable[[], Rig]] = {}
CERTAINTY: dict[str, str] = {}


def rig(certainty: str) -> Callable[[Callable[[], Rig]], Callable[[], Rig]]:
    def register(build: Callable[[], Rig]) -> Callable[[], Rig]:
        RIGS[build.__name__] = build
        CERTAINTY[build.__name__] = certainty
        return build

    return register


FINGERS = ("thumb", "index", "middle", "ring", "pinky")


def sides(build: Callable[[str, str], None]) -> None:
    for side, word in (("l", "l"), ("r", "r")):
        build(side, word)


def fingers(
    r: Rig, side: str, hand: str, name: Callable[[str, int], str | None], *, first: int = 1
) -> None:
    """Finger chains under ``hand``: ``name(finger, k)`` for k = 0 (metacarpal, None when
    the rig has none) and ``first``..3."""
    for finger in FINGERS:
        parent = hand
        base = name(finger, 0)
        if base is not None:
            parent = r.add(base, parent, f"{finger}0", "s_hand", side=side)
        for k in range(first, 4):
            joint = name(finger, k)
            if joint is not None:
                parent = r.add(joint, parent, f"{finger}{k + 1 - first}", "s_hand", side=side)


def twists(
    r: Rig, side: str, parent: str, names: list[str], start: str, end: str, seg: str
) -> None:
    """Twist bones under ``parent``, spread along the bone ``start`` -> ``end``."""
    for i, name in enumerate(names):
        r.add(name, parent, f"{start}@{end}:{(i + 1) / (len(names) + 1):.3f}", seg, side=side)
