"""A body's canonical joints in a *display frame*, for drawing stick figures.

Lengths in body heights, y up (the file's vertical axis, see :func:`display_up`), the
pelvis's floor point at the first frame at the origin (floor = the 5th percentile over frames
of each frame's lowest joint, so a wild frame cannot move it), facing +z at the first frame
(x is then the subject's left). Pure numpy: the service computes it where the
:class:`~app.motion.body.Body` is built (the describer, when a clip is stored; a preview
request, when none was stored), and the numbers are the same either way.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from app.motion.body import Body
from app.motion.skeleton_map import CANONICAL_INDEX

STORE_FPS = 30.0
"""Rate of the stored previews (:func:`at_store_rate`)."""
RATE_SLACK = 1.001  # files write 1/30 s as 0.0333333: their 30.0003 fps counts as 30

# Percentile over frames of each frame's lowest joint that sets the preview's floor.
_FLOOR_PERCENTILE = 5.0


@dataclass(frozen=True, eq=False)
class DisplayMotion:
    """A clip's canonical joints in the display frame.

    ``positions`` are ``(F, C, 3)`` body heights every ``frame_time`` seconds from the first
    frame after the lead-in; the file itself has ``source_frame_count`` frames after its
    ``lead_in_frames``, every ``source_frame_time`` seconds (the same numbers for a motion at
    the file's own rate).
    """

    positions: np.ndarray
    frame_time: float
    lead_in_frames: int
    source_frame_count: int
    source_frame_time: float

    @property
    def duration(self) -> float:
        return max(0, self.positions.shape[0] - 1) * self.frame_time


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


def body_display(body: Body) -> DisplayMotion:
    """``body``'s canonical joints in the display frame at the file's own rate."""
    positions = display_positions(body)
    return DisplayMotion(
        positions, body.frame_time, body.lead_in_frames, positions.shape[0], body.frame_time
    )


def resample(
    positions: np.ndarray,
    frame_time: float,
    fps: float,
    max_frames: int,
    start: float = 0.0,
    end: float | None = None,
) -> tuple[np.ndarray, bool]:
    """Frames at ``fps`` from ``start`` to ``end`` seconds (default: the last frame) by linear
    interpolation in time, at most ``max_frames`` of them.

    Returns the ``(F', C, 3)`` frames and whether the span was cut short.
    """
    count = positions.shape[0]
    last = (count - 1) * frame_time
    stop = last if end is None else min(end, last)
    # Files round their frame time (0.008333 for 1/120 s): a relative slack of 1e-4 keeps
    # the last frame, and output times within 1/1000 of a source frame take that frame.
    span = max(0.0, stop - start)
    wanted = int(np.floor(span * fps * (1 + 1e-4) + 1e-6)) + 1
    truncated = wanted > max_frames
    n = min(wanted, max_frames)
    source = (start + np.arange(n) / fps) / frame_time  # fractional source frame of each
    nearest = np.round(source)
    source = np.where(np.abs(source - nearest) < 1e-3, nearest, source)
    low = np.clip(np.floor(source).astype(np.int64), 0, count - 1)
    high = np.minimum(low + 1, count - 1)
    weight = np.clip(source - low, 0.0, 1.0)[:, None, None]
    return positions[low] * (1.0 - weight) + positions[high] * weight, truncated


def at_store_rate(display: DisplayMotion) -> DisplayMotion:
    """``display`` at :data:`STORE_FPS` (or its own rate when slower), float32: what a stored
    preview holds."""
    if display.frame_time * STORE_FPS * RATE_SLACK >= 1.0:  # its own rate
        frame_time, positions = display.frame_time, display.positions
    else:
        frame_time = 1.0 / STORE_FPS
        positions, _ = resample(display.positions, display.frame_time, STORE_FPS, 2**62)
    return replace(
        display, positions=np.ascontiguousarray(positions, np.float32), frame_time=frame_time
    )


def stored_preview_of(body: Body) -> DisplayMotion:
    """What a clip's stored preview holds, from its :class:`Body`: the display frame at
    :data:`STORE_FPS`, float32 (small: ~8 KB a second of motion)."""
    return at_store_rate(body_display(body))
