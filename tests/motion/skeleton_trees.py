"""Joint trees of the skeleton families we support, as indented text (names as in real files).

Offsets are synthetic (each bone 1 unit along its parent's direction); only names and
structure matter for the mapping tests. Real files are exercised in the data tests.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from app.motion.model import Skeleton


def _indented(text: str) -> list[tuple[str, int, list[str]]]:
    """(name, parent index or -1, the rest of the line's words) per line of an indented
    tree."""
    rows: list[tuple[str, int, list[str]]] = []
    stack: list[tuple[int, int]] = []  # (indent, row index)
    for raw in text.strip("\n").splitlines():
        if not raw.strip():
            continue
        indent = len(raw) - len(raw.lstrip())
        while stack and stack[-1][0] >= indent:
            stack.pop()
        name, *words = raw.split()
        rows.append((name, stack[-1][1] if stack else -1, words))
        stack.append((indent, len(rows) - 1))
    return rows


def skeleton_from_tree(text: str) -> Skeleton:
    """Build a Skeleton from an indented tree; a trailing ``*`` marks an end site."""
    rows = _indented(text)
    offsets = np.tile([0.0, 1.0, 0.0], (len(rows), 1))
    offsets[0] = 0.0
    return Skeleton(
        tuple(name.rstrip("*") for name, _, _ in rows),
        np.array([parent for _, parent, _ in rows]),
        offsets,
        np.array([name.endswith("*") for name, _, _ in rows]),
    )


MOTIONBUILDER = """
Hips
  LHipJoint
    LeftUpLeg
      LeftLeg
        LeftFoot
          LeftToeBase
            LeftToeBase_end*
  RHipJoint
    RightUpLeg
      RightLeg
        RightFoot
          RightToeBase
            RightToeBase_end*
  LowerBack
    Spine
      Spine1
        Neck
          Neck1
            Head
              Head_end*
        LeftShoulder
          LeftArm
            LeftForeArm
              LeftHand
                LeftFingerBase
                  LeftHandIndex1
                    LeftHandIndex1_end*
                LThumb
                  LThumb_end*
        RightShoulder
          RightArm
            RightForeArm
              RightHand
                RightFingerBase
                  RightHandIndex1
                    RightHandIndex1_end*
                RThumb
                  RThumb_end*
"""

MAX = """
Hips
  LHipJoint
    LeftHip
      LeftKnee
        LeftAnkle
          LeftToe
            LeftToe_end*
  RHipJoint
    RightHip
      RightKnee
        RightAnkle
          RightToe
            RightToe_end*
  lowerback
    Chest
      Chest2
        lowerneck
          Neck
            Head
              Head_end*
        LeftCollar
          LeftShoulder
            LeftElbow
              LeftWrist
                lhand
                  LFingers
                    LFingers_end*
                  LThumb
                    LThumb_end*
        RightCollar
          RightShoulder
            RightElbow
              RightWrist
                rhand
                  RFingers
                    RFingers_end*
                  RThumb
                    RThumb_end*
"""

DAZ = """
hip
  abdomen
    chest
      neck
        head
          leftEye
            leftEye_end*
          rightEye
            rightEye_end*
      rCollar
        rShldr
          rForeArm
            rHand
              rThumb1
                rThumb2
                  rThumb2_end*
              rIndex1
                rIndex2
                  rIndex2_end*
              rMid1
                rMid2
                  rMid2_end*
      lCollar
        lShldr
          lForeArm
            lHand
              lThumb1
                lThumb2
                  lThumb2_end*
              lIndex1
                lIndex2
                  lIndex2_end*
              lMid1
                lMid2
                  lMid2_end*
  rButtock
    rThigh
      rShin
        rFoot
          rFoot_end*
  lButtock
    lThigh
      lShin
        lFoot
          lFoot_end*
"""

BANDAI = """
joint_Root
  Hips
    Spine
      Chest
        Neck
          Head
            Head_end*
        Shoulder_L
          UpperArm_L
            LowerArm_L
              Hand_L
                Hand_L_end*
        Shoulder_R
          UpperArm_R
            LowerArm_R
              Hand_R
                Hand_R_end*
    UpperLeg_L
      LowerLeg_L
        Foot_L
          Toes_L
            Toes_L_end*
    UpperLeg_R
      LowerLeg_R
        Foot_R
          Toes_R
            Toes_R_end*
"""

CMU_ASF = """
root
  lhipjoint
    lfemur
      ltibia
        lfoot
          ltoes
            ltoes_end*
  rhipjoint
    rfemur
      rtibia
        rfoot
          rtoes
            rtoes_end*
  lowerback
    upperback
      thorax
        lowerneck
          upperneck
            head
              head_end*
        lclavicle
          lhumerus
            lradius
              lwrist
                lhand
                  lfingers
                    lfingers_end*
                lthumb
                  lthumb_end*
        rclavicle
          rhumerus
            rradius
              rwrist
                rhand
                  rfingers
                    rfingers_end*
                rthumb
                  rthumb_end*
"""

MIXAMO = """
mixamorig:Hips
  mixamorig:Spine
    mixamorig:Spine1
      mixamorig:Spine2
        mixamorig:Neck
          mixamorig:Head
            mixamorig:HeadTop_End*
        mixamorig:LeftShoulder
          mixamorig:LeftArm
            mixamorig:LeftForeArm
              mixamorig:LeftHand
                mixamorig:LeftHandThumb1
                  mixamorig:LeftHandThumb1_end*
                mixamorig:LeftHandMiddle1
                  mixamorig:LeftHandMiddle2
                    mixamorig:LeftHandMiddle2_end*
        mixamorig:RightShoulder
          mixamorig:RightArm
            mixamorig:RightForeArm
              mixamorig:RightHand
                mixamorig:RightHandThumb1
                  mixamorig:RightHandThumb1_end*
                mixamorig:RightHandMiddle1
                  mixamorig:RightHandMiddle2
                    mixamorig:RightHandMiddle2_end*
  mixamorig:LeftUpLeg
    mixamorig:LeftLeg
      mixamorig:LeftFoot
        mixamorig:LeftToeBase
          mixamorig:LeftToe_End*
  mixamorig:RightUpLeg
    mixamorig:RightLeg
      mixamorig:RightFoot
        mixamorig:RightToeBase
          mixamorig:RightToe_End*
"""


def skeleton_from_points(text: str) -> Skeleton:
    """Build a Skeleton from an indented tree of ``name x y z`` lines, each the joint's rest
    position in the world (the offsets are the differences); a ``*`` after the name marks an
    end site."""
    rows = _indented(text)
    parents = np.array([parent for _, parent, _ in rows])
    at = np.array([[float(v) for v in words] for _, _, words in rows])
    offsets = at - at[np.maximum(parents, 0)]
    offsets[0] = 0.0
    return Skeleton(
        tuple(name.rstrip("*") for name, _, _ in rows),
        parents,
        offsets,
        np.array([name.endswith("*") for name, _, _ in rows]),
    )


# A short game rig in the shape of Khronos's CesiumMan sample (Y up, metres): three spine
# joints, the neck two, arms of three joints with no hand bones, legs ending in a ball joint
# a little below and ahead of the ankle; every leaf a joint (a point, no tail).
SHORT_GAME_RIG = """
torso_1 0 0 0
  torso_2 0 0.145 0.011
    torso_3 0 0.395 -0.004
      neck_1 0 0.459 0.006
        neck_2 0 0.511 0.008
      arm_L_4 0.091 0.395 -0.004
        arm_L_3 0.307 0.285 -0.016
          arm_L_2 0.45 0.196 0.066
      arm_R -0.091 0.395 -0.004
        arm_R_2 -0.306 0.286 -0.016
          arm_R_3 -0.45 0.196 0.067
  leg_L_1 0.068 -0.065 0.024
    leg_L_2 0.077 -0.327 0.068
      leg_L_3 0.078 -0.593 -0.005
        leg_L_5 0.08 -0.658 0.027
  leg_R_1 -0.068 -0.065 0.024
    leg_R_2 -0.077 -0.327 0.068
      leg_R_3 -0.078 -0.593 -0.005
        leg_R_5 -0.08 -0.658 0.027
"""


# Segment lengths as fractions of standing height (Drillis & Contini 1966), for the
# synthetic humanoids below.
_THIGH, _SHIN, _ANKLE_HEIGHT, _FOOT = 0.245, 0.246, 0.039, 0.152
_UPPER_ARM, _FOREARM, _HAND = 0.186, 0.146, 0.108
_SIDE_NAMES = {
    "unity": {
        "hip": "UpperLeg", "knee": "LowerLeg", "ankle": "Foot", "toe": "Toes",
        "clavicle": "Shoulder", "shoulder": "UpperArm", "elbow": "LowerArm", "wrist": "Hand",
    },
    "blender": {
        "hip": "thigh", "knee": "shin", "ankle": "foot", "toe": "toe",
        "clavicle": "shoulder", "shoulder": "upper_arm", "elbow": "forearm", "wrist": "hand",
    },
    "anon": {},
}  # fmt: skip


@dataclass(frozen=True)
class Humanoid:
    """The shape of a synthetic humanoid rig (rest pose, Y up, metres).

    ``hand``: ``"fingers"`` (three fingers and a thumb branching at the wrist), ``"bone"``
    (one hand bone, no fingers) or ``"none"`` (the arm ends at the wrist). ``arm_angle``:
    degrees below the horizontal (0 is a T-pose, 45 an A-pose). ``names``: a key of
    :data:`_SIDE_NAMES`; ``"anon"`` names every joint ``j<number>``.
    """

    clavicle: bool = True
    spines: int = 3
    neck: bool = True
    head_end: bool = True
    hand: str = "fingers"
    finger_ends: bool = True
    toes: bool = True
    arm_angle: float = 0.0
    hips_coincide: bool = False
    twist_bones: bool = False
    face_bones: int = 0
    names: str = "unity"
    height: float = 1.7


def synthetic_humanoid(shape: Humanoid) -> tuple[Skeleton, dict[str, str]]:
    """A rig of ``shape`` and the truth: canonical joint -> the joint's name (``head`` is the
    head joint; the mapper may take an end effector above it)."""
    h = shape.height
    joints: list[tuple[str, str | None, np.ndarray]] = []

    def add(name: str, parent: str | None, point: Sequence[float]) -> str:
        joints.append((name, parent, np.asarray(point, dtype=float)))
        return name

    pelvis_height = (_THIGH + _SHIN + _ANKLE_HEIGHT + 0.04) * h
    truth = {"pelvis": add("Hips", None, [0.0, pelvis_height, 0.0])}
    shoulder_height = pelvis_height + 0.30 * h
    parent = "Hips"
    for i in range(shape.spines):
        rise = (i + 1) * (shoulder_height - pelvis_height) / shape.spines
        parent = add(f"Spine{i or ''}", parent, [0.0, pelvis_height + rise, 0.0])
    truth["chest"] = chest = parent
    if shape.neck:
        parent = truth["neck"] = add("Neck", chest, [0.0, shoulder_height + 0.04 * h, 0.0])
    truth["head"] = head = add("Head", parent, [0.0, shoulder_height + 0.09 * h, 0.0])
    if shape.head_end:
        add("HeadTop_End", head, [0.0, h, 0.0])
    for k in range(shape.face_bones):  # eyes, brows, lips: short leaves in front of the head
        angle = 2 * np.pi * k / max(shape.face_bones, 1)
        spot = [0.04 * h * np.cos(angle), shoulder_height + 0.1 * h + 0.03 * h * np.sin(angle)]
        add(f"Face{k}", head, [spot[0], spot[1], 0.06 * h])
    slope = np.radians(shape.arm_angle)
    words = _SIDE_NAMES[shape.names]
    for side, sign in (("l", 1.0), ("r", -1.0)):

        def name(part: str, side: str = side) -> str:
            word = words.get(part, part)
            if shape.names == "blender":
                return f"{word}.{side.upper()}"
            return f"{'Left' if side == 'l' else 'Right'}{word}"

        along = np.array([sign * np.cos(slope), -np.sin(slope), 0.0])
        top = chest
        if shape.clavicle:
            top = add(
                name("clavicle"), chest, [sign * 0.02 * h, shoulder_height - 0.02 * h, 0.02 * h]
            )
        shoulder = np.array([sign * 0.1 * h, shoulder_height - 0.01 * h, 0.0])
        elbow, wrist = (
            shoulder + along * _UPPER_ARM * h,
            shoulder + along * (_UPPER_ARM + _FOREARM) * h,
        )
        upper = truth[f"{side}_shoulder"] = add(name("shoulder"), top, shoulder)
        if shape.twist_bones:
            add(name("shoulder") + "Twist", upper, (shoulder + elbow) / 2)
        truth[f"{side}_elbow"] = add(name("elbow"), upper, elbow)
        hand = truth[f"{side}_wrist"] = add(name("wrist"), truth[f"{side}_elbow"], wrist)
        if shape.hand == "bone":
            add(name("wrist") + "_end", hand, wrist + along * _HAND * h)
        elif shape.hand == "fingers":
            for finger, across in enumerate((-0.02, 0.0, 0.02)):
                base = wrist + along * 0.05 * h + np.array([0.0, 0.0, across * h])
                first = add(name(f"finger{finger}1"), hand, base)
                second = add(name(f"finger{finger}2"), first, base + along * 0.03 * h)
                if shape.finger_ends:
                    add(name(f"finger{finger}3"), second, base + along * 0.055 * h)
            thumb = add(name("thumb1"), hand, wrist + along * 0.02 * h + [0.0, 0.0, 0.03 * h])
            add(name("thumb2"), thumb, wrist + along * 0.04 * h + [0.0, 0.0, 0.05 * h])
        x = sign * 0.09 * h
        hip = [0.0, pelvis_height, 0.0] if shape.hips_coincide else [x, pelvis_height - 0.04 * h, 0]
        truth[f"{side}_hip"] = add(name("hip"), "Hips", hip)
        knee = [x, (_SHIN + _ANKLE_HEIGHT) * h, 0.0]
        truth[f"{side}_knee"] = add(name("knee"), truth[f"{side}_hip"], knee)
        foot = truth[f"{side}_ankle"] = add(
            name("ankle"), truth[f"{side}_knee"], [x, _ANKLE_HEIGHT * h, 0]
        )
        if shape.toes:
            toe = add(name("toe"), foot, [x, 0.01 * h, 0.7 * _FOOT * h])
            add(name("toe") + "_End", toe, [x, 0.01 * h, _FOOT * h])
    index = {name: i for i, (name, _, _) in enumerate(joints)}
    parents = np.array([index[p] if p is not None else -1 for _, p, _ in joints])
    points = np.array([point for _, _, point in joints])
    offsets = points - points[np.maximum(parents, 0)]
    offsets[0] = 0.0
    names = tuple(name for name, _, _ in joints)
    if shape.names == "anon":
        rename = {name: f"j{i}" for i, name in enumerate(names)}
        names = tuple(rename[n] for n in names)
        truth = {c: rename[n] for c, n in truth.items()}
    return Skeleton(names, parents, offsets, np.zeros(len(names), dtype=bool)), truth


# SMPL's joints in its template rest pose (neutral body, metres, Y up), in SMPL's own tree:
# collar -> shoulder -> elbow -> wrist -> hand, pelvis -> hip -> knee -> ankle -> foot.
SMPL = """
Pelvis -0.0018 -0.2233 0.0282
  L_Hip 0.0695 -0.3142 0.0239
    L_Knee 0.1040 -0.6758 0.0169
      L_Ankle 0.0870 -1.0708 -0.0213
        L_Foot 0.1197 -1.1353 0.0996
  R_Hip -0.0677 -0.3147 0.0214
    R_Knee -0.1056 -0.6793 0.0147
      R_Ankle -0.0873 -1.0721 -0.0186
        R_Foot -0.1185 -1.1367 0.1049
  Spine1 -0.0025 -0.1089 0.0013
    Spine2 0.0054 0.0247 0.0295
      Spine3 0.0011 0.0724 0.0312
        Neck -0.0017 0.2922 -0.0140
          Head 0.0051 0.3612 0.0494
        L_Collar 0.0774 0.2000 0.0027
          L_Shoulder 0.1990 0.2342 -0.0149
            L_Elbow 0.4501 0.2207 -0.0307
              L_Wrist 0.7004 0.2301 -0.0362
                L_Hand 0.7837 0.2212 -0.0536
        R_Collar -0.0742 0.1989 0.0001
          R_Shoulder -0.1918 0.2326 -0.0149
            R_Elbow -0.4502 0.2204 -0.0291
              R_Wrist -0.6991 0.2319 -0.0376
                R_Hand -0.7850 0.2213 -0.0559
"""
