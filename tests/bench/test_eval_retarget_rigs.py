"""Which rigs and clips bench/eval_retarget.py evaluates (bench/eval_retarget_rigs.py)."""

from __future__ import annotations

from pathlib import Path

import pytest

from app.errors import NoAnimation
from app.services.parser_pool import ParserPool
from bench.eval_retarget_rigs import family, read_rig_motion, rig_file_name, spread_sample
from tests.motion.conftest import BANDAI_FIXTURE

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures"


def test_a_sample_spreads_over_the_families_and_is_seeded() -> None:
    names = [f"bandai-ds1/data/walk_{i:03d}.bvh" for i in range(174)]
    names += ["wild-bvh/mixamo/a.bvh", "wild-bvh/mixamo/b.bvh", "cmu/asf-amc/01/01_01.amc"]
    picked = spread_sample(names, 6, seed=3)
    assert len(picked) == 6 and picked == sorted(set(picked))
    # One per family in turn (the first 6 of 177 clips would be Bandai's alone); a family
    # that runs out leaves its turn to the others.
    counts = {f: sum(family(names[i]) == f for i in picked) for f in map(family, names)}
    assert counts == {"bandai-ds1/data": 3, "wild-bvh/mixamo": 2, "cmu/asf-amc": 1}
    assert spread_sample(names, 6, seed=3) == picked
    assert spread_sample(names, 6, seed=4) != picked
    assert spread_sample(names, 500) == list(range(len(names)))


def test_a_rig_file_is_read_as_an_upload_also_without_frames(tmp_path: Path) -> None:
    text = (FIXTURES / BANDAI_FIXTURE).read_text()
    rest_only = tmp_path / "rest.bvh"
    head, _, _ = text.partition("MOTION")
    rest_only.write_text(head + "MOTION\nFrames: 0\nFrame Time: 0.033333\n")
    pool = ParserPool(1)
    try:
        motion = read_rig_motion(rest_only, pool, rig=True)
        assert motion.frame_count == 1
        # As a clip it is refused, as the service refuses it (no rest-only clips).
        with pytest.raises(NoAnimation):
            read_rig_motion(rest_only, pool)
    finally:
        pool.close()
    assert rig_file_name(rest_only) == "file: rest.bvh"
