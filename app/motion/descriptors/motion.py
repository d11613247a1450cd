"""``motion``: our descriptor — limb-direction posture, kinetic energy and root trajectory.

Both papers say what they miss: posture variation ignores locomotion and speed, kinetic
energy ignores the direction of travel; and joint-offset features change when a converter
changes the skeleton's proportions. This descriptor concatenates three blocks, each
computed in the pelvis-fixed body frame (x = left, y = up, z = forward):

``limbs`` (60 numbers, dimensionless)
    Unit direction of ten segments — left/right upper arm, forearm, thigh and shin, the
    trunk (pelvis -> neck) and the head (neck -> head) — mean and population std over
    frames of each of the three components. Directions, not offsets, so bone lengths and
    proportions (a DAZ generic figure vs the CMU subject) matter little.
``energy`` (50 numbers)
    The ``kinetic`` descriptor: log(mean ω² + 1) per joint DOF plus root speeds.
``travel`` (8 numbers)
    Root motion in the body's own heading frame (forward projected on the floor): mean
    forward and lateral velocity (signed: walking back or to the left is negative forward /
    positive lateral), mean signed turning rate (rad/s, positive = turning left), mean
    horizontal speed, std of forward and lateral velocity, rms vertical velocity and the
    net displacement per second — velocities in body heights per second.

Each block is divided by a fixed scale (the root-mean-square of the block's per-dimension
standard deviations over the reference corpus of ``bench/`` — Bandai dataset 1 and the CMU
clips in ``../shared/data``, computed once and frozen here with the descriptor's version) and
multiplied by a fixed block weight, so no block dominates by its units and a clip's vector
never depends on which other clips are in a library.
"""

from __future__ import annotations

import numpy as np

from app.motion.body import Body
from app.motion.descriptors import Descriptor
from app.motion.descriptors.kinetic import DESCRIPTOR as KINETIC
from app.motion.descriptors.kinetic import compute_kinetic, velocity_span
from app.motion.skeleton_map import CANONICAL_INDEX

LIMB_SEGMENTS: tuple[tuple[str, str], ...] = (
    *((f"{s}_shoulder", f"{s}_elbow") for s in "lr"),
    *((f"{s}_elbow", f"{s}_wrist") for s in "lr"),
    *((f"{s}_hip", f"{s}_knee") for s in "lr"),
    *((f"{s}_knee", f"{s}_ankle") for s in "lr"),
    ("pelvis", "neck"),
    ("neck", "head"),
)
_SEGMENT_FROM = np.array([CANONICAL_INDEX[a] for a, _ in LIMB_SEGMENTS])
_SEGMENT_TO = np.array([CANONICAL_INDEX[b] for _, b in LIMB_SEGMENTS])

KINETIC_DIMENSION = KINETIC.dimension
TRAVEL_DIMENSION = 8

# Frozen block scales (reference corpus, see module docstring) and block weights.
# Scales: `bench/motion_scales.py` on the 263 clips of ../shared/data (version 1).
BLOCK_SCALES = {"limbs": 1.4204, "energy": 3.98354, "travel": 1.31194}
# Weights: energy and travel count fully; limb directions, the block most affected by how a
# converter poses a skeleton, at half weight. The ablation behind it is in docs/evaluation.md.
BLOCK_WEIGHTS = {"limbs": 0.5, "energy": 1.0, "travel": 1.0}


def limb_block(body: Body) -> np.ndarray:
    """``(60,)`` mean then std over frames of the limb unit directions in the body frame."""
    relative = body.positions[:, _SEGMENT_TO] - body.positions[:, _SEGMENT_FROM]
    local = relative @ body.pelvis_frames
    norms = np.linalg.norm(local, axis=2, keepdims=True)
    directions = local / np.maximum(norms, 1e-12)
    return np.concatenate([directions.mean(axis=0).ravel(), directions.std(axis=0).ravel()])


def heading_frames(body: Body) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame floor-plane heading: ``(F, 3)`` forward and ``(F, 3)`` left unit vectors."""
    up = body.world_up
    forward = body.pelvis_frames[:, :, 2]
    forward = forward - (forward @ up)[:, None] * up
    norms = np.linalg.norm(forward, axis=1, keepdims=True)
    # Lying or bent so far that forward is vertical: fall back to the lateral axis turned.
    lateral = body.pelvis_frames[:, :, 0]
    fallback = np.cross(lateral, up)
    forward = np.where(norms > 1e-6, forward / np.maximum(norms, 1e-12), fallback)
    forward /= np.maximum(np.linalg.norm(forward, axis=1, keepdims=True), 1e-12)
    left = np.cross(up, forward)
    return forward, left


def travel_block(body: Body) -> np.ndarray:
    """``(8,)`` root trajectory features in the heading frame (see module docstring)."""
    frames = body.frame_count
    if frames < 2:
        return np.zeros(TRAVEL_DIMENSION)
    span = velocity_span(body.frame_time, frames)
    seconds = span * body.frame_time
    pelvis = body.joint("pelvis") / body.height
    velocity = (pelvis[span:] - pelvis[:-span]) / seconds
    forward, left = heading_frames(body)
    up = body.world_up
    v_forward = np.einsum("fa,fa->f", velocity, forward[:-span])
    v_left = np.einsum("fa,fa->f", velocity, left[:-span])
    v_up = velocity @ up
    horizontal_speed = np.hypot(v_forward, v_left)
    # Signed yaw change of the heading about the up axis over the span.
    sin_turn = np.einsum(
        "fa,fa->f", np.cross(forward[:-span], forward[span:]), np.tile(up, (len(v_up), 1))
    )
    cos_turn = np.einsum("fa,fa->f", forward[:-span], forward[span:])
    turn_rate = np.arctan2(sin_turn, cos_turn) / seconds
    duration = (frames - 1) * body.frame_time
    displacement = pelvis[-1] - pelvis[0]
    net_rate = np.linalg.norm(displacement - (displacement @ up) * up) / max(duration, 1e-9)
    return np.array(
        [
            v_forward.mean(),
            v_left.mean(),
            turn_rate.mean(),
            horizontal_speed.mean(),
            v_forward.std(),
            v_left.std(),
            np.sqrt((v_up**2).mean()),
            net_rate,
        ]
    )


def compute_motion(body: Body) -> np.ndarray:
    """``(118,)`` scaled and weighted limbs (60), energy (50) and travel (8) blocks."""
    blocks = {
        "limbs": limb_block(body),
        "energy": compute_kinetic(body),
        "travel": travel_block(body),
    }
    return np.concatenate(
        [blocks[name] * (BLOCK_WEIGHTS[name] / BLOCK_SCALES[name]) for name in blocks]
    )


DESCRIPTOR = Descriptor(
    name="motion",
    dimension=len(LIMB_SEGMENTS) * 6 + KINETIC_DIMENSION + TRAVEL_DIMENSION,
    version=1,
    description="mocap-index's own: limb directions, kinetic energy and body-frame root travel "
    "(direction, speed, turning), each block scaled by frozen corpus constants.",
    compute=compute_motion,
)
