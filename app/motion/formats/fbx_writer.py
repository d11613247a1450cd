"""Write a :class:`Motion` as a binary FBX 7.4 file with Blender's own FBX exporter (bpy).

**Call only in an export worker process** (:mod:`app.services.export_pool`): bpy is Blender,
a large C program, and the server never imports it. One export is one scene: the worker
starts from an empty factory scene every time.

The skeleton becomes an armature whose bones are the joints (end sites included), each bone
from its joint toward its first child, every bone unconnected so the offsets are exactly the
skeleton's; the motion becomes one action keyed at every frame, which the exporter bakes
into one animation stack with every key kept (``bake_anim_simplify_factor=0``). Blender's
bone frames are not the motion's (a bone's Y axis runs along it), so each key is the joint's
rotation seen in its bone's rest frame: ``basis = B^T · L · B`` for bone rest orientation
``B`` and local rotation ``L`` — the armature's world positions are exactly the motion's.
The exporter's bake would step the scene through every frame (seconds per hundred frames);
it gets each frame's bone transforms computed from those keys in numpy instead
(:mod:`app.motion.formats.fbx_bake`), and writes the same file.

Lengths: the motion arrives in the output unit and the scene's unit scale says what that
unit is (``UnitScaleFactor`` is centimetres per unit: 1 for cm, 100 for m, 2.54 for inches).
Axes: the motion arrives Y-up; the armature object turns it into Blender's Z-up and the
exporter's ``axis_up="Y"`` turns it back, so the file's coordinates are the motion's, Y up.
Frame rate: the scene's (a rate like 59.94 is ``fps / fps_base``); frames ``0 .. F-1``.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Collection, Mapping, Sequence
from contextlib import AbstractContextManager, nullcontext
from typing import Any, Literal

import numpy as np

from app.motion.formats.fbx_bake import BakeOutcome, numpy_bake
from app.motion.formats.gltf_writer import quaternions
from app.motion.model import Motion
from app.motion.skeleton_map import rest_pose

BONE_NAME_BYTES = 63  # Blender truncates longer names


def bpy_available() -> str | None:
    """Why bpy cannot be used here, or ``None`` when it can (imports it)."""
    try:
        import bpy  # noqa: F401
    except Exception as error:  # ImportError, or a broken install failing in its own way
        return f"{type(error).__name__}: {error}"
    return None


def _tails(motion: Motion, rest: np.ndarray, moved: Collection[int] = ()) -> np.ndarray:
    """``(J, 3)`` bone tails: toward the nearest descendant at a distinct position (the first
    child's, else a grandchild's: a joint whose children all sit on it, like a hips joint
    whose hip joints start at its centre, points at its first real bone), else along the
    parent's bone (a leaf) by a tenth of the body's size or the parent bone's length.

    A bone with a child in ``moved`` (joints whose offset is animated, like the hips under an
    extracted root) points across its children instead, as far as possible from every one
    of them: Blender's FBX importer puts a bone's tail along its rest Y axis at the mean
    distance of its children and *connects* a child whose head lies there, and a connected
    bone's animated location is ignored (the child would stay at its first frame's offset).
    """
    skeleton = motion.skeleton
    count = skeleton.joint_count
    size = float(np.ptp(rest, axis=0).max()) if count > 1 else 1.0
    size = size if size > 0 else 1.0
    children: list[list[int]] = [[] for _ in range(count)]
    for j in range(1, count):
        children[int(skeleton.parents[j])].append(j)
    tails = np.empty_like(rest)
    direction = np.tile([0.0, 1.0, 0.0], (count, 1))
    for j in range(count):
        queue = list(children[j])
        vector = None
        while queue:
            candidate = queue.pop(0)
            offset = rest[candidate] - rest[j]
            if np.linalg.norm(offset) > 1e-6 * size:
                vector = offset
                break
            queue.extend(children[candidate])
        p = int(skeleton.parents[j])
        if vector is not None and any(c in moved for c in children[j]):
            vector = _across(vector, [rest[c] - rest[j] for c in children[j]])
        if vector is not None:
            tails[j] = rest[j] + vector
            direction[j] = vector / np.linalg.norm(vector)
            continue
        if p >= 0:
            direction[j] = direction[p]
            length = float(np.linalg.norm(rest[j] - rest[p]))
        else:
            length = 0.0
        length = length if length > 1e-6 * size else 0.1 * size
        tails[j] = rest[j] + direction[j] * min(length, 0.1 * size)
    return tails


def _across(vector: np.ndarray, offsets: Sequence[np.ndarray]) -> np.ndarray:
    """``(3,)`` a vector of ``vector``'s length along the axis (forward z, side x, up y, the
    first on a tie) farthest from the direction of every non-zero one of ``offsets``."""
    length = float(np.linalg.norm(vector))
    directions = [o / np.linalg.norm(o) for o in offsets if np.linalg.norm(o) > 1e-9 * length]
    axes = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    worst = [max((abs(float(a @ d)) for d in directions), default=0.0) for a in axes]
    return axes[int(np.argmin(worst))] * length


def write_fbx(
    motion: Motion,
    *,
    metres_per_unit: float = 0.01,
    name: str = "motion",
    bake: Literal["numpy", "blender"] = "numpy",
) -> bytes:
    """The FBX bytes of ``motion`` (Y-up, lengths in a unit of ``metres_per_unit`` metres).

    ``bake``: where the exporter's animation bake gets each frame's bone transforms from.
    ``"numpy"``: computed from the keys for all frames at once
    (:mod:`app.motion.formats.fbx_bake`; the same file, tens of times faster), and should
    Blender compose bones otherwise than that module expects, the export is done again the
    other way. ``"blender"``: the motion keyed as an action that the exporter plays through,
    one ``frame_set`` per frame, as it does alone.

    Raises
    ------
    ValueError
        A joint name that Blender would cut short, which would lose the name.
    RuntimeError
        The exporter failed.
    """
    too_long = [n for n in motion.skeleton.names if len(n.encode("utf-8")) > BONE_NAME_BYTES]
    if too_long:
        raise ValueError(
            f"joint name {too_long[0][:80]!r} is longer than FBX export keeps "
            f"({BONE_NAME_BYTES} bytes)"
        )
    if bake == "numpy":
        data = _export(motion, metres_per_unit, name, keyed=False)
        if data is not None:
            return data
    data = _export(motion, metres_per_unit, name, keyed=True)
    assert data is not None  # a keyed scene is always baked
    return data


def _export(motion: Motion, metres_per_unit: float, name: str, *, keyed: bool) -> bytes | None:
    """One export from an empty scene: the motion keyed as an action (``keyed``) or posed at
    rest with the bake computed in numpy; ``None`` when the numpy bake refused the scene."""
    import bpy

    skeleton = motion.skeleton
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    fps = 1.0 / motion.frame_time
    scene.render.fps = max(1, round(fps))
    scene.render.fps_base = scene.render.fps / fps
    scene.frame_start = 0
    scene.frame_end = max(motion.frame_count - 1, 0)
    scene.unit_settings.system = "METRIC"
    scene.unit_settings.scale_length = metres_per_unit

    armature = bpy.data.armatures.new("Armature")
    obj = bpy.data.objects.new("Armature", armature)
    scene.collection.objects.link(obj)
    obj.rotation_euler = (np.pi / 2, 0.0, 0.0)  # the motion's Y-up into Blender's Z-up
    bpy.context.view_layer.objects.active = obj
    rest = rest_pose(skeleton) + motion.root_translation[0]
    moved = _moved_joints(motion)
    tails = _tails(motion, rest, moved)
    bpy.ops.object.mode_set(mode="EDIT")
    bones: list[Any] = []
    for j, joint in enumerate(skeleton.names):
        bone = armature.edit_bones.new(joint)
        bone.head = tuple(rest[j])
        bone.tail = tuple(tails[j])
        bone.roll = 0.0
        bone.use_connect = False
        if skeleton.parents[j] >= 0:
            bone.parent = bones[int(skeleton.parents[j])]
        bones.append(bone)
    bpy.ops.object.mode_set(mode="OBJECT")
    frames_b = np.array([np.array(armature.bones[n].matrix_local)[:3, :3] for n in skeleton.names])
    frames_b_t = np.swapaxes(frames_b, -1, -2)

    # Keys: rotation in each bone's rest frame, translation of the top bone (and of bones
    # whose offset changes) in its rest frame too.
    basis = frames_b_t[None] @ motion.local_rotations @ frames_b[None]  # (F, J, 3, 3)
    locations: dict[int, np.ndarray] = {
        0: ((motion.root_translation - rest[0]) @ frames_b[0]),
    }
    if motion.local_translations is not None:
        change = motion.local_translations - skeleton.offsets[None]
        for j in moved:
            locations[j] = change[:, j] @ frames_b[j]

    if keyed:
        _key_action(obj, name, skeleton.names, basis, locations)
    else:
        # The rest pose: the static transforms the exporter writes (a reader takes them for
        # the skeleton's rest pose, where the skeleton's shape and body axes are read; the
        # first frame's pose there tilted the body frame of a re-upload by its trunk's lean),
        # and what the numpy bake checks itself against (identity keys).
        for joint in skeleton.names:
            pose_bone = obj.pose.bones[joint]
            pose_bone.rotation_mode = "QUATERNION"
            pose_bone.rotation_quaternion = (1.0, 0.0, 0.0, 0.0)
            pose_bone.location = (0.0, 0.0, 0.0)
    scene.frame_set(0)
    baking: AbstractContextManager[BakeOutcome | None] = (
        nullcontext() if keyed else numpy_bake(skeleton.names, basis, locations)
    )
    handle, path = tempfile.mkstemp(suffix=".fbx")
    os.close(handle)
    try:
        with baking as outcome:
            result = _run_exporter(path)
        if outcome is not None and outcome.refused is not None:
            return None
        if "FINISHED" not in result:
            raise RuntimeError(f"Blender's FBX exporter did not finish ({result})")
        with open(path, "rb") as stream:
            return stream.read()
    finally:
        os.unlink(path)


def _moved_joints(motion: Motion) -> set[int]:
    """The joints below the top one whose offset from their parent is animated."""
    if motion.local_translations is None:
        return set()
    offsets = motion.skeleton.offsets
    change = motion.local_translations - offsets[None]
    size = float(np.abs(offsets).max(initial=0.0)) or 1.0
    return {j for j in np.flatnonzero(np.abs(change).max(axis=(0, 2)) > 1e-9 * size).tolist() if j}


def _key_action(
    obj: Any,
    name: str,
    joints: Sequence[str],
    basis: np.ndarray,
    locations: Mapping[int, np.ndarray],
) -> None:
    """Key ``basis`` ``(F, J, 3, 3)`` and ``locations`` (joint -> ``(F, 3)``) on the
    armature ``obj``'s pose bones at frames ``0 .. F-1``, as one action named ``name``."""
    import bpy

    frames = basis.shape[0]
    quats = quaternions(basis)[..., [3, 0, 1, 2]]  # (F, J, 4) Blender's (w, x, y, z)
    action = bpy.data.actions.new(name)
    frame_numbers = np.arange(frames, dtype=np.float64)

    def curve(path: str, index: int, group: str, values: np.ndarray) -> None:
        fcurve = action.fcurves.new(path, index=index, action_group=group)
        fcurve.keyframe_points.add(frames)
        keys = np.empty(2 * frames)
        keys[0::2] = frame_numbers
        keys[1::2] = values
        fcurve.keyframe_points.foreach_set("co", keys)
        fcurve.update()

    for j, joint in enumerate(joints):
        pose_bone = obj.pose.bones[joint]
        pose_bone.rotation_mode = "QUATERNION"
        path = f'pose.bones["{_escape(joint)}"]'
        for axis in range(4):
            curve(f"{path}.rotation_quaternion", axis, joint, quats[:, j, axis])
        if j in locations:
            for axis in range(3):
                curve(f"{path}.location", axis, joint, locations[j][:, axis])
    # Blender 4.4's actions animate through a slot: assign both once the curves exist.
    animation = obj.animation_data_create()
    animation.action = action
    if hasattr(animation, "action_slot") and len(getattr(action, "slots", ())):
        animation.action_slot = action.slots[0]


def _run_exporter(path: str) -> set[str]:
    """Blender's FBX exporter on the scene, into ``path``: the operator's result."""
    import bpy

    result: set[str] = bpy.ops.export_scene.fbx(
        filepath=path,
        object_types={"ARMATURE"},
        use_selection=False,
        apply_unit_scale=True,
        apply_scale_options="FBX_SCALE_UNITS",
        axis_forward="-Z",
        axis_up="Y",
        add_leaf_bones=False,
        primary_bone_axis="Y",
        secondary_bone_axis="X",
        use_armature_deform_only=False,
        armature_nodetype="NULL",
        bake_anim=True,
        bake_anim_use_all_bones=True,
        bake_anim_use_nla_strips=False,
        bake_anim_use_all_actions=False,
        bake_anim_force_startend_keying=True,
        bake_anim_step=1.0,
        bake_anim_simplify_factor=0.0,
    )
    return result


def _escape(name: str) -> str:
    """A bone name inside a Blender data path's ``["..."]``."""
    return name.replace("\\", "\\\\").replace('"', '\\"')


__all__ = ["bpy_available", "write_fbx"]
