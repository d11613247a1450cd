from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from app.errors import ParseError
from app.motion import transforms
from app.motion.body import build_body, pelvis_basis
from app.motion.formats import read_bvh
from app.motion.kinematics import forward_kinematics
from app.motion.lead_in import count_lead_in_frames
from app.motion.model import Motion
from app.motion.pipeline import analyse
from app.motion.skeleton_map import CANONICAL_INDEX
from tests.motion.canonical import check_canonical_body
from tests.motion.skeleton_trees import Humanoid, synthetic_humanoid
from tests.motion.synthetic import walker_motion, walking
from tests.motion.test_mapping_probes import frame_as_rest

FIXTURES = Path(__file__).parents[1] / "fixtures"


def _leaning(motion: Motion, degrees: float) -> Motion:
    """The walker with its whole body pitched forward about the lateral (x) axis."""
    pitch = transforms.rotation_about([1.0, 0.0, 0.0], degrees)
    local = motion.local_rotations.copy()
    local[:, 0] = pitch @ local[:, 0]
    return transforms._replace(motion, local_rotations=local)


def test_a_leaning_body_does_not_tilt_the_floor():
    # A dash leans 30-40 degrees on average; the vertical must stay the file's up axis.
    body = build_body(_leaning(walker_motion(), 40.0))
    np.testing.assert_array_equal(body.world_up, [0.0, 1.0, 0.0])


def test_pelvis_frame_is_orthonormal_and_points_left_up_forward():
    body = build_body(walker_motion())
    frames = body.pelvis_frames
    np.testing.assert_allclose(
        frames.transpose(0, 2, 1) @ frames, np.broadcast_to(np.eye(3), frames.shape), atol=1e-12
    )
    np.testing.assert_allclose(np.linalg.det(frames), 1.0)
    # The walker faces +z with its left hand on +x (see tests/motion/synthetic.py).
    mean = frames.mean(axis=0)
    assert mean[0, 0] > 0.95 and mean[1, 1] > 0.95 and mean[2, 2] > 0.95


def test_body_height_ignores_units():
    body = build_body(walker_motion())
    scaled = build_body(transforms.rescale(walker_motion(), 2.54))
    # Leg bone path (42 + 40) plus the pelvis -> head joint path (12 + 20 + 12 + 6 + 6), cm.
    np.testing.assert_allclose(body.height, 138.0)
    np.testing.assert_allclose(scaled.height, 2.54 * body.height)


def test_rest_pose_lead_in_is_dropped_and_a_real_clip_is_kept():
    motion = walker_motion()
    assert count_lead_in_frames(motion) == 0
    # Prepend one rest-pose frame, as MotionBuilder's converter does.
    rest = np.tile(np.eye(3), (1, motion.skeleton.joint_count, 1, 1))
    with_tpose = transforms._replace(
        motion,
        local_rotations=np.concatenate([rest, motion.local_rotations]),
        root_translation=np.concatenate([motion.root_translation[:1], motion.root_translation]),
    )
    assert count_lead_in_frames(with_tpose) == 1
    assert build_body(with_tpose).lead_in_frames == 1


def _sentinel(motion: Motion, frames: list[int]) -> Motion:
    """``motion`` with the root thrown to a sentinel position in ``frames`` (as broken
    exporters write -99999 or 1e6 where tracking was lost)."""
    root = motion.root_translation.copy()
    root[frames] = 1e6
    translations = None
    if motion.local_translations is not None:
        translations = motion.local_translations.copy()
        translations[frames, 0] = 1e6
    return transforms._replace(motion, root_translation=root, local_translations=translations)


def test_implausible_frames_at_the_ends_go_like_lead_in_frames():
    from app.motion.formats import read_bvh
    from app.motion.pipeline import analyse
    from tests.motion.conftest import BANDAI_FIXTURE, fixture_bytes

    motion = read_bvh(fixture_bytes(BANDAI_FIXTURE))
    broken = analyse(_sentinel(motion, [0, 1, 2, 38, 39]))
    clean = analyse(motion.slice_frames(3, 38))
    assert broken.lead_in_frames == 3
    assert broken.body.frame_count == 35
    assert "3 implausible frames at the start dropped" in broken.warnings
    assert "2 implausible frames at the end dropped" in broken.warnings
    for name, vector in clean.descriptors.items():
        np.testing.assert_allclose(broken.descriptors[name], vector, atol=1e-6)
    # In the middle: kept, and said.
    middle = analyse(_sentinel(motion, [20]))
    assert middle.body.frame_count == 40
    assert any("1 frames in the middle look implausible" in w for w in middle.warnings)


def test_hips_at_the_pelvis_take_the_sides_from_where_the_legs_part():
    # Both hip joints sit at the pelvis; the legs separate at the knees.
    skeleton, truth = synthetic_humanoid(Humanoid(hips_coincide=True))
    body = build_body(walking(skeleton, truth))
    assert skeleton.names[body.mapping.joints[CANONICAL_INDEX["l_hip"]]] == truth["l_hip"]
    lateral = body.pelvis_frames[:, :, 0].mean(axis=0)
    assert lateral[0] > 0.95  # the left knee is on +x, and so is the subject's left


def test_a_rest_pose_only_one_frame_shows_is_not_the_bodys_rest():
    # A pose estimator writes its first frame as the rest pose, and that frame is bent 60
    # degrees forward at the spine: the other frames (upright) do not show it, so the body's
    # axes are the frames' own, not the one bent pose's (docs/skeletons.md, "2026-11-27, a
    # rest pose one frame shows").
    walker = walker_motion(frames=60, fps=30.0)
    body = build_body(walker)
    assert body.mapping is not None
    canonical = body.mapping.joints
    spine = int(canonical[CANONICAL_INDEX["spine"]])
    world, _ = forward_kinematics(walker, joints=[spine])
    above = world[0, walker.skeleton.parents[spine]]
    bend = transforms.rotation_about([1.0, 0.0, 0.0], 60.0)  # about the walker's left (+x)
    bent = walker.local_rotations.copy()
    bent[0, spine] = above.T @ bend @ above @ bent[0, spine]
    copy = frame_as_rest(transforms._replace(walker, local_rotations=bent), 0)

    basis = pelvis_basis(copy, canonical, rest_is_a_figure=False)
    rotations, _ = forward_kinematics(copy, joints=canonical)
    up = rotations[1:, canonical[CANONICAL_INDEX["pelvis"]]] @ basis[:, 1]  # (F-1, 3)
    agreement = np.einsum("fa,fa->f", up, body.pelvis_frames[1:, :, 1])
    assert float(agreement.min()) > np.cos(np.radians(30.0))


def test_a_pelvis_whose_children_turn_it_back_reads_its_axes_from_the_joints():
    """A pose network's BVH: every child of the pelvis sits at the pelvis with a rotation of
    its own, and the pelvis turned 90 degrees is turned back by its children, so the same
    world motion has a pelvis rotation that moves no bone. Read from that rotation the body
    lies on its side; read from the joints it stands as the capture does."""
    capture = read_bvh(
        (Path(__file__).parents[1] / "fixtures/cmu_mb_02_01_first41.bvh").read_bytes()
    )
    turn = transforms.rotation_about(np.array([0.0, 0.0, 1.0]), 90.0)
    pelvis = int(np.flatnonzero(capture.skeleton.parents < 0)[0])
    children = np.flatnonzero(capture.skeleton.parents == pelvis)
    assert np.all(capture.skeleton.offsets[children] == 0)  # CMU's hip joints and lower back
    rotations = capture.local_rotations.copy()
    rotations[:, pelvis] = rotations[:, pelvis] @ turn
    rotations[:, children] = turn.T @ rotations[:, children]
    network = replace(capture, local_rotations=rotations)
    np.testing.assert_allclose(
        forward_kinematics(network)[1], forward_kinematics(capture)[1], atol=1e-9
    )
    body = build_body(network)
    check_canonical_body(body, "pelvis turned back by its children", upright=True)
    assert any("does not carry the hips" in warning for warning in body.warnings)
    assert not any("does not carry the hips" in w for w in build_body(capture).warnings)
    # Posture (joints in the body frame) as the capture's but for the spine's bend the
    # joints' up carries (0.16 of its length; 1.2 read from the turned pelvis). The energies
    # are the file's own angles, which differ: `kinetic` and `motion`'s energy blocks do.
    plain, turned = analyse(capture), analyse(network)
    a, b = plain.descriptors["posture"], turned.descriptors["posture"]
    assert np.linalg.norm(a - b) <= 0.25 * np.linalg.norm(a)


def test_a_still_pose_is_stored_as_what_it_is():
    """A rig's template written with frames that all hold one pose (or a single frame) is
    described, and said to be a still pose; a capture is not."""
    capture = read_bvh(
        (Path(__file__).parents[1] / "fixtures/cmu_mb_02_01_first41.bvh").read_bytes()
    )
    held = capture.slice_frames(5, 6)
    still = replace(
        held,
        local_rotations=np.repeat(held.local_rotations, 28, axis=0),
        root_translation=np.repeat(held.root_translation, 28, axis=0),
    )
    assert any("a still pose (all 28 frames the same)" in w for w in analyse(still).warnings)
    assert any("a still pose (one frame)" in w for w in analyse(held).warnings)
    assert not any("still pose" in w for w in analyse(capture).warnings)


def test_a_bone_no_float_can_measure_in_the_first_frame_is_named() -> None:
    """Found by fuzzing a dev file: a neck position channel set to 1e308 in a clip's first
    frame made the body's height (a sum of bone lengths) infinite. Every check made in body
    heights then passed, and the `motion` vector came out NaN ("degenerate"). The bone and its
    joint are named instead."""
    text = (FIXTURES / "bandai_walk_normal_001_first40.bvh").read_text()
    head, frames = text.split("Frame Time:")
    lines = frames.split("\n")
    values = lines[1].split()
    values[4 * 6 + 1] = "1e308"  # the first frame's Neck Yposition (six channels a joint)
    lines[1] = " ".join(values)
    motion = read_bvh((head + "Frame Time:" + "\n".join(lines)).encode())
    with pytest.raises(ParseError, match="the bone to joint 'Neck' is"):
        analyse(motion)
