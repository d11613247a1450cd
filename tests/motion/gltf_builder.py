"""Build small skinned GLB files from a :class:`Motion` (known motion, any fault wanted).

``build_glb(motion)`` writes one node per joint (rest offsets as translations), a skin over
them, and one animation: every joint's rotation per frame and the root's translation, at
the clip's frame rate with LINEAR keys. ``document`` and ``chunks`` let a test damage the
JSON or the binary before packing (``pack_glb``).
"""

from __future__ import annotations

import json
import struct
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from app.motion.model import Motion


def gltf_parts(motion: Motion, *, name: str = "clip") -> tuple[dict[str, Any], bytes]:
    """The glTF JSON document and its binary buffer for ``motion``."""
    skeleton = motion.skeleton
    count = skeleton.joint_count
    frames = motion.frame_count
    times = (np.arange(frames) * motion.frame_time).astype(np.float32)
    quats = Rotation.from_matrix(motion.local_rotations.reshape(-1, 3, 3)).as_quat()
    quats = quats.reshape(frames, count, 4).astype(np.float32)  # x, y, z, w
    blobs: list[bytes] = []
    views: list[dict[str, Any]] = []
    accessors: list[dict[str, Any]] = []

    def add(array: np.ndarray, kind: str) -> int:
        data = np.ascontiguousarray(array, dtype=np.float32).tobytes()
        offset = sum(len(b) for b in blobs)
        blobs.append(data)
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": len(data)})
        accessor = {"bufferView": len(views) - 1, "componentType": 5126, "count": len(array)}
        accessor["type"] = kind
        if kind == "SCALAR":
            accessor["min"], accessor["max"] = [float(array.min())], [float(array.max())]
        accessors.append(accessor)
        return len(accessors) - 1

    time_accessor = add(times, "SCALAR")
    samplers, channels = [], []
    for joint in range(count):
        samplers.append({"input": time_accessor, "output": add(quats[:, joint], "VEC4")})
        channels.append(
            {"sampler": len(samplers) - 1, "target": {"node": joint, "path": "rotation"}}
        )
    samplers.append({"input": time_accessor, "output": add(motion.root_translation, "VEC3")})
    channels.append({"sampler": len(samplers) - 1, "target": {"node": 0, "path": "translation"}})
    nodes = []
    for joint in range(count):
        children = [int(c) for c in np.flatnonzero(skeleton.parents == joint)]
        node: dict[str, Any] = {
            "name": skeleton.names[joint],
            "translation": [float(v) for v in skeleton.offsets[joint]],
        }
        if children:
            node["children"] = children
        nodes.append(node)
    binary = b"".join(blobs)
    document = {
        "asset": {"version": "2.0", "generator": "tests/motion/gltf_builder.py"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": nodes,
        "skins": [{"joints": list(range(count))}],
        "animations": [{"name": name, "samplers": samplers, "channels": channels}],
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": len(binary)}],
    }
    return document, binary


def pack_glb(document: dict[str, Any], binary: bytes | None) -> bytes:
    """A GLB container of ``document`` and ``binary``."""
    text = json.dumps(document).encode()
    text += b" " * (-len(text) % 4)
    chunks = struct.pack("<I4s", len(text), b"JSON") + text
    if binary is not None:
        padded = binary + b"\0" * (-len(binary) % 4)
        chunks += struct.pack("<I4s", len(padded), b"BIN\0") + padded
    return b"glTF" + struct.pack("<II", 2, 12 + len(chunks)) + chunks


def build_glb(motion: Motion, *, name: str = "clip") -> bytes:
    """A skinned GLB holding ``motion`` as one animation called ``name``."""
    return pack_glb(*gltf_parts(motion, name=name))


def two_animation_glb(motion: Motion) -> bytes:
    """``motion`` as a skinned GLB with two animations: "walk" (all of it) and "start" (its
    first 10 frames)."""
    return multi_animation_glb({"walk": motion, "start": motion.slice_frames(0, 10)})


def multi_animation_glb(animations: dict[str, Motion]) -> bytes:
    """One skinned GLB holding each motion of ``animations`` (same skeleton) as an animation
    of that name, in order; the first motion's rest pose is the file's."""
    (first, motion), *others = animations.items()
    document, binary = gltf_parts(motion, name=first)
    for name, other in others:
        extra, extra_binary = gltf_parts(other, name=name)
        shift = len(binary)
        for view in extra["bufferViews"]:
            view["byteOffset"] += shift
        base = len(document["accessors"])
        document["accessors"] += [
            dict(a, bufferView=a["bufferView"] + len(document["bufferViews"]))
            for a in extra["accessors"]
        ]
        document["bufferViews"] += extra["bufferViews"]
        animation = extra["animations"][0]
        for sampler in animation["samplers"]:
            sampler["input"] += base
            sampler["output"] += base
        document["animations"].append(animation)
        binary += extra_binary
        document["buffers"][0]["byteLength"] = len(binary)
    return pack_glb(document, binary)


def with_empty_take(motion: Motion, *, seconds: float = 10.0) -> bytes:
    """``motion`` as a skinned GLB animation "walk", after an animation "Take 001" that lasts
    ``seconds`` and moves no node (its one channel drives morph weights), as the FBX SDK
    writes an empty default take beside a Mixamo one."""
    document, binary = gltf_parts(motion, name="walk")
    binary = _two_keys(document, binary, np.zeros(2), "SCALAR", seconds)
    last = len(document["accessors"]) - 1
    document["animations"].insert(
        0,
        {
            "name": "Take 001",
            "samplers": [{"input": last - 1, "output": last}],
            "channels": [{"sampler": 0, "target": {"node": 0, "path": "weights"}}],
        },
    )
    return pack_glb(document, binary)


def with_prop_take(motion: Motion, *, seconds: float = 10.0) -> bytes:
    """``motion`` as a skinned GLB animation "walk", after an animation "prop" that lasts
    ``seconds`` and moves a node outside the skeleton (a second scene root, no joint), as
    Blender writes one animation per animated object of a scene."""
    document, binary = gltf_parts(motion, name="walk")
    places = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    binary = _two_keys(document, binary, places, "VEC3", seconds)
    document["nodes"].append({"name": "prop"})
    document["scenes"][0]["nodes"].append(len(document["nodes"]) - 1)
    last = len(document["accessors"]) - 1
    prop = len(document["nodes"]) - 1
    document["animations"].insert(
        0,
        {
            "name": "prop",
            "samplers": [{"input": last - 1, "output": last}],
            "channels": [{"sampler": 0, "target": {"node": prop, "path": "translation"}}],
        },
    )
    return pack_glb(document, binary)


def _two_keys(
    document: dict[str, Any], binary: bytes, values: np.ndarray, kind: str, seconds: float
) -> bytes:
    """Append accessors of two key times (0 and ``seconds``) and of ``values`` (two, of
    glTF type ``kind``) to ``document``; the binary buffer with them."""
    times = np.array([0.0, seconds], dtype=np.float32).tobytes()
    for data, of in ((times, "SCALAR"), (np.asarray(values, dtype=np.float32).tobytes(), kind)):
        document["bufferViews"].append(
            {"buffer": 0, "byteOffset": len(binary), "byteLength": len(data)}
        )
        accessor = {"bufferView": len(document["bufferViews"]) - 1, "componentType": 5126}
        document["accessors"].append(accessor | {"count": 2, "type": of})
        binary += data
    document["buffers"][0]["byteLength"] = len(binary)
    return binary
