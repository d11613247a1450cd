"""Stick-figure previews of clips: canonical joints per frame in a display frame.

The display frame
    A clip is run through the motion core (parse -> :func:`~app.motion.body.build_body`, so
    converter lead-in frames are dropped as for the descriptors) and its canonical joints are
    put in a *display frame* (:mod:`app.motion.display`: body heights, y up, facing +z at
    the first frame). Frames are resampled to the requested rate by linear interpolation in
    time, at most :data:`MAX_SKELETON_FRAMES` of them per response.

Where a stored clip's frames come from
    Up to :data:`~app.motion.display.STORE_FPS` frames per second, from the clip's *stored
    preview*: its whole motion in the display frame at 30 fps (or its own rate when lower),
    kept as one file per clip content under ``<data dir>/previews/`` (:class:`PreviewStore`).
    The preview is written when the clip is stored (upload, import, reindex:
    :func:`save_stored_preview`, from the body the describer built, so the file is parsed
    once), and made on demand for a clip stored without one. A page's first view of a
    clip then reads a small file instead of parsing the clip, across restarts and server
    processes. The folder is a cache (named by the content hash and
    :func:`preview_version`, so a new motion core makes new files): it can be deleted at any
    time. Faster rates (the clip page stepping through a 120-fps take frame by frame) read
    the file again; that motion is kept in memory for the next windows.

Spans (``start``, ``end``)
    Seconds of the file as uploaded, lead-in frames included, as everywhere in the API (moments,
    ``GET /clips/{id}/file``). A response covers the frames of the span (at most
    ``max_frames`` of them), so a page can fetch any part of a take of any length.

Encodings (``encoding``)
    ``json``: ``frames`` as nested lists ``[frame][joint] = [x, y, z]``, rounded to
    :data:`DECIMALS` decimals. ``compact``: ``root`` = base64 of little-endian float32
    ``(F, 3)``, the pelvis per frame; ``offsets`` = base64 of little-endian int16 ``(F, C, 3)``,
    each joint minus the pelvis in units of :data:`OFFSET_UNIT` body heights (0.1 mm at
    1.7 m; offsets beyond +-3.27 body heights are clipped). A third of the JSON's size before
    compression, and decoded by a browser without parsing numbers.
"""

from __future__ import annotations

import base64
import gzip
import hashlib
import json
import logging
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from app.db import clips as clip_db
from app.errors import InvalidInput, NoStoredFile, ParseError
from app.motion.display import (
    RATE_SLACK,
    STORE_FPS,
    DisplayMotion,
    at_store_rate,
    body_display,
    resample,
)
from app.motion.model import Motion, ParseLimits
from app.motion.pipeline import describable_body
from app.motion.skeleton_map import CANONICAL_BONES, CANONICAL_INDEX, CANONICAL_JOINTS
from app.services.clips import stored_upload
from app.services.describe import read_motion, span_frames
from app.services.library import Library
from app.services.lru import LRUCache
from app.services.parser_pool import ParserPool
from app.services.preview_store import PreviewStore, preview_store
from app.services.uploads import Upload

log = logging.getLogger(__name__)

MAX_SKELETON_FRAMES = 600
"""Most frames one skeleton response carries; longer spans are truncated (``truncated``)."""
MIN_FPS, MAX_FPS, DEFAULT_FPS = 0.01, 1000.0, 30.0
DECIMALS = 4
"""``json`` coordinates are rounded to this many decimals of a body height (0.1 mm at 1.7 m)."""
OFFSET_UNIT = 1e-4
"""Body heights per step of the ``compact`` encoding's int16 joint offsets."""
ENCODINGS = ("json", "compact")
GZIP_LEVEL = 6
SKELETON_FORMAT_VERSION = 2
"""Changes whenever the numbers a skeleton response carries change (in ETags and stored
preview names)."""
_PELVIS = CANONICAL_INDEX["pelvis"]


@dataclass(frozen=True, eq=False)
class Skeleton:
    """One skeleton response, already encoded (``body`` is JSON bytes) and, once asked for,
    gzipped: a search page fetches fifty at once, and compressing each again every time cost
    more than everything else the request does."""

    body: bytes
    etag: str

    @cached_property
    def gzipped(self) -> bytes:
        return gzip.compress(self.body, compresslevel=GZIP_LEVEL, mtime=0)


def save_stored_preview(library: Library, content_hash: str, display: DisplayMotion) -> None:
    """Store the preview of a clip just stored (``display``: :attr:`Description.preview
    <app.services.describe.Description.preview>`, made by the describer from the body it
    built). It never raises: the clip is stored already, and a preview that cannot be
    written (a full disk, a read-only folder) is logged and made again when first shown."""
    preview_store(library.settings).save(content_hash, preview_version(library), display)


def _nbytes(display: DisplayMotion) -> int:
    return int(display.positions.nbytes)


class SkeletonCache:
    """Per-application caches: the full-rate display motions of the clips a page steps
    through, stored previews (at :data:`STORE_FPS`), encoded responses — each bounded in
    number and bytes — and the :class:`PreviewStore` when there is a data directory."""

    def __init__(self, store_root: Path | None = None) -> None:
        self.motions: LRUCache[tuple[int, str], DisplayMotion] = LRUCache(
            8, max_weight=256e6, weigh=_nbytes
        )
        self.previews: LRUCache[tuple[str, str], DisplayMotion] = LRUCache(
            1024, max_weight=128e6, weigh=_nbytes
        )
        self.responses: LRUCache[tuple[Any, ...], Skeleton] = LRUCache(
            512, max_weight=64e6, weigh=lambda s: 2 * len(s.body)
        )
        self.store = PreviewStore(store_root) if store_root is not None else None


def extent(positions: np.ndarray) -> dict[str, float]:
    """How much room ``(F, C, 3)`` frames need around the pelvis, for framing them: the
    tallest frame (``height``: its highest joint minus its lowest) and the farthest any joint
    gets from the pelvis over the floor (``reach``), in body heights."""
    if positions.shape[0] == 0:
        return {"height": 0.0, "reach": 0.0}
    heights = positions[..., 1].max(axis=1) - positions[..., 1].min(axis=1)
    across = positions[..., [0, 2]] - positions[:, _PELVIS, None][..., [0, 2]]
    return {
        "height": round(float(heights.max()), DECIMALS),
        "reach": round(float(np.sqrt((across**2).sum(axis=-1)).max()), DECIMALS),
    }


def read_stored_motion(library: Library, clip: clip_db.ClipRecord) -> Motion:
    """Parse a stored clip's file(s) again (ParseError if they no longer parse;
    NoStoredFile for a clip without files)."""
    if not clip.files:
        raise NoStoredFile(clip.id, clip.format)
    upload = stored_upload(library, clip)
    return read_motion(upload, library.settings.parse_limits, library.parsers).motion


def upload_display_motion(
    upload: Upload, limits: ParseLimits, parsers: ParserPool | None = None
) -> DisplayMotion:
    """Parse and map an uploaded (not stored) clip; errors name the uploaded file."""
    read = read_motion(upload, limits, parsers)
    try:
        return display_motion(read.motion)
    except ParseError as error:
        part = upload.parts[0]
        source = f"{part.role} {part.filename!r}"
        raise type(error)(error.reason, line=error.line, source=source) from None


def display_motion(motion: Motion) -> DisplayMotion:
    """A motion's canonical joints in the display frame at the file's own rate, from the
    body an upload would be described from (:func:`~app.motion.pipeline.describable_body`:
    a frame no body can take, a 1e308 in the file, is refused as it is on upload, not
    drawn into a payload no JSON can hold)."""
    return body_display(describable_body(motion))


def preview_version(library: Library) -> str:
    """Names the stored previews of this motion core: the response format and every
    descriptor's version (a change to the motion core that moves joints changes those)."""
    versions = ",".join(f"{n}:{d.version}" for n, d in sorted(library.descriptors.items()))
    text = f"{SKELETON_FORMAT_VERSION};{versions}"
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def _b64(array: np.ndarray) -> str:
    return base64.b64encode(np.ascontiguousarray(array).tobytes()).decode("ascii")


def _whole(value: float) -> float | int:
    return int(value) if float(value).is_integer() else value


def skeleton_payload(
    display: DisplayMotion,
    *,
    clip_id: int | None,
    fps: float,
    max_frames: int,
    start: float = 0.0,
    end: float | None = None,
    encoding: str = "json",
) -> dict[str, Any]:
    """The skeleton response (see ``GET /clips/{id}/skeleton``) as plain JSON values;
    ``start``/``end``: seconds from the first frame after the lead-in."""
    start = min(max(0.0, start), display.duration)
    frames, truncated = resample(display.positions, display.frame_time, fps, max_frames, start, end)
    # The extent covers the span asked for, every stored frame of it (not only those
    # returned): an overview of a take frames its every pose.
    span_end = display.duration if end is None else min(end, display.duration)
    first = int(np.floor(start / display.frame_time + 1e-6))
    last = int(np.ceil(span_end / display.frame_time - 1e-6))
    lead_in = display.lead_in_frames * display.source_frame_time
    body: dict[str, Any] = {
        "clip_id": clip_id,
        "fps": _whole(fps),
        "start": round(lead_in + start, 6),
        "frame_count": int(frames.shape[0]),
        "truncated": truncated,
        "duration": round((frames.shape[0] - 1) / fps, 6),
        "source_frame_count": int(display.source_frame_count),
        "source_duration": round(
            max(0, display.source_frame_count - 1) * display.source_frame_time, 6
        ),
        "source_fps": round(1.0 / display.source_frame_time, 6),
        "lead_in_frames": display.lead_in_frames,
        "units": "body heights",
        "joints": list(CANONICAL_JOINTS),
        "bones": [list(b) for b in CANONICAL_BONES],
        "extent": extent(display.positions[first : last + 1]),
        "encoding": encoding,
    }
    if encoding == "compact":
        pelvis = frames[:, _PELVIS]
        steps = np.round((frames - pelvis[:, None]) / OFFSET_UNIT)
        body["offset_unit"] = OFFSET_UNIT
        body["root"] = _b64(pelvis.astype("<f4"))
        body["offsets"] = _b64(np.clip(steps, -32767, 32767).astype("<i2"))
    else:
        body["frames"] = np.round(frames, DECIMALS).tolist()
    return body


def check_skeleton_params(fps: float, max_frames: int, encoding: str = "json") -> None:
    if not (np.isfinite(fps) and MIN_FPS <= fps <= MAX_FPS):
        raise InvalidInput(f"fps: must be between {MIN_FPS:g} and {MAX_FPS:g}, got {fps:g}")
    if not 1 <= max_frames <= MAX_SKELETON_FRAMES:
        raise InvalidInput(
            f"max_frames: must be between 1 and {MAX_SKELETON_FRAMES}, got {max_frames}"
        )
    if encoding not in ENCODINGS:
        raise InvalidInput(f"encoding: must be one of {', '.join(ENCODINGS)}, got {encoding!r}")


def _full_rate(library: Library, cache: SkeletonCache, clip: clip_db.ClipRecord) -> DisplayMotion:
    return cache.motions.get_or_compute(
        (clip.id, clip.content_hash), lambda: display_motion(read_stored_motion(library, clip))
    )


def stored_preview(
    library: Library, cache: SkeletonCache, clip: clip_db.ClipRecord
) -> DisplayMotion:
    """The clip's motion at :data:`STORE_FPS`: from memory, else from the preview store, else
    read from its file (and stored for next time)."""
    version = preview_version(library)
    key = (clip.content_hash, version)

    def load_or_make() -> DisplayMotion:
        store = cache.store
        found = store.load(*key) if store is not None else None
        if found is not None:
            return found
        made = at_store_rate(_full_rate(library, cache, clip))
        if store is not None:
            store.save(*key, made)
        return made

    return cache.previews.get_or_compute(key, load_or_make)


def clip_skeleton(
    library: Library,
    cache: SkeletonCache,
    clip: clip_db.ClipRecord,
    fps: float,
    max_frames: int,
    *,
    start: float | None = None,
    end: float | None = None,
    encoding: str = "json",
) -> Skeleton:
    """The encoded skeleton response of a stored clip (cached); ``start``/``end`` in seconds
    of the file (lead-in included)."""
    check_skeleton_params(fps, max_frames, encoding)
    if not clip.files:
        raise NoStoredFile(clip.id, clip.format)
    span: tuple[int, int] | None = None
    if start is not None or end is not None:
        span = span_frames(clip.frame_count, clip.frame_time, clip.lead_in_frames, start, end)
    key = (clip.id, clip.content_hash, fps, max_frames, span, encoding)

    def compute() -> Skeleton:
        if fps <= STORE_FPS * RATE_SLACK:
            display = stored_preview(library, cache, clip)
        else:
            display = _full_rate(library, cache, clip)
        first, last = 0.0, None
        if span is not None:
            first = (span[0] - clip.lead_in_frames) * clip.frame_time
            last = (span[1] - 1 - clip.lead_in_frames) * clip.frame_time
        payload = skeleton_payload(
            display,
            clip_id=clip.id,
            fps=fps,
            max_frames=max_frames,
            start=first,
            end=last,
            encoding=encoding,
        )
        tag_text = f"{SKELETON_FORMAT_VERSION}:{preview_version(library)}:{key}"
        tag = hashlib.sha256(tag_text.encode()).hexdigest()[:32]
        return Skeleton(_encode(payload), f'"{tag}"')

    return cache.responses.get_or_compute(key, compute)


def upload_skeleton(
    upload: Upload,
    limits: ParseLimits,
    fps: float,
    max_frames: int,
    parsers: ParserPool | None = None,
    encoding: str = "json",
) -> bytes:
    """The encoded skeleton response of an uploaded clip (nothing stored, nothing cached)."""
    check_skeleton_params(fps, max_frames, encoding)
    display = upload_display_motion(upload, limits, parsers)
    payload = skeleton_payload(
        display, clip_id=None, fps=fps, max_frames=max_frames, encoding=encoding
    )
    return _encode(payload)


def _encode(payload: dict[str, Any]) -> bytes:
    return json.dumps(payload, separators=(",", ":"), allow_nan=False).encode()
