"""A mapped IVF index (app/index/frozen.py) answers exactly as the same index held in memory,
through adds, removes, re-described vectors, filtered searches, saves and reloads; and it is
the file's pages, not a copy."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from app.index.descriptor_index import DescriptorIndex
from app.index.kinds import IVF, IndexOptions

DIMENSION = 6
COUNT = 4000


def vectors_for(ids: np.ndarray, salt: int = 0) -> np.ndarray:
    rng = np.random.default_rng(int(ids.sum()) + salt)
    return rng.normal(size=(ids.size, DIMENSION)).astype(np.float32)


def pair(tmp_path: Path) -> tuple[DescriptorIndex, DescriptorIndex]:
    """The same IVF index twice: mapped from its file, and held in memory."""
    ids = np.arange(1, COUNT + 1, dtype=np.int64) * 3
    vectors = vectors_for(ids)
    mapped = DescriptorIndex("posture", DIMENSION, 1, tmp_path / "a", options=IndexOptions("ivf"))
    mapped.replace_all(ids, vectors, persist=True)
    (tmp_path / "b").mkdir()
    for name in ("posture.faiss", "posture.json"):  # the same cells, read into memory
        shutil.copy(tmp_path / "a" / name, tmp_path / "b" / name)
    held = DescriptorIndex(
        "posture", DIMENSION, 1, tmp_path / "b", options=IndexOptions("ivf", mmap=False)
    )
    assert held.load_or_rebuild(_Source(ids, vectors)) is None
    assert mapped.mapped and not held.mapped and held.kind == mapped.kind == IVF
    return mapped, held


class _Source:
    def __init__(self, ids: np.ndarray, vectors: np.ndarray) -> None:
        self._ids, self._vectors = ids, vectors

    def watermark(self) -> int:
        return 0

    def count(self) -> int:
        return int(self._ids.size)

    def ids(self) -> np.ndarray:
        return self._ids

    def vectors(self) -> tuple[np.ndarray, np.ndarray]:
        return self._ids, self._vectors

    def changed(self, since: int) -> np.ndarray:
        return np.zeros(0, np.int64)

    def vectors_of(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        rows = np.searchsorted(self._ids, ids)
        return self._ids[rows], self._vectors[rows]


def assert_same(mapped: DescriptorIndex, held: DescriptorIndex, probes: np.ndarray) -> None:
    assert mapped.size == held.size
    assert np.array_equal(np.sort(mapped.ids()), np.sort(held.ids()))
    assert np.array_equal(mapped.sorted_ids(), np.sort(held.ids()))
    rng = np.random.default_rng(5)
    allowed = np.sort(rng.choice(held.ids(), min(held.size, 50), replace=False))
    for query in probes:
        for kwargs in ({}, {"allowed": allowed}):
            a = mapped.search(query, 10, **kwargs)  # type: ignore[arg-type]
            b = held.search(query, 10, **kwargs)  # type: ignore[arg-type]
            assert np.allclose(a.distances, b.distances)
            assert set(a.ids.tolist()) == set(b.ids.tolist()) or np.allclose(
                a.distances[-1], b.distances[-1]
            )
    some = held.ids()[:: max(1, held.size // 40)]
    for vector_id in some.tolist():
        assert np.array_equal(mapped.reconstruct(vector_id), held.reconstruct(vector_id))
    kept_a, found_a = mapped.reconstruct_batch(np.append(some, -5))
    kept_b, found_b = held.reconstruct_batch(np.append(some, -5))
    assert np.array_equal(kept_a, kept_b) and np.array_equal(found_a, found_b)
    with pytest.raises(KeyError):
        mapped.reconstruct(-5)


@settings(
    max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    steps=st.lists(
        st.tuples(
            st.sampled_from(["add", "remove", "change", "save", "reload"]),
            st.lists(st.integers(1, COUNT + 300), max_size=40, unique=True),
        ),
        max_size=8,
    )
)
def test_mapped_index_answers_like_the_one_in_memory(
    tmp_path_factory: pytest.TempPathFactory, steps: list[tuple[str, list[int]]]
) -> None:
    tmp_path = tmp_path_factory.mktemp("frozen")
    mapped, held = pair(tmp_path)
    probes = np.random.default_rng(1).normal(size=(5, DIMENSION)).astype(np.float32)
    for step, (kind, numbers) in enumerate(steps):
        ids = np.asarray(numbers, np.int64) * 3
        present = set(held.ids().tolist())
        if kind == "add":
            new = np.array([i for i in ids.tolist() if i not in present], np.int64)
            for index in (mapped, held):
                index.add(new, vectors_for(new, step), persist=False)
        elif kind == "remove":
            assert mapped.remove(ids, persist=False) == held.remove(ids, persist=False)
        elif kind == "change":  # re-described, deleted and new clips, as the feed names them
            current = ids[: ids.size // 2]
            fresh = vectors_for(current, 100 + step)
            for index in (mapped, held):
                index.apply_changes(ids, current, fresh, persist=False)
        elif kind == "save":
            mapped.save()
            assert mapped.mapped
        else:  # another process: the file, then nothing missed
            mapped.save()
            mapped = DescriptorIndex(
                "posture", DIMENSION, 1, tmp_path / "a", options=IndexOptions("ivf")
            )
            found = mapped.read_file()
            assert not isinstance(found, str), found
            ids_now, vectors_now = held.all_vectors()
            order = np.argsort(ids_now)
            mapped.load_or_rebuild(_Source(ids_now[order], vectors_now[order]), found)
            assert mapped.mapped
        assert_same(mapped, held, probes)


def test_mapped_index_is_the_files_pages(tmp_path: Path) -> None:
    mapped, _ = pair(tmp_path)
    # Mapped lists cannot grow: a change lands beside them, and the file is untouched.
    before = (tmp_path / "a" / "posture.faiss").read_bytes()
    mapped.add(np.array([1, 2]), vectors_for(np.array([1, 2])), persist=False)
    mapped.remove(np.array([3, 6]), persist=False)
    assert (tmp_path / "a" / "posture.faiss").read_bytes() == before
    assert mapped.size == COUNT
    mapped.save()  # a new file with the changes, mapped in turn
    reopened = DescriptorIndex("posture", DIMENSION, 1, tmp_path / "a", options=IndexOptions("ivf"))
    found = reopened.read_file()
    assert not isinstance(found, str)
    assert found[0].ntotal == COUNT
    ids, vectors = mapped.all_vectors()
    reopened.load_or_rebuild(_Source(ids, vectors), found)
    assert reopened.mapped and not reopened._index.changed  # type: ignore[attr-defined]
    assert reopened.sorted_ids()[:3].tolist() == [1, 2, 9]


def test_vectors_gathered_as_float_rows_are_the_stored_ones(tmp_path: Path) -> None:
    mapped, held = pair(tmp_path)
    frozen = mapped._index  # type: ignore[attr-defined]
    assert frozen._rows is not None  # the codes seen as float rows (see FrozenIVF._view_rows)
    rng = np.random.default_rng(5)
    ids = rng.choice(np.arange(1, 3 * COUNT + 10), 700, replace=False).astype(np.int64)
    found, vectors = mapped.reconstruct_batch(ids)
    expected_found, expected = held.reconstruct_batch(ids)
    assert 0 < found.sum() < ids.size
    assert np.array_equal(found, expected_found) and np.array_equal(vectors, expected)
    rows, frozen._rows = frozen._rows, None  # the bytewise gather gives the same
    assert np.array_equal(mapped.reconstruct_batch(ids)[1], vectors)
    frozen._rows = rows
