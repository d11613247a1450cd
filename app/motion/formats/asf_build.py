"""The :class:`~app.motion.model.Motion` of an ASF skeleton and the ``(F, D)`` values of its
AMC (see :mod:`app.motion.formats.asf_amc` for what the numbers mean and how the joints are
planned): rest offsets from the bones' directions and lengths, local rotations
``L_b = C_b @ M_b @ C_b.T`` from the ASF axis frames, translations from ``t*`` and ``l`` dofs.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from app.motion.formats.bvh import matrices_from_euler
from app.motion.model import Motion, Skeleton

if TYPE_CHECKING:  # the reader's own records, read here, made there
    from app.motion.formats.asf_amc import _Asf, _JointPlan


def build_motion(
    asf: _Asf,
    joints: list[_JointPlan],
    layout: dict[str, tuple[int, int]],
    values: np.ndarray,
    angle_unit: str,
    frame_time: float,
    first_frame: int,
) -> Motion:
    """The skeleton, ``(F, D)`` AMC values and ASF axis frames -> :class:`Motion`."""
    frame_count = values.shape[0]
    joint_count = len(joints)
    scale = 1.0 / asf.length_multiplier
    asf_to_radians = math.pi / 180.0 if asf.angle_unit == "deg" else 1.0
    amc_to_radians = math.pi / 180.0 if angle_unit == "deg" else 1.0
    index_of = {j.name: i for i, j in enumerate(joints) if not j.end_site}

    # Rest skeleton: a bone's joint sits at its parent bone's tip.
    bone_vectors = {
        name: np.array(bone.direction, dtype=np.float64) * (bone.length or 0.0) * scale
        for name, bone in asf.bones.items()
    }
    bone_vectors["root"] = np.zeros(3)
    offsets = np.zeros((joint_count, 3))
    for index, joint in enumerate(joints):
        if joint.end_site:
            offsets[index] = bone_vectors[joint.bone]
        elif joint.parent >= 0:
            offsets[index] = bone_vectors[joints[joint.parent].bone]

    # Axis frames C_b, (3, 3) each.
    axis_frames = {
        name: matrices_from_euler(
            bone.axis_order.lower(), np.array(bone.axis_angles) * asf_to_radians
        )
        for name, bone in asf.bones.items()
    }
    axis_frames["root"] = matrices_from_euler(
        asf.root.axis_order.lower(), np.array(asf.root_orientation) * asf_to_radians
    )

    rotations = np.zeros((frame_count, joint_count, 3, 3))
    rotations[..., 0, 0] = rotations[..., 1, 1] = rotations[..., 2, 2] = 1.0
    # Group bones by their rotation dof sequence so each group is one vectorised call.
    groups: dict[str, list[tuple[str, list[int]]]] = {}
    for bone in (asf.root, *asf.bones.values()):
        if bone.name not in layout:
            continue
        first, _ = layout[bone.name]
        sequence = "".join(d[1] for d in bone.dof if d.startswith("r"))
        columns = [first + k for k, d in enumerate(bone.dof) if d.startswith("r")]
        if sequence:
            groups.setdefault(sequence, []).append((bone.name, columns))
    for sequence, members in groups.items():
        names = [name for name, _ in members]
        angles = values[:, np.array([columns for _, columns in members])] * amc_to_radians
        frames = np.stack([axis_frames[name] for name in names])  # (G, 3, 3)
        # L = C @ M @ C.T with M extrinsic in dof order, (F, G, 3, 3)
        local = matrices_from_euler(sequence, angles, frames=frames)
        rotations[:, [index_of[name] for name in names]] = local

    root_translation = np.repeat(np.array(asf.root_position)[None] * scale, frame_count, axis=0)
    if "root" in layout:
        first, _ = layout["root"]
        for k, dof in enumerate(asf.root.dof):
            if dof.startswith("t"):
                root_translation[:, "xyz".index(dof[1])] += values[:, first + k] * scale

    local_translations = _bone_translations(
        asf, joints, layout, values, offsets, axis_frames, scale
    )
    if local_translations is not None:
        local_translations[:, 0] = root_translation

    skeleton = Skeleton(
        names=tuple(j.name for j in joints),
        parents=np.array([j.parent for j in joints], dtype=np.int64),
        offsets=offsets,
        end_site=np.array([j.end_site for j in joints], dtype=bool),
    )
    multiplier = asf.length_multiplier
    if math.isclose(multiplier, 0.45):
        length_unit = "inches (ASF length / 0.45)"
    elif multiplier == 1.0:
        length_unit = "ASF units"
    else:
        length_unit = f"ASF units / {multiplier:g}"
    return Motion(
        skeleton=skeleton,
        frame_time=float(frame_time),
        root_translation=root_translation,
        local_rotations=rotations,
        local_translations=local_translations,
        source_format="asf/amc",
        length_unit=length_unit,
        notes={
            "asf_name": asf.name,
            "length_multiplier": multiplier,
            "angle_unit": angle_unit,
            "amc_first_frame": first_frame,
        },
    )


def _bone_translations(
    asf: _Asf,
    joints: list[_JointPlan],
    layout: dict[str, tuple[int, int]],
    values: np.ndarray,
    offsets: np.ndarray,
    axis_frames: dict[str, np.ndarray],
    scale: float,
) -> np.ndarray | None:
    """``(F, J, 3)`` offsets moved by bone ``tx ty tz`` and ``l`` dofs, or ``None`` if none."""
    moving = [
        bone for bone in asf.bones.values() if any(d.startswith("t") or d == "l" for d in bone.dof)
    ]
    if not moving:
        return None
    frame_count = values.shape[0]
    translations = np.repeat(offsets[None], frame_count, axis=0)
    for bone in moving:
        first, _ = layout[bone.name]
        shift = np.zeros((frame_count, 3))
        for k, dof in enumerate(bone.dof):
            if dof.startswith("t"):
                shift[:, "xyz".index(dof[1])] = values[:, first + k] * scale
        bone_joint = next(i for i, j in enumerate(joints) if j.bone == bone.name)
        # translations are along the bone's own axes
        translations[:, bone_joint] += shift @ axis_frames[bone.name].T
        if "l" in bone.dof:
            stretch = values[:, first + bone.dof.index("l")] * scale
            direction = np.array(bone.direction, dtype=np.float64)
            for child, joint in enumerate(joints):
                if joint.parent == bone_joint:
                    translations[:, child] += stretch[:, None] * direction
    return translations
