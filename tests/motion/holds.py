"""Exact still stretches made from real takes: a frame held for longer, as a capture that
holds a pose (an idle, a T-pose lead-out, a motionless rig) has one."""

from __future__ import annotations

import dataclasses

import numpy as np

from app.motion.body import Body
from app.motion.model import Motion


def _held_index(frames: int, at: int, extra: int) -> np.ndarray:
    return np.concatenate([np.arange(at + 1), np.full(extra, at), np.arange(at + 1, frames)])


def held(body: Body, at: int, extra: int) -> Body:
    """``body`` with frame ``at`` held ``extra`` frames longer (a fresh memo)."""
    index = _held_index(body.frame_count, at, extra)
    return dataclasses.replace(
        body,
        positions=body.positions[index],
        rotations=body.rotations[index],
        pelvis_frames=body.pelvis_frames[index],
        _memo={},
    )


def held_motion(motion: Motion, at: int, extra: int) -> Motion:
    """``motion`` with frame ``at`` held ``extra`` frames longer."""
    return frames_at(motion, _held_index(motion.frame_count, at, extra))


def frames_at(motion: Motion, index: np.ndarray) -> Motion:
    """``motion`` made of its frames ``index`` (``(F',)`` int or ``(F,)`` bool), in order."""
    return dataclasses.replace(
        motion,
        root_translation=motion.root_translation[index],
        local_rotations=motion.local_rotations[index],
        local_translations=None
        if motion.local_translations is None
        else motion.local_translations[index],
    )
