"""A small clip library on disk for the evaluation tests, built from the test fixtures."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from tests.conftest import FIXTURES_DIR


def _fixture(name: str) -> Path:
    path = FIXTURES_DIR / name
    if not path.is_file():
        pytest.skip(f"test fixture {path} is absent")
    return path


def _shorter_bvh(source: Path, target: Path, frames: int) -> None:
    """A copy of a BVH keeping only its first ``frames`` frames (a second, different clip)."""
    lines = source.read_text().splitlines(keepends=True)
    start = next(i for i, line in enumerate(lines) if line.startswith("Frames:"))
    lines[start] = f"Frames: {frames}\n"
    target.write_text("".join(lines[: start + 2 + frames]))


def clip_tree(root: Path) -> Path:
    """A small library: one CMU trial as ASF/AMC and as MotionBuilder BVH, two Bandai-named
    clips, an unreadable BVH and an AMC without a skeleton."""
    clips = root / "clips"
    for folder in ("asf-amc/02", "bvh-mb/02", "bandai", "orphan"):
        (clips / folder).mkdir(parents=True)
    shutil.copy(_fixture("cmu_02.asf"), clips / "asf-amc/02/02.asf")
    shutil.copy(_fixture("cmu_02_01_first40.amc"), clips / "asf-amc/02/02_01.amc")
    shutil.copy(_fixture("cmu_02_01_first40.amc"), clips / "orphan/09_01.amc")
    shutil.copy(_fixture("cmu_mb_02_01_first41.bvh"), clips / "bvh-mb/02/02_01.bvh")
    bandai = _fixture("bandai_walk_normal_001_first40.bvh")
    shutil.copy(bandai, clips / "bandai/dataset-1_walk_normal_001.bvh")
    _shorter_bvh(bandai, clips / "bandai/dataset-1_walk_happy_001.bvh", 25)
    (clips / "bandai/broken.bvh").write_text("HIERARCHY\nROOT Hips\n{\n")
    (root / "labels.tsv").write_text(
        "clip\taction\n02_01\twalk\ndataset-1_walk_normal_001\twalk\n"
        "dataset-1_walk_happy_001\trun\nbroken\twalk\n"
    )
    return clips
