"""Which cells an IVF search scans, found through a graph over the centroids.

An IVF search first compares the query with every centroid to choose its ``nprobe`` nearest
cells. At a million clips (4,000 cells) that scan was a third of FAISS's time for ``motion``
(4,000 x 135 floats: 0.10-0.12 ms of 0.28-0.36 ms, in-process, bench/README.md). A
:class:`CellGraph` — an HNSW graph (``faiss.IndexHNSWFlat``) over the same centroids — finds
the same cells for a fraction of that (0.02-0.03 ms); the lists are then scanned as before
(``search_preassigned``), so where the cells are the same the answer is the same, bit for bit.
The graph is approximate, and one failure is structural: a centroid that no node links to is
never returned, whatever the search effort (1 of 4,000 in a 1M-clip ``motion`` library, which
alone made the graph find other cells for 4 of 1,000 stored vectors). So when the graph is
built, every centroid is searched for itself, in one batch and just as a query is (its search
effort, ``nprobe`` results); those not among their own results are *unreachable*
(:meth:`CellGraph.unreachable_cells`), and each query is also compared with them directly,
the ``nprobe`` nearest of both kept (:meth:`CellGraph.nearest`). On motion centroids they are
a handful (one of 4,000); a graph that misses many searches poorly, and the direct comparisons
then make it slower than the scan, so it is not kept (below). Beyond that the graph returned
the scan's cells for every query measured (300 stored motion vectors at ``nprobe`` 12, search
effort 24 and more). Its search effort (HNSW's ``efSearch``, the candidates a search keeps)
is measured when it is built: the smallest of a few steps that finds the scan's cells for
every one of :data:`EFFORT_SAMPLES` stored vectors, one step higher for queries that are not
stored vectors (:meth:`CellGraph.settle_effort`), at most :func:`effort`; the unreachable
cells are those of that effort.

The graph is built from the index's centroids in memory (a few MB; ~0.7 s for 4,000 x 135
on one loaded core, and ~0.2 s more to search every centroid for itself at each effort
tried), and what was decided — the graph with its effort, or that none is worth having — is
stored beside the index file (``<stem>.cells.arrays``, :func:`store_graph`): the next start,
in any process, reads it back instead (:func:`stored_graph`) when it was decided from that
very file (inode, size, modification time) with the same settings and matches its
checksum, else decides again (the samples are drawn with a fixed seed; once stored, every
process searches the same graph at the same effort, or none tries one). It is a cache of
the index, as the index is of the database.
It is kept only when it measures faster than the scan and finds the same cells for every one
of :data:`SAMPLES` stored vectors used as queries: for ``kinetic`` (4,000 x 50,
``nprobe`` 64) the scan is cheap and the graph, which must then look at 128 candidates, was no
faster. Building one costs ~1 s of CPU, so it is not even tried where it cannot win: below
:data:`GRAPH_MIN_CELLS` cells; when the graph would compare about as many centroids as the
scan (its search effort times :data:`LINKS` above :data:`CROWDED` of the cells: ``kinetic``'s
``nprobe`` 64);
or when the scan is already quick (under :data:`QUICK_SCAN` seconds a query: ``posture``'s
4,000 x 12, 35 us, against 33 us through a graph).

Shapes: queries ``(Q, D)`` float32; centroids ``(nlist, D)`` float32.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import faiss
import numpy as np

from app.index.array_file import beside_index, read_arrays, write_arrays

log = logging.getLogger(__name__)

GRAPH_MIN_CELLS = 1000  # fewer cells: their scan is cheap (1,000 x 135 floats: ~0.03 ms)
LINKS = 32  # neighbours per node (HNSW's M): 16 took longer to search at the same recall
BUILD_EFFORT = 80  # HNSW's efConstruction
MIN_EFFORT = 48
# The search efforts tried below effort(nprobe), smallest first (see CellGraph.settle_effort)
EFFORT_STEPS = (16, 20, 24, 32)
EFFORT_MARGIN = 1  # steps taken above the smallest effort that finds every sample's cells
EFFORT_SAMPLES = 1000  # stored vectors whose cells choose the effort
SAMPLES = 200  # stored vectors timed and compared when deciding whether to keep a graph
KEEP_BELOW = 0.75  # ... kept when it takes at most this share of the scan's time
CROWDED = 0.5  # no graph whose search would compare this share of the centroids or more
QUICK_SCAN = 50e-6  # a scan of the centroids this quick is kept without trying a graph
CACHE_FORMAT = 2  # of the <index>.cells files (see stored_graph); 2: with its effort
NO_GRAPH = 0  # the stored effort of an index for which no graph was worth having


def effort(nprobe: int) -> int:
    """The graph's largest search effort (HNSW's ``efSearch``) for ``nprobe`` cells: twice
    as many candidates as cells, at least :data:`MIN_EFFORT` (a graph searched with less is
    one whose samples measured it enough, :meth:`CellGraph.settle_effort`)."""
    return max(MIN_EFFORT, 2 * nprobe)


def efforts(nprobe: int) -> list[int]:
    """The search efforts :meth:`CellGraph.settle_effort` tries for ``nprobe`` cells,
    smallest first: :data:`EFFORT_STEPS` (at least ``nprobe``: HNSW keeps that many
    candidates anyway) under :func:`effort`, then it."""
    largest = effort(nprobe)
    return sorted({max(nprobe, step) for step in EFFORT_STEPS if step < largest} | {largest})


class CellGraph:
    """The nearest cells of an IVF index's ``centroids`` ``(nlist, D)``, through an HNSW graph
    (see the module docstring)."""

    def __init__(self, centroids: np.ndarray, nprobe: int, search_effort: int = 0) -> None:
        """The graph over ``centroids`` ``(nlist, D)`` for searches of ``nprobe`` cells at
        ``search_effort`` (0: :func:`effort`)."""
        array = np.ascontiguousarray(centroids, dtype=np.float32)
        graph: Any = faiss.IndexHNSWFlat(int(array.shape[1]), LINKS)
        graph.hnsw.efConstruction = BUILD_EFFORT
        graph.add(array)
        self._use(graph, nprobe, search_effort or effort(nprobe))
        self.compare_directly(self.unreachable_cells())

    def _use(self, graph: Any, nprobe: int, search_effort: int) -> None:
        self.nprobe = nprobe  # the cells a search asks for (those the graph was checked for)
        self.graph = graph
        self.count = int(graph.ntotal)
        self.dimension = int(graph.d)
        # FAISS only reads the parameters: one object for every search
        self._params: Any = faiss.SearchParametersHNSW()  # type: ignore[attr-defined]
        self.effort = search_effort  # HNSW's efSearch: candidates a search keeps
        self._params.efSearch = search_effort
        self.unreachable = np.empty(0, np.int64)  # (U,) cells each query is compared with
        self._unreachable_centroids = np.empty((0, self.dimension), np.float32)  # (U, D)

    def arrays(self) -> dict[str, np.ndarray]:
        """The graph as arrays to store (:meth:`restored` reads them back): FAISS's bytes of
        the graph ``(B,)`` uint8, its unreachable cells ``(U,)`` and its search effort
        ``(1,)``."""
        return {
            "graph": faiss.serialize_index(self.graph),
            "unreachable": self.unreachable,
            "effort": np.array([self.effort], np.int64),
        }

    @classmethod
    def restored(cls, arrays: Mapping[str, np.ndarray], nprobe: int) -> CellGraph:
        """The graph :meth:`arrays` gave, for searches of ``nprobe`` cells (those it was
        checked for), at the effort and with the unreachable cells found when it was built:
        the same graph (FAISS's own bytes), so the same cells for every query."""
        graph = cls.__new__(cls)
        stored = faiss.deserialize_index(np.ascontiguousarray(arrays["graph"]))
        graph._use(stored, nprobe, int(np.asarray(arrays["effort"]).reshape(-1)[0]))
        graph.compare_directly(np.asarray(arrays["unreachable"], np.int64))
        return graph

    def set_effort(self, search_effort: int) -> None:
        """Search with ``search_effort`` from now on; the unreachable cells are found again
        (they depend on it)."""
        self.effort = search_effort
        self._params.efSearch = search_effort
        self.compare_directly(self.unreachable_cells())

    def settle_effort(self, queries: np.ndarray, scanned: np.ndarray) -> int:
        """Search with the smallest of :func:`efforts` that finds, for every one of
        ``queries`` ``(Q, D)`` (stored vectors), the cells the scan of the centroids found
        (``scanned`` ``(Q, nprobe)``), taken :data:`EFFORT_MARGIN` steps higher (unseen
        queries lie as the stored ones do, but not exactly on them); the largest effort when
        none does (the keep rule then judges the graph). Returns the effort.

        A graph search keeps ``effort`` candidates while it walks; on a library's centroids
        fewer than :func:`effort`'s 48 already find the scan's cells (20-24 at 1M ``motion``
        clips, ``nprobe`` 12, bench/README.md), and each one costs a search a few distance
        computations."""
        steps = efforts(self.nprobe)
        chosen = steps[-1]
        for at, step in enumerate(steps[:-1]):
            self.set_effort(step)
            found = self.nearest(queries)[1]
            if _same_cells(scanned, found):
                chosen = steps[min(at + EFFORT_MARGIN, len(steps) - 1)]
                break
        if chosen != self.effort:
            self.set_effort(chosen)
        return chosen

    def unreachable_cells(self) -> np.ndarray:
        """``(U,)`` the cells whose centroid, searched for as a query is, is not among the
        graph's results: a query nearest them would miss them too (an identical twin found at
        distance 0 does not stand in for one, as a scan returns both)."""
        centroids = self.graph.reconstruct_n(0, self.count)
        _squared, found = self.graph.search(centroids, self.nprobe, params=self._params)
        own = (found == np.arange(self.count)[:, None]).any(axis=1)
        return np.flatnonzero(~own).astype(np.int64)

    def compare_directly(self, cells: np.ndarray) -> None:
        """Compare every query with the centroids of ``cells`` ``(U,)`` too (see
        :meth:`nearest`)."""
        unreachable = np.unique(np.asarray(cells, np.int64))
        centroids = [self.graph.reconstruct(int(cell)) for cell in unreachable]
        self._unreachable_centroids = np.array(centroids, np.float32).reshape(-1, self.dimension)
        self.unreachable = unreachable

    @classmethod
    def of(cls, index: Any, nprobe: int, samples: np.ndarray) -> CellGraph | None:
        """The graph over the centroids of the IVF ``index`` for searches of ``nprobe`` cells,
        when it is worth having for queries like ``samples`` ``(S, D)`` (see the module
        docstring), else None: its search effort chosen from all of them
        (:meth:`settle_effort`), then the first :data:`SAMPLES` timed and compared."""
        nlist = int(index.nlist)
        quantizer: Any = faiss.downcast_index(index.quantizer)
        if nlist < GRAPH_MIN_CELLS or not isinstance(quantizer, faiss.IndexFlatL2):
            return None
        if effort(nprobe) * LINKS > CROWDED * nlist:
            return None
        everyone = np.ascontiguousarray(samples, dtype=np.float32)
        queries = everyone[:SAMPLES]
        scan_time, scanned = _timed(lambda q: quantizer.search(q, nprobe)[1], queries)
        if scan_time < QUICK_SCAN:
            return None
        graph = cls(quantizer.reconstruct_n(0, nlist), nprobe)
        chosen = graph.settle_effort(everyone, quantizer.search(everyone, nprobe)[1])
        graph_time, found = _timed(lambda q: graph.nearest(q)[1], queries)
        same = _same_cells(np.array(scanned), np.array(found))
        keep = same and graph_time <= KEEP_BELOW * scan_time
        log.info(
            "cells of a %d-cell index: graph %.1f us at effort %d (centroids unreachable, "
            "compared directly: %d), scan %.1f us a query, %s cells: %s",
            nlist,
            graph_time * 1e6,
            chosen,
            graph.unreachable.size,
            scan_time * 1e6,
            "same" if same else "other",
            "graph kept" if keep else "scan kept",
        )
        return graph if keep else None

    def nearest(self, queries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(Q, nprobe)`` squared distances to and numbers of the cells nearest each of
        ``queries`` ``(Q, D)``, nearest first: the graph's, merged with the unreachable
        cells'."""
        # FAISS's own call without its Python wrapper's checks (the graph's dimension is the
        # index's; a search asks for a dozen cells once per request)
        queries = np.ascontiguousarray(queries, np.float32)
        count, dimension = queries.shape
        if dimension != self.dimension:  # native code reads D floats a query, unchecked
            raise ValueError(f"queries of {dimension} numbers for a {self.dimension}-D graph")
        distances = np.empty((count, self.nprobe), np.float32)
        cells = np.empty((count, self.nprobe), np.int64)
        self.graph.search_c(
            count,
            faiss.swig_ptr(queries),
            self.nprobe,
            faiss.swig_ptr(distances),
            faiss.swig_ptr(cells),
            self._params,
        )
        if not self.unreachable.size:
            return distances, cells
        return self._merged(queries, distances, cells)

    def _merged(
        self, queries: np.ndarray, distances: np.ndarray, cells: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The ``nprobe`` nearest of the graph's ``cells`` ``(Q, nprobe)`` (at ``distances``)
        and the unreachable cells, each once, nearest first (both arrays updated in place)."""
        extra = int(self.unreachable.size)
        to_extra = np.empty(extra, np.float32)
        for row in range(int(queries.shape[0])):
            faiss.fvec_L2sqr_ny(  # type: ignore[attr-defined]  # the scan's kernel and bits
                faiss.swig_ptr(to_extra),
                faiss.swig_ptr(queries[row]),
                faiss.swig_ptr(self._unreachable_centroids),
                self.dimension,
                extra,
            )
            # Plain floats: a handful, usually none nearer than the graph's last cell.
            for column, squared in enumerate(to_extra.tolist()):
                if squared >= distances[row, -1] or self.unreachable[column] in cells[row]:
                    continue  # farther (than one merged before, too), or the graph's too
                place = int(np.searchsorted(distances[row], squared, side="right"))
                distances[row, place + 1 :] = distances[row, place:-1]  # numpy copies overlaps
                cells[row, place + 1 :] = cells[row, place:-1]
                distances[row, place], cells[row, place] = squared, self.unreachable[column]
        return distances, cells


def _same_cells(scanned: np.ndarray, found: np.ndarray) -> bool:
    """Whether each row of ``found`` ``(Q, nprobe)`` holds the cells of that row of
    ``scanned`` (in any order: the lists scanned, so the answer, are the same)."""
    return bool(np.array_equal(np.sort(scanned, axis=1), np.sort(found, axis=1)))


def _cache_file(
    index_file: str, identity: list[int], nprobe: int
) -> tuple[Path, str, dict[str, Any]]:
    """Where the graph of ``index_file`` is kept (``<stem>.cells.arrays``) and its stamp."""
    settings = {
        "format": CACHE_FORMAT,
        "nprobe": nprobe,
        "links": LINKS,
        "build_effort": BUILD_EFFORT,
        "efforts": efforts(nprobe),
        "effort_margin": EFFORT_MARGIN,
        "effort_samples": EFFORT_SAMPLES,
        # the keep rule's: a graph not kept under other settings might be (and vice versa)
        "keep": [GRAPH_MIN_CELLS, SAMPLES, KEEP_BELOW, CROWDED, QUICK_SCAN],
    }
    return beside_index(index_file, "cells", identity, settings)


def stored_graph(
    index_file: str, identity: list[int], nprobe: int, index: Any
) -> tuple[bool, CellGraph | None]:
    """What an earlier start of any process decided for the IVF ``index`` (mapped from
    ``index_file``) and stored beside it (:func:`store_graph`): ``(True, graph)``, or ``(True,
    None)`` when no graph was worth having, if that was decided from that very file for
    ``nprobe`` cells and the file matches its checksum; ``(False, None)`` otherwise (decide
    again). Building a graph again costs 0.5-0.8 s of CPU for the 4,000 x 135 ``motion``
    centroids of a 1M-clip library, against 0.006 s to read it back; trying one that is then
    not kept (``posture``'s) 0.4-0.8 s — in every worker at every start, were it not stored
    (bench/README.md). The file is a cache of the index, as the index is of the database; a
    missing or stale one is decided again."""
    directory, stem, stamp = _cache_file(index_file, identity, nprobe)
    found = read_arrays(directory, stem, stamp)
    if isinstance(found, str) or not {"graph", "unreachable", "effort"} <= found[0].keys():
        return False, None
    stored_effort = int(np.asarray(found[0]["effort"]).reshape(-1)[0])
    if stored_effort == NO_GRAPH and not found[0]["graph"].size:
        return True, None
    if stored_effort not in efforts(nprobe):
        return False, None  # an effort the rule never picks
    graph = CellGraph.restored(found[0], nprobe)
    if graph.count != int(index.nlist) or graph.dimension != int(index.d):
        return False, None
    return True, graph


def store_graph(index_file: str, identity: list[int], nprobe: int, graph: CellGraph | None) -> None:
    """Keep what was decided for the index file ``index_file`` (``identity`` as in
    :func:`stored_graph`) and searches of ``nprobe`` cells — ``graph``, or None: no graph
    worth having — for the next start of any process."""
    directory, stem, stamp = _cache_file(index_file, identity, nprobe)
    arrays: dict[str, np.ndarray] = {
        "graph": np.empty(0, np.uint8),
        "unreachable": np.empty(0, np.int64),
        "effort": np.array([NO_GRAPH], np.int64),
    }
    if graph is not None:
        arrays = graph.arrays()
    with contextlib.suppress(OSError):  # a read-only directory: decided at every start
        write_arrays(directory, stem, arrays, stamp)


def _timed(search: Any, queries: np.ndarray, rounds: int = 3) -> tuple[float, list[np.ndarray]]:
    """The least CPU seconds a query of ``queries`` ``(Q, D)`` took through ``search`` (one
    query at a time, as served; best of ``rounds``) and the cells found."""
    best = float("inf")
    found: list[np.ndarray] = []
    for _ in range(rounds):
        started = time.thread_time()
        found = [search(queries[i : i + 1])[0] for i in range(queries.shape[0])]
        best = min(best, (time.thread_time() - started) / queries.shape[0])
    return best, found
