"""Write a :class:`Motion` as a binary glTF 2.0 file (``.glb``): the skeleton and one animation.

Plain structured code after the glTF 2.0 specification (the rules it relies on are tested in
``tests/motion/test_gltf_writer.py``), so the file loads in Blender, three.js, Godot,
Unity's glTFast and Unreal's glTF importer:

* **Nodes.** One node per joint (end sites included, so the head top and toe tips keep their
  place), named as in the skeleton, children listed by their parents, the top joint the
  scene's only root node. A node's rest transform is its joint's offset (translation) and no
  rotation, except the top node, which carries the turn from the clip's up axis to glTF's
  +Y (``up_rotation``). A skin lists every joint with its inverse bind matrix (the inverse
  of the joint's world transform in that rest pose), so importers build an armature.
* **Animation.** One animation: a rotation channel for every joint that rotates (unit
  quaternions ``(x, y, z, w)``, consecutive ones on the same hemisphere), a translation
  channel for the top joint and for any joint whose offset changes during the clip; one
  shared time input, ``frame / fps`` seconds (with ``min``/``max`` as the spec requires), and
  ``LINEAR`` interpolation (slerp for rotations), so sampling at the frame times gives the
  frames back.
* **Units.** Metres, +Y up, as the spec says: lengths are multiplied by ``metres_per_unit``.
* **Container.** A 12-byte header, a JSON chunk padded with spaces and a binary chunk padded
  with zeros, each to a multiple of 4 bytes; every accessor's data 4-byte aligned.
"""

from __future__ import annotations

import json
import struct

import numpy as np

from app.motion.model import Motion
from app.motion.skeleton_map import rest_pose

GLB_MAGIC = 0x46546C67  # "glTF"
JSON_CHUNK = 0x4E4F534A  # "JSON"
BIN_CHUNK = 0x004E4942  # "BIN\0"
FLOAT = 5126
GENERATOR = "mocap-index"


def quaternions(rotations: np.ndarray) -> np.ndarray:
    """``(F, J, 4)`` unit quaternions ``(x, y, z, w)`` of ``(F, J, 3, 3)`` rotations, each on
    the hemisphere of the frame before (so interpolation never takes the long way round).

    Shepperd's method, vectorised: from the largest of ``w, x, y, z`` (the best-conditioned
    square root) — three times faster than scipy's ``from_matrix``, which first checks that
    every matrix is a rotation (ours are, by construction)."""
    r = np.asarray(rotations, dtype=np.float64)
    m00, m11, m22 = r[..., 0, 0], r[..., 1, 1], r[..., 2, 2]
    squares = np.stack(
        [1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22, 1 + m00 + m11 + m22],
        axis=-1,
    )  # 4 x^2, 4 y^2, 4 z^2, 4 w^2
    best = np.argmax(squares, axis=-1)
    root = np.sqrt(np.maximum(np.take_along_axis(squares, best[..., None], -1)[..., 0], 1e-300))
    sums = {
        "xy": r[..., 0, 1] + r[..., 1, 0],
        "xz": r[..., 0, 2] + r[..., 2, 0],
        "yz": r[..., 1, 2] + r[..., 2, 1],
        "wx": r[..., 2, 1] - r[..., 1, 2],
        "wy": r[..., 0, 2] - r[..., 2, 0],
        "wz": r[..., 1, 0] - r[..., 0, 1],
    }
    candidates = np.stack(
        [
            np.stack([root * root, sums["xy"], sums["xz"], sums["wx"]], axis=-1),
            np.stack([sums["xy"], root * root, sums["yz"], sums["wy"]], axis=-1),
            np.stack([sums["xz"], sums["yz"], root * root, sums["wz"]], axis=-1),
            np.stack([sums["wx"], sums["wy"], sums["wz"], root * root], axis=-1),
        ],
        axis=-2,
    )  # (..., 4 choices, 4 components), each 2 * root * q
    quats = np.take_along_axis(candidates, best[..., None, None], -2)[..., 0, :]
    quats /= np.linalg.norm(quats, axis=-1, keepdims=True)
    if quats.shape[0] > 1:
        flips = np.sum(quats[1:] * quats[:-1], axis=-1) < 0  # (F-1, J)
        signs = np.cumprod(np.where(flips, -1.0, 1.0), axis=0)
        quats[1:] *= signs[..., None]
    return quats


class _Buffer:
    """The binary chunk under construction, with its buffer views and accessors."""

    def __init__(self) -> None:
        self.data = bytearray()
        self.views: list[dict[str, object]] = []
        self.accessors: list[dict[str, object]] = []

    def add(self, values: np.ndarray, kind: str, *, bounds: bool = False) -> int:
        """Store ``(count, n)`` float32 values as one accessor of ``kind`` (``"SCALAR"``,
        ``"VEC3"``, ``"VEC4"``, ``"MAT4"``); returns its index."""
        array = np.ascontiguousarray(values, dtype="<f4")
        count = int(array.shape[0])
        offset = len(self.data)
        self.data += array.tobytes()
        self.data += b"\x00" * (-len(self.data) % 4)
        self.views.append({"buffer": 0, "byteOffset": offset, "byteLength": array.nbytes})
        accessor: dict[str, object] = {
            "bufferView": len(self.views) - 1,
            "componentType": FLOAT,
            "count": count,
            "type": kind,
        }
        if bounds:
            flat = array.reshape(count, -1)
            accessor["min"] = [float(v) for v in flat.min(axis=0)]
            accessor["max"] = [float(v) for v in flat.max(axis=0)]
        self.accessors.append(accessor)
        return len(self.accessors) - 1


def _moving_joints(motion: Motion) -> np.ndarray:
    """``(J,)`` bool: joints whose offset changes during the clip (translation channels)."""
    count = motion.skeleton.joint_count
    moving = np.zeros(count, dtype=bool)
    if motion.local_translations is not None and motion.frame_count:
        spread = np.abs(motion.local_translations - motion.skeleton.offsets[None]).max(axis=0)
        size = float(np.abs(motion.skeleton.offsets).max(initial=0.0)) or 1.0
        moving = spread.max(axis=1) > 1e-9 * size
    moving[0] = False  # the top joint has its own translation channel
    return moving


def write_glb(
    motion: Motion,
    *,
    metres_per_unit: float = 1.0,
    up_rotation: np.ndarray | None = None,
    animation_name: str = "motion",
) -> bytes:
    """The GLB bytes of ``motion`` (see the module docstring).

    Parameters
    ----------
    motion:
        ``F >= 1`` frames of ``J`` joints.
    metres_per_unit:
        The clip's length unit in metres (glTF is in metres).
    up_rotation:
        ``(3, 3)`` rotation taking the clip's world onto glTF's (+Y up); ``None``: the clip
        is Y-up already.
    animation_name:
        The animation's name.
    """
    skeleton = motion.skeleton
    count, frames = skeleton.joint_count, motion.frame_count
    turn = np.eye(3) if up_rotation is None else np.asarray(up_rotation, dtype=np.float64)
    scale = float(metres_per_unit)
    offsets = skeleton.offsets * scale
    buffer = _Buffer()

    # Rest pose: offsets, no rotation but the top joint's turn to +Y up, at frame 0's place.
    top_rest = turn @ motion.root_translation[0] * scale
    rest_quat_top = quaternions(turn[None, None])[0, 0]
    nodes: list[dict[str, object]] = []
    children: list[list[int]] = [[] for _ in range(count)]
    for j in range(1, count):
        children[int(skeleton.parents[j])].append(j)
    for j in range(count):
        node: dict[str, object] = {"name": skeleton.names[j]}
        translation = top_rest if j == 0 else offsets[j]
        if np.any(translation != 0):
            node["translation"] = [float(v) for v in translation]
        if j == 0 and not np.allclose(rest_quat_top, [0, 0, 0, 1]):
            node["rotation"] = [float(v) for v in rest_quat_top]
        if children[j]:
            node["children"] = children[j]
        nodes.append(node)

    # Inverse bind matrices: the inverse of each joint's rest world transform.
    rest = rest_pose(skeleton) * scale  # (J, 3), offsets only, top joint at the origin
    world_rest = (rest - rest[0]) @ turn.T + top_rest
    inverse_bind = np.zeros((count, 4, 4))
    inverse_bind[:, :3, :3] = turn.T
    inverse_bind[:, :3, 3] = -(world_rest @ turn)  # R^T (-p)
    inverse_bind[:, 3, 3] = 1.0
    # glTF matrices are column-major.
    ibm_accessor = buffer.add(np.swapaxes(inverse_bind, 1, 2).reshape(count, 16), "MAT4")

    times = np.arange(frames, dtype=np.float64) * motion.frame_time
    time_accessor = buffer.add(times[:, None], "SCALAR", bounds=True)
    local = motion.local_rotations.copy()
    local[:, 0] = turn @ local[:, 0]
    quats = quaternions(local)  # (F, J, 4)
    samplers: list[dict[str, object]] = []
    channels: list[dict[str, object]] = []

    def channel(node: int, path: str, values: np.ndarray, kind: str) -> None:
        output = buffer.add(values, kind)
        samplers.append({"input": time_accessor, "output": output, "interpolation": "LINEAR"})
        channels.append({"sampler": len(samplers) - 1, "target": {"node": node, "path": path}})

    channel(0, "translation", motion.root_translation @ turn.T * scale, "VEC3")
    for j in range(count):
        if not skeleton.end_site[j]:
            channel(j, "rotation", quats[:, j], "VEC4")
    moving = _moving_joints(motion)
    for moved in np.flatnonzero(moving).tolist():
        assert motion.local_translations is not None
        channel(moved, "translation", motion.local_translations[:, moved] * scale, "VEC3")

    document = {
        "asset": {"version": "2.0", "generator": GENERATOR},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": nodes,
        "skins": [
            {
                "name": "skeleton",
                "joints": list(range(count)),
                "skeleton": 0,
                "inverseBindMatrices": ibm_accessor,
            }
        ],
        "animations": [{"name": animation_name, "samplers": samplers, "channels": channels}],
        "accessors": buffer.accessors,
        "bufferViews": buffer.views,
        "buffers": [{"byteLength": len(buffer.data)}],
    }
    text = json.dumps(document, separators=(",", ":"), allow_nan=False).encode("utf-8")
    text += b" " * (-len(text) % 4)
    binary = bytes(buffer.data)
    total = 12 + 8 + len(text) + 8 + len(binary)
    return b"".join(
        [
            struct.pack("<III", GLB_MAGIC, 2, total),
            struct.pack("<II", len(text), JSON_CHUNK),
            text,
            struct.pack("<II", len(binary), BIN_CHUNK),
            binary,
        ]
    )


__all__ = ["quaternions", "write_glb"]
