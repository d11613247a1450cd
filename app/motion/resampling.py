"""A clip at another frame rate: rotations slerped, translations interpolated linearly.

The output has exactly ``fps`` frames per second and keeps the clip's first and last frames:
``K = round(duration * fps) + 1`` frames spread evenly from the first frame to the last, so
the clip's playing time changes by less than half an output frame (at most a few
milliseconds), never its start or end pose.
"""

from __future__ import annotations

import numpy as np

from app.motion.model import Motion

MIN_FPS = 1.0
MAX_FPS = 1000.0


def sample_times(frame_count: int, frame_time: float, fps: float) -> np.ndarray:
    """``(K,)`` fractional source-frame positions of the output frames (first 0, last
    ``frame_count - 1``)."""
    if frame_count < 2:
        return np.zeros(max(frame_count, 1))
    duration = (frame_count - 1) * frame_time
    count = max(2, int(np.floor(duration * fps + 0.5)) + 1)
    return np.linspace(0.0, frame_count - 1.0, count)


def slerp_frames(rotations: np.ndarray, at: np.ndarray) -> np.ndarray:
    """``(K, J, 3, 3)`` rotations ``(F, J, 3, 3)`` slerped at fractional frames ``at``
    ``(K,)`` (each joint along the shortest arc between the two frames around it)."""
    # SciPy's rotations here only (~0.3 s to import): not at every server start.
    from scipy.spatial.transform import Rotation

    frames, joints = rotations.shape[:2]
    lower = np.clip(np.floor(at).astype(np.int64), 0, max(frames - 2, 0))
    upper = np.minimum(lower + 1, frames - 1)
    u = np.clip(at - lower, 0.0, 1.0)
    a = Rotation.from_matrix(rotations[lower].reshape(-1, 3, 3))
    b = Rotation.from_matrix(rotations[upper].reshape(-1, 3, 3))
    step = (a.inv() * b).as_rotvec() * np.repeat(u, joints)[:, None]
    out = (a * Rotation.from_rotvec(step)).as_matrix().reshape(len(at), joints, 3, 3)
    # Frames that fall on a source frame are that frame exactly (no round trip through
    # quaternions): the first and last frames, and every frame of an unchanged rate.
    exact = np.abs(at - np.round(at)) < 1e-9
    out[exact] = rotations[np.round(at[exact]).astype(np.int64)]
    return out


def lerp_frames(values: np.ndarray, at: np.ndarray) -> np.ndarray:
    """``(K, ...)`` linear interpolation of ``(F, ...)`` values at fractional frames ``at``."""
    frames = values.shape[0]
    lower = np.clip(np.floor(at).astype(np.int64), 0, max(frames - 2, 0))
    upper = np.minimum(lower + 1, frames - 1)
    u = np.clip(at - lower, 0.0, 1.0).reshape(-1, *([1] * (values.ndim - 1)))
    return values[lower] * (1.0 - u) + values[upper] * u


def resample_to_rate(motion: Motion, fps: float) -> Motion:
    """``motion`` at ``fps`` frames per second (see the module docstring).

    Raises
    ------
    ValueError
        ``fps`` outside ``[MIN_FPS, MAX_FPS]``.
    """
    if not MIN_FPS <= fps <= MAX_FPS:
        raise ValueError(f"fps must be between {MIN_FPS:g} and {MAX_FPS:g}, got {fps:g}")
    at = sample_times(motion.frame_count, motion.frame_time, fps)
    return Motion(
        skeleton=motion.skeleton,
        frame_time=1.0 / fps,
        root_translation=lerp_frames(motion.root_translation, at),
        local_rotations=slerp_frames(motion.local_rotations, at),
        local_translations=None
        if motion.local_translations is None
        else lerp_frames(motion.local_translations, at),
        source_format=motion.source_format,
        length_unit=motion.length_unit,
        notes=dict(motion.notes),
    )


__all__ = ["MAX_FPS", "MIN_FPS", "resample_to_rate", "sample_times"]
