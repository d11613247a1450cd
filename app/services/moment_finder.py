"""Finding a moments query's nearest moments in one window index (see app/services/moments.py).

A :class:`MomentFinder` searches the window index with a few of the query's parts (the
*probes*, :data:`MAX_PROBES` at most, spread over the query), places the moments of the stored
windows near their hits (each seed window puts the query where its nearest part lies), and
measures how well each placed moment fits (the mean distance of its windows to the parts at
their offsets). What it measured of a window and of a seed is kept for the next, wider round
of the same search. The (parts x windows) comparisons are made a block of at most
:data:`BLOCK_BYTES` at a time (issue 21).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.db import windows as window_db
from app.index.places import Places
from app.services.describe import WINDOW_LENGTHS
from app.services.library import Library
from app.services.library_caches import window_index_name
from app.services.moment_arrays import Known, distinct, members, same_moments, to_nearest
from app.services.moment_parts import Parts

PROBE_AHEAD = 2  # a probe search asks for this many times the windows a round needs
MAX_PROBES = 16  # query parts that search the window index, at most
PROBE_COVER = 0.15  # ... until every part is this near one (share of a typical distance)
DIRECT_PARTS = 8  # a query of this many parts at most: each window's nearest part exactly
# The expanded form's rounding error on a squared distance stays below this share of the two
# squares summed (~D * 1e-16 for D of a few hundred): pairs further apart are told apart.
SQUARES_SLACK = 1e-9
BLOCK_BYTES = 64 * 2**20  # memory one block of a search's comparisons may take (issue 21)


def pair_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise distances ``(N,)`` of ``a`` and ``b`` ``(N, D)``, from the differences: the
    same number for the same pair whatever else a search computed (the expanded form
    through a matrix product loses the last digits near zero, and depends on the batch)."""
    return pair_distances_of(a - b)


def pair_distances_of(difference: np.ndarray) -> np.ndarray:
    """Row lengths ``(N,)`` of differences ``(N, D)`` (see :func:`pair_distances`)."""
    return np.sqrt(np.einsum("ij,ij->i", difference, difference))


@dataclass(frozen=True)
class PlacedMoments:
    """Placed moments: clip ids, starts and ends (seconds), distances ``(N,)``."""

    clips: np.ndarray
    starts: np.ndarray
    ends: np.ndarray
    distances: np.ndarray

    @classmethod
    def empty(cls) -> PlacedMoments:
        nothing = np.zeros(0)
        return cls(np.zeros(0, np.int64), nothing, nothing, nothing)


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


class MomentFinder:
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
        self.probes, cover = _probes(self.query, PROBE_COVER * self.scale.median, MAX_PROBES)
        # Every part lies within this of a probe (a hair more: float noise).
        self.cover = cover * (1 + 1e-6) + 1e-9
        self.facts = Known(2)  # clip id -> frame time, frame count
        self._probed: tuple[np.ndarray, np.ndarray] | None = None  # distances, ids
        self._nearest = Known(2)  # window id -> its nearest part, distance
        self._placed = Known(4)  # seed window id -> clip id, start, end, distance
        self._hits = np.zeros(0, np.int64)  # the hits placed so far (see found)
        self._found = PlacedMoments.empty()  # ... and their clips' moments

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

    def found(self, hits: np.ndarray) -> PlacedMoments:
        """:meth:`moments` of ``hits`` (sorted, unique; a superset of the last call's), with
        only the clips holding new hits placed again: a clip's moments depend on its own
        hits alone (a wider round adds hits to a few of the clips it had)."""
        bits = window_db.WINDOW_ID_BITS
        new = hits[~members(hits, self._hits)]
        changed = distinct(new >> bits)  # window ids hold their clip's id in the high bits
        kept = self._found
        keep = ~members(kept.clips, changed)
        placed = self.moments(hits[members(hits >> bits, changed)])
        self._hits = hits
        self._found = PlacedMoments(
            np.concatenate([kept.clips[keep], placed.clips]),
            np.concatenate([kept.starts[keep], placed.starts]),
            np.concatenate([kept.ends[keep], placed.ends]),
            np.concatenate([kept.distances[keep], placed.distances]),
        )
        return self._found

    def moments(self, hits: np.ndarray) -> PlacedMoments:
        """The moments placed by the seeds near the hits (within a query's length of one, in
        its clip), with their distances."""
        bits = window_db.WINDOW_ID_BITS
        clips = distinct(hits >> bits)
        held, facts = self.facts.find(clips)
        if not held.all():  # no SQL: the catalogue (clips deleted meanwhile are not there)
            unknown = clips[~held]
            listed, listed_facts = self.library.catalogue.frame_arrays(unknown)
            if listed_facts.size:
                self.facts.add(unknown[listed], listed_facts)
            held, facts = self.facts.find(clips)
            clips, facts = clips[held], facts[held]
        if not clips.size:
            return PlacedMoments.empty()
        rows, offsets = self.places.of_clips(clips)
        group = np.repeat(np.arange(clips.size), np.diff(offsets))
        frame_time = facts[:, 0][group]
        frames = facts[:, 1][group]
        starts, stops = rows.starts * frame_time, rows.stops * frame_time
        # Seconds from each window to the nearest hit of its clip (clips kept far apart).
        apart = 4.0 * (float(np.max(frames * frame_time)) + self.seconds + 1.0)
        keys = group * apart + starts  # ascending: clips in order, their windows by start
        marked = members(rows.ids, hits)
        if not marked.any():  # their clips deleted meanwhile
            return PlacedMoments.empty()
        to_hit = to_nearest(keys, keys[marked])
        slack = float(frame_time.max())
        seed_reach = max(self.seconds - self.length, 0.0) + slack
        nothing = np.zeros((0, self.query.shape[1]), np.float32)
        gathered: tuple[np.ndarray, np.ndarray] = (np.zeros(0, np.int64), nothing)
        if self.whole:  # the hits themselves, centred on their window
            seeds = np.flatnonzero(marked)
        else:
            seeds, gathered = self._local_minima(
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
            near = np.flatnonzero(to_nearest(keys, keys[fresh]) <= self.seconds + slack)
            held, stored = self._vectors(rows.ids, near, *gathered)
            window = near[held]
            position = np.full(len(rows), -1)
            position[window] = np.arange(window.size)
            fresh = fresh[position[fresh] >= 0]
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
                # Seeds placing the very same moment (a clip no longer than the query is
                # one moment, whichever window placed it) share its fit: the same windows
                # and parts, so the same number.
                one_each, again = same_moments(group[fresh], placed)
                distance = self._fits_in_blocks(
                    placed[one_each],
                    spans[one_each],
                    group[window],
                    starts[window],
                    stops[window],
                    frame_time[window],
                    position[fresh[one_each]],
                    stored,
                )[again]
            moments = np.stack([clips[group[fresh]], placed, placed + spans, distance], axis=1)
            self._placed.add(rows.ids[fresh], moments)
        known, found = self._placed.find(rows.ids[seeds])
        found = found[known]
        return PlacedMoments(found[:, 0].astype(np.int64), found[:, 1], found[:, 2], found[:, 3])

    def _vectors(
        self, ids: np.ndarray, wanted: np.ndarray, had: np.ndarray, vectors: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Which of the windows ``wanted`` (ascending rows of ``ids`` ``(N,)``) are held
        ``(M,)`` bool, and their ``(K, D)`` float64 vectors: those among ``had`` (ascending
        rows) from ``vectors`` (theirs, gathered this round), the others from the index.
        Gathering a row from the mapped lists reads far apart: the windows around a seed
        are mostly those whose nearest part was just measured."""
        at = np.minimum(np.searchsorted(had, wanted), max(had.size - 1, 0))
        reuse = had[at] == wanted if had.size else np.zeros(wanted.size, bool)
        missing = np.flatnonzero(~reuse)
        found, fetched = self.index.reconstruct_batch(ids[wanted[missing]])
        held = reuse.copy()
        held[missing[found]] = True
        stored = np.empty((wanted.size, self.query.shape[1]))
        stored[reuse] = vectors[at[reuse]]
        stored[missing[found]] = fetched
        return held, stored if held.all() else stored[held]

    def _local_minima(
        self, rows: Places, group: np.ndarray, region: np.ndarray, seedable: np.ndarray
    ) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
        """The seeds (rows of ``rows``): windows ``seedable`` nearer their nearest part than
        the window before them in their clip (or as near) and than the one after — a
        moment's best place, not its slopes. ``region`` (the seedable windows and their
        neighbours) get their nearest part measured. Whether a window is a seed depends on
        it, its neighbours and the query only, never on which windows the probes found.
        Also the rows whose vectors were gathered for it, and those ``(K, D)`` float32."""
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
        return candidates[lowest], (unknown, vectors)

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
            for block in blocks_within(np.full(len(windows), per_window), BLOCK_BYTES)
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
            for block in blocks_within(clip_windows * per_pair, BLOCK_BYTES)
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
                pair_distances(q[rows[i : i + chunk]], windows[columns[i : i + chunk]])
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
            every = pair_distances_of(difference).reshape(len(q), tied.size)
            nearest[tied] = every.argmin(axis=0)  # the first part on ties
        difference = q[nearest]  # a fresh (M, D) array: the pair's difference in place
        difference -= windows
        return nearest, pair_distances_of(difference)

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
        difference = self.query[pairs // len(stored)]  # fresh: the difference in place
        difference -= stored[pairs % len(stored)]
        unique = pair_distances_of(difference)
        sums = np.bincount(owner, weights=unique[which], minlength=seeds.size)
        return sums / np.maximum(counts, 1)


# Bytes per (part, window) pair besides the vectors: for the nearest part, 9 for the matrix
# and its mask and, when every pair ties (a query repeating itself), about 40 for the tied
# pairs' indexes, distances and order; about 100 for a fit's index arrays. With room.
NEAREST_BYTES_PER_PAIR = 64
FIT_BYTES_PER_PAIR = 128


def blocks_within(weights: np.ndarray, budget: int) -> list[slice]:
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
