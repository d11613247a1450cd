"""An IVF index of compressed (8-bit) lists with its exact vectors beside it
(``MOCAP_WINDOW_CODES=sq8``, app/index/frozen.py): where every cell is scanned, its answers
are exactly a flat float32 index's; it survives saves, reloads and changes; and a missing,
stale or damaged exact-vectors file is noticed and the index rebuilt from the database."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from app.index.array_file import TOKEN_BYTES
from app.index.descriptor_index import DescriptorIndex
from app.index.kinds import FLAT, IVF, SQ8, IndexOptions
from tests.index.test_frozen import _Source  # the database's view, of given vectors

DIMENSION = 13  # padded to 16 in the lists
COUNT = 3000
K = 40


def library(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    ids = np.sort(rng.choice(10 * COUNT, COUNT, replace=False)).astype(np.int64) + 1
    return ids, rng.normal(size=(COUNT, DIMENSION)).astype(np.float32)


def every_cell(directory: Path) -> DescriptorIndex:
    # nprobe above nlist: FAISS scans every cell, so the candidates hold the true nearest
    options = IndexOptions(IVF, nprobe=10_000, codes=SQ8)
    return DescriptorIndex("windows-motion-1s", DIMENSION, 1, directory, options=options)


def flat(ids: np.ndarray, vectors: np.ndarray, directory: Path) -> DescriptorIndex:
    index = DescriptorIndex("flat", DIMENSION, 1, directory, options=IndexOptions(FLAT))
    index.replace_all(ids, vectors, persist=False)
    return index


def assert_same_answers(index: DescriptorIndex, exact: DescriptorIndex) -> None:
    queries = np.random.default_rng(9).normal(size=(25, DIMENSION)).astype(np.float32)
    distances, ids = index.search_batch(queries, K)
    expected_distances, expected_ids = exact.search_batch(queries, K)
    assert np.array_equal(ids, expected_ids)
    assert np.allclose(distances, expected_distances, rtol=1e-5, atol=1e-6)
    allowed = exact.sorted_ids()[::3]
    _, filtered = index.search_batch(queries[:5], K, allowed=allowed)
    assert np.array_equal(filtered, exact.search_batch(queries[:5], K, allowed=allowed)[1])


def test_every_cell_scanned_answers_like_exact_search(tmp_path: Path) -> None:
    ids, vectors = library()
    index = every_cell(tmp_path / "a")
    index.replace_all(ids, vectors)  # built, saved, then mapped with its exact vectors
    assert index.kind == IVF and index.codes == SQ8 and index.mapped
    assert (tmp_path / "a" / "windows-motion-1s.exact.arrays").exists()
    exact = flat(ids, vectors, tmp_path / "b")
    assert_same_answers(index, exact)
    # Vectors read back are the exact ones, not the lossy codes.
    found, held = index.reconstruct_batch(ids[::7])
    assert found.all() and np.array_equal(held, vectors[::7])
    # Changes beside the mapped file, then saved into a new one.
    gone, fresh = ids[:50], np.arange(1, 31, dtype=np.int64) * 7 + 10 * COUNT
    fresh_vectors = np.random.default_rng(3).normal(size=(30, DIMENSION)).astype(np.float32)
    for target in (index, exact):
        target.remove(gone, persist=False)
        target.add(fresh, fresh_vectors, persist=False)
    assert_same_answers(index, exact)
    index.save()
    assert index.mapped and index.size == COUNT - 50 + 30
    assert_same_answers(index, exact)


def test_reloaded_from_its_files_it_answers_the_same(tmp_path: Path) -> None:
    ids, vectors = library(1)
    every_cell(tmp_path).replace_all(ids, vectors)
    reopened = every_cell(tmp_path)
    assert reopened.load_or_rebuild(_Source(ids, vectors)) is None
    assert reopened.codes == SQ8 and reopened.mapped
    assert_same_answers(reopened, flat(ids, vectors, tmp_path / "flat"))


def damage_exact_file(stem: Path, damage: str, write_other: Callable[[Path], object]) -> None:
    """Spoil the exact vectors beside the index file ``stem`` (``<stem>.exact.arrays``):
    ``missing``, ``damaged`` (one byte of one vector) or ``stale`` (another index file's,
    which ``write_other`` writes as ``<dir>/other/<stem name>``: a save that died half way)."""
    path = stem.with_name(stem.name + ".exact.arrays")
    if damage == "missing":
        path.unlink()
    elif damage == "damaged":
        data = bytearray(path.read_bytes())
        data[len(data) // 2] ^= 0xFF  # one number of one vector
        path.write_bytes(bytes(data))
    else:
        other = stem.parent / "other" / stem.name
        write_other(other)
        for suffix in (".exact.arrays", ".exact.json"):
            name = stem.name + suffix
            (stem.parent / name).write_bytes((other.parent / name).read_bytes())


@pytest.mark.parametrize("damage", ["missing", "damaged", "stale"])
def test_a_bad_exact_vectors_file_is_rebuilt_from_the_database(tmp_path: Path, damage: str) -> None:
    ids, vectors = library(2)
    every_cell(tmp_path).replace_all(ids, vectors)
    damage_exact_file(
        tmp_path / "windows-motion-1s",
        damage,
        lambda other: every_cell(other.parent).replace_all(*library(3)),
    )
    reopened = every_cell(tmp_path)
    assert reopened.load_or_rebuild(_Source(ids, vectors)) is not None  # rebuilt
    assert reopened.codes == SQ8
    assert_same_answers(reopened, flat(ids, vectors, tmp_path / "flat"))
    again = every_cell(tmp_path)  # and saved whole again
    assert again.load_or_rebuild(_Source(ids, vectors)) is None


def test_a_damaged_exact_file_mapped_unchecked_is_caught_by_the_later_check(
    tmp_path: Path,
) -> None:
    ids, vectors = library(4)
    every_cell(tmp_path).replace_all(ids, vectors)
    path = tmp_path / "windows-motion-1s.exact.arrays"
    data = bytearray(path.read_bytes())
    data[-5 - TOKEN_BYTES] ^= 0xFF  # a vector (the file ends with its write's token)
    path.write_bytes(bytes(data))
    server = every_cell(tmp_path)
    found = server.read_file(verify=False)  # as a server starts: checksums later
    assert not isinstance(found, str)
    problem = server.verify_file()
    assert problem is not None and "exact" in problem


def test_switching_codes_rebuilds_the_lists_from_the_vectors(tmp_path: Path) -> None:
    ids, vectors = library(5)
    plain = DescriptorIndex(
        "windows-motion-1s", DIMENSION, 1, tmp_path, options=IndexOptions(IVF, nprobe=10_000)
    )
    plain.replace_all(ids, vectors)
    assert plain.codes == "float32"
    switched = every_cell(tmp_path)
    switched.load_or_rebuild(_Source(ids, vectors))
    assert switched.codes == SQ8 and switched.mapped
    assert_same_answers(switched, flat(ids, vectors, tmp_path / "flat"))


def test_cells_to_scan_are_calibrated_on_re_ranked_candidates(tmp_path: Path) -> None:
    # Near-copies of the same motion (windows of similar takes): 8-bit codes cannot order
    # them, their exact vectors can. Calibrated on the codes alone, every cell was scanned.
    rng = np.random.default_rng(6)
    centres = rng.normal(size=(300, DIMENSION)).astype(np.float32)
    vectors = np.repeat(centres, 20, axis=0) + rng.normal(0, 1e-3, (6000, DIMENSION)).astype(
        np.float32
    )
    ids = np.arange(1, 6001, dtype=np.int64)
    scanned = {}
    for codes in ("float32", SQ8):
        index = DescriptorIndex(
            f"windows-{codes}", DIMENSION, 1, tmp_path, options=IndexOptions(IVF, codes=codes)
        )
        index.replace_all(ids, vectors)
        scanned[codes] = index.nprobe
        cells = index._index.base.nlist  # type: ignore[attr-defined]
    assert scanned[SQ8] <= 2 * scanned["float32"] < cells
