"""A scale for distances: how similar a search result is, in words an animator can read.

Distances differ by descriptor by two orders of magnitude (posture ~0.03, motion ~0.6,
kinetic ~2.6 between good matches), so ``distance`` alone says nothing. Each index gets the
library's *typical neighbour distances*: for a sample of its vectors (up to
:data:`SAMPLE`, drawn with a fixed seed), the distances to their :data:`NEIGHBOURS` nearest
others (windows: of other clips — a clip's own overlapping windows are not its neighbours).
A result's ``similarity`` is the share of those distances that are larger than its own, in
percent: 97 means the result is nearer than 97 % of the library's typical neighbours, 50 as
near as a typical neighbour, 0 farther than all of them.

The scale is computed when first asked for (that search waits: 0.2-1.5 s at 12,000 clips
and 350,000 windows on a loaded 2-core machine, bench/README.md) and again, in a background
thread while searches go on with the old one, once the index has grown or shrunk by
:data:`REFRESH_SHARE`: a sorted array per index, so a search pays one ``searchsorted`` over
its hits. A scale far from the index's size (half or twice it: an import by another process,
a library that was empty at start) is not served meanwhile: the search waits for a new one.

The scale of an index that holds exactly its mapped file's vectors is a function of that
file: it is kept beside it (``<stem>.scale.arrays``, stamped with the file and the settings
like the adaptive probe's decision, app/index/probe_cutoff.py), so every worker and restart
reads it instead of measuring again; a server's verifier thread reads or measures it at
start (:meth:`NeighbourScales.of`), before the first search asks.
"""

from __future__ import annotations

import contextlib
import threading
from bisect import bisect_right
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np

from app.index.array_file import beside_index, read_arrays, write_arrays
from app.index.descriptor_index import DescriptorIndex

SAMPLE = 1000  # vectors whose neighbours make the scale
NEIGHBOURS = 10  # nearest others of each
REFRESH_SHARE = 0.05  # recompute once the index size moved by this share
SEED = 24
IDENTICAL = 1e-6  # distances below this share of a typical vector's length are zero
FAR = 2.0  # a scale of an index this many times larger or smaller is not served
FORMAT = 1  # of the file kept beside an index


@dataclass(frozen=True)
class Scale:
    """Sorted typical neighbour distances ``(M,)`` of an index holding ``size`` vectors."""

    distances: np.ndarray
    size: int

    def similarities(self, distances: list[float]) -> list[float]:
        """Percent (one decimal, halves to even) of the typical distances larger than each of
        ``distances``; 100 for all when the scale is empty (a library of one). In Python
        floats: for a search's dozen hits numpy's calls cost more than the work."""
        typical = self._typical
        size = len(typical)
        if not size:
            return [100.0] * len(distances)
        return [
            round(100.0 * (size - bisect_right(typical, d)) / size * 10.0) / 10.0 for d in distances
        ]

    @cached_property
    def _typical(self) -> list[float]:
        return self.distances.tolist()

    @cached_property
    def median(self) -> float:
        """The median typical distance (0 when the scale is empty): a moments search asks
        for it at every search, and it never changes."""
        return float(np.median(self.distances)) if self.distances.size else 0.0


def _stale(scale: Scale | None, size: int) -> bool:
    return scale is None or abs(size - scale.size) > REFRESH_SHARE * scale.size


def _far(scale: Scale, size: int) -> bool:
    """Whether ``scale`` describes a library so unlike one of ``size`` vectors that its
    similarities would mislead (a library empty at start, then filled): measured again
    before it answers, not in the background."""
    if scale.size < 2:
        return size >= 2
    return not scale.size / FAR <= size <= scale.size * FAR


def measure(index: DescriptorIndex, group: Callable[[np.ndarray], np.ndarray] | None) -> Scale:
    """The scale of ``index`` now; ``group`` maps ids ``(N,)`` to what must differ between
    neighbours (windows: their clip), else only a vector itself is left out."""
    ids = index.sorted_ids()
    size = int(ids.size)
    if size < 2:
        return Scale(np.empty(0), size)
    rng = np.random.default_rng(SEED)
    chosen = ids if size <= SAMPLE else np.sort(rng.choice(ids, SAMPLE, replace=False))
    held, vectors = index.reconstruct_batch(chosen)
    chosen = chosen[held]
    # Windows overlap their clip's neighbours: ask for enough to skip a clip's own.
    extra = 1 if group is None else 24
    k = min(size, NEIGHBOURS + extra)
    squared, found = index.search_many(vectors, k)
    distances = np.sqrt(np.maximum(squared.astype(np.float64), 0.0))
    own = chosen[:, None] if group is None else group(chosen)[:, None]
    other = (found >= 0) & ((found if group is None else group(found)) != own)
    # An identical vector is the same motion stored twice (one file in two formats, a rig
    # that never moves), not a neighbour: many of them would make every other distance
    # look far.
    other &= distances > IDENTICAL * max(float(np.median(np.linalg.norm(vectors, axis=1))), 1e-12)
    # The NEIGHBOURS nearest others of each row (rows are sorted nearest first).
    rank = np.cumsum(other, axis=1)
    keep = other & (rank <= NEIGHBOURS)
    return Scale(np.sort(distances[keep]), size)


def kept_or_measured(
    index: DescriptorIndex, group: Callable[[np.ndarray], np.ndarray] | None
) -> Scale:
    """:func:`measure`, or the same scale read from beside the index's file when the index
    holds exactly that file's vectors (then the measurement is a function of the file), and
    kept there when measured on it."""
    place = index.unchanged_file()
    if place is None:
        return measure(index, group)
    directory, stem, stamp = _kept_at(place, index, group)
    found = read_arrays(directory, stem, stamp)
    if not isinstance(found, str):
        arrays, meta = found
        distances = arrays.get("distances")
        if distances is not None and distances.ndim == 1 and meta.get("size") == index.size:
            return Scale(np.array(distances, np.float64), index.size)
    scale = measure(index, group)
    if index.unchanged_file() == place:  # not replaced while measuring
        with contextlib.suppress(OSError):  # a read-only directory: measured at every start
            write_arrays(
                directory, stem, {"distances": scale.distances}, {**stamp, "size": scale.size}
            )
    return scale


def _kept_at(
    place: tuple[str, list[int]],
    index: DescriptorIndex,
    group: Callable[[np.ndarray], np.ndarray] | None,
) -> tuple[Any, str, dict[str, Any]]:
    """Where the scale of the index file ``place`` (path, identity) is kept and its stamp:
    the file and what the measurement depends on (windows are grouped by their clip; the
    cells an IVF search scans)."""
    settings = {
        "format": FORMAT,
        "sample": SAMPLE,
        "neighbours": NEIGHBOURS,
        "seed": SEED,
        "identical": IDENTICAL,
        "grouped": group is not None,
        "nprobe": index.nprobe,
    }
    return beside_index(place[0], "scale", place[1], settings)


@dataclass
class NeighbourScales:
    """The scale of each index, by name, computed when first needed and kept current."""

    _scales: dict[str, Scale] = field(default_factory=dict)
    _lock: threading.Lock = field(default_factory=threading.Lock)
    _refreshing: set[str] = field(default_factory=set)

    def of(
        self,
        name: str,
        index: DescriptorIndex,
        group: Callable[[np.ndarray], np.ndarray] | None = None,
    ) -> Scale:
        scale = self._scales.get(name)
        if scale is not None:
            size = index.size
            if not _stale(scale, size):
                return scale
            if not _far(scale, size):
                self._refresh(name, index, group)
                return scale
        with self._lock:  # the first measurement: the others wait for it
            scale = self._scales.get(name)
            if scale is None or _far(scale, index.size):
                scale = self._scales[name] = kept_or_measured(index, group)
            return scale

    def forget(self, name: str) -> None:
        """Drop the scale of ``name`` (its index was rebuilt: a damaged file's vectors may
        have made it): the next search measures or reads it again."""
        with self._lock:
            self._scales.pop(name, None)

    def _refresh(
        self,
        name: str,
        index: DescriptorIndex,
        group: Callable[[np.ndarray], np.ndarray] | None,
    ) -> None:
        """Measure ``name`` again in a thread of its own (one at a time per index)."""
        with self._lock:
            if name in self._refreshing:
                return
            self._refreshing.add(name)

        def run() -> None:
            try:
                self._scales[name] = kept_or_measured(index, group)
            finally:
                with self._lock:
                    self._refreshing.discard(name)

        threading.Thread(target=run, name=f"scale-{name}", daemon=True).start()
