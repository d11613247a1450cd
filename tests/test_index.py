"""FAISS indexes on synthetic vectors: exact neighbours, filters, persistence and rebuilds."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import numpy as np
import pytest

from app.index import DescriptorIndex, IndexSet, ReadWriteLock

D = 8


def make_data(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    ids = np.arange(10, 10 + 3 * n, 3, dtype=np.int64)  # ids are not positions
    return ids, rng.normal(size=(n, D)).astype(np.float32)


def brute_force(
    ids: np.ndarray, vectors: np.ndarray, query: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    distances = np.linalg.norm(vectors.astype(np.float64) - query, axis=1)
    order = np.argsort(distances, kind="stable")
    return ids[order], distances[order]


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


def test_remove(index: DescriptorIndex) -> None:
    ids, vectors = make_data(10)
    index.add(ids, vectors)
    assert index.remove([int(ids[2]), 99999]) == 1
    assert index.size == 9 and int(ids[2]) not in index.ids().tolist()
    assert int(ids[2]) not in index.search(vectors[2], 9).ids.tolist()
    with pytest.raises(KeyError):
        index.reconstruct(int(ids[2]))
    np.testing.assert_array_equal(index.reconstruct(int(ids[3])), vectors[3])


def test_rejects_wrong_dimension_and_non_finite(index: DescriptorIndex) -> None:
    with pytest.raises(ValueError):
        index.add([1], np.zeros((1, D + 1), np.float32))
    with pytest.raises(ValueError):
        index.add([1], np.full((1, D), np.nan, np.float32))
    with pytest.raises(ValueError):
        index.search(np.zeros(D - 1, np.float32), 3)


def test_persisted_index_is_loaded_when_it_matches(tmp_path: Path) -> None:
    ids, vectors = make_data(30)
    DescriptorIndex("posture", D, 1, tmp_path).add(ids, vectors)
    assert (tmp_path / "posture.faiss").is_file()
    meta = json.loads((tmp_path / "posture.json").read_text())
    assert meta["version"] == 1 and meta["count"] == 30

    def must_not_rebuild() -> tuple[np.ndarray, np.ndarray]:
        raise AssertionError("rebuilt although the file matched")

    reopened = DescriptorIndex("posture", D, 1, tmp_path)
    assert reopened.load_or_rebuild(ids[::-1], must_not_rebuild) is None
    assert reopened.search(vectors[5], 3).ids.tolist()[0] == ids[5]


def _damage_truncate(directory: Path) -> None:
    path = directory / "posture.faiss"
    path.write_bytes(path.read_bytes()[:100])


def _damage_flip_byte(directory: Path) -> None:
    path = directory / "posture.faiss"
    data = bytearray(path.read_bytes())
    data[-5] ^= 0xFF  # inside the vectors: only the checksum notices
    path.write_bytes(bytes(data))


def _damage_garbage_meta(directory: Path) -> None:
    (directory / "posture.json").write_text("{not json")


@pytest.mark.parametrize(
    ("damage", "reason"),
    [
        (lambda d: (d / "posture.faiss").unlink(), "missing"),
        (lambda d: (d / "posture.json").unlink(), "missing"),
        (_damage_truncate, "checksum"),
        (_damage_flip_byte, "checksum"),
        (_damage_garbage_meta, "unreadable"),
    ],
)
def test_damaged_index_is_rebuilt(tmp_path: Path, damage: object, reason: str) -> None:
    ids, vectors = make_data(30)
    DescriptorIndex("posture", D, 1, tmp_path).add(ids, vectors)
    damage(tmp_path)  # type: ignore[operator]
    reopened = DescriptorIndex("posture", D, 1, tmp_path)
    problem = reopened.load_or_rebuild(ids, lambda: (ids, vectors))
    assert problem is not None and reason in problem
    assert reopened.size == 30
    assert reopened.search(vectors[7], 1).ids.tolist() == [ids[7]]
    # the rebuilt index was saved and now loads as it is
    again = DescriptorIndex("posture", D, 1, tmp_path)
    assert again.load_or_rebuild(ids, lambda: (ids[:0], vectors[:0])) is None
    assert again.size == 30


def test_index_disagreeing_with_database_is_rebuilt(tmp_path: Path) -> None:
    ids, vectors = make_data(30)
    DescriptorIndex("posture", D, 1, tmp_path).add(ids, vectors)
    other_ids = ids.copy()
    other_ids[0] = 1  # same count, one different id
    for expected, reason in ((ids[:-1], "holds 30"), (other_ids, "ids differ")):
        reopened = DescriptorIndex("posture", D, 1, tmp_path)
        problem = reopened.load_or_rebuild(expected, lambda e=expected: (e, vectors[: e.size]))
        assert problem is not None and reason in problem
        DescriptorIndex("posture", D, 1, tmp_path).replace_all(ids, vectors)


def test_new_descriptor_version_or_dimension_rebuilds(tmp_path: Path) -> None:
    ids, vectors = make_data(5)
    DescriptorIndex("posture", D, 1, tmp_path).add(ids, vectors)
    v2 = DescriptorIndex("posture", D, 2, tmp_path)
    assert "version" in (v2.load_or_rebuild(ids, lambda: (ids, vectors)) or "")
    wider = DescriptorIndex("posture", D + 1, 2, tmp_path)
    wide = np.hstack([vectors, np.zeros((5, 1), np.float32)])
    assert "dimension" in (wider.load_or_rebuild(ids, lambda: (ids, wide)) or "")


def test_index_set_adds_and_removes_everywhere(tmp_path: Path) -> None:
    indexes = IndexSet(
        {
            "posture": DescriptorIndex("posture", D, 1, tmp_path),
            "kinetic": DescriptorIndex("kinetic", 3, 1, tmp_path),
        }
    )
    indexes.add([1, 2], {"posture": np.ones((2, D)), "kinetic": np.zeros((2, 3))})
    assert indexes.sizes() == {"posture": 2, "kinetic": 2}
    indexes.remove([1])
    assert indexes.sizes() == {"posture": 1, "kinetic": 1}


def test_searches_during_writes_see_whole_clips(index: DescriptorIndex) -> None:
    ids, vectors = make_data(400)
    stop = threading.Event()
    errors: list[BaseException] = []

    def searcher() -> None:
        try:
            while not stop.is_set():
                found = index.search(vectors[0], 400)
                assert len(set(found.ids.tolist())) == len(found)
                assert set(found.ids.tolist()) <= set(ids.tolist())
        except BaseException as exc:  # reported below
            errors.append(exc)

    threads = [threading.Thread(target=searcher) for _ in range(3)]
    for t in threads:
        t.start()
    for start in range(0, 400, 20):
        index.add(ids[start : start + 20], vectors[start : start + 20], persist=False)
        index.remove(ids[start : start + 5], persist=False)
    stop.set()
    for t in threads:
        t.join()
    assert not errors
    assert index.size == 300


def test_read_write_lock_excludes_writers() -> None:
    lock = ReadWriteLock()
    state = {"readers": 0, "writers": 0, "bad": False}
    guard = threading.Lock()

    def reader() -> None:
        for _ in range(200):
            with lock.read():
                with guard:
                    state["readers"] += 1
                    state["bad"] |= state["writers"] > 0
                with guard:
                    state["readers"] -= 1

    def writer() -> None:
        for _ in range(200):
            with lock.write():
                with guard:
                    state["writers"] += 1
                    state["bad"] |= state["readers"] > 0 or state["writers"] > 1
                with guard:
                    state["writers"] -= 1

    threads = [threading.Thread(target=f) for f in (reader, reader, writer, writer)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not state["bad"]
