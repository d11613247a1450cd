"""Names from exporters we have not seen: a real rig renamed into another exporter's naming
convention must map to the same source joints as the named original (issue 20; names are
hints, docs/skeletons.md, "Names from exporters we have not seen").

Each rig is renamed through its own named mapping: every canonical joint gets the name the
convention gives that joint (``Bip01 L UpperArm``, ``upperarm_l``, ``lShldrBend``,
``DEF-upper_arm.L``, ``ShoulderLeft``, ``L_Shoulder``, ``左腕``...), the joints between them
(spine, neck, collar, twist, finger and toe joints) the convention's names for such joints,
and every other joint the convention's generic or numbered names. The structure is not
touched, so the renamed rig must map to the same joints, compared by index. Two hostile
namings: every name on the other side (a mirrored naming: the names decide a mirrored
capture, so the mapping is the original's with left and right swapped), and the rig's own
names shuffled among its joints (the names lie: the mapping must be no worse than with no
names at all).

On the CMU and Bandai fixtures every convention is asserted; on the 66 human BVH files of
the development sets (``tests/motion/test_nameless_real.py``), per convention, a ratchet on
the number of rigs that map alike.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable

import numpy as np
import pytest

from app.errors import MocapError
from app.motion.formats import read_bvh
from app.motion.ground import sample_frames
from app.motion.mapping.tree import _is_thumb
from app.motion.model import Motion
from app.motion.pipeline import describable_body
from app.motion.skeleton_map import CANONICAL_INDEX, CANONICAL_JOINTS
from tests.motion.conftest import BANDAI_FIXTURE, CMU_BVH_FIXTURE, fixture_bytes
from tests.motion.read_once import read_only
from tests.motion.test_mapping_pairs import nameless
from tests.motion.test_nameless_real import FILES

# A joint's role in the rig, from the named mapping: (role, side "l"/"r"/None, index among
# the joints of that role and side, how many there are).
Role = tuple[str, str | None, int, int]


def _chain_up(parents: np.ndarray, joint: int, stop: set[int]) -> list[int]:
    """``joint`` and its ancestors up to (not including) the first joint of ``stop``."""
    out = []
    while joint >= 0 and joint not in stop:
        out.append(joint)
        joint = int(parents[joint])
    return out[::-1]


def roles(motion: Motion) -> list[Role]:
    """Every joint's role, read from the named rig's mapping."""
    mapping = describable_body(motion).mapping
    assert mapping is not None
    skeleton = motion.skeleton
    parents = skeleton.parents
    at = {c: int(mapping.joints[CANONICAL_INDEX[c]]) for c in CANONICAL_JOINTS}
    found: dict[int, tuple[str, str | None, int]] = {}

    def put(joints: list[int], role: str, side: str | None) -> None:
        for i, j in enumerate(joints):
            found.setdefault(j, (role, side, i))

    pelvis, neck, head = at["pelvis"], at["neck"], int(mapping.head_joint)
    trunk = _chain_up(parents, head, set())
    below_pelvis = trunk[trunk.index(pelvis) + 1 :]
    put(trunk[: trunk.index(pelvis)], "root", None)
    put([pelvis], "pelvis", None)
    neck_at = below_pelvis.index(neck) if neck in below_pelvis else len(below_pelvis) - 1
    put(below_pelvis[:neck_at], "spine", None)
    put(below_pelvis[neck_at:-1], "neck", None)
    put([head], "head", None)
    trunk_set = set(trunk)
    for side in "lr":
        arm = _chain_up(parents, at[f"{side}_wrist"], trunk_set)
        shoulder, elbow = arm.index(at[f"{side}_shoulder"]), arm.index(at[f"{side}_elbow"])
        put(arm[: shoulder - 1], "arm_root", side)
        put(arm[max(shoulder - 1, 0) : shoulder], "clavicle", side)
        put([arm[shoulder]], "shoulder", side)
        put(arm[shoulder + 1 : elbow], "upperarm_twist", side)
        put([arm[elbow]], "elbow", side)
        put(arm[elbow + 1 : -1], "forearm_twist", side)
        put([arm[-1]], "wrist", side)
        leg = _chain_up(parents, at[f"{side}_ankle"], trunk_set)
        hip, knee = leg.index(at[f"{side}_hip"]), leg.index(at[f"{side}_knee"])
        put(leg[:hip], "leg_root", side)
        put([leg[hip]], "hip", side)
        put(leg[hip + 1 : knee], "thigh_twist", side)
        put([leg[knee]], "knee", side)
        put(leg[knee + 1 : -1], "calf_twist", side)
        put([leg[-1]], "ankle", side)
        toe = _chain_up(parents, at[f"{side}_toe"], set(leg))
        toe = [j for j in toe if not skeleton.end_site[j]]
        put(toe[:1], "toe", side)
        put(toe[1:], "toe_end", side)
    # Everything else, by where it hangs: fingers, toes, face, or anywhere (an extra).
    below = {"wrist": "finger", "ankle": "toe_end", "toe": "toe_end", "head": "face"}
    below_kinds = {*below.values(), "thumb"}
    owner: list[tuple[str, str | None]] = []
    for j in range(skeleton.joint_count):
        if j in found:
            role, side, _ = found[j]
            owner.append((below.get(role, role if role in below_kinds else "extra"), side))
            continue
        p = int(parents[j])
        kind, side = owner[p] if p >= 0 else ("extra", None)
        if kind in ("finger", "thumb") and _is_thumb(skeleton.names[j]):
            kind = "thumb"  # the rig's thumb stays a thumb (the hand tip skips thumbs)
        found[j] = (kind, side, -1)
        owner.append((kind, side))
    counters: dict[tuple[str, str | None], int] = {}
    out: list[Role] = []
    totals: dict[tuple[str, str | None], int] = {}
    for role, side, _ in found.values():
        totals[(role, side)] = totals.get((role, side), 0) + 1
    for j in range(skeleton.joint_count):
        role, side, index = found[j]
        if skeleton.end_site[j] and index < 0:
            out.append(("end", side, 0, 1))
            continue
        if index < 0:
            index = counters.get((role, side), 0)
            counters[(role, side)] = index + 1
        out.append((role, side, index, totals[(role, side)]))
    return out


# A convention: role, side, index, count -> name. ``None`` for a role it has no name for
# (the generic ``extra`` name is used then).
Convention = Callable[[str, str | None, int, int], str | None]


def _biped(role: str, side: str | None, i: int, n: int) -> str | None:
    """3ds Max Biped."""
    s = {"l": "L ", "r": "R ", None: ""}[side]
    names = {
        "root": "Bip01" if i == 0 else f"Bip01 Footsteps{i}",
        "pelvis": "Bip01 Pelvis",
        "spine": "Bip01 Spine" if i == 0 else f"Bip01 Spine{i}",
        "neck": "Bip01 Neck" if i == 0 else f"Bip01 Neck{i}",
        "head": "Bip01 Head",
        "clavicle": f"Bip01 {s}Clavicle",
        "shoulder": f"Bip01 {s}UpperArm",
        "upperarm_twist": f"Bip01 {s}UpArmTwist" + (str(i) if i else ""),
        "elbow": f"Bip01 {s}Forearm",
        "forearm_twist": f"Bip01 {s}ForeTwist" + (str(i) if i else ""),
        "wrist": f"Bip01 {s}Hand",
        "finger": f"Bip01 {s}Finger{i // 3 + 1}{i % 3 or ''}",
        "thumb": f"Bip01 {s}Finger0{i or ''}",
        "hip": f"Bip01 {s}Thigh",
        "thigh_twist": f"Bip01 {s}ThighTwist" + (str(i) if i else ""),
        "knee": f"Bip01 {s}Calf",
        "calf_twist": f"Bip01 {s}CalfTwist" + (str(i) if i else ""),
        "ankle": f"Bip01 {s}Foot",
        "toe": f"Bip01 {s}Toe0",
        "toe_end": f"Bip01 {s}Toe{i // 2}{i % 2 + 1}",
        "face": f"Bip01 Ponytail1{i}",
        "extra": f"Bip01 {s}Xtra{i:02d}",
    }
    return names.get(role)


def _unreal(role: str, side: str | None, i: int, n: int) -> str | None:
    """Unreal Engine 4 mannequin (also Unreal's UE5 Manny for these joints)."""
    s = f"_{side}" if side else ""
    fingers = ("index", "middle", "ring", "pinky")
    names = {
        "root": "root" if i == 0 else f"root_{i:02d}",
        "pelvis": "pelvis",
        "spine": f"spine_{i + 1:02d}",
        "neck": f"neck_{i + 1:02d}",
        "head": "head",
        "clavicle": f"clavicle{s}",
        "shoulder": f"upperarm{s}",
        "upperarm_twist": f"upperarm_twist_{i + 1:02d}{s}",
        "elbow": f"lowerarm{s}",
        "forearm_twist": f"lowerarm_twist_{i + 1:02d}{s}",
        "wrist": f"hand{s}",
        "finger": f"{fingers[i // 3 % 4]}_{i % 3 + 1:02d}{s}" + ("" if i < 12 else f"_{i}"),
        "thumb": f"thumb_{i + 1:02d}{s}",
        "hip": f"thigh{s}",
        "thigh_twist": f"thigh_twist_{i + 1:02d}{s}",
        "knee": f"calf{s}",
        "calf_twist": f"calf_twist_{i + 1:02d}{s}",
        "ankle": f"foot{s}",
        "toe": f"ball{s}",
        "toe_end": f"littletoe_{i + 1:02d}{s}",
        "face": f"facial_{i + 1:02d}",
        "extra": f"ik_bone_{i:02d}{s}",
    }
    return names.get(role)


def _spread(names: tuple[str, ...], i: int, n: int) -> str:
    """The ``i``-th of ``n`` joints named from ``names`` (first and last kept)."""
    if i >= n:
        return names[0]
    if n <= len(names):
        picks = [round(k * (len(names) - 1) / max(n - 1, 1)) for k in range(n)]
        return names[picks[i]]
    return names[i] if i < len(names) else f"{names[-1]}{i}"


def _daz(role: str, side: str | None, i: int, n: int) -> str | None:
    """DAZ Genesis 3 / 8."""
    s = side or ""
    names = {
        "root": "Genesis8Female" if i == 0 else f"Genesis8Female{i}",
        "pelvis": "hip",
        "spine": _spread(("abdomenLower", "abdomenUpper", "chestLower", "chestUpper"), i, n),
        "neck": _spread(("neckLower", "neckUpper"), i, n),
        "head": "head",
        "clavicle": f"{s}Collar",
        "shoulder": f"{s}ShldrBend",
        "upperarm_twist": f"{s}ShldrTwist" + (str(i) if i else ""),
        "elbow": f"{s}ForearmBend",
        "forearm_twist": f"{s}ForearmTwist" + (str(i) if i else ""),
        "wrist": f"{s}Hand",
        "finger": f"{s}{('Index', 'Mid', 'Ring', 'Pinky')[i // 3 % 4]}{i % 3 + 1}"
        + ("" if i < 12 else str(i)),
        "thumb": f"{s}Thumb{i + 1}",
        "hip": f"{s}ThighBend",
        "thigh_twist": f"{s}ThighTwist" + (str(i) if i else ""),
        "knee": f"{s}Shin",
        "ankle": f"{s}Foot",
        "toe": f"{s}Toe",
        "toe_end": f"{s}SmallToe{i + 1}",
        "face": f"{'upperFaceRig' if i == 0 else f'faceRig{i}'}",
        "extra": f"{s}Extra{i}" if s else f"extra{i}",
    }
    return names.get(role)


def _rigify(role: str, side: str | None, i: int, n: int) -> str | None:
    """Blender Rigify (the deforming ``DEF-`` bones)."""
    s = f".{side.upper()}" if side else ""
    names = {
        "root": "root" if i == 0 else f"root.{i:03d}",
        "pelvis": "DEF-spine",
        "spine": f"DEF-spine.{i + 1:03d}",
        "neck": f"DEF-spine.{i + 10:03d}",
        "head": "DEF-spine.020",
        "arm_root": f"DEF-breast{s}" + (f".{i:03d}" if i else ""),
        "clavicle": f"DEF-shoulder{s}",
        "shoulder": f"DEF-upper_arm{s}",
        "upperarm_twist": f"DEF-upper_arm{s}.{i + 1:03d}",
        "elbow": f"DEF-forearm{s}",
        "forearm_twist": f"DEF-forearm{s}.{i + 1:03d}",
        "wrist": f"DEF-hand{s}",
        "finger": f"DEF-f_{('index', 'middle', 'ring', 'pinky')[i // 3 % 4]}.{i % 3 + 1:02d}{s}"
        + ("" if i < 12 else f".{i:03d}"),
        "thumb": f"DEF-thumb.{i + 1:02d}{s}",
        "leg_root": f"DEF-pelvis{s}" + (f".{i:03d}" if i else ""),
        "hip": f"DEF-thigh{s}",
        "thigh_twist": f"DEF-thigh{s}.{i + 1:03d}",
        "knee": f"DEF-shin{s}",
        "calf_twist": f"DEF-shin{s}.{i + 1:03d}",
        "ankle": f"DEF-foot{s}",
        "toe": f"DEF-toe{s}",
        "toe_end": f"DEF-toe{s}.{i + 1:03d}",
        "face": f"DEF-face.{i:03d}",
        "extra": f"DEF-bone{s}.{i:03d}",
    }
    return names.get(role)


def _kinect(role: str, side: str | None, i: int, n: int) -> str | None:
    """Microsoft Kinect v2 (``JointType``)."""
    s = {"l": "Left", "r": "Right", None: ""}[side]
    names = {
        "pelvis": "SpineBase",
        "spine": "SpineShoulder" if i == n - 1 else "SpineMid" if i == 0 else None,
        "neck": "Neck" if i == 0 else None,
        "head": "Head",
        "shoulder": f"Shoulder{s}",
        "elbow": f"Elbow{s}",
        "wrist": f"Wrist{s}",
        "finger": (f"Hand{s}", f"HandTip{s}")[i] if i < 2 else None,
        "thumb": f"Thumb{s}" if i == 0 else None,
        "hip": f"Hip{s}",
        "knee": f"Knee{s}",
        "ankle": f"Ankle{s}",
        "toe": f"Foot{s}",
    }
    return names.get(role)


def _smpl(role: str, side: str | None, i: int, n: int) -> str | None:
    """SMPL / SMPL-H (the body model's joint names)."""
    s = {"l": "L_", "r": "R_", None: ""}[side]
    names = {
        "root": "root" if i == 0 else None,
        "pelvis": "Pelvis",
        "spine": f"Spine{i + 1}",
        "neck": "Neck" if i == 0 else None,
        "head": "Head",
        "clavicle": f"{s}Collar",
        "shoulder": f"{s}Shoulder",
        "elbow": f"{s}Elbow",
        "wrist": f"{s}Wrist",
        "finger": f"{s}Hand" if i == 0 else f"{s}{('Index', 'Middle', 'Ring')[i % 3]}{i}",
        "thumb": f"{s}Thumb{i + 1}",
        "hip": f"{s}Hip",
        "knee": f"{s}Knee",
        "ankle": f"{s}Ankle",
        "toe": f"{s}Foot",
    }
    return names.get(role)


def _mmd(role: str, side: str | None, i: int, n: int) -> str | None:
    """MikuMikuDance / VRM standard bone names (Japanese, as PMX models and MMD-derived VRM
    and BVH exports write them)."""
    s = {"l": "左", "r": "右", None: ""}[side]
    digits = str(i).translate(str.maketrans("0123456789", "０１２３４５６７８９"))
    names = {
        "root": ("全ての親", "センター", "グルーブ")[i] if i < 3 else f"センター{i}",
        "pelvis": "下半身",
        "spine": "上半身" if i == 0 else f"上半身{i + 1}",
        "neck": "首" if i == 0 else f"首{i + 1}",
        "head": "頭",
        "clavicle": f"{s}肩",
        "shoulder": f"{s}腕",
        "upperarm_twist": f"{s}腕捩" + (str(i) if i else ""),
        "elbow": f"{s}ひじ",
        "forearm_twist": f"{s}手捩" + (str(i) if i else ""),
        "wrist": f"{s}手首",
        "finger": f"{s}{('人指', '中指', '薬指', '小指')[i // 3 % 4]}{digits}",
        "thumb": f"{s}親指{digits}",
        "leg_root": f"腰キャンセル{s}" + (str(i) if i else ""),
        "hip": f"{s}足",
        "knee": f"{s}ひざ",
        "ankle": f"{s}足首",
        "toe": f"{s}つま先",
        "face": "両目" if i == 0 else f"髪{i}",
        "extra": f"{s}ダミー{i}",
    }
    return names.get(role)


def _vroid(role: str, side: str | None, i: int, n: int) -> str | None:
    """VRoid Studio's VRM export (``J_Bip_`` bones, VRM humanoid names inside)."""
    s = {"l": "L", "r": "R", None: "C"}[side]
    names = {
        "root": "Root" if i == 0 else f"Root{i}",
        "pelvis": "J_Bip_C_Hips",
        "spine": _spread(("J_Bip_C_Spine", "J_Bip_C_Chest", "J_Bip_C_UpperChest"), i, n),
        "neck": "J_Bip_C_Neck" if i == 0 else f"J_Adj_C_Neck{i}",
        "head": "J_Bip_C_Head",
        "clavicle": f"J_Bip_{s}_Shoulder",
        "shoulder": f"J_Bip_{s}_UpperArm",
        "upperarm_twist": f"J_Sec_{s}_UpperArmTwist{i}",
        "elbow": f"J_Bip_{s}_LowerArm",
        "forearm_twist": f"J_Sec_{s}_LowerArmTwist{i}",
        "wrist": f"J_Bip_{s}_Hand",
        "finger": f"J_Bip_{s}_{('Index', 'Middle', 'Ring', 'Little')[i // 3 % 4]}"
        f"{i % 3 + 1}" + ("" if i < 12 else f"_{i}"),
        "thumb": f"J_Bip_{s}_Thumb{i + 1}",
        "hip": f"J_Bip_{s}_UpperLeg",
        "knee": f"J_Bip_{s}_LowerLeg",
        "ankle": f"J_Bip_{s}_Foot",
        "toe": f"J_Bip_{s}_ToeBase",
        "face": f"J_Adj_{s}_FaceEye" if i == 0 else f"J_Sec_Hair{i}",
        "extra": f"J_Sec_{s}_Bust{i}",
    }
    return names.get(role)


# Held out: written after the name rules were settled, and not looked at while writing them.


def _character_creator(role: str, side: str | None, i: int, n: int) -> str | None:
    """Reallusion Character Creator 3/4 and iClone (``CC_Base_`` bones)."""
    s = {"l": "L_", "r": "R_", None: ""}[side]
    names = {
        "root": "RL_BoneRoot" if i == 0 else f"CC_Base_BoneRoot{i}",
        "pelvis": "CC_Base_Hip",
        "spine": _spread(("CC_Base_Waist", "CC_Base_Spine01", "CC_Base_Spine02"), i, n),
        "neck": "CC_Base_NeckTwist01" if i == 0 else f"CC_Base_NeckTwist0{i + 1}",
        "head": "CC_Base_Head",
        "clavicle": f"CC_Base_{s}Clavicle",
        "shoulder": f"CC_Base_{s}Upperarm",
        "upperarm_twist": f"CC_Base_{s}UpperarmTwist0{i + 1}",
        "elbow": f"CC_Base_{s}Forearm",
        "forearm_twist": f"CC_Base_{s}ForearmTwist0{i + 1}",
        "wrist": f"CC_Base_{s}Hand",
        "finger": f"CC_Base_{s}{('Index', 'Mid', 'Ring', 'Pinky')[i // 3 % 4]}{i % 3 + 1}",
        "thumb": f"CC_Base_{s}Thumb{i + 1}",
        "leg_root": f"CC_Base_Pelvis{i or ''}" if side == "l" else None,
        "hip": f"CC_Base_{s}Thigh",
        "thigh_twist": f"CC_Base_{s}ThighTwist0{i + 1}",
        "knee": f"CC_Base_{s}Calf",
        "calf_twist": f"CC_Base_{s}CalfTwist0{i + 1}",
        "ankle": f"CC_Base_{s}Foot",
        "toe": f"CC_Base_{s}ToeBase",
        "toe_end": f"CC_Base_{s}BigToe{i + 1}",
        "face": f"CC_Base_FacialBone{i or ''}",
        "extra": f"CC_Base_{s}RibsTwist{i}",
    }
    return names.get(role)


def _second_life(role: str, side: str | None, i: int, n: int) -> str | None:
    """Second Life / OpenSimulator avatar skeleton (``mShoulderLeft``)."""
    s = {"l": "Left", "r": "Right", None: ""}[side]
    names = {
        "pelvis": "mPelvis",
        "spine": _spread(("mTorso", "mChest"), i, n),
        "neck": "mNeck" if i == 0 else None,
        "head": "mHead",
        "clavicle": f"mCollar{s}",
        "shoulder": f"mShoulder{s}",
        "elbow": f"mElbow{s}",
        "wrist": f"mWrist{s}",
        "finger": f"mHand{('Index', 'Middle', 'Ring', 'Pinky')[i // 3 % 4]}{i % 3 + 1}{s}",
        "thumb": f"mHandThumb{i + 1}{s}",
        "hip": f"mHip{s}",
        "knee": f"mKnee{s}",
        "ankle": f"mAnkle{s}",
        "toe": f"mFoot{s}",
        "toe_end": f"mToe{s}",
        "face": f"mSkull{i or ''}",
    }
    return names.get(role)


def _source_engine(role: str, side: str | None, i: int, n: int) -> str | None:
    """Valve's Source engine biped (``ValveBiped.Bip01_L_UpperArm``)."""
    s = {"l": "L_", "r": "R_", None: ""}[side]
    names = {
        "root": "ValveBiped.Bip01" if i == 0 else None,
        "pelvis": "ValveBiped.Bip01_Pelvis",
        "spine": "ValveBiped.Bip01_Spine" + (str(i) if i else ""),
        "neck": "ValveBiped.Bip01_Neck1" if i == 0 else None,
        "head": "ValveBiped.Bip01_Head1",
        "clavicle": f"ValveBiped.Bip01_{s}Clavicle",
        "shoulder": f"ValveBiped.Bip01_{s}UpperArm",
        "elbow": f"ValveBiped.Bip01_{s}Forearm",
        "forearm_twist": f"ValveBiped.Bip01_{s}Ulna" if i == 0 else None,
        "wrist": f"ValveBiped.Bip01_{s}Hand",
        "finger": f"ValveBiped.Bip01_{s}Finger{i // 3 + 1}{i % 3 or ''}",
        "thumb": f"ValveBiped.Bip01_{s}Finger0{i or ''}",
        "hip": f"ValveBiped.Bip01_{s}Thigh",
        "knee": f"ValveBiped.Bip01_{s}Calf",
        "ankle": f"ValveBiped.Bip01_{s}Foot",
        "toe": f"ValveBiped.Bip01_{s}Toe0",
        "extra": f"ValveBiped.Bip01_{s}Bone{i}",
    }
    return names.get(role)


def _optitrack(role: str, side: str | None, i: int, n: int) -> str | None:
    """OptiTrack Motive's skeleton export (``Skeleton_LUArm``)."""
    s = {"l": "L", "r": "R", None: ""}[side]
    names = {
        "pelvis": "Skeleton_Hip",
        "spine": _spread(("Skeleton_Ab", "Skeleton_Chest"), i, n),
        "neck": "Skeleton_Neck" if i == 0 else None,
        "head": "Skeleton_Head",
        "clavicle": f"Skeleton_{s}Shoulder",
        "shoulder": f"Skeleton_{s}UArm",
        "elbow": f"Skeleton_{s}FArm",
        "wrist": f"Skeleton_{s}Hand",
        "hip": f"Skeleton_{s}Thigh",
        "knee": f"Skeleton_{s}Shin",
        "ankle": f"Skeleton_{s}Foot",
        "toe": f"Skeleton_{s}Toe",
    }
    return names.get(role)


def _blender_numbered(role: str, side: str | None, i: int, n: int) -> str | None:
    """Blender's default bone names (every bone added is ``Bone``, ``Bone.001``...)."""
    return None


def renamed(motion: Motion, convention: Convention, *, swap_sides: bool = False) -> Motion:
    """``motion`` with its joints named as ``convention`` names them (``swap_sides``: every
    sided name given to the joint on the other side)."""
    flip = {"l": "r", "r": "l", None: None}
    names: list[str] = []
    counters: dict[str | None, int] = {}
    for j, (role, side, i, n) in enumerate(roles(motion)):
        side = flip[side] if swap_sides else side
        parent = int(motion.skeleton.parents[j])
        name = f"{names[parent]}_end" if role == "end" else convention(role, side, i, n)
        if name is None or name in names:
            k = counters.get(side, 0)
            counters[side] = k + 1
            name = convention("extra", side, 100 + k, 0) or (
                "Bone" if not names else f"Bone.{len(names):03d}"
            )
        names.append(name)
    return dataclasses.replace(
        motion, skeleton=dataclasses.replace(motion.skeleton, names=tuple(names))
    )


def with_helpers(motion: Motion) -> Motion:
    """``motion`` renamed as Rigify names it, with the helper bones a Rigify export that keeps
    every bone adds: beside each shoulder, elbow, hip and knee, an ``ORG-`` copy of the bone
    and an ``MCH-`` mechanism bone (short leaves pointing back along the bone above, no
    motion of their own; appended, so the rig's own joints keep their indices)."""
    named = renamed(motion, _rigify)
    skeleton = named.skeleton
    parents, offsets = list(skeleton.parents), list(skeleton.offsets)
    names, end_site = list(skeleton.names), list(skeleton.end_site)
    frames = named.frame_count
    helpers = [
        j
        for j, (role, _, _, _) in enumerate(roles(motion))
        if role in ("shoulder", "elbow", "hip", "knee")
    ]
    for j in helpers:
        for prefix, share in (("ORG-", -0.3), ("MCH-", -0.15)):
            parents.append(j)
            offsets.append(share * np.asarray(skeleton.offsets[j]))
            names.append(prefix + names[j].removeprefix("DEF-"))
            end_site.append(False)
    extra = len(parents) - skeleton.joint_count
    rotations = np.concatenate(
        [named.local_rotations, np.broadcast_to(np.eye(3), (frames, extra, 3, 3))], axis=1
    )
    translations = named.local_translations
    if translations is not None:
        added = np.asarray(offsets[skeleton.joint_count :])
        translations = np.concatenate(
            [translations, np.broadcast_to(added, (frames, *added.shape))], axis=1
        )
    return dataclasses.replace(
        named,
        skeleton=dataclasses.replace(
            skeleton,
            names=tuple(names),
            parents=np.array(parents),
            offsets=np.array(offsets),
            end_site=np.array(end_site),
        ),
        local_rotations=np.ascontiguousarray(rotations),
        local_translations=None if translations is None else np.ascontiguousarray(translations),
    )


def shuffled_names(motion: Motion, seed: int = 0) -> Motion:
    """``motion`` with its own names shuffled among its joints (names that lie)."""
    names = list(motion.skeleton.names)
    np.random.default_rng(seed).shuffle(names)
    return dataclasses.replace(
        motion, skeleton=dataclasses.replace(motion.skeleton, names=tuple(names))
    )


CONVENTIONS: dict[str, Convention] = {
    "biped": _biped,
    "unreal": _unreal,
    "daz": _daz,
    "rigify": _rigify,
    "kinect": _kinect,
    "smpl": _smpl,
    "mmd": _mmd,
    "vroid": _vroid,
    "blender numbered": _blender_numbered,
    "character creator": _character_creator,
    "second life": _second_life,
    "source engine": _source_engine,
    "optitrack": _optitrack,
}
MIRRORED = ("biped", "unreal", "mmd")


def _joints(motion: Motion) -> tuple[np.ndarray, bool | None]:
    """The mapping's joints, and whether it took the capture as mirrored or, where the rest
    pose shows no side (``sides_open``) and the frames may show none either, ``None``."""
    mapping = describable_body(motion).mapping
    assert mapping is not None
    return mapping.joints.copy(), None if mapping.sides_open else mapping.mirrored


_SWAP = np.array(
    [
        CANONICAL_INDEX[{"l": "r_", "r": "l_"}[c[0]] + c[2:] if c[:2] in ("l_", "r_") else c]
        for c in CANONICAL_JOINTS
    ]
)


def outcome(
    motion: Motion, name: str, own: tuple[np.ndarray, bool | None] | None = None
) -> str | None:
    """None when the copy of ``motion`` named by convention ``name`` maps like ``motion``
    (``mirrored ...``: sides swapped and the capture taken as mirrored; ``shuffled``: the
    copy with its names shuffled maps alike whenever the nameless copy does), else how not.
    ``own``: ``_joints(motion)`` when already known."""
    joints, mirrored = _joints(motion) if own is None else own
    names = motion.skeleton.names
    try:
        if name == "shuffled":
            if not np.array_equal(_joints(nameless(motion))[0], joints):
                return None  # no worse than nameless either way
            copy = shuffled_names(motion)
        elif name == "rigify with ORG/MCH helpers":
            copy = with_helpers(motion)
        elif name.startswith("mirrored "):
            copy = renamed(motion, CONVENTIONS[name.split(" ", 1)[1]], swap_sides=True)
            joints = joints[_SWAP]
        else:
            copy = renamed(motion, CONVENTIONS[name])
        got, got_mirrored = _joints(copy)
    except MocapError as error:
        return f"refused: {error}"
    differ = np.flatnonzero(got != joints)
    if differ.size:
        return str([(CANONICAL_JOINTS[i], names[joints[i]], names[got[i]]) for i in differ])
    # Sides named the other way round than the geometry shows are a mirrored capture; where
    # no pose shows a side, the names alone decide (docs/skeletons.md, "sides").
    if name.startswith("mirrored ") and got_mirrored is not None and got_mirrored == mirrored:
        return "sides swapped but not taken as a mirrored capture"
    return None


NAMES = (
    *CONVENTIONS,
    "rigify with ORG/MCH helpers",
    *(f"mirrored {c}" for c in MIRRORED),
    "shuffled",
)


# Namings a fixture does not survive yet.
FIXTURE_GAPS: set[tuple[str, str]] = set()


@pytest.mark.parametrize("fixture", [CMU_BVH_FIXTURE, BANDAI_FIXTURE])
@pytest.mark.parametrize("name", NAMES)
def test_the_fixtures_map_alike_under_every_naming(fixture: str, name: str) -> None:
    found = outcome(read_bvh(fixture_bytes(fixture)), name)
    if (fixture, name) in FIXTURE_GAPS:
        assert found is not None, "maps alike now: take it out of FIXTURE_GAPS"
    else:
        assert found is None


# Human dev BVH files whose renamed copy maps alike, at least (a ratchet per convention).
RECORDED: dict[str, int] = {
    "biped": 66,
    "unreal": 66,
    "daz": 66,  # 56 before the words rules (bend, camelCase)
    "rigify": 66,
    "kinect": 66,  # 59 before "ankle" ranked before "foot" and the lower of two dropped
    "smpl": 66,  # 59 likewise
    "mmd": 66,  # 56 before the MMD/VRM standard names
    "vroid": 66,
    "blender numbered": 66,  # names that say nothing: the nameless count (56 before pass 4)
    "character creator": 66,
    "second life": 66,  # 56 before (held out)
    "source engine": 66,
    "optitrack": 66,  # 56 held out; 66 once Motive's UArm/FArm were added
    "rigify with ORG/MCH helpers": 66,
    "mirrored biped": 66,
    "mirrored unreal": 66,
    "mirrored mmd": 66,  # 0 before: 左/右 were no side words
    "shuffled": 64,  # 20 before names the tree contradicts were set aside
}


@functools.cache
def _dev_motions() -> dict[str, tuple[Motion, tuple[np.ndarray, bool | None]]]:
    """Each dev file's clip (read-only: every naming copies it) and its own mapping, mapped
    once for every naming."""
    found = {}
    for path in FILES:
        motion = read_only(sample_frames(read_bvh(path.read_bytes()), 60))
        joints, mirrored = _joints(motion)
        joints.flags.writeable = False
        found[f"{path.parent.name}/{path.name}"] = motion, (joints, mirrored)
    return found


@pytest.mark.skipif(not FILES, reason="no wild-bvh or wild-more in ../shared/data")
@pytest.mark.parametrize("name", NAMES)
def test_human_dev_rigs_renamed_into_other_conventions(name: str) -> None:
    found = {key: outcome(motion, name, own) for key, (motion, own) in _dev_motions().items()}
    count = sum(v is None for v in found.values())
    print(f"{name}: {count} of {len(found)} map like the named rig")
    assert count >= RECORDED[name], {k: v for k, v in found.items() if v}
