"""Searches of an index held in memory (app/index/held_index.py) on synthetic vectors: exact
Euclidean neighbours, the query clip left out, fewer vectors than asked, id filters, and the
stored vectors read back. The indexes are filled through :class:`DescriptorIndex`, which
builds on :class:`HeldIndex`."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from app.index.descriptor_index import DescriptorIndex
from app.index.kinds import IndexOptions
from tests.index.test_descriptor_index import D, brute_force, clustered, make_data


@pytest.fixture
def index(tmp_path: Path) -> DescriptorIndex:
    return DescriptorIndex("posture", D, 1, tmp_path)


def test_search_is_exact_euclidean(index: DescriptorIndex) -> None:
    ids, vectors = make_data(50)
    index.add(ids, vectors)
    query = np.random.default_rng(1).normal(size=D).astype(np.float32)
    found = index.search(query, 10)
    want_ids, want_distances = brute_force(ids, vectors, query)
    assert found.ids.tolist() == want_ids[:10].tolist()
    np.testing.assert_allclose(found.distances, want_distances[:10], rtol=1e-4)
    assert np.all(np.diff(found.distances) >= 0)


def test_search_excludes_the_query_clip_without_losing_a_result(index: DescriptorIndex) -> None:
    ids, vectors = make_data(20)
    index.add(ids, vectors)
    found = index.search(vectors[3], 5, exclude=int(ids[3]))
    assert len(found) == 5 and int(ids[3]) not in found.ids.tolist()
    want_ids, _ = brute_force(ids, vectors, vectors[3])
    assert found.ids.tolist() == want_ids[1:6].tolist()


def test_k_larger_than_library_returns_everything_without_padding(
    index: DescriptorIndex,
) -> None:
    ids, vectors = make_data(4)
    index.add(ids, vectors)
    assert sorted(index.search(vectors[0], 10).ids.tolist()) == sorted(ids.tolist())
    assert len(index.search(vectors[0], 10, exclude=int(ids[0]))) == 3
    empty = DescriptorIndex("kinetic", D, 1, index.directory)
    assert len(empty.search(vectors[0], 5)) == 0


def test_allowed_ids_filter_is_exact(index: DescriptorIndex) -> None:
    ids, vectors = make_data(100)
    index.add(ids, vectors)
    allowed = ids[::7]
    found = index.search(vectors[0], 5, allowed=allowed, exclude=int(ids[0]))
    mask = np.isin(ids, allowed) & (ids != ids[0])
    want_ids, want_distances = brute_force(ids[mask], vectors[mask], vectors[0])
    assert found.ids.tolist() == want_ids[:5].tolist()
    np.testing.assert_allclose(found.distances, want_distances[:5], rtol=1e-4)
    assert len(index.search(vectors[0], 5, allowed=np.array([], np.int64))) == 0


@pytest.mark.parametrize("kind", ["flat", "ivf"])
def test_reconstruct_batch_returns_the_stored_vectors_and_says_which_are_held(
    tmp_path: Path, kind: str
) -> None:
    ids, vectors = clustered(5000)
    index = DescriptorIndex("posture", 12, 1, tmp_path, options=IndexOptions(kind=kind))
    index.replace_all(ids, vectors, persist=False)
    assert index.kind == kind
    rows = np.array([4999, 3, 77, 3])
    held, got = index.reconstruct_batch(ids[rows])
    assert held.all()
    np.testing.assert_array_equal(got, vectors[rows])
    absent = int(ids.max()) + 1
    held, got = index.reconstruct_batch(np.array([ids[5], absent, ids[9]]))
    assert held.tolist() == [True, False, True]
    np.testing.assert_array_equal(got, vectors[[5, 9]])
    held, got = index.reconstruct_batch(np.zeros(0, np.int64))
    assert held.size == 0 and got.shape == (0, 12)
