"""Read exported files with Blender's own importers (bpy), in a process of its own.

Run as ``python tests/api/blender_reader.py`` with a JSON list of ``{"path", "frames"}`` on
stdin; prints one JSON object per file: the scene's frame rate, the armature's frame range,
its bone names and, for each requested frame (0-based, the file's own frames), every bone's
head in world coordinates, metres, turned from Blender's Z-up back to Y-up. For glTF,
which has no frame rate, the rate is the key spacing. Files are read
by extension: ``.fbx`` (Blender's FBX importer), ``.glb`` (its glTF importer), ``.bvh`` (its
BVH importer, lengths in the file's units). Each file is read into an empty factory scene.
"""

from __future__ import annotations

import contextlib
import json
import os
import sys

import numpy as np


def _quiet_import() -> None:
    # Blender talks on stdout/stderr; the answer goes to the real stdout only.
    with open(os.devnull, "w") as devnull, contextlib.redirect_stderr(devnull):
        import bpy  # noqa: F401


def read(path: str, frames: list[int]) -> dict[str, object]:
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    if path.endswith(".fbx"):
        bpy.ops.import_scene.fbx(filepath=path, use_anim=True, ignore_leaf_bones=False)
    elif path.endswith(".glb"):
        bpy.ops.import_scene.gltf(filepath=path)
    elif path.endswith(".bvh"):
        bpy.ops.import_anim.bvh(filepath=path, update_scene_fps=True, update_scene_duration=True)
    else:
        raise ValueError(path)
    scene = bpy.context.scene
    armatures = [o for o in scene.objects if o.type == "ARMATURE"]
    if len(armatures) != 1:
        return {"error": f"{len(armatures)} armatures"}
    armature = armatures[0]
    action = armature.animation_data.action if armature.animation_data else None
    start, end = (float(v) for v in action.frame_range) if action else (0.0, 0.0)
    keys, times = 0, []
    if action is not None:
        longest = max(action.fcurves, key=lambda c: len(c.keyframe_points), default=None)
        if longest is not None:
            keys = len(longest.keyframe_points)
            times = sorted(k.co[0] for k in longest.keyframe_points)
    fps = scene.render.fps / scene.render.fps_base
    step = 1.0  # Blender frames per file frame
    if path.endswith(".glb") and keys > 1:
        # glTF has no frame rate: the importer puts keys at time x the scene's rate; the
        # file's rate is its key spacing.
        step = (end - start) / (keys - 1)
        fps = fps / step
    out: dict[str, object] = {
        "fps": fps,
        "start": start,
        "end": end,
        "keys": keys,
        "names": [b.name for b in armature.pose.bones],
        "frames": {},
    }
    poses = {}
    for frame in frames:
        # At the key itself: an importer may put keys between whole frames.
        at = times[frame] if frame < len(times) else start + frame * step
        scene.frame_set(int(np.floor(at)), subframe=at - np.floor(at))
        world = armature.matrix_world
        heads = {}
        for bone in armature.pose.bones:
            p = world @ bone.head
            heads[bone.name] = [p.x, p.z, -p.y]  # Blender Z-up -> Y-up
        poses[str(frame)] = heads
    out["frames"] = poses
    return out


def main() -> None:
    requests = json.load(sys.stdin)
    real_stdout = os.dup(1)
    with open(os.devnull, "w") as devnull:
        os.dup2(devnull.fileno(), 1)
        os.dup2(devnull.fileno(), 2)
    _quiet_import()
    results = []
    for request in requests:
        try:
            results.append(read(request["path"], request["frames"]))
        except Exception as error:  # reported per file, the others still read
            results.append({"error": f"{type(error).__name__}: {error}"})
    with os.fdopen(real_stdout, "w") as stream:
        json.dump(results, stream)


if __name__ == "__main__":
    main()
