"""A window's nearest query part (``MomentFinder._nearest_parts``) for a query of few parts is
chosen from the expanded form and measured for that pair only: the very numbers — part and
distance, to the last digit — of measuring every (part, window) pair from its difference,
also with windows that copy a part, near ties, a query repeating itself and any scale. Seeds
placing the very same moment share one fit, with the numbers of fitting each."""

from __future__ import annotations

import numpy as np
import pytest

from app.services.moment_arrays import same_moments
from app.services.moment_finder import DIRECT_PARTS, MomentFinder, pair_distances_of

DIMENSION = 135  # the motion descriptor's windows


def every_pair(query: np.ndarray, windows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each window's first nearest part and its distance, every pair measured."""
    difference = (query[:, None, :] - windows[None, :, :]).reshape(-1, query.shape[1])
    every = pair_distances_of(difference).reshape(len(query), len(windows))
    nearest = every.argmin(axis=0)
    return nearest, every[nearest, np.arange(len(windows))]


class _Query:
    """What ``_nearest_of_few_parts`` reads of a finder: the query's parts."""

    def __init__(self, query: np.ndarray) -> None:
        self.query = query


@pytest.mark.parametrize("seed", range(6))
def test_few_parts_give_every_pairs_numbers(seed: int) -> None:
    rng = np.random.default_rng(seed)
    for parts in range(1, DIRECT_PARTS + 1):
        scale = 10.0 ** rng.uniform(-3, 3)
        query = rng.normal(size=(parts, DIMENSION)) * scale
        if seed % 2 and parts > 1:
            query[-1] = query[0]  # a query repeating itself: every window ties
        windows = (rng.normal(size=(400, DIMENSION)) * scale).astype(np.float32).astype(float)
        copies = rng.integers(0, 400, 100)
        windows[copies] = query[rng.integers(0, parts, 100)].astype(np.float32)
        windows[:50] = query[0] + rng.normal(size=DIMENSION) * scale * 1e-7  # near ties
        found = MomentFinder._nearest_of_few_parts(_Query(query), windows)  # type: ignore[arg-type]
        expected = every_pair(query, windows)
        assert np.array_equal(found[0], expected[0])
        assert np.array_equal(found[1], expected[1])


class _Windows:
    """What ``_vectors`` reads of a finder: the query's width and the window index."""

    def __init__(self, stored: dict[int, np.ndarray]) -> None:
        self.query = np.zeros((1, DIMENSION))
        self.index = self
        self.stored = stored
        self.asked: list[int] = []

    def reconstruct_batch(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self.asked += ids.tolist()
        held = np.array([int(i) in self.stored for i in ids], bool)
        found = [self.stored[int(i)] for i in ids if int(i) in self.stored]
        return held, np.array(found, np.float32).reshape(-1, DIMENSION)


def test_vectors_gathered_this_round_are_not_read_again() -> None:
    rng = np.random.default_rng(1)
    ids = np.arange(100, dtype=np.int64) * 7
    stored = {int(i): rng.normal(size=DIMENSION).astype(np.float32) for i in ids if i % 5}
    windows = _Windows(stored)
    had = np.array([3, 4, 9, 41, 43], np.int64)  # held rows, as the region's gathered are
    wanted = np.array([1, 3, 4, 5, 9, 10, 41, 42, 99], np.int64)
    held, vectors = MomentFinder._vectors(  # type: ignore[arg-type]
        windows, ids, wanted, had, np.stack([stored[int(ids[r])] for r in had])
    )
    assert sorted(windows.asked) == sorted(int(ids[r]) for r in wanted if r not in had)
    assert held.tolist() == [int(ids[r]) in stored for r in wanted]
    expected = np.stack([stored[int(ids[r])] for r in wanted[held]]).astype(np.float64)
    assert vectors.dtype == np.float64 and np.array_equal(vectors, expected)


class _Fitting:
    """What ``_fits`` reads of a finder: the query's parts, their offsets and its length."""

    def __init__(self, query: np.ndarray, offsets: np.ndarray, seconds: float) -> None:
        self.query, self.seconds = query, seconds
        self.parts = type("Parts", (), {"offsets": offsets})()


@pytest.mark.parametrize("seed", range(4))
def test_seeds_placing_one_moment_share_its_fit_to_the_last_digit(seed: int) -> None:
    rng = np.random.default_rng(seed)
    hop, length, frame = 0.25, 1.0, 1 / 30
    counts = rng.integers(4, 30, 5)  # five clips' windows, in clip and start order
    group = np.repeat(np.arange(counts.size), counts)
    starts = np.concatenate([np.arange(c) * hop for c in counts])
    stops = starts + length
    frame_time = np.full(group.size, frame)
    stored = rng.normal(size=(group.size, DIMENSION)) * 10.0 ** rng.uniform(-2, 2)
    offsets = np.arange(int(rng.integers(1, 9))) * hop
    seconds = float(offsets[-1] + length)
    finder = _Fitting(rng.normal(size=(offsets.size, DIMENSION)), offsets, seconds)
    # Seeds anywhere, many placing the very same moment (whole short clips, clipped starts).
    seeds = rng.integers(0, group.size, 200)
    placed = np.round(rng.uniform(-1, 4, seeds.size) / frame) * frame
    placed[::3] = 0.0
    durations = counts[group[seeds]] * hop + length - hop
    spans = np.minimum(seconds, durations)
    placed = np.clip(placed, 0.0, durations - spans)
    fit = MomentFinder._fits  # type: ignore[arg-type]
    every = fit(finder, placed, spans, group, starts, stops, frame_time, seeds, stored)
    distinct, again = same_moments(group[seeds], placed)
    assert distinct.size < seeds.size
    assert len({(int(group[s]), float(p)) for s, p in zip(seeds, placed, strict=True)}) == (
        distinct.size
    )
    shared = fit(
        finder,
        placed[distinct],
        spans[distinct],
        group,
        starts,
        stops,
        frame_time,
        seeds[distinct],
        stored,
    )[again]
    assert np.array_equal(shared, every)
    for row in rng.choice(seeds.size, 10, replace=False):  # and alone, as any block gives
        one = slice(row, row + 1)
        alone = fit(
            finder, placed[one], spans[one], group, starts, stops, frame_time, seeds[one], stored
        )
        assert alone[0] == every[row]
