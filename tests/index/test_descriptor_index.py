"""FAISS indexes on synthetic vectors kept in step with a database: changes, persistence and
rebuilds (the searches themselves: test_held_index.py)."""

from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from app.index.descriptor_index import DescriptorIndex
from app.index.index_set import IndexSet
from app.index.kinds import FLAT, IVF, IndexOptions
from app.index.locks import ReadWriteLock

D = 8


class Source:
    """The database as :meth:`DescriptorIndex.load_or_rebuild` sees it (in memory). Its change
    feed, as on SQLite without deletes: clip ``i`` was added at feed position ``i``; ``changes``
    adds (position, clip id) rows (a delete, a new vector)."""

    def __init__(
        self,
        ids: np.ndarray,
        vectors: np.ndarray,
        watermark: int | None = None,
        changes: list[tuple[int, int]] | None = None,
    ):
        order = np.argsort(ids)
        self._ids, self._vectors = ids[order], vectors[order]
        self._watermark = int(ids.max()) if watermark is None and ids.size else watermark or 0
        self._changes = changes or []
        self.full_reads = 0

    def watermark(self) -> int:
        return self._watermark

    def count(self) -> int:
        return int(self._ids.size)

    def ids(self) -> np.ndarray:
        return self._ids

    def vectors(self) -> tuple[np.ndarray, np.ndarray]:
        self.full_reads += 1
        return self._ids, self._vectors

    def changed(self, since: int) -> np.ndarray:
        more = [clip_id for position, clip_id in self._changes if position >= since]
        return np.unique(np.concatenate([self._ids[self._ids >= since], np.array(more, np.int64)]))

    def vectors_of(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        keep = np.isin(self._ids, ids)
        return self._ids[keep], self._vectors[keep]


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
    DescriptorIndex("posture", D, 1, tmp_path).add(
        ids, vectors, synced_to=int(ids.max()), persist=True
    )
    assert (tmp_path / "posture.faiss").is_file()
    meta = json.loads((tmp_path / "posture.json").read_text())
    assert meta["version"] == 1 and meta["count"] == 30 and meta["kind"] == FLAT
    assert meta["feed_position"] == ids.max()

    reopened = DescriptorIndex("posture", D, 1, tmp_path)
    source = Source(ids, vectors)
    assert reopened.load_or_rebuild(source) is None
    assert source.full_reads == 0  # not rebuilt
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
    DescriptorIndex("posture", D, 1, tmp_path).add(
        ids, vectors, synced_to=int(ids.max()), persist=True
    )
    damage(tmp_path)  # type: ignore[operator]
    reopened = DescriptorIndex("posture", D, 1, tmp_path)
    problem = reopened.load_or_rebuild(Source(ids, vectors))
    assert problem is not None and reason in problem
    assert reopened.size == 30
    assert reopened.search(vectors[7], 1).ids.tolist() == [ids[7]]
    # the rebuilt index was saved and now loads as it is
    again = DescriptorIndex("posture", D, 1, tmp_path)
    source = Source(ids, vectors)
    assert again.load_or_rebuild(source) is None
    assert again.size == 30 and source.full_reads == 0


def test_index_behind_the_database_catches_up_without_a_rebuild(tmp_path: Path) -> None:
    # What an import or a server killed before it saved leaves: a file missing the newest rows.
    ids, vectors = make_data(40)
    DescriptorIndex("posture", D, 1, tmp_path).add(
        ids[:25], vectors[:25], synced_to=int(ids[24]), persist=True
    )
    reopened = DescriptorIndex("posture", D, 1, tmp_path)
    source = Source(ids, vectors)
    assert reopened.load_or_rebuild(source) is None
    assert source.full_reads == 0
    assert reopened.size == 40 and reopened.synced_to == ids.max()
    assert reopened.search(vectors[33], 1).ids.tolist() == [ids[33]]
    meta = json.loads((tmp_path / "posture.json").read_text())
    assert meta["count"] == 40 and meta["feed_position"] == ids.max()  # saved after catching up


def test_index_disagreeing_with_database_is_repaired_or_rebuilt(tmp_path: Path) -> None:
    ids, vectors = make_data(30)
    DescriptorIndex("posture", D, 1, tmp_path).add(
        ids, vectors, synced_to=int(ids.max()), persist=True
    )
    # One clip deleted by another process: the index is repaired (the clip removed).
    reopened = DescriptorIndex("posture", D, 1, tmp_path)
    problem = reopened.load_or_rebuild(Source(ids[1:], vectors[1:], watermark=int(ids.max())))
    assert problem is not None and "holds 30" in problem
    assert reopened.size == 29 and int(ids[0]) not in reopened.ids().tolist()
    # A database from a backup, older than the index: everything is checked.
    DescriptorIndex("posture", D, 1, tmp_path).replace_all(ids, vectors, synced_to=10**6)
    reopened = DescriptorIndex("posture", D, 1, tmp_path)
    problem = reopened.load_or_rebuild(Source(ids, vectors))
    assert problem is not None and "another database" in problem
    assert sorted(reopened.ids().tolist()) == sorted(ids.tolist())
    # Ids that have nothing in common: the index ends up holding the database's.
    other = ids + 100_000
    reopened = DescriptorIndex("posture", D, 1, tmp_path)
    assert reopened.load_or_rebuild(Source(other, vectors, watermark=10**6)) is not None
    assert sorted(reopened.ids().tolist()) == sorted(other.tolist())
    found = reopened.search(vectors[3], 1)
    assert found.ids.tolist() == [other[3]] and found.distances[0] == pytest.approx(0)


def test_new_descriptor_version_or_dimension_rebuilds(tmp_path: Path) -> None:
    ids, vectors = make_data(5)
    DescriptorIndex("posture", D, 1, tmp_path).add(
        ids, vectors, synced_to=int(ids.max()), persist=True
    )
    v2 = DescriptorIndex("posture", D, 2, tmp_path)
    assert "version" in (v2.load_or_rebuild(Source(ids, vectors)) or "")
    wider = DescriptorIndex("posture", D + 1, 2, tmp_path)
    wide = np.hstack([vectors, np.zeros((5, 1), np.float32)])
    assert "dimension" in (wider.load_or_rebuild(Source(ids, wide)) or "")


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


# -- index kinds -------------------------------------------------------------------------


def clustered(n: int, dimension: int = 12, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Vectors around a few hundred centres, as descriptor vectors of many clips are."""
    rng = np.random.default_rng(seed)
    centres = rng.normal(size=(300, dimension)) * 3
    vectors = centres[rng.integers(0, 300, n)] + rng.normal(size=(n, dimension)) * 0.5
    return np.arange(1, n + 1, dtype=np.int64) * 2, vectors.astype(np.float32)


def test_index_kind_follows_the_options() -> None:
    auto = IndexOptions(auto_threshold=1000)
    assert auto.kind_for(999) == FLAT and auto.kind_for(1000) == IVF
    assert auto.kind_for(600, current=IVF) == IVF  # hysteresis: ivf down to half the threshold
    assert auto.kind_for(499, current=IVF) == FLAT
    assert IndexOptions(kind="flat").kind_for(10**7) == FLAT
    assert IndexOptions(kind="ivf").kind_for(5000) == IVF
    assert IndexOptions(kind="ivf").kind_for(10) == FLAT  # too few vectors to train cells
    assert IndexOptions().nlist_for(1_000_000) == 4000
    with pytest.raises(ValueError):
        IndexOptions(kind="hnsw")


def test_ivf_recall_against_exact_search(tmp_path: Path) -> None:
    ids, vectors = clustered(20_000)
    options = IndexOptions(kind="ivf")
    ivf = DescriptorIndex("posture", 12, 1, tmp_path, options=options)
    ivf.replace_all(ids, vectors, persist=False)
    exact = DescriptorIndex("posture", 12, 1, tmp_path, options=IndexOptions(kind="flat"))
    exact.replace_all(ids, vectors, persist=False)
    assert ivf.kind == IVF and exact.kind == FLAT and ivf.size == 20_000
    assert ivf.scan_cost() < exact.scan_cost() // 10
    rng = np.random.default_rng(1)
    found = total = 0
    for row in rng.choice(ids.size, 300, replace=False):
        want = set(exact.search(vectors[row], 10, exclude=int(ids[row])).ids.tolist())
        got = ivf.search(vectors[row], 10, exclude=int(ids[row]))
        assert len(got) == 10 and int(ids[row]) not in got.ids.tolist()
        assert np.all(np.diff(got.distances) >= 0)
        found += len(want & set(got.ids.tolist()))
        total += 10
    assert found / total >= 0.99


def test_ivf_remove_filter_persist_and_convert(tmp_path: Path) -> None:
    ids, vectors = clustered(5000)
    options = IndexOptions(kind="auto", auto_threshold=4000)
    index = DescriptorIndex("posture", 12, 1, tmp_path, options=options)
    index.replace_all(ids, vectors, synced_to=int(ids.max()))
    assert index.kind == IVF
    # removal
    assert index.remove([int(ids[0]), 123_456_789]) == 1
    assert index.size == 4999 and int(ids[0]) not in index.ids().tolist()
    assert int(ids[0]) not in index.search(vectors[0], 20).ids.tolist()
    np.testing.assert_array_equal(index.reconstruct(int(ids[5])), vectors[5])
    with pytest.raises(KeyError):
        index.reconstruct(int(ids[0]))
    # a label filter is exact (every cell is probed)
    allowed = ids[1::37]
    found = index.search(vectors[1], 5, allowed=allowed, exclude=int(ids[1]))
    mask = np.isin(ids, allowed) & (ids != ids[1])
    want_ids, want_distances = brute_force(ids[mask], vectors[mask], vectors[1])
    assert found.ids.tolist() == want_ids[:5].tolist()
    np.testing.assert_allclose(found.distances, want_distances[:5], rtol=1e-4)
    # saved and loaded as IVF
    index.save()
    assert json.loads((tmp_path / "posture.json").read_text())["kind"] == IVF
    reopened = DescriptorIndex("posture", 12, 1, tmp_path, options=options)
    source = Source(ids[1:], vectors[1:], watermark=int(ids.max()))
    assert reopened.load_or_rebuild(source) is None and source.full_reads == 0
    assert reopened.kind == IVF and reopened.size == 4999
    # options asking for a flat index convert it when it is loaded
    flat_options = IndexOptions(kind="flat")
    flat = DescriptorIndex("posture", 12, 1, tmp_path, options=flat_options)
    assert flat.load_or_rebuild(source) is None and flat.kind == FLAT and flat.size == 4999
    assert flat.search(vectors[9], 1).ids.tolist() == [ids[9]]
    back = DescriptorIndex("posture", 12, 1, tmp_path, options=options)
    assert back.load_or_rebuild(source) is None and back.kind == IVF
    assert sorted(back.ids().tolist()) == sorted(ids[1:].tolist())


def test_small_indexes_save_after_each_change_large_ones_on_request(tmp_path: Path) -> None:
    ids, vectors = make_data(30)
    at_once = IndexOptions(autosave_below=100, save_delay=0)
    small = DescriptorIndex("posture", D, 1, tmp_path, options=at_once)
    small.add(ids[:10], vectors[:10])
    assert json.loads((tmp_path / "posture.json").read_text())["count"] == 10
    later = DescriptorIndex("motion", D, 1, tmp_path, options=IndexOptions(save_delay=0.2))
    later.add(ids[:3], vectors[:3])
    later.add(ids[3:5], vectors[3:5])
    assert not (tmp_path / "motion.json").exists()
    deadline = time.monotonic() + 10
    while not (tmp_path / "motion.json").exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert json.loads((tmp_path / "motion.json").read_text())["count"] == 5
    large = DescriptorIndex("kinetic", D, 1, tmp_path, options=IndexOptions(autosave_below=5))
    large.add(ids, vectors)
    assert not (tmp_path / "kinetic.json").exists() and large.unsaved_changes == 30
    IndexSet({"kinetic": large}).save()
    assert json.loads((tmp_path / "kinetic.json").read_text())["count"] == 30
    assert large.unsaved_changes == 0


def test_apply_changes_adds_removes_and_replaces_idempotently(index: DescriptorIndex) -> None:
    ids, vectors = make_data(10)
    index.add(ids[:6], vectors[:6])
    # the database now: clip 0 deleted, clip 1 re-described, clips 6-9 added
    now_ids = ids[1:]
    now_vectors = vectors[1:].copy()
    now_vectors[0] += 1.0
    changed = np.concatenate([ids[:2], ids[6:]])
    wanted = now_vectors[np.isin(now_ids, changed)]
    assert index.apply_changes(changed, changed[1:], wanted, synced_to=7) == (5, 2)
    assert sorted(index.ids().tolist()) == sorted(now_ids.tolist())
    np.testing.assert_array_equal(index.reconstruct(int(ids[1])), now_vectors[0])
    assert index.synced_to == 7
    # applying the same changes again (a feed row read twice) changes nothing
    assert index.apply_changes(changed, changed[1:], wanted, synced_to=7) == (0, 0)
    assert index.size == 9
    # after a swap (the highest id held is worked out again) and a removal of the top id
    index.replace_all(now_ids, now_vectors, persist=False)
    index.remove([int(now_ids[-1])])
    top = np.array([now_ids[-1], now_ids[0]])
    changed_again = now_vectors[[-1, 0]] + 2.0
    assert index.apply_changes(top, top, changed_again) == (2, 1)
    np.testing.assert_array_equal(index.reconstruct(int(now_ids[0])), changed_again[1])
    assert index.apply_changes(top, top, changed_again) == (0, 0)


def test_index_behind_applies_deletes_from_the_feed(tmp_path: Path) -> None:
    ids, vectors = make_data(30)
    DescriptorIndex("posture", D, 1, tmp_path).add(
        ids, vectors, synced_to=int(ids.max()), persist=True
    )
    # another process deleted clip 0 (feed row after the saved position) and added none
    source = Source(ids[1:], vectors[1:], watermark=int(ids.max()) + 5,
                    changes=[(int(ids.max()) + 1, int(ids[0]))])  # fmt: skip
    reopened = DescriptorIndex("posture", D, 1, tmp_path)
    assert reopened.load_or_rebuild(source) is None  # caught up, not repaired
    assert reopened.size == 29 and source.full_reads == 0


@pytest.mark.parametrize("kind", ["flat", "ivf"])
def test_sorted_ids_follow_every_change(tmp_path: Path, kind: str) -> None:
    """sorted_ids is read from FAISS once, then kept up to date by add, remove,
    apply_changes and replace_all: always the ids FAISS holds, ascending."""
    rng = np.random.default_rng(3)
    ids, vectors = clustered(6000)
    index = DescriptorIndex("posture", 12, 1, tmp_path, options=IndexOptions(kind=kind))
    index.replace_all(ids[:4000], vectors[:4000], persist=False)
    assert index.kind == kind

    def agrees() -> None:
        np.testing.assert_array_equal(index.sorted_ids(), np.sort(index.ids()))

    agrees()
    index.add(ids[4000:4500], vectors[4000:4500], persist=False)  # above every id held
    agrees()
    low = rng.choice(ids[:4000], 50, replace=False)
    index.remove(np.concatenate([low, [10**9]]), persist=False)  # one absent
    agrees()
    index.add(low[:20], vectors[np.searchsorted(ids, low[:20])], persist=False)  # among them
    agrees()
    changed = np.concatenate([ids[4400:4600], low[20:30]])
    keep = changed[::2]
    rows = np.searchsorted(ids, keep)
    index.apply_changes(changed, keep, vectors[rows] + 1.0, persist=False)
    agrees()
    index.replace_all(ids[:100], vectors[:100], persist=False)
    agrees()


def _flip_byte(path: Path, at: int, *, keep_time: bool) -> None:
    """Change byte ``at`` (from the end: inside the vectors) in place (same size and inode);
    ``keep_time``: with the modification time put back, as a stamp cannot tell."""
    info = path.stat()
    with open(path, "r+b") as stream:
        stream.seek(at, 2)
        byte = stream.read(1)[0]
        stream.seek(at, 2)
        stream.write(bytes([byte ^ 0xFF]))
    mtime = info.st_mtime_ns if keep_time else info.st_mtime_ns + 1_000_000
    os.utime(path, ns=(info.st_atime_ns, mtime))


@pytest.mark.parametrize("verify", [True, False])
def test_a_verified_index_file_is_not_hashed_again_until_it_changes(
    tmp_path: Path, verify: bool
) -> None:
    # The checksum of an unchanged file is checked once (stamped), at the first start (verify)
    # or by the server's later check; a file changed since is hashed again and refused.
    ids, vectors = make_data(3000)
    options = IndexOptions(IVF, nlist=8)
    DescriptorIndex("posture", D, 1, tmp_path, options=options).replace_all(ids, vectors)
    path = tmp_path / "posture.faiss"

    def problem() -> str | None:
        index = DescriptorIndex("posture", D, 1, tmp_path, options=options)
        found = index.read_file(verify=verify)
        if isinstance(found, str):
            return found
        later = index.verify_file()
        index.load_or_rebuild(Source(ids, vectors), found)
        return later

    assert problem() is None
    assert (tmp_path / "posture.faiss.verified").is_file()
    _flip_byte(path, -5, keep_time=True)
    assert problem() is None  # the stamp trusted: not hashed
    _flip_byte(path, -9, keep_time=False)
    found = problem()
    assert found is not None and "checksum" in found
