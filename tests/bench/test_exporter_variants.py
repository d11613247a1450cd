"""``bench/exporter_variants.py --pairs``: variants another tool wrote, compared with their
sources by the service's readers (the CMU fixture as a GLB of the same motion, and a source
the service refuses)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from app.motion.formats import read_bvh
from bench import exporter_variants
from tests.motion.gltf_builder import build_glb

FIXTURES = Path(__file__).parents[1] / "fixtures"
CMU = FIXTURES / "cmu_mb_02_01_first41.bvh"


def test_pairs_are_compared_and_a_refused_source_is_said(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    same = tmp_path / "cmu.glb"
    same.write_bytes(build_glb(read_bvh(CMU.read_bytes())))
    broken = tmp_path / "broken.bvh"
    broken.write_text("HIERARCHY\nROOT Hips\n{\n")
    pairs = tmp_path / "pairs.txt"
    pairs.write_text(f"{CMU} {same}\n{broken} {same}\n")
    out = tmp_path / "distances.json"
    argv = ["exporter_variants.py", "--pairs", str(pairs), "--json", str(out)]
    monkeypatch.setattr(sys, "argv", argv)
    exporter_variants.main()
    (distances,) = json.loads(out.read_text()).values()
    assert set(distances) == {"posture", "kinetic", "motion"}
    assert max(distances.values()) < 1e-6  # the same motion, whichever file holds it
    assert "broken.bvh: source REFUSED" in capsys.readouterr().out
