"""``posture``: posture-variation descriptor of Miura et al. (2013), exactly as in the paper.

Sixteen joints — left/right shoulder, elbow, wrist, finger tip (``hand_tip``), knee, ankle,
toe, plus neck and head — are expressed in the pelvis-fixed body frame (root translation and
rotation removed; x = subject's left, y = up, z = forward) and divided by body height, so
every coordinate is dimensionless. Per frame ``n`` the covariance of the joint coordinates
with 1/J normalisation gives six numbers ``f(n) = (σxx, σyy, σzz, σxy, σyz, σzx)`` (paper eq. 2);
the clip's vector is their mean over frames followed by their population standard
deviation (eq. 3): 12 numbers in units of (body heights)². Compared with the Euclidean
distance. Mirroring a motion left-to-right flips the sign of σxy and σzx only.
"""

from __future__ import annotations

import numpy as np

from app.motion.body import Body
from app.motion.descriptors import Descriptor
from app.motion.skeleton_map import CANONICAL_INDEX

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


def compute_posture(body: Body) -> np.ndarray:
    """``(12,)`` mean then population standard deviation of the per-frame features."""
    features = posture_features(body.local_positions()[:, _POSTURE_INDEX])
    return np.concatenate([features.mean(axis=0), features.std(axis=0)])


DESCRIPTOR = Descriptor(
    name="posture",
    dimension=12,
    version=1,
    description="Posture variation (Miura et al. 2013): mean and std of the 16-joint covariance "
    "in the pelvis frame, body-height units.",
    compute=compute_posture,
)
