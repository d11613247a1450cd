"""Cross-format twins: the same CMU capture read from ASF/AMC and from its BVH conversions."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from app.motion.formats import read_asf_amc, read_bvh
from app.motion.pipeline import ClipAnalysis, analyse, describable_body
from app.motion.skeleton_map import CANONICAL_INDEX, rest_pose
from tests.motion.shared import SHARED_DATA, requires_shared_data

pytestmark = requires_shared_data
CMU = SHARED_DATA / "cmu"
THREE_FORMAT_TRIALS = ("02_01", "02_02", "02_03", "02_04", "03_01", "03_02")


@pytest.fixture(scope="module")
def cmu_clips() -> list[tuple[str, str, ClipAnalysis]]:
    """(trial, format folder, analysis) for every CMU clip in ../shared/data."""
    clips = []
    for path in sorted(CMU.rglob("*.bvh")):
        clips.append(
            (path.stem, path.relative_to(CMU).parts[0], analyse(read_bvh(path.read_bytes())))
        )
    for amc in sorted(CMU.rglob("*.amc")):
        asf = amc.with_name(amc.stem.split("_")[0] + ".asf")
        motion = read_asf_amc(asf.read_bytes(), amc.read_bytes())
        clips.append((amc.stem, "asf-amc", analyse(motion)))
    return clips


def _distances(clips: list[tuple[str, str, ClipAnalysis]], descriptor: str) -> np.ndarray:
    vectors = np.stack([a.descriptors[descriptor] for _, _, a in clips]).astype(np.float64)
    distances = np.linalg.norm(vectors[:, None] - vectors[None], axis=2)
    np.fill_diagonal(distances, np.inf)
    return distances


def test_converters_lead_in_frames_are_dropped(cmu_clips):
    for trial, folder, analysis in cmu_clips:
        if folder == "bvh-mb":
            assert 1 <= analysis.lead_in_frames <= 2, trial  # one T-pose frame, then a jump
        elif folder == "bvh-daz":
            assert 3 <= analysis.lead_in_frames <= 6, trial  # T-pose blended in over ~4 frames
        else:
            assert analysis.lead_in_frames == 0, (folder, trial)


def test_kinetic_asf_amc_and_motionbuilder_twins_are_mutual_nearest_neighbours(cmu_clips):
    nearest = _distances(cmu_clips, "kinetic").argmin(axis=1)
    where = {(trial, folder): i for i, (trial, folder, _) in enumerate(cmu_clips)}
    pairs = [
        (i, where[(trial, "bvh-mb")])
        for (trial, folder), i in where.items()
        if folder == "asf-amc" and (trial, "bvh-mb") in where
    ]
    assert len(pairs) == 28
    for amc_index, bvh_index in pairs:
        assert nearest[amc_index] == bvh_index, cmu_clips[amc_index][0]
        assert nearest[bvh_index] == amc_index, cmu_clips[bvh_index][0]


def test_motion_finds_the_same_trial_in_another_format_for_most_three_format_clips(cmu_clips):
    nearest = _distances(cmu_clips, "motion").argmin(axis=1)
    trials = [t for t, _, _ in cmu_clips]
    chosen = [
        i
        for i, (trial, folder, _) in enumerate(cmu_clips)
        if trial in THREE_FORMAT_TRIALS and folder in ("asf-amc", "bvh-mb", "bvh-daz")
    ]
    assert len(chosen) == 18
    hits = [trials[nearest[i]] == trials[i] for i in chosen]
    print(f"motion: nearest other clip is the same trial for {np.mean(hits):.2f} of 18")
    assert np.mean(hits) >= 0.8


def _fine_labels() -> dict[str, str]:
    rows = Path(CMU / "labels.tsv").read_text().splitlines()[1:]
    return {row.split("\t")[0]: row.split("\t")[2] for row in rows}


def test_motion_is_at_least_as_accurate_as_both_papers_on_cmu_fine_labels(cmu_clips):
    labels = _fine_labels()
    trials = np.array([t for t, _, _ in cmu_clips])
    fine = np.array([labels.get(t, "") for t in trials])
    scored = fine != ""
    accuracy = {}
    for name in ("posture", "kinetic", "motion"):
        distances = _distances(cmu_clips, name)
        distances[trials[:, None] == trials[None]] = np.inf  # a clip's own twins never count
        predicted = fine[distances.argmin(axis=1)]
        accuracy[name] = float(np.mean(predicted[scored] == fine[scored]))
    print("CMU fine-label 1-NN accuracy, twins excluded:", accuracy)
    assert accuracy["motion"] >= max(accuracy["posture"], accuracy["kinetic"])


def _degrees(rotations: np.ndarray) -> np.ndarray:
    """``(...)`` angle in degrees of each ``(..., 3, 3)`` rotation."""
    cosine = (np.trace(rotations, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))


def test_daz_conversion_is_read_as_the_same_pelvis_motion_on_another_figure():
    """``posture`` misses every DAZ twin (docs/skeletons.md, "the DAZ twins"): not a misreading.

    The two files' pelvis frames agree frame for frame up to one constant turn (the figures'
    rest spines lean differently), once the converter's lead-in is dropped; the DAZ figure is
    another body (shoulders about 40 % narrower in leg lengths, a thigh shorter than the shin) and
    has no point above its head joint, so its ``head`` is the head joint itself.
    """
    trial = CMU / "asf-amc" / "02"
    original = describable_body(
        read_asf_amc((trial / "02.asf").read_bytes(), (trial / "02_01.amc").read_bytes())
    )
    daz_motion = read_bvh((CMU / "bvh-daz" / "02" / "02_01.bvh").read_bytes())
    daz = describable_body(daz_motion)

    # The DAZ file has one frame more (its rest pose first), so its frame k+1 is AMC frame k.
    start = daz.lead_in_frames - 1
    original_frames = original.pelvis_frames[start : start + daz.frame_count]
    relative = np.einsum("fba,fbc->fac", daz.pelvis_frames[: len(original_frames)], original_frames)
    assert len(relative) == daz.frame_count  # every frame has its twin
    assert np.abs(relative - relative[0]).max() < 1e-3  # one constant turn...
    assert 0.5 < _degrees(relative[0]) < 5.0  # ...of a few degrees

    def proportions(motion, body) -> tuple[float, float]:
        """Shoulder width and thigh over shin, in leg lengths, from the rest pose."""
        pose = rest_pose(motion.skeleton)[body.mapping.joints]
        at = {name: pose[CANONICAL_INDEX[name]] for name in CANONICAL_INDEX}
        thigh = np.linalg.norm(at["l_knee"] - at["l_hip"])
        shin = np.linalg.norm(at["l_ankle"] - at["l_knee"])
        return float(np.linalg.norm(at["l_shoulder"] - at["r_shoulder"]) / (thigh + shin)), float(
            thigh / shin
        )

    original_motion = read_asf_amc(
        (trial / "02.asf").read_bytes(), (trial / "02_01.amc").read_bytes()
    )
    daz_width, daz_thigh = proportions(daz_motion, daz)
    original_width, original_thigh = proportions(original_motion, original)
    assert daz_width < 0.7 * original_width
    assert daz_thigh < 0.85 < original_thigh

    head = CANONICAL_INDEX["head"]
    assert daz.mapping.joints[head] == daz.mapping.head_joint
    assert original.mapping.joints[head] != original.mapping.head_joint
