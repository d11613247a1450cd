"""The library's typical neighbour distances, which give every search result its similarity."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from app.index.descriptor_index import DescriptorIndex
from app.index.neighbour_scale import NEIGHBOURS, NeighbourScales, Scale, measure


def line_index(tmp_path: Path, count: int) -> DescriptorIndex:
    """Points 0, 1, 2, ... on a line (and one exact copy of point 0)."""
    index = DescriptorIndex("posture", 2, 1, tmp_path)
    points = np.zeros((count, 2), np.float32)
    points[:, 0] = np.arange(count)
    points[-1] = points[0]
    index.add(np.arange(1, count + 1), points, persist=False)
    return index


def test_similarity_is_the_share_of_typical_distances_larger(tmp_path: Path) -> None:
    scale = Scale(np.array([1.0, 2.0, 3.0, 4.0]), size=5)
    assert scale.similarities([0.0, 1.0, 2.5, 4.0, 9.0]) == [
        100.0,
        75.0,
        50.0,
        0.0,
        0.0,
    ]
    assert Scale(np.empty(0), size=1).similarities([3.0]) == [100.0]


def test_typical_distances_are_each_vectors_nearest_others(tmp_path: Path) -> None:
    index = line_index(tmp_path, 40)
    scale = measure(index, None)
    # Each point's 10 nearest others on the line, the identical copy left out (distance 0:
    # the same motion twice is no neighbour).
    assert scale.size == 40 and scale.distances.min() >= 1.0
    assert scale.distances.size <= 40 * NEIGHBOURS and scale.distances.max() <= NEIGHBOURS
    assert np.all(np.diff(scale.distances) >= 0)
    # Windows: neighbours of another clip only (here: ids of one clip share id // 10).
    grouped = measure(index, lambda ids: ids // 10)
    assert grouped.distances.min() >= 1.0 and grouped.distances.mean() > scale.distances.mean()


def test_scales_follow_the_index_in_the_background(tmp_path: Path) -> None:
    index = line_index(tmp_path, 20)
    scales = NeighbourScales()
    first = scales.of("posture", index)
    assert scales.of("posture", index) is first  # cached
    more = np.zeros((20, 2), np.float32)
    more[:, 1] = 0.5  # nearer neighbours than any before
    more[:, 0] = np.arange(20)
    index.add(np.arange(100, 120), more, persist=False)
    assert scales.of("posture", index) is first  # the old one while measuring again
    for _ in range(100):
        if scales.of("posture", index) is not first:
            break
        time.sleep(0.05)
    again = scales.of("posture", index)
    assert again.size == 40 and again.distances.min() < first.distances.min()


def test_similarities_are_the_share_larger_rounded_to_one_decimal() -> None:
    """Against the definition in numpy (searchsorted, round half to even): random distances,
    the typical distances themselves (ties), and none larger or smaller than all of them."""
    rng = np.random.default_rng(5)
    for size in (1, 7, 16, 80, 1000, 3333):  # 16, 80: halves to round (6.25 %, 1.25 %)
        typical = np.sort(rng.gamma(2.0, 0.3, size))
        scale = Scale(typical, size)
        probes = np.concatenate(
            [rng.gamma(2.0, 0.3, 500), typical[rng.integers(0, size, 50)], [0.0, 1e9]]
        )
        larger = size - np.searchsorted(typical, probes, side="right")
        assert scale.similarities(probes.tolist()) == np.round(100.0 * larger / size, 1).tolist()
    assert Scale(np.empty(0), 1).similarities([0.5, 2.0]) == [100.0, 100.0]
