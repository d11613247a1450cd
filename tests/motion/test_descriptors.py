"""Descriptor properties: dimensions, invariances, mirror symmetry, frame-rate robustness."""

from __future__ import annotations

from functools import cache
from pathlib import Path

import numpy as np
import pytest

from app.motion import transforms
from app.motion.body import build_body
from app.motion.descriptors import REGISTRY
from app.motion.descriptors.kinetic import KINETIC_JOINTS, compute_kinetic
from app.motion.formats import read_asf_amc, read_bvh
from app.motion.model import Motion
from app.motion.pipeline import analyse
from tests.motion.shared import SHARED_DATA, requires_shared_data
from tests.motion.synthetic import walker_motion

CMU = SHARED_DATA / "cmu"
BANDAI = SHARED_DATA / "bandai-ds1" / "data"


@cache
def _bvh(path: Path) -> Motion:
    return read_bvh(path.read_bytes())


@cache
def _amc(trial: str) -> Motion:
    subject = trial.split("_")[0]
    folder = CMU / "asf-amc" / subject
    asf, amc = folder / f"{subject}.asf", folder / f"{trial}.amc"
    return read_asf_amc(asf.read_bytes(), amc.read_bytes())


def _relative_change(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(a))


def _real_clips() -> list[tuple[str, Motion]]:
    return [
        ("bandai walk-left", _bvh(BANDAI / "dataset-1_walk-left_normal_001.bvh")),
        ("bandai punch", _bvh(BANDAI / "dataset-1_punch_normal_001.bvh")),
        ("cmu asf/amc 02_05", _amc("02_05")),
        ("cmu daz 02_01", _bvh(CMU / "bvh-daz" / "02" / "02_01.bvh")),
        ("cmu max 131_01", _bvh(CMU / "bvh-max" / "131_01.bvh")),
    ]


def test_registry_dimensions_match_vectors():
    analysis = analyse(walker_motion())
    assert REGISTRY["posture"].dimension == 12
    for name, descriptor in REGISTRY.items():
        vector = analysis.descriptors[name]
        assert vector.shape == (descriptor.dimension,)
        assert vector.dtype == np.float32
        assert np.all(np.isfinite(vector))


def _moved(motion: Motion) -> Motion:
    """The same motion about another vertical axis direction, elsewhere, in other units."""
    up = build_body(motion).world_up
    turned = transforms.rotate(motion, transforms.rotation_about(up, 131.0))
    return transforms.rescale(transforms.translate(turned, [250.0, 3.0, -75.0]), 2.54)


def _assert_invariant(motion: Motion) -> None:
    before = analyse(motion).descriptors
    after = analyse(_moved(motion)).descriptors
    for name in REGISTRY:
        assert _relative_change(before[name], after[name]) < 1e-5, name


def test_rotation_translation_and_units_do_not_matter_synthetic():
    _assert_invariant(walker_motion())


@requires_shared_data
def test_rotation_translation_and_units_do_not_matter_real():
    for _, motion in _real_clips():
        _assert_invariant(motion)


def _assert_mirror_symmetry(motion: Motion) -> None:
    original = analyse(motion)
    mirrored = analyse(transforms.mirror(motion))
    p, q = original.descriptors["posture"], mirrored.descriptors["posture"]
    same = [0, 1, 2, 4, *range(6, 12)]  # σxx σyy σzz σyz means and every std
    np.testing.assert_allclose(q[same], p[same], rtol=1e-4, atol=1e-7)
    np.testing.assert_allclose(q[[3, 5]], -p[[3, 5]], rtol=1e-4, atol=1e-7)
    # Kinetic energy is mirror-symmetric once left and right joints trade places.
    joints = compute_kinetic(original.body)[:-2].reshape(len(KINETIC_JOINTS), 3)
    swapped = [
        KINETIC_JOINTS.index({"l": "r", "r": "l"}[n[0]] + n[1:]) if n[1] == "_" else i
        for i, n in enumerate(KINETIC_JOINTS)
    ]
    mirrored_joints = compute_kinetic(mirrored.body)[:-2].reshape(len(KINETIC_JOINTS), 3)
    np.testing.assert_allclose(mirrored_joints, joints[swapped], rtol=1e-4, atol=1e-7)


def test_mirror_flips_only_the_sagittal_covariances_synthetic():
    _assert_mirror_symmetry(walker_motion())


@requires_shared_data
def test_mirror_flips_only_the_sagittal_covariances_real():
    _assert_mirror_symmetry(_bvh(BANDAI / "dataset-1_walk-left_normal_001.bvh"))
    _assert_mirror_symmetry(_amc("02_05"))


@requires_shared_data
@pytest.mark.parametrize("trial", ["02_01", "02_03", "02_05", "02_07", "03_02"])
def test_120_fps_resampled_to_30_fps_changes_each_descriptor_under_3_percent(trial):
    motion = _amc(trial)
    full = analyse(motion).descriptors
    coarse = analyse(transforms.resample(motion, 4)).descriptors
    for name in REGISTRY:
        assert _relative_change(full[name], coarse[name]) < 0.03, name


def test_travel_direction_is_signed():
    """Walking backwards or sideways changes the motion descriptor's travel block sign."""
    from app.motion.descriptors.motion import travel_block

    forward = travel_block(build_body(walker_motion(speed=120.0)))
    backward = travel_block(build_body(walker_motion(speed=-120.0)))
    assert forward[0] > 0.3 and backward[0] < -0.3
    assert abs(forward[1]) < 0.05
