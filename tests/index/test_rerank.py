"""Candidates of compressed lists ranked by exact distances (app/index/rerank.py), and a clip
index of 8-bit codes (``MOCAP_CLIP_CODES=sq8``) searched by clip: the distances answered are
exactly a float32 index's, the file says what its lists hold, a second opening of it answers
alike, and a damaged or stale exact-vectors file is rebuilt from the database."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from app.config import Settings
from app.index.descriptor_index import DescriptorIndex
from app.index.kinds import FLAT, FLOAT32, IVF, SQ8, IndexOptions
from app.index.rerank import ranked, ranked_one
from app.services.library_caches import index_options
from tests.index.test_compressed import damage_exact_file
from tests.index.test_frozen import _Source  # the database's view, of given vectors

DIMENSION = 13  # padded to 16 in the lists
COUNT = 3000
K = 10


def library(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``(COUNT,)`` sorted ids with gaps and ``(COUNT, DIMENSION)`` vectors around a few
    centres (descriptor vectors cluster around the real clips)."""
    rng = np.random.default_rng(seed)
    ids = np.sort(rng.choice(10 * COUNT, COUNT, replace=False)).astype(np.int64) + 1
    centres = rng.normal(size=(12, DIMENSION)) * 3
    vectors = centres[rng.integers(0, 12, COUNT)] + rng.normal(size=(COUNT, DIMENSION))
    return ids, vectors.astype(np.float32)


def clip_index(directory: Path, codes: str = SQ8, nprobe: int = 0) -> DescriptorIndex:
    """A clip index (searched by clip: its adaptive probe and cells decided when saved);
    ``nprobe`` 0: calibrated when built."""
    options = IndexOptions(IVF, nprobe=nprobe, codes=codes)
    return DescriptorIndex("motion", DIMENSION, 1, directory, options=options)


def flat(ids: np.ndarray, vectors: np.ndarray, directory: Path) -> DescriptorIndex:
    index = DescriptorIndex("motion", DIMENSION, 1, directory, options=IndexOptions(FLAT))
    index.replace_all(ids, vectors, persist=False)
    return index


def answers(index: DescriptorIndex, ids: np.ndarray, vectors: np.ndarray) -> list[object]:
    """Searches by clip of every 37th stored clip: ``(id, distance)`` lists."""
    return [index.nearest(vectors[row], K, exclude=int(ids[row])) for row in range(0, ids.size, 37)]


def test_one_query_is_ranked_as_a_batch_is() -> None:
    ids, vectors = library(0)
    query = np.random.default_rng(1).normal(size=DIMENSION).astype(np.float32) * 3
    for count in (22, 7):  # more candidates than wanted, and fewer (padding)
        candidates = np.full(22, -1, np.int64)
        candidates[:count] = np.random.default_rng(count).choice(ids, count, replace=False)
        one = ranked_one(query, candidates, K, vectors, ids)
        batch = ranked(query[None], candidates[None], K, vectors, ids.searchsorted)
        assert one[1].tolist() == batch[1].tolist()
        assert one[0].tobytes() == batch[0].tobytes()
        found = one[1][0][one[1][0] >= 0]
        assert found.size == min(count, K)
        exact = ((vectors[ids.searchsorted(found)] - query) ** 2).sum(axis=1)
        np.testing.assert_allclose(one[0][0][: found.size], exact, rtol=1e-5)
        assert np.isinf(one[0][0][found.size :]).all()


def test_a_search_by_clip_answers_a_float32_scans_numbers(tmp_path: Path) -> None:
    ids, vectors = library(2)
    # Every cell scanned: the candidates hold the true nearest, so the answers are exact.
    index = clip_index(tmp_path / "a", nprobe=10_000)
    index.replace_all(ids, vectors)
    assert index.kind == IVF and index.codes == SQ8 and index.mapped
    exact = flat(ids, vectors, tmp_path / "flat")
    assert answers(index, ids, vectors) == answers(exact, ids, vectors)  # distances bit for bit
    # Changes held beside the mapped file (removed clips, new ones) are searched alike.
    gone = ids[5:400:3]
    fresh = np.arange(1, 41, dtype=np.int64) + 20 * COUNT
    fresh_vectors = library(3)[1][:40]
    for target in (index, exact):
        target.remove(gone, persist=False)
        target.add(fresh, fresh_vectors, persist=False)
    assert answers(index, ids, vectors) == answers(exact, ids, vectors)


def test_the_file_says_sq8_and_a_second_opening_answers_alike(tmp_path: Path) -> None:
    ids, vectors = library(4)
    first = clip_index(tmp_path)  # nprobe calibrated on re-ranked candidates
    first.replace_all(ids, vectors)
    assert first.nprobe < first._index.base.nlist  # a real probe, not every cell
    assert first.file.mapped_meta["codes"] == SQ8
    assert (tmp_path / "motion.exact.arrays").exists()
    again = clip_index(tmp_path)  # another worker, or the next start
    assert again.load_or_rebuild(_Source(ids, vectors)) is None  # used as it is
    assert again.codes == SQ8 and again.mapped
    assert answers(again, ids, vectors) == answers(first, ids, vectors)
    # Every answer at its exact distance, nearest first
    for row, found in zip(range(0, ids.size, 37), answers(again, ids, vectors), strict=True):
        hits = np.array([clip for clip, _ in found])
        exact = np.sqrt(((vectors[ids.searchsorted(hits)] - vectors[row]) ** 2).sum(axis=1))
        np.testing.assert_allclose([d for _, d in found], exact, rtol=1e-5, atol=1e-6)
        assert [d for _, d in found] == sorted(d for _, d in found)


@pytest.mark.parametrize("damage", ["damaged", "stale"])
def test_a_bad_exact_file_of_a_clip_index_is_rebuilt(tmp_path: Path, damage: str) -> None:
    ids, vectors = library(5)
    clip_index(tmp_path, nprobe=10_000).replace_all(ids, vectors)
    damage_exact_file(
        tmp_path / "motion",
        damage,
        lambda other: clip_index(other.parent, nprobe=10_000).replace_all(*library(6)),
    )
    reopened = clip_index(tmp_path, nprobe=10_000)
    assert reopened.load_or_rebuild(_Source(ids, vectors)) is not None  # rebuilt
    assert reopened.codes == SQ8
    exact = flat(ids, vectors, tmp_path / "flat")
    assert answers(reopened, ids, vectors) == answers(exact, ids, vectors)


def test_the_setting_chooses_the_clip_lists_and_switching_rebuilds(tmp_path: Path) -> None:
    assert index_options(Settings(data_dir=tmp_path)).codes == FLOAT32
    assert index_options(Settings(data_dir=tmp_path, clip_codes="sq8")).codes == SQ8
    ids, vectors = library(7)
    plain = clip_index(tmp_path, FLOAT32, nprobe=10_000)
    plain.replace_all(ids, vectors)
    switched = clip_index(tmp_path, SQ8, nprobe=10_000)
    assert switched.load_or_rebuild(_Source(ids, vectors)) is None  # converted, not repaired
    assert switched.codes == SQ8 and switched.mapped
    assert answers(switched, ids, vectors) == answers(plain, ids, vectors)
    back = clip_index(tmp_path, FLOAT32, nprobe=10_000)
    back.load_or_rebuild(_Source(ids, vectors))
    assert back.codes == FLOAT32 and not (tmp_path / "motion.exact.arrays").exists()
