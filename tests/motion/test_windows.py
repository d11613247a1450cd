"""Windows: where they lie, and the contract of ``describe_windows`` that a faster
implementation must keep (a window's vector is the descriptor of the sliced body)."""

from __future__ import annotations

import numpy as np
import pytest

from app.motion.body import Body, build_body
from app.motion.descriptors import REGISTRY
from app.motion.formats import read_asf_amc, read_bvh
from app.motion.windows import describe_windows, slice_body, window_frames, window_spans
from tests.motion.conftest import (
    BANDAI_FIXTURE,
    CMU_AMC_FIXTURE,
    CMU_ASF_FIXTURE,
    CMU_BVH_FIXTURE,
    fixture_bytes,
)
from tests.motion.holds import held
from tests.motion.shared import SHARED_DATA, requires_shared_data


def _bodies() -> list[Body]:
    return [
        build_body(read_bvh(fixture_bytes(BANDAI_FIXTURE))),
        build_body(read_bvh(fixture_bytes(CMU_BVH_FIXTURE))),
        build_body(read_asf_amc(fixture_bytes(CMU_ASF_FIXTURE), fixture_bytes(CMU_AMC_FIXTURE))),
    ]


@pytest.mark.parametrize("frame_time", [1 / 30, 1 / 120, 1 / 24])
@pytest.mark.parametrize("frames", [1, 2, 29, 30, 31, 45, 61, 240, 1001])
def test_spans_cover_the_clip_at_every_length_it_is_long_enough_for(
    frames: int, frame_time: float
) -> None:
    lengths = (1.0, 2.0, 4.0, 8.0)
    spans = window_spans(frames, frame_time, lengths)
    assert spans.dtype == np.int64 and spans.ndim == 2 and spans.shape[1] == 3
    assert len(spans) >= 1
    assert np.all(spans[:, 1] >= 0) and np.all(spans[:, 2] <= frames)
    assert np.all(spans[:, 2] > spans[:, 1])
    fitting = [i for i, length in enumerate(lengths) if window_frames(length, frame_time) <= frames]
    if not fitting:  # shorter than every length: one window over all of it
        assert spans.tolist() == [[0, 0, frames]]
        return
    assert sorted(set(spans[:, 0].tolist())) == fitting
    for index in fitting:
        rows = spans[spans[:, 0] == index]
        size = window_frames(lengths[index], frame_time)
        assert np.all(rows[:, 2] - rows[:, 1] == size)
        assert rows[0, 1] == 0 and rows[-1, 2] == frames  # covered from start to end
        steps = np.diff(rows[:, 1])
        # Every half window; every quarter for the shortest length.
        hop = max(1, int(np.floor(size / (4 if index == 0 else 2) + 0.5)))
        if len(steps):
            assert np.all(steps[:-1] == hop) and 0 < steps[-1] <= hop


def test_window_of_the_whole_clip_is_the_clip_vector() -> None:
    for body in _bodies():
        spans = np.array([[0, 0, body.frame_count]])
        names = list(REGISTRY)
        windows = describe_windows(body, spans, names)
        for name in names:
            clip = REGISTRY[name].compute(build_body_again(body))
            np.testing.assert_allclose(windows[name][0], clip, atol=1e-5, rtol=1e-5)


def build_body_again(body: Body) -> Body:
    """The same body with a fresh memo, so nothing computed before is reused."""
    return slice_body(body, 0, body.frame_count)


def test_any_window_is_the_descriptor_of_the_sliced_body() -> None:
    rng = np.random.default_rng(7)
    for body in _bodies():
        # Spans of half a second or more: the descriptors' finite differences span up to
        # 0.1 s and shrink on shorter clips, so a tiny span is not "the clip cut to it" (no
        # window or moment query is shorter than the shortest window, 1 s).
        f = body.frame_count
        least = min(f, int(np.ceil(0.5 / body.frame_time)))
        starts = rng.integers(0, f - least + 1, size=6)
        stops = np.minimum(f, starts + rng.integers(least, f + 1, size=6))
        spans = np.stack([np.zeros(6, np.int64), starts, stops], axis=1)
        spans = np.concatenate([spans, window_spans(f, body.frame_time, (0.5, 1.0))])
        windows = describe_windows(body, spans, list(REGISTRY))
        for row, (_, start, stop) in enumerate(spans.tolist()):
            part = slice_body(body, start, stop)
            assert part.frame_count == stop - start
            for name, vectors in windows.items():
                assert vectors.dtype == np.float32 and vectors.shape[0] == len(spans)
                np.testing.assert_allclose(
                    vectors[row], REGISTRY[name].compute(part), atol=1e-5, rtol=1e-5
                )


def test_spans_outside_the_body_are_refused() -> None:
    body = _bodies()[0]
    with pytest.raises(ValueError, match="within"):
        describe_windows(body, np.array([[0, 0, body.frame_count + 1]]), ["motion"])
    with pytest.raises(ValueError, match="at least one frame"):
        describe_windows(body, np.array([[0, 5, 5]]), ["motion"])


@requires_shared_data
def test_windows_of_a_real_take_match_the_sliced_body() -> None:
    path = sorted((SHARED_DATA / "bandai-ds1" / "data").glob("*.bvh"))[0]
    body = build_body(read_bvh(path.read_bytes()))
    spans = window_spans(body.frame_count, body.frame_time)
    windows = describe_windows(body, spans, ["motion"])
    for row in range(0, len(spans), max(1, len(spans) // 8)):
        _, start, stop = spans[row].tolist()
        expected = REGISTRY["motion"].compute(slice_body(body, start, stop))
        np.testing.assert_allclose(windows["motion"][row], expected, atol=1e-5, rtol=1e-5)


# ------------------------------------------------------------------------------ still stretches


def _bodies_with_real_takes() -> list[Body]:
    bodies = _bodies()
    bandai = SHARED_DATA / "bandai-ds1" / "data" / "dataset-1_dance-short_normal_001.bvh"
    if bandai.is_file():
        bodies.append(build_body(read_bvh(bandai.read_bytes())))
    return bodies


@pytest.mark.parametrize("extra", [1, 5, 37, 240])
def test_inserting_or_removing_a_still_stretch_changes_no_window_outside_it(extra: int) -> None:
    """Hold frame ``at`` for ``extra`` more frames. Every window that ends by frame ``at`` is
    the same window of the longer take, and every window that starts at ``at`` or later is
    the same window ``extra`` frames later, for every descriptor: equal up to float64
    rounding, which is 1e-9 relative for means and at most 1e-6 absolute for a standard
    deviation near 0 (computed from moments, it is the square root of a difference at
    rounding level; the stored float32 vectors resolve about 1e-7 of their values). Read
    backwards, removing the stretch changes nothing else either. Windows that hold part of
    the stretch change, as they should: they describe it."""
    rng = np.random.default_rng(extra)
    for body in _bodies_with_real_takes():
        f = body.frame_count
        at = f // 2
        longer = held(body, at, extra)
        assert longer.frame_count == f + extra
        starts = rng.integers(0, at, size=8)
        before = np.stack([starts, np.minimum(at + 1, starts + rng.integers(1, f, 8))], axis=1)
        starts = rng.integers(at, f, size=8)
        after = np.stack([starts, np.minimum(f, starts + rng.integers(1, f, 8))], axis=1)
        spans = np.concatenate([before, after, [[0, at + 1], [at, f]]])
        moved = spans + np.where(spans[:, :1] >= at, extra, 0)
        for name, descriptor in REGISTRY.items():
            original = descriptor.compute_spans(body, spans)
            again = descriptor.compute_spans(longer, moved)
            assert np.all(np.isfinite(again)), name
            np.testing.assert_allclose(again, original, rtol=1e-9, atol=1e-6, err_msg=name)


def test_a_window_inside_a_still_stretch_is_still() -> None:
    """Still is a value, not an error: zero energy, equal part shares, no travel, no spread."""
    from app.motion.descriptors.motion import PART_SHARE_FLOOR, motion_blocks

    for body in _bodies_with_real_takes():
        at = body.frame_count // 3
        longer = held(body, at, 150)
        inside = np.array([[at + 10, at + 140]])
        blocks = motion_blocks(longer, inside)
        assert np.all(blocks["energy"] == 0)
        np.testing.assert_array_equal(blocks["parts"], np.log(1 / 16 + PART_SHARE_FLOOR))
        assert np.all(blocks["travel"] == 0) and np.all(blocks["sideways"] == 0)
        # No spread: a standard deviation from moments is 0 up to the square root of a
        # rounding-level difference between a constant's mean square and squared mean
        # (sums over a few thousand frames: sqrt(1e-13), below 1e-6 of a unit direction).
        assert np.all(np.abs(blocks["limbs"][:, 30:]) < 1e-6)
        posture = REGISTRY["posture"].compute_spans(longer, inside)[0]
        assert np.all(np.abs(posture[6:]) < 1e-6) and np.any(posture[:6] != 0)
        assert np.all(REGISTRY["kinetic"].compute_spans(longer, inside) == 0)
