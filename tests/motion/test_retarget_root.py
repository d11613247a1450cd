"""Root options, frame-rate resampling and units of exports (root_motion, resampling, units)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from app.motion.body import build_body
from app.motion.formats import read_asf_amc, read_bvh
from app.motion.ground import canonical_positions, horizontal
from app.motion.kinematics import forward_kinematics
from app.motion.resampling import resample_to_rate, sample_times
from app.motion.root_motion import RENAMED_ROOT, ROOT_NAME, extract_root, in_place, vertical
from app.motion.skeleton_map import CANONICAL_INDEX
from app.motion.units import metres_per_unit
from tests.motion.conftest import (
    BANDAI_FIXTURE,
    CMU_AMC_FIXTURE,
    CMU_ASF_FIXTURE,
    CMU_BVH_FIXTURE,
    fixture_bytes,
)
from tests.motion.synthetic import walker_motion
from tests.motion.test_gravity import _on_the_back

CLIPS = {
    "cmu-bvh": lambda: read_bvh(fixture_bytes(CMU_BVH_FIXTURE)),
    "bandai": lambda: read_bvh(fixture_bytes(BANDAI_FIXTURE)),  # static root, moving Hips
    "asf": lambda: read_asf_amc(fixture_bytes(CMU_ASF_FIXTURE), fixture_bytes(CMU_AMC_FIXTURE)),
    "walker": lambda: walker_motion(frames=120),
    # Dragged head first along a Y-up floor: the trunk's mean lies along the floor (-Z).
    "on its back": lambda: _on_the_back(read_bvh(fixture_bytes(CMU_BVH_FIXTURE))),
}


@pytest.mark.parametrize("name", list(CLIPS))
def test_in_place_removes_the_horizontal_travel_only(name: str) -> None:
    motion = CLIPS[name]()
    body = build_body(motion)
    placed = in_place(motion, body.mapping)  # type: ignore[arg-type]
    before = canonical_positions(motion, body.mapping)  # type: ignore[arg-type]
    after = canonical_positions(placed, body.mapping)  # type: ignore[arg-type]
    up = vertical(motion, body.mapping)  # type: ignore[arg-type]
    pelvis = CANONICAL_INDEX["pelvis"]
    travel = horizontal(after[:, pelvis], up)
    assert np.abs(travel).max() <= 1e-6 * body.height
    np.testing.assert_allclose(after[:, pelvis] @ up, before[:, pelvis] @ up, atol=1e-9)
    np.testing.assert_array_equal(placed.local_rotations, motion.local_rotations)
    # Relative to the pelvis, every joint is where it was.
    np.testing.assert_allclose(
        after - after[:, pelvis, None], before - before[:, pelvis, None], atol=1e-9
    )


@pytest.mark.parametrize("name", list(CLIPS))
def test_extract_puts_travel_and_yaw_on_a_new_root_at_floor_level(name: str) -> None:
    motion = CLIPS[name]()
    body = build_body(motion)
    mapping = body.mapping
    assert mapping is not None
    out = extract_root(motion, mapping)
    assert out.skeleton.names[0] == ROOT_NAME
    assert out.skeleton.names[1:] == tuple(
        RENAMED_ROOT if n.lower() == ROOT_NAME else n for n in motion.skeleton.names
    )
    rotations, positions = forward_kinematics(out)
    _, before = forward_kinematics(motion)
    # Every original joint's world position unchanged (so the hips are where they were).
    np.testing.assert_allclose(positions[:, 1:], before, atol=1e-9 * body.height)
    canonical = canonical_positions(motion, mapping)
    up = vertical(motion, mapping)
    pelvis = canonical[:, CANONICAL_INDEX["pelvis"]]
    root = positions[:, 0]
    np.testing.assert_allclose(horizontal(root - pelvis, up), 0.0, atol=1e-9 * body.height)
    floor = (
        canonical[:, [CANONICAL_INDEX[n] for n in ("l_ankle", "l_toe", "r_ankle", "r_toe")]] @ up
    ).min()
    np.testing.assert_allclose(root @ up, floor, atol=1e-9 * body.height)
    # The root only turns about the up axis.
    np.testing.assert_allclose(rotations[:, 0] @ up, np.broadcast_to(up, root.shape), atol=1e-12)


def test_extract_keeps_a_joint_already_called_root_under_the_new_one() -> None:
    motion = read_bvh(fixture_bytes(BANDAI_FIXTURE))
    names = ("root", *motion.skeleton.names[1:])
    motion = dataclasses.replace(motion, skeleton=dataclasses.replace(motion.skeleton, names=names))
    out = extract_root(motion, build_body(motion).mapping)  # type: ignore[arg-type]
    assert out.skeleton.names[:2] == (ROOT_NAME, RENAMED_ROOT)
    assert out.skeleton.parents[1] == 0


def test_the_yaw_follows_the_body_turning() -> None:
    motion = walker_motion(frames=60)
    turn = Rotation.from_rotvec(np.outer(np.linspace(0, np.pi / 2, 60), [0, 1, 0])).as_matrix()
    local = motion.local_rotations.copy()
    local[:, 0] = turn @ local[:, 0]
    turned = dataclasses.replace(motion, local_rotations=local)
    out = extract_root(turned, build_body(turned).mapping)  # type: ignore[arg-type]
    yaw = Rotation.from_matrix(out.local_rotations[:, 0]).as_rotvec()[:, 1]
    # The walker's own hip sway (0.1 rad) rides on the quarter turn.
    np.testing.assert_allclose(yaw - yaw[0], np.linspace(0, np.pi / 2, 60), atol=0.15)


def test_resampling_keeps_the_first_and_last_frames_and_the_rate() -> None:
    motion = read_bvh(fixture_bytes(CMU_BVH_FIXTURE))  # 41 frames at 120 fps
    out = resample_to_rate(motion, 30.0)
    assert out.frame_time == pytest.approx(1 / 30)
    assert out.frame_count == 11
    np.testing.assert_array_equal(out.local_rotations[0], motion.local_rotations[0])
    np.testing.assert_array_equal(out.local_rotations[-1], motion.local_rotations[-1])
    np.testing.assert_array_equal(out.root_translation[-1], motion.root_translation[-1])
    # Every fourth source frame is a 30-fps frame, exactly.
    np.testing.assert_array_equal(out.local_rotations, motion.local_rotations[::4])
    same = resample_to_rate(motion, 1 / motion.frame_time)
    np.testing.assert_array_equal(same.local_rotations, motion.local_rotations)


def test_resampling_slerps_rotations_and_interpolates_translations() -> None:
    motion = walker_motion(frames=3, fps=10.0)
    local = np.tile(np.eye(3), (3, motion.skeleton.joint_count, 1, 1))
    local[1, 1] = Rotation.from_rotvec([0, 0, 1.0]).as_matrix()
    local[2, 1] = Rotation.from_rotvec([0, 0, 2.0]).as_matrix()
    motion = dataclasses.replace(motion, local_rotations=local)
    out = resample_to_rate(motion, 40.0)  # 0.2 s -> 9 frames
    assert out.frame_count == len(sample_times(3, 0.1, 40.0)) == 9
    angles = Rotation.from_matrix(out.local_rotations[:, 1]).as_rotvec()[:, 2]
    np.testing.assert_allclose(angles, np.linspace(0, 2.0, 9), atol=1e-12)
    np.testing.assert_allclose(
        out.root_translation[:, 2], np.linspace(*motion.root_translation[[0, -1], 2], 9)
    )
    with pytest.raises(ValueError, match="fps"):
        resample_to_rate(motion, 0.0)


@pytest.mark.parametrize(
    ("name", "expected"),
    [("cmu-bvh", 0.0254 / 0.45), ("bandai", 0.01), ("asf", 0.0254), ("walker", 0.01)],
)
def test_units_are_inferred_from_the_body(name: str, expected: float) -> None:
    motion = CLIPS[name]()
    assert metres_per_unit(motion.source_format, build_body(motion).height) == expected
    assert metres_per_unit("fbx", 1.0) == metres_per_unit("gltf", 123.0) == 1.0


def test_a_take_on_the_floor_goes_in_place_and_into_the_engine_upright() -> None:
    """The root options and the file's axes use the describer's vertical (the floor's, since
    2026-11-28). Before, exports read the trunk's mean: for a take dragged along the floor on
    its back that lies along the floor (-Z), so ``in-place`` kept the travel and flattened the
    height, and a GLB or FBX stood the body on the floor's edge."""
    from app.services.export import ExportOptions, prepare_motion

    motion = CLIPS["on its back"]()
    body = build_body(motion)
    assert body.mapping is not None
    np.testing.assert_array_equal(vertical(motion, body.mapping), [0.0, 1.0, 0.0])
    np.testing.assert_array_equal(vertical(motion, body.mapping), body.world_up)
    before = canonical_positions(motion, body.mapping)[:, CANONICAL_INDEX["pelvis"]]
    assert np.ptp(before[:, 2]) > 0.5 * body.height  # it travels along the floor
    placed = canonical_positions(in_place(motion, body.mapping), body.mapping)
    pelvis = placed[:, CANONICAL_INDEX["pelvis"]]
    assert np.abs(pelvis[:, [0, 2]]).max() <= 1e-6 * body.height
    np.testing.assert_allclose(pelvis[:, 1], before[:, 1], atol=1e-9)
    prepared = prepare_motion(motion, ExportOptions(format="glb", root="in-place"), None)
    np.testing.assert_allclose(prepared.up_rotation @ [0.0, 1.0, 0.0], [0.0, 1.0, 0.0])
