"""FAISS indexes: one per descriptor, ids = clip ids.

Two kinds of index, chosen per descriptor by :class:`IndexOptions` (``MOCAP_INDEX_TYPE``):

``flat``
    ``IndexIDMap2(IndexFlatL2)``: exact, scans every vector (about 5 ms per query at 1,000,000
    12-D vectors on one core).
``ivf``
    ``IndexIVFFlat`` (ids kept natively): the vectors are split into ``nlist`` k-means cells
    and a query scans the ``nprobe`` nearest cells only. Distances are exact; the neighbour
    set is approximate (recall@10 against exact search is measured by ``bench/bench_search.py``
    and ``tests/index/test_descriptor_index.py``). A search restricted to some ids (a label
    filter) probes every cell, so it stays exact. With many cells the nearest ones may be
    found through a graph over the centroids instead of a scan of them, where that measures
    faster and finds the same cells (:mod:`app.index.cells`).

``auto`` (the default) keeps ``flat`` below ``auto_threshold`` vectors and builds ``ivf`` when
an index is (re)built at or above it; a loaded ``ivf`` index stays ``ivf`` down to half the
threshold, so a library near the threshold does not flip kind at each start.

The database is the source of truth; an index is a cache of its vectors that can always be
rebuilt. Each index is persisted as ``<dir>/<descriptor>.faiss`` with a ``<descriptor>.json``
beside it recording the descriptor version, dimension, kind, vector count, the sha256 of the
index file and ``feed_position``, the position in the database's change feed
(:mod:`app.db.changes`) the index reflects: every clip added, deleted or re-described before
it is in the index as the database has it. :meth:`DescriptorIndex.load_or_rebuild` brings a
file that is merely behind up to date by applying the clips changed since (cheap: an import
killed half way or a server killed before it saved costs only the rows it missed), then checks
the vector count against the database; a count that still disagrees is repaired by comparing
ids. A missing, unreadable or damaged file, or one of another version or dimension, is
rebuilt. (``synced_to`` in the code is that feed position.)

Files: saves write a temporary file and rename it, under an exclusive ``fcntl.flock`` on
``<dir>/.lock`` (loads take it shared), so two processes (the server and ``mocap-index
import``) never interleave the ``.faiss`` and ``.json`` of one index.

Concurrency: searches share a read lock, add/remove take the write lock, so a search sees a
clip either entirely or not at all.

Shapes: a query is ``(D,)`` float32; batches are ``(N, D)`` float32 C-contiguous with ``(N,)``
int64 ids.
"""

from __future__ import annotations

import ctypes
import json
import logging
import math
import os
import threading
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import faiss
import numpy as np

from app.index.array_file import (
    file_sha256,
    has_checksum,
    is_stamped,
    read_arrays,
    stream_sha256,
    verify_arrays,
    write_arrays,
    write_stamp,
)
from app.index.frozen import FrozenIVF
from app.index.kinds import (
    FLAT,
    FLOAT32,
    IVF,
    SQ8,
    IndexOptions,
    as_ids,
    as_vectors,
    build_index,
    codes_of,
    empty_flat,
    has_id_map,
    ivf_ids,
    kind_of,
    padded_width,
    selector,
    with_id_map,
)
from app.index.locks import ReadWriteLock, directory_lock

log = logging.getLogger(__name__)

EXACT_FORMAT = 1  # the layout of an index's exact vectors file (compressed lists)


class VectorSource(Protocol):
    """The database's view of one descriptor's vectors (one consistent snapshot)."""

    def watermark(self) -> int:
        """The feed position of this snapshot: every change before it is reflected by what
        the other methods return."""
        ...

    def count(self) -> int:
        """How many vectors of the descriptor (and its version) the database holds."""
        ...

    def ids(self) -> np.ndarray:
        """``(N,)`` int64 sorted ids of every vector."""
        ...

    def vectors(self) -> tuple[np.ndarray, np.ndarray]:
        """Ids ``(N,)`` and vectors ``(N, D)`` of every clip (id order)."""
        ...

    def changed(self, since: int) -> np.ndarray:
        """``(N,)`` int64 ids of the clips changed (added, deleted, re-described) at or after
        feed position ``since``."""
        ...

    def vectors_of(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ids and vectors of the given clips (those that have one)."""
        ...


@dataclass(frozen=True)
class Neighbours:
    """Search results, nearest first: ``ids`` ``(n,)`` int64, ``distances`` ``(n,)`` float64
    Euclidean (not squared)."""

    ids: np.ndarray
    distances: np.ndarray

    def __len__(self) -> int:
        return int(self.ids.shape[0])


def _return_freed_memory() -> None:
    """Give the heap's free pages back to the system (glibc's ``malloc_trim``): mapping an
    index file reads and sorts its ids (the locator) in temporary arrays, whose pages would
    otherwise stay in each server process's resident memory, private to it."""
    if _LIBC is not None:
        _LIBC.malloc_trim(0)


def _libc() -> Any:
    try:
        return ctypes.CDLL("libc.so.6")  # glibc; elsewhere nothing is trimmed
    except OSError:
        return None


_LIBC = _libc()


class DescriptorIndex:
    """The index of one descriptor.

    Parameters
    ----------
    name, dimension, version:
        The descriptor (as in the registry); only vectors of this version are held.
    directory:
        Where ``<name>.faiss`` and ``<name>.json`` are written.
    index:
        A FAISS index to start from (default: an empty flat one).
    options:
        Index kind and search settings.
    """

    def __init__(
        self,
        name: str,
        dimension: int,
        version: int,
        directory: Path,
        index: Any | None = None,
        options: IndexOptions | None = None,
    ) -> None:
        self.name = name
        self.dimension = dimension
        self.version = version
        self.directory = directory
        self.options = options if options is not None else IndexOptions()
        self._index = index if index is not None else empty_flat(dimension)
        self._max_id: int | None = None  # see _id_bound
        self._sorted: np.ndarray | None = None  # see sorted_ids
        self._synced_to = 0
        self._unsaved = 0
        self.autosave = True  # False: changes are saved only by an explicit save()
        self._timer: threading.Timer | None = None
        self._timer_lock = threading.Lock()
        self._lock = ReadWriteLock()
        self._save_lock = threading.Lock()
        self._unchecked: tuple[int, str] | None = None  # see read_file(verify=False)
        self._unchecked_exact: tuple[Any, Any] | None = None  # ... its exact vectors
        self._mapped_inode = -1  # the index file mapped (see _map), and its metadata
        self._mapped_meta: dict[str, Any] = {}

    @property
    def path(self) -> Path:
        return self.directory / f"{self.name}.faiss"

    @property
    def meta_path(self) -> Path:
        return self.directory / f"{self.name}.json"

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

    @property
    def synced_to(self) -> int:
        """The largest database clip id whose vector this index reflects."""
        return self._synced_to

    @property
    def unsaved_changes(self) -> int:
        return self._unsaved

    def mark_synced(self, position: int) -> None:
        """Nothing changed up to feed position ``position``: the index reflects it."""
        self._synced_to = max(self._synced_to, int(position))

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

    def _autosave(self, persist: bool | None) -> None:
        if persist:
            self.try_save()
        elif persist is None and self.autosave and self.size <= self.options.autosave_below:
            if self.options.save_delay <= 0:
                self.try_save()
            else:
                self._schedule_save()

    def _schedule_save(self) -> None:
        """Save in ``save_delay`` seconds (once for every change made meanwhile): a file per
        upload would cost more than describing the upload."""
        with self._timer_lock:
            if self._timer is not None:
                return
            self._timer = threading.Timer(self.options.save_delay, self._timed_save)
            self._timer.daemon = True
            self._timer.start()

    def _timed_save(self) -> None:
        with self._timer_lock:
            self._timer = None
        self.try_save()

    def flush(self) -> None:
        """Save now if anything is unsaved (a pending delayed save is done now instead)."""
        with self._timer_lock:
            timer, self._timer = self._timer, None
        if timer is not None:
            timer.cancel()
        if self._unsaved:
            self.try_save()

    def try_save(self) -> bool:
        """:meth:`save`, logging instead of raising when the file cannot be written (the
        index in memory is right; a file that is behind catches up when it is next loaded).
        Returns whether it was saved."""
        try:
            self.save()
        except (OSError, RuntimeError) as exc:  # FAISS reports unwritable files as RuntimeError
            log.warning(
                "could not save the %s index (%s); it catches up from the database when next "
                "loaded",
                self.name,
                exc,
            )
            return False
        return True

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

    def add(
        self,
        ids: np.ndarray | list[int],
        vectors: np.ndarray,
        *,
        persist: bool | None = None,
        synced_to: int | None = None,
    ) -> None:
        """Add ``vectors`` ``(N, D)`` under ``ids`` ``(N,)`` (ids must not be present yet).

        ``synced_to`` records the database clip id the index now reflects. ``persist``: save
        now (True), not now (False), or when the index is small (None).
        """
        ids_ = as_ids(ids)
        array = as_vectors(vectors, self.dimension)
        if array.shape[0] != ids_.shape[0]:
            raise ValueError("ids and vectors differ in length")
        if ids_.size == 0 and synced_to is None:
            return
        with self._lock.write():
            if ids_.size:
                self._add_locked(ids_, array)
                self._note_added(ids_)
                self._unsaved += int(ids_.size)
                if self._max_id is not None:
                    self._max_id = max(self._max_id, int(ids_.max()))
            if synced_to is not None:
                self._synced_to = max(self._synced_to, int(synced_to))
        if ids_.size:
            self._autosave(persist)

    def remove(self, ids: np.ndarray | list[int], *, persist: bool | None = None) -> int:
        """Remove ``ids`` (absent ones are ignored); returns how many were removed."""
        ids_ = as_ids(ids)
        if ids_.size == 0:
            return 0
        with self._lock.write():
            removed = self._remove_locked(ids_)
            self._note_removed(ids_)
            self._unsaved += removed
        if removed:
            self._autosave(persist)
        return removed

    def apply_changes(
        self,
        changed: np.ndarray,
        ids: np.ndarray,
        vectors: np.ndarray,
        *,
        persist: bool | None = None,
        synced_to: int | None = None,
    ) -> tuple[int, int]:
        """Make the index agree with the database about the ``changed`` ``(C,)`` clips, whose
        current vectors are ``vectors`` ``(N, D)`` under ``ids`` ``(N,)`` (those that still
        have one): a clip gone from the database leaves the index, a new one enters, one whose
        vector differs is replaced. Applying the same changes twice changes nothing. Returns
        how many vectors were added and removed."""
        changed_ = np.unique(as_ids(changed))
        ids_ = as_ids(ids)
        array = (
            as_vectors(vectors, self.dimension)
            if ids_.size
            else np.empty((0, self.dimension), np.float32)
        )
        current = {int(i): row for row, i in enumerate(ids_.tolist())}
        with self._lock.write():
            remove: set[int] = set()
            add: list[int] = []
            # New ids (an import's) are above every id held: no lookup, which FAISS answers
            # for an absent id by raising (~10 us each, ~20 window ids per clip).
            bound = self._id_bound()
            for clip_id in changed_.tolist():
                held = self._held(clip_id) if clip_id <= bound else None
                row = current.get(clip_id)
                if held is not None and (row is None or not np.array_equal(held, array[row])):
                    remove.add(clip_id)
                if row is not None and (held is None or clip_id in remove):
                    add.append(row)
            if remove:
                gone = as_ids(sorted(remove))  # kept alive while FAISS reads it
                self._remove_locked(gone)
                self._note_removed(gone)
            if add:
                rows = np.asarray(add, dtype=np.int64)
                self._add_locked(ids_[rows], np.ascontiguousarray(array[rows]))
                self._note_added(ids_[rows])
                self._max_id = max(bound, int(ids_[rows].max()))
            self._unsaved += len(add) + len(remove)
            if synced_to is not None:
                self._synced_to = max(self._synced_to, int(synced_to))
        if add or remove:
            self._autosave(persist)
        return len(add), len(remove)

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
        squared, ids = self._search_selected(q, wanted, allowed)
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

    def nearest(self, query: np.ndarray, k: int, *, exclude: int) -> list[tuple[int, float]]:
        """:meth:`search` of a stored vector ``query`` ``(D,)`` float32 without filters, as
        ``(id, Euclidean distance)`` pairs, nearest first, ``exclude`` (the query clip)
        left out: the same hits and the same numbers, without the arrays around them (the
        plain ``GET /search``, app/services/search.py)."""
        wanted = min(k + 1, self.size)
        if wanted <= 0:
            return []
        q = np.ascontiguousarray(query, np.float32).reshape(1, -1)
        if q.shape[1] != self.dimension:
            raise ValueError(f"expected a vector of {self.dimension} numbers, got {query.shape}")
        squared, ids = self._search_selected(q, wanted, None)
        sqrt = math.sqrt
        found = [
            (i, sqrt(max(s, 0.0)))  # as search()
            for i, s in zip(ids[0].tolist(), squared[0].tolist(), strict=True)
            if i >= 0 and i != exclude  # FAISS pads with -1 past the vectors
        ]
        return found[:k]

    def _search_selected(
        self, q: np.ndarray, wanted: int, allowed: np.ndarray | None
    ) -> tuple[Any, Any]:
        """FAISS's squared distances and ids ``(Q, wanted)`` of the ``wanted`` nearest to ``q``
        ``(Q, D)`` among ``allowed`` (sorted unique ids; ``None``: all; an IVF index then probes
        every cell)."""
        with self._lock.read():
            index = self._index
            if isinstance(index, FrozenIVF):
                return index.search(q, wanted, nprobe=self.nprobe, allowed=allowed)
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

    def replace_all(
        self,
        ids: np.ndarray,
        vectors: np.ndarray,
        *,
        persist: bool = True,
        synced_to: int | None = None,
        kind: str | None = None,
        threads: int | None = None,
    ) -> None:
        """Swap in a new index holding exactly ``vectors`` ``(N, D)`` under ``ids`` ``(N,)``,
        of ``kind`` (default: what :class:`IndexOptions` asks for ``N`` vectors)."""
        ids_ = as_ids(ids)
        array = (
            as_vectors(vectors, self.dimension)
            if ids_.size
            else np.empty((0, self.dimension), np.float32)
        )
        kind = kind or self.options.kind_for(int(ids_.size))
        fresh = build_index(ids_, array, kind, self.options, threads=threads)
        if kind_of(fresh) == IVF and codes_of(fresh) == SQ8:  # its exact vectors beside it
            order = np.argsort(ids_, kind="stable")
            fresh = FrozenIVF(fresh, array[order], ids_[order])
        self._drop_unchecked()  # that file is no longer used
        with self._lock.write():
            self._index = fresh
            self._max_id = None
            self._sorted = None
            self._unsaved = int(ids_.size) + 1
            if synced_to is not None:
                self._synced_to = int(synced_to)
        if persist:
            self.save()

    def save(self) -> None:
        """Write the index and its metadata atomically (temp file, then rename), under the
        directory's exclusive file lock; then map the file (IVF; see app/index/frozen.py)
        instead of holding a copy, when nothing changed meanwhile."""
        # The save lock keeps two saves in order: the last state serialised is the one written.
        with self._save_lock, directory_lock(self.directory, exclusive=True):
            with self._lock.read():
                index = self._index
                count = int(index.ntotal)
                kind = self.kind
                nprobe = self.nprobe
                synced_to = self._synced_to
                unsaved = self._unsaved
                if (
                    isinstance(index, FrozenIVF)
                    and index.mapped_from is not None
                    and not index.changed
                    and self._is_mapped_file()
                ):
                    # The file holds these vectors: only the feed position moves on.
                    self._write_meta(dict(self._mapped_meta, feed_position=synced_to))
                    self._unsaved = max(0, self._unsaved - unsaved)
                    return
                written = index.merged() if isinstance(index, FrozenIVF) else index
                if isinstance(index, FrozenIVF) and index.exact is not None:
                    # a copy, mapped once written: no id hash table for FAISS to rebuild
                    written.set_direct_map_type(faiss.DirectMap.NoMap)  # type: ignore[attr-defined]
                exact = (
                    index.all_vectors()
                    if isinstance(index, FrozenIVF) and index.exact is not None
                    else None
                )
                tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.tmp")
                try:
                    faiss.write_index(written, str(tmp))
                except BaseException:
                    tmp.unlink(missing_ok=True)
                    raise
            del written
            try:
                fd = os.open(tmp, os.O_RDONLY)
                try:
                    os.fsync(fd)
                finally:
                    os.close(fd)
                meta = {
                    "descriptor": self.name,
                    "version": self.version,
                    "dimension": self.dimension,
                    "kind": kind,
                    "codes": FLOAT32 if exact is None else SQ8,
                    "nprobe": nprobe,
                    "count": count,
                    "feed_position": synced_to,
                    "sha256": file_sha256(tmp),
                    "saved_at": time.time(),
                }
                if exact is not None:  # first: an index file never lacks its exact vectors
                    write_arrays(
                        self.directory,
                        f"{self.name}.exact",
                        {"ids": exact[0], "vectors": exact[1]},
                        {"format": EXACT_FORMAT, "index_sha256": meta["sha256"]},
                        lock=False,
                    )
                    del exact
                os.replace(tmp, self.path)
            finally:
                tmp.unlink(missing_ok=True)
            self._write_meta(meta)
            mapped = self._map(meta) if kind == IVF and self._maps(meta) else None
            with self._lock.write():
                if mapped is not None and self._index is index and self._unsaved == unsaved:
                    self._index = mapped  # nothing changed while writing: share the file
                    self._sorted = None
                self._unsaved = max(0, self._unsaved - unsaved)

    def _write_meta(self, meta: dict[str, Any]) -> None:
        meta_tmp = self.meta_path.with_name(f".{self.meta_path.name}.{os.getpid()}.tmp")
        try:
            meta_tmp.write_text(json.dumps(meta, indent=2))
            os.replace(meta_tmp, self.meta_path)
        finally:
            meta_tmp.unlink(missing_ok=True)

    def _maps(self, meta: dict[str, Any]) -> bool:
        """Whether an IVF file of ``meta`` is mapped (compressed lists always are: their
        exact vectors are only read that way)."""
        return self.options.mmap or meta.get("codes") == SQ8

    def _read_exact(
        self, meta: dict[str, Any], *, verify: bool
    ) -> tuple[np.ndarray, np.ndarray] | str:
        """The sorted ids ``(N,)`` and ``(N, D)`` exact vectors of the index file of ``meta``
        (mapped), or why they cannot be used: missing, damaged, or written with another index
        file."""
        expect = {"format": EXACT_FORMAT, "index_sha256": meta.get("sha256")}
        found = read_arrays(self.directory, f"{self.name}.exact", expect, verify=verify, lock=False)
        if isinstance(found, str):
            return found
        arrays, exact_meta = found
        ids, vectors = arrays.get("ids"), arrays.get("vectors")
        if vectors is None or vectors.ndim != 2 or vectors.shape[1] != self.dimension:
            return "exact vectors of another shape"
        if ids is None or ids.shape != (vectors.shape[0],) or ids.dtype != np.int64:
            return "exact vectors without their ids"
        if not verify:
            self._unchecked_exact = (arrays, exact_meta)
        return ids, vectors

    def _map(self, meta: dict[str, Any], *, verify_exact: bool = True) -> FrozenIVF | None:
        """The index file, mapped (None when it cannot be: the copy in memory stays), with
        its exact vectors when its lists are compressed (the caller holds the directory's
        lock; their checksum is checked later when ``verify_exact`` is False)."""
        try:
            exact: tuple[np.ndarray, np.ndarray] | tuple[None, None] = (None, None)
            if meta.get("codes") == SQ8:
                found = self._read_exact(meta, verify=verify_exact)
                if isinstance(found, str):
                    log.warning("the %s index's exact vectors: %s", self.name, found)
                    return None
                exact = found
            mapped = FrozenIVF.open(str(self.path), exact[1], exact[0])
            self._mapped_inode = os.stat(self.path).st_ino
        except (OSError, RuntimeError) as exc:
            log.warning("could not map the %s index file (%s); holding a copy", self.name, exc)
            return None
        self._mapped_meta = meta
        _return_freed_memory()
        return mapped

    def _is_mapped_file(self) -> bool:
        """Whether the index file is still the one mapped (not replaced by another process)."""
        try:
            return os.stat(self.path).st_ino == self._mapped_inode
        except OSError:
            return False

    def read_file(self, *, verify: bool = True) -> tuple[Any, dict[str, Any]] | str:
        """The persisted index and its metadata, or why they cannot be used (file work only:
        several indexes can be read at once, in threads). An IVF index is mapped, not read
        (see app/index/frozen.py); with ``verify=False`` its checksum is checked later, by
        :meth:`verify_file` (hashing a large file is most of a server's start-up)."""
        with directory_lock(self.directory, exclusive=False):
            try:
                meta = json.loads(self.meta_path.read_text())
                later = not verify and meta.get("kind") == IVF and self._maps(meta)
                # Checked now (at once when its stamp shows it unchanged since it matched);
                # "": it does not match.
                expected = meta.get("sha256")
                digest = None if later else expected if has_checksum(self.path, expected) else ""
            except FileNotFoundError as exc:
                return f"missing {Path(exc.filename).name}"
            except (OSError, ValueError) as exc:
                return f"unreadable metadata: {exc}"
            if not isinstance(meta, dict):
                return "unreadable metadata"
            for key, value in (
                ("descriptor", self.name),
                ("version", self.version),
                ("dimension", self.dimension),
            ):
                if meta.get(key) != value:
                    return f"{key} is {meta.get(key)!r}, expected {value!r}"
            if digest is not None and meta.get("sha256") != digest:
                return "index file does not match its checksum"
            try:
                if meta.get("kind") == IVF and self._maps(meta):
                    if digest is None:  # the file now mapped, open until checked (the lock
                        # keeps another process from replacing it meanwhile)
                        self._unchecked = (os.open(self.path, os.O_RDONLY), str(meta["sha256"]))
                    mapped = self._map(meta, verify_exact=digest is not None)
                    if mapped is None:
                        return "unreadable index"
                    index: Any = mapped
                    plain: Any = mapped.base
                else:
                    index = plain = faiss.read_index(str(self.path))
            except RuntimeError as exc:
                return f"unreadable index: {exc}"
        width = padded_width(self.dimension) if codes_of(plain) == SQ8 else self.dimension
        if kind_of(plain) is None or plain.d != width:
            return "index of another kind or dimension"
        if kind_of(plain) == IVF and not isinstance(index, FrozenIVF) and not has_id_map(index):
            with_id_map(index)  # a file written before the id map was kept: save it again
            meta["resave"] = True
        if int(index.ntotal) != meta.get("count"):
            return "index count disagrees with its metadata"
        if kind_of(index) == FLAT and index.id_map.size() != index.ntotal:
            return "index count disagrees with its id map"
        return index, meta

    def _drop_unchecked(self) -> None:
        self._unchecked_exact = None
        unchecked, self._unchecked = self._unchecked, None
        if unchecked is not None:
            os.close(unchecked[0])

    def verify_file(self) -> str | None:
        """Check the checksum of the file mapped by ``read_file(verify=False)``: why it cannot
        be used (the caller rebuilds the index), or None."""
        unchecked, self._unchecked = self._unchecked, None
        exact, self._unchecked_exact = self._unchecked_exact, None
        if exact is not None and (problem := verify_arrays(*exact)) is not None:
            if unchecked is not None:
                os.close(unchecked[0])
            return f"exact vectors: {problem}"
        if unchecked is None:
            return None
        fd, expected = unchecked
        try:
            with os.fdopen(fd, "rb") as stream:
                info = os.fstat(stream.fileno())  # the file mapped, even if replaced since
                if is_stamped(self.path, info, expected):
                    return None  # unchanged since it matched: not hashed again
                digest = stream_sha256(stream)
        except OSError as exc:
            return f"unreadable index file: {exc}"
        if digest != expected:
            return "index file does not match its checksum"
        write_stamp(self.path, info, expected)
        return None

    def load_or_rebuild(
        self, source: VectorSource, found: tuple[Any, dict[str, Any]] | str | None = None
    ) -> str | None:
        """Load the persisted index and bring it up to date with ``source`` (the database);
        rebuild it from ``source`` when the file cannot be used. Returns why it was rebuilt or
        repaired, or ``None`` when the file was used as it is (plus rows it had not seen).
        ``found``: what :meth:`read_file` returned, when it was called already."""
        if found is None:
            found = self.read_file()
        watermark = source.watermark()
        if isinstance(found, str):
            return self._rebuild(source, watermark, found)
        index, meta = found
        with self._lock.write():
            self._index = index
            self._max_id = None
            self._sorted = None
            self._synced_to = 0
            self._unsaved = 0
        position = meta.get("feed_position")
        changed = bool(meta.get("resave"))
        problem: str | None = None
        if isinstance(position, int) and 0 <= position <= watermark:
            self._synced_to = position
            # Behind: apply what changed since (also at the same position on PostgreSQL,
            # where transactions running then may have committed since).
            touched = source.changed(since=position)
            if touched.size:
                ids, vectors = source.vectors_of(touched)
                added, removed = self.apply_changes(touched, ids, vectors, persist=False)
                changed = changed or bool(added or removed)
            changed = changed or position != watermark
            self._synced_to = watermark
            expected = source.count()
            if self.size != expected:
                problem = f"index holds {self.size} vectors, database {expected}"
        else:
            problem = (
                "index was saved from another database"
                if isinstance(position, int)
                else "index records no database position"
            )
        if problem is not None:
            repaired = self._repair(source, watermark, problem)
            if repaired is not None:
                return repaired
            changed = True
        desired = self.options.kind_for(self.size, self.kind)
        if desired != self.kind or (desired == IVF and self.codes != self.options.codes):
            ids, vectors = self.all_vectors()
            log.info("building a %s index for %s (%d vectors)", desired, self.name, ids.size)
            self.replace_all(ids, vectors, persist=False, synced_to=self._synced_to, kind=desired)
            changed = True
        if changed:
            self.save()
        return problem

    def _repair(self, source: VectorSource, watermark: int, problem: str) -> str | None:
        """Make the loaded index hold exactly the database's ids by adding and removing the
        difference; rebuild instead when it is large. Returns the rebuild reason, or None."""
        expected = source.ids()
        have = self.ids()
        missing = np.setdiff1d(expected, have, assume_unique=True)
        extra = np.setdiff1d(have, expected, assume_unique=True)
        if missing.size + extra.size > max(1000, expected.size // 4):
            if expected.size == have.size:
                problem = "index ids differ from the database"
            return self._rebuild(source, watermark, problem)
        self.remove(extra, persist=False)
        if missing.size:
            ids, vectors = source.vectors_of(missing)
            self.add(ids, vectors, persist=False)
        self._synced_to = watermark
        log.warning(
            "repaired the %s index from the database (%d added, %d removed): %s",
            self.name,
            missing.size,
            extra.size,
            problem,
        )
        return None

    def _rebuild(self, source: VectorSource, watermark: int, problem: str) -> str:
        ids, vectors = source.vectors()
        self.replace_all(ids, vectors, synced_to=watermark, persist=True)
        # A new, empty library has no index yet: that is no news (the library says so once).
        level = logging.WARNING if ids.size else logging.DEBUG
        log.log(
            level,
            "rebuilt the %s index from the database (%d vectors, %s): %s",
            self.name,
            ids.size,
            self.kind,
            problem,
        )
        return problem


class IndexSet(Mapping[str, DescriptorIndex]):
    """The indexes of every descriptor, by descriptor name."""

    def __init__(self, indexes: Mapping[str, DescriptorIndex]) -> None:
        self._indexes = dict(indexes)

    def __getitem__(self, name: str) -> DescriptorIndex:
        return self._indexes[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._indexes)

    def __len__(self) -> int:
        return len(self._indexes)

    def add(self, ids: np.ndarray | list[int], vectors: Mapping[str, np.ndarray]) -> None:
        """Add one batch: ``vectors[name]`` is ``(N, D_name)`` for the ``(N,)`` ``ids``."""
        for name, array in vectors.items():
            self._indexes[name].add(ids, array)

    def remove(self, ids: np.ndarray | list[int]) -> None:
        """Remove ``ids`` from every index."""
        for index in self._indexes.values():
            index.remove(ids)

    def sizes(self) -> dict[str, int]:
        return {name: index.size for name, index in self._indexes.items()}

    def save(self, *, only_changed: bool = True) -> None:
        """Save every index (with ``only_changed``: those with unsaved changes); a file that
        cannot be written is logged, not raised (see :meth:`DescriptorIndex.try_save`)."""
        for index in self._indexes.values():
            if only_changed:
                index.flush()
            else:
                index.try_save()
