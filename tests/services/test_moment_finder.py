"""A window's nearest query part (``MomentFinder._nearest_parts``) for a query of few parts is
chosen from the expanded form and measured for that pair only: the very numbers — part and
distance, to the last digit — of measuring every (part, window) pair from its difference,
also with windows that copy a part, near ties, a query repeating itself and any scale."""

from __future__ import annotations

import numpy as np
import pytest

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
