"""BVH reader: real files, conventions, every rejection case, limits and fuzzing."""

from __future__ import annotations

import itertools
import random
import re
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from app.errors import DescribeTimeout, LimitExceeded, NoAnimation, ParseError
from app.motion import model as model_module
from app.motion.formats import bvh as bvh_module
from app.motion.formats import read_bvh
from app.motion.formats import text as text_module
from app.motion.formats.bvh import matrices_from_euler
from app.motion.model import Motion, ParseLimits
from tests.motion.conftest import (
    BANDAI_FIXTURE,
    CMU_BVH_FIXTURE,
    assert_consistent,
    fixture_bytes,
    fixture_text,
    world_positions,
)
from tests.motion.shared import data_folder
from tests.motion.work import Clock, RecordingPattern

# Line numbers matter: the rejection tests below edit this text by line.
TINY = """\
HIERARCHY
ROOT Hips
{
  OFFSET 1 2 3
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Chest
  {
    OFFSET 0 10 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 5 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.04
0 90 0 10 20 30 40 50 60
1 91 2 0 0 0 0 0 90
"""
# line numbers of TINY
L_ROOT, L_JOINT, L_CHEST_OFFSET, L_CHEST_CHANNELS, L_END_SITE = 2, 6, 8, 9, 10
L_CLOSE_CHEST, L_CLOSE_ROOT, L_MOTION, L_FRAMES, L_FRAME_TIME = 14, 15, 16, 17, 18
L_FRAME_1, L_FRAME_2 = 19, 20


def edit(text: str, line: int, new: str | None) -> str:
    """``text`` with 1-based ``line`` replaced by ``new`` (deleted when ``None``)."""
    lines = text.split("\n")
    if new is None:
        del lines[line - 1]
    else:
        lines[line - 1] = new
    return "\n".join(lines)


def cut_after(text: str, line: int) -> str:
    """The first ``line`` lines of ``text``."""
    return "\n".join(text.split("\n")[:line]) + "\n"


def chain_bvh(depth: int, frames: int = 1) -> str:
    """A BVH whose joints are nested ``depth`` deep (one rotation channel each)."""
    parts = ["HIERARCHY"]
    for level in range(depth):
        parts.append(f"{'ROOT' if level == 0 else 'JOINT'} j{level}")
        parts.append("{")
        parts.append("OFFSET 0 1 0")
        parts.append("CHANNELS 1 Zrotation")
    parts.extend("}" * depth)
    parts += ["MOTION", f"Frames: {frames}", "Frame Time: 0.01"]
    parts += [" ".join(["1"] * depth)] * frames
    return "\n".join(parts) + "\n"


def header_counts(text: str) -> tuple[int, float]:
    frames = re.search(r"Frames:\s*(\d+)", text)
    frame_time = re.search(r"Frame Time:\s*(\S+)", text)
    assert frames is not None and frame_time is not None
    return int(frames.group(1)), float(frame_time.group(1))


# ------------------------------------------------------------------------------ conventions


def test_tiny_file_reads_every_number_where_it_belongs() -> None:
    motion = read_bvh(TINY)
    assert_consistent(motion)
    skeleton = motion.skeleton
    assert skeleton.names == ("Hips", "Chest", "Chest_end")
    np.testing.assert_array_equal(skeleton.parents, [-1, 0, 1])
    np.testing.assert_array_equal(skeleton.end_site, [False, False, True])
    np.testing.assert_array_equal(skeleton.offsets, [[1, 2, 3], [0, 10, 0], [0, 5, 0]])
    assert motion.frame_count == 2
    assert motion.frame_time == pytest.approx(0.04)
    assert motion.source_format == "bvh"
    # root position channels replace the root OFFSET
    np.testing.assert_array_equal(motion.root_translation, [[0, 90, 0], [1, 91, 2]])
    assert motion.local_translations is None
    # intrinsic in the listed order: Zrotation Xrotation Yrotation -> "ZXY"
    expected_root = Rotation.from_euler("ZXY", [10, 20, 30], degrees=True).as_matrix()
    expected_chest = Rotation.from_euler("ZXY", [40, 50, 60], degrees=True).as_matrix()
    np.testing.assert_allclose(motion.local_rotations[0, 0], expected_root, atol=1e-12)
    np.testing.assert_allclose(motion.local_rotations[0, 1], expected_chest, atol=1e-12)
    np.testing.assert_allclose(
        motion.local_rotations[1, 1],
        np.eye(3)[[0, 1, 2]] @ Rotation.from_euler("Y", 90, degrees=True).as_matrix(),
        atol=1e-12,
    )
    np.testing.assert_array_equal(
        motion.local_rotations[:, 2], np.broadcast_to(np.eye(3), (2, 3, 3))
    )


@pytest.mark.parametrize(
    "channels",
    [
        "Xrotation Yrotation Zrotation",
        "Yrotation Zrotation Xrotation",
        "Zrotation Yrotation Xrotation",
    ],
)
def test_rotation_order_is_intrinsic_in_listed_order(channels: str) -> None:
    text = edit(TINY, L_CHEST_CHANNELS, f"CHANNELS 3 {channels}")
    motion = read_bvh(text)
    sequence = "".join(name[0] for name in channels.split())
    expected = Rotation.from_euler(sequence, [40, 50, 60], degrees=True).as_matrix()
    np.testing.assert_allclose(motion.local_rotations[0, 1], expected, atol=1e-12)


def test_channels_in_any_count_and_order_with_position_channels_on_a_joint() -> None:
    text = edit(TINY, L_CHEST_CHANNELS, "CHANNELS 2 Yposition Xrotation")
    text = edit(text, 5, "CHANNELS 1 Zrotation")
    text = edit(text, L_FRAME_1, "30 7 45")
    text = edit(text, L_FRAME_2, "0 -1 0")
    motion = read_bvh(text)
    # root without position channels keeps its OFFSET every frame
    np.testing.assert_array_equal(motion.root_translation, [[1, 2, 3], [1, 2, 3]])
    np.testing.assert_allclose(
        motion.local_rotations[0, 0], Rotation.from_euler("Z", 30, degrees=True).as_matrix()
    )
    np.testing.assert_allclose(
        motion.local_rotations[0, 1], Rotation.from_euler("X", 45, degrees=True).as_matrix()
    )
    # a partial position channel replaces only its component of the offset
    assert motion.local_translations is not None
    np.testing.assert_array_equal(motion.local_translations[:, 1], [[0, 7, 0], [0, -1, 0]])
    np.testing.assert_array_equal(motion.local_translations[:, 2], [[0, 5, 0], [0, 5, 0]])
    np.testing.assert_array_equal(motion.local_translations[:, 0], motion.root_translation)


def test_joint_without_channels_and_extra_end_site_names_stay_unique() -> None:
    text = TINY.replace(
        "    End Site\n    {\n      OFFSET 0 5 0\n    }\n",
        "    End Site\n    {\n      OFFSET 0 5 0\n    }\n"
        "    End Site\n    {\n      OFFSET 0 6 0\n    }\n"
        "    JOINT Chest_end\n    {\n      OFFSET 1 0 0\n    }\n",
    )
    motion = read_bvh(text)
    assert motion.skeleton.names == ("Hips", "Chest", "Chest_end2", "Chest_end3", "Chest_end")
    np.testing.assert_array_equal(motion.skeleton.end_site, [False, False, True, True, False])
    np.testing.assert_array_equal(
        motion.local_rotations[:, 4], np.broadcast_to(np.eye(3), (2, 3, 3))
    )


@pytest.mark.parametrize("length", [1, 2, 3])
def test_matrices_from_euler_matches_scipy(length: int) -> None:
    rng = np.random.default_rng(length)
    angles = rng.uniform(-np.pi, np.pi, size=(7, 5, length))
    for axes in itertools.product("XYZ", repeat=length):
        sequence = "".join(axes)
        if any(a == b for a, b in itertools.pairwise(sequence)):
            continue  # scipy refuses consecutive repeats
        for seq in (sequence, sequence.lower()):
            expected = Rotation.from_euler(seq, angles.reshape(-1, length)).as_matrix()
            got = matrices_from_euler(seq, angles)
            assert got.shape == (7, 5, 3, 3)
            np.testing.assert_allclose(got.reshape(-1, 3, 3), expected, atol=1e-12, err_msg=seq)


def test_matrices_from_euler_in_a_frame_matches_matrix_products() -> None:
    rng = np.random.default_rng(3)
    angles = rng.uniform(-np.pi, np.pi, size=(11, 4, 3))
    frames = Rotation.random(4, random_state=5).as_matrix()  # one per column of the batch
    for sequence in ("xyz", "ZXY", "zx", "y"):
        k = len(sequence)
        plain = matrices_from_euler(sequence, angles[..., :k])
        expected = frames @ plain @ np.swapaxes(frames, -1, -2)
        got = matrices_from_euler(sequence, angles[..., :k], frames=frames)
        np.testing.assert_allclose(got, expected, atol=1e-12, err_msg=sequence)


def test_text_variants_read_the_same() -> None:
    original = fixture_text(BANDAI_FIXTURE)
    reference = read_bvh(original)
    header, _, block = original.partition("Frame Time:\t0.0333333\n")
    lines = block.rstrip("\n").split("\n")
    exponent = " ".join(f"{float(v):.10e}" for v in lines[0].split())
    variants = {
        "crlf": original.replace("\n", "\r\n"),
        "old mac cr": original.replace("\n", "\r"),
        "mixed crlf and lf": original.replace("\n", "\r\n", 150),
        "tabs": original.replace(" ", "\t"),
        "scientific": header
        + "Frame Time:\t0.0333333\n"
        + "\n".join([exponent, *lines[1:]])
        + "\n",
        "trailing blank lines": original + "\n\n  \n\t\n",
        "no final newline": original.rstrip("\n"),
        "bom bytes": "\ufeff".encode() + original.encode(),
        "bom str": "\ufeff" + original,
        "blank lines inside the frame block": original.replace(lines[5] + "\n", lines[5] + "\n\n"),
    }
    for name, text in variants.items():
        motion = read_bvh(text)
        assert motion.skeleton.names == reference.skeleton.names, name
        np.testing.assert_allclose(motion.local_rotations, reference.local_rotations, err_msg=name)
        np.testing.assert_allclose(motion.root_translation, reference.root_translation)


# ------------------------------------------------------------------------------ real fixtures


def test_bandai_fixture_reads_position_channels_on_every_joint() -> None:
    text = fixture_text(BANDAI_FIXTURE)
    motion = read_bvh(fixture_bytes(BANDAI_FIXTURE))
    assert_consistent(motion)
    skeleton = motion.skeleton
    assert (motion.frame_count, motion.frame_time) == header_counts(text)
    assert skeleton.names[:3] == ("joint_Root", "Hips", "Spine")
    assert skeleton.end_site.sum() == text.count("End Site")
    assert motion.local_translations is not None

    first_frame = np.array(text.split("Frame Time:\t0.0333333\n")[1].split("\n")[0].split(), float)
    # 6 channels per non-end joint: X Y Z position then Z X Y rotation
    per_joint = first_frame.reshape(-1, 6)
    channel_joints = np.flatnonzero(~skeleton.end_site)
    np.testing.assert_array_equal(motion.root_translation[0], per_joint[0, :3])
    np.testing.assert_array_equal(
        motion.local_translations[0, channel_joints[1:]], per_joint[1:, :3]
    )
    np.testing.assert_allclose(
        motion.local_rotations[0, channel_joints],
        Rotation.from_euler("ZXY", per_joint[:, 3:], degrees=True).as_matrix(),
        atol=1e-12,
    )
    # Bandai position values below Hips repeat the OFFSETs: they replace, not add to, them
    below_hips = channel_joints[2:]
    np.testing.assert_allclose(
        motion.local_translations[:, below_hips],
        np.broadcast_to(skeleton.offsets[below_hips], (motion.frame_count, len(below_hips), 3)),
        atol=1e-4,
    )


def test_bandai_fixture_bone_lengths_stay_constant() -> None:
    motion = read_bvh(fixture_bytes(BANDAI_FIXTURE))
    _assert_rigid_bones(motion)


def _assert_rigid_bones(motion: Motion) -> None:
    positions = world_positions(motion)
    parents = motion.skeleton.parents
    lengths = np.linalg.norm(positions[:, 2:] - positions[:, parents[2:]], axis=-1)
    # joints below Hips: constant over frames and equal to the OFFSET lengths
    np.testing.assert_allclose(lengths, lengths[:1].repeat(len(lengths), axis=0), atol=1e-4)
    np.testing.assert_allclose(
        lengths[0], np.linalg.norm(motion.skeleton.offsets[2:], axis=-1), atol=1e-4
    )
    # a real person in centimetres, Y up: the head gets well above the feet
    names = motion.skeleton.names
    head, foot = names.index("Head"), names.index("Foot_L")
    assert 120 < np.max(positions[:, head, 1] - positions[:, foot, 1]) < 250


def test_cmu_motionbuilder_fixture_has_only_root_positions() -> None:
    text = fixture_text(CMU_BVH_FIXTURE)
    motion = read_bvh(text)
    assert_consistent(motion)
    assert (motion.frame_count, motion.frame_time) == header_counts(text)
    assert motion.local_translations is None
    assert motion.skeleton.joint_count == 31 + 7  # 31 joints + 7 End Sites
    # first frame is the converter's T-pose: no root rotation, translation as in the file
    np.testing.assert_allclose(motion.local_rotations[0, 0], np.eye(3))
    np.testing.assert_allclose(motion.root_translation[0], [10.4194, 16.7048, -30.1003])


# ------------------------------------------------------------------------------ rejections

REJECTIONS: list[tuple[str, str | bytes, type[Exception], int | None, str]] = [
    ("empty bytes", b"", ParseError, None, "empty"),
    ("only whitespace", " \n\t\r\n", ParseError, None, "empty"),
    ("not a BVH", "hello world\nthis is text\n", ParseError, 1, "not a BVH"),
    ("binary NUL bytes", b"HIERARCHY\x00\x01\x02", ParseError, None, "NUL"),
    ("UTF-16 that is not", b"\xff\xfeH\x00\x00\xd8", ParseError, None, "says UTF-16"),
    ("no ROOT", "HIERARCHY\n\n", ParseError, None, "no ROOT"),
    (
        "truncated hierarchy (EOF)",
        cut_after(TINY, L_CHEST_CHANNELS),
        ParseError,
        L_CHEST_CHANNELS,
        "truncated",
    ),
    ("unbalanced braces", edit(TINY, L_CLOSE_CHEST, None), ParseError, L_MOTION - 1, "truncated"),
    ("extra closing brace", edit(TINY, L_CLOSE_ROOT, "}\n}"), ParseError, 16, "expected MOTION"),
    ("joint with no name", edit(TINY, L_JOINT, "  JOINT"), ParseError, L_JOINT, "without a name"),
    ("root with no name", edit(TINY, L_ROOT, "ROOT"), ParseError, L_ROOT, "without a name"),
    ("duplicate joint names", edit(TINY, L_JOINT, "JOINT Hips"), ParseError, L_JOINT, "duplicate"),
    (
        "OFFSET count",
        edit(TINY, L_CHEST_OFFSET, "OFFSET 0 10"),
        ParseError,
        L_CHEST_OFFSET,
        "3 numbers",
    ),
    (
        "OFFSET text",
        edit(TINY, L_CHEST_OFFSET, "OFFSET 0 ten 0"),
        ParseError,
        L_CHEST_OFFSET,
        "not a number",
    ),
    (
        "OFFSET nan",
        edit(TINY, L_CHEST_OFFSET, "OFFSET 0 nan 0"),
        ParseError,
        L_CHEST_OFFSET,
        "finite",
    ),
    ("no OFFSET", edit(TINY, L_CHEST_OFFSET, ""), ParseError, L_CLOSE_CHEST, "no OFFSET"),
    (
        "CHANNELS count disagrees",
        edit(TINY, L_CHEST_CHANNELS, "CHANNELS 2 Zrotation Xrotation Yrotation"),
        ParseError,
        L_CHEST_CHANNELS,
        "says 2 but lists 3",
    ),
    (
        "CHANNELS count missing",
        edit(TINY, L_CHEST_CHANNELS, "CHANNELS Zrotation"),
        ParseError,
        L_CHEST_CHANNELS,
        "count",
    ),
    (
        "unknown channel",
        edit(TINY, L_CHEST_CHANNELS, "CHANNELS 3 Zrotation Xrotation Wrotation"),
        ParseError,
        L_CHEST_CHANNELS,
        "unknown channel",
    ),
    (
        "repeated channel",
        edit(TINY, L_CHEST_CHANNELS, "CHANNELS 3 Zrotation Zrotation Yrotation"),
        ParseError,
        L_CHEST_CHANNELS,
        "twice",
    ),
    (
        "End Site with CHANNELS",
        edit(TINY, 12, "OFFSET 0 5 0 CHANNELS 1 Xrotation"),
        ParseError,
        12,
        "3 numbers",
    ),
    (
        "unknown keyword",
        edit(TINY, L_CHEST_OFFSET, "OFSET 0 10 0"),
        ParseError,
        L_CHEST_OFFSET,
        "unknown keyword",
    ),
    ("no brace after JOINT", edit(TINY, 7, "OFFSET 0 0 0"), ParseError, 7, "expected '{'"),
    (
        "JOINT after the root closed",
        edit(TINY, L_CLOSE_ROOT, "}\nJOINT Late"),
        ParseError,
        16,
        "expected MOTION",
    ),
    (
        "a ROOT inside a joint",
        edit(TINY, L_JOINT, "ROOT Other"),
        ParseError,
        L_JOINT,
        "a ROOT inside the joint 'Hips'",
    ),
    ("MOTION missing", cut_after(TINY, L_CLOSE_ROOT), NoAnimation, None, "no MOTION section"),
    (
        "MOTION missing, hierarchy open",
        cut_after(TINY, L_CLOSE_CHEST),
        ParseError,
        None,
        "truncated",
    ),
    ("Frames missing", edit(TINY, L_FRAMES, None), ParseError, L_FRAMES, "Frames:"),
    (
        "Frames not an integer",
        edit(TINY, L_FRAMES, "Frames: 2.5"),
        ParseError,
        L_FRAMES,
        "whole number",
    ),
    ("Frames zero", edit(TINY, L_FRAMES, "Frames: 0"), NoAnimation, L_FRAMES, "no animation"),
    ("Frames negative", edit(TINY, L_FRAMES, "Frames: -3"), ParseError, L_FRAMES, "at least 1"),
    ("Frames empty", edit(TINY, L_FRAMES, "Frames:"), ParseError, L_FRAMES, "whole number"),
    ("Frame Time missing", edit(TINY, L_FRAME_TIME, None), ParseError, L_FRAME_TIME, "Frame Time"),
    (
        "Frame Time zero",
        edit(TINY, L_FRAME_TIME, "Frame Time: 0"),
        ParseError,
        L_FRAME_TIME,
        "greater than 0",
    ),
    (
        "Frame Time negative",
        edit(TINY, L_FRAME_TIME, "Frame Time: -0.01"),
        ParseError,
        L_FRAME_TIME,
        "greater than 0",
    ),
    (
        "Frame Time nan",
        edit(TINY, L_FRAME_TIME, "Frame Time: nan"),
        ParseError,
        L_FRAME_TIME,
        "finite",
    ),
    (
        "Frame Time overflow",
        edit(TINY, L_FRAME_TIME, "Frame Time: 1e309"),
        ParseError,
        L_FRAME_TIME,
        "finite",
    ),
    (
        "Frame Time absurd",
        edit(TINY, L_FRAME_TIME, "Frame Time: 11"),
        ParseError,
        L_FRAME_TIME,
        "absurd",
    ),
    (
        "Frame Time text",
        edit(TINY, L_FRAME_TIME, "Frame Time: fast"),
        ParseError,
        L_FRAME_TIME,
        "not a number",
    ),
    (
        # The last frame cut short is dropped, but 1 of 2 frames is too few.
        "too few values",
        edit(TINY, L_FRAME_2, "1 91 2 0 0 0 0 0"),
        ParseError,
        L_FRAMES,
        "has 8 values, expected 9",
    ),
    (
        "too many values",
        edit(TINY, L_FRAME_1, "0 90 0 10 20 30 40 50 60 70"),
        ParseError,
        L_FRAME_1,
        "has 10 values, more than the 9 channels",
    ),
    (
        "non-numeric value",
        edit(TINY, L_FRAME_2, "1 91 2 0 x 0 0 0 90"),
        ParseError,
        L_FRAME_2,
        "value 5",
    ),
    (
        "value with a comma",
        edit(TINY, L_FRAME_2, "1 91 2 0 0,5 0 0 0 90"),
        ParseError,
        L_FRAME_2,
        "not a number",
    ),
    (
        # nan is a missing value; a channel missing in every frame cannot be filled in.
        "nan in every frame",
        edit(
            edit(TINY, L_FRAME_1, "0 90 0 10 nan 30 40 50 60"), L_FRAME_2, "1 91 2 0 nan 0 0 0 90"
        ),
        ParseError,
        None,
        "too little data",
    ),
    (
        "inf value",
        edit(TINY, L_FRAME_2, "1 91 2 0 0 0 0 -inf 90"),
        ParseError,
        L_FRAME_2,
        "not finite",
    ),
    (
        "overflowing value",
        edit(TINY, L_FRAME_2, "1 91 2 0 0 0 0 1e309 90"),
        ParseError,
        L_FRAME_2,
        "not finite",
    ),
    (
        "fewer frame lines than Frames:",
        edit(TINY, L_FRAMES, "Frames: 3"),
        ParseError,
        L_FRAMES,
        "Frames: says 3 but the file has 2 complete frame lines",
    ),
    (
        "no frame lines",
        cut_after(TINY, L_FRAME_TIME),
        ParseError,
        L_FRAMES,
        "has 0 complete frame lines",
    ),
    (
        "no channels at all",
        re.sub(r"CHANNELS .*", "CHANNELS 0", TINY),
        ParseError,
        None,
        "no CHANNELS",
    ),
]


@pytest.mark.parametrize(
    ("data", "error", "line", "message"),
    [case[1:] for case in REJECTIONS],
    ids=[case[0] for case in REJECTIONS],
)
def test_rejects_bad_input(
    data: str | bytes, error: type[Exception], line: int | None, message: str
) -> None:
    with pytest.raises(error) as raised:
        read_bvh(data)
    assert message in str(raised.value)
    if line is not None:
        assert isinstance(raised.value, ParseError)
        assert raised.value.line == line
        assert f"line {line}" in str(raised.value)


def test_a_rig_without_animation_is_refused_as_a_rig() -> None:
    """``Frames: 0``, or a whole hierarchy and no MOTION section: a rig, not a damaged file."""
    for text in (edit(TINY, L_FRAMES, "Frames: 0"), cut_after(TINY, L_CLOSE_ROOT)):
        with pytest.raises(NoAnimation, match="rig with no animation") as raised:
            read_bvh(text)
        assert raised.value.code == "no_animation"
        assert "a skeleton of 3 joints" in raised.value.detail


@pytest.mark.parametrize(
    ("folder", "name"),
    [
        ("wild-bvh", "perception-neuron/pns_template.bvh"),
        ("wild-more", "bvh-misc/g7199_template.bvh"),
        ("wild-more", "bvh-misc/g7199_output.bvh"),
    ],
)
def test_real_rig_only_files_are_refused_as_rigs(folder: str, name: str) -> None:
    with pytest.raises(NoAnimation, match="Frames: 0"):
        read_bvh((data_folder(folder) / name).read_bytes())


@pytest.mark.parametrize("newline", ["\r\n", "\r"])
def test_line_numbers_count_any_line_end(newline: str) -> None:
    text = edit(TINY, L_FRAME_2, "1 91 2 0 x 0 0 0 90").replace("\n", newline)
    with pytest.raises(ParseError) as raised:
        read_bvh(text)
    assert raised.value.line == L_FRAME_2


def test_a_last_frame_cut_short_is_dropped_with_a_warning() -> None:
    text = fixture_text(BANDAI_FIXTURE)
    cut = text[: len(text) - 500]  # mid-way through the last frame line (a download cut)
    motion = read_bvh(cut)
    assert motion.frame_count == 39
    assert motion.notes["warnings"] == [
        f"the last frame (line {cut.count(chr(10)) + 1}) was cut short: dropped"
    ]


def test_a_middle_frame_cut_short_is_damage_named_by_its_line() -> None:
    lines = fixture_text(BANDAI_FIXTURE).split("\n")
    middle = lines.index("MOTION") + 3 + 20
    lines[middle] = " ".join(lines[middle].split()[:-4])
    with pytest.raises(ParseError, match="values, expected") as raised:
        read_bvh("\n".join(lines))
    assert raised.value.line == middle + 1


def test_frames_is_a_claim_not_a_contract() -> None:
    # More complete lines than declared: the declared count, the rest ignored.
    motion = read_bvh(edit(TINY, L_FRAMES, "Frames: 1"))
    assert motion.frame_count == 1
    assert motion.notes["warnings"] == ["1 line after the 1 frames that Frames: declares ignored"]
    # Fewer: accepted down to 90 % of the claim (Bandai's 40 frames declared as 44).
    text = re.sub(r"Frames:\s*40", "Frames: 44", fixture_text(BANDAI_FIXTURE))
    motion = read_bvh(text)
    assert motion.frame_count == 40
    assert "Frames: says 44 but the file has 40 complete frames" in motion.notes["warnings"][0]
    with pytest.raises(ParseError, match="says 45 but the file has 40 complete frame lines"):
        read_bvh(text.replace("Frames: 44", "Frames: 45"))


def test_short_lines_a_tool_appended_are_ignored() -> None:
    motion = read_bvh(TINY + "0 0\n1\n")
    assert motion.frame_count == 2
    assert motion.notes["warnings"] == ["2 short lines after the last frame ignored"]


def test_nan_values_are_missing_data_filled_from_neighbours() -> None:
    text = TINY + "2 92 4 0 0 0 0 0 90\n"
    text = edit(edit(text, L_FRAMES, "Frames: 3"), L_FRAME_2, "1 91 nan 0 0 0 0 0 90")
    motion = read_bvh(text)
    np.testing.assert_allclose(motion.root_translation[:, 2], [0.0, 2.0, 4.0])
    assert "filled in" in motion.notes["warnings"][0]


@pytest.mark.parametrize("written", ["1.#QNAN0", "-1.#IND00", "1.#SNAN", "-1.#ind"])
def test_nan_as_old_msvc_runtimes_print_it_is_missing_data_too(written: str) -> None:
    text = TINY + "2 92 4 0 0 0 0 0 90\n"
    text = edit(edit(text, L_FRAMES, "Frames: 3"), L_FRAME_2, f"1 91 {written} 0 0 0 0 0 90")
    motion = read_bvh(text)
    np.testing.assert_allclose(motion.root_translation[:, 2], [0.0, 2.0, 4.0])
    assert "filled in" in motion.notes["warnings"][0]


def test_infinity_as_old_msvc_runtimes_print_it_is_still_damage() -> None:
    with pytest.raises(ParseError, match=r"'1\.#INF00', is not a number"):
        read_bvh(edit(TINY, L_FRAME_2, "1 91 1.#INF00 0 0 0 0 0 90"))


# ------------------------------------------------------------------------------ limits


def test_depth_limit() -> None:
    with pytest.raises(LimitExceeded, match="deeper than the limit of 256"):
        read_bvh(chain_bvh(300))
    assert read_bvh(chain_bvh(300), limits=ParseLimits(max_depth=300)).skeleton.joint_count == 300


def test_very_deep_hierarchy_does_not_recurse() -> None:
    depth = 20_000  # far past Python's recursion limit
    motion = read_bvh(chain_bvh(depth), limits=ParseLimits(max_depth=None, max_joints=None))
    assert motion.skeleton.joint_count == depth
    assert motion.skeleton.parents[-1] == depth - 2


def test_joint_limit_counts_end_sites() -> None:
    with pytest.raises(LimitExceeded, match="limit of 2"):
        read_bvh(TINY, limits=ParseLimits(max_joints=2))
    assert read_bvh(TINY, limits=ParseLimits(max_joints=3)).skeleton.joint_count == 3


def test_frame_limit_is_checked_before_reading_frames(monkeypatch: pytest.MonkeyPatch) -> None:
    def never(*args: object, **kwargs: object) -> None:
        raise AssertionError("the frames were read although the header is over the limit")

    monkeypatch.setattr(bvh_module, "read_frames", never)
    with pytest.raises(LimitExceeded, match="frames"):
        read_bvh(edit(TINY, L_FRAMES, "Frames: 1000000000000"))
    with pytest.raises(LimitExceeded, match="frames"):
        read_bvh(edit(TINY, L_FRAMES, "Frames: " + "9" * 5000))
    with pytest.raises(LimitExceeded, match="frames"):
        read_bvh(TINY, limits=ParseLimits(max_frames=1))


def test_value_limit_covers_the_rotation_matrices_produced() -> None:
    # 2 frames x 3 joints x 9 = 54 output values although the file holds only 18
    with pytest.raises(LimitExceeded, match="values"):
        read_bvh(TINY, limits=ParseLimits(max_values=50))
    assert read_bvh(TINY, limits=ParseLimits(max_values=54)).frame_count == 2


# ------------------------------------------------------------------------------ hostile input
# Nothing here times the reader (this machine's speed is not the code's): work that could
# grow faster than the input is pinned by what the reader is made to do, and a read that
# runs too long by its deadline. The timings live in bench/bench_hostile_parse.py.


def _refused(data: str, match: str) -> ParseError:
    with pytest.raises(ParseError, match=match) as raised:
        read_bvh(data)
    return raised.value


def test_ten_megabyte_frame_line() -> None:
    huge = " ".join(["1.5"] * 2_500_000)
    _refused(edit(TINY, L_FRAME_2, huge), "has more than 9 values")
    # Beyond the declared frames a huge line is ignored.
    assert read_bvh(edit(edit(TINY, L_FRAME_2, huge), L_FRAMES, "Frames: 1")).frame_count == 1


def test_ten_megabyte_lines_elsewhere() -> None:
    _refused(edit(TINY, L_JOINT, "JOINT " + "a" * 10_000_000), "characters long")
    _refused("HIERARCHY " + "x " * 5_000_000, "far too long")
    _refused("x" * 10_000_000, "not a BVH")
    _refused(
        edit(TINY, L_FRAME_TIME, "Frame Time: " + "1" * 10_000_000),
        f"longer than {text_module.MAX_NUMBER_TOKEN} characters",
    )


# Where a number is read: a frame value (the line pass, after the C readers refused the
# line), an OFFSET (hierarchy) and the Frame Time.
_NUMBER_PLACES = {
    "frame value": lambda token: edit(TINY, L_FRAME_2, "1 91 2 0 0 0 0 0 " + token),
    "OFFSET": lambda token: edit(TINY, L_CHEST_OFFSET, f"OFFSET 0 {token} 0"),
    "Frame Time": lambda token: edit(TINY, L_FRAME_TIME, f"Frame Time: {token}"),
}


@pytest.mark.parametrize("place", list(_NUMBER_PLACES))
@pytest.mark.parametrize("shape", ["{digits}x", "{digits}.{digits}e", "-{digits}e+{digits}y"])
def test_a_long_invalid_number_costs_the_same_whatever_its_length(
    monkeypatch: pytest.MonkeyPatch, place: str, shape: str
) -> None:
    """One long invalid number (digits then a letter) once froze a server: the number pattern
    backtracked over every split of the digits with the GIL held (18 s at 32,000 digits, 22
    minutes at 200,000). A token is refused by its length before any pattern reads it: the
    pattern's work is the same at 20,000 and 200,000 digits, and never more than
    MAX_NUMBER_TOKEN characters a token."""
    recorder = RecordingPattern(text_module.NUMBER_RE)
    monkeypatch.setattr(text_module, "NUMBER_RE", recorder)
    read_bvh(TINY)  # its hierarchy is remembered from here on, as for the first size
    work = []
    # a hierarchy line is refused past 65,536 characters: 200,000 digits would not reach it
    for digits in (10_000, 30_000) if place == "OFFSET" else (20_000, 200_000):
        recorder.lengths.clear()
        token = shape.format(digits="1" * digits)
        error = _refused(_NUMBER_PLACES[place](token), "not a number")
        assert f"longer than {text_module.MAX_NUMBER_TOKEN} characters" in str(error)
        assert len(str(error)) < 300  # the token is not echoed whole
        assert max(recorder.lengths, default=0) <= text_module.MAX_NUMBER_TOKEN
        work.append(sum(recorder.lengths))
    assert work[0] == work[1]


def test_the_number_pattern_is_linear_and_reads_numbers_as_before() -> None:
    """Possessive quantifiers (no re-reading a run of digits) accept exactly the numbers the
    greedy pattern did, so the token bound is a second guard, not the only one."""
    greedy = re.compile(
        r"[+-]?(?:(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|nan|inf|infinity)",
        re.ASCII | re.IGNORECASE,
    )
    rng = random.Random(3)
    alphabet = "0123456789.eE+-naifty x"
    tokens = ["1.", ".5", "1e5", "1.e5", "-1.5E-3", "+.5e+2", "NaN", "-Infinity", "1.5e", "."]
    tokens += ["".join(rng.choice(alphabet) for _ in range(rng.randint(1, 8))) for _ in range(5000)]
    for token in tokens:
        assert (text_module.NUMBER_RE.fullmatch(token) is None) == (
            greedy.fullmatch(token) is None
        ), token
    # A match that fails at the end of a million digits is found to fail (in milliseconds;
    # the greedy pattern would need hours, so a regression here hangs rather than passes).
    assert text_module.NUMBER_RE.fullmatch("1" * 1_000_000 + "x") is None


def test_a_read_past_its_deadline_stops_with_describe_timeout() -> None:
    with pytest.raises(DescribeTimeout, match="time limit"):
        read_bvh(TINY, limits=ParseLimits(deadline=time.monotonic() - 1.0))


def test_the_reader_looks_at_the_clock_while_it_walks_a_long_frame_block(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The line pass over 300,000 lines looks at the clock every LINES_PER_CLOCK_CHECK lines,
    so a deadline stops it inside the walk: the describe timeout reaches into the parse."""
    clock = Clock()
    monkeypatch.setattr(model_module.time, "monotonic", clock)
    text = TINY + "1 91 2 0 0 0 0 0 90\n" * 300_000
    motion = read_bvh(text, limits=ParseLimits(deadline=1e12))
    assert motion.frame_count == 2
    assert clock.looks >= 300_000 // text_module.LINES_PER_CLOCK_CHECK
    clock.looks = 0
    with pytest.raises(DescribeTimeout):
        read_bvh(text, limits=ParseLimits(deadline=10.0))
    assert clock.looks == 11  # stopped at the first look past the deadline


def test_many_frame_lines_beyond_the_header() -> None:
    text = TINY + "1 91 2 0 0 0 0 0 90\n" * 300_000
    motion = read_bvh(text)
    assert motion.frame_count == 2
    assert motion.notes["warnings"] == [
        "300000 lines after the 2 frames that Frames: declares ignored"
    ]


def test_many_joints_and_braces() -> None:
    # 1000 sibling End Sites all wanting the same name
    sites = "End Site\n{\nOFFSET 0 0 0\n}\n" * 990
    text = TINY.replace("    End Site\n", sites + "    End Site\n", 1)
    motion = read_bvh(text)
    assert motion.skeleton.joint_count == 993
    assert len(set(motion.skeleton.names)) == 993
    _refused("HIERARCHY\n" + "{\n" * 1_000_000, "unexpected '{'")


# ------------------------------------------------------------------------------ fuzzing

_TOKENS = [
    "",
    "0",
    "-1",
    "1e309",
    "nan",
    "inf",
    "1.5.2",
    "{",
    "}",
    "ROOT",
    "JOINT",
    "End",
    "Site",
    "OFFSET",
    "CHANNELS",
    "MOTION",
    "Frames:",
    "Frame",
    "Time:",
    "Xposition",
    "Zrotation",
    "99999999999999999999999",
    "\t",
    "é",
    "\x00",
    "\r",
    "#",
]


def _first_frames(text: str, frames: int) -> str:
    """A real file cut to its first ``frames`` frames, with ``Frames:`` edited to match."""
    header, _frames_line, rest = re.split(r"(Frames:\s*\d+)", text, maxsplit=1)
    lines = rest.split("\n")
    return header + f"Frames: {frames}" + "\n".join(lines[: frames + 2]) + "\n"


_FUZZ_BASES = [
    TINY,
    _first_frames(fixture_text(CMU_BVH_FIXTURE), 4),
    _first_frames(fixture_text(BANDAI_FIXTURE), 3),
]


@st.composite
def mutated_bvh(draw: st.DrawFn) -> bytes:
    """A real (or tiny) BVH with a few lines or tokens deleted, repeated, swapped or replaced."""
    # a seeded Random (not hypothesis' own, which favours zeros) spreads edits over the file
    rng = random.Random(draw(st.integers(0, 2**32 - 1)))
    lines = draw(st.sampled_from(_FUZZ_BASES)).split("\n")
    motion_line = next(i for i, line in enumerate(lines) if line.startswith("MOTION"))
    for _ in range(draw(st.integers(1, 3))):
        if not lines:
            break
        # half of the edits land in the MOTION section, where most of the numbers are
        low = min(motion_line, len(lines) - 1) if rng.random() < 0.5 else 0
        i = rng.randint(low, len(lines) - 1)
        operation = rng.choices(
            ["number", "delete", "duplicate", "replace", "token", "swap"], [4, 2, 2, 1, 2, 1]
        )[0]
        if operation == "number":  # usually keeps the file valid
            tokens = lines[i].split() or [""]
            tokens[rng.randrange(len(tokens))] = rng.choice(
                [f"{rng.uniform(-1e3, 1e3):.6g}", "-0", "+.5", "1E-3", "7.", "1e300"]
            )
            lines[i] = " ".join(tokens)
        elif operation == "delete":
            del lines[i]
        elif operation == "duplicate":
            lines.insert(i, lines[i])
        elif operation == "replace":
            lines[i] = draw(st.text(max_size=30))
        elif operation == "token":
            tokens = lines[i].split() or [""]
            tokens[rng.randrange(len(tokens))] = draw(
                st.sampled_from(_TOKENS) | st.text(max_size=6)
            )
            lines[i] = " ".join(tokens)
        else:
            j = rng.randrange(len(lines))
            lines[i], lines[j] = lines[j], lines[i]
    data = "\n".join(lines).encode("utf-8", "surrogatepass")
    if rng.random() < 0.2:
        data = data[: rng.randint(0, len(data))]
    if rng.random() < 0.2:
        position = rng.randint(0, len(data))
        data = data[:position] + draw(st.binary(min_size=1, max_size=8)) + data[position:]
    return data


def _read_or_reject(data: bytes | str) -> None:
    try:
        motion = read_bvh(data, limits=ParseLimits(max_frames=10_000, max_joints=500))
    except (ParseError, LimitExceeded):
        return
    assert_consistent(motion)


@settings(
    max_examples=300,
    deadline=2000,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
@given(mutated_bvh())
def test_fuzzed_real_files_parse_or_raise_parse_error(data: bytes) -> None:
    _read_or_reject(data)


@settings(max_examples=200, deadline=1000, database=None)
@given(st.one_of(st.binary(max_size=300), st.text(max_size=300)))
def test_random_input_parses_or_raises_parse_error(data: bytes | str) -> None:
    _read_or_reject(data)


# ------------------------------------------------------------------------------ shared data


def _bvh_files(root: Path) -> list[Path]:
    bandai = sorted((root / "bandai-ds1" / "data").glob("*.bvh"))
    cmu = sorted(
        p
        for folder in ("bvh-mb", "bvh-daz", "bvh-max")
        for p in (root / "cmu" / folder).rglob("*.bvh")
    )
    return bandai + cmu


@pytest.mark.slow
def test_every_shared_bvh_file_parses(motion_data: Path) -> None:
    files = _bvh_files(motion_data)
    assert len(files) >= 174 + 37
    for path in files:
        text = path.read_bytes().decode("utf-8")
        motion = read_bvh(text)
        frames, frame_time = header_counts(text)
        assert motion.frame_count == frames, path.name
        assert motion.frame_time == pytest.approx(frame_time), path.name
        assert motion.local_rotations.shape == (frames, motion.skeleton.joint_count, 3, 3)
        assert np.isfinite(motion.local_rotations).all(), path.name
        assert np.isfinite(motion.root_translation).all(), path.name
        is_bandai = "bandai" in str(path)
        assert (motion.local_translations is not None) == is_bandai, path.name


@pytest.mark.slow
def test_every_bandai_file_repeats_offsets_in_its_position_channels(motion_data: Path) -> None:
    for path in sorted((motion_data / "bandai-ds1" / "data").glob("*.bvh")):
        motion = read_bvh(path.read_bytes())
        assert motion.local_translations is not None
        moving = np.flatnonzero(~motion.skeleton.end_site)[2:]  # below joint_Root and Hips
        np.testing.assert_allclose(
            motion.local_translations[:, moving],
            np.broadcast_to(motion.skeleton.offsets[moving], (motion.frame_count, len(moving), 3)),
            atol=1e-4,
            err_msg=path.name,
        )


@pytest.mark.slow
@pytest.mark.parametrize(
    "name",
    [
        "dataset-1_dance-short_normal_001.bvh",
        "dataset-1_dash_tired_001.bvh",
        "dataset-1_kick_normal_001.bvh",
    ],
)
def test_bandai_bone_lengths_stay_constant(motion_data: Path, name: str) -> None:
    motion = read_bvh((motion_data / "bandai-ds1" / "data" / name).read_bytes())
    assert_consistent(motion)
    _assert_rigid_bones(motion)


def test_a_hierarchy_read_before_is_reused_and_frames_are_still_read() -> None:
    from app.motion.formats import bvh

    first = read_bvh(TINY)
    again = read_bvh(edit(TINY, L_FRAME_2, "2 92 4 0 0 0 0 0 45"))
    assert again.skeleton.names == first.skeleton.names
    np.testing.assert_array_equal(again.skeleton.offsets, first.skeleton.offsets)
    np.testing.assert_array_equal(again.root_translation[1], [2, 92, 4])
    assert not np.allclose(again.local_rotations[1], first.local_rotations[1])
    key = (TINY[: TINY.index("Frames:")], bvh.DEFAULT_LIMITS)
    assert key in bvh._HIERARCHIES._read  # remembered: the second file did not read it again
    # One character changed: read in full, with its own error and line number.
    broken = edit(TINY, L_CHEST_OFFSET, "    OFFSET 0 10")
    for _ in range(2):
        with pytest.raises(ParseError, match="OFFSET") as error:
            read_bvh(broken)
        assert error.value.line == L_CHEST_OFFSET
    # Other limits: read again under them.
    with pytest.raises(LimitExceeded):
        read_bvh(TINY, limits=ParseLimits(max_joints=2))


@pytest.mark.parametrize("name", [BANDAI_FIXTURE, CMU_BVH_FIXTURE])
def test_both_frame_readers_give_the_same_bits(name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    from app.motion.formats import bvh_frames

    text = fixture_text(name)
    fast_reads: list[bool] = []
    polars_reader = bvh_frames.read_spaced_numbers

    def counted(*args: object) -> object:
        values = polars_reader(*args)  # type: ignore[arg-type]
        fast_reads.append(values is not None)
        return values

    monkeypatch.setattr(bvh_frames, "read_spaced_numbers", counted)
    fast = read_bvh(text)
    monkeypatch.setattr(
        bvh_frames, "IN_PLACE_BYTES", 0
    )  # as for a long take: from the file's bytes
    in_place = read_bvh(text.encode())
    assert fast_reads == [True, True]  # polars read the block (else numpy is compared with itself)
    monkeypatch.setattr(bvh_frames, "read_spaced_numbers", lambda *args: None)  # numpy's reader
    slow = read_bvh(text)
    for motion in (fast, in_place):
        assert motion.local_rotations.tobytes() == slow.local_rotations.tobytes()
        assert motion.root_translation.tobytes() == slow.root_translation.tobytes()


NUMBER_TOKENS = st.one_of(
    st.floats(allow_nan=False, allow_infinity=False, width=64).map(repr),
    st.floats(allow_nan=False, allow_infinity=False, width=32).map(lambda x: f"{x:.6g}"),
    st.from_regex(r"[+-]?[0-9]{0,4}\.?[0-9]{0,4}([eE][+-]?[0-9]{0,3})?", fullmatch=True),
    st.sampled_from(["nan", "inf", "-0", "1e", ".", "+", "1.2.3", '"1"', "0x10", "1_0", ""]),
)


@settings(max_examples=400, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.lists(NUMBER_TOKENS, min_size=2, max_size=4),
            st.sampled_from([" ", "  ", "\t"]),  # between the numbers
            st.sampled_from(["", " ", "  "]),  # at the line's end
        ),
        min_size=1,
        max_size=4,
    )
)
def test_polars_reads_numbers_as_numpy_does(lines: list[tuple[list[str], str, str]]) -> None:
    """Whatever polars reads as finite numbers, numpy reads the same (same bits); the rest
    goes to numpy (None) or to the caller's line-by-line pass (not finite)."""
    import io

    from app.motion.formats.bvh_frames import read_spaced_numbers

    block = "\n".join(gap.join(tokens) + end for tokens, gap, end in lines).rstrip()
    # read in place from the middle of a larger buffer, as from a whole file
    head = "HIERARCHY\n{ }\nFrame Time: 1\n"
    data = (head + block + "\n\n").encode("ascii")
    got = read_spaced_numbers(data, len(head), len(head) + len(block), len(lines), 3)
    if got is None or not np.isfinite(got).all():
        return
    expected = np.loadtxt(io.StringIO(block), dtype=np.float64, comments=None, ndmin=2)
    assert got.tobytes() == expected.tobytes()


def test_a_file_of_several_skeletons_is_read_as_its_largest_with_a_warning():
    """A second ROOT (a prop, another person) before and after the body: the body's joints
    and its own columns of every frame are read, the others left out with a warning."""
    prop = "ROOT Ball\n{\n  OFFSET 0 0 0\n  CHANNELS 3 Xposition Yposition Zposition\n}\n"
    hierarchy, motion = TINY.split("MOTION\n")
    lines = motion.rstrip("\n").split("\n")
    header, frames = lines[:2], lines[2:]
    plain = read_bvh(TINY)
    for before in (True, False):
        body = hierarchy.replace("HIERARCHY\n", "")
        both = prop + body if before else body + prop
        rows = [f"7 8 9 {row}" if before else f"{row} 7 8 9" for row in frames]
        text = "HIERARCHY\n" + both + "MOTION\n" + "\n".join([*header, *rows]) + "\n"
        motion = read_bvh(text)
        assert motion.skeleton.names == plain.skeleton.names
        np.testing.assert_array_equal(motion.local_rotations, plain.local_rotations)
        np.testing.assert_array_equal(motion.root_translation, plain.root_translation)
        number = 2 if before else 1
        assert motion.notes["warnings"] == [
            f"the file holds 2 skeletons (ROOTs); the largest, number {number}, 'Hips' "
            "(2 joints), is read and 'Ball' (1 joints) left out"
        ]


@pytest.mark.parametrize(
    "encoding, note",
    [
        ("utf-8", None),
        ("utf-16", "the file is UTF-16 text: read as such"),
        ("cp932", "the file is not UTF-8: read as cp932 (joint names may look wrong)"),
    ],
)
def test_files_in_other_encodings_are_read_with_their_names(encoding, note):
    """Japanese tools (MikuMikuDance data) write Shift-JIS names; some Windows tools UTF-16.
    The format's words and numbers are ASCII in all of them: the names are what differ."""
    text = TINY.replace("Hips", "センター").replace("Chest", "上半身")
    motion = read_bvh(text.encode(encoding))
    assert motion.skeleton.names[:2] == ("センター", "上半身")
    assert motion.notes.get("warnings", [None])[0] == note
    np.testing.assert_array_equal(motion.local_rotations, read_bvh(TINY).local_rotations)


def test_a_western_code_page_name_is_read_too():
    motion = read_bvh(TINY.replace("Chest", "Brustkorbé").encode("cp1252"))
    assert motion.skeleton.names[1] == "Brustkorbé"  # 0xe9 then a line end: no Shift-JIS
    assert "not UTF-8: read as cp1252" in motion.notes["warnings"][0]


def test_two_people_of_one_rig_read_as_the_first():
    """A multi-person export: the same rig twice (same joint names), one after the other."""
    hierarchy, motion = TINY.split("MOTION\n")
    lines = motion.rstrip("\n").split("\n")
    rows = [f"{row} {row}" for row in lines[2:]]
    text = hierarchy + hierarchy.replace("HIERARCHY\n", "") + "MOTION\n"
    read = read_bvh(text + "\n".join([*lines[:2], *rows]) + "\n")
    np.testing.assert_array_equal(read.local_rotations, read_bvh(TINY).local_rotations)
    assert "number 1, 'Hips' (2 joints), is read" in read.notes["warnings"][0]


def test_numbers_with_decimal_commas_are_read_as_decimal_points():
    """A tool under a European locale prints 12,5: the whole file is so (OFFSETs, frames)."""
    text = re.sub(r"(\d)\.(\d)", r"\1,\2", TINY.replace("OFFSET 1 2 3", "OFFSET 1.5 2 3"))
    plain = read_bvh(TINY.replace("OFFSET 1 2 3", "OFFSET 1.5 2 3"))
    text = text.replace("0 90 0 10", "0,5 90 0 10")  # and a root position of 0.5
    motion = read_bvh(text)
    assert motion.frame_time == pytest.approx(0.04)
    assert motion.skeleton.offsets[0, 0] == pytest.approx(1.5)
    assert motion.root_translation[0, 0] == pytest.approx(0.5)
    np.testing.assert_allclose(motion.local_rotations, plain.local_rotations)
    assert "decimal commas" in motion.notes["warnings"][0]


def test_commas_beside_decimal_points_are_still_not_numbers():
    text = TINY.replace("OFFSET 0 10 0", "OFFSET 0 10,5 0").replace("0 90 0 10", "0.5 90 0 10")
    with pytest.raises(ParseError, match="'10,5' is not a number"):
        read_bvh(text)


@pytest.mark.parametrize(
    "written", ["Frame Time 0.04", "FrameTime: 0.04", "Frame Time= 0.04", "Frame Times: 0.04"]
)
def test_frame_time_without_its_colon(written):
    motion = read_bvh(TINY.replace("Frame Time: 0.04", written))
    assert motion.frame_time == pytest.approx(0.04)


def test_braces_glued_to_words_are_braces():
    """Hand-written exporters glue a brace to the word before it ("End Site{", "JOINT Chest{",
    "}}"): the same hierarchy as written with spaces."""
    glued = (
        TINY.replace("ROOT Hips\n{", "ROOT Hips{")
        .replace("JOINT Chest\n  {", "JOINT Chest{")
        .replace("End Site\n    {", "End Site{")
        .replace("    }\n  }\n}", "    }}}")
    )
    assert "Site{" in glued and "}}}" in glued
    motion, plain = read_bvh(glued), read_bvh(TINY)
    assert motion.skeleton.names == plain.skeleton.names
    np.testing.assert_array_equal(motion.skeleton.parents, plain.skeleton.parents)
    np.testing.assert_array_equal(motion.skeleton.offsets, plain.skeleton.offsets)
    np.testing.assert_array_equal(motion.local_rotations, plain.local_rotations)


def test_frames_zero_with_values_after_it_is_a_rig_that_says_so():
    """'Frames: 0' is a rig with no animation (the count is a claim: lines beyond it are not
    read), and when values follow, the refusal says where they start."""
    counted_none = TINY.replace("Frames: 2", "Frames: 0")
    with pytest.raises(NoAnimation, match=r"the values from line 19 on are not read") as e:
        read_bvh(counted_none)
    assert e.value.line == L_FRAMES
    rig = counted_none.split("0 90 0 10")[0]
    with pytest.raises(NoAnimation, match=r"no motion to describe$"):
        read_bvh(rig)


def test_numpy_s_reader_is_given_ascii_text_only(monkeypatch: pytest.MonkeyPatch) -> None:
    """numpy's C text reader crashed the process on a fuzzed file with characters beyond the
    BMP (tests/motion/test_asf_amc.py). A BVH whose frame lines are spaced by an ideographic
    space (U+3000) is read by the line pass and given to numpy as ASCII: the same values."""
    given_text: list[str] = []
    loadtxt = np.loadtxt

    def watched(source, *args, **kwargs):  # type: ignore[no-untyped-def]
        text = source.getvalue()
        given_text.append(text)
        return loadtxt(source, *args, **kwargs)

    monkeypatch.setattr(np, "loadtxt", watched)
    text = fixture_bytes(CMU_BVH_FIXTURE).decode("ascii")
    head, frames = text.split("Frame Time:", 1)
    first, rest = frames.split("\n", 1)
    spaced = head + "Frame Time:" + first + "\n" + rest.replace(" ", "\u3000", 5)
    motion = read_bvh(spaced.encode("utf-8"))
    np.testing.assert_allclose(
        motion.local_rotations, read_bvh(fixture_bytes(CMU_BVH_FIXTURE)).local_rotations
    )
    assert given_text and all(text.isascii() for text in given_text)


def test_a_stray_mark_on_a_channels_name_is_read_past_with_a_warning() -> None:
    """A dance capture shared widely writes ``Zrotation#`` on one joint: the name is still
    that channel's (the code before refused the file); a misspelt name still is not."""
    marked = read_bvh(edit(TINY, L_CHEST_CHANNELS, "CHANNELS 3 Zrotation Xrotation Yrotation#"))
    plain = read_bvh(TINY)
    np.testing.assert_array_equal(marked.local_rotations, plain.local_rotations)
    assert marked.notes["warnings"] == [
        f"line {L_CHEST_CHANNELS}: channel 'Yrotation#' read as 'Yrotation'"
    ]
    for wrong in ("Yrotaton#", "#", "Y#rotation"):
        with pytest.raises(ParseError, match="unknown channel"):
            read_bvh(edit(TINY, L_CHEST_CHANNELS, f"CHANNELS 3 Zrotation Xrotation {wrong}"))
