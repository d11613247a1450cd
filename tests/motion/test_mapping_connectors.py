"""Rigs from pose generators (issue 20, docs/skeletons.md "connectors at the trunk's point and
legs with no foot"): a writer that puts, for each limb and the neck, a joint of no length at
the trunk's point (``Pelvis_L_Hip`` on the pelvis, then ``L_Hip`` where the thigh starts), and
legs that end at the ankle itself, an End Site, with no foot bones. Both map as the same rig
without them: the hip is the joint set apart from the pelvis, the ankle the leg's end."""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.spatial.transform import Rotation

from app.motion.model import Skeleton
from app.motion.pipeline import describable_body
from app.motion.skeleton_map import CANONICAL_JOINTS
from tests.motion.canonical import check_canonical_body
from tests.motion.rig_building import bone_axes, nameless
from tests.motion.synthetic import walking

# (joint, parent, rest offset in cm (Y up, facing +z), End Site?) for the ``L`` side and the
# trunk; the ``R`` side mirrors the limbs. ``{s}`` is the side's letter, ``{side}`` its word.
_CONNECTORS = [
    ("Pelvis", None, (0, 0, 0), False),
    ("Pelvis_{s}_Hip", "Pelvis", (0, 0, 0), False),
    ("{s}_Hip", "Pelvis_{s}_Hip", (9, -3, 0), False),
    ("{s}_Knee", "{s}_Hip", (0, -42, 0), False),
    ("{s}_Ankle", "{s}_Knee", (0, -40, 0), False),
    ("{s}_Foot", "{s}_Ankle", (0, -6, 12), True),
    ("Pelvis_Spine1", "Pelvis", (0, 0, 0), False),
    ("Spine1", "Pelvis_Spine1", (0, 12, 0), False),
    ("Spine3", "Spine1", (0, 20, 0), False),
    ("Spine3_Neck", "Spine3", (0, 0, 0), False),
    ("Neck", "Spine3_Neck", (0, 12, 0), False),
    ("Head", "Neck", (0, 26, 0), True),
    ("Spine3_{s}_Collar", "Spine3", (0, 0, 0), False),
    ("{s}_Collar", "Spine3_{s}_Collar", (5, 2, 0), False),
    ("{s}_Shoulder", "{s}_Collar", (12, 0, 0), False),
    ("{s}_Elbow", "{s}_Shoulder", (28, 0, 0), False),
    ("{s}_Wrist", "{s}_Elbow", (25, 0, 0), True),
]
_NO_FOOT = [
    ("Hips", None, (0, 0, 0), False),
    ("Hips_{side}UpLeg", "Hips", (0, 0, 0), False),
    ("{side}UpLeg", "Hips_{side}UpLeg", (9, -3, 0), False),
    ("{side}Leg", "{side}UpLeg", (0, -42, 0), False),
    ("{side}Foot", "{side}Leg", (0, -40, 2), True),
    ("Spine", "Hips", (0, 12, 0), False),
    ("Spine2", "Spine", (0, 20, 0), False),
    ("Neck", "Spine2", (0, 12, 0), False),
    ("Head", "Neck", (0, 26, 0), True),
    ("{side}Shoulder", "Spine2", (5, 2, 0), False),
    ("{side}Arm", "{side}Shoulder", (12, 0, 0), False),
    ("{side}ForeArm", "{side}Arm", (28, 0, 0), False),
    ("{side}Hand", "{side}ForeArm", (25, 0, 0), True),
]


_Table = list[tuple[str, str | None, tuple[int, int, int], bool]]


def _rig(table: _Table) -> tuple[Skeleton, list[str]]:
    """The rig of ``table``, both sides, and its joints' names."""
    names: list[str] = []
    parents: list[int] = []
    offsets: list[tuple[float, ...]] = []
    ends: list[bool] = []
    for s, side, sign in (("L", "Left", 1.0), ("R", "Right", -1.0)):
        for name, parent, offset, end in table:
            sided = "{" in name
            if not sided and s == "R":
                continue
            names.append(name.format(s=s, side=side))
            parents.append(-1 if parent is None else names.index(parent.format(s=s, side=side)))
            offsets.append((sign * offset[0] if sided else offset[0], offset[1], offset[2]))
            ends.append(end)
    skeleton = Skeleton(
        tuple(names), np.array(parents), np.array(offsets, dtype=float), np.array(ends)
    )
    return skeleton, names


def _mapped(table: _Table, truth: dict[str, str]) -> dict[str, str]:
    """Canonical joint -> the name of the joint it maps to, the rig walking (``truth``: the
    joints :func:`walking` turns), after the canonical body's checks."""
    skeleton, names = _rig(table)
    motion = walking(skeleton, truth)
    body = describable_body(motion)
    check_canonical_body(body, "rig")
    assert body.mapping is not None
    return {c: names[int(j)] for c, j in zip(CANONICAL_JOINTS, body.mapping.joints, strict=True)}


def test_a_connector_at_the_trunks_point_is_not_the_limbs_top() -> None:
    truth = {
        f"{side}_{part}": f"{side.upper()}_{name}"
        for side in "lr"
        for part, name in (("hip", "Hip"), ("knee", "Knee"), ("shoulder", "Shoulder"))
    } | {f"{side}_elbow": f"{side.upper()}_Elbow" for side in "lr"}
    joints = _mapped(_CONNECTORS, truth)
    for side in "lr":
        assert joints[f"{side}_hip"] == f"{side.upper()}_Hip"
        assert joints[f"{side}_knee"] == f"{side.upper()}_Knee"
        assert joints[f"{side}_ankle"] == f"{side.upper()}_Ankle"
    # On the trunk's line the neck starts at the chest's top, where its connector sits.
    assert joints["neck"] == "Spine3_Neck"


# The joints ``walking`` turns in the rigs named as Mixamo names them.
_MIXAMO_NAMED = {
    f"{side}_{part}": f"{word}{name}"
    for side, word in (("l", "Left"), ("r", "Right"))
    for part, name in (("hip", "UpLeg"), ("knee", "Leg"), ("shoulder", "Arm"), ("elbow", "ForeArm"))
}


def test_a_leg_with_no_foot_ends_at_its_ankle() -> None:
    truth = _MIXAMO_NAMED
    joints = _mapped(_NO_FOOT, truth)
    for side, word in (("l", "Left"), ("r", "Right")):
        assert joints[f"{side}_hip"] == f"{word}UpLeg"
        assert joints[f"{side}_knee"] == f"{word}Leg"
        assert joints[f"{side}_ankle"] == f"{word}Foot"


# A leg with no foot under a joint both legs hang from (a Blender rig's ``Hip``), the rig's
# rest pose no figure (bones along their parent's axis, as a converter writes them), so
# the frames are read: the leg ends at the ankle itself, and nothing past it turns forward.
# Nameless, as where no name on the chain says "ankle" (a heel bone beside the foot, at the
# ankle's place, ending the chain instead).
_NO_FOOT_SHARED_HIP = [
    ("Hips", None, (0, 0, 0), False),
    ("Hip", "Hips", (0, -3, 0), False),
    ("{side}UpLeg", "Hip", (9, -7, 0), False),
    ("{side}Leg", "{side}UpLeg", (0, -42, 0), False),
    ("{side}Foot", "{side}Leg", (0, -40, 0), True),
    *_NO_FOOT[5:],
]


def test_a_bent_knee_on_a_leg_with_no_foot_is_not_its_ankle() -> None:
    """The left thigh upright and the shin swung back (a knee bent 49 degrees, the shin more
    level than the thigh), the right thigh forward with the same bend: the left knee turns
    as an ankle turns to the toes. Read so, the ankle was the knee, the knee the thigh's top
    and the hip the joint both legs hang from ("the two legs share their hip"): every frame
    refused, and the clip with them."""
    skeleton, names = _rig(_NO_FOOT_SHARED_HIP)
    truth = _MIXAMO_NAMED
    motion = walking(skeleton, truth, frames=4)
    rotations = motion.local_rotations.copy()
    for name, turn in (
        ("LeftUpLeg", 0.0),
        ("LeftLeg", 0.85),
        ("RightUpLeg", -0.45),
        ("RightLeg", 0.85),
    ):
        rotations[:, skeleton.index(name)] = Rotation.from_rotvec([turn, 0.0, 0.0]).as_matrix()
    motion = nameless(bone_axes(dataclasses.replace(motion, local_rotations=rotations), 1))
    body = describable_body(motion)
    check_canonical_body(body, "rig")
    assert body.mapping is not None
    joints = {c: names[int(j)] for c, j in zip(CANONICAL_JOINTS, body.mapping.joints, strict=True)}
    for side, word in (("l", "Left"), ("r", "Right")):
        assert joints[f"{side}_hip"] == f"{word}UpLeg"
        assert joints[f"{side}_knee"] == f"{word}Leg"
        assert joints[f"{side}_ankle"] == f"{word}Foot"
