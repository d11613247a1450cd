"""Stick-figure previews of clips: canonical joints per frame in a display frame.

A stored clip is read again from its stored file(s) and run through the motion core (parse ->
:func:`~app.motion.body.build_body`, so converter lead-in frames are dropped as for the
descriptors). The canonical joints are put in a *display frame*: lengths in body heights, y up
(the file's vertical axis, see :func:`display_up`), the pelvis's floor point at the first
frame at the origin (floor = the 5th percentile over frames of each frame's lowest joint, so a
wild frame cannot move it), facing +z at the first frame (x is then the subject's left).
Frames are resampled to the requested rate by linear interpolation in time and cut after
:data:`MAX_SKELETON_FRAMES`.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from typing import Any

import numpy as np

from app.db import repository as repo
from app.errors import InvalidInput, NoStoredFile, ParseError
from app.motion.body import Body, build_body
from app.motion.model import Motion, ParseLimits
from app.motion.skeleton_map import CANONICAL_BONES, CANONICAL_INDEX, CANONICAL_JOINTS
from app.services.clips import stored_upload
from app.services.describe import read_motion
from app.services.library import Library
from app.services.lru import LRUCache
from app.services.parser_pool import ParserPool
from app.services.uploads import Upload

MAX_SKELETON_FRAMES = 600
"""Most frames one skeleton response carries; longer clips are truncated (``truncated``)."""
MIN_FPS, MAX_FPS, DEFAULT_FPS = 1, 120, 30
DECIMALS = 4
"""Joint coordinates are rounded to this many decimals of a body height (0.1 mm at 1.7 m)."""
SKELETON_FORMAT_VERSION = 1
"""Changes whenever the numbers a skeleton response carries change (part of its ETag)."""


@dataclass(frozen=True, eq=False)
class DisplayMotion:
    """A clip's canonical joints in the display frame at the file's own frame rate."""

    positions: np.ndarray  # (F, C, 3) body heights; y up, facing +z at frame 0
    frame_time: float
    lead_in_frames: int


@dataclass(frozen=True)
class Skeleton:
    """One skeleton response, already encoded (``body`` is JSON bytes)."""

    body: bytes
    etag: str


class SkeletonCache:
    """Per-application caches: display motions by (clip id, content hash), responses by
    (clip id, content hash, fps, max frames)."""

    def __init__(self, motions: int = 8, responses: int = 64) -> None:
        self.motions: LRUCache[tuple[int, str], DisplayMotion] = LRUCache(motions)
        self.responses: LRUCache[tuple[int, str, int, int], Skeleton] = LRUCache(responses)


def display_up(world_up: np.ndarray) -> np.ndarray:
    """The coordinate axis nearest to the body's ``world_up``, as a unit vector.

    Mocap files are authored with an axis up. ``Body.world_up`` snaps to an axis only within
    30 degrees; clips whose body leans more on average (Bandai's dashes and sad side-steps,
    35-39 degrees) keep a tilted up there, which would make a figure drift upwards as it
    travels. A picture needs the true vertical, so it always snaps.
    """
    vector = np.asarray(world_up, dtype=float)
    axis = int(np.argmax(np.abs(vector)))
    up = np.zeros(3)
    up[axis] = 1.0 if vector[axis] >= 0 else -1.0
    return up


# Percentile over frames of each frame's lowest joint that sets the preview's floor.
_FLOOR_PERCENTILE = 5.0


def display_positions(body: Body) -> np.ndarray:
    """``(F, C, 3)`` canonical joint positions in the display frame (see module docstring).

    Axes: x = the subject's left at the first frame, y = up (:func:`display_up`), z = the
    subject's forward at the first frame projected on the floor; a proper rotation of the
    file's world (no mirroring), then divided by body height.
    """
    up = display_up(body.world_up)
    frame0 = body.pelvis_frames[0]

    def horizontal(v: np.ndarray) -> np.ndarray:
        return np.asarray(v - np.dot(v, up) * up, dtype=float)

    forward = horizontal(frame0[:, 2])
    if np.linalg.norm(forward) > 1e-6:
        z = forward / np.linalg.norm(forward)
        x = np.cross(up, z)
    else:  # lying face down or up at the first frame: face by the hips instead
        left = horizontal(frame0[:, 0])
        if np.linalg.norm(left) < 1e-6:
            left = horizontal(np.eye(3)[int(np.argmin(np.abs(up)))])
        x = left / np.linalg.norm(left)
        z = np.cross(x, up)
    basis = np.stack([x, up, z], axis=1)  # columns: display axes in world coordinates
    pelvis0 = body.positions[0, CANONICAL_INDEX["pelvis"]]
    # Robust: the lowest point of most frames, so a frame gone wild (a sentinel value kept
    # in the middle of a clip) cannot lift the figure far above the floor.
    floor = float(np.percentile((body.positions @ up).min(axis=1), _FLOOR_PERCENTILE))
    origin = horizontal(pelvis0) + floor * up
    return np.asarray(((body.positions - origin) @ basis) / body.height)


def resample(
    positions: np.ndarray, frame_time: float, fps: int, max_frames: int
) -> tuple[np.ndarray, bool]:
    """Frames at ``fps`` by linear interpolation in time, at most ``max_frames`` of them.

    Returns the ``(F', C, 3)`` frames and whether the clip was cut short.
    """
    count = positions.shape[0]
    duration = (count - 1) * frame_time
    # Files round their frame time (0.008333 for 1/120 s): a relative slack of 1e-4 keeps
    # the last frame, and output times within 1/1000 of a source frame take that frame.
    wanted = int(np.floor(duration * fps * (1 + 1e-4) + 1e-6)) + 1
    truncated = wanted > max_frames
    n = min(wanted, max_frames)
    source = np.arange(n) / fps / frame_time  # fractional source frame of each output frame
    nearest = np.round(source)
    source = np.where(np.abs(source - nearest) < 1e-3, nearest, source)
    low = np.clip(np.floor(source).astype(np.int64), 0, count - 1)
    high = np.minimum(low + 1, count - 1)
    weight = np.clip(source - low, 0.0, 1.0)[:, None, None]
    return positions[low] * (1.0 - weight) + positions[high] * weight, truncated


def read_stored_motion(library: Library, clip: repo.ClipRecord) -> Motion:
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
    body = build_body(motion)
    return DisplayMotion(display_positions(body), body.frame_time, body.lead_in_frames)


def skeleton_payload(
    display: DisplayMotion, *, clip_id: int | None, fps: int, max_frames: int
) -> dict[str, Any]:
    """The skeleton response (see ``GET /clips/{id}/skeleton``) as plain JSON values."""
    frames, truncated = resample(display.positions, display.frame_time, fps, max_frames)
    source_frames = display.positions.shape[0]
    return {
        "clip_id": clip_id,
        "fps": fps,
        "frame_count": int(frames.shape[0]),
        "truncated": truncated,
        "duration": round((frames.shape[0] - 1) / fps, 6),
        "source_frame_count": int(source_frames),
        "source_duration": round((source_frames - 1) * display.frame_time, 6),
        "lead_in_frames": display.lead_in_frames,
        "units": "body heights",
        "joints": list(CANONICAL_JOINTS),
        "bones": [list(b) for b in CANONICAL_BONES],
        "frames": np.round(frames, DECIMALS).tolist(),
    }


def check_skeleton_params(fps: int, max_frames: int) -> None:
    if not MIN_FPS <= fps <= MAX_FPS:
        raise InvalidInput(f"fps: must be between {MIN_FPS} and {MAX_FPS}, got {fps}")
    if not 1 <= max_frames <= MAX_SKELETON_FRAMES:
        raise InvalidInput(
            f"max_frames: must be between 1 and {MAX_SKELETON_FRAMES}, got {max_frames}"
        )


def clip_skeleton(
    library: Library, cache: SkeletonCache, clip: repo.ClipRecord, fps: int, max_frames: int
) -> Skeleton:
    """The encoded skeleton response of a stored clip (cached)."""
    check_skeleton_params(fps, max_frames)
    key = (clip.id, clip.content_hash, fps, max_frames)

    def compute() -> Skeleton:
        display = cache.motions.get_or_compute(
            (clip.id, clip.content_hash),
            lambda: display_motion(read_stored_motion(library, clip)),
        )
        payload = skeleton_payload(display, clip_id=clip.id, fps=fps, max_frames=max_frames)
        tag = hashlib.sha256(f"{SKELETON_FORMAT_VERSION}:{key}".encode()).hexdigest()[:32]
        return Skeleton(_encode(payload), f'"{tag}"')

    return cache.responses.get_or_compute(key, compute)


def upload_skeleton(
    upload: Upload,
    limits: ParseLimits,
    fps: int,
    max_frames: int,
    parsers: ParserPool | None = None,
) -> bytes:
    """The encoded skeleton response of an uploaded clip (nothing stored, nothing cached)."""
    check_skeleton_params(fps, max_frames)
    display = upload_display_motion(upload, limits, parsers)
    return _encode(skeleton_payload(display, clip_id=None, fps=fps, max_frames=max_frames))


def _encode(payload: dict[str, Any]) -> bytes:
    return json.dumps(payload, separators=(",", ":"), allow_nan=False).encode()
