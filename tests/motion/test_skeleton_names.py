"""Joint names as hints (``app.motion.skeleton_names``): the naming conventions of exporters
the development sets do not have, read by general rules (words, modifiers, side forms, the
MMD/VRM standard names), never by a list of files."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from app.motion.formats import read_bvh
from app.motion.mapping.tree import _chain_hints, _Tree, contradicted_names
from app.motion.skeleton_names import name_hint, name_side, words
from tests.motion.conftest import CMU_BVH_FIXTURE, fixture_bytes
from tests.motion.test_mapping_names import shuffled_names


@pytest.mark.parametrize(
    ("name", "expected"),
    [
        ("lShldrBend", ["l", "shldr", "bend"]),
        ("LeftUpLeg", ["left", "up", "leg"]),
        ("LHipJoint", ["l", "hip", "joint"]),
        ("Bip01 L Toe0Nub", ["bip", "01", "l", "toe", "0", "nub"]),
        ("DEF-upper_arm.L.001", ["def", "upper", "arm", "l", "001"]),
        ("左足ＩＫ", ["左足", "ik"]),  # full-width letters count as ASCII
        ("mixamorig:RightHand", ["mixamorig", "right", "hand"]),
    ],
)
def test_names_split_into_words(name: str, expected: list[str]) -> None:
    assert words(name) == expected


@pytest.mark.parametrize(
    ("name", "side", "part"),
    [
        # 3ds Max Biped, Unreal mannequin, DAZ Genesis 3/8, Blender Rigify
        ("Bip01 L UpperArm", "l", "shoulder"),
        ("Bip01 R Calf", "r", "knee"),
        ("Bip01 L Toe0", "l", "toe"),
        ("lowerarm_l", "l", "elbow"),
        ("ball_r", "r", "toe"),
        ("lShldrBend", "l", "shoulder"),
        ("rForearmBend", "r", "elbow"),
        ("lThighBend", "l", "hip"),
        ("lShin", "l", "knee"),
        ("DEF-upper_arm.L", "l", "shoulder"),
        ("DEF-shin.R", "r", "knee"),
        ("knee_jnt_l", "l", "knee"),
        # Kinect, SMPL, VRoid
        ("ElbowLeft", "l", "elbow"),
        ("L_Collar", "l", "clavicle"),
        ("J_Bip_R_LowerLeg", "r", "knee"),
        # MMD / VRM standard Japanese names: 左 left, 右 right
        ("左腕", "l", "shoulder"),
        ("右ひじ", "r", "elbow"),
        ("左手首", "l", "wrist"),
        ("右足", "r", "hip"),
        ("左ひざ", "l", "knee"),
        ("左足首", "l", "ankle"),
        ("右つま先", "r", "toe"),
        ("左肩", "l", "clavicle"),
        # ARKit body: every name tagged "_joint"
        ("left_upLeg_joint", "l", "hip"),
        ("right_leg_joint", "r", "knee"),
        ("left_forearm_joint", "l", "elbow"),
        ("right_arm_joint", "r", "shoulder"),
    ],
)
def test_conventions_name_their_parts(name: str, side: str, part: str) -> None:
    hint = name_hint(name)
    assert hint.side == side and part in hint.parts, hint
    assert name_side(name) == side


@pytest.mark.parametrize(
    ("name", "part"),
    [
        ("首", "neck"),
        ("頭", "head"),
        ("neckLower", "neck"),
        ("Bip01 Head", "head"),
        ("hips_joint", "pelvis"),
        ("head_joint", "head"),
    ],
)
def test_unsided_parts(name: str, part: str) -> None:
    assert part in name_hint(name).parts


def test_joint_is_a_tag_only_when_set_off() -> None:
    # CMU's LHipJoint is the bone from the pelvis to the hip: "Joint" glued on stays a word.
    assert name_hint("LHipJoint").parts == {}
    assert name_hint("joint").parts == {}


@pytest.mark.parametrize(
    "name",
    [
        # Twist and roll bones, IK/FK controls, mechanism, helper and nub bones are not the
        # joint: they name no part (a twist bone must never be taken for the joint).
        "lShldrTwist",
        "upperarm_twist_01_l",
        "Bip01 L ForeTwist",
        "LeftForeArmRoll",
        "ik_foot_l",
        "MCH-forearm.L",
        "左足ＩＫ",
        "左腕捩",
        "Bip01 L Toe0Nub",
        "HandTipLeft",
        "LeftUpLegHelper",
        # Words that only contain a part: substrings never count.
        "左親指０",
        "SpineShoulder",
        "Bone.001",
    ],
)
def test_names_of_bones_that_are_not_the_joint_name_no_part(name: str) -> None:
    assert name_hint(name).parts == {}


@pytest.mark.parametrize(
    ("name", "side"),
    [
        ("Oberarm_links", "l"),
        ("Oberschenkel.rechts", "r"),
        ("bras_gauche", "l"),
        ("jambe_droite", "r"),
        ("brazo_izquierdo", "l"),
        ("pierna_derecha", "r"),
        ("braccio_sinistro", "l"),
        ("gamba_destra", "r"),
        ("perna_esquerda", "l"),
        ("腰キャンセル右", "r"),
        ("左ダミー", "l"),
        ("lShldrTwist", "l"),
        ("Lt_Arm_Ctrl", "l"),
        ("Spine", None),
        ("Hips", None),
        ("lowerarm", None),
    ],
)
def test_side_words_in_other_forms_and_languages(name: str, side: str | None) -> None:
    assert name_side(name) == side


def test_the_lower_of_two_joints_naming_one_part_is_not_it() -> None:
    """SMPL's L_Ankle -> L_Foot and Kinect's WristLeft -> HandLeft: the lower joint is the
    bone beyond; a better word below a worse one stays (Mixamo's LeftShoulder -> LeftArm)."""
    names = ["Pelvis", "L_Hip", "L_Knee", "L_Ankle", "L_Foot", "LeftShoulder", "LeftArm"]
    parents = np.array([-1, 0, 1, 2, 3, 0, 5])
    hints = _chain_hints(parents, [name_hint(n) for n in names], np.zeros(len(names), bool))
    assert "ankle" in hints[3].parts and "ankle" not in hints[4].parts
    assert "shoulder" in hints[6].parts


def test_a_connector_on_its_parents_place_claims_no_part_below_it() -> None:
    """A joint of no length at the trunk's point named after the limb (``Pelvis_L_Hip``)
    leaves the part's name to the joint set apart below it (``L_Hip``); one set apart keeps
    it from the joint below (``L_Ankle`` above ``L_Foot``, as above)."""
    names = ["Pelvis", "Pelvis_L_Hip", "L_Hip", "L_Knee", "L_Ankle", "L_Foot"]
    parents = np.array([-1, 0, 1, 2, 3, 4])
    on_parent = np.array([False, True, False, False, False, False])
    hints = _chain_hints(parents, [name_hint(n) for n in names], on_parent)
    assert "hip" in hints[1].parts and "hip" in hints[2].parts
    assert "ankle" in hints[4].parts and "ankle" not in hints[5].parts
    apart = _chain_hints(parents, [name_hint(n) for n in names], np.zeros(len(names), bool))
    assert "hip" not in apart[2].parts


def test_names_the_tree_contradicts_are_not_read() -> None:
    motion = read_bvh(fixture_bytes(CMU_BVH_FIXTURE))
    skeleton = motion.skeleton
    assert contradicted_names(skeleton.parents, [name_hint(n) for n in skeleton.names]) == 0
    assert _Tree(skeleton).names_trusted
    lying = shuffled_names(motion).skeleton
    assert contradicted_names(lying.parents, [name_hint(n) for n in lying.names]) >= 2
    tree = _Tree(lying)
    assert not tree.names_trusted
    assert all(not hint.parts for hint in tree.hints) and set(tree.sides) == {None}


def test_long_hostile_names_stay_fast() -> None:
    # One pass over the name; only the last words can name a part.
    assert name_hint("aB" * 20_000 + "_l_hand").parts == {"wrist": 1}
    assert name_hint("1" * 25_677 + "l").parts == {}


@pytest.mark.parametrize("name", ["left_hand_root", "Hand_L_root", "RightFootRoot", "l_root"])
def test_a_sided_name_names_no_midline_joint(name: str) -> None:
    # The pelvis, neck and head are one each, on the midline: "root" or "hips" after a side
    # word qualifies a limb's part and is not the pelvis.
    assert "pelvis" not in name_hint(name).parts
    assert "pelvis" in name_hint("root").parts


def test_a_hand_root_below_the_wrist_keeps_the_rigs_names() -> None:
    # A pose estimator's template hangs the fingers from a "left_hand_root"; read as the
    # pelvis below both arms, it made the tree contradict two names and every name was
    # dropped.
    motion = read_bvh(fixture_bytes(CMU_BVH_FIXTURE))
    names = [
        {"LeftFingerBase": "left_hand_root", "RightFingerBase": "right_hand_root"}.get(n, n)
        for n in motion.skeleton.names
    ]
    tree = _Tree(dataclasses.replace(motion.skeleton, names=tuple(names)))
    assert tree.names_trusted
    assert "wrist" in tree.hints[names.index("LeftHand")].parts
