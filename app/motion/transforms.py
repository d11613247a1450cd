"""Whole-clip transforms: rotate, translate, rescale, resample and mirror a :class:`Motion`.

They change how a motion is recorded, not what it is, so descriptors must (nearly) ignore
them; tests use them to check exactly that, and they are handy for augmentation.
"""

from __future__ import annotations

import re

import numpy as np

from app.motion.model import Motion, Skeleton


def _replace(motion: Motion, **changes: object) -> Motion:
    fields = {
        "skeleton": motion.skeleton,
        "frame_time": motion.frame_time,
        "root_translation": motion.root_translation,
        "local_rotations": motion.local_rotations,
        "local_translations": motion.local_translations,
        "source_format": motion.source_format,
        "length_unit": motion.length_unit,
        "notes": dict(motion.notes),
    }
    fields.update(changes)
    return Motion(**fields)  # type: ignore[arg-type]


def rotate(motion: Motion, rotation: np.ndarray) -> Motion:
    """Rotate the whole motion about the world origin by the ``(3, 3)`` matrix ``rotation``."""
    local = motion.local_rotations.copy()
    local[:, 0] = rotation @ local[:, 0]
    return _replace(
        motion,
        root_translation=motion.root_translation @ rotation.T,
        local_rotations=local,
    )


def rotation_about(axis: np.ndarray, degrees: float) -> np.ndarray:
    """``(3, 3)`` rotation by ``degrees`` about the unit ``axis`` (Rodrigues' formula)."""
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    angle = np.radians(degrees)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * (k @ k)


def translate(motion: Motion, offset: np.ndarray) -> Motion:
    """Move the whole motion by the ``(3,)`` vector ``offset``."""
    return _replace(motion, root_translation=motion.root_translation + np.asarray(offset))


def rescale(motion: Motion, factor: float) -> Motion:
    """Multiply every length (offsets, translations) by ``factor``, e.g. 2.54 for cm->inch."""
    skeleton = motion.skeleton
    scaled = Skeleton(
        names=skeleton.names,
        parents=skeleton.parents,
        offsets=skeleton.offsets * factor,
        end_site=skeleton.end_site,
    )
    return _replace(
        motion,
        skeleton=scaled,
        root_translation=motion.root_translation * factor,
        local_translations=None
        if motion.local_translations is None
        else motion.local_translations * factor,
    )


def resample(motion: Motion, step: int) -> Motion:
    """Keep every ``step``-th frame (e.g. 4 turns 120 fps into 30 fps)."""
    return _replace(
        motion,
        frame_time=motion.frame_time * step,
        root_translation=motion.root_translation[::step],
        local_rotations=motion.local_rotations[::step],
        local_translations=None
        if motion.local_translations is None
        else motion.local_translations[::step],
    )


_SWAPS = (
    (re.compile(r"Left|Right"), {"Left": "Right", "Right": "Left"}),
    (re.compile(r"left|right"), {"left": "right", "right": "left"}),
    (re.compile(r"LEFT|RIGHT"), {"LEFT": "RIGHT", "RIGHT": "LEFT"}),
    # Side letters as a name prefix (lhumerus, lShldr, LHipJoint) or suffix (Arm_L, Arm.l).
    (re.compile(r"^[lLrR]|[lLrR]$"), {"l": "r", "r": "l", "L": "R", "R": "L"}),
)


def opposite_side_names(names: tuple[str, ...]) -> tuple[str, ...]:
    """Each name with its side swapped, where the swapped name is another joint's name.

    ``LeftArm`` <-> ``RightArm``, ``lhumerus`` <-> ``rhumerus``, ``Arm_L`` <-> ``Arm_R``;
    names without a counterpart in ``names`` (``lowerback``, ``Hips``) stay as they are.
    """
    present = set(names)
    out = []
    for name in names:
        swapped = name
        for pattern, table in _SWAPS:
            for match in pattern.finditer(name):
                candidate = name[: match.start()] + table[match.group()] + name[match.end() :]
                if candidate != name and candidate in present:
                    swapped = candidate
                    break
            if swapped != name:
                break
        out.append(swapped)
    return tuple(out)


def change_basis(motion: Motion, matrix: np.ndarray) -> Motion:
    """The same clip written in other coordinates: ``(3, 3)`` orthogonal ``matrix`` ``Q``.

    Every offset and translation becomes ``Q o`` and every rotation ``Q R Q^T``, so positions
    from forward kinematics become ``Q p``: with a rotation, the file of another up axis (a
    Y-up clip as a Z-up exporter writes it, rest pose included); with a reflection, the
    clip seen in a mirror.
    """
    q = np.asarray(matrix, dtype=np.float64)
    skeleton = motion.skeleton
    changed = Skeleton(
        names=skeleton.names,
        parents=skeleton.parents,
        offsets=skeleton.offsets @ q.T,
        end_site=skeleton.end_site,
    )
    return _replace(
        motion,
        skeleton=changed,
        root_translation=motion.root_translation @ q.T,
        local_rotations=q @ motion.local_rotations @ q.T,
        local_translations=None
        if motion.local_translations is None
        else motion.local_translations @ q.T,
    )


def reflect(motion: Motion, *, axis: int = 0) -> Motion:
    """The motion seen in a mirror: world coordinate ``axis`` negated, names unchanged.

    Undoes a mirrored capture (the limbs called left on the subject's right) without
    renaming anything; see :func:`change_basis`.
    """
    flip = np.ones(3)
    flip[axis] = -1.0
    return change_basis(motion, np.diag(flip))


def mirror(motion: Motion, *, lateral_axis: int = 0) -> Motion:
    """Mirror the motion left-to-right.

    World coordinate ``lateral_axis`` is negated (a reflection ``M`` across a plane containing
    the up axis, see :func:`reflect`), and joint names swap sides so the joint labelled left
    is again on the subject's left.
    """
    reflected = reflect(motion, axis=lateral_axis)
    skeleton = reflected.skeleton
    renamed = Skeleton(
        names=opposite_side_names(skeleton.names),
        parents=skeleton.parents,
        offsets=skeleton.offsets,
        end_site=skeleton.end_site,
    )
    return _replace(reflected, skeleton=renamed)
