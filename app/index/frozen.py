"""An IVF index mapped read-only from its file, and the changes since, in memory.

FAISS maps an index file with ``IO_FLAG_MMAP_IFC``: the inverted lists (the codes and ids,
nearly all of an index) stay in the file's pages, which every process mapping the file
shares through the page cache — ``mocap-index serve --workers 2`` holds one copy, not two,
and starts without reading the lists into memory. Such an index must not change (FAISS
aborts the process on any write to a mapped list), so a :class:`FrozenIVF` keeps the changes
made since the file beside it, like the catalogue's overlay:

* ``delta``: vectors added since (a small flat index, exact);
* ``gone``: ids of the mapped lists that are deleted or replaced (sorted; searches skip them
  through an id selector).

A search asks both and merges by distance. Where each id of the file lies (its list and
offset: the *locator*, sorted by id) is read once when the file is mapped — and kept in a
file beside it for the next start, see :mod:`app.index.locator` — so a vector is found
without FAISS's id hash table, which would be a private copy in every process (~40 bytes per
vector). :meth:`merged` gives an ordinary (owned, writable) index of the current vectors, to
write as the next file.

**Compressed lists** (``IndexIVFScalarQuantizer``, 8 bits a number, the vectors padded to a
multiple of 8: ``MOCAP_WINDOW_CODES``, ``MOCAP_CLIP_CODES``): the lists
hold a quarter of the bytes, but their distances are approximate and their vectors lossy.
The exact vectors then come with the index (``exact``, ``(N, D)`` float32 in the locator's
order — by id — mapped from a file written beside the index): a search asks the lists for
:data:`RERANK` times the neighbours wanted and ranks them by their exact distances, and a
vector read is an exact row. A search touches the pages of its candidates' rows only, so the
server's memory is the codes' quarter plus what the searches read.

Shapes: a query is ``(1, D)`` float32; ids ``(N,)`` int64; vectors ``(N, D)`` float32.
"""

from __future__ import annotations

import ctypes
import os
import threading
from typing import Any

import faiss
import numpy as np

from app.index import probe_cutoff, rerank
from app.index.cells import (
    EFFORT_SAMPLES,
    GRAPH_MIN_CELLS,
    CellGraph,
    store_graph,
    stored_graph,
)
from app.index.kinds import RERANK, SQ8, codes_of, empty_flat, padded
from app.index.locator import LIST_SHIFT, Locator, stored_locator, walk_lists


class FrozenIVF:
    """``base`` (a mapped IVF index) minus ``gone`` plus ``delta`` (see the module
    docstring)."""

    def __init__(
        self,
        base: Any,
        exact: np.ndarray | None = None,
        exact_ids: np.ndarray | None = None,
        locator: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> None:
        self.base = base
        self.mapped_from: str | None = None  # the file the base is mapped from (see open)
        self.file_identity: list[int] | None = None  # ... its inode, size and mtime (ns)
        # Compressed lists: the exact vectors beside them, by id (``exact_ids``, sorted: the
        # file's ids), queries padded to base.d.
        self.exact = exact
        self.width = int(base.d)
        self.dimension = int(exact.shape[1]) if exact is not None else self.width
        if codes_of(base) == SQ8 and (exact is None or exact.shape[0] != int(base.ntotal)):
            raise ValueError("an index of compressed lists needs its exact vectors")
        # The mapped file never changes: what a search asks of it on every call, read once.
        self.base_total = int(base.ntotal)
        self.base_nprobe = int(base.nprobe)
        self._params: dict[int, Any] = {}  # nprobe -> unfiltered search parameters (read-only)
        self.delta = empty_flat(self.dimension)
        # How many vectors ``delta`` holds, kept in step by add and remove: every search and
        # vector read asks, and FAISS's ``ntotal`` through SWIG costs a microsecond or two.
        self.delta_total = 0
        self.gone = np.zeros(0, np.int64)
        if exact is not None and exact_ids is not None and exact_ids.size == self.base_total:
            # Vectors are read from the exact rows: the ids are the whole locator (no pass
            # over the lists and no sort at start: ~1 s a worker at 100 hours of windows).
            self.locator = Locator(exact_ids, np.zeros(0, np.int64))
        else:
            self.locator = Locator(*(locator if locator is not None else walk_lists(base)))
        self.base_ids, self.places = self.locator.ids, self.locator.places  # (N,) each
        self._codes: np.ndarray | None = None  # see _view_codes
        self._rows: np.ndarray | None = None  # ... and _view_rows
        self._list_starts = np.zeros(0, np.int64)
        # The cells' graph (app/index/cells.py): built in a thread at the first search, the
        # centroids scanned until it is there.
        self.cells: CellGraph | None = None
        self._cells_started = int(base.nlist) < GRAPH_MIN_CELLS  # True: none to build
        self._cells_lock = threading.Lock()
        # The adaptive probe (app/index/probe_cutoff.py): nprobe -> the ratio beyond which a
        # search by clip skips a cell (None: none skipped), decided from the file's vectors.
        self._cutoffs: dict[int, float | None] = {}
        self._cutoff_lock = threading.Lock()
        self._quantizer: Any = faiss.downcast_index(base.quantizer)

    @classmethod
    def open(
        cls, path: str, exact: np.ndarray | None = None, exact_ids: np.ndarray | None = None
    ) -> FrozenIVF:
        """Map the IVF index file at ``path`` (its id hash table, if it has one, dropped);
        ``exact``, ``exact_ids``: its vectors by id, for compressed lists (see the module
        docstring)."""
        # Before the read: were the file replaced in between, a cache stamped with this
        # identity would name a file that is gone (see stored_graph), never the new one.
        info = os.stat(path)
        base = faiss.read_index(path, faiss.IO_FLAG_MMAP_IFC)
        if base.direct_map.type != faiss.DirectMap.NoMap:  # type: ignore[attr-defined]
            base.set_direct_map_type(faiss.DirectMap.NoMap)  # type: ignore[attr-defined]
        stored = exact is not None and exact_ids is not None and exact_ids.size == base.ntotal
        locator = None if stored else stored_locator(path, base)
        frozen = cls(base, exact, exact_ids, locator)
        frozen.mapped_from = path
        frozen.file_identity = [info.st_ino, info.st_size, info.st_mtime_ns]
        frozen._view_codes(os.path.getsize(path))
        return frozen

    def _view_codes(self, file_size: int) -> None:
        """For a mapped IVFFlat file, a numpy view of the mapping holding every list's codes
        (raw float32 vectors) and each list's offset in it, so many vectors are read in one
        gather instead of one FAISS call each (a moments search reads a hundred or more).
        Only when every list lies inside one span no longer than the file: the mapping."""
        base: Any = self.base
        if not isinstance(base, faiss.IndexIVFFlat) or not self.base_ids.size:
            return
        invlists: Any = base.invlists
        code_size = 4 * self.dimension
        sizes = np.array([invlists.list_size(c) for c in range(base.nlist)], np.int64)
        starts = np.array(
            [int(invlists.get_codes(c)) if sizes[c] else 0 for c in range(base.nlist)], np.int64
        )
        used = sizes > 0
        first = int(starts[used].min())
        span = int((starts[used] + sizes[used] * code_size).max()) - first
        if span > file_size:
            return
        region = (ctypes.c_uint8 * span).from_address(first)
        self._codes = np.frombuffer(memoryview(region).cast("B"), np.uint8)
        self._list_starts = np.where(used, starts - first, -1)
        self._view_rows(first, starts[used] - first)

    def _view_rows(self, first: int, list_starts: np.ndarray) -> None:
        """When every list starts a whole number of floats after the first (``list_starts``:
        their byte offsets from ``first``), the codes as overlapping ``(R, D)`` float32 rows,
        one starting at every float: a gather of vectors then copies whole rows (``rows[byte
        offset // 4]``) instead of indexing each byte (a moments search reads thousands of
        windows; 2-4 times faster at 100 hours of windows)."""
        assert self._codes is not None
        floats = self._codes.size // 4
        if np.any(list_starts % 4) or floats < self.dimension:  # unaligned to memory is fine
            return
        as_floats = self._codes[: floats * 4].view(np.float32)
        self._rows = np.lib.stride_tricks.as_strided(
            as_floats, (floats - self.dimension + 1, self.dimension), (4, 4), writeable=False
        )

    # -- what it holds ---------------------------------------------------------------------

    @property
    def ntotal(self) -> int:
        return self.base_total - int(self.gone.size) + self.delta_total

    @property
    def changed(self) -> bool:
        """Whether it differs from its file."""
        return bool(self.gone.size or self.delta_total)

    def _base_rows(self, ids: np.ndarray) -> np.ndarray:
        """Rows of the locator holding ``ids`` ``(M,)`` (-1: not in the file, or gone)."""
        ids = np.asarray(ids, np.int64)
        rows = self.locator.rows(ids)
        if self.gone.size:
            rows[np.isin(ids, self.gone)] = -1
        return rows

    def _base_row(self, vector_id: int) -> int:
        """:meth:`_base_rows` of one id (a search's query clip), without arrays."""
        at = self.locator.row(vector_id)
        if at >= 0 and self.gone.size:
            gone_at = int(self.gone.searchsorted(vector_id))
            if gone_at < self.gone.size and int(self.gone[gone_at]) == vector_id:
                return -1
        return at

    def ids(self) -> np.ndarray:
        """``(N,)`` int64 ids held (sorted)."""
        kept = self.base_ids
        if self.gone.size:
            kept = kept[~np.isin(kept, self.gone, assume_unique=True)]
        if not self.delta_total:
            return kept
        added = faiss.vector_to_array(self.delta.id_map).astype(np.int64)
        return np.union1d(kept, added)

    def vector(self, vector_id: int) -> np.ndarray | None:
        """The ``(D,)`` float32 vector held under ``vector_id``, or None."""
        if self.delta_total:
            try:
                return np.asarray(self.delta.reconstruct(int(vector_id)), np.float32)
            except RuntimeError:
                pass
        row = self._base_row(int(vector_id))
        if row < 0:
            return None
        if self.exact is not None:
            return np.array(self.exact[row], np.float32)
        place = int(self.places[row])
        if self._codes is not None:  # one slice of the mapping, no FAISS call
            code_size = 4 * self.dimension
            start = int(self._list_starts[place >> LIST_SHIFT])
            start += (place & ((1 << LIST_SHIFT) - 1)) * code_size
            return self._codes[start : start + code_size].view(np.float32).copy()
        out = np.empty(self.dimension, np.float32)
        self.base.reconstruct_from_offset(
            place >> LIST_SHIFT, place & ((1 << LIST_SHIFT) - 1), faiss.swig_ptr(out)
        )
        return out

    def vectors(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Which of ``ids`` ``(M,)`` are held ``(M,)`` bool, and their ``(K, D)`` float32
        vectors in the order of ``ids``."""
        ids = np.asarray(ids, np.int64)
        rows = self._base_rows(ids)
        from_base = rows >= 0
        if self.exact is not None and not self.delta_total:
            return from_base, np.array(self.exact[rows[from_base]], np.float32)
        if self._codes is None or self.delta_total:
            kept, found = [], []
            for vector_id in ids.tolist():
                vector = self.vector(vector_id)
                kept.append(vector is not None)
                if vector is not None:
                    found.append(vector)
            stacked = np.stack(found) if found else np.empty((0, self.dimension), np.float32)
            return np.array(kept, bool), stacked
        places = self.places[rows[from_base]]
        code_size = 4 * self.dimension
        offsets = (
            self._list_starts[places >> LIST_SHIFT] + (places & ((1 << LIST_SHIFT) - 1)) * code_size
        )
        if self._rows is not None:
            return from_base, self._rows[offsets // 4]
        gathered = self._codes[offsets[:, None] + np.arange(code_size)]
        return from_base, gathered.view(np.float32).reshape(-1, self.dimension)

    def all_vectors(self) -> tuple[np.ndarray, np.ndarray]:
        """Every ``(ids (N,), vectors (N, D))`` held (ids ascending)."""
        ids = self.ids()
        if self.exact is not None and not self.gone.size and not self.delta_total:
            return ids, self.exact  # the rows are the ids' order: no copy (12 M windows: 6.6 GB)
        if self.exact is not None:  # rows of the file's order, then the delta's one by one
            rows = self._base_rows(ids)
            vectors = np.empty((ids.size, self.dimension), np.float32)
            vectors[rows >= 0] = self.exact[rows[rows >= 0]]
            for at in np.flatnonzero(rows < 0).tolist():
                vectors[at] = self.delta.reconstruct(int(ids[at]))
            return ids, vectors
        if not self.delta_total and self._rows is not None:  # one gather of the codes
            return ids, self.vectors(ids)[1]
        vectors = np.empty((ids.size, self.dimension), np.float32)
        for row, vector_id in enumerate(ids.tolist()):
            found = self.vector(vector_id)
            assert found is not None
            vectors[row] = found
        return ids, vectors

    # -- changes ---------------------------------------------------------------------------

    def add(self, ids: np.ndarray, vectors: np.ndarray) -> None:
        """Add vectors under ids not held yet."""
        self.delta.add_with_ids(vectors, ids)
        self.delta_total = int(self.delta.ntotal)

    def remove(self, ids: np.ndarray) -> int:
        """Remove ``ids`` (absent ones ignored); returns how many were held."""
        removed = 0
        if self.delta_total:
            removed += int(self.delta.remove_ids(faiss.IDSelectorBatch(ids)))
            self.delta_total = int(self.delta.ntotal)
        in_base = ids[self._base_rows(ids) >= 0]
        if in_base.size:
            self.gone = np.union1d(self.gone, in_base)
            removed += int(np.unique(in_base).size)
        return removed

    # -- searches --------------------------------------------------------------------------

    def search(
        self,
        queries: np.ndarray,
        k: int,
        *,
        nprobe: int,
        allowed: np.ndarray | None = None,
        adaptive: bool = False,
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(Q, k)`` squared distances and ids of the nearest held vectors to ``queries``
        ``(Q, D)`` (padded with id -1), among ``allowed`` (sorted unique ids; every cell is
        then probed) when given. ``adaptive``: skip the cells a query's nearest ones make
        unlikely, where the file's decision says so (app/index/probe_cutoff.py)."""
        fetch = k
        if self.exact is not None:  # compressed lists: candidates, ranked exactly below
            fetch = max(1, min(k * RERANK, self.base_total))
            queries = np.ascontiguousarray(queries, np.float32)
        exact_queries = queries
        queries = padded(queries, self.width)
        keep: list[Any] = []  # selectors FAISS reads must stay alive
        params: Any
        if allowed is not None:
            wanted = allowed if not self.gone.size else np.setdiff1d(allowed, self.gone, True)
            keep.append(wanted)
            params = faiss.SearchParametersIVF()
            params.sel = faiss.IDSelectorBatch(wanted)
            params.nprobe = int(self.base.nlist)
        elif self.gone.size:
            inner = faiss.IDSelectorBatch(self.gone)
            keep.append(inner)
            params = faiss.SearchParametersIVF()
            params.nprobe = nprobe
            params.sel = faiss.IDSelectorNot(inner)
        else:  # the usual search: parameters FAISS only reads, made once per nprobe
            params = self._params.get(nprobe)
            if params is None:
                params = faiss.SearchParametersIVF()
                params.nprobe = nprobe
                self._params[nprobe] = params
        cells = self.cells if allowed is None else None  # a filtered search probes all
        # FAISS's own calls without their Python wrappers' checks and copies (``queries`` is
        # C-contiguous float32 of the lists' width, ``padded``): a plain search makes one.
        count = int(queries.shape[0])
        squared = np.empty((count, fetch), np.float32)
        ids = np.empty((count, fetch), np.int64)
        # A query's decisive cells only, where the file's decision says so
        cutoff = self.cutoff(nprobe) if adaptive and allowed is None else None
        graph = cells is not None and cells.nprobe == nprobe
        if not graph and not self._cells_started and allowed is None:
            self._start_cells(nprobe)
        if graph or cutoff is not None:
            if cells is not None and graph:  # the graph's cells: the scan's (app/index/cells.py)
                to_cells, nearest = cells.nearest(queries)
            else:
                to_cells = np.empty((count, nprobe), np.float32)
                nearest = np.empty((count, nprobe), np.int64)
                self._quantizer.search_c(
                    count,
                    faiss.swig_ptr(queries),
                    nprobe,
                    faiss.swig_ptr(to_cells),
                    faiss.swig_ptr(nearest),
                    None,
                )
            every_cell = nearest.copy() if cutoff is not None else nearest
            if cutoff is not None:
                probe_cutoff.skip_far_cells(to_cells, nearest, cutoff)
            # FAISS's own search after its scan of the centroids
            self._search_cells(queries, fetch, nearest, to_cells, squared, ids, params)
            rows = np.flatnonzero(ids[:, -1] < 0) if cutoff is not None else None
            if rows is not None and rows.size:
                # The decisive cells held fewer than ``fetch`` vectors (a query in a small
                # cell, a large k): every cell, as the full search, never fewer hits than it —
                # for those queries only, so that a query's answer is the same in any batch.
                more_squared = np.empty((rows.size, fetch), np.float32)
                more_ids = np.empty((rows.size, fetch), np.int64)
                self._search_cells(
                    np.ascontiguousarray(queries[rows]),
                    fetch,
                    np.ascontiguousarray(every_cell[rows]),
                    np.ascontiguousarray(to_cells[rows]),
                    more_squared,
                    more_ids,
                    params,
                )
                squared[rows], ids[rows] = more_squared, more_ids
        else:
            self.base.search_c(
                count,
                faiss.swig_ptr(queries),
                fetch,
                faiss.swig_ptr(squared),
                faiss.swig_ptr(ids),
                params,
            )
        if self.exact is not None and count == 1:  # a search by clip or file
            squared, ids = rerank.ranked_one(exact_queries[0], ids[0], k, self.exact, self.base_ids)
        elif self.exact is not None:
            squared, ids = rerank.ranked(exact_queries, ids, k, self.exact, self._base_rows)
        queries = exact_queries
        if not self.delta_total:
            return squared, ids
        flat: Any = None
        if allowed is not None:
            flat = faiss.SearchParameters()
            flat.sel = faiss.IDSelectorBatch(allowed)
        more_squared, more_ids = self.delta.search(queries, k, params=flat)
        every_squared = np.concatenate([squared, more_squared], axis=1)
        every_ids = np.concatenate([ids, more_ids], axis=1)
        # Padding (-1) last; then nearest first, the file's hits before the delta's on ties.
        rank = np.where(every_ids >= 0, every_squared, np.inf)
        order = np.argsort(rank, axis=1, kind="stable")[:, :k]
        return (
            np.take_along_axis(every_squared, order, axis=1),
            np.take_along_axis(every_ids, order, axis=1),
        )

    def prepare(self, nprobe: int | None = None) -> None:
        """Decide the adaptive probe and build (or read) the cells' graph for searches of
        ``nprobe`` cells (default: the file's calibrated number) now, in the caller's thread:
        the process that wrote the file, or a server's verifier thread, so that no search
        pays for them (each is a function of the file; a search still decides them itself
        when nothing did)."""
        nprobe = nprobe or self.base_nprobe
        self.cutoff(nprobe)
        with self._cells_lock:  # not when a search has started building it already
            if self._cells_started:
                return
            self._cells_started = True
        self.build_cells(nprobe)

    def _start_cells(self, nprobe: int) -> None:
        """Build the cells' graph in a thread (once): the first search does not wait."""
        with self._cells_lock:
            if self._cells_started:
                return
            self._cells_started = True
        threading.Thread(
            target=self.build_cells, args=(nprobe,), name="cell-graph", daemon=True
        ).start()

    def build_cells(self, nprobe: int | None = None) -> None:
        """Build the cells' graph now for searches of ``nprobe`` cells (default: the file's
        calibrated number); see app/index/cells.py: none when it is not worth having."""
        self._cells_started = True
        if int(self.base.nlist) < GRAPH_MIN_CELLS:
            return
        nprobe = nprobe or self.base_nprobe
        file, identity = self.mapped_from, self.file_identity
        # Decided beside the file by an earlier start (app/index/cells.py: a cache of the index)
        if file is not None and identity is not None:
            decided, self.cells = stored_graph(file, identity, nprobe, self.base)
            if decided:
                return
        self.cells = CellGraph.of(self.base, nprobe, self._samples(EFFORT_SAMPLES, 0)[1])
        if file is not None and identity is not None:  # a graph, or none worth having
            store_graph(file, identity, nprobe, self.cells)

    def _samples(self, count: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
        """``count`` stored vectors of the file, drawn with ``seed`` (the same for a file at
        every start): their ids ``(S,)`` and vectors ``(S, W)`` padded to the lists' width."""
        rng = np.random.default_rng(seed)
        sample = np.sort(rng.choice(self.base_ids, min(count, self.base_ids.size), False))
        _, vectors = self.vectors(sample)
        return sample, padded(vectors, self.width)

    def _search_cells(
        self,
        queries: np.ndarray,
        fetch: int,
        cells: np.ndarray,
        to_cells: np.ndarray,
        squared: np.ndarray,
        ids: np.ndarray,
        params: Any,
    ) -> None:
        """FAISS's search of ``cells`` ``(Q, nprobe)`` (-1: skipped) at ``to_cells``, into
        ``squared`` and ``ids`` ``(Q, fetch)``."""
        self.base.search_preassigned_c(
            int(queries.shape[0]),
            faiss.swig_ptr(queries),
            fetch,
            faiss.swig_ptr(cells),
            faiss.swig_ptr(to_cells),
            faiss.swig_ptr(squared),
            faiss.swig_ptr(ids),
            False,
            params,
        )

    def cutoff(self, nprobe: int) -> float | None:
        """The ratio beyond which an adaptive search of ``nprobe`` cells skips a cell (None:
        none skipped): read from beside the file, else measured from the file's vectors and
        stored there — once per file, whichever process comes first, the same decision in
        every one (app/index/probe_cutoff.py)."""
        try:
            return self._cutoffs[nprobe]
        except KeyError:
            pass
        with self._cutoff_lock:
            if nprobe not in self._cutoffs:
                self._cutoffs[nprobe] = self._decided_cutoff(nprobe)
        return self._cutoffs[nprobe]

    def _decided_cutoff(self, nprobe: int) -> float | None:
        few_cells = int(self.base.nlist) < probe_cutoff.MIN_CELLS  # the centroids' scan is most
        if few_cells or self.exact is not None or not self.base_total:  # compressed: reranked
            return None
        return probe_cutoff.decided_cutoff(
            self.base, nprobe, self.mapped_from, self.file_identity, self._samples
        )

    def scan_cost(self, nprobe: int, *, filtered: bool) -> int:
        """Numbers one search compares (see DescriptorIndex.scan_cost)."""
        nlist = int(self.base.nlist)
        held = int(self.base.ntotal)
        probed = held if filtered else min(nprobe, nlist) * held // max(nlist, 1)
        return (nlist + probed + self.delta_total) * self.dimension

    # -- the next file ---------------------------------------------------------------------

    def merged(self) -> Any:
        """The base with the changes applied, to be written: an owned, writable copy, or
        the base itself when there are no changes (a copy would be a second 2.3 GB of
        8-bit lists at 1,000 hours of windows, bench/README.md)."""
        if not self.gone.size and not self.delta_total:
            return self.base
        index = faiss.deserialize_index(faiss.serialize_index(self.base))
        if self.gone.size:
            index.remove_ids(faiss.IDSelectorArray(self.gone.size, faiss.swig_ptr(self.gone)))
        if self.delta.ntotal:
            ids = faiss.vector_to_array(self.delta.id_map).astype(np.int64)
            flat: Any = faiss.downcast_index(self.delta.index)
            count = int(self.delta.ntotal)
            vectors = faiss.rev_swig_ptr(flat.get_xb(), count * self.dimension)
            vectors = np.asarray(vectors, np.float32).reshape(count, self.dimension)
            index.add_with_ids(padded(vectors, self.width), ids)
        return index
