"""A small synthetic walker: a real skeleton tree animated by smooth joint rotations."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from app.motion.kinematics import forward_kinematics
from app.motion.model import Motion, Skeleton
from app.motion.skeleton_map import rest_pose
from tests.motion.skeleton_trees import MOTIONBUILDER, skeleton_from_tree

# Rest offsets of a MotionBuilder-style figure (units: cm), standing in a T-pose, facing +z.
_OFFSETS = {
    "LHipJoint": (0, 0, 0),
    "LeftUpLeg": (9, -5, 0),
    "LeftLeg": (0, -42, 0),
    "LeftFoot": (0, -40, 0),
    "LeftToeBase": (0, -6, 12),
    "LeftToeBase_end": (0, 0, 5),
    "LowerBack": (0, 0, 0),
    "Spine": (0, 12, 0),
    "Spine1": (0, 20, 0),
    "Neck": (0, 12, 0),
    "Neck1": (0, 6, 0),
    "Head": (0, 6, 0),
    "Head_end": (0, 18, 0),
    "LeftShoulder": (0, 0, 0),
    "LeftArm": (17, 2, 0),
    "LeftForeArm": (28, 0, 0),
    "LeftHand": (25, 0, 0),
    "LeftFingerBase": (0, 0, 0),
    "LeftHandIndex1": (8, 0, 0),
    "LeftHandIndex1_end": (6, 0, 0),
    "LThumb": (0, 0, 0),
    "LThumb_end": (5, 0, 5),
}


def _offset(name: str) -> tuple[float, ...]:
    if name in _OFFSETS:
        return _OFFSETS[name]
    mirrored = name.replace("Right", "Left").replace("RHip", "LHip").replace("RThumb", "LThumb")
    x, y, z = _OFFSETS[mirrored]
    return (-x, y, z)


def walker_skeleton() -> Skeleton:
    tree = skeleton_from_tree(MOTIONBUILDER)
    offsets = np.array([(0.0, 0.0, 0.0)] + [_offset(n) for n in tree.names[1:]], dtype=float)
    return Skeleton(tree.names, tree.parents, offsets, tree.end_site)


def walker_motion(frames: int = 240, fps: float = 120.0, speed: float = 120.0) -> Motion:
    """A figure swinging arms and legs at 1 Hz while moving forward (+z) at ``speed`` cm/s."""
    skeleton = walker_skeleton()
    t = np.arange(frames) / fps
    phase = 2 * np.pi * 1.0 * t
    rotvecs = np.zeros((frames, skeleton.joint_count, 3))
    swing = {"LeftUpLeg": 0.5, "RightUpLeg": -0.5, "LeftArm": -0.4, "RightArm": 0.4}
    for name, amplitude in swing.items():
        rotvecs[:, skeleton.index(name), 0] = amplitude * np.sin(phase)
    for name in ("LeftLeg", "RightLeg"):
        rotvecs[:, skeleton.index(name), 0] = 0.4 + 0.4 * np.sin(phase + 1.0)
    for name in ("LeftForeArm", "RightForeArm"):
        rotvecs[:, skeleton.index(name), 1] = 0.3 + 0.2 * np.sin(phase)
    rotvecs[:, 0, 1] = 0.1 * np.sin(phase)  # pelvis yaw sway
    local = Rotation.from_rotvec(rotvecs.reshape(-1, 3)).as_matrix()
    local = local.reshape(frames, skeleton.joint_count, 3, 3)
    end = skeleton.end_site
    local[:, end] = np.eye(3)
    root = np.stack([np.zeros(frames), 90 + 2 * np.sin(2 * phase), speed * t], axis=1)
    return Motion(skeleton, 1.0 / fps, root, local)


def walking(skeleton: Skeleton, truth: dict[str, str], frames: int = 60) -> Motion:
    """``skeleton`` (a rig standing in its rest pose, Y up, facing +z, whose joint frames are
    the world's in the rest pose) walking forward at 1 Hz: thighs and arms swing, knees and
    elbows bend forward. ``truth`` names the canonical joints (see
    :func:`tests.motion.skeleton_trees.synthetic_humanoid`)."""
    fps = 30.0
    phase = 2 * np.pi * np.arange(frames) / fps
    rotvecs = np.zeros((frames, skeleton.joint_count, 3))
    for side, sign in (("l", 1.0), ("r", -1.0)):
        rotvecs[:, skeleton.index(truth[f"{side}_hip"]), 0] = -0.4 * sign * np.sin(phase)
        rotvecs[:, skeleton.index(truth[f"{side}_knee"]), 0] = 0.5 + 0.4 * np.sin(phase + 1.0)
        rotvecs[:, skeleton.index(truth[f"{side}_shoulder"]), 0] = 0.3 * sign * np.sin(phase)
        # The forearm turns forward about the vertical: -y for the left arm (along +x).
        bend = 0.4 + 0.2 * np.sin(phase)
        rotvecs[:, skeleton.index(truth[f"{side}_elbow"]), 1] = -sign * bend
    local = Rotation.from_rotvec(rotvecs.reshape(-1, 3)).as_matrix()
    local = local.reshape(frames, skeleton.joint_count, 3, 3)
    height = float(np.ptp([p for p in rest_pose(skeleton)[:, 1]]))
    root = np.stack(
        [np.zeros(frames), np.full(frames, 0.57 * height), 0.8 * height * phase / (2 * np.pi)],
        axis=1,
    )
    return Motion(skeleton, 1.0 / fps, root, local)


def grown(motion: Motion, parents: list[int], offsets: list[np.ndarray]) -> Motion:
    """``motion`` with joints added under ``parents`` at rest ``offsets``, never moving."""
    skeleton, count = motion.skeleton, len(parents)
    grown = Skeleton(
        (*skeleton.names, *(f"extra{i}" for i in range(count))),
        np.concatenate([skeleton.parents, parents]),
        np.concatenate([skeleton.offsets, offsets]),
        np.concatenate([skeleton.end_site, np.zeros(count, dtype=bool)]),
    )
    frames = motion.frame_count
    rotations = np.concatenate(
        [motion.local_rotations, np.broadcast_to(np.eye(3), (frames, count, 3, 3))], axis=1
    )
    translations = None
    if motion.local_translations is not None:
        extra = np.broadcast_to(np.array(offsets), (frames, count, 3))
        translations = np.concatenate([motion.local_translations, extra], axis=1)
    return dataclasses.replace(
        motion, skeleton=grown, local_rotations=rotations, local_translations=translations
    )


def bones_scaled(motion: Motion, joints: Sequence[int], scale: float) -> Motion:
    """``motion`` with the bones ending at ``joints`` ``scale`` times as long (their rest
    offsets and, where the clip has them, their translations), nothing else changed."""
    offsets = motion.skeleton.offsets.copy()
    offsets[list(joints)] *= scale
    translations = motion.local_translations
    if translations is not None:
        translations = translations.copy()
        translations[:, list(joints)] *= scale
    skeleton = dataclasses.replace(motion.skeleton, offsets=offsets)
    return dataclasses.replace(motion, skeleton=skeleton, local_translations=translations)


def joint_oriented(motion: Motion, keep: frozenset[int] = frozenset()) -> Motion:
    """``motion`` as a rig with joint orientation writes it (Maya's "orient joints", many
    pose-estimation exporters): every joint's frame turned so its first child lies along its
    x axis, the offsets given in those frames and the rotations turned to match. Forward
    kinematics gives the same positions; the rest pose of the offsets is no standing figure
    (each child along its parent's x). The joints ``keep`` keep the world's axes (a writer
    that orients every joint but the root)."""
    skeleton = motion.skeleton
    count = skeleton.joint_count
    rest = rest_pose(skeleton)
    turn = np.broadcast_to(np.eye(3), (count, 3, 3)).copy()  # joint frame in the rest pose
    for j in range(count):
        children = [c for c in range(count) if skeleton.parents[c] == j]
        if j in keep:
            continue  # the world's axes
        bone = rest[children[0]] - rest[j] if children else np.zeros(3)
        if np.linalg.norm(bone) > 0:
            x = bone / np.linalg.norm(bone)
            helper = np.array([0.0, 0.0, 1.0]) if abs(x[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
            y = np.cross(helper, x)
            y /= np.linalg.norm(y)
            turn[j] = np.stack([x, y, np.cross(x, y)], axis=1)
        elif j > 0:
            turn[j] = turn[skeleton.parents[j]]
    parents = np.maximum(skeleton.parents, 0)
    offsets = np.einsum("jba,jb->ja", turn[parents], rest - rest[parents])
    offsets[0] = 0.0
    world = np.zeros_like(motion.local_rotations)
    for j in range(count):
        above = world[:, skeleton.parents[j]] if j else np.eye(3)
        world[:, j] = above @ motion.local_rotations[:, j]
    oriented_world = world @ turn[None]
    local = oriented_world.copy()
    local[:, 1:] = np.swapaxes(oriented_world[:, parents[1:]], -1, -2) @ oriented_world[:, 1:]
    return dataclasses.replace(
        motion,
        skeleton=Skeleton(skeleton.names, skeleton.parents, offsets, skeleton.end_site),
        local_rotations=local,
    )


def hung_from_root(motion: Motion, names: Sequence[str]) -> Motion:
    """``motion`` with the joints ``names`` (and what hangs from them) moved to hang from the
    root, keeping every world position and rotation: a game rig whose foot bones are IK
    bones under the root, held at the end of the shins by the animation."""
    skeleton = motion.skeleton
    world, at = forward_kinematics(motion)
    moved = [skeleton.index(name) for name in names]
    parents = skeleton.parents.copy()
    parents[moved] = 0
    rest = rest_pose(skeleton)
    offsets = rest - rest[np.maximum(parents, 0)]
    offsets[0] = 0.0
    local = motion.local_rotations.copy()
    per_frame = np.broadcast_to(offsets, (motion.frame_count, *offsets.shape)).copy()
    for j in moved:
        local[:, j] = np.swapaxes(world[:, 0], -1, -2) @ world[:, j]
        per_frame[:, j] = np.einsum("fba,fb->fa", world[:, 0], at[:, j] - at[:, 0])
    return dataclasses.replace(
        motion,
        skeleton=Skeleton(skeleton.names, parents, offsets, skeleton.end_site),
        local_rotations=local,
        local_translations=per_frame,
    )


def below(skeleton: Skeleton, joint: int) -> list[int]:
    """Every joint strictly below ``joint`` (parents come before their children)."""
    found: set[int] = {joint}
    out = []
    for j in range(joint + 1, skeleton.joint_count):
        if skeleton.parents[j] in found:
            found.add(j)
            out.append(j)
    return out


def with_cloth_chains(
    motion: Motion,
    head: int,
    chest: int,
    pelvis: int,
    hips: tuple[int, int],
    *,
    in_rest: bool = True,
    seed: int = 11,
) -> Motion:
    """``motion`` with cloth and hair bones as character rigs carry them (VRoid's
    ``J_Sec_*``, a game character's skirt and ponytail), never moving: twelve hair chains of
    three or four bones from ``head``, hanging down the back and the sides to lengths of
    their own (down to the waist), eight skirt chains round ``pelvis`` hanging to mid-thigh,
    and two short chains forward from ``chest``. Long chains that hang as limbs do, unlike
    small leaves. ``hips``: the left and the right hip joint (they say the sides); the
    cloth hangs in the rest pose (``in_rest``: a character's bind pose) or else in the first
    frame (for a rig whose rest pose is no figure)."""
    if in_rest:
        pose = rest_pose(motion.skeleton)  # (J, 3)
        world = np.broadcast_to(np.eye(3), (len(pose), 3, 3))
    else:
        turns, at = forward_kinematics(motion.slice_frames(0, 1))
        pose, world = at[0], turns[0]  # (J, 3), (J, 3, 3)
    # The body's size: the joints from the pelvis down the tree (a root joint left at the
    # origin while the hips walk away is no part of it).
    body = [pelvis, *below(motion.skeleton, pelvis)]
    height = float(np.ptp(pose[body], axis=0).max())
    up = pose[head] - pose[pelvis]
    up /= np.linalg.norm(up)
    across = pose[hips[0]] - pose[hips[1]]
    across -= up * (across @ up)
    across /= np.linalg.norm(across)
    front = np.cross(across, up)
    rng = np.random.default_rng(seed)
    hung: list[int] = []
    offsets: list[np.ndarray] = []

    def chain(top: int, steps: list[np.ndarray]) -> None:
        parent = top
        for step in steps:
            hung.append(parent)
            offsets.append(world[top].T @ step)  # in the parent's frame: no bone turns
            parent = motion.skeleton.joint_count + len(hung) - 1

    for k in range(12):  # hair: out of the skull, then down the back and the sides
        angle = np.pi * (0.1 + 0.8 * k / 11)
        out = np.cos(angle) * across - np.sin(angle) * front
        bones = int(rng.integers(3, 5))
        down = (0.15 * out - up) / np.linalg.norm(0.15 * out - up)
        length = height * rng.uniform(0.05, 0.32)
        chain(head, [0.06 * height * (0.6 * out + 0.4 * up)] + [length / bones * down] * bones)
    for k in range(8):  # a skirt's pleats
        out = np.cos(2 * np.pi * k / 8) * across + np.sin(2 * np.pi * k / 8) * front
        drop = height * rng.uniform(0.17, 0.22) / 3
        chain(pelvis, [0.09 * height * out] + [drop * (0.3 * out - up)] * 3)
    for side in (1, -1):
        chain(chest, [0.05 * height * (front + 0.3 * side * across)] * 2)
    return grown(motion, hung, offsets)
