"""Descriptor properties: dimensions, invariances, mirror symmetry, frame-rate robustness."""

from __future__ import annotations

import dataclasses
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
from tests.motion.holds import held, held_motion
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


# ------------------------------------------------------------------------------ still stretches


def _takes_to_hold() -> list[tuple[str, Motion]]:
    takes = list(_fixture_motions())
    if (BANDAI / "dataset-1_walk_normal_001.bvh").is_file():
        takes.append(("bandai walk", _bvh(BANDAI / "dataset-1_walk_normal_001.bvh")))
    if (CMU / "asf-amc" / "02" / "02_05.amc").is_file():
        takes.append(("cmu amc 02_05", _amc("02_05")))
    return takes


def test_the_whole_clip_changes_only_by_its_still_samples():
    """Inserting N more frames into a still stretch adds N still samples to the clip and
    changes no other sample (the stretch is already longer than a velocity span, so no
    sample straddles its edges differently). For the whole-clip vectors "changes nothing but
    the still part" is then, exactly (to 1e-9): the clip's energy totals are unchanged (the
    still samples add zero energy), so the parts shares are unchanged; the travel sums are
    unchanged; and every mean of a per-frame quantity (posture covariances, limb directions
    and their squares) is the frame-weighted mean of the clip's and the held pose's."""
    from app.motion.descriptors.kinetic import velocity_span
    from app.motion.descriptors.motion import motion_blocks
    from app.motion.spans import whole_clip
    from app.motion.windows import slice_body

    for name, motion in _takes_to_hold():
        body = build_body(motion)
        span = velocity_span(body.frame_time, body.frame_count)
        at = body.frame_count // 2
        one = held(body, at, span + 1)
        more = held(body, at, span + 1 + 25)
        f1, f2 = one.frame_count, more.frame_count
        n1, n2 = f1 - span, f2 - span  # velocity samples of the whole clip
        pose = slice_body(one, at, at + 1)
        for descriptor in ("kinetic", "posture", "motion"):
            for b in (one, more):
                assert np.all(np.isfinite(REGISTRY[descriptor].compute(b))), (name, descriptor)
        k1, k2 = compute_kinetic(one), compute_kinetic(more)
        np.testing.assert_allclose(np.expm1(k2) * n2, np.expm1(k1) * n1, rtol=1e-9, atol=1e-12)
        p1, p2, p0 = (REGISTRY["posture"].compute(b) for b in (one, more, pose))
        np.testing.assert_allclose(
            p2[:6] * f2, p1[:6] * f1 + p0[:6] * (f2 - f1), rtol=1e-9, atol=1e-12
        )
        squares = [p[6:] ** 2 + p[:6] ** 2 for p in (p1, p2, p0)]
        np.testing.assert_allclose(
            squares[1] * f2, squares[0] * f1 + squares[2] * (f2 - f1), rtol=1e-6, atol=1e-12
        )
        b1, b2, b0 = (motion_blocks(b, whole_clip(b.frame_count)) for b in (one, more, pose))
        np.testing.assert_allclose(b2["parts"], b1["parts"], rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(
            b2["limbs"][0, :30] * f2,
            b1["limbs"][0, :30] * f1 + b0["limbs"][0, :30] * (f2 - f1),
            rtol=1e-9,
            atol=1e-12,
        )
        t1, t2 = b1["travel"][0], b2["travel"][0]
        # mean velocities, turn and speed sum to the same; so do the second moments
        np.testing.assert_allclose(t2[:4] * n2, t1[:4] * n1, rtol=1e-9, atol=1e-12)
        second = [np.append(t[4:6] ** 2 + t[:2] ** 2, t[6] ** 2) for t in (t1, t2)]
        np.testing.assert_allclose(second[1] * n2, second[0] * n1, rtol=1e-6, atol=1e-12)
        # the net displacement is the same, over a longer time
        np.testing.assert_allclose(t2[7] * (f2 - 1), t1[7] * (f1 - 1), rtol=1e-9, atol=1e-12)


def test_real_takes_with_exact_holds_are_described_and_their_holds_are_still():
    """Real takes with a pose held for two seconds (an idle, a T-pose lead-out at the end)
    are described, every clip and window vector finite; the windows inside a hold are
    still: zero energy."""
    from app.services.describe import MotionDescriber

    describer = MotionDescriber()
    for name, motion in _takes_to_hold():
        hold = round(2.0 / motion.frame_time)
        for at in (motion.frame_count // 2, motion.frame_count - 1):
            still = held_motion(motion, at, hold)
            analysis = analyse(still)
            for vector in analysis.descriptors.values():
                assert np.all(np.isfinite(vector)), name
            windows = describer._windows(analysis.body)
            for vectors in windows.vectors.values():
                assert np.all(np.isfinite(vectors)), name
            body = analysis.body
            lead = body.lead_in_frames
            inside = np.array([[at - lead + 1, at - lead + hold]])
            kinetic = REGISTRY["kinetic"].compute_spans(body, inside)
            assert np.all(kinetic[:, :-2] == 0), name  # no joint turns


@pytest.mark.parametrize("frames", [1, 2, 3])
def test_one_two_and_three_frame_clips_are_described(frames):
    """A pose file, or a take cut to two or three frames: every vector finite (the
    velocity span shrinks to what the clip has), windows included."""
    from app.services.describe import MotionDescriber
    from tests.motion.conftest import BANDAI_FIXTURE, CMU_BVH_FIXTURE, fixture_bytes

    for fixture in (BANDAI_FIXTURE, CMU_BVH_FIXTURE):
        motion = read_bvh(fixture_bytes(fixture)).slice_frames(10, 10 + frames)
        analysis = analyse(motion)
        assert analysis.body.frame_count == frames
        for name, vector in analysis.descriptors.items():
            assert np.all(np.isfinite(vector)), (fixture, name)
        windows = MotionDescriber()._windows(analysis.body)
        assert len(windows.spans) == 1
        assert np.all(np.isfinite(windows.vectors["motion"]))
        if frames == 1:
            assert np.all(analysis.descriptors["kinetic"] == 0)


def test_a_take_that_never_moves_is_still_everywhere():
    """One real pose held for three seconds: zero energy and travel, equal part shares, no
    spread of the pose, and the same vector for every window."""
    from app.motion.descriptors.motion import PART_SHARE_FLOOR, motion_blocks
    from app.motion.spans import whole_clip
    from tests.motion.conftest import BANDAI_FIXTURE, fixture_bytes

    pose = read_bvh(fixture_bytes(BANDAI_FIXTURE)).slice_frames(20, 21)
    still = held_motion(pose, 0, 89)
    analysis = analyse(still)
    assert np.all(analysis.descriptors["kinetic"] == 0)
    blocks = motion_blocks(analysis.body, whole_clip(analysis.body.frame_count))
    np.testing.assert_array_equal(blocks["parts"], np.log(1 / 16 + PART_SHARE_FLOOR))
    assert np.all(blocks["travel"] == 0) and np.all(blocks["sideways"] == 0)
    assert np.all(np.abs(analysis.descriptors["posture"][6:]) < 1e-6)


@pytest.mark.parametrize(
    ("folder", "name"),
    [
        ("wild-bvh", "smpl-video/romp_dance2.bvh"),
        ("wild-more", "bvh-misc/HansonZhang-cuhksz_test.bvh"),
    ],
)
def test_real_takes_once_refused_for_degenerate_motion_are_described(folder, name):
    """Both hold still for a second or more; their still windows once had a mean energy of
    -1e-17, and 'degenerate motion' refused the upload."""
    from app.motion.model import ParseLimits
    from app.services.describe import MotionDescriber
    from app.services.uploads import Upload
    from tests.motion.shared import data_folder

    path = data_folder(folder) / name
    upload = Upload.from_files(file=(path.name, path.read_bytes()))
    description = MotionDescriber().describe(upload, ParseLimits())
    assert description.windows is not None
    for vector in description.vectors.values():
        assert np.all(np.isfinite(vector))
    assert np.all(np.isfinite(description.windows.vectors["motion"]))


def test_motion_measures_travel_in_leg_lengths() -> None:
    """A longer trunk (spine, neck, head twice as long) changes the body height but not the
    legs: the same walk travels as far per leg length, so ``travel`` and ``sideways`` and
    the energy block's root terms are unchanged (version 3; in body heights they were not)."""
    from app.motion.descriptors.motion import motion_blocks
    from app.motion.spans import whole_clip

    walk = walker_motion()
    offsets = walk.skeleton.offsets.copy()
    for name in ("Spine", "Spine1", "Neck", "Neck1", "Head", "Head_end"):
        offsets[walk.skeleton.index(name)] *= 2.0
    tall = dataclasses.replace(walk, skeleton=dataclasses.replace(walk.skeleton, offsets=offsets))
    short_body, tall_body = build_body(walk), build_body(tall)
    assert tall_body.height > 1.2 * short_body.height
    blocks = [motion_blocks(b, whole_clip(b.frame_count)) for b in (short_body, tall_body)]
    np.testing.assert_allclose(blocks[0]["travel"], blocks[1]["travel"], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(blocks[0]["sideways"], blocks[1]["sideways"], atol=1e-12)
    np.testing.assert_allclose(
        blocks[0]["energy"][:, -2:], blocks[1]["energy"][:, -2:], rtol=1e-9, atol=1e-12
    )


def _turns_per_frame(heading: np.ndarray) -> np.ndarray:
    """``(F - 1,)`` degrees the ``(F, 3)`` unit heading turns from frame to frame."""
    cosines = np.einsum("fa,fa->f", heading[1:], heading[:-1])
    return np.degrees(np.arccos(np.clip(cosines, -1.0, 1.0)))


def test_a_body_lying_on_its_back_heads_as_steadily_as_standing() -> None:
    """The walk laid on its back (tests/motion/test_gravity.py): its forward points at the
    sky, and the floor part of it (a fifth of its length) turned 4.1 times as much per frame
    as the upright walk's heading (``motion`` 4). The heading square to the hips' axis
    (``motion`` 5) turns about as much lying as standing."""
    from app.motion.descriptors.motion import heading_frames
    from tests.motion.conftest import CMU_BVH_FIXTURE, fixture_bytes
    from tests.motion.test_gravity import _on_the_back

    walk = read_bvh(fixture_bytes(CMU_BVH_FIXTURE))
    standing = _turns_per_frame(heading_frames(build_body(walk))[0]).mean()
    lying = _turns_per_frame(heading_frames(build_body(_on_the_back(walk)))[0]).mean()
    assert lying <= 1.5 * standing, (lying, standing)
