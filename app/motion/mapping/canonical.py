"""The canonical joints every descriptor uses, and what a mapping of a source skeleton onto
them says (:class:`SkeletonMap`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from app.motion.model import Skeleton
from app.motion.skeleton_names import normalise_name

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

FAMILY_NAMES = (
    "cmu-asf",
    "motionbuilder",
    "3dsmax",
    "daz",
    "bandai",
    "mixamo",
    "biped",
    "generic",
)


@dataclass(frozen=True)
class SkeletonMap:
    """Where each canonical joint lives in a source skeleton.

    Attributes
    ----------
    joints:
        ``(C,)`` int64 source joint index per canonical joint, ``C = len(CANONICAL_JOINTS)``.
    family:
        The naming convention recognised (informational, see :data:`FAMILY_NAMES`).
    derived:
        Canonical joints placed by a rule rather than found as their own joint (``spine``,
        ``chest``, a neck taken from the head's parent, ``hand_tip``, a toe from the ankle).
    end_sites:
        Canonical points that are end effectors (End Sites or leaves without a frame of
        their own): ``head``, ``*_toe``, ``*_hand_tip`` where the rig has them.
    head_joint:
        Source index of the head *joint* (the head point's parent when the head point is an
        end effector); body height is measured to it.
    how:
        Canonical joint -> how it was found (``"name"``, ``"structure"``, ``"geometry"``,
        ``"end effector"``, ``"derived: ..."``).
    mirrored:
        The geometry is left-handed (the limbs called left lie on the subject's right): the
        motion must be reflected across ``mirror_axis`` before it is described.
    mirror_axis:
        World axis (0, 1, 2) nearest the body's lateral direction, to reflect across.
    pose:
        Which pose the geometry was read from: ``"rest pose"`` or ``"frame N"``.
    sides_open:
        The rest pose shows no side (straight knees, no feet), or shows it only by bent
        knees (a pose of the take written as the rest pose): the clip's frames chose left
        and right, so the mapping is made again for every clip of the rig.
    limbs_open:
        The rest pose left a limb's joints to choose among joints in one straight line (a
        collar bone in line with a T-posed arm, a wrist among the hand's joints): the clip's
        frames chose (the joints inside one limb part stay in line when it moves), so the
        mapping is made again for every clip of the rig.
    held:
        ``(joint, limb end, distance)`` for mapped joints that do not hang from the limb
        they end (a foot bone under the root that IK keeps at the end of the shin): in the
        mapping they hang from that limb end, at that rest-pose distance.
    warnings:
        Short sentences for the user about what the mapping had to decide.
    """

    joints: np.ndarray
    family: str
    derived: tuple[str, ...]
    end_sites: tuple[str, ...] = ()
    head_joint: int = -1
    how: dict[str, str] = field(default_factory=dict)
    mirrored: bool = False
    mirror_axis: int = 0
    pose: str = "rest pose"
    sides_open: bool = False
    limbs_open: bool = False
    held: tuple[tuple[int, int, float], ...] = ()
    warnings: tuple[str, ...] = ()

    def describe(self, names: Sequence[str]) -> dict[str, dict[str, str]]:
        """Canonical joint -> ``{"joint": source name, "how": ...}`` for people to read."""
        return {
            canonical: {"joint": names[int(j)], "how": self.how.get(canonical, "structure")}
            for canonical, j in zip(CANONICAL_JOINTS, self.joints, strict=True)
        }


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


def rest_pose(skeleton: Skeleton) -> np.ndarray:
    """``(J, 3)`` joint positions of the rest pose (offsets only), root at the origin."""
    out = np.zeros((skeleton.joint_count, 3))
    for j in range(1, skeleton.joint_count):
        out[j] = out[skeleton.parents[j]] + skeleton.offsets[j]
    return out
