"""``posture``: posture-variation descriptor of Miura et al. (2013), exactly as in the paper.

"Consider the constellation of the joints and end effectors … shoulders, elbows, wrists,
fingers, knees, ankles, toes, neck and head. End effectors are hereafter regarded as
joints." and "The position of each joint is described in the coordinate system fixed to the
pelvis". Sixteen points — left/right shoulder, elbow, wrist, finger tip (``hand_tip``), knee,
ankle, toe, plus neck and head, where head, toes and finger tips are the end effectors the
skeleton has (:mod:`app.motion.skeleton_map`) — are expressed in the pelvis-fixed body frame
of :mod:`app.motion.body` (x = subject's left, y = up, z = forward, one set of axes per
skeleton found in its rest pose) and divided by body height, so every coordinate is
dimensionless. Per frame ``n`` the covariance of the joint coordinates with 1/J
normalisation gives six numbers ``f(n) = (σxx, σyy, σzz, σxy, σyz, σzx)`` (paper eq. 2); the
clip's vector is their mean over frames followed by their population standard deviation
(eq. 3): 12 numbers in units of (body heights)². Compared with the Euclidean distance.
Mirroring a motion left-to-right flips the sign of σxy and σzx only.

The paper: "where N is the number of frames and f̄ and s̄ are the mean and standard deviation
of f(n)'s". A still stretch, or a clip of one frame, is no special case: its frames share one
pose, so f̄ is that pose's covariance and s̄ is exactly 0 (rounding that would make the
variance a hair negative is clamped to 0, see :func:`~app.motion.spans.std_from_moments`).
Height is > 0 for every body (:func:`~app.motion.body.build_body` refuses a skeleton of zero
height), so every number is finite.
"""

from __future__ import annotations

import numpy as np

from app.motion.body import Body
from app.motion.descriptors import Descriptor, whole_clip_vector
from app.motion.skeleton_map import CANONICAL_INDEX
from app.motion.spans import RunningMeans, std_from_moments

POSTURE_JOINTS: tuple[str, ...] = (
    *(f"{s}_{p}" for s in ("l", "r") for p in ("shoulder", "elbow", "wrist", "hand_tip")),
    *(f"{s}_{p}" for s in ("l", "r") for p in ("knee", "ankle", "toe")),
    "neck",
    "head",
)
_POSTURE_INDEX = np.array([CANONICAL_INDEX[name] for name in POSTURE_JOINTS])


def posture_features(local_positions: np.ndarray) -> np.ndarray:
    """Per-frame covariance entries (paper eq. 1-2).

    Parameters
    ----------
    local_positions:
        ``(F, 16, 3)`` joint coordinates in the body frame, divided by body height.

    Returns
    -------
    ``(F, 6)`` columns σxx, σyy, σzz, σxy, σyz, σzx.
    """
    centred = local_positions - local_positions.mean(axis=1, keepdims=True)
    cov = np.einsum("fja,fjb->fab", centred, centred) / local_positions.shape[1]
    return np.stack(
        [cov[:, 0, 0], cov[:, 1, 1], cov[:, 2, 2], cov[:, 0, 1], cov[:, 1, 2], cov[:, 2, 0]],
        axis=1,
    )


def posture_spans(body: Body, spans: np.ndarray) -> np.ndarray:
    """``(W, 12)`` mean then population std of the per-frame features over each span.

    ``spans`` is ``(W, 2)`` frame ranges ``[start, stop)`` of ``body``.
    """
    features = posture_features(body.local_positions()[:, _POSTURE_INDEX])
    means = RunningMeans(np.concatenate([features, features**2], axis=1))
    moments = means.mean(spans[:, 0], spans[:, 1])
    mean, mean_square = moments[:, :6], moments[:, 6:]
    return np.concatenate([mean, std_from_moments(mean, mean_square)], axis=1)


DESCRIPTOR = Descriptor(
    name="posture",
    dimension=12,
    version=2,
    description="How the body is held: how spread out, tall or leaning the pose is on average "
    "and how much it varies, whatever the speed. Finds clips of similar stance (crouching, "
    "upright, arms out); blind to direction and speed of travel.",
    compute_spans=posture_spans,
)
compute_posture = whole_clip_vector(DESCRIPTOR)
