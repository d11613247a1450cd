"""Cutting BVH and AMC files to some of their frames, read back by the parsers."""

from __future__ import annotations

import numpy as np
import pytest

from app.errors import ParseError
from app.motion.formats import read_asf_amc, read_bvh
from app.motion.formats.cut import cut_amc, cut_bvh
from tests.motion.conftest import (
    BANDAI_FIXTURE,
    CMU_AMC_FIXTURE,
    CMU_ASF_FIXTURE,
    CMU_BVH_FIXTURE,
    fixture_bytes,
    fixture_text,
)


@pytest.mark.parametrize("name", [BANDAI_FIXTURE, CMU_BVH_FIXTURE])
@pytest.mark.parametrize(("first", "stop"), [(0, 1), (5, 25), (0, 40), (39, 40)])
def test_cut_bvh_keeps_the_hierarchy_and_exactly_those_frames(
    name: str, first: int, stop: int
) -> None:
    text = fixture_text(name)
    whole = read_bvh(text)
    cut = cut_bvh(text, first, stop)
    part = read_bvh(cut)
    assert part.frame_count == stop - first
    assert part.frame_time == whole.frame_time
    assert part.skeleton.names == whole.skeleton.names
    assert cut.split("MOTION")[0] == text.replace("\r\n", "\n").split("MOTION")[0]
    np.testing.assert_array_equal(part.root_translation, whole.root_translation[first:stop])
    np.testing.assert_array_equal(part.local_rotations, whole.local_rotations[first:stop])


def test_cut_bvh_tolerates_crlf_and_blank_lines_between_frames() -> None:
    text = fixture_text(BANDAI_FIXTURE)
    head, frames = text.split("Frame Time:")
    frame_time, *lines = frames.split("\n")
    messy = head + "Frame Time:" + frame_time + "\n" + "\n\n".join(lines)
    messy = messy.replace("\n", "\r\n")
    part = read_bvh(cut_bvh(messy, 3, 13))
    np.testing.assert_array_equal(part.local_rotations, read_bvh(text).local_rotations[3:13])


@pytest.mark.parametrize(("first", "stop"), [(0, 1), (10, 30), (0, 40)])
def test_cut_amc_renumbers_exactly_those_frames(first: int, stop: int) -> None:
    asf, amc = fixture_bytes(CMU_ASF_FIXTURE), fixture_text(CMU_AMC_FIXTURE)
    whole = read_asf_amc(asf, amc)
    cut = cut_amc(amc, first, stop)
    part = read_asf_amc(asf, cut)
    assert part.frame_count == stop - first
    numbers = [line for line in cut.splitlines() if line.strip().isdigit()]
    assert numbers == [str(n) for n in range(1, stop - first + 1)]
    np.testing.assert_array_equal(part.local_rotations, whole.local_rotations[first:stop])
    np.testing.assert_array_equal(part.root_translation, whole.root_translation[first:stop])


def test_cut_outside_the_frames_or_of_no_motion_is_refused() -> None:
    with pytest.raises(ValueError, match="not within"):
        cut_bvh(fixture_text(BANDAI_FIXTURE), 0, 41)
    with pytest.raises(ValueError, match="not within"):
        cut_amc(fixture_text(CMU_AMC_FIXTURE), 5, 5)
    with pytest.raises(ParseError, match="MOTION"):
        cut_bvh("HIERARCHY\nROOT a\n{\n}\n", 0, 1)
