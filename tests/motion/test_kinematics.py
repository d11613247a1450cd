import numpy as np
from scipy.spatial.transform import Rotation

from app.motion.kinematics import (
    ancestors_closure,
    bone_lengths,
    forward_kinematics,
    rotation_log,
)
from app.motion.model import Motion, Skeleton
from tests.motion.synthetic import walker_motion


def _chain() -> Motion:
    """root -> a -> b(end): root rotates 90 deg about z, a rotates 90 deg about x."""
    skeleton = Skeleton(
        names=("root", "a", "b"),
        parents=np.array([-1, 0, 1]),
        offsets=np.array([[0.0, 0, 0], [1, 0, 0], [0, 2, 0]]),
        end_site=np.array([False, False, True]),
    )
    local = np.tile(np.eye(3), (1, 3, 1, 1))
    local[0, 0] = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    local[0, 1] = Rotation.from_euler("x", 90, degrees=True).as_matrix()
    return Motion(skeleton, 0.1, np.array([[5.0, 0, 0]]), local)


def test_forward_kinematics_matches_hand_computation():
    rotations, positions = forward_kinematics(_chain())
    # a: root + Rz(90) @ (1,0,0) = (5,1,0); b: a + Rz(90) Rx(90) @ (0,2,0) = a + (0,0,2).
    np.testing.assert_allclose(positions[0, 1], [5, 1, 0], atol=1e-12)
    np.testing.assert_allclose(positions[0, 2], [5, 1, 2], atol=1e-12)
    np.testing.assert_allclose(rotations[0, 2], rotations[0, 1], atol=1e-12)


def test_subset_computes_only_the_needed_chain():
    motion = walker_motion(frames=10)
    skeleton = motion.skeleton
    head = skeleton.index("Head")
    _, full = forward_kinematics(motion)
    _, partial = forward_kinematics(motion, joints=[head])
    needed = ancestors_closure(skeleton.parents, [head])
    np.testing.assert_allclose(partial[:, needed], full[:, needed])
    assert np.isnan(partial[:, skeleton.index("LeftFoot")]).all()


def test_bone_lengths_stay_constant_over_frames():
    motion = walker_motion(frames=50)
    _, positions = forward_kinematics(motion)
    parents = motion.skeleton.parents
    lengths = np.linalg.norm(positions[:, 1:] - positions[:, parents[1:]], axis=2)
    np.testing.assert_allclose(lengths, np.broadcast_to(bone_lengths(motion)[1:], lengths.shape))


def test_rotation_log_matches_scipy_including_tiny_and_half_turns():
    rng = np.random.default_rng(7)
    rotvecs = rng.normal(size=(500, 3))
    rotvecs /= np.linalg.norm(rotvecs, axis=1, keepdims=True)
    angles = np.concatenate(
        [rng.uniform(0, np.pi - 1e-2, 490), [0, 1e-9, 1e-5, np.pi - 1e-4] * 2, [0.5, 1]]
    )
    rotvecs *= angles[:, None]
    matrices = Rotation.from_rotvec(rotvecs).as_matrix()
    got = rotation_log(matrices)
    # A half turn is the same rotation either way round: compare the rotations themselves.
    np.testing.assert_allclose(Rotation.from_rotvec(got).as_matrix(), matrices, atol=1e-9)
    regular = angles < np.pi - 1e-2
    np.testing.assert_allclose(got[regular], rotvecs[regular], atol=1e-9)
