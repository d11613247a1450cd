"""A window's nearest query part (``MomentFinder._nearest_parts``) for a query of few parts is
chosen from the expanded form and measured for that pair only: the very numbers — part and
distance, to the last digit — of measuring every (part, window) pair from its difference,
also with windows that copy a part, near ties, a query repeating itself and any scale."""

from __future__ import annotations

import numpy as np
import pytest

from app.services.moment_finder import DIRECT_PARTS, MomentFinder, _Known, pair_distances_of

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


def test_known_rows_merge_in_id_order_whatever_order_they_come_in() -> None:
    rng = np.random.default_rng(0)
    known = _Known(2)
    every = rng.permutation(1000)[:300].astype(np.int64)
    for batch in np.array_split(every, 7):
        known.add(batch, np.stack([batch * 2.0, batch * 3.0], axis=1))
    assert np.array_equal(known.ids, np.sort(every))
    asked = np.array([every[5], 5000, every[200], -1])
    held, rows = known.find(asked)
    assert held.tolist() == [True, False, True, False]
    assert np.array_equal(rows[held], np.stack([asked[held] * 2.0, asked[held] * 3.0], axis=1))
    assert np.isnan(rows[~held]).all()


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
