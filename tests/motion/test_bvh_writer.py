"""BVH export (app/motion/formats/bvh_writer.py): whatever a clip was read from, its BVH
read back puts every joint where the clip had it."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from app.motion.formats import read_asf_amc, read_bvh
from app.motion.formats.bvh_writer import euler_zxy, write_bvh
from app.motion.formats.fbx import read_fbx
from app.motion.formats.gltf import read_gltf
from app.motion.kinematics import forward_kinematics
from tests.conftest import FIXTURES_DIR
from tests.motion.gltf_builder import build_glb


def _motions():
    cmu = read_bvh((FIXTURES_DIR / "cmu_mb_02_01_first41.bvh").read_bytes())
    return {
        "bvh": cmu,
        "bvh, 6 channels per joint": read_bvh(
            (FIXTURES_DIR / "bandai_walk_normal_001_first40.bvh").read_bytes()
        ),
        "asf/amc": read_asf_amc(
            (FIXTURES_DIR / "cmu_02.asf").read_bytes(),
            (FIXTURES_DIR / "cmu_02_01_first40.amc").read_bytes(),
        ),
        "fbx": read_fbx((FIXTURES_DIR / "ufbx_maya_human_ik_7400_binary.fbx").read_bytes())[0],
        "glb": read_gltf(build_glb(cmu))[0],
        "vrma": read_gltf((FIXTURES_DIR / "three_vrm_test.vrma").read_bytes())[0],
    }


MOTIONS = _motions()


def _same_joints(original, exported):
    """Positions of the original's joints in both clips, ``(F, J, 3)`` each."""
    _, a = forward_kinematics(original)
    _, b = forward_kinematics(exported)
    index = {name: j for j, name in enumerate(exported.skeleton.names)}
    by_name = [index[name.replace(" ", "_")] for name in original.skeleton.names]
    return a, b[:, by_name]


@pytest.mark.parametrize("kind", list(MOTIONS))
def test_round_trip_puts_every_joint_back(kind):
    motion = MOTIONS[kind]
    text = write_bvh(motion)
    again = read_bvh(text)
    assert again.frame_count == motion.frame_count
    assert again.frame_time == pytest.approx(motion.frame_time, rel=1e-9)
    a, b = _same_joints(motion, again)
    size = np.ptp(a.reshape(-1, 3), axis=0).max()
    assert np.abs(a - b).max() <= 1e-6 * size, kind
    # One rotation order for every joint.
    channels = [line.split()[2:] for line in text.splitlines() if "CHANNELS" in line]
    assert all(c[-3:] == ["Zrotation", "Xrotation", "Yrotation"] for c in channels)


def test_end_sites_stay_end_sites():
    motion = MOTIONS["bvh"]
    again = read_bvh(write_bvh(motion))
    assert again.skeleton.joint_count == motion.skeleton.joint_count
    np.testing.assert_array_equal(again.skeleton.end_site, motion.skeleton.end_site)
    np.testing.assert_allclose(again.skeleton.offsets, motion.skeleton.offsets, atol=1e-9)


def test_a_frame_range():
    motion = MOTIONS["bvh"]
    part = read_bvh(write_bvh(motion, (10, 20)))
    assert part.frame_count == 10
    a, b = _same_joints(motion, part)
    np.testing.assert_allclose(b, a[10:20], atol=1e-6)


def test_zxy_angles_rebuild_the_rotation_also_at_gimbal_lock():
    rng = np.random.default_rng(3)
    rotations = Rotation.random(200, random_state=rng).as_matrix()
    locked = Rotation.from_euler("ZXY", [[40, 90, 10], [-70, -90, 25]], degrees=True).as_matrix()
    matrices = np.concatenate([rotations, locked])
    angles = euler_zxy(matrices)
    rebuilt = Rotation.from_euler("ZXY", angles, degrees=True).as_matrix()
    np.testing.assert_allclose(rebuilt, matrices, atol=1e-9)
