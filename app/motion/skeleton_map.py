"""Source joint names -> the canonical joints every descriptor uses.

Names are compared whole, never as substrings: a source name is lower-cased, a namespace
prefix such as ``mixamorig:`` and known rig prefixes are removed, and separators
(``_ - . :`` and spaces) are dropped, so ``UpperLeg_L``, ``upperleg.l`` and ``LeftUpperLeg``
all compare equal to the generated forms of base ``upperleg`` on the left side
(``leftupperleg``, ``lupperleg``, ``upperlegl``, ``upperlegleft``).

Each canonical joint has an ordered list of base names; the first base that some joint
matches wins. The order resolves names that mean different things in different families:
``LeftShoulder`` is the upper-arm joint in the 3ds Max conversion of CMU data but the
clavicle in MotionBuilder/Mixamo rigs, so ``arm``/``upperarm`` come before ``shoulder``.

Joints that some families lack are derived from the tree instead of failing:

* ``chest`` is the parent of the neck (the joint the upper trunk hangs from);
* ``spine`` is the first joint on the pelvis->neck path that sits away from the pelvis;
* ``hand_tip`` is the descendant of the wrist farthest from it along bones (thumbs skipped);
* ``toe`` falls back to the farthest descendant of the ankle (DAZ rigs have no toe joint).

A skeleton missing any required joint is refused with
:class:`~app.errors.SkeletonMappingError` naming the missing canonical joints.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from app.errors import SkeletonMappingError
from app.motion.model import Skeleton

SIDES = ("l", "r")

# Canonical joint names in a fixed order: descriptors index into this tuple.
CANONICAL_JOINTS: tuple[str, ...] = (
    "pelvis",
    "spine",
    "chest",
    "neck",
    "head",
    *(
        f"{side}_{part}"
        for side in SIDES
        for part in (
            "shoulder",
            "elbow",
            "wrist",
            "hand_tip",
            "hip",
            "knee",
            "ankle",
            "toe",
        )
    ),
)
CANONICAL_INDEX: dict[str, int] = {name: i for i, name in enumerate(CANONICAL_JOINTS)}

# Parent of each canonical joint in the canonical tree (for bones and relative rotations).
CANONICAL_PARENT: dict[str, str | None] = {
    "pelvis": None,
    "spine": "pelvis",
    "chest": "spine",
    "neck": "chest",
    "head": "neck",
}
for _side in SIDES:
    CANONICAL_PARENT.update(
        {
            f"{_side}_shoulder": "chest",
            f"{_side}_elbow": f"{_side}_shoulder",
            f"{_side}_wrist": f"{_side}_elbow",
            f"{_side}_hand_tip": f"{_side}_wrist",
            f"{_side}_hip": "pelvis",
            f"{_side}_knee": f"{_side}_hip",
            f"{_side}_ankle": f"{_side}_knee",
            f"{_side}_toe": f"{_side}_ankle",
        }
    )

# Canonical bones as (parent, child) index pairs, for drawing stick figures.
CANONICAL_BONES: tuple[tuple[int, int], ...] = tuple(
    (CANONICAL_INDEX[parent], CANONICAL_INDEX[child])
    for child, parent in CANONICAL_PARENT.items()
    if parent is not None
)

# The same joint on the other side (identity for the midline), for mirroring.
MIRROR_INDEX: np.ndarray = np.array(
    [
        CANONICAL_INDEX[
            "r" + name[1:]
            if name.startswith("l_")
            else "l" + name[1:]
            if name.startswith("r_")
            else name
        ]
        for name in CANONICAL_JOINTS
    ]
)

_UNSIDED_BASES: dict[str, tuple[str, ...]] = {
    # Bandai's static "joint_Root" sits above "Hips": hips must win over root.
    "pelvis": ("hips", "hip", "pelvis", "root"),
    "neck": ("lowerneck", "neck", "neck1", "neck01"),
    "head": ("head",),
}
_SIDED_BASES: dict[str, tuple[str, ...]] = {
    "shoulder": ("arm", "upperarm", "shldr", "humerus", "shoulder"),
    "elbow": ("forearm", "lowerarm", "elbow", "radius"),
    "wrist": ("wrist", "hand"),
    "hip": ("upleg", "upperleg", "thigh", "femur", "hip"),
    "knee": ("leg", "lowerleg", "shin", "knee", "tibia", "calf"),
    "ankle": ("foot", "ankle"),
    "toe": ("toebase", "toe", "toes", "ball"),
}
REQUIRED = (
    "pelvis",
    "neck",
    "head",
    *(
        f"{side}_{part}"
        for side in SIDES
        for part in ("shoulder", "elbow", "wrist", "hip", "knee", "ankle")
    ),
)

_PREFIXES = ("mixamorig", "bip01", "bip001", "character1", "def")
_SEPARATORS = re.compile(r"[\s_\-.:|]+")


def normalise_name(name: str) -> str:
    """Lower-case ``name`` without namespace, rig prefix or separators.

    ``mixamorig:LeftArm`` -> ``leftarm``, ``UpperLeg_L`` -> ``upperlegl``.
    """
    lowered = name.strip().lower()
    if ":" in lowered:
        lowered = lowered.rsplit(":", 1)[1]
    compact = _SEPARATORS.sub("", lowered)
    for prefix in _PREFIXES:
        if compact.startswith(prefix) and len(compact) > len(prefix):
            compact = compact[len(prefix) :]
            break
    return compact


def _sided_forms(side: str, base: str) -> tuple[str, ...]:
    word = "left" if side == "l" else "right"
    return (f"{word}{base}", f"{side}{base}", f"{base}{side}", f"{base}{word}")


@dataclass(frozen=True)
class SkeletonMap:
    """Where each canonical joint lives in a source skeleton.

    Attributes
    ----------
    joints:
        ``(C,)`` int64 source joint index per canonical joint, ``C = len(CANONICAL_JOINTS)``.
    family:
        The naming convention recognised (``"cmu-asf"``, ``"motionbuilder"``, ``"3dsmax"``,
        ``"daz"``, ``"bandai"``, ``"mixamo"``, ``"biped"`` or ``"generic"``).
    derived:
        Canonical joints that were derived from the tree rather than matched by name.
    """

    joints: np.ndarray
    family: str
    derived: tuple[str, ...]


def detect_family(names: tuple[str, ...]) -> str:
    """A short name for the skeleton's naming convention (informational)."""
    normal = {normalise_name(n) for n in names}
    if any(n.lower().startswith("mixamorig") for n in names):
        return "mixamo"
    if {"lhumerus", "lfemur", "ltibia"} <= normal:
        return "cmu-asf"
    if {"lhipjoint", "leftupleg", "leftfingerbase"} <= normal:
        return "motionbuilder"
    if {"lhipjoint", "lefthip", "leftcollar"} <= normal:
        return "3dsmax"
    if {"lshldr", "lthigh", "abdomen"} <= normal:
        return "daz"
    if {"upperlegl", "upperarml", "jointroot"} <= normal:
        return "bandai"
    if {"leftupleg", "leftarm", "leftforearm"} <= normal:
        return "biped"
    return "generic"


def map_skeleton(skeleton: Skeleton) -> SkeletonMap:
    """Find every canonical joint in ``skeleton``.

    Raises
    ------
    SkeletonMappingError
        If a required canonical joint has no match; the message lists all missing ones.
    """
    normal = [normalise_name(n) for n in skeleton.names]
    candidates = [j for j in range(skeleton.joint_count) if not skeleton.end_site[j]]
    by_name: dict[str, int] = {}
    for j in candidates:
        by_name.setdefault(normal[j], j)

    found: dict[str, int] = {}
    for canon, bases in _UNSIDED_BASES.items():
        for base in bases:
            if base in by_name:
                found[canon] = by_name[base]
                break
    for side in SIDES:
        for part, bases in _SIDED_BASES.items():
            for base in bases:
                hit = next((by_name[f] for f in _sided_forms(side, base) if f in by_name), None)
                if hit is not None:
                    found[f"{side}_{part}"] = hit
                    break

    missing = [c for c in REQUIRED if c not in found]
    if missing:
        raise SkeletonMappingError(
            "cannot find the canonical joints "
            + ", ".join(missing)
            + " in this skeleton (joints: "
            + ", ".join(skeleton.names[:40])
            + (" ..." if skeleton.joint_count > 40 else "")
            + ")"
        )

    derived: list[str] = []
    lengths = np.linalg.norm(skeleton.offsets, axis=1)
    parents = skeleton.parents

    path_to_neck = _path_between(parents, found["pelvis"], found["neck"])
    if path_to_neck is None:
        raise SkeletonMappingError("the neck is not below the pelvis in this skeleton's hierarchy")
    # Chest: the joint the neck hangs from (the pelvis itself in a very coarse rig).
    found["chest"] = (
        int(parents[found["neck"]]) if found["neck"] != found["pelvis"] else found["pelvis"]
    )
    derived.append("chest")
    # Spine: first joint above the pelvis that is not at the pelvis, else the chest.
    spine = next((j for j in path_to_neck[1:] if lengths[j] > 0), found["chest"])
    found["spine"] = int(spine)
    derived.append("spine")

    for side in SIDES:
        found[f"{side}_hand_tip"] = _farthest_descendant(
            skeleton, found[f"{side}_wrist"], skip=_is_thumb
        )
        derived.append(f"{side}_hand_tip")
        if f"{side}_toe" not in found:
            found[f"{side}_toe"] = _farthest_descendant(skeleton, found[f"{side}_ankle"])
            derived.append(f"{side}_toe")

    joints = np.array([found[name] for name in CANONICAL_JOINTS], dtype=np.int64)
    return SkeletonMap(joints=joints, family=detect_family(skeleton.names), derived=tuple(derived))


def _is_thumb(name: str) -> bool:
    # Only steers the hand-tip search away from thumbs; canonical matching stays whole-name.
    return "thumb" in normalise_name(name)


def _path_between(parents: np.ndarray, top: int, bottom: int) -> list[int] | None:
    """Joints from ``top`` down to ``bottom`` inclusive, or None if ``top`` is no ancestor."""
    path = [bottom]
    j = bottom
    while j != top:
        j = int(parents[j])
        if j < 0:
            return None
        path.append(j)
    return path[::-1]


def _farthest_descendant(
    skeleton: Skeleton, start: int, skip: Callable[[str], bool] | None = None
) -> int:
    """Descendant of ``start`` (inclusive) with the longest bone path from it."""
    lengths = np.linalg.norm(skeleton.offsets, axis=1)
    best, best_distance = start, 0.0
    stack = [(start, 0.0)]
    while stack:
        joint, distance = stack.pop()
        if distance > best_distance:
            best, best_distance = joint, distance
        for child in skeleton.children(joint):
            if skip is not None and skip(skeleton.names[child]):
                continue
            stack.append((child, distance + float(lengths[child])))
    return best
