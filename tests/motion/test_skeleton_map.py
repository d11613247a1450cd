"""Mapping by structure on real rigs (tests/fixtures), and refusals of what is not a person."""

import contextlib
import dataclasses
import random
import re
from collections.abc import Callable, Iterator
from itertools import product

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from app.errors import ParseError, SkeletonMappingError
from app.motion import transforms
from app.motion.body import _frame_poses, build_body
from app.motion.formats import read_asf_amc, read_bvh
from app.motion.model import Motion, Skeleton
from app.motion.skeleton_map import (
    CANONICAL_BONES,
    CANONICAL_INDEX,
    CANONICAL_JOINTS,
    MIRROR_INDEX,
    SkeletonMap,
    map_skeleton,
    rest_pose,
)
from app.motion.skeleton_names import name_hint, name_side, normalise_name
from tests.motion.canonical import check_canonical_body
from tests.motion.conftest import (
    BANDAI_FIXTURE,
    CMU_AMC_FIXTURE,
    CMU_ASF_FIXTURE,
    CMU_BVH_FIXTURE,
    fixture_bytes,
)
from tests.motion.skeleton_trees import SMPL, Humanoid, skeleton_from_points, synthetic_humanoid
from tests.motion.synthetic import grown, hung_from_root, joint_oriented, walking


def _cmu_bvh() -> Motion:
    return read_bvh(fixture_bytes(CMU_BVH_FIXTURE))


def _bandai() -> Motion:
    return read_bvh(fixture_bytes(BANDAI_FIXTURE))


def _cmu_asf() -> Motion:
    return read_asf_amc(fixture_bytes(CMU_ASF_FIXTURE), fixture_bytes(CMU_AMC_FIXTURE))


def _map(motion: Motion) -> SkeletonMap:
    return map_skeleton(motion.skeleton, _frame_poses(motion))


def _named(motion: Motion, mapping: SkeletonMap) -> dict[str, str]:
    names = motion.skeleton.names
    return {c: names[j] for c, j in zip(CANONICAL_JOINTS, mapping.joints, strict=True)}


EXPECTED = {
    "cmu-bvh-motionbuilder": (
        _cmu_bvh,
        {
            "pelvis": "Hips",
            "chest": "Spine1",
            "neck": "Neck",
            # The spine chain's end effector: the End Site above the head joint.
            "head": "Head_end",
            "l_shoulder": "LeftArm",
            "l_elbow": "LeftForeArm",
            "l_wrist": "LeftHand",
            "l_hand_tip": "LeftHandIndex1_end",
            "l_hip": "LeftUpLeg",
            "l_knee": "LeftLeg",
            "l_ankle": "LeftFoot",
            "l_toe": "LeftToeBase_end",
            "r_shoulder": "RightArm",
            "r_toe": "RightToeBase_end",
        },
    ),
    "bandai": (
        # The rest pose of these offsets is not a standing figure (bones along local x):
        # the geometry is read from frames of the motion.
        _bandai,
        {
            "pelvis": "Hips",
            "spine": "Spine",
            "chest": "Chest",
            "neck": "Neck",
            "head": "Head",  # its End Site has zero length: the head joint is the point
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
        _cmu_asf,
        {
            "pelvis": "root",
            "chest": "thorax",
            "neck": "lowerneck",
            "head": "head_end",
            "l_shoulder": "lhumerus",
            "l_elbow": "lradius",
            "l_wrist": "lwrist",
            "l_hand_tip": "lfingers_end",
            "l_hip": "lfemur",
            "l_knee": "ltibia",
            "l_ankle": "lfoot",
            "l_toe": "ltoes_end",
        },
    ),
}


@pytest.mark.parametrize("rig", sorted(EXPECTED))
def test_real_rigs_map_to_the_right_joints(rig):
    load, expected = EXPECTED[rig]
    motion = load()
    mapping = _map(motion)
    got = _named(motion, mapping)
    for canonical, source in expected.items():
        assert got[canonical] == source, canonical
    for name in CANONICAL_JOINTS:
        if name.startswith("l_"):
            assert got[name] != got["r_" + name[2:]]
    assert mapping.mirrored is False
    assert mapping.warnings == ()


def test_end_effectors_are_listed_and_the_head_joint_kept_for_height():
    motion = _cmu_bvh()
    mapping = _map(motion)
    assert {"head", "l_toe", "r_toe", "l_hand_tip", "r_hand_tip"} <= set(mapping.end_sites)
    assert motion.skeleton.names[mapping.head_joint] == "Head"
    assert mapping.how["head"].startswith("end effector")
    described = mapping.describe(motion.skeleton.names)
    assert described["l_elbow"] == {"joint": "LeftForeArm", "how": "name"}


def _end_site_beyond_leaf_bones(skeleton: Skeleton, leaves: tuple[str, ...]) -> Skeleton:
    """``skeleton`` with the End Sites called ``leaves`` made leaf bones (as in FBX), and,
    like a converter writing that FBX as BVH, a new End Site beyond each repeating it."""
    names, parents = list(skeleton.names), list(skeleton.parents)
    offsets, end_site = list(skeleton.offsets), list(skeleton.end_site)
    for leaf in leaves:
        j = names.index(leaf)
        end_site[j] = False
        names.append(leaf + "_end")
        parents.append(j)
        offsets.append(offsets[j])
        end_site.append(True)
    return Skeleton(tuple(names), np.array(parents), np.array(offsets), np.array(end_site))


def test_head_and_toes_are_the_first_points_beyond_their_joints_end_site_or_leaf_bone():
    # A Mixamo BVH ends HeadTop_End with an End Site repeating its bone; the FBX it came from
    # ends at the HeadTop_End bone: both map the head to HeadTop_End, the same point.
    skeleton = _cmu_bvh().skeleton
    leaves = ("Head_end", "LeftToeBase_end", "RightToeBase_end")
    plain = map_skeleton(skeleton)
    extended = _end_site_beyond_leaf_bones(skeleton, leaves)
    again = map_skeleton(extended)
    np.testing.assert_array_equal(again.joints, plain.joints)
    assert again.head_joint == plain.head_joint
    assert extended.names[again.joints[CANONICAL_JOINTS.index("head")]] == "Head_end"


def test_the_rest_pose_mapping_is_remembered_per_skeleton():
    def unread() -> Iterator[tuple[str, np.ndarray]]:
        raise AssertionError("frames read although the rest pose decided")
        yield  # pragma: no cover

    motion = _cmu_bvh()
    first = _map(motion)
    assert map_skeleton(motion.skeleton, unread()) is first
    # An equal skeleton built anew (another clip of the rig) hits the same memo entry.
    copy = Skeleton(
        motion.skeleton.names,
        motion.skeleton.parents.copy(),
        motion.skeleton.offsets.copy(),
        motion.skeleton.end_site.copy(),
    )
    assert map_skeleton(copy, unread()) is first
    assert not first.joints.flags.writeable
    # Rigs whose rest pose is not a standing figure still read each clip's own frames.
    bandai = _bandai()
    assert _map(bandai).pose.startswith("frame")
    assert _map(bandai).pose.startswith("frame")


def test_names_are_hints_read_whole():
    assert normalise_name("mixamorig:LeftUpLeg") == "leftupleg"
    assert normalise_name("UpperLeg_L") == "upperlegl"
    assert name_hint("mixamorig:LeftUpLeg").parts == {"hip": 0}
    assert name_hint("f_avg_L_Hip").side == "l"
    assert "hip" in name_hint("Bip01_R_Thigh").parts
    assert name_hint("upperarm01.L").side == "l" and "shoulder" in name_hint("upperarm01.L").parts
    assert "knee" in name_hint("LoLeg_L").parts
    assert "elbow" in name_hint("LeftLowArm").parts
    # Substrings never count: a helper bone named after a leg says nothing.
    assert name_hint("LeftUpLegHelper").parts == {}
    assert name_hint("Hips").parts == {"pelvis": 0}
    assert name_side("lfemur") == "l" and name_side("RightHandThumb1") == "r"
    # Trailing digits go, in one pass (a regex retried every start of a long run of digits:
    # tests/hostile/found.json's 25,677-digit joint names held the server for 12 s).
    assert name_hint("LeftToe_End012").parts == {} and "toe" in name_hint("LeftToe012").parts
    assert name_hint("1" * 25_677 + "l").parts == {}
    assert name_side("Hips") is None


def _renamed(motion: Motion, names: tuple[str, ...]) -> Motion:
    skeleton = motion.skeleton
    return dataclasses.replace(
        motion, skeleton=Skeleton(names, skeleton.parents, skeleton.offsets, skeleton.end_site)
    )


def test_a_helper_bone_named_like_a_leg_changes_nothing():
    motion = _cmu_bvh()
    names = tuple(n.replace("LeftUpLeg", "LeftUpLegHelper") for n in motion.skeleton.names)
    np.testing.assert_array_equal(_map(_renamed(motion, names)).joints, _map(motion).joints)


def test_meaningless_names_map_the_same_joints():
    motion = _cmu_bvh()
    names = tuple(f"j{i}" for i in range(motion.skeleton.joint_count))
    np.testing.assert_array_equal(_map(_renamed(motion, names)).joints, _map(motion).joints)


def _subtree(skeleton: Skeleton, top: int) -> Skeleton:
    """The part of ``skeleton`` from joint ``top`` down, as a skeleton of its own."""
    keep = [j for j in range(skeleton.joint_count) if _under(skeleton, j, top)]
    index = {j: i for i, j in enumerate(keep)}
    parents = np.array([index.get(int(skeleton.parents[j]), -1) for j in keep])
    offsets = skeleton.offsets[keep].copy()
    offsets[0] = 0.0
    return Skeleton(
        tuple(skeleton.names[j] for j in keep), parents, offsets, skeleton.end_site[keep]
    )


def _under(skeleton: Skeleton, joint: int, top: int) -> bool:
    while joint >= 0:
        if joint == top:
            return True
        joint = int(skeleton.parents[joint])
    return False


def _refused(skeleton: Skeleton) -> str:
    with pytest.raises(SkeletonMappingError) as caught:
        map_skeleton(skeleton)
    return str(caught.value)


def test_a_hand_alone_is_refused():
    skeleton = _cmu_asf().skeleton
    message = _refused(_subtree(skeleton, skeleton.index("lhumerus")))
    assert "not a whole humanoid" in message and "missing" in message


def test_an_upper_body_alone_is_refused_for_missing_legs():
    skeleton = _cmu_asf().skeleton
    message = _refused(_subtree(skeleton, skeleton.index("lowerback")))
    assert "not a whole humanoid" in message
    assert "legs" in message


def test_a_head_alone_is_refused():
    skeleton = _cmu_asf().skeleton
    message = _refused(_subtree(skeleton, skeleton.index("lowerneck")))
    assert "not a whole humanoid" in message


def _without(skeleton: Skeleton, top: int) -> Skeleton:
    """``skeleton`` without joint ``top`` and everything below it."""
    keep = [j for j in range(skeleton.joint_count) if not _under(skeleton, j, top)]
    index = {j: i for i, j in enumerate(keep)}
    parents = np.array([index.get(int(skeleton.parents[j]), -1) for j in keep])
    return Skeleton(
        tuple(skeleton.names[j] for j in keep),
        parents,
        skeleton.offsets[keep].copy(),
        skeleton.end_site[keep],
    )


def test_a_body_without_a_head_is_refused_saying_so():
    """A humanoid robot's rig often has no head joint (the head is part of the torso): the
    refusal says the head is what is missing and where it was looked for, not why the first
    combination of limb ends tried fails ("the legs hang from the arms' branch point")."""
    skeleton = _cmu_bvh().skeleton
    headless = _without(skeleton, skeleton.index("Neck"))
    message = _refused(headless)
    assert "no head" in message and "(Spine1)" in message, message


def test_all_zero_offsets_are_refused():
    skeleton = _cmu_bvh().skeleton
    flat = Skeleton(
        skeleton.names, skeleton.parents, np.zeros_like(skeleton.offsets), skeleton.end_site
    )
    assert "every OFFSET is 0" in _refused(flat)


def test_a_chain_of_three_bones_names_what_is_missing():
    skeleton = Skeleton(
        ("Root", "Bone1", "Bone2", "Bone2_end"),
        np.array([-1, 0, 1, 2]),
        np.array([[0, 0, 0], [0, 1, 0], [0, 1, 0], [0, 1, 0]], dtype=float),
        np.array([False, False, False, True]),
    )
    message = _refused(skeleton)
    assert "not a whole humanoid" in message


def _quadruped(skeleton: Skeleton) -> Skeleton:
    """A real biped's rest offsets re-posed on all fours: the trunk (pelvis to head) tipped
    forward to horizontal, the arms hanging straight down like front legs."""
    pose = rest_pose(skeleton)
    pelvis = skeleton.index("Hips")
    tip = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # +y (up) -> +z
    trunk = {
        j for j in range(skeleton.joint_count) if _under(skeleton, j, skeleton.index("LowerBack"))
    }
    arms = {
        j
        for side in ("Left", "Right")
        for j in range(skeleton.joint_count)
        if _under(skeleton, j, skeleton.index(f"{side}Arm"))
    }
    offsets = skeleton.offsets.copy()
    for j in trunk - arms:
        offsets[j] = tip @ offsets[j]
    for j in arms:
        length = np.linalg.norm(skeleton.offsets[j])
        offsets[j] = (0.0, -length, 0.0)
    del pose, pelvis
    return Skeleton(skeleton.names, skeleton.parents, offsets, skeleton.end_site)


def test_a_quadruped_with_biped_names_is_refused():
    message = _refused(_quadruped(_cmu_bvh().skeleton))
    assert "four-legged" in message


def test_bones_and_mirror_tables_are_consistent():
    assert len(CANONICAL_BONES) == len(CANONICAL_JOINTS) - 1
    assert np.array_equal(MIRROR_INDEX[MIRROR_INDEX], np.arange(len(CANONICAL_JOINTS)))
    for i, name in enumerate(CANONICAL_JOINTS):
        other = CANONICAL_JOINTS[MIRROR_INDEX[i]]
        assert other == name or {name[:2], other[:2]} == {"l_", "r_"}


def _shapes(count: int, seed: int = 20) -> list[Humanoid]:
    """``count`` humanoid shapes drawn from every combination of the options game, capture
    and video-pose rigs show (no clavicle, one to four spine joints, no neck, hand bones or
    none, no toes, A-pose, hips at the pelvis, twist and face bones, no names)."""
    options = {
        "clavicle": (True, False),
        "spines": (1, 2, 4),
        "neck": (True, False),
        "head_end": (True, False),
        "hand": ("fingers", "bone", "none"),
        "toes": (True, False),
        "arm_angle": (0.0, 45.0),
        "hips_coincide": (False, True),
        "twist_bones": (False, True),
        "face_bones": (0, 30),
        "names": ("unity", "blender", "anon"),
    }
    every = [dict(zip(options, values, strict=True)) for values in product(*options.values())]
    return [Humanoid(**shape) for shape in random.Random(seed).sample(every, count)]


def _shape_id(shape: Humanoid) -> str:
    fields = dataclasses.asdict(shape)
    return "-".join(f"{k}={v}" for k, v in fields.items() if v != getattr(Humanoid, k))


# How the same motion reaches the mapper: as written, with joint orientation in the
# rotations (each child along its parent's x: the rest pose is no standing figure, as in
# Maya and pose-estimation exports), Z up, upside down (image coordinates, y down), and
# joint-oriented along an odd axis.
_WRITTEN: dict[str, Callable[[Motion], Motion]] = {
    "plain": lambda motion: motion,
    "joint-oriented": joint_oriented,
    "z-up": lambda motion: transforms.change_basis(
        motion, transforms.rotation_about([1.0, 0.0, 0.0], 90.0)
    ),
    "y-down": lambda motion: transforms.change_basis(
        motion, transforms.rotation_about([1.0, 0.0, 0.0], 180.0)
    ),
    "oriented-odd-axis": lambda motion: joint_oriented(
        transforms.change_basis(motion, transforms.rotation_about([1.0, 2.0, 3.0], 77.0))
    ),
}


@pytest.mark.parametrize(
    ("shape", "written"),
    [(shape, list(_WRITTEN)[i % len(_WRITTEN)]) for i, shape in enumerate(_shapes(80))],
    ids=lambda value: value if isinstance(value, str) else _shape_id(value),
)
def test_humanoids_of_every_shape_map_right_and_look_like_people(shape: Humanoid, written: str):
    skeleton, truth = synthetic_humanoid(shape)
    body = build_body(_WRITTEN[written](walking(skeleton, truth)))
    got = {c: skeleton.names[j] for c, j in zip(CANONICAL_JOINTS, body.mapping.joints, strict=True)}
    # Without names, chest -> A -> B (a leaf) is a neck and a head or a head and its top: the
    # head point is B either way; which joint is the neck, the structure cannot say.
    limbs = [c for c in truth if c not in ("head", "neck")]
    assert {c: got[c] for c in limbs} == {c: truth[c] for c in limbs}
    assert body.mapping.mirrored is False
    # An odd axis leaves no coordinate axis for the world's vertical: upright by medians.
    check_canonical_body(body, str(shape), upright=written != "oriented-odd-axis" or None)


def test_a_rest_pose_without_sides_takes_them_from_the_motion():
    # Straight legs, no feet and no names: nothing in the rest pose tells left from right.
    # The motion's bent knees do, in the clip as it is and in its mirror image.
    skeleton, truth = synthetic_humanoid(Humanoid(names="anon", toes=False, clavicle=False))
    motion = walking(skeleton, truth)
    assert map_skeleton(skeleton).warnings == (
        "left and right could not be told apart; sides are a guess",
    )
    for clip in (motion, transforms.reflect(motion, axis=0)):
        body = build_body(clip)
        assert body.mapping.sides_open and body.warnings == ()
        check_canonical_body(body, "anonymous rig", upright=True)
    # With names, the same mirrored clip is a mirrored capture.
    named, truth = synthetic_humanoid(Humanoid(toes=False, clavicle=False))
    body = build_body(transforms.reflect(walking(named, truth), axis=0))
    assert body.mapping.mirrored is True
    check_canonical_body(body, "mirrored capture", upright=True)


def test_a_rig_of_one_or_two_bones_is_refused_not_a_server_error():
    # An abstract rig (a bone or two, any axis) has no body proper: a clean 422.
    for offsets in ([[0, 0, 0], [0, 0, 1.0]], [[0, 0, 0], [0, 1.0, 0], [1.0, 0, 0]]):
        count = len(offsets)
        skeleton = Skeleton(
            tuple(f"b{i}" for i in range(count)),
            np.arange(-1, count - 1),
            np.array(offsets, dtype=float),
            np.zeros(count, dtype=bool),
        )
        motion = Motion(
            skeleton, 1 / 30, np.zeros((3, 3)), np.broadcast_to(np.eye(3), (3, count, 3, 3)).copy()
        )
        with pytest.raises(SkeletonMappingError, match="not a whole humanoid"):
            build_body(motion)


def test_any_tree_of_joints_maps_or_is_refused_never_anything_else():
    # Random trees (1-40 joints; offsets random, along one axis, half zero, huge, tiny or
    # flat; random rotations, still or not): a mapping or a SkeletonMappingError / ParseError.
    rng = np.random.default_rng(11)
    for trial in range(120):
        count = int(rng.integers(1, 40))
        parents = np.array([-1] + [int(rng.integers(0, j)) for j in range(1, count)])
        offsets = rng.normal(size=(count, 3))
        if trial % 4 == 1:
            offsets = np.outer(rng.normal(size=count), rng.normal(size=3))
        elif trial % 4 == 2:
            offsets *= rng.random((count, 1)) < 0.5
        elif trial % 4 == 3:
            offsets *= 10.0 ** rng.integers(-8, 8)
        offsets[0] = 0.0
        skeleton = Skeleton(
            tuple(f"j{i}" for i in range(count)), parents, offsets, np.zeros(count, dtype=bool)
        )
        frames = int(rng.integers(1, 12))
        turns = rng.normal(size=(frames * count, 3)) * rng.choice([0.0, 0.3, 3.0])
        local = Rotation.from_rotvec(turns).as_matrix().reshape(frames, count, 3, 3)
        motion = Motion(skeleton, 1 / 30, rng.normal(size=(frames, 3)), local)
        with contextlib.suppress(ParseError):  # SkeletonMappingError is one
            build_body(motion)


FACE_RIG = """
root 0 0 0
  neck 0 0.05 -0.02
    head 0 0.12 0
      jaw 0 0.10 0.03
        chin 0 0.04 0.09
          chin_end 0 0.02 0.11
        tongue_1 0 0.08 0.05
          tongue_2 0 0.082 0.07
            tongue_3 0 0.083 0.085
      eye_L 0.032 0.16 0.08
        eye_L_end 0.032 0.16 0.1
      eye_R -0.032 0.16 0.08
        eye_R_end -0.032 0.16 0.1
      brow_inner_L 0.015 0.185 0.095
        brow_mid_L 0.035 0.19 0.09
          brow_outer_L 0.055 0.185 0.075
      brow_inner_R -0.015 0.185 0.095
        brow_mid_R -0.035 0.19 0.09
          brow_outer_R -0.055 0.185 0.075
      cheek_L 0.05 0.13 0.08
        cheek_L_end 0.06 0.12 0.07
      cheek_R -0.05 0.13 0.08
        cheek_R_end -0.06 0.12 0.07
      ear_L 0.075 0.15 0
        ear_L_end 0.08 0.17 -0.01
      ear_R -0.075 0.15 0
        ear_R_end -0.08 0.17 -0.01
"""


def test_a_face_rig_is_not_a_person():
    skeleton = skeleton_from_points(FACE_RIG)
    rng = np.random.default_rng(4)
    turns = rng.normal(size=(30 * skeleton.joint_count, 3)) * 0.3
    local = Rotation.from_rotvec(turns).as_matrix().reshape(30, skeleton.joint_count, 3, 3)
    with pytest.raises(SkeletonMappingError, match="not a whole humanoid"):
        build_body(Motion(skeleton, 1 / 30, np.zeros((30, 3)), local))


# A creature standing on its front legs, whose tiny "feet" (three-joint claws) hang at the
# end of long legs and whose head carries two feather chains: the humanoid the shapes allow
# takes the claws for legs and the feathers for arms.
CREATURE = """
chest 0 1 0
  leg_L 0.15 0.9 0.1
    shin_L 0.2 0.4 0.15
      claw_L 0.2 0.05 0.2
        claw_L_1 0.2 0.02 0.25
          claw_L_2 0.2 0 0.3
  leg_R -0.15 0.9 0.1
    shin_R -0.2 0.4 0.15
      claw_R -0.2 0.05 0.2
        claw_R_1 -0.2 0.02 0.25
          claw_R_2 -0.2 0 0.3
  neck 0 1.3 0.2
    skull 0 1.6 0.25
      crest_L 0.1 1.8 0.2
        crest_L_1 0.12 1.85 0.2
          crest_L_2 0.14 1.88 0.2
      crest_R -0.1 1.8 0.2
        crest_R_1 -0.12 1.85 0.2
          crest_R_2 -0.14 1.88 0.2
      snout 0 1.9 0.3
"""


def test_limbs_hanging_far_from_the_trunk_for_their_length_are_no_person_s():
    message = _refused(skeleton_from_points(CREATURE))
    assert "not a" in message


def test_many_long_props_do_not_hide_the_limbs():
    # Seven body-long chains (IK targets, weapons, cloth) hanging from the root outnumber the
    # first candidates for limb ends; more are looked at before the rig is refused.
    skeleton, truth = synthetic_humanoid(Humanoid(names="anon"))
    rng = np.random.default_rng(2)
    parents: list[int] = []
    offsets: list[np.ndarray] = []
    for _ in range(7):
        way = rng.normal(size=3)
        parents += [0, skeleton.joint_count + len(parents)]
        offsets += [way / np.linalg.norm(way) * 0.9, way / np.linalg.norm(way) * 0.6]
    busy = grown(walking(skeleton, truth), parents, offsets)
    mapping = build_body(busy).mapping
    got = {c: busy.skeleton.names[j] for c, j in zip(CANONICAL_JOINTS, mapping.joints, strict=True)}
    assert {c: got[c] for c in truth if c != "head"} == {c: truth[c] for c in truth if c != "head"}


@pytest.mark.parametrize("names", ["blender", "anon"])
def test_feet_held_by_ik_at_the_end_of_the_shins_are_the_ankles(names: str):
    # The foot bones hang from the root (Quaternius-style game rigs); the animation keeps
    # them at the end of the shins. The motion shows it: each stays at one distance from its
    # knee while the knee bends.
    skeleton, truth = synthetic_humanoid(Humanoid(names=names))
    motion = hung_from_root(walking(skeleton, truth), [truth["l_ankle"], truth["r_ankle"]])
    body = build_body(motion)
    got = {c: skeleton.names[j] for c, j in zip(CANONICAL_JOINTS, body.mapping.joints, strict=True)}
    limbs = [c for c in truth if c not in ("head", "neck")]
    assert {c: got[c] for c in limbs} == {c: truth[c] for c in limbs}
    assert any("held by IK" in w for w in body.warnings)
    check_canonical_body(body, "ik feet", upright=True)
    # A still clip of the same rig shows nothing: the legs end at the knees.
    with pytest.raises(SkeletonMappingError):
        build_body(motion.slice_frames(0, 1))


def _with_end_sites(skeleton: Skeleton, length: float) -> Skeleton:
    """``skeleton`` with an End Site ``length`` long beyond every leaf, along its bone."""
    leaves = [j for j in range(skeleton.joint_count) if j not in set(skeleton.parents.tolist())]
    ends = [skeleton.offsets[j] / np.linalg.norm(skeleton.offsets[j]) * length for j in leaves]
    return Skeleton(
        (*skeleton.names, *(f"{skeleton.names[j]}_end" for j in leaves)),
        np.concatenate([skeleton.parents, leaves]),
        np.concatenate([skeleton.offsets, ends]),
        np.concatenate([skeleton.end_site, np.ones(len(leaves), dtype=bool)]),
    )


@pytest.mark.parametrize("named", [True, False], ids=["smpl-names", "no-names"])
@pytest.mark.parametrize("end_sites", [False, True], ids=["leaves", "end-sites"])
def test_smpl_chains_map_collar_shoulder_elbow_wrist_hand(named: bool, end_sites: bool):
    # collar -> shoulder -> elbow -> wrist -> hand and hip -> knee -> ankle -> foot, with or
    # without names, with or without End Sites beyond the hands and feet (as SMPL-to-BVH
    # exporters write them).
    skeleton = skeleton_from_points(SMPL)
    if end_sites:
        skeleton = _with_end_sites(skeleton, 0.05)
    if not named:
        skeleton = dataclasses.replace(
            skeleton, names=tuple(f"J{i}" for i in range(skeleton.joint_count))
        )
    mapping = map_skeleton(skeleton)
    truth = skeleton_from_points(SMPL).names
    got = {c: truth[j] for c, j in zip(CANONICAL_JOINTS, mapping.joints, strict=True) if j < 24}
    for side in "LR":
        s = side.lower()
        assert got[f"{s}_shoulder"] == f"{side}_Shoulder"
        assert got[f"{s}_elbow"] == f"{side}_Elbow"
        assert got[f"{s}_wrist"] == f"{side}_Wrist"
        assert got[f"{s}_hip"] == f"{side}_Hip"
        assert got[f"{s}_knee"] == f"{side}_Knee"
        assert got[f"{s}_ankle"] == f"{side}_Ankle"
    assert mapping.mirrored is False


# A T-posed rig without usable names whose collar bones lie in line with the arms and whose
# forearms are longer than the upper arms (as Vicon's and Xsens's are): the rest pose alone
# prefers the collar for the shoulder. Y up, metres.
_COLLAR_IN_LINE = """
j1 0 1.0 0
  j2 0 1.2 0
    j3 0 1.4 0
      j4 0 1.5 0
        j5 0 1.58 0
          j6* 0 1.75 0
      j7 0.03 1.45 0
        j8 0.18 1.45 0
          j9 0.44 1.45 0
            j10 0.72 1.45 0
              j11* 0.85 1.45 0
      j12 -0.03 1.45 0
        j13 -0.18 1.45 0
          j14 -0.44 1.45 0
            j15 -0.72 1.45 0
              j16* -0.85 1.45 0
  j17 0.1 0.95 0
    j18 0.1 0.52 0
      j19 0.1 0.08 0
        j20 0.1 0.02 0.12
          j21* 0.1 0.02 0.18
  j22 -0.1 0.95 0
    j23 -0.1 0.52 0
      j24 -0.1 0.08 0
        j25 -0.1 0.02 0.12
          j26* -0.1 0.02 0.18
"""


def _arms_swinging(skeleton: Skeleton, frames: int = 60) -> Motion:
    """``skeleton`` (:data:`_COLLAR_IN_LINE`) lowering and raising its arms at the shoulders
    (the collar bones stay still), elbows and knees bending."""
    phase = 2 * np.pi * np.arange(frames) / 30.0
    rotvecs = np.zeros((frames, skeleton.joint_count, 3))
    for shoulder, elbow, knee, sign in (("j8", "j9", "j18", 1.0), ("j13", "j14", "j23", -1.0)):
        rotvecs[:, skeleton.index(shoulder), 2] = -sign * (0.7 + 0.5 * np.sin(phase))
        rotvecs[:, skeleton.index(elbow), 1] = -sign * (0.4 + 0.2 * np.sin(phase))
        rotvecs[:, skeleton.index(knee), 0] = 0.5 + 0.4 * np.sin(phase + 1.0)
    local = Rotation.from_rotvec(rotvecs.reshape(-1, 3)).as_matrix()
    root = np.stack([np.zeros(frames), np.ones(frames), 0.5 * phase], axis=1)
    return Motion(skeleton, 1 / 30.0, root, local.reshape(frames, skeleton.joint_count, 3, 3))


def test_the_shoulder_is_where_the_arm_swings_not_a_collar_bone_in_line_with_it():
    # Collar roots wider than the hips (0.12 from the spine's line, the hips 0.1): in the
    # rest pose the line of clavicle, upper arm and forearm leaves the proportions to
    # choose, and the clip's frames are left to decide.
    skeleton = skeleton_from_points(
        _COLLAR_IN_LINE.replace("j7 0.03", "j7 0.12").replace("j12 -0.03", "j12 -0.12")
    )
    alone = map_skeleton(skeleton)
    assert alone.limbs_open
    assert [skeleton.names[alone.joints[CANONICAL_INDEX[f"{s}_shoulder"]]] for s in "lr"] == [
        "j7",
        "j12",
    ]
    # In the motion the collar bone keeps its line while the upper arm swings: a joint that
    # turns inside the "upper arm" is the shoulder.
    body = build_body(_arms_swinging(skeleton))
    got = {c: skeleton.names[j] for c, j in zip(CANONICAL_JOINTS, body.mapping.joints, strict=True)}
    assert [got[f"{s}_{part}"] for part in ("shoulder", "elbow", "wrist") for s in "lr"] == [
        "j8",
        "j13",
        "j9",
        "j14",
        "j10",
        "j15",
    ]
    check_canonical_body(body, "collar in line", upright=True)


def test_a_shoulder_sits_wider_than_the_hips_a_collar_root_does_not():
    # Collar roots near the spine (0.03 from its line, the hips 0.1): the rest pose alone
    # tells the shoulder, whatever the proportions say, and the frames agree.
    skeleton = skeleton_from_points(_COLLAR_IN_LINE)
    for mapping in (map_skeleton(skeleton), build_body(_arms_swinging(skeleton)).mapping):
        assert mapping is not None
        tops = [skeleton.names[mapping.joints[CANONICAL_INDEX[f"{s}_shoulder"]]] for s in "lr"]
        assert tops == ["j8", "j13"]


@pytest.mark.parametrize("end_site", [False, True], ids=["leaf joint", "zero-length end site"])
def test_a_head_leaf_joint_one_joint_above_the_arms_is_the_head_on_its_neck(end_site: bool):
    # chest -> neck -> head with nothing beyond the head (or a zero-length End Site, which
    # adds no point): without names, the leaf is the head and the joint below it the neck,
    # not a head sitting on the shoulders with the leaf for its top.
    skeleton, truth = synthetic_humanoid(Humanoid(names="anon", head_end=False))
    if end_site:
        skeleton = _with_end_sites(skeleton, 0.0)
    mapping = map_skeleton(skeleton)
    got = {c: skeleton.names[mapping.joints[CANONICAL_INDEX[c]]] for c in ("neck", "head")}
    assert got == {"neck": truth["neck"], "head": truth["head"]}
    assert skeleton.names[mapping.head_joint] == truth["head"]
    assert "neck derived from the head's parent" not in mapping.warnings


def _with_tails(skeleton: Skeleton) -> Skeleton:
    """``skeleton`` with two alike tails from its pelvis, pointing straight back (along -z,
    opposite a trunk tipped to +z), one above the other, each 0.8 of a leg long."""
    pelvis = skeleton.index("Hips")
    leg = sum(
        float(np.linalg.norm(skeleton.offsets[skeleton.index(n)]))
        for n in ("LeftLeg", "LeftFoot", "LeftToeBase")
    )
    names, parents = list(skeleton.names), list(skeleton.parents)
    offsets, end_site = list(skeleton.offsets), list(skeleton.end_site)
    for tail, lift in (("TailA", 0.02), ("TailB", -0.02)):
        parent = pelvis
        for k in range(5):
            names.append(f"{tail}{k}" if k < 4 else f"{tail}_end")
            parents.append(parent)
            offsets.append(np.array([0.0, lift * leg if k == 0 else 0.0, -0.2 * leg * 0.8]))
            end_site.append(k == 4)
            parent = len(names) - 1
    return Skeleton(
        tuple(names), np.array(parents), np.array(offsets), np.array(end_site, dtype=bool)
    )


def test_an_animal_with_two_tails_is_refused_as_four_legged():
    """Two tails pointing back from an animal's hips, opposite its level spine, pass for a
    person's legs (lying down) while its hind legs, longer, hang down. A person stands on
    the longest limbs hanging from the pelvis: the animal reading wins (on main the tails
    were taken for legs and the animal stored as a person)."""
    message = _refused(_with_tails(_quadruped(_cmu_bvh().skeleton)))
    assert "four-legged" in message


def test_limbs_pointing_every_way_are_refused_for_what_failed_not_as_an_animal():
    """A rest pose whose legs go up beside the spine while the arms reach out sideways is no
    upright body, and no animal's stance either (its four limbs do not hang one way): the
    refusal says the legs do not reach down, where it used to call it a four-legged animal
    (a video tool's rest offsets, differences of detected landmarks, read so)."""
    skeleton = _cmu_bvh().skeleton
    legs = {
        j
        for side in ("Left", "Right")
        for j in range(skeleton.joint_count)
        if _under(skeleton, j, skeleton.index(f"{side}UpLeg"))
    }
    offsets = skeleton.offsets.copy()
    offsets[sorted(legs), 1] *= -1  # the legs up, mirrored about the hips' height
    message = _refused(Skeleton(skeleton.names, skeleton.parents, offsets, skeleton.end_site))
    assert "four-legged" not in message
    assert "the legs do not reach down from the pelvis away from the spine" in message


LONE_HAND = """
wrist 0 0 0
  hand 0 2 0
    index1 -1.5 9 0
      index2 -1.6 12 0
        index3 -1.7 14 0
    middle1 0 9.5 0
      middle2 0 12.5 0
        middle3 0 15 0
    ring1 1.5 9 0
      ring2 1.6 12 0
        ring3 1.7 14 0
    pinky1 3 8 0
      pinky2 3.3 10 0
        pinky3 3.5 11.5 0
    thumb1 -2.5 4 1
      thumb2 -4 6 1.5
        thumb3 -5 8 2
"""


def test_a_lone_hand_is_refused_as_limb_ends_that_leave_one_joint():
    """A hand solve on its own (five fingers from the palm): refused naming what it is, not
    "the legs hang from the arms' branch point" (the first choice the tree refused)."""
    message = _refused(skeleton_from_points(LONE_HAND))
    assert "every limb end leaves one joint (hand) by a branch of its own" in message


def test_a_rig_of_a_few_leaves_on_its_root_is_refused_for_what_it_lacks():
    """A test fixture's four joints (hips, and the head and two feet hanging from them by one
    bone each): every joint but the root is a shallow leaf, so the pose's size was measured
    over the root alone and the refusal said every joint sits at one point (they are 10
    apart). The size is now the whole rig's, and the refusal names what is missing."""
    rig = skeleton_from_points(
        """
        Hips 0 10 0
          Head* 0 20 0
          LeftFoot* 1 0 0
          RightFoot* -1 0 0
        """
    )
    message = _refused(rig)
    assert "at one point" not in message
    assert "found only" in message and "missing legs, arms or head" in message


def test_legs_that_do_not_reach_down_far_enough_are_named_with_their_reach() -> None:
    """A figure whose legs point forward more than down (a cartoon's feet longer than its
    legs, a rig posed sitting on nothing) is refused, and the refusal says which limbs were
    tried as legs and how far down they reach: they are there, not "missing" alone."""
    motion = read_bvh(fixture_bytes(CMU_BVH_FIXTURE)).slice_frames(0, 3)
    names = list(motion.skeleton.names)
    offsets = motion.skeleton.offsets.copy()
    forward = np.array([0.0, -np.cos(np.radians(65.0)), np.sin(np.radians(65.0))])
    for side in ("Left", "Right"):
        for part in ("Leg", "Foot", "ToeBase", "ToeBase_end"):
            j = names.index(side + part)
            offsets[j] = forward * np.linalg.norm(offsets[j])
    still = dataclasses.replace(
        motion,
        skeleton=dataclasses.replace(motion.skeleton, offsets=offsets),
        local_rotations=np.broadcast_to(np.eye(3), motion.local_rotations.shape).copy(),
        root_translation=np.repeat(motion.root_translation[:1], motion.frame_count, axis=0),
    )
    with pytest.raises(SkeletonMappingError) as refused:
        build_body(still)
    message = str(refused.value)
    assert "missing legs (the limbs ending at LeftToeBase_end, RightToeBase_end reach down" in (
        message
    )
    reach = [float(x) for x in re.findall(r"reach down (-?[0-9.]+) and (-?[0-9.]+)", message)[0]]
    assert all(0.3 < r < 0.5 for r in reach) and "a leg at least 0.5" in message


def test_a_limb_ending_above_the_pelvis_is_not_named_as_a_leg_that_falls_short() -> None:
    """Where the limbs tried as legs include one that ends above the pelvis (a hand, the
    head: a skeleton whose legs a writer left out), the legs are missing, and the refusal
    does not call that limb a leg that reaches too little."""
    from app.motion.mapping.hypotheses import _check_pose
    from app.motion.mapping.tree import _Tree

    skeleton = read_bvh(fixture_bytes(CMU_BVH_FIXTURE)).skeleton
    tree, pose = _Tree(skeleton), rest_pose(skeleton)
    at = {name: skeleton.names.index(name) for name in skeleton.names}
    pelvis, chest = at["Hips"], at["Spine1"]
    hands = (at["LeftHandIndex1_end"], at["RightHandIndex1_end"])
    extent = float(np.linalg.norm(np.ptp(pose, axis=0)))

    def why(feet: tuple[int, int]) -> str:
        legs = [float(tree.path[f] - tree.path[pelvis]) for f in feet]
        arms = [float(tree.path[h] - tree.path[chest]) for h in hands]
        body, reason, _ = _check_pose(
            tree, pose, extent, at["Head_end"], hands, feet, chest, pelvis, legs, arms, ()
        )
        assert body is None
        return reason

    # A leg straight down, and a hand's end beside the hips a little above the pelvis.
    pose[at["LeftToeBase_end"]] = pose[pelvis] + np.array([0.08, -0.45, 0.0]) * extent
    pose[at["LThumb_end"]] = pose[pelvis] + np.array([0.1, 0.005, 0.0]) * extent
    assert why((at["LeftToeBase_end"], at["LThumb_end"])) == (
        "no two legs reach down from the pelvis: missing legs"
    )


def test_keypoints_hung_side_by_side_from_the_root_are_refused_as_keypoints() -> None:
    """A pose estimator's "positional" BVH: 16 keypoints each a child of the root with a
    zero OFFSET and an End Site, moved by position channels alone. No limb is a chain, so
    nothing can be mapped; the refusal says why in those words, not that every joint sits
    at one point (the frames spread them out)."""
    keypoints = ["RHip", "RKnee", "RFoot", "LHip", "LKnee", "LFoot", "Spine", "Thorax"]
    keypoints += ["Neck", "Head", "LShoulder", "LElbow", "LWrist", "RShoulder", "RElbow"]
    keypoints += ["RWrist"]
    names, parents, end_site = ["Hip"], [-1], [False]
    for name in keypoints:
        names += [name, f"{name}_end"]
        parents += [0, len(parents)]
        end_site += [False, True]
    offsets = np.zeros((len(names), 3))
    offsets[np.array(end_site)] = [0.0, 0.1, 0.0]
    star = Skeleton(tuple(names), np.array(parents), offsets, np.array(end_site))
    with pytest.raises(SkeletonMappingError) as refused:
        map_skeleton(star)
    assert str(refused.value).startswith(
        "the 16 joints all hang from the root 'Hip' directly, with no bone between any two"
    )
    assert "keypoints, not a skeleton" in str(refused.value)
