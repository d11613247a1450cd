"""The body's axes read from the frames when the rest pose is no figure of the body
(app/motion/body_axes.py): up from the world's up seen from the pelvis when the take stands."""

from __future__ import annotations

import numpy as np

from app.motion import transforms
from app.motion.body import build_body, pelvis_basis
from app.motion.kinematics import forward_kinematics
from app.motion.model import Motion
from app.motion.skeleton_map import CANONICAL_INDEX
from tests.motion.synthetic import walker_motion
from tests.motion.test_mapping_probes import own_axes


def _hunched_walk() -> tuple[Motion, np.ndarray]:
    """A walk bent forward 30 degrees at the spine in every frame, and its canonical joints."""
    walker = walker_motion(frames=60, fps=30.0)
    canonical = build_body(walker).mapping.joints  # type: ignore[union-attr]
    spine = int(canonical[CANONICAL_INDEX["spine"]])
    hunched = walker.local_rotations.copy()
    hunched[:, spine] = transforms.rotation_about([1.0, 0.0, 0.0], 30.0) @ hunched[:, spine]
    return transforms._replace(walker, local_rotations=hunched), canonical


def _least_agreement_with_its_copy_in_odd_axes(motion: Motion, canonical: np.ndarray) -> float:
    """cos of the largest angle, over the frames, between the body's up read from ``motion``'s
    rest pose (it stands) and read from the frames of a copy with every bone in axes of its
    own (a rest pose that is no figure)."""
    body = build_body(motion)
    copy = own_axes(motion)
    basis = pelvis_basis(copy, canonical, rest_is_a_figure=False)
    rotations, _ = forward_kinematics(copy, joints=canonical)
    up = rotations[:, canonical[CANONICAL_INDEX["pelvis"]]] @ basis[:, 1]  # (F, 3)
    return float(np.einsum("fa,fa->f", up, body.pelvis_frames[:, :, 1]).min())


def test_a_hunched_walk_in_odd_bone_axes_reads_up_from_the_standing_pelvis() -> None:
    # The frames' trunk leans with the spine, but the pelvis of a standing body stays near
    # level, so the body's up is the world's up seen from the pelvis, as the walker's own rest
    # pose puts it (docs/skeletons.md, "2026-11-27, the body's up from a take that stands").
    # Read from the trunk, it was 22 degrees off.
    walk, canonical = _hunched_walk()
    assert _least_agreement_with_its_copy_in_odd_axes(walk, canonical) > np.cos(np.radians(5.0))


def test_a_hunched_walk_turned_as_a_whole_finds_its_own_up_axis() -> None:
    # The hunched walk written lying (the whole take turned 90 degrees about a horizontal
    # axis, a file authored z-up or a take "stored lying down"): the world's up is the
    # coordinate axis the trunk keeps nearest, so the body's axes are those of the take as
    # written upright.
    walk, canonical = _hunched_walk()
    lying = transforms.rotate(walk, transforms.rotation_about([1.0, 0.0, 0.0], 90.0))
    assert _least_agreement_with_its_copy_in_odd_axes(lying, canonical) > np.cos(np.radians(5.0))
