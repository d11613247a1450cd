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

Layout: :class:`DescriptorIndex` builds on :class:`app.index.saved_index.SavedIndex` (its
files: saving, reading back; see there for the file locks), which builds on
:class:`app.index.held_index.HeldIndex` (the FAISS index in memory: what it holds, its
searches). Searches share a read lock, add/remove take the write lock, so a search sees a
clip either entirely or not at all.

Shapes: a query is ``(D,)`` float32; batches are ``(N, D)`` float32 C-contiguous with ``(N,)``
int64 ids.
"""

from __future__ import annotations

import logging
from typing import Any, Protocol

import faiss
import numpy as np

from app.index.frozen import FrozenIVF
from app.index.kinds import (
    IVF,
    SQ8,
    as_ids,
    as_vectors,
    build_index,
    codes_of,
    kind_of,
)
from app.index.saved_index import SavedIndex

log = logging.getLogger(__name__)


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


class DescriptorIndex(SavedIndex):
    """The index of one descriptor kept in step with the database: changes applied, loaded
    and brought up to date or rebuilt (:class:`SavedIndex` saves it; what it holds and its
    searches are :class:`HeldIndex`'s). Constructed as :class:`SavedIndex`."""

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
            # Its vectors are read from the exact rows: no id hash table (~40 bytes a vector)
            fresh.set_direct_map_type(faiss.DirectMap.NoMap)  # type: ignore[attr-defined]
            if np.all(ids_[1:] > ids_[:-1]):  # already in id order (the database's): no copy
                fresh = FrozenIVF(fresh, array, ids_)
            else:
                order = np.argsort(ids_, kind="stable")
                fresh = FrozenIVF(fresh, array[order], ids_[order])
        self.file.drop_unchecked()  # that file is no longer used
        with self._lock.write():
            self._index = fresh
            self._max_id = None
            self._sorted = None
            self._unsaved = int(ids_.size) + 1
            if synced_to is not None:
                self._synced_to = int(synced_to)
        if persist:
            self.save()

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
