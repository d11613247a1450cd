"""The adaptive probe (app/index/probe_cutoff.py): a ratio measured from the index file's own
vectors, cells beyond it skipped, the full search's answers otherwise; the decision stored
beside the file, so every opening of that file (another worker, a restart) answers alike, and
measured again for a rebuilt file or a damaged or stale decision file."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import faiss
import numpy as np
import pytest

from app.index import probe_cutoff
from app.index.descriptor_index import DescriptorIndex
from app.index.frozen import FrozenIVF
from app.index.held_index import HeldIndex
from app.index.kinds import IVF, IndexOptions, with_id_map
from app.index.probe_cutoff import CUTOFFS, measure_cutoff, skip_far_cells
from tests.index.test_descriptor_index import Source

DIMENSION = 16
CENTRES = 40
NLIST = 64
NPROBE = 16


@pytest.fixture(autouse=True)
def small_indexes_decide(monkeypatch: pytest.MonkeyPatch) -> None:
    """These indexes have 64 cells (a real library's: 1,000 and more)."""
    monkeypatch.setattr(probe_cutoff, "MIN_CELLS", 1)


def clustered(count: int, seed: int) -> np.ndarray:
    """``(count, DIMENSION)`` float32 vectors around :data:`CENTRES` centres (as descriptor
    vectors cluster around the real clips, bench/README.md)."""
    rng = np.random.default_rng(seed)
    centres = np.random.default_rng(0).normal(size=(CENTRES, DIMENSION)) * 4
    return (centres[rng.integers(0, CENTRES, count)] + rng.normal(size=(count, DIMENSION))).astype(
        np.float32
    )


def ivf_file(tmp_path: Path, vectors: np.ndarray, nprobe: int = NPROBE) -> str:
    """An IVF index file of ``vectors`` (ids 1..N) written as a save writes one (a new file
    replacing the old by a rename)."""
    quantizer = faiss.IndexFlatL2(DIMENSION)
    index = faiss.IndexIVFFlat(quantizer, DIMENSION, NLIST, faiss.METRIC_L2)
    index.own_fields = True
    quantizer.this.disown()
    index.cp.seed = 1
    index.train(vectors)
    with_id_map(index)
    index.add_with_ids(vectors, np.arange(1, vectors.shape[0] + 1, dtype=np.int64))
    index.nprobe = nprobe
    path = tmp_path / "kinetic.faiss"
    faiss.write_index(index, str(tmp_path / ".kinetic.faiss.tmp"))
    (tmp_path / ".kinetic.faiss.tmp").replace(path)
    return str(path)


def opened_without_measuring(path: str, monkeypatch: pytest.MonkeyPatch) -> FrozenIVF:
    """The file opened and its decision read, failing if it had to be measured."""

    def measured(*_args: object) -> None:
        raise AssertionError("measured: the stored decision was not used")

    frozen = FrozenIVF.open(path)
    with monkeypatch.context() as patch:
        patch.setattr(probe_cutoff, "measure_cutoff", measured)
        frozen.cutoff(NPROBE)
    return frozen


def test_cells_farther_than_the_ratio_are_skipped_in_place() -> None:
    to_cells = np.array([[1.0, 1.5, 2.5, 9.0], [0.0, 0.0, 1.0, 2.0]], np.float32)
    cells = np.array([[7, 3, 5, 1], [2, 4, 6, 8]], np.int64)
    skip_far_cells(to_cells, cells, 2.0)
    # the nearest cell is always kept; a query on a centroid keeps the cells at distance 0
    assert cells.tolist() == [[7, 3, -1, -1], [2, 4, -1, -1]]


def test_a_measured_ratio_keeps_the_full_searchs_hits_for_other_queries(tmp_path: Path) -> None:
    vectors = clustered(8_000, seed=1)
    frozen = FrozenIVF.open(ivf_file(tmp_path, vectors))
    cutoff = frozen.cutoff(NPROBE)
    assert cutoff in CUTOFFS  # 40 tight clusters over 64 cells: most lists are far
    queries = clustered(300, seed=2)  # not stored, not measured
    found = kept = 0
    for query in queries:
        _, full = frozen.search(query[None], 10, nprobe=NPROBE)
        squared, adaptive = frozen.search(query[None], 10, nprobe=NPROBE, adaptive=True)
        found += len(set(full[0].tolist()))
        kept += len(set(full[0].tolist()) & set(adaptive[0].tolist()))
        # every hit at its exact distance, nearest first
        exact = ((vectors[adaptive[0] - 1] - query) ** 2).sum(axis=1)
        np.testing.assert_allclose(squared[0], exact, rtol=1e-4, atol=1e-4)
        assert (np.diff(squared[0]) >= 0).all()
    assert kept / found >= 0.99


def test_decisive_cells_too_small_for_k_mean_every_cell(tmp_path: Path) -> None:
    """A skipping search never answers fewer hits than the full one: where the decisive
    cells hold fewer than ``k`` vectors (~200 a cluster here, k = 300), every cell is
    searched. At a million clips one kinetic search of ~30,000 answered 6 hits of 10."""
    vectors = clustered(8_000, seed=1)
    frozen = FrozenIVF.open(ivf_file(tmp_path, vectors))
    assert frozen.cutoff(NPROBE) in CUTOFFS
    for query in vectors[:100]:
        full = frozen.search(query[None], 300, nprobe=NPROBE)
        squared, adaptive = frozen.search(query[None], 300, nprobe=NPROBE, adaptive=True)
        assert (full[1] >= 0).all() and (adaptive >= 0).all()
        exact = ((vectors[adaptive[0] - 1] - query) ** 2).sum(axis=1)
        np.testing.assert_allclose(squared[0], exact, rtol=1e-4, atol=1e-4)


def test_too_small_a_saving_means_every_cell_and_the_same_answers(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    vectors = clustered(5_000, seed=4)
    frozen = FrozenIVF.open(ivf_file(tmp_path, vectors, 8))
    monkeypatch.setattr(probe_cutoff, "MIN_SAVED", 1.01)  # no ratio saves more than all
    ids = np.arange(1, 201, dtype=np.int64)
    cutoff, measured = measure_cutoff(frozen.base, vectors[:200], 8, ids)
    assert cutoff is None and measured["ratio"] in CUTOFFS  # a ratio kept the hits, no more
    assert frozen.cutoff(8) is None
    for query in vectors[:50]:
        full = frozen.search(query[None], 10, nprobe=8)
        adaptive = frozen.search(query[None], 10, nprobe=8, adaptive=True)
        assert full[1].tolist() == adaptive[1].tolist()
        assert full[0].tobytes() == adaptive[0].tobytes()


def test_two_openings_of_one_file_decide_and_answer_alike(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    vectors = clustered(8_000, seed=6)
    path = ivf_file(tmp_path, vectors)
    first = FrozenIVF.open(path)  # a worker, or the server before a restart
    decided = first.cutoff(NPROBE)
    assert (tmp_path / "kinetic.probe.arrays").exists()
    again = opened_without_measuring(path, monkeypatch)  # the other worker, or after it
    assert again.cutoff(NPROBE) == decided
    for query in clustered(100, seed=7):
        one = first.search(query[None], 10, nprobe=NPROBE, adaptive=True)
        other = again.search(query[None], 10, nprobe=NPROBE, adaptive=True)
        assert one[1].tolist() == other[1].tolist()
        assert one[0].tobytes() == other[0].tobytes()
    # measured again without the stored file, the same decision: it depends on the file only
    for stored in tmp_path.glob("kinetic.probe.*"):
        stored.unlink()
    assert FrozenIVF.open(path).cutoff(NPROBE) == decided


def test_a_rebuilt_index_decides_again(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = ivf_file(tmp_path, clustered(8_000, seed=8))
    FrozenIVF.open(path).cutoff(NPROBE)
    stamped = json.loads((tmp_path / "kinetic.probe.json").read_text())["index_file"]
    path = ivf_file(tmp_path, np.random.default_rng(9).normal(size=(8_000, DIMENSION)))
    with pytest.raises(AssertionError, match="measured"):  # another file: decided again
        opened_without_measuring(path, monkeypatch)
    FrozenIVF.open(path).cutoff(NPROBE)
    assert json.loads((tmp_path / "kinetic.probe.json").read_text())["index_file"] != stamped
    opened_without_measuring(path, monkeypatch)  # ... and stored again


def test_another_nprobe_is_decided_for_itself(tmp_path: Path) -> None:
    path = ivf_file(tmp_path, clustered(8_000, seed=10))
    FrozenIVF.open(path).cutoff(NPROBE)
    frozen = FrozenIVF.open(path)
    frozen.cutoff(4)  # MOCAP_IVF_NPROBE set: the stored decision is for 16 cells
    assert json.loads((tmp_path / "kinetic.probe.json").read_text())["nprobe"] == 4


@pytest.mark.parametrize("damage", ["bytes", "stamp", "ratio"])
def test_a_damaged_or_stale_decision_is_never_used(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, damage: str
) -> None:
    path = ivf_file(tmp_path, clustered(8_000, seed=11))
    decided = FrozenIVF.open(path).cutoff(NPROBE)
    arrays, meta = tmp_path / "kinetic.probe.arrays", tmp_path / "kinetic.probe.json"
    described = json.loads(meta.read_text())
    if damage == "bytes":  # not its checksum
        data = bytearray(arrays.read_bytes())
        data[3] ^= 0xFF
        arrays.write_bytes(bytes(data))
    elif damage == "stamp":  # measured with another rule
        described["kept_hits"] = 0.5
        meta.write_text(json.dumps(described))
    else:  # a ratio the rule never picks, with a checksum that matches
        stamp = {k: v for k, v in described.items() if k not in ("arrays", "sha256")}
        probe_cutoff.write_arrays(
            tmp_path, "kinetic.probe", {"cutoff": np.array([1.234], np.float64)}, stamp
        )
    with pytest.raises(AssertionError, match="measured"):
        opened_without_measuring(path, monkeypatch)
    assert FrozenIVF.open(path).cutoff(NPROBE) == decided  # measured again, the same
    opened_without_measuring(path, monkeypatch)  # ... and stored again


def test_an_adaptive_search_sees_removed_and_added_vectors(tmp_path: Path) -> None:
    vectors = clustered(8_000, seed=5)
    frozen = FrozenIVF.open(ivf_file(tmp_path, vectors))
    assert frozen.cutoff(NPROBE) is not None
    query = vectors[99][None]
    _, before = frozen.search(query, 5, nprobe=NPROBE, adaptive=True)
    assert before[0][0] == 100  # the stored vector itself
    frozen.remove(np.array([100], np.int64))
    frozen.add(np.array([9_000], np.int64), query + 1e-3)
    _, after = frozen.search(query, 5, nprobe=NPROBE, adaptive=True)
    assert after[0][0] == 9_000 and 100 not in after[0].tolist()


@pytest.fixture()
def measures(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """Counts the decisions measured (each a call of the real :func:`measure_cutoff`)."""
    calls: list[int] = []
    real = probe_cutoff.measure_cutoff

    def counted(*args: Any) -> tuple[float | None, dict[str, float]]:
        calls.append(1)
        return real(*args)

    monkeypatch.setattr(probe_cutoff, "measure_cutoff", counted)
    return calls


def ivf_options() -> IndexOptions:
    return IndexOptions(kind=IVF, nlist=NLIST, nprobe=NPROBE, save_delay=0)


def test_a_saved_clip_index_decides_before_its_first_search(
    tmp_path: Path, measures: list[int]
) -> None:
    vectors = clustered(8_000, seed=3)
    ids = np.arange(1, vectors.shape[0] + 1, dtype=np.int64)
    index = DescriptorIndex("kinetic", DIMENSION, 1, tmp_path, options=ivf_options())
    index.replace_all(ids, vectors)  # built and written as a rebuild or fill-synthetic does
    assert index.mapped and measures == [1]
    assert (tmp_path / "kinetic.probe.arrays").exists()
    index.search(vectors[7], 5, exclude=8)  # the first search by clip: decided already
    reopened = DescriptorIndex("kinetic", DIMENSION, 1, tmp_path, options=ivf_options())
    found = reopened.read_file()
    assert not isinstance(found, str)
    reopened.load_or_rebuild(Source(ids, vectors), found)  # another worker, a restart
    hits = reopened.search(vectors[7], 5, exclude=8).ids.tolist()
    assert measures == [1] and hits == index.search(vectors[7], 5, exclude=8).ids.tolist()


def test_a_window_index_decides_nothing_ahead(tmp_path: Path, measures: list[int]) -> None:
    """Window indexes are searched in batches, which scan every cell: no decision to make."""
    vectors = clustered(8_000, seed=3)
    index = DescriptorIndex(
        "windows", DIMENSION, 1, tmp_path, options=ivf_options(), searched_by_clip=False
    )
    index.replace_all(np.arange(1, vectors.shape[0] + 1, dtype=np.int64), vectors)
    assert index.mapped and measures == []
    assert not (tmp_path / "windows.probe.arrays").exists()


def test_prepared_searches_measure_once_then_searches_read_the_decision(
    tmp_path: Path, measures: list[int]
) -> None:
    """A file from another process without its decision: the verifier thread's
    ``prepare_searches`` measures it, the first search does not (and its answers are those
    of a search deciding lazily)."""
    vectors = clustered(8_000, seed=4)
    path = ivf_file(tmp_path, vectors)
    options = IndexOptions(nprobe=NPROBE)
    lazy = HeldIndex(DIMENSION, FrozenIVF.open(path), options)
    expected = [lazy.search(vector, 5).ids.tolist() for vector in vectors[:20]]
    assert measures == [1]  # by the first search
    Path(path).with_name("kinetic.probe.arrays").unlink()
    held = HeldIndex(DIMENSION, FrozenIVF.open(path), options)
    held.prepare_searches()
    assert measures == [1, 1]
    assert [held.search(vector, 5).ids.tolist() for vector in vectors[:20]] == expected
    assert measures == [1, 1]


def test_a_query_gets_the_same_answer_in_a_batch_as_alone(tmp_path: Path) -> None:
    """The search lane (app/api/search_lane.py) scans the plain searches waiting at once in
    one call: each must get what it gets alone — also where some of the batch's decisive
    cells are too small for ``k`` (those are searched again in every cell) and others not.
    Before, a batch with one such query searched every query of it in every cell."""
    vectors = clustered(8_000, seed=1)
    frozen = FrozenIVF.open(ivf_file(tmp_path, vectors))
    assert frozen.cutoff(NPROBE) in CUTOFFS
    queries = np.concatenate([vectors[:40], clustered(40, seed=9)])
    for k in (10, 300):  # 300: more than a cluster's ~200, so some rows go to every cell
        batch_squared, batch_ids = frozen.search(queries, k, nprobe=NPROBE, adaptive=True)
        for row, query in enumerate(queries):
            squared, ids = frozen.search(query[None], k, nprobe=NPROBE, adaptive=True)
            assert batch_ids[row].tolist() == ids[0].tolist(), (k, row)
            assert batch_squared[row].tolist() == squared[0].tolist(), (k, row)
    # ... and the batch's rows that kept their decisive cells did not search every cell
    _, full_ids = frozen.search(queries, 300, nprobe=NPROBE)
    _, adaptive_ids = frozen.search(queries, 300, nprobe=NPROBE, adaptive=True)
    assert (adaptive_ids != full_ids).any(axis=1).any()


def test_nearest_many_answers_each_query_as_nearest_does(tmp_path: Path) -> None:
    vectors = clustered(8_000, seed=3)
    held = HeldIndex(DIMENSION, FrozenIVF.open(ivf_file(tmp_path, vectors)))
    rows = np.arange(0, 8_000, 97)
    excludes = [int(row) + 1 for row in rows]  # each query is a stored clip, left out
    many = held.nearest_many(vectors[rows], 10, excludes)
    assert len(many) == rows.size
    for answer, row, exclude in zip(many, rows, excludes, strict=True):
        alone = held.search(vectors[row], 10, exclude=exclude)  # the general one-query path
        assert [i for i, _ in answer] == alone.ids.tolist()
        assert [d for _, d in answer] == alone.distances.tolist()
        assert len(answer) == 10 and exclude not in [i for i, _ in answer]
