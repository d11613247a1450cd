"""Cross-format twins: the same CMU capture read from ASF/AMC and from its BVH conversions."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from app.motion.formats import read_asf_amc, read_bvh
from app.motion.pipeline import ClipAnalysis, analyse
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
