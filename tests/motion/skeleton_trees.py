"""Joint trees of the skeleton families we support, as indented text (names as in real files).

Offsets are synthetic (each bone 1 unit along its parent's direction); only names and
structure matter for the mapping tests. Real files are exercised in the data tests.
"""

from __future__ import annotations

import numpy as np

from app.motion.model import Skeleton


def skeleton_from_tree(text: str) -> Skeleton:
    """Build a Skeleton from an indented tree; a trailing ``*`` marks an end site."""
    names: list[str] = []
    parents: list[int] = []
    end_site: list[bool] = []
    stack: list[tuple[int, int]] = []  # (indent, joint index)
    for raw in text.strip("\n").splitlines():
        if not raw.strip():
            continue
        indent = len(raw) - len(raw.lstrip())
        name = raw.strip()
        is_end = name.endswith("*")
        name = name.rstrip("*")
        while stack and stack[-1][0] >= indent:
            stack.pop()
        parents.append(stack[-1][1] if stack else -1)
        names.append(name)
        end_site.append(is_end)
        stack.append((indent, len(names) - 1))
    offsets = np.tile([0.0, 1.0, 0.0], (len(names), 1))
    offsets[0] = 0.0
    return Skeleton(tuple(names), np.array(parents), offsets, np.array(end_site))


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
    names: list[str] = []
    parents: list[int] = []
    points: list[np.ndarray] = []
    end_site: list[bool] = []
    stack: list[tuple[int, int]] = []  # (indent, joint index)
    for raw in text.strip("\n").splitlines():
        if not raw.strip():
            continue
        indent = len(raw) - len(raw.lstrip())
        name, *xyz = raw.split()
        while stack and stack[-1][0] >= indent:
            stack.pop()
        parents.append(stack[-1][1] if stack else -1)
        names.append(name.rstrip("*"))
        end_site.append(name.endswith("*"))
        points.append(np.array([float(v) for v in xyz]))
        stack.append((indent, len(names) - 1))
    at = np.array(points)
    offsets = np.array([at[j] - at[p] if p >= 0 else np.zeros(3) for j, p in enumerate(parents)])
    return Skeleton(tuple(names), np.array(parents), offsets, np.array(end_site))


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
