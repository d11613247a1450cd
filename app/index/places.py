"""Where each stored window lies, in memory: the moments search's map from window id to frames.

A moments search turns FAISS hits (window ids) into spans of clips and then, for each moment it
places, reads the windows of one clip near the hit. Asked of the database, that is ~30 indexed
queries per search (~1 ms each on a 0.7 GB SQLite file at 100 hours of windows): most of a
search's time. A :class:`WindowPlaces` holds the same facts for one window index as three
arrays sorted by window id — about 16 bytes per window, 19 MB at 100 hours — and answers both
questions with a binary search.

Like the window index it sits beside, it is a cache of ``clip_windows`` rows: loaded from the
database, changed only with the index (the change feed names the clips whose windows changed;
their rows replace what was held) and rebuilt when the index is. Window ids are
``clip id << WINDOW_ID_BITS | ordinal`` and a clip's ordinals follow its windows' starts within
one length, so id order groups a clip's windows and orders them by start.

Readers never lock: a change builds new arrays and swaps them in one assignment. Changes
take a lock of their own (a delete drops its clip's windows while a sync may be adding
others: neither may lose the other's).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, slots=True)
class Places:
    """Windows ``ids`` ``(N,)`` int64 (sorted) lying at frames ``[starts, stops)`` ``(N,)``
    int64 of their clip's file."""

    ids: np.ndarray
    starts: np.ndarray
    stops: np.ndarray

    @classmethod
    def empty(cls) -> Places:
        nothing = np.zeros(0, np.int64)
        return cls(nothing, nothing, nothing)

    @classmethod
    def of(cls, ids: np.ndarray, starts: np.ndarray, stops: np.ndarray) -> Places:
        """Rows in any order, sorted by id."""
        ids = np.asarray(ids, np.int64)
        order = np.argsort(ids, kind="stable")
        return cls(
            ids[order], np.asarray(starts, np.int64)[order], np.asarray(stops, np.int64)[order]
        )

    def __len__(self) -> int:
        return int(self.ids.size)


def rows_of_clips(
    sorted_ids: np.ndarray, clip_ids: np.ndarray, id_bits: int
) -> tuple[np.ndarray, np.ndarray]:
    """Where the windows of some clips lie in ``sorted_ids`` ``(N,)`` (window ids ascending,
    ``clip id << id_bits | ordinal``): rows ``(M,)``, one clip after another, and ``(C + 1,)``
    offsets (clip ``c``'s rows are ``offsets[c]:offsets[c + 1]``). A binary search a clip."""
    clips = np.asarray(clip_ids, np.int64)
    first = np.searchsorted(sorted_ids, clips << id_bits)
    counts = np.searchsorted(sorted_ids, (clips + 1) << id_bits) - first
    offsets = np.zeros(clips.size + 1, np.int64)
    np.cumsum(counts, out=offsets[1:])
    return np.repeat(first - offsets[:-1], counts) + np.arange(offsets[-1]), offsets


class WindowPlaces:
    """The places of one window index's windows (see the module docstring).

    ``id_bits``: the low bits of a window id that number the windows of one clip.
    """

    def __init__(self, id_bits: int) -> None:
        self._id_bits = id_bits
        self._places = Places.empty()
        self._changing = threading.Lock()
        self.loaded = False
        self.changed = False  # since loaded: what the places file lacks

    def __len__(self) -> int:
        return len(self._places)

    @property
    def held(self) -> Places:
        """Every window held (to save them)."""
        return self._places

    def replace_all(self, places: Places) -> None:
        """Hold exactly ``places`` (as the database has them)."""
        with self._changing:
            self._places = places
            self.loaded = True
            self.changed = False

    def apply_changes(self, clip_ids: np.ndarray, places: Places) -> None:
        """The clips ``clip_ids`` ``(C,)`` changed: their windows are now ``places`` (those
        the database holds of them; none for a deleted clip)."""
        with self._changing:
            self._apply(np.unique(np.asarray(clip_ids, np.int64)), places)

    def _apply(self, clips: np.ndarray, places: Places) -> None:
        held = self._places
        if not clips.size and not len(places):
            return
        self.changed = True
        keep = ~np.isin(held.ids >> self._id_bits, clips)
        ids = np.concatenate([held.ids[keep], places.ids])
        starts = np.concatenate([held.starts[keep], places.starts])
        stops = np.concatenate([held.stops[keep], places.stops])
        if ids.size > 1 and not np.all(ids[1:] > ids[:-1]):
            order = np.argsort(ids, kind="stable")
            ids, starts, stops = ids[order], starts[order], stops[order]
        self._places = Places(ids, starts, stops)

    def remove_clips(self, clip_ids: np.ndarray) -> None:
        """Forget the windows of deleted clips."""
        self.apply_changes(clip_ids, Places.empty())

    def find(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For window ids ``ids`` ``(M,)``: whether each is held ``(M,)`` bool, and its start
        and stop frames ``(M,)`` int64 (0 where not held)."""
        held = self._places
        ids = np.asarray(ids, np.int64)
        if not len(held) or not ids.size:
            nothing = np.zeros(ids.size, np.int64)
            return np.zeros(ids.size, bool), nothing, nothing.copy()
        at = np.minimum(np.searchsorted(held.ids, ids), len(held) - 1)
        found = held.ids[at] == ids
        return found, np.where(found, held.starts[at], 0), np.where(found, held.stops[at], 0)

    def of_clips(self, clip_ids: np.ndarray) -> tuple[Places, np.ndarray]:
        """The windows of the clips ``clip_ids`` ``(C,)``, one clip after another, each in id
        (= start) order, and ``(C + 1,)`` offsets: clip ``c``'s windows are rows
        ``offsets[c]:offsets[c + 1]``."""
        held = self._places
        rows, offsets = rows_of_clips(held.ids, clip_ids, self._id_bits)
        return Places(held.ids[rows], held.starts[rows], held.stops[rows]), offsets

    def ids_of_clips(self, clip_ids: np.ndarray) -> np.ndarray:
        """``(N,)`` int64 ids of the windows held of the clips ``clip_ids``."""
        return self.of_clips(np.unique(np.asarray(clip_ids, np.int64)))[0].ids


__all__ = ["Places", "WindowPlaces", "rows_of_clips"]
