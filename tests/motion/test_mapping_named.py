"""Names shifted one joint down each limb (issue 20; app/motion/mapping/named.py): some
converters (video pose tools) name each joint after the bone that ENDS there, so the joint
named ``LeftArm`` sits at the elbow, ``LeftForeArm`` at the wrist and ``LeftHand`` a few
units past it; ``LeftUpLeg`` at the knee, ``LeftLeg`` at the ankle. Structure decides, names
are hints: such a rig maps as the same rig named as usual, and a warning says the names were
not followed. A rig whose names are where they say maps by name, without that warning."""

from __future__ import annotations

import numpy as np

from app.motion.model import Motion, Skeleton
from app.motion.pipeline import describable_body
from app.motion.skeleton_map import CANONICAL_JOINTS
from tests.motion.synthetic import walking

# One rig (cm, T-pose, Y up, facing +z), joint by joint: parent, rest offset, the joint's
# name as usually named, and as named after the bone that ends there. The ``L`` side; the
# ``R`` side mirrors it.
_RIG = [
    ("Hips", None, (0, 0, 0), "Hips", "Hips"),
    ("hip", "Hips", (9, -3, 0), "LeftUpLeg", "LHipJoint"),
    ("knee", "hip", (0, -42, 0), "LeftLeg", "LeftUpLeg"),
    ("ankle", "knee", (0, -40, 0), "LeftFoot", "LeftLeg"),
    ("ball", "ankle", (0, -6, 12), "LeftToeBase", "LeftFoot"),
    ("toe", "ball", (0, 0, 6), "LeftToeBase_end", "LeftToeBase"),
    ("Spine", "Hips", (0, 12, 0), "Spine", "Spine"),
    ("Chest", "Spine", (0, 20, 0), "Chest", "Chest"),
    ("Neck", "Chest", (0, 12, 0), "Neck", "Neck"),
    ("Head", "Neck", (0, 8, 0), "Head", "Head"),
    ("Head_end", "Head", (0, 18, 0), "Head_end", "Head_end"),
    ("shoulder", "Chest", (17, 2, 0), "LeftArm", "LeftShoulder"),
    ("elbow", "shoulder", (28, 0, 0), "LeftForeArm", "LeftArm"),
    ("wrist", "elbow", (25, 0, 0), "LeftHand", "LeftForeArm"),
    ("knuckle", "wrist", (8, 0, 0), "LeftHandIndex1", "LeftHand"),
    ("fingertip", "knuckle", (6, 0, 0), "LeftHandIndex1_end", "LeftHandIndex1"),
]
_ENDS = {"toe", "Head_end", "fingertip"}


def _rig(shifted: bool) -> tuple[Motion, list[str]]:
    """The rig walking, named as usual or shifted, and its joints' places (``l_knee``...)."""
    names: list[str] = []
    places: list[str] = []
    parents: list[int] = []
    offsets: list[tuple[float, ...]] = []
    for side, sign, swap in (("l", 1.0, ("Left", "L")), ("r", -1.0, ("Right", "R"))):
        for place, parent, offset, usual, after_bone in _RIG:
            name = after_bone if shifted else usual
            trunk = place[0].isupper()
            if trunk and side == "r":
                continue
            if not trunk:
                name = name.replace("Left", swap[0]).replace("LHip", swap[1] + "Hip")
                place = f"{side}_{place}"
                parent = parent if parent[0].isupper() else f"{side}_{parent}"
            names.append(name)
            places.append(place)
            parents.append(-1 if parent is None else places.index(parent))
            offsets.append((sign * offset[0], offset[1], offset[2]))
    skeleton = Skeleton(
        tuple(names),
        np.array(parents),
        np.array(offsets, dtype=float),
        np.array([place.split("_", 1)[-1] in _ENDS or place in _ENDS for place in places]),
    )
    truth = {
        f"{side}_{part}": names[places.index(f"{side}_{part}")]
        for side in "lr"
        for part in ("hip", "knee", "shoulder", "elbow")
    }
    return walking(skeleton, truth), places


def _mapped(shifted: bool) -> tuple[dict[str, str], tuple[str, ...]]:
    """Canonical joint -> the place of the joint it maps to, and the mapping's warnings."""
    motion, places = _rig(shifted)
    mapping = describable_body(motion).mapping
    assert mapping is not None
    return (
        {c: places[int(j)] for c, j in zip(CANONICAL_JOINTS, mapping.joints, strict=True)},
        mapping.warnings,
    )


def test_plain_rig_maps_by_its_names() -> None:
    joints, warnings = _mapped(shifted=False)
    for side in "lr":
        for part in ("hip", "knee", "ankle", "shoulder", "elbow", "wrist"):
            assert joints[f"{side}_{part}"] == f"{side}_{part}"
    assert not any("names not followed" in w for w in warnings)


def test_names_shifted_down_the_limbs_map_as_the_plain_rig() -> None:
    plain, _ = _mapped(shifted=False)
    shifted, warnings = _mapped(shifted=True)
    assert shifted == plain
    said = " ".join(w for w in warnings if "names not followed" in w)
    assert "'LeftArm' .. 'LeftForeArm'" in said and "'RightUpLeg' .. 'RightLeg'" in said
