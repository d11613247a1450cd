"""Moments search: where in the stored clips a span of motion happens.

The query is a span ``[start, end)`` (seconds from the first frame of the file, lead-in
included) of a stored clip or of an uploaded file. It is described as its own *parts*: its
windows of one stored window length ``L`` (:func:`part_length`: the longest length whose
stored windows always fit one whole inside a span of the query's length), one starting at
every frame of the query (a few frames apart past :data:`MAX_PARTS`). A stored clip has its
windows of length ``L`` every quarter (1 s) or half (longer) of ``L``.

**The moments of a clip.** Every stored window ``w`` of length ``L`` of a clip places one
moment: the span of the query's length that puts ``w`` where the query part nearest to it
lies (``w``'s start minus that part's offset; moved to lie inside the clip, and the whole
clip when it is shorter than the query). Its ``distance`` is how well the whole span fits:
the mean, over the clip's windows lying inside it, of each window's distance to the query's
part at the same offset. An exact copy of a query of 1.25 s or more is therefore placed to
a frame (a stored window lies whole inside it and equals the part at its offset) and found
at distance 0.

**The list.** Moments nearest first (by distance, then clip id, then start), at most
``per_clip`` of one clip and none overlapping a nearer one of its clip; a query from a
stored clip never returns a moment overlapping its own span. This list depends on the query
and the library only: a larger ``k`` extends it, a larger ``per_clip`` keeps every moment a
smaller one chose, in the same order, and a ``label`` or ``licence`` filter returns it
restricted to the clips the filter keeps.

**Finding it without scanning every window.** A moment's distance is a mean over its
windows, each at least as far as that window is from its nearest query part, so a moment
nearer than ``d`` holds a window within ``d`` of some part. A few parts (:data:`PROBES`,
spread over the query) search the window index for their nearest windows; every part lies
within ``cover`` of one of them, so a window none of their searches reached within ``t`` is
at least ``t - cover`` from every part. Every moment nearer than ``t - cover`` thus holds a
window among the hits, and is placed by a window at most a query's length from it: the
moments of all windows that near the hits are placed and ranked, and the search widens (four
times as many hits) until the ``k``-th moment of the list is nearer than ``t - cover`` or the
index has no more windows. The answer is then exact on flat indexes (libraries of fewer than
``MOCAP_INDEX_AUTO_THRESHOLD`` windows of a length); on IVF indexes the probes' searches are
approximate (a filtered one scans every cell).

A query too short for any stored window to lie inside it (a clip shorter than 1 s) has no
parts: its whole-span vector searches the shortest windows, a moment is centred on its
window and its distance is that window's.

Where each window lies comes from the library's in-memory window places
(:mod:`app.index.places`), not the database: a search reads only the query clip and the
found clips' names and frame rates. Windows of clips deleted by another process are skipped
(no place, or no clip row), as clip searches do.
"""

from __future__ import annotations

import dataclasses
import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from app.db import clips as clip_db
from app.db import label_filters as label_db
from app.db import windows as window_db
from app.db.entries import ClipEntry
from app.errors import InvalidInput, MomentsOff, NotFound
from app.index.places import Places
from app.licences import LicenceArg, licence_filter
from app.motion.windows import hop_share
from app.services.captures import group_nearest_first
from app.services.clips import MAX_ID, stored_upload
from app.services.describe import (
    WINDOW_LENGTHS,
    MotionDescriber,
    SpanDescription,
    span_frames,
)
from app.services.library import Library, window_index_name
from app.services.search import allowed_clip_ids, capture_rule, check_k, clip_vector
from app.services.uploads import SCENE_FORMATS, Upload

MAX_PER_CLIP = 1000
MAX_PARTS = 2048  # query parts at most: one per frame up to this many
PROBE_AHEAD = 2  # a probe search asks for this many times the windows a round needs
MAX_PROBES = 16  # query parts that search the window index, at most
PROBE_COVER = 0.15  # ... until every part is this near one (share of a typical distance)
FIRST_FETCH = 256  # windows each probe asks for first (twice as many per widening)
SPAN_CACHE = 32  # described stored spans kept (a page asking again, a span dragged back)
DIRECT_PARTS = 8  # a query of this many parts at most: each window's nearest part exactly
# The expanded form's rounding error on a squared distance stays below this share of the two
# squares summed (~D * 1e-16 for D of a few hundred): pairs further apart are told apart.
SQUARES_SLACK = 1e-9
BLOCK_BYTES = 64 * 2**20  # memory one block of a search's comparisons may take (issue 21)


@dataclass(frozen=True, slots=True)
class Moment:
    """A found span ``[start, end)`` in seconds of the clip's file."""

    clip: ClipEntry
    format: str
    start: float
    end: float
    distance: float
    similarity: float = 100.0  # see app.index.neighbour_scale
    others: tuple[Moment, ...] = ()  # collapse: the same moment in near-identical clips


@dataclass(frozen=True, slots=True)
class MomentQuery:
    """The query's span in seconds of its file, its clip when it is a stored one, and (an
    upload) the stored clip with the same content, if any."""

    clip: ClipEntry | None
    start: float
    end: float
    stored_clip: clip_db.ClipRecord | None = None


@dataclass(frozen=True)
class Parts:
    """The query's own windows of one ``length`` (seconds; 0: none, ``vectors`` is then the
    whole span's vector): ``offsets`` ``(J,)`` seconds from the query's start, ascending,
    ``vectors`` ``(J, D)`` float32."""

    length: float
    offsets: np.ndarray
    vectors: np.ndarray


def part_length(seconds: float) -> float:
    """The window length a query of ``seconds`` is split into to place its moments: the
    longest whose stored windows (one every half or quarter length, :func:`hop_share`)
    always fit one whole into a span of the query's length, else the shortest."""
    fitting = [
        length
        for length in WINDOW_LENGTHS
        if (1 + 1 / hop_share(length, WINDOW_LENGTHS)) * length <= seconds + 1e-9
    ]
    return fitting[-1] if fitting else min(WINDOW_LENGTHS)


def nearest_lengths(seconds: float, lengths: tuple[float, ...] = WINDOW_LENGTHS) -> list[float]:
    """The window lengths nearest ``seconds``: the longest at most as long and the shortest
    at least as long (one when the query is shorter or longer than every window, or as long
    as one)."""
    ordered = sorted(lengths)
    below = [length for length in ordered if length <= seconds + 1e-9]
    above = [length for length in ordered if length >= seconds - 1e-9]
    chosen = {below[-1] if below else ordered[0], above[0] if above else ordered[-1]}
    return sorted(chosen)


def window_descriptors(library: Library) -> list[str]:
    return sorted({key.name for key in library.window_keys.values()})


def _check(library: Library, descriptor: str, k: int, per_clip: int) -> None:
    if not library.window_keys:
        raise MomentsOff(
            "moments search is off in this library (MOCAP_MOMENTS=false): no windows are "
            "kept. Set MOCAP_MOMENTS=true, restart, and run `mocap-index reindex` to describe "
            "the clips stored without windows"
        )
    library.descriptor(descriptor)
    if descriptor not in window_descriptors(library):
        known = ", ".join(window_descriptors(library)) or "none"
        raise InvalidInput(
            f"descriptor: moments are searched under the descriptors with windows ({known}), "
            f"not {descriptor!r}"
        )
    check_k(library, k)
    if not 1 <= per_clip <= MAX_PER_CLIP:
        raise InvalidInput(f"per_clip: must be between 1 and {MAX_PER_CLIP}, got {per_clip}")


# -------------------------------------------------------------------- the moments' list


def _pair_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise distances ``(N,)`` of ``a`` and ``b`` ``(N, D)``, from the differences: the
    same number for the same pair whatever else a search computed (the expanded form
    through a matrix product loses the last digits near zero, and depends on the batch)."""
    return _pair_distances_of(a - b)


def _pair_distances_of(difference: np.ndarray) -> np.ndarray:
    """Row lengths ``(N,)`` of differences ``(N, D)`` (see :func:`_pair_distances`)."""
    return np.sqrt(np.einsum("ij,ij->i", difference, difference))


@dataclass(frozen=True)
class _Candidates:
    """Placed moments: clip ids, starts and ends (seconds), distances ``(N,)``."""

    clips: np.ndarray
    starts: np.ndarray
    ends: np.ndarray
    distances: np.ndarray

    @classmethod
    def empty(cls) -> _Candidates:
        nothing = np.zeros(0)
        return cls(np.zeros(0, np.int64), nothing, nothing, nothing)


class _Known:
    """Numbers measured per window id, kept across a search's rounds: ``(N, C)`` float64
    rows, looked up by binary search."""

    def __init__(self, columns: int) -> None:
        self.ids = np.zeros(0, np.int64)
        self.values = np.zeros((0, columns))

    def find(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Which of ``ids`` ``(M,)`` are known ``(M,)`` bool, and their rows ``(M, C)``
        (nan where unknown)."""
        at = np.minimum(np.searchsorted(self.ids, ids), max(self.ids.size - 1, 0))
        known = self.ids[at] == ids if self.ids.size else np.zeros(ids.size, bool)
        rows = np.full((ids.size, self.values.shape[1]), np.nan)
        rows[known] = self.values[at[known]]
        return known, rows

    def add(self, ids: np.ndarray, values: np.ndarray) -> None:
        ids = np.concatenate([self.ids, ids])
        values = np.concatenate([self.values, values])
        order = np.argsort(ids, kind="stable")
        self.ids, self.values = ids[order], values[order]


def _members(values: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """Which of ``values`` ``(N,)`` are among ``keys`` ``(M,)`` (sorted, unique): ``(N,)``
    bool (``np.isin`` without its sort)."""
    if not keys.size:
        return np.zeros(values.size, bool)
    at = np.minimum(np.searchsorted(keys, values), keys.size - 1)
    return keys[at] == values


def _to_nearest(keys: np.ndarray, marks: np.ndarray) -> np.ndarray:
    """For each of ``keys`` ``(N,)``, how far the nearest of ``marks`` ``(M,)`` (M >= 1) is."""
    marks = np.sort(marks)
    at = np.clip(np.searchsorted(marks, keys), 1, max(marks.size - 1, 1))
    below, above = marks[np.maximum(at - 1, 0)], marks[np.minimum(at, marks.size - 1)]
    return np.minimum(np.abs(keys - below), np.abs(keys - above))


def _probes(query: np.ndarray, target: float, most: int) -> tuple[np.ndarray, float]:
    """The parts that search the index — from the middle one, each next the part farthest
    from those chosen, until every part lies within ``target`` of one or ``most`` are
    chosen — and how far the farthest part lies from them: ``(P,)`` rows of ``query``
    ``(J, D)`` and that distance."""
    count = len(query)
    chosen = [count // 2]
    nearest = np.linalg.norm(query - query[chosen[0]], axis=1)
    while len(chosen) < min(most, count) and float(nearest.max()) > target:
        far = int(nearest.argmax())
        chosen.append(far)
        nearest = np.minimum(nearest, np.linalg.norm(query - query[far], axis=1))
    return np.array(sorted(chosen), np.int64), float(nearest.max())


class _Finder:
    """One moments search (see the module docstring): the query's parts against one window
    index, the moments placed around the probes' hits. What it measured of a window (its
    nearest part) and of a seed (its moment) is kept for the next, wider round."""

    def __init__(
        self,
        library: Library,
        descriptor: str,
        parts: Parts,
        seconds: float,
        exclude: tuple[int, int, int] | None,
    ) -> None:
        self.library, self.seconds, self.exclude = library, seconds, exclude
        self.whole = parts.length == 0  # no parts: the span's vector against short windows
        self.length = min(WINDOW_LENGTHS) if self.whole else parts.length
        self.name = window_index_name(descriptor, self.length)
        self.index = library.window_indexes[self.name]
        self.places = library.places(self.name)
        self.parts = parts
        self.query = parts.vectors.astype(np.float64)
        self.scale = library.scales.of(
            self.name, self.index, lambda ids: ids >> window_db.WINDOW_ID_BITS
        )
        typical = float(np.median(self.scale.distances)) if self.scale.distances.size else 0.0
        self.probes, cover = _probes(self.query, PROBE_COVER * typical, MAX_PROBES)
        # Every part lies within this of a probe (a hair more: float noise).
        self.cover = cover * (1 + 1e-6) + 1e-9
        self.facts = _Known(2)  # clip id -> frame time, frame count
        self._probed: tuple[np.ndarray, np.ndarray] | None = None  # distances, ids
        self._nearest = _Known(2)  # window id -> its nearest part, distance
        self._placed = _Known(4)  # seed window id -> clip id, start, end, distance
        self._hits = np.zeros(0, np.int64)  # the hits placed so far (see found)
        self._found = _Candidates.empty()  # ... and their clips' moments

    def probe(self, wanted: int, allowed: np.ndarray | None) -> tuple[np.ndarray, float]:
        """The window ids the probes found (each its ``wanted`` nearest) and how far their
        searches surely reach: every window nearer a probe than that is among them (inf:
        the probes saw every window). One FAISS search serves several widenings: it asks
        for :data:`PROBE_AHEAD` times as many (a flat index's cost hardly depends on it)."""
        if self._probed is None or self._probed[1].shape[1] < wanted:
            self._probed = self.index.search_batch(
                self.query[self.probes].astype(np.float32),
                min(wanted * PROBE_AHEAD, max(self.index.size, wanted)),
                allowed=allowed,
            )
        distances, ids = self._probed[0][:, :wanted], self._probed[1][:, :wanted]
        full = ids[:, -1] >= 0
        reach = float(distances[full, -1].min()) if full.any() else np.inf
        return np.unique(ids[ids >= 0]), reach

    def found(self, hits: np.ndarray) -> _Candidates:
        """:meth:`moments` of ``hits`` (sorted, unique; a superset of the last call's), with
        only the clips holding new hits placed again: a clip's moments depend on its own
        hits alone (a wider round adds hits to a few of the clips it had)."""
        bits = window_db.WINDOW_ID_BITS
        new = hits[~_members(hits, self._hits)]
        changed = np.unique(new >> bits)
        kept = self._found
        keep = ~_members(kept.clips, changed)
        placed = self.moments(hits[_members(hits >> bits, changed)])
        self._hits = hits
        self._found = _Candidates(
            np.concatenate([kept.clips[keep], placed.clips]),
            np.concatenate([kept.starts[keep], placed.starts]),
            np.concatenate([kept.ends[keep], placed.ends]),
            np.concatenate([kept.distances[keep], placed.distances]),
        )
        return self._found

    def moments(self, hits: np.ndarray) -> _Candidates:
        """The moments placed by the seeds near the hits (within a query's length of one, in
        its clip), with their distances."""
        bits = window_db.WINDOW_ID_BITS
        clips = np.unique(hits >> bits)
        held, facts = self.facts.find(clips)
        if not held.all():  # no SQL: the catalogue (clips deleted meanwhile are not there)
            listed = self.library.catalogue.frames(clips[~held].tolist())
            if listed:
                self.facts.add(
                    np.fromiter(listed, np.int64, len(listed)), np.array(list(listed.values()))
                )
            held, facts = self.facts.find(clips)
            clips, facts = clips[held], facts[held]
        if not clips.size:
            return _Candidates.empty()
        rows, offsets = self.places.of_clips(clips)
        group = np.repeat(np.arange(clips.size), np.diff(offsets))
        frame_time = facts[:, 0][group]
        frames = facts[:, 1][group]
        starts, stops = rows.starts * frame_time, rows.stops * frame_time
        # Seconds from each window to the nearest hit of its clip (clips kept far apart).
        apart = 4.0 * (float(np.max(frames * frame_time)) + self.seconds + 1.0)
        keys = group * apart + starts
        marked = _members(rows.ids, hits)
        if not marked.any():  # their clips deleted meanwhile
            return _Candidates.empty()
        to_hit = _to_nearest(keys, keys[marked])
        slack = float(frame_time.max())
        seed_reach = max(self.seconds - self.length, 0.0) + slack
        if self.whole:  # the hits themselves, centred on their window
            seeds = np.flatnonzero(marked)
        else:
            seeds = self._local_minima(
                rows, group, to_hit <= seed_reach + self.length + slack, to_hit <= seed_reach
            )
        if self.exclude is not None:  # nothing overlapping the query's own span
            clip, first, stop = self.exclude
            mine = (rows.ids[seeds] >> bits == clip) & (rows.starts[seeds] < stop)
            seeds = seeds[~(mine & (rows.stops[seeds] > first))]
        fresh = seeds[~self._placed.find(rows.ids[seeds])[0]]
        if fresh.size:
            # Windows a moment placed by a fresh seed may hold (in its clip, a query's
            # length around it), with their vectors.
            near = _to_nearest(keys, keys[fresh]) <= self.seconds + slack
            held, vectors = self.index.reconstruct_batch(rows.ids[near])
            window = np.flatnonzero(near)[held]
            position = np.full(len(rows), -1)
            position[window] = np.arange(window.size)
            fresh = fresh[position[fresh] >= 0]
            stored = vectors.astype(np.float64)
            durations = frames[fresh] * frame_time[fresh]
            spans = np.minimum(self.seconds, durations)
            if self.whole:
                _, distance = self._nearest_parts(stored[position[fresh]])
                placed = (starts[fresh] + stops[fresh]) / 2 - spans / 2
            else:
                part = self._nearest.find(rows.ids[fresh])[1][:, 0].astype(np.int64)
                placed = starts[fresh] - self.parts.offsets[part]
            placed = np.clip(placed, 0.0, durations - spans)
            if not self.whole:
                distance = self._fits_in_blocks(
                    placed,
                    spans,
                    group[window],
                    starts[window],
                    stops[window],
                    frame_time[window],
                    position[fresh],
                    stored,
                )
            moments = np.stack([clips[group[fresh]], placed, placed + spans, distance], axis=1)
            self._placed.add(rows.ids[fresh], moments)
        known, found = self._placed.find(rows.ids[seeds])
        found = found[known]
        return _Candidates(found[:, 0].astype(np.int64), found[:, 1], found[:, 2], found[:, 3])

    def _local_minima(
        self, rows: Places, group: np.ndarray, region: np.ndarray, seedable: np.ndarray
    ) -> np.ndarray:
        """The seeds (rows of ``rows``): windows ``seedable`` nearer their nearest part than
        the window before them in their clip (or as near) and than the one after — a
        moment's best place, not its slopes. ``region`` (the seedable windows and their
        neighbours) get their nearest part measured. Whether a window is a seed depends on
        it, its neighbours and the query only, never on which windows the probes found."""
        wanted = np.flatnonzero(region)
        unknown = wanted[~self._nearest.find(rows.ids[wanted])[0]]
        held, vectors = self.index.reconstruct_batch(rows.ids[unknown])
        unknown = unknown[held]
        if unknown.size:
            part, distance = self._nearest_parts_in_blocks(vectors)
            self._nearest.add(rows.ids[unknown], np.stack([part, distance], axis=1))
        delta = self._nearest.find(rows.ids)[1][:, 1]
        candidates = np.flatnonzero(seedable & ~np.isnan(delta))
        last = len(rows) - 1
        left, right = np.maximum(candidates - 1, 0), np.minimum(candidates + 1, last)
        has_left = (candidates > 0) & (group[left] == group[candidates])
        has_right = (candidates < last) & (group[right] == group[candidates])
        here = delta[candidates]
        lowest = (~has_left | (here <= delta[left])) & (~has_right | (here < delta[right]))
        return candidates[lowest]

    # Bounded work (issue 21): a long query has up to MAX_PARTS parts and the clips near
    # the hits thousands of windows, so (parts x windows) matrices are built a block at a
    # time, within BLOCK_BYTES. A window's nearest part and a moment's fit depend on that
    # window or moment alone: the blocks give the same numbers as one pass.

    def _nearest_parts_in_blocks(self, windows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_nearest_parts` of ``windows`` ``(M, D)`` (float32), a block of windows at
        a time: a float64 (parts x block) matrix, its mask, and the block in float64."""
        per_window = len(self.query) * NEAREST_BYTES_PER_PAIR + 8 * windows.shape[1]
        if len(self.query) <= DIRECT_PARTS:  # ... and every pair's difference
            per_window += len(self.query) * 8 * windows.shape[1]
        found = [
            self._nearest_parts(windows[block].astype(np.float64))
            for block in _blocks(np.full(len(windows), per_window), BLOCK_BYTES)
        ]
        if not found:
            return np.zeros(0, np.int64), np.zeros(0)
        return np.concatenate([f[0] for f in found]), np.concatenate([f[1] for f in found])

    def _fits_in_blocks(
        self,
        placed: np.ndarray,
        spans: np.ndarray,
        group: np.ndarray,
        starts: np.ndarray,
        stops: np.ndarray,
        frame_time: np.ndarray,
        seeds: np.ndarray,
        stored: np.ndarray,
    ) -> np.ndarray:
        """:meth:`_fits`, a block of moments at a time: a moment compares at most the
        windows of its clip, each pair gathering a part and a window (float64) and their
        difference."""
        clip_windows = np.bincount(group)[group[seeds]]
        per_pair = FIT_BYTES_PER_PAIR + 3 * 8 * stored.shape[1]
        fits = [
            self._fits(
                placed[block],
                spans[block],
                group,
                starts,
                stops,
                frame_time,
                seeds[block],
                stored,
            )
            for block in _blocks(clip_windows * per_pair, BLOCK_BYTES)
        ]
        return np.concatenate(fits) if fits else np.zeros(0)

    def _nearest_parts(self, windows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For each of ``windows`` ``(M, D)``: the first query part nearest to it, and its
        distance (exact: the parts near the expanded form's minimum are measured again from
        their differences)."""
        q = self.query
        if len(q) <= DIRECT_PARTS:
            return self._nearest_of_few_parts(windows)
        squared = q @ windows.T  # (J, M), turned in place into squared distances
        squared *= -2.0
        squared += (q**2).sum(axis=1)[:, None]
        squared += (windows**2).sum(axis=1)[None, :]
        lowest = np.sqrt(np.maximum(squared.min(axis=0), 0.0))
        rows, columns = np.nonzero(squared <= ((lowest + 1e-6) ** 2)[None, :])
        del squared
        # Ties (a query that repeats itself) can be most pairs: measured a chunk at a time.
        chunk = max(1, BLOCK_BYTES // (3 * 8 * q.shape[1]))
        exact = np.concatenate(
            [
                _pair_distances(q[rows[i : i + chunk]], windows[columns[i : i + chunk]])
                for i in range(0, len(rows), chunk)
            ]
            or [np.zeros(0)]
        )
        order = np.lexsort((rows, exact, columns))  # per column: nearest, then first part
        first = order[np.r_[True, columns[order][1:] != columns[order][:-1]]]
        return rows[first], exact[first]

    def _nearest_of_few_parts(self, windows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_nearest_parts` of ``windows`` ``(M, D)`` for a query of few parts, with
        the very numbers of measuring every (part, window) pair from its difference (the
        first nearest part on ties) at about one pair's cost a window: the expanded form (a
        matrix product) names each window's nearest part when no other part lies within its
        rounding error, far below ``SQUARES_SLACK`` of the squares summed; only that pair is
        then measured from its difference. Windows with such near ties (a query repeating
        itself) measure every pair so."""
        q = self.query
        count = len(windows)
        query_squares = np.einsum("ij,ij->i", q, q)
        window_squares = np.einsum("ij,ij->i", windows, windows)
        # (J, M), turned in place into squared distances: a BLAS product, one thread since
        # app/__init__.py sets it (with numpy's two threads an einsum had been quicker; with
        # one the product is 1.6-3.5x quicker than the einsum for 6 parts x 2,000-8,000
        # windows of 135-300 numbers).
        squared = q @ windows.T
        squared *= -2.0
        squared += query_squares[:, None]
        squared += window_squares[None, :]
        nearest = squared.argmin(axis=0)
        lowest = squared[nearest, np.arange(count)]
        slack = SQUARES_SLACK * (float(query_squares.max()) + window_squares)
        tied = np.flatnonzero(np.count_nonzero(squared <= lowest + 2 * slack, axis=0) > 1)
        if tied.size:
            difference = (q[:, None, :] - windows[None, tied, :]).reshape(-1, q.shape[1])
            every = _pair_distances_of(difference).reshape(len(q), tied.size)
            nearest[tied] = every.argmin(axis=0)  # the first part on ties
        return nearest, _pair_distances_of(q[nearest] - windows)

    def _fits(
        self,
        placed: np.ndarray,
        spans: np.ndarray,
        group: np.ndarray,
        starts: np.ndarray,
        stops: np.ndarray,
        frame_time: np.ndarray,
        seeds: np.ndarray,
        stored: np.ndarray,
    ) -> np.ndarray:
        """The distance of each moment ``[placed, placed + spans)`` ``(S,)`` placed by the
        windows ``seeds`` (rows of ``group``, ``starts``, ... and ``stored`` ``(M, D)``: the
        windows near them): the mean distance of its clip's windows lying inside it to the
        parts at their offsets."""
        tolerance = frame_time[seeds] / 2
        # A clip's windows are contiguous and in start order (and stop order: one length).
        apart = 4.0 * (float(stops.max()) + self.seconds + 1.0)
        start_keys, stop_keys = group * apart + starts, group * apart + stops
        base = group[seeds] * apart + placed
        low = np.searchsorted(start_keys, base - tolerance)
        high = np.searchsorted(stop_keys, base + spans + tolerance, side="right")
        counts = np.maximum(high - low, 0)
        owner = np.repeat(np.arange(seeds.size), counts)
        within = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        columns = np.repeat(low, counts) + within
        # Each window against the part nearest its offset in the moment.
        offsets = starts[columns] - placed[owner]
        known = self.parts.offsets
        part = np.clip(np.searchsorted(known, offsets), 0, len(known) - 1)
        below = np.maximum(part - 1, 0)
        closer = np.abs(known[below] - offsets) <= np.abs(known[part] - offsets)
        part = np.where(closer, below, part)
        # Moments placed near each other share most pairs: each measured once.
        pairs, which = np.unique(part * len(stored) + columns, return_inverse=True)
        unique = _pair_distances(self.query[pairs // len(stored)], stored[pairs % len(stored)])
        sums = np.bincount(owner, weights=unique[which], minlength=seeds.size)
        return sums / np.maximum(counts, 1)


# Bytes per (part, window) pair besides the vectors: for the nearest part, 9 for the matrix
# and its mask and, when every pair ties (a query repeating itself), about 40 for the tied
# pairs' indexes, distances and order; about 100 for a fit's index arrays. With room.
NEAREST_BYTES_PER_PAIR = 64
FIT_BYTES_PER_PAIR = 128


def _blocks(weights: np.ndarray, budget: int) -> list[slice]:
    """Consecutive slices of items ``weights`` ``(N,)`` (bytes each) weighing at most
    ``budget`` together, or one item alone when it weighs more."""
    total = np.cumsum(weights)
    blocks: list[slice] = []
    start = 0
    while start < len(weights):
        before = int(total[start - 1]) if start else 0
        stop = max(int(np.searchsorted(total, before + budget, side="right")), start + 1)
        blocks.append(slice(start, stop))
        start = stop
    return blocks


def _chosen(
    found: _Candidates,
    per_clip: int,
    exclude: tuple[int, int, int] | None,
    frame_of: dict[int, float],
    most: int,
) -> list[int]:
    """The first ``most`` rows of ``found`` in the list's order: nearest first (then clip
    id, then start), at most ``per_clip`` of a clip, none overlapping a nearer one of its
    clip or the query's own span. Whether a row is chosen depends on the nearer rows only,
    so the walk stops at ``most`` (a round places thousands of moments for ten)."""
    order = np.lexsort((found.starts, found.clips, found.distances))
    chosen: list[int] = []
    of_clip: dict[int, list[tuple[float, float]]] = {}
    last: tuple[int, float] | None = None
    for row in order.tolist():
        clip, start, end = int(found.clips[row]), float(found.starts[row]), float(found.ends[row])
        if last == (clip, start):
            continue  # the same moment, placed by another window
        last = (clip, start)
        if exclude is not None and clip == exclude[0]:
            frame = frame_of[clip]
            if start < exclude[2] * frame - 1e-9 and exclude[1] * frame < end - 1e-9:
                continue
        spans = of_clip.setdefault(clip, [])
        if len(spans) < per_clip and all(end <= a + 1e-9 or b <= start + 1e-9 for a, b in spans):
            spans.append((start, end))
            chosen.append(row)
            if len(chosen) == most:
                break
    return chosen


def _search(
    library: Library,
    descriptor: str,
    parts: Parts,
    seconds: float,
    k: int,
    per_clip: int,
    allowed_clips: np.ndarray | None,
    exclude: tuple[int, int, int] | None,
    collapse: bool = False,
) -> list[Moment]:
    """The first ``k`` moments of the list (see the module docstring); ``exclude``: (clip
    id, first, stop) frames of the query's own span."""
    finder = _Finder(library, descriptor, parts, seconds, exclude)
    allowed = None if allowed_clips is None else finder.places.ids_of_clips(allowed_clips)
    need = 3 * k + 10 if collapse else k
    wanted = min(FIRST_FETCH + need, max(finder.index.size, 1))
    if exclude is not None:  # the query's own windows come first: do not count them
        own, _ = finder.places.of_clips(np.array([exclude[0]]))
        wanted += int(np.count_nonzero((own.starts < exclude[2]) & (own.stops > exclude[1])))
    while True:
        hits, reach = finder.probe(wanted, allowed)
        found = finder.found(hits)
        frame_of = {}
        if exclude is not None:
            held, facts = finder.facts.find(np.array([exclude[0]], np.int64))
            frame_of = {exclude[0]: float(facts[0, 0])} if held[0] else {}
        chosen = _chosen(found, per_clip, exclude, frame_of, need)
        sure = reach * (1 - 1e-5) - finder.cover  # FAISS measures in float32
        if np.isinf(reach) or (len(chosen) >= need and found.distances[chosen[need - 1]] < sure):
            break
        wanted = min(wanted * 2, finder.index.size + wanted)
    chosen = chosen[:need]
    names = library.catalogue.get_many(int(found.clips[r]) for r in chosen)
    similarity = finder.scale.similarities(found.distances[chosen].tolist())
    moments = [
        Moment(
            names[int(found.clips[r])],
            names[int(found.clips[r])].format,
            _round(float(found.starts[r])),
            _round(float(found.ends[r])),
            float(found.distances[r]),
            s,
        )
        for r, s in zip(chosen, similarity, strict=True)
        if int(found.clips[r]) in names
    ]
    if collapse:
        moments = _collapsed(library, moments)
    return moments[:k]


def _collapsed(library: Library, moments: list[Moment]) -> list[Moment]:
    """One moment per group of the same moment in near-identical clips (spans overlapping
    by half their length or more): the nearest, the others in its ``others``."""
    ids = np.array([m.clip.id for m in moments], np.int64)
    unique, position = np.unique(ids, return_inverse=True)
    clip_near = capture_rule(library).pairs(unique)
    near = clip_near[np.ix_(position, position)]

    def same_place(a: int, b: int) -> bool:
        first, second = moments[a], moments[b]
        overlap = min(first.end, second.end) - max(first.start, second.start)
        shorter = min(first.end - first.start, second.end - second.start)
        return first.clip.id != second.clip.id and overlap >= shorter / 2

    groups = group_nearest_first(ids.tolist(), near, fits=same_place)
    return [
        dataclasses.replace(moments[g[0]], others=tuple(moments[p] for p in g[1:])) for g in groups
    ]


def _round(seconds: float) -> float:
    return round(seconds, 6)


# --------------------------------------------------------------------------- the queries


def search_moments_by_clip(
    library: Library,
    clip_id: int,
    descriptor: str,
    *,
    start: float | None,
    end: float | None,
    k: int,
    per_clip: int,
    label: label_db.LabelFilter,
    licence: LicenceArg = None,
    collapse: bool = False,
) -> tuple[MomentQuery, list[Moment]]:
    """Moments like the span ``[start, end)`` of stored clip ``clip_id`` (``GET
    /search/moments``); none overlapping that span itself."""
    _check(library, descriptor, k, per_clip)
    if not 0 < clip_id <= MAX_ID:  # no such id (and the database driver's overflow)
        raise NotFound(f"no clip with id {clip_id}")
    info = library.descriptor(descriptor)
    library.refresh()
    clip = library.clip_entry(clip_id)
    if clip is None:
        raise NotFound(f"no clip with id {clip_id}")
    first, stop = span_frames(
        clip.frame_count, clip.frame_time, clip.lead_in_frames, start, end, WINDOW_LENGTHS[0]
    )
    seconds = (stop - first) * clip.frame_time
    stored = _StoredSpan(clip, descriptor, info.version, first, stop)
    parts = _span_parts(library, stored)
    allowed = allowed_clip_ids(library, label, licence_filter(licence))
    moments = _search(
        library,
        descriptor,
        parts,
        seconds,
        k,
        per_clip,
        allowed,
        (clip.id, first, stop),
        collapse,
    )
    query = MomentQuery(
        clip,
        _round(start if start is not None else 0.0),
        _round(end if end is not None else clip.duration),
    )
    return query, moments


@dataclass(frozen=True)
class _StoredSpan:
    """Frames ``[first, stop)`` of a stored clip, queried under ``descriptor`` of ``version``."""

    clip: ClipEntry
    descriptor: str
    version: int
    first: int
    stop: int


class _SpanCache:
    """The parts of the stored spans described last (by clip, content, descriptor version
    and frames): describing reads the clip's file."""

    def __init__(self, size: int) -> None:
        self._size = size
        self._held: OrderedDict[tuple[object, ...], Parts] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key: tuple[object, ...]) -> Parts | None:
        with self._lock:
            parts = self._held.get(key)
            if parts is not None:
                self._held.move_to_end(key)
            return parts

    def put(self, key: tuple[object, ...], parts: Parts) -> None:
        with self._lock:
            self._held[key] = parts
            while len(self._held) > self._size:
                self._held.popitem(last=False)


_SPANS = _SpanCache(SPAN_CACHE)


def _span_parts(library: Library, span: _StoredSpan) -> Parts:
    """The query's parts: described from the clip's stored file at every frame (as an
    upload's are), else — a clip without a file — its stored windows inside the span."""
    clip = span.clip
    if clip.filenames and isinstance(library.describer, MotionDescriber):
        key: tuple[object, ...] = (id(library), clip.id, clip.content_hash, span.descriptor)
        key = (*key, span.version, span.first, span.stop)
        parts = _SPANS.get(key)
        if parts is None:
            parts = _parts_of(
                _described_span(library, clip, span.descriptor, span.first, span.stop)
            )
            _SPANS.put(key, parts)
        return parts
    parts = _stored_parts(library, span)
    if parts is not None:
        return parts
    vector = _stored_span_vector(library, span)
    if vector is None:
        raise InvalidInput(
            f"clip {clip.id} has no stored file to describe a part of ({clip.format} clip); "
            "search from the whole clip or one of its windows"
        )
    return Parts(0.0, np.zeros(1), vector[None, :])


def _parts_of(span: SpanDescription) -> Parts:
    """A described span's parts (its own vector alone when it has none)."""
    if span.parts.size == 0:
        return Parts(0.0, np.zeros(1), span.vector[None, :])
    offsets = span.part_offsets.astype(np.float64) * span.frame_time
    return Parts(span.part_length, offsets, span.parts)


def _stored_span_vector(library: Library, span: _StoredSpan) -> np.ndarray | None:
    """The query vector without reading the file, when the span is the whole clip (the clip's
    vector) or exactly a stored window; else ``None``."""
    clip, descriptor, first, stop = span.clip, span.descriptor, span.first, span.stop
    if first == clip.lead_in_frames and stop == clip.frame_count:
        return clip_vector(library, clip.id, descriptor)
    for name, key in library.window_keys.items():
        if key.name != descriptor:
            continue
        windows, _ = library.places(name).of_clips(np.array([clip.id]))
        exact = np.flatnonzero((windows.starts == first) & (windows.stops == stop))
        if exact.size:
            try:
                return library.window_indexes[name].reconstruct(int(windows.ids[exact[0]]))
            except KeyError:
                return None
    return None


def _stored_parts(library: Library, span: _StoredSpan) -> Parts | None:
    """The query's parts from the stored windows of its clip inside its span (a clip with
    no file: a window every quarter or half window, not every frame)."""
    clip, first, stop = span.clip, span.first, span.stop
    length = part_length((stop - first) * clip.frame_time)
    name = window_index_name(span.descriptor, length)
    if name not in library.window_keys:
        return None
    windows, _ = library.places(name).of_clips(np.array([clip.id]))
    inside = (first <= windows.starts) & (windows.stops <= stop)
    held, vectors = library.window_indexes[name].reconstruct_batch(windows.ids[inside])
    if not held.any():
        return None
    offsets = (windows.starts[inside][held] - first) * clip.frame_time
    return Parts(length, offsets.astype(np.float64), vectors)


def _described_span(
    library: Library, entry: ClipEntry, descriptor: str, first: int, stop: int
) -> SpanDescription:
    """Read the clip's stored file and describe frames ``[first, stop)`` with its parts."""
    describer = library.describer
    assert isinstance(describer, MotionDescriber)
    with library.reads() as session:  # the files' hashes are not in the catalogue
        clip = clip_db.get_clip(session, entry.id)
    if clip is None:  # deleted meanwhile
        raise NotFound(f"no clip with id {entry.id}")
    return describer.describe_span(
        stored_upload(library, clip),
        library.settings.parse_limits,
        descriptor,
        first * clip.frame_time,
        stop * clip.frame_time,
        part_length=part_length,
        part_step=0.0,
        max_parts=MAX_PARTS,
    )


def search_moments_by_upload(
    library: Library,
    upload: Upload,
    descriptor: str,
    *,
    start: float | None,
    end: float | None,
    k: int,
    per_clip: int,
    label: label_db.LabelFilter,
    licence: LicenceArg = None,
    collapse: bool = False,
) -> tuple[MomentQuery, list[Moment]]:
    """Moments like the span ``[start, end)`` of an uploaded file, which is stored nowhere
    (``POST /search/moments``)."""
    _check(library, descriptor, k, per_clip)
    describer = library.describer
    if not isinstance(describer, MotionDescriber):
        raise InvalidInput("moments search needs the motion describer")
    span = describer.describe_span(
        upload,
        library.settings.parse_limits,
        descriptor,
        start,
        end,
        min_seconds=WINDOW_LENGTHS[0],
        part_length=part_length,
        part_step=0.0,
        max_parts=MAX_PARTS,
    )
    library.refresh()
    seconds = (span.end_frame - span.start_frame) * span.frame_time
    allowed = allowed_clip_ids(library, label, licence_filter(licence))
    moments = _search(
        library, descriptor, _parts_of(span), seconds, k, per_clip, allowed, None, collapse
    )
    if upload.format in SCENE_FORMATS:
        upload = dataclasses.replace(upload, animation=span.animation)
    with library.reads() as session:
        stored = clip_db.get_clip_by_hash(session, upload.content_hash)
    duration = span.frame_count * span.frame_time
    query = MomentQuery(
        None,
        _round(start if start is not None else 0.0),
        _round(end if end is not None else duration),
        stored,
    )
    return query, moments


__all__ = [
    "Moment",
    "MomentQuery",
    "nearest_lengths",
    "search_moments_by_clip",
    "search_moments_by_upload",
]
