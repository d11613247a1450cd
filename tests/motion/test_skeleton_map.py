import numpy as np
import pytest

from app.errors import SkeletonMappingError
from app.motion.skeleton_map import (
    CANONICAL_BONES,
    CANONICAL_JOINTS,
    MIRROR_INDEX,
    map_skeleton,
    normalise_name,
)
from tests.motion.skeleton_trees import (
    BANDAI,
    CMU_ASF,
    DAZ,
    MAX,
    MIXAMO,
    MOTIONBUILDER,
    skeleton_from_tree,
)

# canonical joint -> expected source joint name, per family
EXPECTED = {
    "motionbuilder": (
        MOTIONBUILDER,
        {
            "pelvis": "Hips",
            "chest": "Spine1",
            "neck": "Neck",
            "head": "Head",
            "l_shoulder": "LeftArm",
            "l_elbow": "LeftForeArm",
            "l_wrist": "LeftHand",
            "l_hand_tip": "LeftHandIndex1_end",
            "l_hip": "LeftUpLeg",
            "l_knee": "LeftLeg",
            "l_ankle": "LeftFoot",
            "l_toe": "LeftToeBase",
            "r_shoulder": "RightArm",
        },
    ),
    "3dsmax": (
        MAX,
        {
            "pelvis": "Hips",
            "chest": "Chest2",
            "neck": "lowerneck",
            "l_shoulder": "LeftShoulder",
            "l_elbow": "LeftElbow",
            "l_wrist": "LeftWrist",
            "l_hand_tip": "LFingers_end",
            "l_hip": "LeftHip",
            "l_knee": "LeftKnee",
            "l_ankle": "LeftAnkle",
            "l_toe": "LeftToe",
        },
    ),
    "daz": (
        DAZ,
        {
            "pelvis": "hip",
            "spine": "abdomen",
            "chest": "chest",
            "neck": "neck",
            "head": "head",
            "l_shoulder": "lShldr",
            "l_elbow": "lForeArm",
            "l_wrist": "lHand",
            "l_hip": "lThigh",
            "l_knee": "lShin",
            "l_ankle": "lFoot",
            # DAZ has no toe joint: the foot's end site stands in for it.
            "l_toe": "lFoot_end",
            "r_toe": "rFoot_end",
        },
    ),
    "bandai": (
        BANDAI,
        {
            "pelvis": "Hips",
            "spine": "Spine",
            "chest": "Chest",
            "l_shoulder": "UpperArm_L",
            "l_elbow": "LowerArm_L",
            "l_wrist": "Hand_L",
            "l_hip": "UpperLeg_L",
            "l_knee": "LowerLeg_L",
            "l_ankle": "Foot_L",
            "l_toe": "Toes_L",
            "r_shoulder": "UpperArm_R",
        },
    ),
    "cmu-asf": (
        CMU_ASF,
        {
            "pelvis": "root",
            "chest": "thorax",
            "neck": "lowerneck",
            "head": "head",
            "l_shoulder": "lhumerus",
            "l_elbow": "lradius",
            "l_wrist": "lwrist",
            "l_hand_tip": "lfingers_end",
            "l_hip": "lfemur",
            "l_knee": "ltibia",
            "l_ankle": "lfoot",
            "l_toe": "ltoes",
        },
    ),
    "mixamo": (
        MIXAMO,
        {
            "pelvis": "mixamorig:Hips",
            "chest": "mixamorig:Spine2",
            "l_shoulder": "mixamorig:LeftArm",
            "l_elbow": "mixamorig:LeftForeArm",
            "l_wrist": "mixamorig:LeftHand",
            "l_hand_tip": "mixamorig:LeftHandMiddle2_end",
            "l_hip": "mixamorig:LeftUpLeg",
            "l_knee": "mixamorig:LeftLeg",
            "l_toe": "mixamorig:LeftToeBase",
        },
    ),
}


@pytest.mark.parametrize("family", sorted(EXPECTED))
def test_each_family_maps_to_the_right_joints(family):
    tree, expected = EXPECTED[family]
    skeleton = skeleton_from_tree(tree)
    mapping = map_skeleton(skeleton)
    assert mapping.family == family
    got = {
        name: skeleton.names[j] for name, j in zip(CANONICAL_JOINTS, mapping.joints, strict=True)
    }
    for canonical, source in expected.items():
        assert got[canonical] == source, canonical
    # Left and right never map to the same joint.
    for name in CANONICAL_JOINTS:
        if name.startswith("l_"):
            assert got[name] != got["r_" + name[2:]]


def test_names_are_normalised_whole():
    assert normalise_name("mixamorig:LeftUpLeg") == "leftupleg"
    assert normalise_name("UpperLeg_L") == "upperlegl"
    assert normalise_name("Left Arm") == "leftarm"
    assert normalise_name("Bip01_L_Thigh") == "lthigh"


def test_substrings_never_match():
    # "LeftHipHelper" contains "LeftHip" and "Hips" contains "hip": neither may be taken
    # for the left hip, so the mapping must fail naming the hips.
    tree = MOTIONBUILDER.replace("LeftUpLeg", "LeftUpLegHelper")
    with pytest.raises(SkeletonMappingError) as caught:
        map_skeleton(skeleton_from_tree(tree))
    assert "l_hip" in str(caught.value)
    assert "r_hip" not in str(caught.value)


def test_unmappable_skeleton_names_every_missing_joint():
    tree = "\n".join(["Root", "  Bone1", "    Bone2", "      Bone2_end*"])
    with pytest.raises(SkeletonMappingError) as caught:
        map_skeleton(skeleton_from_tree(tree))
    message = str(caught.value)
    for missing in ("neck", "head", "l_shoulder", "r_knee", "l_ankle"):
        assert missing in message


def test_bones_and_mirror_tables_are_consistent():
    assert len(CANONICAL_BONES) == len(CANONICAL_JOINTS) - 1
    assert np.array_equal(MIRROR_INDEX[MIRROR_INDEX], np.arange(len(CANONICAL_JOINTS)))
    for i, name in enumerate(CANONICAL_JOINTS):
        other = CANONICAL_JOINTS[MIRROR_INDEX[i]]
        assert other == name or {name[:2], other[:2]} == {"l_", "r_"}
