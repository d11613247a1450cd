"""ASF/AMC reader: CMU conventions checked against the MotionBuilder BVH of the same trial."""

from __future__ import annotations

import random
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from app.errors import DescribeTimeout, LimitExceeded, NoAnimation, ParseError
from app.motion import model as model_module
from app.motion.formats import DEFAULT_AMC_FRAME_TIME, read_asf_amc, read_bvh
from app.motion.formats import amc as amc_module
from app.motion.formats import text as text_module
from app.motion.model import Motion, ParseLimits
from tests.motion.conftest import (
    CMU_AMC_FIXTURE,
    CMU_ASF_FIXTURE,
    CMU_BVH_FIXTURE,
    assert_consistent,
    fixture_bytes,
    fixture_text,
    world_positions,
)
from tests.motion.work import Clock, RecordingPattern

# Line numbers matter: the rejection tests below edit these texts by line.
TINY_ASF = """\
# tiny skeleton
:version 1.10
:name tiny
:units
  mass 1.0
  length 0.5
  angle deg
:root
   order TX TY TZ RX RY RZ
   axis XYZ
   position 0 0 0
   orientation 0 0 0
:bonedata
  begin
     id 1
     name hip
     direction 0 -1 0
     length 2
     axis 0 0 30 XYZ
    dof rx ry rz
    limits (-160.0 20.0)
           (-70.0 70.0)
           (-60.0 70.0)
  end
  begin
     id 2
     name knee
     direction 0 -1 0
     length 3
     axis 10 20 30 XYZ
    dof rz rx
  end
  begin
     id 3
     name spine
     direction 0 1 0
     length 4
     axis 0 0 0 XYZ
  end
:hierarchy
  begin
    root hip spine
    hip knee
  end
"""
A_UNITS_LENGTH, A_ANGLE, A_ORDER, A_AXIS = 6, 7, 9, 10
A_HIP_BEGIN, A_HIP_NAME, A_HIP_DIRECTION, A_HIP_LENGTH, A_HIP_AXIS, A_HIP_DOF = (
    14,
    16,
    17,
    18,
    19,
    20,
)
A_HIP_END, A_KNEE_NAME, A_SPINE_NAME = 24, 27, 35
A_HIERARCHY, A_ROOT_LINE, A_HIP_LINE = 40, 42, 43

TINY_AMC = """\
#!OML:ASF tiny.asf
:FULLY-SPECIFIED
:DEGREES
1
root 1 2 3 10 20 30
hip 5 6 7
knee 40 50
2
root 0 0 0 0 0 0
hip 0 0 0
knee 0 0
"""
M_FIRST_FRAME, M_ROOT_1, M_HIP_1, M_KNEE_1, M_SECOND_FRAME, M_ROOT_2, M_HIP_2, M_KNEE_2 = range(
    4, 12
)


def edit(text: str, line: int, new: str | None) -> str:
    """``text`` with 1-based ``line`` replaced by ``new`` (deleted when ``None``)."""
    lines = text.split("\n")
    if new is None:
        del lines[line - 1]
    else:
        lines[line - 1] = new
    return "\n".join(lines)


def rot(sequence: str, angles: list[float]) -> np.ndarray:
    return Rotation.from_euler(sequence, angles, degrees=True).as_matrix()


def frame_lines(amc_text: str) -> int:
    return len(re.findall(r"^\d+\s*$", amc_text, flags=re.MULTILINE))


# ------------------------------------------------------------------------------ conventions


def test_tiny_skeleton_joints_offsets_and_units() -> None:
    motion = read_asf_amc(TINY_ASF, TINY_AMC)
    assert_consistent(motion)
    skeleton = motion.skeleton
    assert skeleton.names == ("root", "hip", "knee", "knee_end", "spine", "spine_end")
    np.testing.assert_array_equal(skeleton.parents, [-1, 0, 1, 2, 0, 4])
    np.testing.assert_array_equal(skeleton.end_site, [False, False, False, True, False, True])
    # a bone's joint sits at its parent bone's tip; lengths divided by :units length 0.5
    np.testing.assert_allclose(
        skeleton.offsets, [[0, 0, 0], [0, 0, 0], [0, -4, 0], [0, -6, 0], [0, 0, 0], [0, 8, 0]]
    )
    assert motion.source_format == "asf/amc"
    assert motion.length_unit == "ASF units / 0.5"
    assert motion.frame_time == DEFAULT_AMC_FRAME_TIME == pytest.approx(1 / 120)
    assert motion.frame_count == 2
    assert motion.local_translations is None


def test_a_writer_s_unit_words_and_offsets_as_directions_read_as_the_format_means() -> None:
    """A converter seen in the wild writes ``mass kg`` and ``length m`` under ``:units`` and
    each bone's offset as its ``direction`` (with its norm as ``length``): the mass is read by
    no one, the lengths are read as written (with a warning), and the direction is the unit
    vector the format asks for. Before, the file was refused on ``mass kg``, and the bones
    were their lengths squared."""
    units = edit(edit(TINY_ASF, A_UNITS_LENGTH - 1, "  mass kg"), A_UNITS_LENGTH, "  length m")
    offsets = edit(units, A_HIP_DIRECTION, "     direction 0 -2 0")  # the hip bone is 2 long
    motion = read_asf_amc(offsets, TINY_AMC)
    np.testing.assert_allclose(
        motion.skeleton.offsets,
        [[0, 0, 0], [0, 0, 0], [0, -2, 0], [0, -3, 0], [0, 0, 0], [0, 4, 0]],
    )
    assert any("length 'm' names a unit" in w for w in motion.notes["warnings"])
    plain = read_asf_amc(TINY_ASF, TINY_AMC)  # a unit vector stays exactly as written
    np.testing.assert_array_equal(plain.skeleton.offsets / 2, motion.skeleton.offsets)


def test_zeros_for_a_bone_without_dof_are_read_as_nothing_to_turn() -> None:
    """A writer gives every bone three values, also the bones the ASF gives no dof (its
    ``*_dum`` joints): zeros turn nothing and are read; a value that is not zero still
    refuses (``ASF_REJECTIONS``), as no dof could carry it."""
    zeros = edit(TINY_AMC, M_KNEE_2, "knee 0 0\nspine 0 0 0.0")
    motion = read_asf_amc(TINY_ASF, zeros)
    np.testing.assert_array_equal(
        motion.local_rotations, read_asf_amc(TINY_ASF, TINY_AMC).local_rotations
    )


def test_tiny_rotations_follow_the_cmu_convention() -> None:
    motion = read_asf_amc(TINY_ASF, TINY_AMC)
    np.testing.assert_allclose(motion.root_translation, [[2, 4, 6], [0, 0, 0]])
    # root: C = I, M extrinsic in the order RX RY RZ appear in `order`
    np.testing.assert_allclose(motion.local_rotations[0, 0], rot("xyz", [10, 20, 30]), atol=1e-12)
    # bone: L = C M C^T, C extrinsic from `axis`, M extrinsic in `dof` order
    c_hip = rot("xyz", [0, 0, 30])
    c_knee = rot("xyz", [10, 20, 30])
    np.testing.assert_allclose(
        motion.local_rotations[0, 1], c_hip @ rot("xyz", [5, 6, 7]) @ c_hip.T, atol=1e-12
    )
    np.testing.assert_allclose(
        motion.local_rotations[0, 2], c_knee @ rot("zx", [40, 50]) @ c_knee.T, atol=1e-12
    )
    # spine has no dof, end sites never rotate, zero values give identity
    identity = np.broadcast_to(np.eye(3), (2, 3, 3, 3))
    np.testing.assert_allclose(motion.local_rotations[:, [3, 4, 5]], identity, atol=1e-12)
    np.testing.assert_allclose(
        motion.local_rotations[1], np.broadcast_to(np.eye(3), (6, 3, 3)), atol=1e-12
    )


def test_radians_from_asf_units_and_amc_header() -> None:
    radians_asf = edit(TINY_ASF, A_ANGLE, "  angle rad")
    radians_asf = edit(radians_asf, A_HIP_AXIS, f"     axis 0 0 {np.radians(30)} XYZ")
    radians_asf = edit(
        radians_asf, 30, f"     axis {np.radians(10)} {np.radians(20)} {np.radians(30)} XYZ"
    )
    radians_amc = TINY_AMC.replace("knee 40 50", f"knee {np.radians(40)} {np.radians(50)}")
    radians_amc = radians_amc.replace(":DEGREES", ":RADIANS")
    degrees = read_asf_amc(TINY_ASF, TINY_AMC)
    radians = read_asf_amc(radians_asf, radians_amc.replace("hip 5 6 7", "hip 0 0 0"))
    np.testing.assert_allclose(
        radians.local_rotations[0, 2], degrees.local_rotations[0, 2], atol=1e-12
    )
    # :DEGREES in the AMC overrides `angle rad` in the ASF (and vice versa)
    mixed = read_asf_amc(radians_asf, TINY_AMC)
    np.testing.assert_allclose(
        mixed.local_rotations[0, 1], degrees.local_rotations[0, 1], atol=1e-12
    )


def test_root_order_axis_position_and_orientation() -> None:
    asf = edit(TINY_ASF, A_ORDER, "   order RZ RX TY TX")
    asf = edit(asf, A_AXIS, "   axis ZYX")
    asf = edit(asf, 11, "   position 1 1 1")
    asf = edit(asf, 12, "   orientation 10 20 30")
    amc = TINY_AMC.replace("root 1 2 3 10 20 30", "root 15 25 3 4").replace(
        "root 0 0 0 0 0 0", "root 0 0 0 0"
    )
    motion = read_asf_amc(asf, amc)
    # TY=3, TX=4, TZ absent; plus position; all / 0.5
    np.testing.assert_allclose(motion.root_translation, [[10, 8, 2], [2, 2, 2]])
    c_root = rot("zyx", [10, 20, 30])
    expected = c_root @ rot("zx", [15, 25]) @ c_root.T
    np.testing.assert_allclose(motion.local_rotations[0, 0], expected, atol=1e-12)


def test_translation_and_length_dofs_move_joints() -> None:
    asf = edit(TINY_ASF, 31, "    dof tx ty l rz")
    amc = TINY_AMC.replace("knee 40 50", "knee 1 2 0.5 90").replace("knee 0 0", "knee 0 0 0 0")
    motion = read_asf_amc(asf, amc)
    assert motion.local_translations is not None
    c_knee = rot("xyz", [10, 20, 30])
    # knee joint moved along its own axes by (tx, ty, 0) / 0.5
    np.testing.assert_allclose(
        motion.local_translations[0, 2], [0, -4, 0] + c_knee @ [2, 4, 0], atol=1e-12
    )
    # knee_end pushed along the knee's direction by l / 0.5
    np.testing.assert_allclose(motion.local_translations[0, 3], [0, -7, 0], atol=1e-12)
    np.testing.assert_allclose(motion.local_translations[1, 1:], motion.skeleton.offsets[1:])
    np.testing.assert_allclose(motion.local_translations[:, 0], motion.root_translation)
    np.testing.assert_allclose(
        motion.local_rotations[0, 2], c_knee @ rot("z", [90]) @ c_knee.T, atol=1e-12
    )


def test_frame_time_can_be_given() -> None:
    assert read_asf_amc(TINY_ASF, TINY_AMC, frame_time=1 / 60).frame_time == pytest.approx(1 / 60)
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ParseError, match="frame_time"):
            read_asf_amc(TINY_ASF, TINY_AMC, frame_time=bad)


def test_any_bone_order_comments_and_blank_lines() -> None:
    shuffled = TINY_AMC.replace(
        "root 0 0 0 0 0 0\nhip 0 0 0\nknee 0 0\n",
        "\n# a comment\nknee 0 0\nhip 0 0 0\nroot 0 0 0 0 0 0\n\n",
    ).replace("1\nroot", "1\r\nroot")
    expected = read_asf_amc(TINY_ASF, TINY_AMC)
    motion = read_asf_amc(TINY_ASF, shuffled)
    np.testing.assert_allclose(motion.local_rotations, expected.local_rotations)
    np.testing.assert_allclose(motion.root_translation, expected.root_translation)
    # a bone without dof may be listed with no values
    listed = read_asf_amc(TINY_ASF, TINY_AMC.replace("knee 0 0\n", "knee 0 0\nspine\n"))
    np.testing.assert_allclose(listed.local_rotations, expected.local_rotations)


# ------------------------------------------------------------------------------ real fixtures


def test_cmu_fixture_skeleton() -> None:
    motion = read_asf_amc(fixture_bytes(CMU_ASF_FIXTURE), fixture_bytes(CMU_AMC_FIXTURE))
    assert_consistent(motion)
    skeleton = motion.skeleton
    assert motion.frame_count == frame_lines(fixture_text(CMU_AMC_FIXTURE)) == 40
    assert skeleton.joint_count == 1 + 30 + 7  # root, 30 bones, 7 leaf tips
    assert skeleton.names[:7] == (
        "root",
        "lhipjoint",
        "lfemur",
        "ltibia",
        "lfoot",
        "ltoes",
        "ltoes_end",
    )
    assert motion.length_unit.startswith("inches")
    # lfemur sits at the tip of lhipjoint: direction * length / 0.45
    lhipjoint = np.array([0.655637, -0.713449, 0.247245]) * 2.52691 / 0.45
    np.testing.assert_allclose(skeleton.offsets[skeleton.index("lfemur")], lhipjoint)
    np.testing.assert_allclose(
        skeleton.offsets[skeleton.index("ltoes_end")],
        np.array([1.53547e-011, -4.22004e-011, 1]) * 1.11249 / 0.45,
    )
    np.testing.assert_allclose(
        motion.root_translation[0], np.array([10.4194, 16.7048, -30.1003]) / 0.45
    )


# Joints at the same place in the CMU AMC and its MotionBuilder BVH conversion.
SAME_PLACE = [
    ("root", "Hips"),
    ("lfemur", "LeftUpLeg"),
    ("ltibia", "LeftLeg"),
    ("lfoot", "LeftFoot"),
    ("ltoes", "LeftToeBase"),
    ("rfemur", "RightUpLeg"),
    ("rtibia", "RightLeg"),
    ("rfoot", "RightFoot"),
    ("upperback", "Spine"),
    ("thorax", "Spine1"),
    # the converter drops the thorax bone: its Neck and shoulders sit at the thorax start
    ("thorax", "Neck"),
    ("thorax", "LeftShoulder"),
]
# Bone vectors that agree (the part of the body above the dropped thorax bone).
SAME_BONE = [
    (("lowerneck", "head"), ("Neck", "Head")),
    (("lclavicle", "lhumerus"), ("LeftShoulder", "LeftArm")),
    (("lhumerus", "lradius"), ("LeftArm", "LeftForeArm")),
    (("lhumerus", "lwrist"), ("LeftArm", "LeftHand")),
    (("rclavicle", "rhumerus"), ("RightShoulder", "RightArm")),
    (("rhumerus", "rwrist"), ("RightArm", "RightHand")),
    (("head", "head_end"), ("Head", "Head_end")),
]


def assert_matches_motionbuilder(amc: Motion, bvh: Motion, *, tolerance: float = 1e-3) -> None:
    """Same joint positions, in the BVH's units (raw ASF units, i.e. inches * 0.45)."""
    assert bvh.frame_count == amc.frame_count + 1  # the converter's added T-pose
    amc_positions = world_positions(amc) * 0.45
    bvh_positions = world_positions(bvh)[1:]
    a, b = amc.skeleton.index, bvh.skeleton.index
    for amc_joint, bvh_joint in SAME_PLACE:
        np.testing.assert_allclose(
            amc_positions[:, a(amc_joint)],
            bvh_positions[:, b(bvh_joint)],
            atol=tolerance,
            err_msg=f"{amc_joint} vs {bvh_joint}",
        )
    for (amc_from, amc_to), (bvh_from, bvh_to) in SAME_BONE:
        np.testing.assert_allclose(
            amc_positions[:, a(amc_to)] - amc_positions[:, a(amc_from)],
            bvh_positions[:, b(bvh_to)] - bvh_positions[:, b(bvh_from)],
            atol=tolerance,
            err_msg=f"{amc_from}->{amc_to} vs {bvh_from}->{bvh_to}",
        )


def test_cmu_fixture_matches_its_motionbuilder_bvh() -> None:
    amc = read_asf_amc(fixture_bytes(CMU_ASF_FIXTURE), fixture_bytes(CMU_AMC_FIXTURE))
    bvh = read_bvh(fixture_bytes(CMU_BVH_FIXTURE))
    assert_matches_motionbuilder(amc, bvh)
    # and the body really moves over the clip (the check is not trivially true)
    positions = world_positions(amc)
    assert np.ptp(positions[:, amc.skeleton.index("lwrist")], axis=0).max() > 1.0


def test_regular_files_take_the_fast_path(monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(*args: object, **kwargs: object) -> None:
        raise AssertionError("the line-by-line pass should not be needed")

    expected = read_asf_amc(fixture_bytes(CMU_ASF_FIXTURE), fixture_bytes(CMU_AMC_FIXTURE))
    monkeypatch.setattr(amc_module, "_read_amc_lines", refuse)
    fast = read_asf_amc(fixture_bytes(CMU_ASF_FIXTURE), fixture_bytes(CMU_AMC_FIXTURE))
    np.testing.assert_array_equal(fast.local_rotations, expected.local_rotations)


def test_fast_and_line_by_line_passes_agree() -> None:
    text = fixture_text(CMU_AMC_FIXTURE)
    fast = read_asf_amc(fixture_text(CMU_ASF_FIXTURE), text)
    # shuffle the bone lines inside every frame: only the line-by-line pass reads that
    rng = random.Random(7)
    header, body = text.split(":DEGREES\r\n")
    frames = re.split(r"(?m)^(?=\d+\r$)", body)
    shuffled = []
    for frame in frames:
        lines = frame.split("\r\n")
        bones = [line for line in lines[1:] if line]
        rng.shuffle(bones)
        shuffled.append("\r\n".join([lines[0], *bones]) + "\r\n")
    slow = read_asf_amc(fixture_text(CMU_ASF_FIXTURE), header + ":DEGREES\r\n" + "".join(shuffled))
    np.testing.assert_array_equal(slow.local_rotations, fast.local_rotations)
    np.testing.assert_array_equal(slow.root_translation, fast.root_translation)


# ------------------------------------------------------------------------------ rejections

ASF_REJECTIONS: list[tuple[str, str | bytes, int | None, str]] = [
    ("empty", b"", None, "empty"),
    ("not an ASF", "hello\n", 1, "not an ASF"),
    (
        "unknown unit keyword",
        edit(TINY_ASF, A_UNITS_LENGTH, "  size 0.45"),
        A_UNITS_LENGTH,
        "unknown :units keyword",
    ),
    ("unknown angle unit", edit(TINY_ASF, A_ANGLE, "  angle grad"), A_ANGLE, "unknown angle unit"),
    (
        "zero length unit",
        edit(TINY_ASF, A_UNITS_LENGTH, "  length 0"),
        A_UNITS_LENGTH,
        "greater than 0",
    ),
    (
        "bad root order",
        edit(TINY_ASF, A_ORDER, "   order TX TY TQ"),
        A_ORDER,
        "unknown :root order",
    ),
    ("bad root axis", edit(TINY_ASF, A_AXIS, "   axis XY"), A_AXIS, ":root axis"),
    (
        "bone without end",
        edit(TINY_ASF, A_HIP_END, ""),
        A_HIP_END + 1,
        "'begin' inside the bone block begun on line 14",
    ),
    (
        "last bone without end",
        edit(TINY_ASF, 39, ""),
        A_HIERARCHY,
        "has no 'end' before :hierarchy",
    ),
    ("bone without name", edit(TINY_ASF, A_HIP_NAME, ""), A_HIP_END, "no name"),
    (
        "duplicate bone",
        edit(TINY_ASF, A_KNEE_NAME, "     name hip"),
        32,
        "duplicate bone name 'hip'",
    ),
    ("bone named root", edit(TINY_ASF, A_KNEE_NAME, "     name root"), 32, "duplicate bone name"),
    (
        "direction count",
        edit(TINY_ASF, A_HIP_DIRECTION, "direction 0 -1"),
        A_HIP_DIRECTION,
        "3 numbers",
    ),
    (
        "direction text",
        edit(TINY_ASF, A_HIP_DIRECTION, "direction 0 x 0"),
        A_HIP_DIRECTION,
        "not a number",
    ),
    ("negative length", edit(TINY_ASF, A_HIP_LENGTH, "length -2"), A_HIP_LENGTH, "negative"),
    ("infinite length", edit(TINY_ASF, A_HIP_LENGTH, "length 1e999"), A_HIP_LENGTH, "finite"),
    ("no length", edit(TINY_ASF, A_HIP_LENGTH, ""), A_HIP_END, "direction and a length"),
    ("axis without order", edit(TINY_ASF, A_HIP_AXIS, "axis 0 0 30"), A_HIP_AXIS, "bone axis"),
    ("unknown dof", edit(TINY_ASF, A_HIP_DOF, "dof rx rq"), A_HIP_DOF, "unknown dof"),
    ("repeated dof", edit(TINY_ASF, A_HIP_DOF, "dof rx rx"), A_HIP_DOF, "twice"),
    (
        "unknown bone field",
        edit(TINY_ASF, A_HIP_DOF, "colour red"),
        A_HIP_DOF,
        "unknown bone field",
    ),
    (
        "hierarchy unknown child",
        edit(TINY_ASF, A_HIP_LINE, "hip shin"),
        A_HIP_LINE,
        "unknown bone 'shin'",
    ),
    (
        "hierarchy unknown parent",
        edit(TINY_ASF, A_HIP_LINE, "thigh knee"),
        A_HIP_LINE,
        "unknown bone 'thigh'",
    ),
    ("two parents", edit(TINY_ASF, A_HIP_LINE, "hip knee spine"), A_HIP_LINE, "two parents"),
    ("bone not in hierarchy", edit(TINY_ASF, A_HIP_LINE, ""), 25, "not in :hierarchy"),
    (
        "cycle",
        edit(edit(TINY_ASF, A_ROOT_LINE, "root spine"), A_HIP_LINE, "hip knee\n knee hip"),
        14,
        "not connected to root",
    ),
    ("hierarchy without end", edit(TINY_ASF, 44, ""), 45, ":hierarchy has no 'end'"),
    ("no hierarchy", TINY_ASF.split(":hierarchy")[0], None, "no :hierarchy"),
    ("no root section", TINY_ASF.replace(":root", ":rooot"), None, "no :root"),
]


@pytest.mark.parametrize(
    ("asf", "line", "message"),
    [case[1:] for case in ASF_REJECTIONS],
    ids=[case[0] for case in ASF_REJECTIONS],
)
def test_rejects_bad_asf(asf: str | bytes, line: int | None, message: str) -> None:
    with pytest.raises(ParseError) as raised:
        read_asf_amc(asf, TINY_AMC)
    assert message in str(raised.value)
    assert raised.value.source == "ASF"
    if line is not None:
        assert raised.value.line == line
        assert f"ASF, line {line}:" in str(raised.value)


AMC_REJECTIONS: list[tuple[str, str | bytes, int | None, str]] = [
    ("empty", "", None, "empty"),
    ("binary", b"\x00\x01\x02\x03", None, "NUL"),
    ("zero frames", ":FULLY-SPECIFIED\n:DEGREES\n", None, "no frames"),
    (
        "bone before frame number",
        TINY_AMC.replace("1\nroot", "root", 1),
        M_FIRST_FRAME,
        "expected a frame number",
    ),
    (
        "unknown bone",
        edit(TINY_AMC, M_HIP_2, "thigh 0 0 0"),
        M_HIP_2,
        "bone 'thigh' is not in the ASF",
    ),
    (
        "too few values",
        edit(TINY_AMC, M_HIP_2, "hip 0 0"),
        M_HIP_2,
        "needs 3 values (rx ry rz), found 2",
    ),
    (
        "too many values",
        edit(TINY_AMC, M_KNEE_1, "knee 1 2 3"),
        M_KNEE_1,
        "needs 2 values (rz rx), found 3",
    ),
    (
        "far too many values",
        edit(TINY_AMC, M_KNEE_1, "knee " + "1 " * 100),
        M_KNEE_1,
        "found more than 2",
    ),
    (
        "non-numeric value",
        edit(TINY_AMC, M_ROOT_2, "root 0 0 zero 0 0 0"),
        M_ROOT_2,
        "not a number",
    ),
    ("nan value", edit(TINY_AMC, M_ROOT_2, "root 0 0 nan 0 0 0"), M_ROOT_2, "finite"),
    ("overflowing value", edit(TINY_AMC, M_HIP_1, "hip 1e309 0 0"), M_HIP_1, "finite"),
    (
        "frame numbers jump",
        edit(TINY_AMC, M_SECOND_FRAME, "3"),
        M_SECOND_FRAME,
        "consecutive: expected 2, found 3",
    ),
    ("frame numbers repeat", edit(TINY_AMC, M_SECOND_FRAME, "1"), M_SECOND_FRAME, "consecutive"),
    (
        "bone missing from a frame",
        edit(TINY_AMC, M_KNEE_1, None),
        M_FIRST_FRAME,
        "frame 1 has no values for bone 'knee'",
    ),
    ("bone twice in a frame", edit(TINY_AMC, M_KNEE_1, "hip 1 2 3"), M_KNEE_1, "appears twice"),
    (
        "no-dof bone with values",
        edit(TINY_AMC, M_KNEE_2, "knee 0 0\nspine 1"),
        M_KNEE_2 + 1,
        "has no dof",
    ),
    (
        "frame number with text",
        edit(TINY_AMC, M_SECOND_FRAME, "2 x"),
        M_SECOND_FRAME,
        "frame number line has extra text",
    ),
]


@pytest.mark.parametrize(
    ("amc", "line", "message"),
    [case[1:] for case in AMC_REJECTIONS],
    ids=[case[0] for case in AMC_REJECTIONS],
)
def test_rejects_bad_amc(amc: str | bytes, line: int | None, message: str) -> None:
    with pytest.raises(ParseError) as raised:
        read_asf_amc(TINY_ASF, amc)
    assert message in str(raised.value)
    assert raised.value.source == "AMC"
    if line is not None:
        assert raised.value.line == line
        assert f"AMC, line {line}:" in str(raised.value)


@pytest.mark.parametrize("amc", [":FULLY-SPECIFIED\n:DEGREES\n", "# a comment\n:DEGREES\n#\n"])
def test_an_amc_without_frames_is_a_rig_without_animation(amc: str) -> None:
    with pytest.raises(NoAnimation, match="no animation") as raised:
        read_asf_amc(TINY_ASF, amc)
    assert raised.value.code == "no_animation" and raised.value.source == "AMC"


def test_a_last_frame_cut_short_is_dropped_with_a_warning() -> None:
    # A download cut in the last frame: the frames before it are whole.
    motion = read_asf_amc(TINY_ASF, TINY_AMC[: TINY_AMC.index("knee 0 0")])
    assert motion.frame_count == 1
    assert motion.notes["warnings"] == [
        f"the last frame (2, line {M_SECOND_FRAME}) was cut short: dropped"
    ]


# ------------------------------------------------------------------------------ limits


def chain_asf(bones: int) -> str:
    """An ASF whose bones form one chain ``bones`` long."""
    parts = [":units", "  length 1", ":root", "  order TX TY TZ RX RY RZ", ":bonedata"]
    for i in range(bones):
        parts += [
            "begin",
            f"name b{i}",
            "direction 0 1 0",
            "length 1",
            "axis 0 0 0 XYZ",
            "dof rz",
            "end",
        ]
    parts += [":hierarchy", "begin", "root b0"]
    parts += [f"b{i} b{i + 1}" for i in range(bones - 1)]
    parts += ["end"]
    return "\n".join(parts) + "\n"


def chain_amc(bones: int, frames: int = 1) -> str:
    lines = []
    for frame in range(1, frames + 1):
        lines += [str(frame), "root 0 0 0 0 0 0"] + [f"b{i} 1" for i in range(bones)]
    return "\n".join(lines) + "\n"


def test_deep_chain_without_recursion() -> None:
    bones = 5_000
    motion = read_asf_amc(
        chain_asf(bones), chain_amc(bones), limits=ParseLimits(max_depth=None, max_joints=None)
    )
    assert motion.skeleton.joint_count == bones + 2
    assert motion.skeleton.names[-1] == f"b{bones - 1}_end"


def test_depth_and_joint_limits() -> None:
    with pytest.raises(LimitExceeded, match="deeper"):
        read_asf_amc(chain_asf(300), chain_amc(300))
    with pytest.raises(LimitExceeded, match="joints"):
        read_asf_amc(chain_asf(50), chain_amc(50), limits=ParseLimits(max_joints=20))
    with pytest.raises(LimitExceeded, match="joints"):
        read_asf_amc(TINY_ASF, TINY_AMC, limits=ParseLimits(max_joints=5))
    assert read_asf_amc(TINY_ASF, TINY_AMC, limits=ParseLimits(max_joints=6)).frame_count == 2


def test_frame_and_value_limits() -> None:
    with pytest.raises(LimitExceeded, match="frames"):
        read_asf_amc(TINY_ASF, TINY_AMC, limits=ParseLimits(max_frames=1))
    with pytest.raises(LimitExceeded, match="values"):
        read_asf_amc(TINY_ASF, TINY_AMC, limits=ParseLimits(max_values=2 * 6 * 9 - 1))
    many = chain_amc(3, frames=50)
    with pytest.raises(LimitExceeded, match="frames"):
        read_asf_amc(chain_asf(3), many, limits=ParseLimits(max_frames=49))
    shuffled = many.replace("root 0 0 0 0 0 0\nb0 1", "b0 1\nroot 0 0 0 0 0 0")
    with pytest.raises(LimitExceeded, match="frames"):
        read_asf_amc(chain_asf(3), shuffled, limits=ParseLimits(max_frames=49))


def test_hostile_long_lines_are_refused() -> None:
    # No timing here (see tests/motion/test_bvh.py and bench/bench_hostile_parse.py).
    with pytest.raises(ParseError):
        read_asf_amc(TINY_ASF, edit(TINY_AMC, M_HIP_1, "hip " + "1 " * 5_000_000))
    with pytest.raises(ParseError):
        read_asf_amc(":units\n" + "mass " * 2_000_000, TINY_AMC)
    with pytest.raises(ParseError):
        read_asf_amc(TINY_ASF, "1\n" + "x" * 10_000_000)


@pytest.mark.parametrize("where", ["AMC value", "ASF length"])
def test_a_long_invalid_number_costs_the_same_whatever_its_length(
    monkeypatch: pytest.MonkeyPatch, where: str
) -> None:
    """A long run of digits then a letter, in an AMC value or an ASF number: refused by its
    length before the number pattern reads it (the pattern once backtracked quadratically)."""
    recorder = RecordingPattern(text_module.NUMBER_RE)
    monkeypatch.setattr(text_module, "NUMBER_RE", recorder)
    work = []
    for digits in (20_000, 200_000):
        recorder.lengths.clear()
        token = "1" * digits + "x"
        if where == "AMC value":
            asf, amc = TINY_ASF, edit(TINY_AMC, M_HIP_1, f"hip 5 {token} 7")
        else:
            asf, amc = TINY_ASF.replace("length 2\n", f"length {token}\n", 1), TINY_AMC
        with pytest.raises(ParseError, match="longer than 100 characters") as raised:
            read_asf_amc(asf, amc)
        assert len(str(raised.value)) < 300
        assert max(recorder.lengths, default=0) <= text_module.MAX_NUMBER_TOKEN
        work.append(sum(recorder.lengths))
    assert work[0] == work[1]


def test_the_line_pass_looks_at_the_clock(monkeypatch: pytest.MonkeyPatch) -> None:
    """An irregular AMC (bones in another order each frame) is read line by line, looking at
    the clock every few thousand lines: a deadline stops it inside the walk."""
    clock = Clock()
    monkeypatch.setattr(model_module.time, "monotonic", clock)
    frames = 30_000
    amc = "\n".join(
        f"{f}\n" + ("b0 1\nroot 0 0 0 0 0 0" if f % 2 else "root 0 0 0 0 0 0\nb0 1")
        for f in range(1, frames + 1)
    )
    assert read_asf_amc(chain_asf(1), amc, limits=ParseLimits(deadline=1e12)).frame_count == frames
    assert clock.looks >= 3 * frames // text_module.LINES_PER_CLOCK_CHECK
    clock.looks = 0
    with pytest.raises(DescribeTimeout):
        read_asf_amc(chain_asf(1), amc, limits=ParseLimits(deadline=5.0))
    assert clock.looks == 6  # stopped at the first look past the deadline


# ------------------------------------------------------------------------------ fuzzing


def _first_frames(amc_text: str, frames: int) -> str:
    cut = amc_text.index(f"\n{frames + 1}\r\n")
    return amc_text[: cut + 1]


_ASF_BASES = [TINY_ASF, fixture_text(CMU_ASF_FIXTURE)]
_AMC_BASES = {TINY_ASF: TINY_AMC, _ASF_BASES[1]: _first_frames(fixture_text(CMU_AMC_FIXTURE), 3)}
_TOKENS = [
    "",
    "0",
    "-1",
    "1e309",
    "nan",
    "begin",
    "end",
    "root",
    ":units",
    ":bonedata",
    ":hierarchy",
    "rx",
    "l",
    "XYZ",
    "length",
    "dof",
    "axis",
    "lfemur",
    "\t",
    "é",
    "#",
    "(",
    "99999999999999",
]


def _mutate(rng: random.Random, draw: st.DrawFn, text: str) -> str:
    lines = text.split("\n")
    for _ in range(rng.randint(1, 3)):
        if not lines:
            break
        i = rng.randrange(len(lines))
        operation = rng.choices(
            ["number", "delete", "duplicate", "replace", "token", "swap"], [4, 2, 2, 1, 2, 1]
        )[0]
        tokens = lines[i].split() or [""]
        if operation == "number":
            tokens[rng.randrange(len(tokens))] = f"{rng.uniform(-200, 200):.5g}"
            lines[i] = " ".join(tokens)
        elif operation == "delete":
            del lines[i]
        elif operation == "duplicate":
            lines.insert(i, lines[i])
        elif operation == "replace":
            lines[i] = draw(st.text(max_size=30))
        elif operation == "token":
            tokens[rng.randrange(len(tokens))] = draw(
                st.sampled_from(_TOKENS) | st.text(max_size=6)
            )
            lines[i] = " ".join(tokens)
        else:
            j = rng.randrange(len(lines))
            lines[i], lines[j] = lines[j], lines[i]
    return "\n".join(lines)


@st.composite
def mutated_pair(draw: st.DrawFn) -> tuple[bytes, bytes]:
    """A real (or tiny) ASF + AMC pair with a few lines or tokens of one or both edited."""
    rng = random.Random(draw(st.integers(0, 2**32 - 1)))
    asf = draw(st.sampled_from(_ASF_BASES))
    amc = _AMC_BASES[asf]
    target = rng.choice(["asf", "amc", "both"])
    if target in ("asf", "both"):
        asf = _mutate(rng, draw, asf)
    if target in ("amc", "both"):
        amc = _mutate(rng, draw, amc)
    encoded = [asf.encode("utf-8", "surrogatepass"), amc.encode("utf-8", "surrogatepass")]
    k = rng.randrange(2)
    if rng.random() < 0.15:
        encoded[k] = encoded[k][: rng.randint(0, len(encoded[k]))]
    if rng.random() < 0.1:
        position = rng.randint(0, len(encoded[k]))
        encoded[k] = (
            encoded[k][:position] + draw(st.binary(min_size=1, max_size=6)) + encoded[k][position:]
        )
    return encoded[0], encoded[1]


def _read_or_reject(asf: bytes | str, amc: bytes | str) -> None:
    try:
        motion = read_asf_amc(asf, amc, limits=ParseLimits(max_frames=10_000, max_joints=500))
    except (ParseError, LimitExceeded):
        return
    assert_consistent(motion)


@settings(
    max_examples=300,
    deadline=2000,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
@given(mutated_pair())
def test_fuzzed_real_files_parse_or_raise_parse_error(pair: tuple[bytes, bytes]) -> None:
    _read_or_reject(*pair)


@settings(max_examples=150, deadline=1000, database=None)
@given(st.one_of(st.binary(max_size=200), st.text(max_size=200)), st.booleans())
def test_random_input_parses_or_raises_parse_error(data: bytes | str, as_asf: bool) -> None:
    if as_asf:
        _read_or_reject(data, TINY_AMC)
    else:
        _read_or_reject(TINY_ASF, data)


# ------------------------------------------------------------------------------ shared data


def _trials(root: Path) -> list[tuple[Path, Path]]:
    trials = []
    for amc in sorted((root / "cmu" / "asf-amc").rglob("*.amc")):
        trials.append((amc.parent / f"{amc.parent.name}.asf", amc))
    return trials


@pytest.mark.slow
def test_every_shared_amc_parses_with_its_asf(motion_data: Path) -> None:
    trials = _trials(motion_data)
    assert len(trials) >= 52
    skeletons: dict[Path, bytes] = {}
    for asf, amc in trials:
        asf_bytes = skeletons.setdefault(asf, asf.read_bytes())
        amc_bytes = amc.read_bytes()
        motion = read_asf_amc(asf_bytes, amc_bytes)
        assert motion.frame_count == frame_lines(amc_bytes.decode()), amc.name
        assert motion.frame_time == pytest.approx(1 / 120)
        assert motion.skeleton.joint_count == 38, amc.name
        assert np.isfinite(motion.local_rotations).all(), amc.name
        assert np.isfinite(motion.root_translation).all(), amc.name


@pytest.mark.slow
@pytest.mark.parametrize("trial", ["02_01", "01_09", "03_02"])
def test_amc_matches_motionbuilder_bvh(motion_data: Path, trial: str) -> None:
    subject = trial.split("_")[0]
    folder = motion_data / "cmu"
    amc = read_asf_amc(
        (folder / "asf-amc" / subject / f"{subject}.asf").read_bytes(),
        (folder / "asf-amc" / subject / f"{trial}.amc").read_bytes(),
    )
    bvh = read_bvh((folder / "bvh-mb" / subject / f"{trial}.bvh").read_bytes())
    assert_matches_motionbuilder(amc.slice_frames(0, 1500), bvh.slice_frames(0, 1501))


@pytest.mark.slow
def test_amc_matches_3dsmax_bvh(motion_data: Path) -> None:
    folder = motion_data / "cmu"
    amc = read_asf_amc(
        (folder / "asf-amc" / "131" / "131.asf").read_bytes(),
        (folder / "asf-amc" / "131" / "131_01.amc").read_bytes(),
    )
    bvh = read_bvh((folder / "bvh-max" / "131_01.bvh").read_bytes())
    assert bvh.frame_count == amc.frame_count  # no added T-pose in this conversion
    amc_positions = world_positions(amc) * 0.45
    bvh_positions = world_positions(bvh)
    for amc_joint, bvh_joint in [
        ("root", "Hips"),
        ("lfemur", "LeftHip"),
        ("ltibia", "LeftKnee"),
        ("rfoot", "RightAnkle"),
    ]:
        np.testing.assert_allclose(
            amc_positions[:, amc.skeleton.index(amc_joint)],
            bvh_positions[:, bvh.skeleton.index(bvh_joint)],
            atol=1e-3,
            err_msg=f"{amc_joint} vs {bvh_joint}",
        )


def _with_commas(text: str) -> str:
    return re.sub(r"(\d)\.(\d)", r"\1,\2", text)


@pytest.mark.parametrize("which", ["both", "amc", "asf"])
def test_numbers_with_decimal_commas_are_read_as_decimal_points(which: str) -> None:
    """A tool under a European locale writes 12,5: the CMU trial so written reads as it is
    with points, and the warnings say which file was read so."""
    asf, amc = fixture_text(CMU_ASF_FIXTURE), fixture_text(CMU_AMC_FIXTURE)
    plain = read_asf_amc(asf, amc)
    if which in ("both", "asf"):
        asf = _with_commas(asf)
    if which in ("both", "amc"):
        amc = _with_commas(amc)
    assert (which == "amc" or asf.count(",") > 200) and (which == "asf" or amc.count(",") > 1000)
    motion = read_asf_amc(asf, amc)
    np.testing.assert_array_equal(motion.skeleton.offsets, plain.skeleton.offsets)
    np.testing.assert_array_equal(motion.local_rotations, plain.local_rotations)
    np.testing.assert_array_equal(motion.root_translation, plain.root_translation)
    said = [w.split(":")[0] for w in motion.notes["warnings"] if "decimal commas" in w]
    assert said == {"both": ["ASF", "AMC"], "amc": ["AMC"], "asf": ["ASF"]}[which]


def test_a_comma_beside_decimal_points_is_still_not_a_number() -> None:
    amc = fixture_text(CMU_AMC_FIXTURE)
    first = re.search(r"(?m)^lfemur (\S+)", amc)
    assert first is not None and "." in first[1]
    amc = amc[: first.start(1)] + first[1].replace(".", ",") + amc[first.end(1) :]
    with pytest.raises(ParseError, match=r"AMC.*is not a number"):
        read_asf_amc(fixture_text(CMU_ASF_FIXTURE), amc)


def test_numpy_s_reader_is_given_ascii_lines_only(monkeypatch: pytest.MonkeyPatch) -> None:
    """A fuzzed AMC with characters beyond the BMP in its frame lines crashed the process
    inside ``np.loadtxt`` (a segmentation fault about once in 60,000 reads; numpy 2.4.6), and
    AMC is read in the server's own process. Such lines now take the line-by-line pass: the
    same clip with a frame number followed by such a character is refused, naming the
    line."""
    given_text: list[str] = []
    loadtxt = np.loadtxt

    def watched(lines, *args, **kwargs):  # type: ignore[no-untyped-def]
        given_text.extend(lines)
        return loadtxt(lines, *args, **kwargs)

    monkeypatch.setattr(amc_module.np, "loadtxt", watched)
    amc = re.sub(r"(?m)^3(\r?)$", "3\U000988a7\\1", fixture_text(CMU_AMC_FIXTURE), count=1)
    assert "\U000988a7" in amc
    with pytest.raises(ParseError) as refused:
        read_asf_amc(fixture_bytes(CMU_ASF_FIXTURE), amc.encode("utf-8"))
    assert refused.value.line is not None
    assert all(line.isascii() for line in given_text)
    read_asf_amc(fixture_bytes(CMU_ASF_FIXTURE), fixture_bytes(CMU_AMC_FIXTURE))
    assert given_text  # the fast path still reads a real file
