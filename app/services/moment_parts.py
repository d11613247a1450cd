"""A moments query's parts: the query span described as its own windows of one length.

A moments search (:mod:`app.services.moments`) compares the stored windows of one length
``L`` (:func:`part_length`) with the query's *parts*: its windows of that length, one
starting at every frame of the query (a few frames apart past :data:`MAX_PARTS`). An upload's
parts are described from the file as it is searched; a stored clip's from its stored file
(the last few kept, :data:`SPAN_CACHE`), else — a clip without a file — from its stored
windows inside the span, else its whole-span vector alone.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from app.db import clips as clip_db
from app.db.entries import ClipEntry
from app.errors import InvalidInput, NotFound
from app.motion.windows import hop_share
from app.services.clips import stored_upload
from app.services.describe import (
    WINDOW_LENGTHS,
    MotionDescriber,
    SpanDescription,
)
from app.services.library import Library
from app.services.library_caches import window_index_name
from app.services.search import clip_vector

MAX_PARTS = 2048  # query parts at most: one per frame up to this many
SPAN_CACHE = 32  # described stored spans kept (a page asking again, a span dragged back)


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


@dataclass(frozen=True)
class StoredSpan:
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


def stored_span_parts(library: Library, span: StoredSpan) -> Parts:
    """The query's parts: described from the clip's stored file at every frame (as an
    upload's are), else — a clip without a file — its stored windows inside the span."""
    clip = span.clip
    if clip.filenames and isinstance(library.describer, MotionDescriber):
        key: tuple[object, ...] = (id(library), clip.id, clip.content_hash, span.descriptor)
        key = (*key, span.version, span.first, span.stop)
        parts = _SPANS.get(key)
        if parts is None:
            parts = described_parts(
                _described_span(library, clip, span.descriptor, span.first, span.stop)
            )
            _SPANS.put(key, parts)
        return parts
    parts = _stored_parts(library, span)
    if parts is not None:
        return parts
    vector = _stored_span_vector(library, span)
    if vector is None:
        with library.reads() as session:  # its windows and vectors went with it: 404, not 422
            if clip_db.get_clip(session, clip.id) is None:
                raise NotFound(f"no clip with id {clip.id}")
        raise InvalidInput(
            f"clip {clip.id} has no stored file to describe a part of ({clip.format} clip); "
            "search from the whole clip or one of its windows"
        )
    return Parts(0.0, np.zeros(1), vector[None, :])


def described_parts(span: SpanDescription) -> Parts:
    """A described span's parts (its own vector alone when it has none)."""
    if span.parts.size == 0:
        return Parts(0.0, np.zeros(1), span.vector[None, :])
    offsets = span.part_offsets.astype(np.float64) * span.frame_time
    return Parts(span.part_length, offsets, span.parts)


def _stored_span_vector(library: Library, span: StoredSpan) -> np.ndarray | None:
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


def _stored_parts(library: Library, span: StoredSpan) -> Parts | None:
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
