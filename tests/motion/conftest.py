"""Helpers for the format-reader tests: where the real files are, and an independent FK.

Small real excerpts ship in ``tests/fixtures`` (see its README). The full datasets live in
``../shared/data`` beside the repository (or wherever ``$MOCAP_SHARED_DATA`` points); tests
that need them skip with a clear reason when that folder is absent.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from app.motion.model import Motion
from tests.conftest import shared_data_dir

REPO_ROOT = Path(__file__).resolve().parents[2]
FIXTURES_DIR = REPO_ROOT / "tests" / "fixtures"

BANDAI_FIXTURE = "bandai_walk_normal_001_first40.bvh"
CMU_BVH_FIXTURE = "cmu_mb_02_01_first41.bvh"
CMU_ASF_FIXTURE = "cmu_02.asf"
CMU_AMC_FIXTURE = "cmu_02_01_first40.amc"


def fixture_bytes(name: str) -> bytes:
    """The bytes of one file in ``tests/fixtures``."""
    return (FIXTURES_DIR / name).read_bytes()


def fixture_text(name: str) -> str:
    """The text of one file in ``tests/fixtures`` with its line ends untouched."""
    return fixture_bytes(name).decode("utf-8")


@pytest.fixture(scope="session")
def motion_data() -> Path:
    """The real datasets; the test is skipped when they are not on this machine."""
    path = shared_data_dir()
    if not (path / "bandai-ds1").is_dir() or not (path / "cmu").is_dir():
        pytest.skip(
            f"real motion data not found at {path.resolve()} "
            "(needs bandai-ds1/ and cmu/; set MOCAP_SHARED_DATA to its location)"
        )
    return path


def world_positions(motion: Motion) -> np.ndarray:
    """``(F, J, 3)`` world joint positions, computed here independently of the app's FK.

    ``G_j = G_parent @ L_j``; ``p_j = p_parent + G_parent @ offset_j`` (per-frame offsets when
    the motion has ``local_translations``); ``p_root = root_translation``.
    """
    skeleton = motion.skeleton
    frames, joints = motion.frame_count, skeleton.joint_count
    world = np.zeros((frames, joints, 3, 3))
    positions = np.zeros((frames, joints, 3))
    for j in range(joints):
        parent = int(skeleton.parents[j])
        if parent < 0:
            world[:, j] = motion.local_rotations[:, j]
            positions[:, j] = motion.root_translation
            continue
        if motion.local_translations is None:
            offset = np.broadcast_to(skeleton.offsets[j], (frames, 3))
        else:
            offset = motion.local_translations[:, j]
        world[:, j] = world[:, parent] @ motion.local_rotations[:, j]
        positions[:, j] = positions[:, parent] + np.einsum("fab,fb->fa", world[:, parent], offset)
    return positions


def assert_consistent(motion: Motion) -> None:
    """Shapes agree, values are finite, rotations are rotations, parents precede children."""
    skeleton = motion.skeleton
    frames, joints = motion.frame_count, skeleton.joint_count
    assert frames >= 1
    assert joints >= 1
    assert motion.frame_time > 0
    assert skeleton.parents[0] == -1
    assert all(0 <= skeleton.parents[j] < j for j in range(1, joints))
    assert len(set(skeleton.names)) == joints
    assert motion.root_translation.shape == (frames, 3)
    assert motion.local_rotations.shape == (frames, joints, 3, 3)
    assert motion.local_rotations.dtype == np.float64
    assert np.isfinite(motion.root_translation).all()
    assert np.isfinite(motion.local_rotations).all()
    assert np.isfinite(skeleton.offsets).all()
    if motion.local_translations is not None:
        assert motion.local_translations.shape == (frames, joints, 3)
        assert np.isfinite(motion.local_translations).all()
    if frames * joints <= 200_000:
        rotations = motion.local_rotations.reshape(-1, 3, 3)
        identity = np.broadcast_to(np.eye(3), rotations.shape)
        np.testing.assert_allclose(rotations @ np.swapaxes(rotations, 1, 2), identity, atol=1e-9)
    ends = np.flatnonzero(skeleton.end_site)
    np.testing.assert_array_equal(
        motion.local_rotations[:, ends], np.broadcast_to(np.eye(3), (frames, len(ends), 3, 3))
    )
