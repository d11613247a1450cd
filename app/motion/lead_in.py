"""Frames at the ends of a clip that are not its motion.

* Lead-in: converters of CMU data prepend the rest pose (:func:`count_lead_in_frames`).
* Implausible frames: joints no body can reach, a root that teleports
  (:func:`implausible_frames`); those at either end are cut like lead-in frames
  (:func:`plausible_span`).

Pure numpy over a :class:`~app.motion.model.Motion`'s local rotations or ``(F, C, 3)``
canonical joint positions.
"""

from __future__ import annotations

import numpy as np

from app.errors import ParseError
from app.motion.model import Motion
from app.motion.skeleton_map import CANONICAL_INDEX

# A clip starts from the rest pose when its first frame's local rotations (non-root joints)
# are on average within this angle of the identity.
_REST_MEAN_ANGLE_DEG = 5.0
# A converter's jump or blend from the rest pose into the motion lasts at most this long...
_MAX_BLEND_SECONDS = 0.1
# ...and changes the pose this many times faster than the clip's median frame-to-frame change.
_BLEND_SPEED_FACTOR = 2.0
# A joint this many body heights from the pelvis is a sentinel value, not a pose...
_MAX_REACH = 3.0
# ...and a pelvis jumping this many body heights from one frame to the next teleports.
_TELEPORT = 2.0


# Frame-to-frame turns below this (radians) are a held pose: arccos of a rounded 1 is ~2e-8.
_STILL_RADIANS = 1e-6


def count_lead_in_frames(motion: Motion) -> int:
    """Number of converter-added frames at the start of ``motion``.

    Converters of CMU data prepend the rest pose: MotionBuilder one T-pose frame, then a jump
    into the motion; DAZ a T-pose that blends into the motion over about four frames. Both
    show as a first frame near the rest pose (mean local rotation of the non-root joints
    within 5 degrees of the identity) followed by frame-to-frame pose changes far above the
    median of the clip's moving frames (frames held still do not count: a long hold would
    make every move look like a jump). Such leading frames are dropped while the change stays
    above twice that median, for at most 0.1 s and never more than half of the clip.
    """
    frames = motion.frame_count
    if frames < 4:
        return 0
    local = motion.local_rotations[:, 1:]
    trace0 = np.trace(local[0], axis1=-2, axis2=-1)
    mean_angle0 = np.degrees(np.arccos(np.clip((trace0 - 1.0) / 2.0, -1.0, 1.0))).mean()
    if mean_angle0 > _REST_MEAN_ANGLE_DEG:
        return 0
    change = _pose_change(local)
    # What moving looks like in this clip: frames held exactly still (an idle, a hold) are
    # no evidence of it, and a long hold must not make every move look like a jump.
    moving = change[change > _STILL_RADIANS]
    typical = float(np.median(moving)) if len(moving) else 0.0
    threshold = _BLEND_SPEED_FACTOR * max(typical, _STILL_RADIANS)
    limit = min(frames // 2, max(1, round(_MAX_BLEND_SECONDS / motion.frame_time)))
    lead_in = 0
    while lead_in < limit and change[lead_in] > threshold:
        lead_in += 1
    return lead_in


def _pose_change(local: np.ndarray) -> np.ndarray:
    """``(F-1,)`` largest rotation angle between consecutive frames over joints, radians."""
    relative_trace = np.einsum("fjab,fjab->fj", local[:-1], local[1:])
    cos_angle = np.clip((relative_trace - 1.0) / 2.0, -1.0, 1.0)
    return np.arccos(cos_angle.min(axis=1))


def implausible_frames(positions: np.ndarray, height: float) -> np.ndarray:
    """``(F,)`` bool: frames no body can take.

    ``positions`` is ``(F, C, 3)`` canonical joints. A frame is implausible when a joint is
    more than :data:`_MAX_REACH` body heights from the pelvis (a rigid skeleton cannot; per-
    joint position channels holding sentinel values can), or when it lies outside the
    longest stretch of frames without a teleport, a pelvis jump of more than
    :data:`_TELEPORT` body heights between two frames (a root thrown to a sentinel position
    and back). A subject walking far away is not a teleport: each step is small.
    """
    pelvis = positions[:, CANONICAL_INDEX["pelvis"]]
    reach = np.linalg.norm(positions - pelvis[:, None], axis=2).max(axis=1) / height
    jumps = np.linalg.norm(np.diff(pelvis, axis=0), axis=1) / height > _TELEPORT
    starts = [0, *(np.flatnonzero(jumps) + 1).tolist()]
    ends = [*starts[1:], len(pelvis)]
    # Stretches that continue one another (the root came back from its excursion) form one
    # trajectory; the one with the most frames is the clip.
    group_of: list[int] = []
    group_end: list[int] = []  # last frame of each trajectory so far
    for start, end in zip(starts, ends, strict=True):
        for g, last in enumerate(group_end):
            step = np.linalg.norm(pelvis[start] - pelvis[last]) / height
            if step <= _TELEPORT * (start - last):
                group_of.append(g)
                group_end[g] = end - 1
                break
        else:
            group_of.append(len(group_end))
            group_end.append(end - 1)
    frames_in = np.zeros(len(group_end), dtype=np.int64)
    for g, start, end in zip(group_of, starts, ends, strict=True):
        frames_in[g] += end - start
    main = int(np.argmax(frames_in))
    outside = np.ones(len(pelvis), dtype=bool)
    for g, start, end in zip(group_of, starts, ends, strict=True):
        if g == main:
            outside[start:end] = False
    return np.asarray((reach > _MAX_REACH) | outside)


def plausible_span(implausible: np.ndarray) -> tuple[int, int]:
    """``(start, stop)`` without the implausible runs at both ends (whole clip if none is
    plausible: then there is nothing sensible to keep, and the error is elsewhere)."""
    plausible = np.flatnonzero(~implausible)
    if len(plausible) == 0:
        raise ParseError("every frame is implausible (joints far from the body)")
    return int(plausible[0]), int(plausible[-1]) + 1
