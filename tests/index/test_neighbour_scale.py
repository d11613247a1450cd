"""The library's typical neighbour distances, which give every search result its similarity."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from app.index import neighbour_scale
from app.index.descriptor_index import DescriptorIndex
from app.index.kinds import IVF, IndexOptions
from app.index.neighbour_scale import NEIGHBOURS, NeighbourScales, Scale, measure
from tests.calls import count_calls
from tests.index.test_descriptor_index import Source


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


def mapped_index(tmp_path: Path) -> tuple[DescriptorIndex, np.ndarray, np.ndarray]:
    """An IVF index written to its file and mapped from it, as a rebuild leaves it."""
    rng = np.random.default_rng(3)
    vectors = (rng.normal(size=(3_000, 8)) + rng.integers(0, 6, (3_000, 1)) * 3).astype(np.float32)
    ids = np.arange(1, vectors.shape[0] + 1, dtype=np.int64)
    options = IndexOptions(kind=IVF, nlist=16, nprobe=4, save_delay=0)
    index = DescriptorIndex("motion", 8, 1, tmp_path, options=options)
    index.replace_all(ids, vectors)
    assert index.mapped
    return index, ids, vectors


def reopened(tmp_path: Path, ids: np.ndarray, vectors: np.ndarray) -> DescriptorIndex:
    """Another worker's (or a restart's) opening of the same file."""
    options = IndexOptions(kind=IVF, nlist=16, nprobe=4, save_delay=0)
    index = DescriptorIndex("motion", 8, 1, tmp_path, options=options)
    found = index.read_file()
    assert not isinstance(found, str)
    index.load_or_rebuild(Source(ids, vectors), found)
    return index


@pytest.fixture()
def measured(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """Counts the scales measured (each a call of the real :func:`measure`)."""
    return count_calls(monkeypatch, neighbour_scale, "measure")


def test_a_file_s_scale_is_kept_beside_it_and_read_by_every_opening(
    tmp_path: Path, measured: list[int]
) -> None:
    index, ids, vectors = mapped_index(tmp_path)
    first = NeighbourScales().of("motion", index)
    assert measured == [1] and (tmp_path / "motion.scale.arrays").exists()
    again = NeighbourScales().of("motion", reopened(tmp_path, ids, vectors))
    assert measured == [1]  # read, not measured
    assert again.size == first.size and again.distances.tobytes() == first.distances.tobytes()
    # Windows (grouped by clip) are another measurement of the same file.
    NeighbourScales().of("motion", index, lambda found: found // 100)
    assert measured == [1, 1]


def test_a_changed_index_a_rebuilt_file_or_a_damaged_scale_is_measured_again(
    tmp_path: Path, measured: list[int]
) -> None:
    index, ids, vectors = mapped_index(tmp_path)
    NeighbourScales().of("motion", index)
    index.add(np.array([90_000]), vectors[:1] + 1, persist=False)  # not the file's vectors
    NeighbourScales().of("motion", index)
    assert measured == [1, 1]
    index, ids, vectors = mapped_index(tmp_path)  # a rebuild: a new file
    NeighbourScales().of("motion", index)
    assert measured == [1, 1, 1]
    kept = tmp_path / "motion.scale.arrays"
    damaged = bytearray(kept.read_bytes())
    damaged[0] ^= 0xFF
    kept.write_bytes(bytes(damaged))
    NeighbourScales().of("motion", reopened(tmp_path, ids, vectors))
    assert measured == [1, 1, 1, 1]


def test_a_scale_far_from_the_index_s_size_is_not_served(tmp_path: Path) -> None:
    """A library empty (or a tenth of its size) when its scale was measured — at a server's
    start, before an import by another process — answers with a scale measured now, not
    100 % for everything while a new one is measured in the background."""
    index = line_index(tmp_path, 1)
    scales = NeighbourScales()
    scales.of("posture", index)  # the verifier thread at start
    assert scales.of("posture", index).size == 1
    points = np.zeros((30, 2), np.float32)
    points[:, 0] = np.arange(30) + 0.5
    index.add(np.arange(100, 130), points, persist=False)
    scale = scales.of("posture", index)
    assert scale.size == 31 and scale.similarities([0.75])[0] < 100.0


def test_the_median_kept_with_a_scale_is_numpys() -> None:
    rng = np.random.default_rng(3)
    for size in (0, 1, 2, 7, 1000):
        distances = np.sort(rng.uniform(0, 5, size))
        expected = float(np.median(distances)) if size else 0.0
        assert Scale(distances, size).median == expected
