"""Moments search: where in the stored clips a span of motion happens.

The query is a span ``[start, end)`` (seconds from the first frame of the file, lead-in
included) of a stored clip or of an uploaded file. It is described as its own *parts*: its
windows of one stored window length ``L`` (:func:`part_length`: the longest length whose
stored windows always fit one whole inside a span of the query's length), one starting at
every frame of the query (a few frames apart past
:data:`~app.services.moment_parts.MAX_PARTS`). A stored clip has its windows of length ``L``
every quarter (1 s) or half (longer) of ``L``.

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
nearer than ``d`` holds a window within ``d`` of some part. A few parts
(:data:`~app.services.moment_finder.MAX_PROBES`, spread over the query) search the window
index for their nearest windows; every part lies within ``cover`` of one of them, so a
window none of their searches reached within ``t`` is at least ``t - cover`` from every
part. Every moment nearer than ``t - cover`` thus holds a window among the hits, and is
placed by a window at most a query's length from it: the moments of all windows that near
the hits are placed and ranked, and the search widens (four times as many hits) until the
``k``-th moment of the list is nearer than ``t - cover`` or the index has no more windows.
The answer is then exact on flat indexes (libraries of fewer than
``MOCAP_INDEX_AUTO_THRESHOLD`` windows of a length); on IVF indexes the probes' searches are
approximate (a filtered one scans every cell).

A query too short for any stored window to lie inside it (a clip shorter than 1 s) has no
parts: its whole-span vector searches the shortest windows, a moment is centred on its
window and its distance is that window's.

Layout: the query's parts are :mod:`app.services.moment_parts`; probing the window index,
placing the moments and measuring their fit is :class:`app.services.moment_finder.MomentFinder`;
this module checks the request, ranks the placed moments into the list and answers.

Where each window lies comes from the library's in-memory window places
(:mod:`app.index.places`), not the database: a search reads only the query clip and the
found clips' names and frame rates. Windows of clips deleted by another process are skipped
(no place, or no clip row), as clip searches do.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from app.db import clips as clip_db
from app.db import label_filters as label_db
from app.db.entries import ClipEntry
from app.errors import InvalidInput, MomentsOff, NotFound
from app.licences import LicenceArg, licence_filter
from app.services.captures import group_nearest_first
from app.services.clips import MAX_ID
from app.services.describe import (
    WINDOW_LENGTHS,
    MotionDescriber,
    span_frames,
)
from app.services.library import Library
from app.services.moment_finder import MomentFinder, PlacedMoments
from app.services.moment_parts import (
    MAX_PARTS,
    Parts,
    StoredSpan,
    described_parts,
    part_length,
    stored_span_parts,
)
from app.services.search import allowed_clip_ids, capture_rule, check_k
from app.services.uploads import SCENE_FORMATS, Upload

MAX_PER_CLIP = 1000
FIRST_FETCH = 256  # windows each probe asks for first (twice as many per widening)


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


def _chosen(
    found: PlacedMoments,
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
    finder = MomentFinder(library, descriptor, parts, seconds, exclude)
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
    stored = StoredSpan(clip, descriptor, info.version, first, stop)
    parts = stored_span_parts(library, stored)
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
        library, descriptor, described_parts(span), seconds, k, per_clip, allowed, None, collapse
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
