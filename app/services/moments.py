"""Moments search: where in the stored clips a span of motion happens.

The query is a span ``[start, end)`` (seconds from the first frame of the file, lead-in
included) of a stored clip or of an uploaded file, described under one descriptor exactly as
a window is (:mod:`app.motion.windows`). It is compared with the stored windows of the window
length(s) nearest the query's length — the largest at most and the smallest at least as long
— through their FAISS indexes. Then:

* **merge**: window hits of one clip that overlap or touch (one after another, in distance
  order) become one moment, whose distance is its best window's;
* **localise**: the query's own windows (its *parts*, one every frame or so) are matched with
  the clip's stored windows near the hits: where a stored window lies whole inside the query
  (or exactly at its end) a part equals it and the moment lands on its frames; else the
  distance branches of the two stored windows around the true place are extrapolated to
  where they meet. Without parts (a stored span too short for any), the best window's place
  moved by the equiangular fit of its neighbours' distances. A moment is as long as the
  query (clipped to its clip) — a 3-s query finds a 3-s span, not a union of windows;
* **rank**: ``3 k`` moments are placed (and up to ``3 per_clip`` regions of one clip: its
  best window may lie in a repetition of the motion), then ranked by how well their whole
  span fits (the mean distance of the stored windows inside it to the query's parts at the
  same offsets): one window's distance ranks a long query by a few seconds of it, and
  windows straddle the boundaries between the motions of a take;
* **limit**: at most ``k`` moments, at most ``per_clip`` of one clip and none overlapping a
  nearer one of its clip, nearest first; a query from a stored clip never returns a moment
  overlapping its own span.

Where each window lies comes from the library's in-memory window places
(:mod:`app.index.places`), not the database: a search reads only the query clip and the
found clips' names and frame rates. Windows of clips deleted by another process are skipped
(no place, or no clip row), as clip searches do.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from app.db import clips as clip_db
from app.db import label_filters as label_db
from app.db import windows as window_db
from app.db.entries import ClipEntry
from app.errors import InvalidInput, MomentsOff, NotFound
from app.labels import label_filter
from app.motion.windows import hop_share
from app.services.clips import stored_upload
from app.services.describe import (
    WINDOW_LENGTHS,
    MotionDescriber,
    SpanDescription,
    span_frames,
)
from app.services.library import Library, window_index_name
from app.services.search import check_k, clip_vector
from app.services.uploads import Upload

MAX_PER_CLIP = 1000
RANKED = 3  # moments placed per moment returned, ranked by how well their whole span fits
MAX_ATTEMPTS = 4


@dataclass(frozen=True, slots=True)
class Moment:
    """A found span ``[start, end)`` in seconds of the clip's file."""

    clip: ClipEntry
    format: str
    start: float
    end: float
    distance: float


@dataclass(frozen=True, slots=True)
class MomentQuery:
    """The query's span in seconds of its file, and its clip when it is a stored one."""

    clip: ClipEntry | None
    start: float
    end: float


@dataclass(frozen=True)
class Parts:
    """The query's own windows of one ``length`` (seconds): ``offsets`` ``(J,)`` seconds from
    the query's start, ``vectors`` ``(J, D)`` float32. They place a moment to a frame or so:
    a window stored in the found clip matches the query's part at the same place."""

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


@dataclass
class _Group:
    """Window hits of one clip merged so far: the best of them (its id and frames ``[start,
    stop)``, in window index ``index``), and ``cover`` the frames of their union."""

    clip_id: int
    best_id: int
    best_start: int
    best_stop: int
    distance: float
    index: str
    cover: tuple[int, int]


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


def nearest_lengths(seconds: float, lengths: tuple[float, ...] = WINDOW_LENGTHS) -> list[float]:
    """The window lengths a query of ``seconds`` is compared with: the longest at most as
    long and the shortest at least as long (one when the query is shorter or longer than
    every window, or as long as one)."""
    ordered = sorted(lengths)
    below = [length for length in ordered if length <= seconds + 1e-9]
    above = [length for length in ordered if length >= seconds - 1e-9]
    chosen = {below[-1] if below else ordered[0], above[0] if above else ordered[-1]}
    return sorted(chosen)


def _index_names(library: Library, descriptor: str, seconds: float) -> list[str]:
    wanted = nearest_lengths(seconds)
    return [
        name
        for name, key in library.window_keys.items()
        if key.name == descriptor and key.length in wanted
    ]


def _refined_centre(library: Library, group: _Group, vector: np.ndarray) -> float:
    """The frame (fractional) where the moment's centre lies: its best window's centre moved
    by the equiangular fit of its neighbours' distances (see the module docstring)."""
    centre = (group.best_start + group.best_stop) / 2
    index = library.window_indexes[group.index]
    neighbours = np.array([group.best_id - 1, group.best_id + 1], np.int64)
    held, starts, _ = library.places(group.index).find(neighbours)
    distances: dict[int, tuple[float, int]] = {}
    for step, window_id, is_held, start in zip(
        (-1, 1), neighbours.tolist(), held.tolist(), starts.tolist(), strict=True
    ):
        if not is_held or window_id >> window_db.WINDOW_ID_BITS != group.clip_id:
            continue
        shift = start - group.best_start
        if shift == 0 or (shift > 0) != (step > 0):
            continue
        try:
            other = index.reconstruct(window_id)
        except KeyError:
            continue
        distances[step] = (float(np.linalg.norm(other - vector)), abs(shift))
    if len(distances) < 2:
        return centre
    (left, hop_left), (right, hop_right) = distances[-1], distances[1]
    rise = max(left, right) - group.distance
    if rise <= 1e-12:
        return centre
    hop = min(hop_left, hop_right)
    offset = (left - right) / (2 * rise) * hop
    return centre + float(np.clip(offset, -hop / 2, hop / 2))


def _aligned_starts(
    library: Library,
    groups: list[_Group],
    frame_times: np.ndarray,
    parts: Parts,
    descriptor: str,
    query_seconds: float,
    exclude: tuple[int, int, int] | None,
) -> list[tuple[float, float] | None]:
    """For each group, where (seconds) its moment starts — the stored window of its clip
    nearest to one of the query's parts, minus that part's offset — and how well the whole
    span fits: the mean distance of the stored windows inside the placed span to the query's
    parts at the same offsets (``None``: no window to compare). ``frame_times`` ``(G,)``.

    All groups at once: their clips' windows of the parts' length near the hits come from
    the window places, their vectors from one batch read of the window index, and their
    distances to the parts from one matrix product; only the fits are per group.
    """
    name = window_index_name(descriptor, parts.length)
    if name not in library.window_keys or parts.vectors.size == 0 or not groups:
        return [None] * len(groups)
    rows, offsets = library.places(name).of_clips(np.array([g.clip_id for g in groups]))
    group_of = np.repeat(np.arange(len(groups)), np.diff(offsets))
    reach = query_seconds / frame_times
    # The frames each group's windows may lie in: the hits' cover and a query's length
    # either side (truncated like the integers they were read with).
    low = np.trunc(np.array([g.cover[0] for g in groups]) - reach).astype(np.int64)
    high = np.trunc(np.array([g.cover[1] for g in groups]) + reach).astype(np.int64) + 1
    keep = (rows.stops >= low[group_of]) & (rows.starts <= high[group_of])
    if exclude is not None:
        own = (rows.ids >> window_db.WINDOW_ID_BITS) == exclude[0]
        keep &= ~own | (rows.stops <= exclude[1]) | (rows.starts >= exclude[2])
    held, stored = library.window_indexes[name].reconstruct_batch(rows.ids[keep])
    kept = np.flatnonzero(keep)[held]
    starts, group_of = rows.starts[kept], group_of[kept]
    stored64 = stored.astype(np.float64)
    query = parts.vectors.astype(np.float64)
    squared = (
        (query**2).sum(axis=1)[:, None]
        + (stored64**2).sum(axis=1)[None, :]
        - 2 * query @ stored64.T
    )
    distances = np.sqrt(np.maximum(squared, 0.0))
    bounds = np.searchsorted(group_of, np.arange(len(groups) + 1))

    def pair_distances(rows: np.ndarray, columns: np.ndarray) -> np.ndarray:
        """Distances of some (part, stored window) pairs, from the differences (the expanded
        form above loses the last digits near zero)."""
        return np.linalg.norm(query[rows] - stored64[columns], axis=1)

    def window_gaps(these: np.ndarray, those: np.ndarray) -> np.ndarray:
        """Distances between some stored windows."""
        return np.linalg.norm(stored64[these] - stored64[those], axis=1)

    starts_s = _placed_starts(
        distances, starts, group_of, bounds, parts, frame_times, pair_distances, window_gaps
    )
    fits = _span_fits(
        distances,
        starts * frame_times[group_of] - starts_s[group_of],
        group_of,
        len(groups),
        parts,
        query_seconds,
    )
    return [
        None if bounds[g] == bounds[g + 1] else (float(starts_s[g]), float(fits[g]))
        for g in range(len(groups))
    ]


def _placed_starts(
    distances: np.ndarray,
    starts: np.ndarray,
    group_of: np.ndarray,
    bounds: np.ndarray,
    parts: Parts,
    frame_times: np.ndarray,
    pair_distances: Callable[[np.ndarray, np.ndarray], np.ndarray],
    window_gaps: Callable[[np.ndarray, np.ndarray], np.ndarray],
) -> np.ndarray:
    """Where (seconds) each group's moment starts (see :func:`_aligned_starts`; nan for a
    group without windows). ``distances`` ``(J, M)`` parts x stored windows, ``starts``
    ``(M,)`` frames and ``group_of`` ``(M,)`` of those windows (grouped, each group's in
    start order: columns ``bounds[g]:bounds[g + 1]``); ``pair_distances(rows, columns)``
    the exact distances of some pairs, ``window_gaps(columns, columns)`` those between some
    stored windows."""
    groups = len(frame_times)
    placed = np.full(groups, np.nan)
    if not distances.size:
        return placed
    present = bounds[1:] > bounds[:-1]
    part, best = _group_argmin(distances, group_of, bounds)
    paired = np.where(present, starts[best] * frame_times - parts.offsets[part], np.nan)
    inner = present & (part > 0) & (part < len(parts.offsets) - 1)
    # Parts on both sides fit worse: this part lies on the stored window itself.
    placed[inner] = paired[inner]
    # Else the best place is beyond the parts' offsets (no stored window fits whole in the
    # query's span): between two stored windows, where their distance branches cross.
    ends = np.flatnonzero(present & ~inner)
    if not ends.size:
        return placed
    # The neighbour on the other side of the true place, if the group has it.
    other = np.where(part[ends] == 0, best[ends] + 1, best[ends] - 1)
    other = np.where((other >= bounds[ends]) & (other < bounds[ends + 1]), other, -1)
    seconds = starts * frame_times[group_of]
    crossing = branch_crossings(distances, seconds, parts.offsets, part[ends], best[ends], other)
    # Unless the end part lies on its stored window itself (a query starting where a window
    # does): it is then nearer to it than half a frame's share of the way to the next
    # stored window (of the same group: the one beyond the end, else the one before).
    step = np.where(part[ends] == 0, 1, -1)
    neighbour = np.where(other >= 0, other, best[ends] - step)
    has = (neighbour >= bounds[ends]) & (neighbour < bounds[ends + 1])
    neighbour = np.where(has, neighbour, best[ends])
    hop = np.abs(seconds[neighbour] - seconds[best[ends]])
    with np.errstate(divide="ignore", invalid="ignore"):
        share = (frame_times[ends] / 2) / hop
    near = pair_distances(part[ends], best[ends]) <= window_gaps(best[ends], neighbour) * share
    on_window = has & (hop > 0) & near
    placed[ends] = np.where(on_window, paired[ends], crossing)
    # Else: where a part fits best between the stored windows (equiangular fits).
    rest = ends[np.isnan(placed[ends])]
    if rest.size:
        shift, lowest = fitted_minima(distances, starts, group_of)
        part, best = _group_argmin(lowest, group_of, bounds)
        placed[rest] = shift[part[rest], best[rest]] * frame_times[rest] - parts.offsets[part[rest]]
    return placed


def _group_argmin(
    matrix: np.ndarray, group_of: np.ndarray, bounds: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Each group's smallest entry of ``matrix`` ``(J, M)`` (its columns ``bounds[g]:
    bounds[g + 1]``, ``group_of`` ``(M,)``), as np.argmin over its block picks it (row-major:
    the lowest row, then the first column, among equal values): rows and columns ``(G,)``
    (0 for a group without columns)."""
    column_row = matrix.argmin(axis=0)
    column_best = matrix[column_row, np.arange(matrix.shape[1])]
    order = np.lexsort((np.arange(len(group_of)), column_row, column_best, group_of))
    present = bounds[1:] > bounds[:-1]
    columns = np.zeros(len(bounds) - 1, np.int64)
    columns[present] = order[bounds[:-1][present]]
    return column_row[columns], columns


def _span_fits(
    distances: np.ndarray,
    offsets: np.ndarray,
    group_of: np.ndarray,
    groups: int,
    parts: Parts,
    query_seconds: float,
) -> np.ndarray:
    """Per group ``(G,)``: the mean distance of its stored windows at ``offsets`` ``(M,)``
    (seconds from its placed start) inside the placed span to the query's parts nearest
    those offsets; its best distance when no stored window lies inside."""
    last = len(parts.offsets) - 1
    inside = (offsets >= -0.02) & (offsets <= query_seconds - parts.length + 0.02)
    rows = np.clip(np.searchsorted(parts.offsets, offsets), 0, last)
    below = np.clip(rows - 1, 0, last)
    nearer = np.abs(parts.offsets[below] - offsets) < np.abs(parts.offsets[rows] - offsets)
    rows = np.where(nearer, below, rows)
    values = distances[rows, np.arange(len(offsets))]
    counts = np.bincount(group_of[inside], minlength=groups)
    sums = np.bincount(group_of[inside], weights=values[inside], minlength=groups)
    lowest = np.full(groups, np.inf)
    np.minimum.at(lowest, group_of, distances.min(axis=0))
    return np.where(counts > 0, sums / np.maximum(counts, 1), lowest)


def branch_crossings(
    distances: np.ndarray,
    starts: np.ndarray,
    offsets: np.ndarray,
    best_part: np.ndarray,
    best: np.ndarray,
    other: np.ndarray,
) -> np.ndarray:
    """Where (seconds) the query starts in each of ``G`` moments whose best pair is an end
    part ``best_part`` ``(G,)`` (0 or the last) and stored window ``best`` ``(G,)``: every
    part against one stored window puts the query's start at ``start - offset``; along those
    places the distance of a window is one branch of a V (about linear). The best window's
    branch and its neighbour's on the other side of the true place, ``other`` ``(G,)`` (-1:
    none), each fitted with a line over the parts, cross there — each with its own slope,
    which a fit from three windows cannot have. nan when the branches do not go down towards
    each other (or too few parts to fit a line).

    ``distances`` ``(J, M)`` parts x stored windows, ``starts`` ``(M,)`` seconds (each
    moment's windows sorted), ``offsets`` ``(J,)`` seconds (ascending).
    """
    count = len(offsets)
    place = np.full(len(best), np.nan)
    if count < 3 or not len(best):
        return place
    there = np.maximum(other, 0)
    # A branch's places are start - offsets: the same spread for every window.
    spread = offsets - offsets.mean()
    scale = max(float((spread**2).sum()), 1e-18)

    def line(column: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Least-squares slope and intercept of each column's distances over its places."""
        y = distances[:, column]
        slope = -(spread[:, None] * (y - y.mean(axis=0))).sum(axis=0) / scale
        return slope, y.mean(axis=0) - slope * (starts[column] - offsets.mean())

    slope_here, at_here = line(best)
    slope_there, at_there = line(there)
    rising = np.where(best_part == 0, 1.0, -1.0)  # the true place is above (below) this branch
    crossing = (other >= 0) & (slope_here * rising < 0) & (slope_there * rising > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        where = (at_there - at_here) / (slope_here - slope_there)
    edge_here = starts[best] - offsets[best_part]
    edge_there = starts[there] - offsets[count - 1 - best_part]
    within = np.clip(where, np.minimum(edge_here, edge_there), np.maximum(edge_here, edge_there))
    place[crossing] = within[crossing]
    return place


def fitted_minima(
    distances: np.ndarray, starts: np.ndarray, group_of: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Where between the stored windows each query part fits best, and how well.

    ``distances`` ``(J, M)`` from each query part to each stored window, whose ``starts``
    ``(M,)`` (frames) are sorted within each group of ``group_of`` ``(M,)`` (a group is one
    moment's windows, its columns contiguous). A window's distance grows about linearly with
    how far it is shifted from the best place (means over shifted frames change linearly),
    so at a window nearer than both its neighbours of the same group (an equal hop ``h``
    away) the equiangular fit gives the best place ``start + x`` with ``x = h (d_left -
    d_right) / (2 rise)`` and its distance ``d - rise |x| / h`` (``rise = max(d_left,
    d_right) - d``). Elsewhere the window's own start and distance stand.

    Returns ``(J, M)`` fitted starts (frames) and fitted distances.
    """
    shift = np.broadcast_to(starts.astype(np.float64), distances.shape).copy()
    lowest = distances.copy()
    if distances.shape[1] < 3:
        return shift, lowest
    left, centre, right = distances[:, :-2], distances[:, 1:-1], distances[:, 2:]
    hop_left = (starts[1:-1] - starts[:-2]).astype(np.float64)
    hop_right = (starts[2:] - starts[1:-1]).astype(np.float64)
    rise = np.maximum(left, right) - centre
    ok = (rise > 1e-12) & (centre <= np.minimum(left, right)) & (hop_left == hop_right)
    ok &= (hop_left > 0) & (group_of[:-2] == group_of[1:-1]) & (group_of[2:] == group_of[1:-1])
    safe_rise = np.where(ok, rise, 1.0)
    x = np.clip((left - right) / (2 * safe_rise), -0.5, 0.5) * hop_left
    shift[:, 1:-1] += np.where(ok, x, 0.0)
    lowest[:, 1:-1] = np.where(ok, centre - safe_rise * np.abs(x) / np.maximum(hop_left, 1), centre)
    return shift, lowest


def _search(
    library: Library,
    descriptor: str,
    vector: np.ndarray,
    query_seconds: float,
    k: int,
    per_clip: int,
    label: label_db.LabelFilter,
    exclude: tuple[int, int, int] | None,
    parts: Parts | None = None,
) -> list[Moment]:
    """``exclude``: (clip id, first, stop) frames of the query's own span; ``parts``: the
    query's own windows, to place the moments (else their best window's neighbours do)."""
    names = _index_names(library, descriptor, query_seconds)
    labelled = library.catalogue.ids_with_labels(label) if label_filter(label) else None
    allowed = {
        name: None if labelled is None else library.places(name).ids_of_clips(labelled)
        for name in names
    }
    # More moments than asked for are placed, then ranked by how well their whole span fits
    # (of one clip too: its best window may lie in a repetition of the motion, not the copy).
    ranked = RANKED if parts is not None else 1
    candidates = k * ranked
    fetch = min(4 * candidates + 20, 4096)  # windows per index; more when too few moments
    groups: list[_Group] = []
    for _ in range(MAX_ATTEMPTS):
        hits, exhausted = _window_hits(library, names, vector, fetch, allowed)
        groups, counted = _merged(hits, exclude, per_clip, per_clip * ranked, candidates)
        if counted >= candidates or exhausted:
            break
        fetch *= 4
    chosen = sorted(groups, key=lambda g: g.distance)
    facts = library.catalogue.frames(g.clip_id for g in chosen)
    chosen = [g for g in chosen if g.clip_id in facts]  # not deleted meanwhile
    frame_times = np.array([facts[g.clip_id][0] for g in chosen], np.float64)
    placed: list[tuple[float, float] | None] = [None] * len(chosen)
    if parts is not None:
        placed = _aligned_starts(
            library, chosen, frame_times, parts, descriptor, query_seconds, exclude
        )
    found: list[tuple[float, int, float, float]] = []  # distance, clip, span
    for group, place in zip(chosen, placed, strict=True):
        frame_time, frame_count = facts[group.clip_id]
        length = min(query_seconds / frame_time, float(frame_count))
        if place is not None:
            start, distance = place
        else:
            distance = group.distance
            start = (_refined_centre(library, group, vector) - length / 2) * frame_time
        first = min(max(0.0, start / frame_time), frame_count - length)
        if exclude is not None and _overlaps_query(exclude, group.clip_id, first, first + length):
            # Placed over the query's own span: next to it, on the side of the best window.
            after = group.best_start >= exclude[1]
            first = float(exclude[2]) if after else exclude[1] - length
            if first < 0 or first + length > frame_count:
                continue
        found.append((distance, group.clip_id, first * frame_time, (first + length) * frame_time))
    found.sort(key=lambda moment: moment[0])
    # Nearest first, at most per_clip of a clip, none overlapping a nearer one of its clip.
    shown: list[tuple[float, int, float, float]] = []
    of_clip: dict[int, list[tuple[float, float]]] = {}
    for moment in found:
        spans = of_clip.setdefault(moment[1], [])
        if len(spans) < per_clip and all(moment[3] <= a or b <= moment[2] for a, b in spans):
            spans.append((moment[2], moment[3]))
            shown.append(moment)
            if len(shown) == k:
                break
    clips = library.catalogue.get_many(clip_id for _, clip_id, _, _ in shown)  # those shown
    return [
        Moment(clips[clip_id], clips[clip_id].format, _round(start), _round(end), distance)
        for distance, clip_id, start, end in shown
        if clip_id in clips
    ]


# (distance, window id, index name, start, stop) of one window hit
_Hit = tuple[float, int, str, int, int]


def _window_hits(
    library: Library,
    names: list[str],
    vector: np.ndarray,
    fetch: int,
    allowed: dict[str, np.ndarray | None],
) -> tuple[list[_Hit], bool]:
    """The ``fetch`` nearest windows of each index in ``names``, nearest first, with where
    they lie (windows no longer held — their clip deleted meanwhile — are left out), and
    whether every index gave fewer than asked for (no more to fetch)."""
    hits: list[_Hit] = []
    exhausted = True
    for name in names:
        found = library.window_indexes[name].search(vector, fetch, allowed=allowed[name])
        exhausted &= len(found) < fetch
        held, starts, stops = library.places(name).find(found.ids)
        hits.extend(
            (distance, window_id, name, start, stop)
            for distance, window_id, start, stop in zip(
                found.distances[held].tolist(),
                found.ids[held].tolist(),
                starts[held].tolist(),
                stops[held].tolist(),
                strict=True,
            )
        )
    hits.sort()
    return hits, exhausted


def _merged(
    hits: list[_Hit],
    exclude: tuple[int, int, int] | None,
    per_clip: int,
    placed_per_clip: int,
    candidates: int,
) -> tuple[list[_Group], int]:
    """Merge the hits (nearest first) into moments: a hit overlapping or touching one of its
    clip's moments widens it; else it starts a new one while its clip has fewer than
    ``per_clip`` and fewer than ``candidates`` count so far, or as one more to place of a
    clip with fewer than ``placed_per_clip`` (at most ``candidates`` such). Returns the
    moments and how many count (at most ``per_clip`` of a clip)."""
    by_clip: dict[int, list[_Group]] = {}
    groups: list[_Group] = []
    counted = extra = 0
    for distance, window_id, name, start, stop in hits:
        clip_id = window_id >> window_db.WINDOW_ID_BITS
        if _overlaps_query(exclude, clip_id, start, stop):
            continue
        of_clip = by_clip.setdefault(clip_id, [])
        merged = False
        for group in of_clip:
            if start <= group.cover[1] and group.cover[0] <= stop:
                group.cover = (min(group.cover[0], start), max(group.cover[1], stop))
                merged = True
                break
        if merged:
            continue
        if len(of_clip) < per_clip and counted < candidates:
            counted += 1
        elif per_clip <= len(of_clip) < placed_per_clip and extra < candidates:
            extra += 1
        else:
            continue
        group = _Group(clip_id, window_id, start, stop, distance, name, (start, stop))
        of_clip.append(group)
        groups.append(group)
    return groups, counted


def _overlaps_query(
    exclude: tuple[int, int, int] | None, clip_id: int, first: float, stop: float
) -> bool:
    """Whether frames ``[first, stop)`` of clip ``clip_id`` overlap the query's own span."""
    return (
        exclude is not None and clip_id == exclude[0] and first < exclude[2] and exclude[1] < stop
    )


def _round(seconds: float) -> float:
    return round(seconds, 6)


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
) -> tuple[MomentQuery, list[Moment]]:
    """Moments like the span ``[start, end)`` of stored clip ``clip_id`` (``GET
    /search/moments``); none overlapping that span itself."""
    _check(library, descriptor, k, per_clip)
    info = library.descriptor(descriptor)
    library.refresh()
    clip = library.clip_entry(clip_id)
    if clip is None:
        raise NotFound(f"no clip with id {clip_id}")
    first, stop = span_frames(
        clip.frame_count, clip.frame_time, clip.lead_in_frames, start, end, WINDOW_LENGTHS[0]
    )
    stored = _StoredSpan(clip, descriptor, info.version, first, stop)
    vector = _stored_span_vector(library, stored)
    if vector is None:
        vector = _described_span(library, clip, descriptor, first, stop).vector
    seconds = (stop - first) * clip.frame_time
    parts = _stored_parts(library, stored)
    moments = _search(
        library,
        descriptor,
        vector,
        seconds,
        k,
        per_clip,
        label,
        (clip.id, first, stop),
        parts,
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
    """The query's parts from the stored windows of its clip inside its span."""
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
    """Read the clip's stored file and describe frames ``[first, stop)``."""
    describer = library.describer
    with library.reads() as session:  # the files' hashes are not in the catalogue
        clip = clip_db.get_clip(session, entry.id)
    if clip is None:
        raise NotFound(f"no clip with id {entry.id}")
    if not clip.files or not isinstance(describer, MotionDescriber):
        raise InvalidInput(
            f"clip {clip.id} has no stored file to describe a part of ({clip.format} clip); "
            "search from the whole clip or one of its windows"
        )
    upload = stored_upload(library, clip)
    return describer.describe_span(
        upload,
        library.settings.parse_limits,
        descriptor,
        first * clip.frame_time,
        stop * clip.frame_time,
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
    )
    library.refresh()
    seconds = (span.end_frame - span.start_frame) * span.frame_time
    parts = Parts(span.part_length, span.part_offsets * span.frame_time, span.parts)
    moments = _search(library, descriptor, span.vector, seconds, k, per_clip, label, None, parts)
    duration = span.frame_count * span.frame_time
    query = MomentQuery(
        None,
        _round(start if start is not None else 0.0),
        _round(end if end is not None else duration),
    )
    return query, moments


__all__ = [
    "Moment",
    "MomentQuery",
    "nearest_lengths",
    "search_moments_by_clip",
    "search_moments_by_upload",
]
