"""The display frame of stick figures and what a stored preview holds (pure numpy)."""

from __future__ import annotations

import numpy as np

from app.motion.body import build_body
from app.motion.display import (
    STORE_FPS,
    DisplayMotion,
    at_store_rate,
    body_display,
    display_up,
    stored_preview_of,
)
from app.motion.formats import read_bvh
from tests.conftest import FIXTURES_DIR


def display(frames: int, fps: float) -> DisplayMotion:
    positions = np.random.default_rng(0).normal(size=(frames, 3, 3))
    return DisplayMotion(positions, 1.0 / fps, 2, frames, 1.0 / fps)


def test_a_faster_take_is_stored_at_30_fps_on_its_own_frames() -> None:
    fast = display(41, 120.0)
    stored = at_store_rate(fast)
    assert stored.frame_time == 1.0 / STORE_FPS and stored.positions.dtype == np.float32
    # 41 frames 1/120 s apart span 1/3 s: 11 frames 1/30 s apart, every fourth one (none
    # interpolated).
    np.testing.assert_array_equal(stored.positions, fast.positions[::4].astype(np.float32))
    # What the file holds is kept, to place spans in it.
    assert (stored.lead_in_frames, stored.source_frame_count) == (2, 41)
    assert stored.source_frame_time == fast.source_frame_time


def test_a_take_at_30_fps_or_slower_keeps_its_frames() -> None:
    for fps in (30.0003, 24.0):  # files write 1/30 s as 0.0333333
        slow = display(12, fps)
        stored = at_store_rate(slow)
        assert stored.frame_time == slow.frame_time
        np.testing.assert_array_equal(stored.positions, slow.positions.astype(np.float32))


def test_the_stored_preview_of_a_body_is_its_display_at_the_store_rate() -> None:
    body = build_body(read_bvh((FIXTURES_DIR / "cmu_mb_02_01_first41.bvh").read_bytes()))
    stored = stored_preview_of(body)
    np.testing.assert_array_equal(stored.positions, at_store_rate(body_display(body)).positions)
    assert stored.positions.shape == (10, body.positions.shape[1], 3)  # 40 frames at 120 fps
    assert stored.lead_in_frames == body.lead_in_frames == 1


def test_up_is_the_nearest_axis() -> None:
    np.testing.assert_array_equal(display_up(np.array([0.3, -0.2, -0.9])), [0, 0, -1])
