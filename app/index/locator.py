"""Where each id of a mapped IVF index file lies: the *locator* (issue 23).

A :class:`app.index.frozen.FrozenIVF` finds a stored vector without FAISS's id hash table,
which would be a private copy in every process (~40 bytes per vector): the file's ids
``(N,)`` sorted and each one's place ``(N,)`` (its list << :data:`LIST_SHIFT` | its offset in
the list). They are read once when the file is mapped, by a pass over the lists and a sort
(:func:`walk_lists`), and kept in ``<stem>.locator.arrays`` beside the file for the next start
(:func:`stored_locator`). :class:`Locator` answers which row holds an id: a guess from a
table of id buckets, checked, else a binary search.

Shapes: ids ``(N,)`` int64 sorted; places ``(N,)`` int64.
"""

from __future__ import annotations

import contextlib
import os
from bisect import bisect_left
from pathlib import Path
from typing import Any

import faiss
import numpy as np

from app.index.array_file import read_arrays, write_arrays

LIST_SHIFT = 32  # a place is list << 32 | offset
LOCATOR_FORMAT = 1  # of the <index>.locator files (see stored_locator)
LOCATOR_CHECKS = 64  # places of a stored locator checked against the lists when it is read
BUCKET_BITS = 20  # ids sharing their bits above these are looked up from one table entry
MAX_BUCKETS = 1 << 22  # ... a table of at most this many entries (32 MB)


def int64_view(array: np.ndarray) -> memoryview:
    """``array`` ``(N,)`` int64 as a view whose items are Python ints."""
    return np.ascontiguousarray(array, np.int64).data.cast("B").cast("q")


def stored_locator(path: str, base: Any) -> tuple[np.ndarray, np.ndarray]:
    """:func:`walk_lists` of the index file at ``path`` (mapped as ``base``), read from
    ``<stem>.locator.arrays`` beside it when that file was written from this very index file
    (its inode, size and modification time; its own checksum; a sample of its places
    checked against the lists), else computed and written there for the next start: the
    pass over the lists and the sort of a million ids are most of opening a window index
    (~0.8 s a worker at 100 hours). The caller holds the directory's lock (shared: the index
    file does not change meanwhile; the locator file is replaced atomically)."""
    directory, stem = Path(path).parent, f"{Path(path).stem}.locator"
    info = os.stat(path)
    stamp = {"format": LOCATOR_FORMAT, "index_file": [info.st_ino, info.st_size, info.st_mtime_ns]}
    found = read_arrays(directory, stem, stamp, lock=False)
    if not isinstance(found, str):
        ids, places = found[0].get("ids"), found[0].get("places")
        if (
            ids is not None
            and places is not None
            and ids.shape == places.shape == (int(base.ntotal),)
            and _places_hold(base, ids, places)
        ):
            return ids, places
    ids, places = walk_lists(base)
    with contextlib.suppress(OSError):  # a read-only directory: computed at the next start
        write_arrays(directory, stem, {"ids": ids, "places": places}, stamp, lock=False)
    return ids, places


def _places_hold(base: Any, ids: np.ndarray, places: np.ndarray) -> bool:
    """Whether a sample of ``places`` (list << LIST_SHIFT | offset) hold their ``ids`` in the
    lists of ``base``, and ``ids`` ascend."""
    if not ids.size:
        return True
    if ids.size > 1 and not bool(np.all(ids[1:] > ids[:-1])):
        return False
    invlists = base.invlists
    offset_mask = (1 << LIST_SHIFT) - 1
    for row in np.linspace(0, ids.size - 1, min(LOCATOR_CHECKS, ids.size)).astype(np.int64):
        cell, offset = int(places[row]) >> LIST_SHIFT, int(places[row]) & offset_mask
        if not 0 <= cell < base.nlist or offset >= invlists.list_size(cell):
            return False
        if int(invlists.get_single_id(cell, offset)) != int(ids[row]):
            return False
    return True


def walk_lists(base: Any) -> tuple[np.ndarray, np.ndarray]:
    """Every id of the IVF index ``base`` ``(N,)`` sorted, and where it lies ``(N,)`` (list
    << LIST_SHIFT | offset)."""
    invlists = base.invlists
    ids, places = [], []
    for cell in range(base.nlist):
        size = invlists.list_size(cell)
        if size:
            ids.append(faiss.rev_swig_ptr(invlists.get_ids(cell), size).copy())
            places.append((cell << LIST_SHIFT) + np.arange(size, dtype=np.int64))
    every = np.concatenate(ids).astype(np.int64) if ids else np.zeros(0, np.int64)
    order = np.argsort(every, kind="stable")
    return every[order], np.concatenate(places)[order] if places else np.zeros(0, np.int64)


class Locator:
    """Which row of the file's sorted ``ids`` ``(N,)`` holds an id; ``places`` ``(N,)``:
    where each lies in the lists (empty when the vectors are read from exact rows)."""

    def __init__(self, ids: np.ndarray, places: np.ndarray) -> None:
        self.ids = ids
        self.places = places
        self._buckets: np.ndarray | None = None  # see guessed_rows
        self._views: tuple[memoryview, memoryview | None] | None = None  # see _id_views

    def rows(self, ids: np.ndarray) -> np.ndarray:
        """Rows holding ``ids`` ``(M,)``: ``(M,)`` int64, -1 where an id is not in the file."""
        ids = np.asarray(ids, np.int64)
        if not self.ids.size:
            return np.full(ids.size, -1, np.int64)
        at = self.guessed_rows(ids)
        found = self.ids[at] == ids
        if not found.all():  # not where a run of consecutive ids puts them: searched for
            missed = np.flatnonzero(~found)
            at[missed] = np.minimum(self.ids.searchsorted(ids[missed]), self.ids.size - 1)
            found[missed] = self.ids[at[missed]] == ids[missed]
        return np.where(found, at, -1)

    def guessed_rows(self, ids: np.ndarray) -> np.ndarray:
        """Where ``ids`` ``(M,)`` would lie in the locator if the ids of their bucket (ids
        sharing their bits above :data:`BUCKET_BITS`) ran without gaps from the bucket's
        first: ``(M,)`` rows, to check. Window ids (``clip << 20 | ordinal``) do within a
        clip, so a vector is found with two reads instead of a binary search over a million
        ids (~20 reads far apart: a moments search looks up thousands)."""
        if self._buckets is None:
            buckets = (int(self.ids[-1]) >> BUCKET_BITS) + 2
            if buckets > MAX_BUCKETS:  # ids too sparse for a table: the binary search
                self._buckets = np.zeros(0, np.int64)
            else:
                edges = np.arange(buckets, dtype=np.int64) << BUCKET_BITS
                self._buckets = self.ids.searchsorted(edges)
        last = self.ids.size - 1
        if not self._buckets.size:
            return np.minimum(self.ids.searchsorted(ids), last)
        bucket = np.clip(ids >> BUCKET_BITS, 0, self._buckets.size - 2)
        first = np.minimum(self._buckets[bucket], last)
        return np.clip(first + (ids - self.ids[first]), 0, last)

    def row(self, vector_id: int) -> int:
        """:meth:`rows` of one id (a search's query clip): the same guess and check, in
        Python ints read through memoryviews (numpy's calls on one number cost more than the
        lookup)."""
        ids, buckets = self._id_views()
        last = len(ids) - 1
        if last < 0:
            return -1
        if buckets is not None:
            bucket = min(max(vector_id >> BUCKET_BITS, 0), len(buckets) - 2)
            first = min(buckets[bucket], last)
            at = min(max(first + vector_id - ids[first], 0), last)
            if ids[at] != vector_id:
                at = min(bisect_left(ids, vector_id), last)
        else:
            at = min(bisect_left(ids, vector_id), last)
        if ids[at] != vector_id:
            return -1
        return at

    def _id_views(self) -> tuple[memoryview, memoryview | None]:
        """The locator's ids and the bucket table of :meth:`guessed_rows` (None: too sparse
        for one) as memoryviews of Python ints (made once: the file never changes)."""
        views = self._views
        if views is None:
            if self.ids.size:
                self.guessed_rows(self.ids[:1])  # builds the bucket table
            table = self._buckets
            views = self._views = (
                int64_view(self.ids),
                int64_view(table) if table is not None and table.size else None,
            )
        return views
