"""Write a :class:`Motion` as a BVH file (any clip, any source format).

The BVH is of the clip's own skeleton: its rest offsets, its joint names, the root's
translation, the clip's frame rate. Every rotating joint has ``Zrotation Xrotation
Yrotation`` channels (one order for all: ``R = Rz @ Rx @ Ry``, what :mod:`.bvh` reads); the
root has ``Xposition Yposition Zposition`` before them, and so does any other joint whose
offset changes during the clip (``Motion.local_translations``: FBX/glTF bones with
animated translation or scale, BVH files with position channels on every joint). End sites
are written as ``End Site``; a leaf joint that is not an end site is a ``JOINT`` with a
zero-length ``End Site`` (BVH joints need a child), so its name survives.

Numbers are written with enough digits (angles to 1e-9 degrees, lengths to 10 significant
digits) that reading the file back gives the joint positions to ~1e-9 of the body's size.
"""

from __future__ import annotations

import io
import re

import numpy as np

from app.motion.formats.scene import unique_names
from app.motion.model import Motion

ORDER = "ZXY"
ROTATION_CHANNELS = "Zrotation Xrotation Yrotation"
POSITION_CHANNELS = "Xposition Yposition Zposition"


def euler_zxy(rotations: np.ndarray) -> np.ndarray:
    """``(..., 3)`` angles ``(z, x, y)`` in degrees with ``R = Rz(z) @ Rx(x) @ Ry(y)`` for
    ``(..., 3, 3)`` rotation matrices (at x = ±90°, z takes all of the twist, y = 0)."""
    r = np.asarray(rotations, dtype=np.float64)
    # Rz Rx Ry: R[2,1] = sin x; R[0,1] = -sin z cos x; R[1,1] = cos z cos x;
    # R[2,0] = -cos x sin y; R[2,2] = cos x cos y.
    # cos x from the two entries it scales (accurate near the lock, unlike sqrt(1 - sin^2)).
    cos_x = np.hypot(r[..., 0, 1], r[..., 1, 1])
    x = np.arctan2(r[..., 2, 1], cos_x)
    regular = cos_x > 1e-7
    z_regular = np.arctan2(-r[..., 0, 1], r[..., 1, 1])
    z = np.where(regular, z_regular, np.arctan2(r[..., 1, 0], r[..., 0, 0]))
    y = np.where(regular, np.arctan2(-r[..., 2, 0], r[..., 2, 2]), 0.0)
    return np.degrees(np.stack([z, x, y], axis=-1))


def _bvh_names(names: tuple[str, ...]) -> tuple[str, ...]:
    """Joint names a BVH reader takes as one token: spaces and braces become ``_``."""
    return unique_names([re.sub(r"[\s{}]+", "_", name) for name in names])


def _number(value: float) -> str:
    text = f"{value:.10g}"
    return "0" if text == "-0" else text


def write_bvh(motion: Motion, frames: tuple[int, int] | None = None) -> str:
    """The BVH text of ``motion`` (or of frames ``start:stop`` of it).

    Parameters
    ----------
    motion:
        Any clip; its ``(F, J, 3, 3)`` local rotations are written as ZXY Euler angles.
    frames:
        Optional ``(start, stop)`` frame range (Python slice semantics, clipped to the clip).

    Returns
    -------
    str
        A complete BVH file (``\\n`` line ends).
    """
    if frames is not None:
        start, stop = frames
        motion = motion.slice_frames(max(0, start), max(0, stop))
    skeleton = motion.skeleton
    count = skeleton.joint_count
    parents = skeleton.parents
    children: list[list[int]] = [[] for _ in range(count)]
    for joint in range(1, count):
        children[int(parents[joint])].append(joint)
    moving = np.zeros(count, dtype=bool)
    moving[0] = True
    if motion.local_translations is not None and motion.frame_count:
        spread = np.abs(motion.local_translations - skeleton.offsets[None]).max(axis=0).max(axis=1)
        size = float(np.abs(skeleton.offsets).max()) if count > 1 else 1.0
        moving |= spread > 1e-9 * max(size, 1e-9)
    moving &= ~skeleton.end_site

    names = _bvh_names(skeleton.names)
    out = io.StringIO()
    out.write("HIERARCHY\n")
    columns: list[tuple[int, str]] = []  # (joint, "position" | "rotation") in channel order

    def write_joint(joint: int, depth: int) -> None:
        pad = "\t" * depth
        if skeleton.end_site[joint]:
            out.write(f"{pad}End Site\n{pad}{{\n")
            offset = " ".join(_number(v) for v in skeleton.offsets[joint])
            out.write(f"{pad}\tOFFSET {offset}\n{pad}}}\n")
            return
        keyword = "ROOT" if depth == 0 else "JOINT"
        out.write(f"{pad}{keyword} {names[joint]}\n{pad}{{\n")
        offset = skeleton.offsets[joint]
        out.write(f"{pad}\tOFFSET {' '.join(_number(v) for v in offset)}\n")
        if moving[joint]:
            out.write(f"{pad}\tCHANNELS 6 {POSITION_CHANNELS} {ROTATION_CHANNELS}\n")
            columns.append((joint, "position"))
        else:
            out.write(f"{pad}\tCHANNELS 3 {ROTATION_CHANNELS}\n")
        columns.append((joint, "rotation"))
        if children[joint]:
            for child in children[joint]:
                write_joint(child, depth + 1)
        else:
            out.write(f"{pad}\tEnd Site\n{pad}\t{{\n{pad}\t\tOFFSET 0 0 0\n{pad}\t}}\n")
        out.write(f"{pad}}}\n")

    write_joint(0, 0)
    frame_count = motion.frame_count
    out.write(f"MOTION\nFrames: {frame_count}\nFrame Time: {_number(motion.frame_time)}\n")
    if frame_count == 0:
        return out.getvalue()
    angles = euler_zxy(motion.local_rotations)  # (F, J, 3)
    blocks = []
    for joint, kind in columns:
        if kind == "rotation":
            blocks.append(angles[:, joint])
        elif joint == 0:
            blocks.append(motion.root_translation)
        else:
            assert motion.local_translations is not None
            blocks.append(motion.local_translations[:, joint])
    values = np.concatenate(blocks, axis=1)
    rows = ["\t".join(_number(v) for v in row) for row in values.tolist()]
    out.write("\n".join(rows))
    out.write("\n")
    return out.getvalue()
