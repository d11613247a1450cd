"""One FAISS index held in memory, read under a read-write lock: what it holds and its searches.

A :class:`HeldIndex` is a flat index (``IndexIDMap2(IndexFlatL2)``), an ``IndexIVFFlat`` or
a :class:`~app.index.frozen.FrozenIVF` (an IVF file mapped, with the changes since), ids being
database keys. It answers which ids it holds (sorted, kept up to date as ids come and go),
the vectors held under ids, and searches: one query, a batch, filtered to some ids or not.
Its files are :class:`~app.index.saved_index.SavedIndex`'s work, and keeping it in step with
the database :class:`~app.index.descriptor_index.DescriptorIndex`'s, which build on this class.

Concurrency: searches share the read lock, changes take the write lock, so a search sees a
clip either entirely or not at all.

Shapes: a query is ``(D,)`` float32; batches are ``(N, D)`` float32 C-contiguous with ``(N,)``
int64 ids.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import faiss
import numpy as np

from app.index.frozen import FrozenIVF
from app.index.kinds import (
    FLAT,
    IVF,
    IndexOptions,
    as_ids,
    as_vectors,
    codes_of,
    empty_flat,
    ivf_ids,
    kind_of,
    selector,
)
from app.index.locks import ReadWriteLock


@dataclass(frozen=True)
class Neighbours:
    """Search results, nearest first: ``ids`` ``(n,)`` int64, ``distances`` ``(n,)`` float64
    Euclidean (not squared)."""

    ids: np.ndarray
    distances: np.ndarray

    def __len__(self) -> int:
        return int(self.ids.shape[0])


class HeldIndex:
    """One FAISS index in memory of vectors of ``dimension`` numbers (default: an empty flat
    one), searched with ``options``' settings."""

    def __init__(
        self, dimension: int, index: Any | None = None, options: IndexOptions | None = None
    ) -> None:
        self.dimension = dimension
        self.options = options if options is not None else IndexOptions()
        self._index = index if index is not None else empty_flat(dimension)
        self._max_id: int | None = None  # see _id_bound
        self._sorted: np.ndarray | None = None  # see sorted_ids
        self._lock = ReadWriteLock()

    @property
    def size(self) -> int:
        return int(self._index.ntotal)

    @property
    def kind(self) -> str:
        return IVF if isinstance(self._index, FrozenIVF) else kind_of(self._index) or FLAT

    @property
    def codes(self) -> str:
        """What an IVF index's lists hold (``float32`` or ``sq8``; see app/index/kinds.py)."""
        index = self._index
        return codes_of(index.base if isinstance(index, FrozenIVF) else index)

    @property
    def mapped(self) -> bool:
        """Whether the index is read from its file's pages (shared by every process mapping
        it; see app/index/frozen.py), not held in memory of its own."""
        return isinstance(self._index, FrozenIVF) and self._index.mapped_from is not None

    @property
    def nprobe(self) -> int:
        """Cells an IVF search scans: ``MOCAP_IVF_NPROBE``, else the one calibrated when the
        index was built (0 for a flat index)."""
        index = self._index
        if isinstance(index, FrozenIVF):
            return self.options.nprobe or index.base_nprobe
        if kind_of(index) != IVF:
            return 0
        return int(self.options.nprobe or index.nprobe)

    def ids(self) -> np.ndarray:
        """``(N,)`` int64 ids in the index (flat: insertion order; IVF: by cell)."""
        with self._lock.read():
            return self._ids()

    def _ids(self) -> np.ndarray:
        if isinstance(self._index, FrozenIVF):
            return self._index.ids()
        if self.kind == IVF:
            return ivf_ids(self._index)
        return faiss.vector_to_array(self._index.id_map).astype(np.int64)

    def sorted_ids(self) -> np.ndarray:
        """``(N,)`` int64 ids in the index, ascending. Read from FAISS once (~60 ms for an IVF
        index of 1.2 M windows), then kept up to date as ids come and go (a few ms per change
        at that size): finding a clip's windows is then a binary search. Do not modify it."""
        with self._lock.read():
            held = self._sorted
            index = self._index
        if held is not None:
            return held
        if isinstance(index, FrozenIVF) and not index.changed:
            # The mapped file's ids are sorted already: no private copy of them (8 MB an
            # index at a million clips, in every worker process).
            return index.base_ids
        with self._lock.write():
            if self._sorted is None:
                self._sorted = np.sort(self._ids())
            return self._sorted

    def _note_added(self, ids: np.ndarray) -> None:
        """Keep :meth:`sorted_ids` up to date (under the write lock)."""
        held = self._sorted
        if held is None or not ids.size:
            return
        new = np.sort(ids)
        if not held.size or new[0] > held[-1]:
            self._sorted = np.concatenate([held, new])
        else:
            self._sorted = np.union1d(held, new)

    def _note_removed(self, ids: np.ndarray) -> None:
        """Keep :meth:`sorted_ids` up to date (under the write lock)."""
        held = self._sorted
        if held is None or not ids.size or not held.size:
            return
        at = np.minimum(np.searchsorted(held, ids), held.size - 1)
        self._sorted = np.delete(held, np.unique(at[held[at] == ids]))

    def _id_bound(self) -> int:
        """No id above this is in the index (kept up to date while adding, computed again
        after the index was swapped; removals leave it high). Under the write lock."""
        if self._max_id is None:
            ids = self._ids()
            self._max_id = int(ids.max()) if ids.size else -1
        return self._max_id

    def _add_locked(self, ids: np.ndarray, vectors: np.ndarray) -> None:
        if isinstance(self._index, FrozenIVF):
            self._index.add(ids, vectors)
        else:
            self._index.add_with_ids(vectors, ids)

    def _remove_locked(self, ids: np.ndarray) -> int:
        if isinstance(self._index, FrozenIVF):
            return self._index.remove(ids)
        return int(self._index.remove_ids(selector(self._index, ids)))

    def _held(self, vector_id: int) -> np.ndarray | None:
        """The vector held under ``vector_id`` (None: not held)."""
        if isinstance(self._index, FrozenIVF):
            return self._index.vector(vector_id)
        try:
            return np.asarray(self._index.reconstruct(int(vector_id)), np.float32)
        except RuntimeError:  # not in the index
            return None

    def search(
        self,
        query: np.ndarray,
        k: int,
        *,
        allowed: np.ndarray | None = None,
        exclude: int | None = None,
    ) -> Neighbours:
        """The ``k`` nearest stored vectors to ``query`` ``(D,)``.

        ``allowed`` ``(M,)`` int64 restricts the search to those ids (exactly: FAISS skips the
        others while scanning, and an IVF index probes every cell); ``exclude`` drops one id
        (the query clip itself) — we ask for one more neighbour and remove it, so it never
        costs a result.
        """
        q = as_vectors(query, self.dimension)
        if q.shape[0] != 1:
            raise ValueError("search takes one query vector")
        available = self.size
        if allowed is not None:
            allowed = np.unique(as_ids(allowed))
            if exclude is not None:
                allowed = allowed[allowed != exclude]
                exclude = None
            available = min(available, int(allowed.size))
        wanted = min(k + (1 if exclude is not None else 0), available)
        if wanted <= 0:
            return Neighbours(np.empty(0, np.int64), np.empty(0, np.float64))
        squared, ids = self._search_selected(q, wanted, allowed, adaptive=True)
        # A dozen numbers: Python's floats and math.sqrt (the same IEEE results as numpy's
        # float64 square root) cost less than the numpy calls filtering them would.
        skipped = -1 if exclude is None else exclude  # FAISS pads with -1 past the vectors
        kept = [
            (i, s)
            for i, s in zip(ids[0].tolist(), squared[0].tolist(), strict=True)
            if i >= 0 and i != skipped
        ][:k]
        return Neighbours(
            np.array([i for i, _ in kept], np.int64),
            np.array([math.sqrt(max(s, 0.0)) for _, s in kept], np.float64),
        )

    def unchanged_file(self) -> tuple[str, list[int]] | None:
        """The IVF file this index maps and its identity (inode, size, modification time)
        when the index holds exactly the file's vectors (none added or removed since): what
        depends only on the vectors can then be kept beside the file. Else None."""
        with self._lock.read():
            index = self._index
            if not isinstance(index, FrozenIVF) or index.changed:
                return None
            if index.mapped_from is None or index.file_identity is None:
                return None
            return index.mapped_from, list(index.file_identity)

    def prepare_searches(self) -> None:
        """Decide now what a mapped IVF file's first search by clip would otherwise decide:
        its adaptive probe and its cells' graph (:meth:`FrozenIVF.prepare`); nothing for
        other indexes. Not under the lock: searches go on meanwhile, on the same file."""
        index = self._index
        if isinstance(index, FrozenIVF) and index.mapped_from is not None:
            index.prepare(self.options.nprobe or index.base_nprobe)

    def nearest(self, query: np.ndarray, k: int, *, exclude: int) -> list[tuple[int, float]]:
        """:meth:`search` of a stored vector ``query`` ``(D,)`` float32 without filters, as
        ``(id, Euclidean distance)`` pairs, nearest first, ``exclude`` (the query clip)
        left out: the same hits and the same numbers, without the arrays around them (the
        plain ``GET /search``, app/services/search.py)."""
        return self.nearest_many(np.reshape(query, (1, -1)), k, [exclude])[0]

    def nearest_many(
        self, queries: np.ndarray, k: int, excludes: list[int]
    ) -> list[list[tuple[int, float]]]:
        """:meth:`nearest` of each of ``queries`` ``(Q, D)`` float32 (stored vectors), leaving
        out ``excludes[q]`` from the answer of query ``q``, in one FAISS call: each answer is
        the one :meth:`nearest` gives that query alone (FAISS answers the queries of a batch
        each by itself), at a fraction of the calls (app/api/search_lane.py); one query is
        :meth:`nearest`."""
        wanted = min(k + 1, self.size)
        if wanted <= 0:
            return [[] for _ in excludes]
        q = np.ascontiguousarray(queries, np.float32)
        if q.ndim != 2 or q.shape[1] != self.dimension:
            raise ValueError(f"expected vectors of {self.dimension} numbers, got {q.shape}")
        squared, ids = self._search_selected(q, wanted, None, adaptive=True)
        sqrt = math.sqrt
        return [
            [
                (i, sqrt(max(s, 0.0)))  # as search()
                for i, s in zip(row_ids, row_squared, strict=True)
                if i >= 0 and i != exclude  # FAISS pads with -1 past the vectors
            ][:k]
            for row_ids, row_squared, exclude in zip(
                ids.tolist(), squared.tolist(), excludes, strict=True
            )
        ]

    def _search_selected(
        self, q: np.ndarray, wanted: int, allowed: np.ndarray | None, *, adaptive: bool = False
    ) -> tuple[Any, Any]:
        """FAISS's squared distances and ids ``(Q, wanted)`` of the ``wanted`` nearest to ``q``
        ``(Q, D)`` among ``allowed`` (sorted unique ids; ``None``: all; an IVF index then probes
        every cell). ``adaptive``: a search by clip or file, whose mapped IVF lists are probed
        adaptively (app/index/probe_cutoff.py; batches — moments — scan every cell)."""
        with self._lock.read():
            index = self._index
            if isinstance(index, FrozenIVF):
                return index.search(
                    q, wanted, nprobe=self.nprobe, allowed=allowed, adaptive=adaptive
                )
            selector = None if allowed is None else faiss.IDSelectorBatch(allowed)
            params: Any = None
            if kind_of(index) == IVF:
                params = faiss.SearchParametersIVF()
                params.nprobe = index.nlist if selector is not None else self.nprobe
            elif selector is not None:
                params = faiss.SearchParameters()
            if selector is not None:
                params.sel = selector
            return index.search(q, wanted, params=params)

    def search_batch(
        self, queries: np.ndarray, k: int, *, allowed: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` nearest stored vectors to each of ``queries`` ``(Q, D)`` in one FAISS
        call (``allowed`` as in :meth:`search`): ``(Q, k)`` Euclidean distances (float64,
        ascending) and ids (int64, -1 past the vectors that qualify)."""
        q = as_vectors(queries, self.dimension)
        if allowed is not None:
            allowed = np.unique(as_ids(allowed))
        wanted = max(1, min(k, self.size if allowed is None else min(self.size, allowed.size)))
        if q.shape[0] == 0 or self.size == 0 or (allowed is not None and allowed.size == 0):
            empty = np.full((q.shape[0], k), -1, np.int64)
            return np.full((q.shape[0], k), np.inf), empty
        squared, ids = self._search_selected(q, wanted, allowed)
        distances = np.full((q.shape[0], k), np.inf)
        found = np.full((q.shape[0], k), -1, np.int64)
        valid = ids >= 0
        distances[:, :wanted] = np.where(
            valid, np.sqrt(np.maximum(squared.astype(np.float64), 0.0)), np.inf
        )
        found[:, :wanted] = ids
        return distances, found

    def scan_cost(self, *, filtered: bool = False) -> int:
        """Roughly how many numbers one search compares: every vector for a flat index (or a
        filtered IVF search), the centroids plus ``nprobe`` cells for IVF."""
        index = self._index
        if isinstance(index, FrozenIVF):
            return index.scan_cost(self.nprobe, filtered=filtered)
        if kind_of(index) != IVF or filtered:
            return self.size * self.dimension
        nlist = int(index.nlist)
        probed = min(self.nprobe, nlist) * self.size // max(nlist, 1)
        return (nlist + probed) * self.dimension

    def search_many(self, queries: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """``(Q, k)`` squared distances and ids for ``queries`` ``(Q, D)`` (benchmarks)."""
        q = as_vectors(queries, self.dimension)
        with self._lock.read():
            if isinstance(self._index, FrozenIVF):
                return self._index.search(q, k, nprobe=self.nprobe)
            params: Any = None
            if self.kind == IVF:
                params = faiss.SearchParametersIVF()
                params.nprobe = self.nprobe
            distances, ids = self._index.search(q, k, params=params)
        return distances, ids

    def reconstruct(self, clip_id: int) -> np.ndarray:
        """The stored ``(D,)`` float32 vector of ``clip_id`` (``KeyError`` when absent)."""
        with self._lock.read():
            held = self._held(clip_id)
        if held is None:
            raise KeyError(clip_id)
        return held

    def reconstruct_many(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The stored vectors of those of ``ids`` ``(N,)`` that are held: kept ids ``(M,)``
        and ``(M, D)`` float32 (one read lock for all)."""
        kept, vectors = [], []
        with self._lock.read():
            for vector_id in np.asarray(ids, dtype=np.int64).tolist():
                held = self._held(vector_id)
                if held is not None:
                    vectors.append(held)
                    kept.append(vector_id)
        if not vectors:
            return np.empty(0, np.int64), np.empty((0, self.dimension), np.float32)
        return np.array(kept, np.int64), np.asarray(np.stack(vectors), dtype=np.float32)

    def reconstruct_batch(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The stored vectors of ``ids`` ``(N,)``: which are held ``(N,)`` bool and their
        ``(M, D)`` float32 vectors, in the order of ``ids`` (one call into FAISS when all are
        held, the usual case; one by one otherwise)."""
        ids = np.ascontiguousarray(ids, dtype=np.int64)
        if not ids.size:
            return np.zeros(0, bool), np.empty((0, self.dimension), np.float32)
        with self._lock.read():
            if isinstance(self._index, FrozenIVF):
                return self._index.vectors(ids)
            try:
                return np.ones(ids.size, bool), self._index.reconstruct_batch(ids)
            except RuntimeError:  # one is not held
                pass
        kept, vectors = self.reconstruct_many(ids)
        return np.isin(ids, kept), vectors

    def all_vectors(self) -> tuple[np.ndarray, np.ndarray]:
        """Every ``(ids (N,), vectors (N, D))`` held (used to change the index kind)."""
        with self._lock.read():
            if isinstance(self._index, FrozenIVF):
                return self._index.all_vectors()
            if self.kind == IVF:
                invlists = self._index.invlists
                id_parts, vector_parts = [], []
                for cell in range(self._index.nlist):
                    size = invlists.list_size(cell)
                    if not size:
                        continue
                    id_parts.append(faiss.rev_swig_ptr(invlists.get_ids(cell), size).copy())
                    codes = faiss.rev_swig_ptr(invlists.get_codes(cell), size * 4 * self.dimension)
                    vector_parts.append(
                        np.frombuffer(codes, dtype=np.float32).reshape(size, self.dimension).copy()
                    )
                if not id_parts:
                    return np.empty(0, np.int64), np.empty((0, self.dimension), np.float32)
                return np.concatenate(id_parts).astype(np.int64), np.concatenate(vector_parts)
            n = self.size
            ids = faiss.vector_to_array(self._index.id_map).astype(np.int64)
            flat: Any = faiss.downcast_index(self._index.index)
            data = faiss.rev_swig_ptr(flat.get_xb(), n * self.dimension) if n else np.empty(0)
            return ids, np.asarray(data, dtype=np.float32).reshape(n, self.dimension).copy()
