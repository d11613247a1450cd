"""``motion``: our descriptor — where the limbs point, how each body part moves, and how the
body travels, each measured so that a different actor, style or skeleton changes it little.

Both papers say what they miss: posture variation ignores locomotion and speed, kinetic
energy ignores the direction of travel; and joint-offset features change when a converter
changes the skeleton's proportions. This descriptor concatenates five blocks, each computed
in the pelvis-fixed body frame of :mod:`app.motion.body` (x = left, y = up, z = forward):

``limbs`` (60 numbers, dimensionless)
    Unit direction of ten segments — left/right upper arm, forearm, thigh and shin, the
    trunk (pelvis -> neck) and the head (neck -> head) — mean and population std over
    frames of each of the three components. Directions, not offsets, so bone lengths and
    proportions (a DAZ generic figure vs the CMU subject) matter little.
``energy`` (50 numbers)
    The ``kinetic`` descriptor: log(mean ω² + 1) per joint DOF plus root speeds.
``parts`` (16 numbers)
    Each joint's share of the body's kinetic energy (its three DOFs summed, divided by the
    sum over the 16 joints), as ``log(share + 1e-4)``. A style makes a whole motion more or
    less vigorous (tired, active, giant); which parts carry the motion is the action's.
``travel`` (8 numbers)
    Root motion in the body's own heading frame (the floor direction square to the hips'
    axis, see :func:`heading_frames`): mean
    forward and lateral velocity (signed: walking back or to the left is negative forward /
    positive lateral), mean signed turning rate (rad/s, positive = turning left), mean
    horizontal speed, std of forward and lateral velocity, rms vertical velocity and the
    net displacement per second — velocities in *leg lengths* per second (hip -> knee ->
    ankle). How far a step carries a body is set by its legs (gaits of different sizes are
    compared by speed over leg length, the Froude number's length), not by its trunk and
    head, whose share of the height differs between characters: a clip retargeted onto a
    short-legged cartoon rig travels as far as that rig's legs carry it, and in body heights
    it would look a slower walk. The energy block's two root terms are in leg lengths per
    second too (the ``kinetic`` descriptor itself keeps the paper's body heights).
``sideways`` (1 number)
    The sideways part of the direction of travel: mean lateral velocity divided by mean
    horizontal speed, times ``s² / (s² + 0.3²)`` for mean speed ``s`` in leg lengths per
    second. It tells walking to the side from walking ahead whatever the speed (which is
    the style's), and fades out below 0.3 leg lengths (about 0.2 body heights) per second,
    where a clip stands rather than travels and the direction of a drift means nothing.
    Forward vs backward is already in the signed forward velocity.

Each block is divided by a fixed scale (the square root of the block's summed per-dimension
variance over the reference corpus — Bandai dataset 1 and the CMU clips of ``../shared/data``
— computed once by ``bench/motion_scales.py`` and frozen here with the descriptor's version)
and multiplied by a fixed block weight, so no block dominates by its units and a clip's
vector never depends on which other clips are in a library. What was tried and why these
weights: ``docs/evaluation.md``.

Every number is a mean (or a function of means) of per-frame quantities, so any span of
frames is described in O(1) after one pass over the clip (:mod:`app.motion.spans`).

Still is a valid value of every block, and every vector is finite by construction (a hold,
an idle, a motionless finger rig, a one- or two-frame clip):

* means of energies, speeds and squares are exactly 0 over still frames, never a rounding
  residue of either sign (:mod:`app.motion.spans`); standard deviations are clamped at 0;
* ``parts`` of a body that does not move at all (total energy exactly 0): every part's share
  is ``1/16``. A still body says nothing about which part carries the motion, so no part is
  favoured; the value is the centre of the shares a barely moving body takes, so a still
  window sits among near-still ones rather than apart from them. Shares are otherwise in
  ``[0, 1]`` and the floor keeps the logarithm finite;
* ``travel``: a still body has zero velocities, turning rate and displacement; the heading
  of a body lying on its back or front, or bent over, is its lateral axis turned about the
  vertical (version 5; before, its forward's short floor part, which turned with every
  breath); ``sideways`` divides by the mean speed only through the gate, which is 0 at
  speed 0;
* ``limbs``: a segment of zero length (two canonical joints at one point) has direction 0.
"""

from __future__ import annotations

import numpy as np

from app.motion.body import Body
from app.motion.descriptors import Descriptor, whole_clip_vector
from app.motion.descriptors.kinetic import (
    KINETIC_JOINTS,
    energy_samples,
    kinetic_from_energies,
)
from app.motion.skeleton_map import CANONICAL_INDEX
from app.motion.spans import RunningMeans, std_from_moments

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

LIMBS_DIMENSION = len(LIMB_SEGMENTS) * 6
ENERGY_DIMENSION = len(KINETIC_JOINTS) * 3 + 2
PARTS_DIMENSION = len(KINETIC_JOINTS)
TRAVEL_DIMENSION = 8
SIDEWAYS_DIMENSION = 1

# Energy shares below this are noise, not a part that moves.
PART_SHARE_FLOOR = 1e-4
# Below this mean horizontal speed (leg lengths/s) a clip stands rather than travels.
TRAVEL_SPEED = 0.3

# Frozen block scales (reference corpus, see module docstring) and block weights.
# Scales: `bench/motion_scales.py` on Bandai dataset 1 + CMU (263 clips; version 3).
BLOCK_SCALES = {
    "limbs": 1.39,
    "energy": 4.03,
    "parts": 5.71,
    "travel": 2.08,
    "sideways": 0.142,
}
# Weights: energy and travel count fully; limb directions, the block most affected by how a
# converter poses a skeleton, at half weight; the two style-independent blocks (parts,
# sideways) at half weight. The ablation behind them is in docs/evaluation.md.
BLOCK_WEIGHTS = {"limbs": 0.5, "energy": 1.0, "parts": 0.5, "travel": 1.0, "sideways": 0.5}


def limb_directions(body: Body) -> np.ndarray:
    """``(F, 10, 3)`` unit direction of each limb segment in the body frame."""
    relative = body.positions[:, _SEGMENT_TO] - body.positions[:, _SEGMENT_FROM]
    local = relative @ body.pelvis_frames
    norms = np.linalg.norm(local, axis=2, keepdims=True)
    return local / np.maximum(norms, 1e-12)


def limb_spans(body: Body, spans: np.ndarray) -> np.ndarray:
    """``(W, 60)`` mean then std over each span's frames of the limb unit directions."""
    directions = limb_directions(body).reshape(body.frame_count, -1)
    half = directions.shape[1]
    moments = RunningMeans(np.concatenate([directions, directions**2], axis=1)).mean(
        spans[:, 0], spans[:, 1]
    )
    mean, mean_square = moments[:, :half], moments[:, half:]
    return np.concatenate([mean, std_from_moments(mean, mean_square)], axis=1)


def parts_from_energies(joints: np.ndarray) -> np.ndarray:
    """``(W, 16)`` log share of each kinetic joint in the body's kinetic energy, from the
    ``(W, 16, 3)`` mean energies per joint DOF (>= 0). A span where nothing moves (total
    exactly 0) has equal shares, ``1/16`` (see the module docstring)."""
    per_joint = joints.sum(axis=2)
    total = per_joint.sum(axis=1, keepdims=True)
    share = np.where(total > 0, per_joint / np.maximum(total, 1e-300), 1.0 / per_joint.shape[1])
    return np.log(share + PART_SHARE_FLOOR)


def heading_frames(body: Body) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame floor-plane heading: ``(F, 3)`` forward and ``(F, 3)`` left unit vectors.

    The heading is the floor direction square to the lateral (hip to hip) axis, which a
    body keeps when it bends, falls or lies on its back or front (a turn about that axis): a
    body lying on its back, whose forward points at the sky, heads where it faced before it
    fell, and its heading is as steady as its hips. Where the lateral axis stands near
    vertical (a body on its side, a cartwheel) its floor part is short, and the forward
    axis's floor part, long there, takes over in the measure the lateral's is lost. An
    upright body's heading is its forward's either way."""
    up = body.world_up
    lateral = body.pelvis_frames[:, :, 0]
    forward = body.pelvis_frames[:, :, 2]
    from_lateral = np.cross(lateral, up)  # length: the lateral axis's floor part
    level = np.linalg.norm(from_lateral, axis=1, keepdims=True)
    from_forward = forward - (forward @ up)[:, None] * up
    heading = from_lateral + (1.0 - np.minimum(level, 1.0)) * from_forward
    norms = np.linalg.norm(heading, axis=1, keepdims=True)
    # The two cancel only upside down and on the side at once: the forward's floor part then.
    heading = np.where(norms > 1e-6, heading, from_forward)
    heading /= np.maximum(np.linalg.norm(heading, axis=1, keepdims=True), 1e-12)
    left = np.cross(up, heading)
    return heading, left


def leg_length(body: Body) -> float:
    """Length of the legs in file units: hip -> knee -> ankle, the two sides averaged (the
    median over frames; the bones are rigid). A body whose legs have no length (a rig whose
    leg joints coincide) falls back to its height."""
    legs = np.mean(
        [
            np.linalg.norm(body.joint(f"{s}_knee") - body.joint(f"{s}_hip"), axis=1)
            + np.linalg.norm(body.joint(f"{s}_ankle") - body.joint(f"{s}_knee"), axis=1)
            for s in "lr"
        ],
        axis=0,
    )
    length = float(np.median(legs)) if len(legs) else 0.0
    return length if length > 1e-3 * body.height else body.height


def body_leg_length(body: Body) -> float:
    """:func:`leg_length`, computed once per body."""
    return body.memo("motion.leg_length", lambda: leg_length(body))


class TravelSamples:
    """Per-sample root motion in the heading frame; sample ``i`` spans frames ``i .. i+h``
    with ``h`` the kinetic velocity span."""

    def __init__(self, body: Body) -> None:
        self.span = energy_samples(body).span
        self.frame_time = body.frame_time
        self.up = body.world_up
        self.pelvis = body.joint("pelvis") / body_leg_length(body)
        h = self.span
        if body.frame_count < 2:
            samples = np.zeros((0, 7))
        else:
            seconds = h * body.frame_time
            velocity = (self.pelvis[h:] - self.pelvis[:-h]) / seconds
            forward, left = heading_frames(body)
            v_forward = np.einsum("fa,fa->f", velocity, forward[:-h])
            v_left = np.einsum("fa,fa->f", velocity, left[:-h])
            v_up = velocity @ self.up
            # Signed yaw change of the heading about the up axis over the span.
            sin_turn = np.cross(forward[:-h], forward[h:]) @ self.up
            cos_turn = np.einsum("fa,fa->f", forward[:-h], forward[h:])
            turn_rate = np.arctan2(sin_turn, cos_turn) / seconds
            samples = np.stack(
                [
                    v_forward,
                    v_left,
                    turn_rate,
                    np.hypot(v_forward, v_left),
                    v_forward**2,
                    v_left**2,
                    v_up**2,
                ],
                axis=1,
            )
        self.samples = RunningMeans(samples)

    def travel(self, spans: np.ndarray) -> np.ndarray:
        """``(W, 8)`` the travel block of each span (see module docstring)."""
        starts, stops = spans[:, 0], spans[:, 1]
        means = self.samples.mean(starts, stops - self.span)
        v_forward, v_left, turn, speed = means[:, 0], means[:, 1], means[:, 2], means[:, 3]
        last = np.maximum(stops - 1, starts)
        displacement = self.pelvis[last] - self.pelvis[starts]
        horizontal = displacement - (displacement @ self.up)[:, None] * self.up
        duration = (last - starts) * self.frame_time
        net_rate = np.where(
            duration > 0, np.linalg.norm(horizontal, axis=1) / np.maximum(duration, 1e-9), 0.0
        )
        return np.stack(
            [
                v_forward,
                v_left,
                turn,
                speed,
                std_from_moments(v_forward, means[:, 4]),
                std_from_moments(v_left, means[:, 5]),
                np.sqrt(means[:, 6]),
                net_rate,
            ],
            axis=1,
        )


def travel_samples(body: Body) -> TravelSamples:
    """The clip's :class:`TravelSamples`, computed once per body."""
    return body.memo("motion.travel_samples", lambda: TravelSamples(body))


def travel_spans(body: Body, spans: np.ndarray) -> np.ndarray:
    """``(W, 8)`` root trajectory features of each span in the heading frame."""
    return travel_samples(body).travel(spans)


def sideways_from_travel(travel: np.ndarray) -> np.ndarray:
    """``(W, 1)`` the sideways share of the direction of travel (see module docstring)."""
    v_left, speed = travel[:, 1], travel[:, 3]
    gate = speed**2 / (speed**2 + TRAVEL_SPEED**2)
    return (v_left / np.maximum(speed, 1e-9) * gate)[:, None]


def motion_blocks(body: Body, spans: np.ndarray) -> dict[str, np.ndarray]:
    """Each block's raw ``(W, block dimension)`` values, before scales and weights."""
    travel = travel_spans(body, spans)
    joints, root = energy_samples(body).mean_energies(spans)  # energy and parts share them
    root = root * (body.height / body_leg_length(body)) ** 2  # (body heights/s)² -> (legs/s)²
    return {
        "limbs": limb_spans(body, spans),
        "energy": kinetic_from_energies(joints, root),
        "parts": parts_from_energies(joints),
        "travel": travel,
        "sideways": sideways_from_travel(travel),
    }


def motion_spans(body: Body, spans: np.ndarray) -> np.ndarray:
    """``(W, 135)`` scaled and weighted blocks: limbs 60, energy 50, parts 16, travel 8,
    sideways 1."""
    blocks = motion_blocks(body, spans)
    return np.concatenate(
        [blocks[name] * (BLOCK_WEIGHTS[name] / BLOCK_SCALES[name]) for name in blocks], axis=1
    )


DESCRIPTOR = Descriptor(
    name="motion",
    dimension=LIMBS_DIMENSION
    + ENERGY_DIMENSION
    + PARTS_DIMENSION
    + TRAVEL_DIMENSION
    + SIDEWAYS_DIMENSION,
    version=5,
    description="The best all-round choice (the default): what the body does — where the "
    "limbs point, which parts move and how hard, and how the body travels (ahead, back, to "
    "the side, turning). Finds the same action across actors, styles and skeletons.",
    compute_spans=motion_spans,
)
compute_motion = whole_clip_vector(DESCRIPTOR)
