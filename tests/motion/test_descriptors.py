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


def _blocks(motion):
    from app.motion.descriptors.motion import motion_blocks
    from app.motion.spans import whole_clip

    body = build_body(motion)
    return {name: v[0] for name, v in motion_blocks(body, whole_clip(body.frame_count)).items()}


def test_travel_direction_is_signed():
    """Walking backwards or sideways changes the motion descriptor's travel block sign."""
    forward = _blocks(walker_motion(speed=120.0))
    backward = _blocks(walker_motion(speed=-120.0))
    assert forward["travel"][0] > 0.3 and backward["travel"][0] < -0.3
    assert abs(forward["travel"][1]) < 0.05
    # Straight ahead or straight back: nothing sideways.
    assert abs(forward["sideways"][0]) < 0.05 and abs(backward["sideways"][0]) < 0.05


def test_walking_sideways_is_sideways_whatever_the_speed():
    """The ``sideways`` block is the lateral share of the direction of travel: about ±1 for a
    walker moving along its lateral axis, slowly (faded a little by the gate that silences
    standing clips) or fast."""
    values = {}
    for speed in (60.0, 240.0):
        for sign in (1, -1):
            walker = walker_motion(speed=0.0)
            root = walker.root_translation.copy()
            root[:, 0] = sign * speed * np.arange(walker.frame_count) * walker.frame_time
            moved = Motion(walker.skeleton, walker.frame_time, root, walker.local_rotations)
            values[speed, sign] = _blocks(moved)["sideways"][0]
    for speed in (60.0, 240.0):
        assert values[speed, 1] == pytest.approx(-values[speed, -1], abs=1e-6)
        assert abs(values[speed, 1]) > 0.75
    assert abs(values[240.0, 1]) > 0.95


def _fixture_motions() -> list[tuple[str, Motion]]:
    from tests.motion.conftest import (
        BANDAI_FIXTURE,
        CMU_AMC_FIXTURE,
        CMU_ASF_FIXTURE,
        CMU_BVH_FIXTURE,
        fixture_bytes,
    )

    return [
        ("bandai", read_bvh(fixture_bytes(BANDAI_FIXTURE))),
        ("cmu bvh", read_bvh(fixture_bytes(CMU_BVH_FIXTURE))),
        (
            "cmu asf/amc",
            read_asf_amc(fixture_bytes(CMU_ASF_FIXTURE), fixture_bytes(CMU_AMC_FIXTURE)),
        ),
    ]


def _first_half_difference(motion: Motion) -> float:
    """Largest difference between the per-frame posture features of the first half of a clip
    computed from that half alone and from the whole clip, relative to their scale."""
    from app.motion.descriptors.posture import _POSTURE_INDEX, posture_features

    whole = build_body(motion)
    half = build_body(motion.slice_frames(0, motion.frame_count // 2))
    # Lead-in frames are a property of the clip's start: the same in both.
    assert half.lead_in_frames == whole.lead_in_frames
    a = posture_features(half.local_positions()[:, _POSTURE_INDEX])
    b = posture_features(whole.local_positions()[: half.frame_count, _POSTURE_INDEX])
    return float(np.abs(a - b).max() / np.abs(b).max())


def test_a_frames_features_do_not_depend_on_the_other_frames():
    """Miura et al.: joint positions "in the coordinate system fixed to the pelvis". The body
    frame comes from the skeleton's rest pose, so the first half of a clip described alone
    has exactly the features those frames have in the whole clip."""
    for name, motion in _fixture_motions():
        assert _first_half_difference(motion) < 1e-9, name


@requires_shared_data
def test_a_frames_features_do_not_depend_on_the_other_frames_on_real_clips():
    for name, motion in _real_clips():
        assert _first_half_difference(motion) < 1e-9, name


def test_every_clip_of_one_skeleton_has_the_same_body_axes():
    """The pelvis frame's basis is one per skeleton: two different clips of the CMU subject
    differ in pelvis rotation only."""
    from app.motion.body import rest_pelvis_basis

    for _name, motion in _fixture_motions():
        mapping = build_body(motion).mapping
        assert mapping is not None
        canonical = mapping.joints
        first = rest_pelvis_basis(motion.slice_frames(0, 10), canonical)
        last = rest_pelvis_basis(motion.slice_frames(20), canonical)
        assert np.allclose(first, last, atol=1e-12)
        assert np.allclose(first.T @ first, np.eye(3), atol=1e-12)
        assert np.linalg.det(first) == pytest.approx(1.0)


@pytest.mark.parametrize("name", list(REGISTRY))
def test_a_span_is_described_as_the_clip_cut_to_it(name):
    """``compute_spans`` over any span equals the descriptor of the body cut to that span, and
    the whole span is the clip's vector (moment search relies on both)."""
    from app.motion.spans import whole_clip
    from app.motion.windows import slice_body

    descriptor = REGISTRY[name]
    for _clip, motion in _fixture_motions():
        body = build_body(motion)
        frames = body.frame_count
        whole = descriptor.compute_spans(body, whole_clip(frames))[0]
        assert np.allclose(whole, descriptor.compute(body), rtol=0, atol=1e-12)
        spans = np.array([[0, frames], [3, frames - 2], [5, 25], [10, 39]])
        spans = spans[spans[:, 1] <= frames]
        described = descriptor.compute_spans(body, spans)
        for (start, stop), vector in zip(spans, described, strict=True):
            alone = descriptor.compute(slice_body(body, int(start), int(stop)))
            assert np.allclose(vector, alone, rtol=1e-7, atol=1e-9), (name, start, stop)


def test_a_one_frame_clip_is_a_pose():
    """A single frame (a pose file) has no velocities: energies and travel are zero, posture
    is the pose's, and every vector is finite."""
    from tests.motion.conftest import BANDAI_FIXTURE, fixture_bytes

    pose = read_bvh(fixture_bytes(BANDAI_FIXTURE)).slice_frames(0, 1)
    vectors = analyse(pose).descriptors
    for name, vector in vectors.items():
        assert np.all(np.isfinite(vector)), name
    assert np.all(vectors["kinetic"] == 0)
    assert np.any(vectors["posture"][:6] != 0) and np.all(vectors["posture"][6:] == 0)
