"""The cells of an IVF search found through a graph over the centroids (app/index/cells.py):
kept only when it finds the cells a scan finds, and then the answers are the scan's, bit for
bit; filtered searches still probe every cell."""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

import faiss
import numpy as np
import pytest

from app.index import cells as cells_module
from app.index import frozen as frozen_module
from app.index.array_file import write_arrays
from app.index.descriptor_index import DescriptorIndex
from app.index.frozen import FrozenIVF
from app.index.kinds import IndexOptions
from tests.calls import count_calls

DIMENSION = 16
COUNT = 12_000
CELLS = 200


@pytest.fixture
def small_graphs(monkeypatch: pytest.MonkeyPatch) -> None:
    """Graphs tried for indexes of a test's size (the service tries them from 1,000 cells,
    when the scan of the centroids is not already quick)."""
    monkeypatch.setattr(cells_module, "GRAPH_MIN_CELLS", 100)
    monkeypatch.setattr(frozen_module, "GRAPH_MIN_CELLS", 100)
    monkeypatch.setattr(cells_module, "CROWDED", float("inf"))
    monkeypatch.setattr(cells_module, "QUICK_SCAN", 0.0)


def clustered(rng: np.random.Generator, count: int) -> np.ndarray:
    """``(count, DIMENSION)`` vectors around 300 centres, as descriptors of similar clips lie."""
    centres = rng.normal(size=(300, DIMENSION)) * 3
    return (centres[rng.integers(0, 300, count)] + rng.normal(size=(count, DIMENSION))).astype(
        np.float32
    )


@pytest.fixture
def index_file(tmp_path: Path, small_graphs: None) -> tuple[Path, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(7)
    ids = np.arange(1, COUNT + 1, dtype=np.int64) * 2
    vectors = clustered(rng, COUNT)
    index = DescriptorIndex(
        "motion", DIMENSION, 1, tmp_path, options=IndexOptions("ivf", nlist=CELLS)
    )
    index.replace_all(ids, vectors, persist=True)
    assert index.mapped
    return index.path, ids, vectors


def without_graph(path: Path) -> FrozenIVF:
    frozen = FrozenIVF.open(str(path))
    frozen._cells_started = True  # never builds one
    return frozen


def test_a_kept_graph_gives_the_scans_answers_bit_for_bit(
    index_file: tuple[Path, np.ndarray, np.ndarray], monkeypatch: pytest.MonkeyPatch
) -> None:
    path, _ids, vectors = index_file
    monkeypatch.setattr(cells_module, "KEEP_BELOW", float("inf"))  # kept when the cells agree
    graph = FrozenIVF.open(str(path))
    graph.build_cells()
    assert graph.cells is not None and graph.cells.count == CELLS
    scan = without_graph(path)
    nprobe = graph.base_nprobe
    rng = np.random.default_rng(3)
    queries = np.concatenate([vectors[rng.choice(COUNT, 150, replace=False)], clustered(rng, 150)])
    for query in queries:
        q = query.reshape(1, -1)
        found = graph.search(q, 11, nprobe=nprobe)
        expected = scan.search(q, 11, nprobe=nprobe)
        assert np.array_equal(found[1], expected[1])
        assert np.array_equal(found[0], expected[0])  # the same float32 distances
    # Another number of cells than the graph was checked for: the scan's way.
    assert np.array_equal(
        graph.search(queries[:1], 11, nprobe=nprobe + 1)[1],
        scan.search(queries[:1], 11, nprobe=nprobe + 1)[1],
    )


def test_a_graph_no_faster_than_the_scan_is_not_kept(
    index_file: tuple[Path, np.ndarray, np.ndarray], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(cells_module, "KEEP_BELOW", 0.0)
    frozen = FrozenIVF.open(str(index_file[0]))
    frozen.build_cells()
    assert frozen.cells is None


def test_no_graph_worth_having_is_decided_once_per_index_file(
    index_file: tuple[Path, np.ndarray, np.ndarray], monkeypatch: pytest.MonkeyPatch
) -> None:
    path, ids, vectors = index_file
    monkeypatch.setattr(cells_module, "KEEP_BELOW", 0.0)  # never faster enough: not kept
    first = FrozenIVF.open(str(path))
    first.build_cells()
    assert first.cells is None
    assert (path.parent / f"{path.stem}.cells.arrays").is_file()  # the decision, stored
    with monkeypatch.context() as patch:  # the next opening reads it: no graph tried
        patch.setattr(cells_module.CellGraph, "of", no_graph_built)
        again = FrozenIVF.open(str(path))
        again.build_cells()
    assert again.cells is None
    nprobe = again.base_nprobe
    assert np.array_equal(
        again.search(vectors[:5], 11, nprobe=nprobe)[1],
        without_graph(path).search(vectors[:5], 11, nprobe=nprobe)[1],
    )
    # The index file written again: decided again (here a graph is now worth having).
    monkeypatch.setattr(cells_module, "KEEP_BELOW", float("inf"))
    index = DescriptorIndex(
        "motion", DIMENSION, 1, path.parent, options=IndexOptions("ivf", nlist=CELLS)
    )
    index.replace_all(ids, vectors[::-1].copy(), persist=True)
    rebuilt = FrozenIVF.open(str(index.path))
    rebuilt.build_cells()
    assert rebuilt.cells is not None


def test_a_quick_scan_or_a_crowded_graph_is_not_tried(
    index_file: tuple[Path, np.ndarray, np.ndarray], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(cells_module, "KEEP_BELOW", float("inf"))
    for name, value in (("QUICK_SCAN", 1.0), ("CROWDED", 0.0)):
        with monkeypatch.context() as patch:
            patch.setattr(cells_module, name, value)
            frozen = FrozenIVF.open(str(index_file[0]))
            frozen.build_cells()
            assert frozen.cells is None, name


def test_too_few_cells_build_no_graph(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    ids = np.arange(1, COUNT + 1, dtype=np.int64)
    index = DescriptorIndex(
        "motion", DIMENSION, 1, tmp_path, options=IndexOptions("ivf", nlist=CELLS)
    )
    index.replace_all(ids, clustered(rng, COUNT), persist=True)
    frozen = FrozenIVF.open(str(index.path))
    frozen.build_cells()
    assert frozen.cells is None  # 200 cells: scanned


def test_the_first_search_builds_the_graph_meanwhile_and_filters_still_probe_every_cell(
    index_file: tuple[Path, np.ndarray, np.ndarray], monkeypatch: pytest.MonkeyPatch
) -> None:
    path, ids, vectors = index_file
    monkeypatch.setattr(cells_module, "KEEP_BELOW", float("inf"))
    frozen = FrozenIVF.open(str(path))
    query = vectors[:1]
    first = frozen.search(query, 10, nprobe=frozen.base_nprobe)  # answered by the scan
    deadline = time.monotonic() + 60
    while frozen.cells is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert frozen.cells is not None
    assert np.array_equal(frozen.search(query, 10, nprobe=frozen.base_nprobe)[1], first[1])
    # A filtered search is exact: every allowed vector is considered, whatever its cell.
    allowed = np.sort(ids[np.random.default_rng(2).choice(COUNT, 500, replace=False)])
    _squared, found = frozen.search(query, 10, nprobe=frozen.base_nprobe, allowed=allowed)
    rows = np.searchsorted(ids, allowed)
    exact = ((vectors[rows] - query) ** 2).sum(axis=1)
    assert set(found[0].tolist()) == set(allowed[np.argsort(exact, kind="stable")[:10]].tolist())


def graph_kept(path: Path, monkeypatch: pytest.MonkeyPatch) -> FrozenIVF:
    """The index file opened and its cells' graph built and stored (kept whatever it times)."""
    monkeypatch.setattr(cells_module, "KEEP_BELOW", float("inf"))
    frozen = FrozenIVF.open(str(path))
    frozen.build_cells()
    return frozen


def no_graph_built(*_args: Any) -> None:
    raise AssertionError("the graph was built, not read from its file")


def test_a_kept_graph_is_read_back_from_beside_its_index_file_by_the_next_start(
    index_file: tuple[Path, np.ndarray, np.ndarray], monkeypatch: pytest.MonkeyPatch
) -> None:
    path, _ids, vectors = index_file
    first = graph_kept(path, monkeypatch)
    assert first.cells is not None
    assert (path.parent / f"{path.stem}.cells.arrays").is_file()
    with monkeypatch.context() as patch:
        patch.setattr(cells_module.CellGraph, "of", no_graph_built)
        again = FrozenIVF.open(str(path))
        again.build_cells()
    assert again.cells is not None
    assert np.array_equal(again.cells.unreachable, first.cells.unreachable)
    assert again.cells.effort == first.cells.effort  # measured once, stored with the graph
    queries = vectors[:100]
    for one, other in zip(first.cells.nearest(queries), again.cells.nearest(queries), strict=True):
        assert np.array_equal(one, other)
    nprobe = first.base_nprobe
    assert np.array_equal(
        again.search(queries[:5], 11, nprobe=nprobe)[1],
        first.search(queries[:5], 11, nprobe=nprobe)[1],
    )


def test_a_graph_file_of_another_index_file_or_damaged_is_built_again(
    index_file: tuple[Path, np.ndarray, np.ndarray], monkeypatch: pytest.MonkeyPatch
) -> None:
    path, ids, vectors = index_file
    monkeypatch.setattr(cells_module, "KEEP_BELOW", float("inf"))
    FrozenIVF.open(str(path)).build_cells()
    cache = path.parent / f"{path.stem}.cells.arrays"
    damaged = bytearray(cache.read_bytes())
    damaged[len(damaged) // 2] ^= 0xFF
    cache.write_bytes(bytes(damaged))
    built = count_calls(monkeypatch, cells_module.CellGraph, "of")
    frozen = FrozenIVF.open(str(path))
    frozen.build_cells()
    assert built == [1] and frozen.cells is not None  # the checksum refused it
    # The index file written again (a reindex: new centroids): the old graph is not used.
    index = DescriptorIndex(
        "motion", DIMENSION, 1, path.parent, options=IndexOptions("ivf", nlist=CELLS)
    )
    index.replace_all(ids, vectors[::-1].copy(), persist=True)
    rebuilt = FrozenIVF.open(str(index.path))
    rebuilt.build_cells()
    assert built == [1, 1] and rebuilt.cells is not None
    scan = without_graph(index.path)
    query = vectors[:1]
    nprobe = rebuilt.base_nprobe
    assert np.array_equal(
        rebuilt.search(query, 11, nprobe=nprobe)[1], scan.search(query, 11, nprobe=nprobe)[1]
    )


def test_a_graph_file_with_an_effort_the_rule_never_picks_is_built_again(
    index_file: tuple[Path, np.ndarray, np.ndarray], monkeypatch: pytest.MonkeyPatch
) -> None:
    path, _ids, vectors = index_file
    first = graph_kept(path, monkeypatch)
    assert first.cells is not None and first.file_identity is not None
    nprobe = first.base_nprobe
    # A forged effort in a file whose checksum and stamp match (written as the service does)
    forged = {**first.cells.arrays(), "effort": np.array([7], np.int64)}
    directory, stem, stamp = cells_module._cache_file(str(path), first.file_identity, nprobe)
    write_arrays(directory, stem, forged, stamp)
    built = count_calls(monkeypatch, cells_module.CellGraph, "of")
    again = FrozenIVF.open(str(path))
    again.build_cells()
    assert built == [1] and again.cells is not None
    assert again.cells.effort in cells_module.efforts(nprobe)
    assert np.array_equal(
        again.search(vectors[:5], 11, nprobe=nprobe)[1],
        without_graph(path).search(vectors[:5], 11, nprobe=nprobe)[1],
    )


# The graph's own cells against a scan of the centroids, on a real IVF index of
# GRAPH_MIN_CELLS cells: k-means over clustered vectors, as a library's cells are trained.

NPROBE = 12


@pytest.fixture(scope="module")
def trained() -> tuple[faiss.IndexIVFFlat, np.ndarray]:
    """An IVF index of 1,000 cells trained on 20,000 clustered vectors (~0.3 s), and 500 other
    vectors like them ``(500, DIMENSION)`` as queries."""
    rng = np.random.default_rng(0)
    vectors = clustered(rng, 20_500)
    quantizer = faiss.IndexFlatL2(DIMENSION)
    index = faiss.IndexIVFFlat(quantizer, DIMENSION, cells_module.GRAPH_MIN_CELLS)
    index.cp.niter = 10  # cells as good as the test needs, in a third of a second
    index.cp.min_points_per_centroid = 1  # 20 a cell: FAISS would only warn
    index.train(vectors[:20_000])
    return index, vectors[20_000:]


def centroids_of(index: faiss.IndexIVFFlat) -> np.ndarray:
    return faiss.downcast_index(index.quantizer).reconstruct_n(0, index.nlist)


def assert_scans_cells(graph: cells_module.CellGraph, index: Any, queries: np.ndarray) -> None:
    """``graph`` finds, for each of ``queries`` ``(Q, D)``, the cells a scan of the centroids
    finds, each once, nearest first; one query at a time (as served) and all at once."""
    scanned_squared, scanned = faiss.downcast_index(index.quantizer).search(queries, NPROBE)
    squared, found = graph.nearest(queries)
    for row in range(queries.shape[0]):
        one_squared, one = graph.nearest(queries[row : row + 1])
        assert np.array_equal(one[0], found[row]) and np.array_equal(one_squared[0], squared[row])
        assert np.array_equal(found[row], scanned[row]), row  # the same cells, in the same order
        # the graph's distances and the scan's are FAISS's, each kernel's own rounding
        assert np.allclose(squared[row], scanned_squared[row], rtol=1e-6, atol=1e-5)
    assert np.all(np.diff(squared, axis=1) >= 0)


def test_the_graph_finds_the_scans_cells_for_every_centroid_and_other_queries(
    trained: tuple[faiss.IndexIVFFlat, np.ndarray],
) -> None:
    index, others = trained
    centroids = centroids_of(index)
    graph = cells_module.CellGraph(centroids, NPROBE)
    assert graph.unreachable.size == 0  # every centroid returned when searched for itself
    assert_scans_cells(graph, index, np.concatenate([centroids, others]))


def test_cells_compared_directly_are_merged_once_each(
    trained: tuple[faiss.IndexIVFFlat, np.ndarray],
) -> None:
    index, others = trained
    centroids = centroids_of(index)
    queries = np.concatenate([centroids[:300], others[:200]])
    graph = cells_module.CellGraph(centroids, NPROBE)
    _squared, found = graph.nearest(queries[:1])
    # Cells the graph also returns for the first query (which must not come twice) and others.
    marked = np.concatenate([found[0, :4], [found[0, -1]], np.arange(0, 1000, 97)])
    graph.compare_directly(marked)
    assert graph.unreachable.size == np.unique(marked).size
    assert_scans_cells(graph, index, queries)


def cut_links_to(graph: cells_module.CellGraph, cells: np.ndarray) -> None:
    """Point every link to one of ``cells`` ``(C,)`` in ``graph`` back at the node holding it
    (a node linked to itself is a visited one): no search can then reach them."""
    hnsw = graph.graph.hnsw
    assert hnsw.entry_point not in cells
    links = faiss.vector_to_array(hnsw.neighbors)
    owners = np.searchsorted(faiss.vector_to_array(hnsw.offsets), np.arange(links.size), "right")
    to_cells = np.isin(links, cells)
    links[to_cells] = owners[to_cells] - 1
    faiss.copy_array_to_vector(links, hnsw.neighbors)


@pytest.mark.parametrize("lost_count", [1, 16])
def test_centroids_no_link_reaches_are_found_and_then_compared_directly(
    trained: tuple[faiss.IndexIVFFlat, np.ndarray], lost_count: int
) -> None:
    index, others = trained
    centroids = centroids_of(index)
    graph = cells_module.CellGraph(centroids, NPROBE)
    # The centroids nearest one centroid (16: more than a query's cells, so merging one
    # pushes out another merged before it), none of them the entry point.
    centre = 1 + int(graph.graph.hnsw.entry_point) % (graph.count - 1)
    nearest = np.argsort(((centroids - centroids[centre]) ** 2).sum(axis=1))
    lost = nearest[nearest != graph.graph.hnsw.entry_point][int(lost_count > 1) :][:lost_count]
    cut_links_to(graph, lost)
    missed = set(lost.tolist()) - set(graph.nearest(centroids[lost])[1].ravel().tolist())
    assert missed == set(lost.tolist())  # the graph alone never returns them
    unreachable = graph.unreachable_cells()
    assert set(lost.tolist()) <= set(unreachable.tolist())  # (their links may have led on)
    graph.compare_directly(np.empty(0, np.int64))
    # queries whose cells include the lost ones: the centroids themselves and the vectors
    # nearest them
    near = np.argsort(((others - centroids[centre]) ** 2).sum(axis=1))[:20]
    queries = np.concatenate([centroids[lost], others[near]])
    _squared, graph_alone = graph.nearest(queries)
    graph.compare_directly(unreachable)
    # The merge: the nprobe nearest of the graph's cells and the unreachable ones, each once.
    _squared, ranked = faiss.downcast_index(index.quantizer).search(queries, index.nlist)
    for row, cells in enumerate(graph.nearest(queries)[1]):
        either = set(graph_alone[row].tolist()) | set(unreachable.tolist())
        assert cells.tolist() == [c for c in ranked[row].tolist() if c in either][:NPROBE]
    if lost_count == 1:  # then the scan's cells for every query (16 cut: the paths through
        assert_scans_cells(graph, index, queries)  # them are gone too, and with them some
        assert_scans_cells(graph, index, centroids)  # other cells: the keep guard's part)
    # the merged cells' distances are the scan's, bit for bit (the graph's own kernel rounds
    # differently)
    scanned_squared, _cells = faiss.downcast_index(index.quantizer).search(centroids[lost], 1)
    squared, found = graph.nearest(centroids[lost])
    assert np.array_equal(found[:, 0], lost) and np.array_equal(squared[:, :1], scanned_squared)


def test_the_log_counts_the_unreachable_centroids(
    trained: tuple[faiss.IndexIVFFlat, np.ndarray],
    small_graphs: None,
    monkeypatch: pytest.MonkeyPatch,
    caplog: pytest.LogCaptureFixture,
) -> None:
    index, others = trained
    monkeypatch.setattr(cells_module, "KEEP_BELOW", float("inf"))
    index.nprobe = NPROBE
    with caplog.at_level(logging.INFO, logger=cells_module.__name__):
        graph = cells_module.CellGraph.of(index, NPROBE, others[:50])
    assert graph is not None
    assert "unreachable, compared directly: 0)" in caplog.text and "graph kept" in caplog.text


def test_the_effort_is_the_smallest_that_finds_every_samples_cells_one_step_up(
    trained: tuple[faiss.IndexIVFFlat, np.ndarray],
) -> None:
    index, others = trained
    quantizer = faiss.downcast_index(index.quantizer)
    graph = cells_module.CellGraph(centroids_of(index), NPROBE)
    assert graph.effort == cells_module.effort(NPROBE)  # before it is measured: the largest
    samples = others[:300]
    scanned = quantizer.search(samples, NPROBE)[1]
    chosen = graph.settle_effort(samples, scanned)
    steps = cells_module.efforts(NPROBE)
    assert chosen == graph.effort and chosen in steps and chosen <= steps[-1]
    assert steps[0] == max(NPROBE, cells_module.EFFORT_STEPS[0])

    def finds_the_scans_cells(effort: int) -> bool:
        probe = cells_module.CellGraph.restored(graph.arrays(), NPROBE)
        probe.set_effort(effort)  # its unreachable cells found again at that effort
        found = probe.nearest(samples)[1]
        return bool(np.array_equal(np.sort(found, axis=1), np.sort(scanned, axis=1)))

    at = steps.index(chosen)
    smallest = max(0, at - cells_module.EFFORT_MARGIN) if at < len(steps) - 1 else None
    if smallest is not None:  # the smallest passing step, then the margin above it
        assert finds_the_scans_cells(steps[smallest])
        assert not any(finds_the_scans_cells(step) for step in steps[:smallest])
    assert finds_the_scans_cells(chosen)
    # At the chosen effort the graph gives the scan's cells for the samples, as served.
    assert_scans_cells(graph, index, samples)
