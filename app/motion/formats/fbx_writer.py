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

Lengths: the motion arrives in the output unit and the scene's unit scale says what that
unit is (``UnitScaleFactor`` is centimetres per unit: 1 for cm, 100 for m, 2.54 for inches).
Axes: the motion arrives Y-up; the armature object turns it into Blender's Z-up and the
exporter's ``axis_up="Y"`` turns it back, so the file's coordinates are the motion's, Y up.
Frame rate: the scene's (a rate like 59.94 is ``fps / fps_base``); frames ``0 .. F-1``.
"""

from __future__ import annotations

import os
import tempfile
from typing import Any

import numpy as np

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


def _tails(motion: Motion, rest: np.ndarray) -> np.ndarray:
    """``(J, 3)`` bone tails: toward the nearest descendant at a distinct position (the first
    child's, else a grandchild's: a joint whose children all sit on it, like a hips joint
    whose hip joints start at its centre, points at its first real bone), else along the
    parent's bone (a leaf) by a tenth of the body's size or the parent bone's length."""
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


def write_fbx(motion: Motion, *, metres_per_unit: float = 0.01, name: str = "motion") -> bytes:
    """The FBX bytes of ``motion`` (Y-up, lengths in a unit of ``metres_per_unit`` metres).

    Raises
    ------
    ValueError
        A joint name that Blender would cut short, which would lose the name.
    RuntimeError
        The exporter failed.
    """
    import bpy
    from scipy.spatial.transform import Rotation

    skeleton = motion.skeleton
    too_long = [n for n in skeleton.names if len(n.encode("utf-8")) > BONE_NAME_BYTES]
    if too_long:
        raise ValueError(
            f"joint name {too_long[0][:80]!r} is longer than FBX export keeps "
            f"({BONE_NAME_BYTES} bytes)"
        )
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
    tails = _tails(motion, rest)
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
    count, frames = skeleton.joint_count, motion.frame_count
    quats = Rotation.from_matrix(basis.reshape(-1, 3, 3)).as_quat().reshape(frames, count, 4)
    quats = np.concatenate([quats[..., 3:], quats[..., :3]], axis=-1)  # Blender: (w, x, y, z)
    locations: dict[int, np.ndarray] = {
        0: ((motion.root_translation - rest[0]) @ frames_b[0]),
    }
    if motion.local_translations is not None:
        change = motion.local_translations - skeleton.offsets[None]
        size = float(np.abs(skeleton.offsets).max(initial=0.0)) or 1.0
        for moved in np.flatnonzero(np.abs(change).max(axis=(0, 2)) > 1e-9 * size).tolist():
            if moved != 0:
                locations[moved] = change[:, moved] @ frames_b[moved]

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

    for j, joint in enumerate(skeleton.names):
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

    scene.frame_set(0)  # the static transforms the exporter writes: the first frame's
    handle, path = tempfile.mkstemp(suffix=".fbx")
    os.close(handle)
    try:
        result = bpy.ops.export_scene.fbx(
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
        if "FINISHED" not in result:
            raise RuntimeError(f"Blender's FBX exporter did not finish ({result})")
        with open(path, "rb") as stream:
            return stream.read()
    finally:
        os.unlink(path)


def _escape(name: str) -> str:
    """A bone name inside a Blender data path's ``["..."]``."""
    return name.replace("\\", "\\\\").replace('"', '\\"')


__all__ = ["bpy_available", "write_fbx"]
