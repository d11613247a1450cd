import numpy as np

from app.motion import transforms
from app.motion.body import build_body, pelvis_basis
from app.motion.kinematics import forward_kinematics
from app.motion.skeleton_map import CANONICAL_INDEX
from tests.motion.synthetic import walker_motion
from tests.motion.test_mapping_probes import own_axes


def test_a_hunched_walk_in_odd_bone_axes_reads_up_from_the_standing_pelvis():
    # A walk bent forward 30 degrees at the spine in every frame, written with every bone in
    # axes of its own (a rest pose that is no figure): the frames' trunk leans with the spine,
    # but the pelvis of a standing body stays near level, so the body's up is the world's up
    # seen from the pelvis, as the walker's own rest pose puts it (docs/skeletons.md,
    # "2026-11-27, the body's up from a take that stands"). Read from the trunk, it was 22
    # degrees off.
    walker = walker_motion(frames=60, fps=30.0)
    canonical = build_body(walker).mapping.joints  # type: ignore[union-attr]
    spine = int(canonical[CANONICAL_INDEX["spine"]])
    hunched = walker.local_rotations.copy()
    hunched[:, spine] = transforms.rotation_about([1.0, 0.0, 0.0], 30.0) @ hunched[:, spine]
    hunched_walk = transforms._replace(walker, local_rotations=hunched)
    body = build_body(hunched_walk)  # its rest pose stands: the axes the copy must find
    copy = own_axes(hunched_walk)

    basis = pelvis_basis(copy, canonical, rest_is_a_figure=False)
    rotations, _ = forward_kinematics(copy, joints=canonical)
    up = rotations[:, canonical[CANONICAL_INDEX["pelvis"]]] @ basis[:, 1]  # (F, 3)
    agreement = np.einsum("fa,fa->f", up, body.pelvis_frames[:, :, 1])
    assert float(agreement.min()) > np.cos(np.radians(5.0))


def test_a_hunched_walk_turned_as_a_whole_finds_its_own_up_axis():
    # The hunched walk written lying (the whole take turned 90 degrees about a horizontal
    # axis, a file authored z-up or a take "stored lying down") with bones in axes of their
    # own: the world's up is the coordinate axis the trunk keeps nearest, so the body's axes
    # are those of the take as written upright.
    walker = walker_motion(frames=60, fps=30.0)
    canonical = build_body(walker).mapping.joints  # type: ignore[union-attr]
    spine = int(canonical[CANONICAL_INDEX["spine"]])
    hunched = walker.local_rotations.copy()
    hunched[:, spine] = transforms.rotation_about([1.0, 0.0, 0.0], 30.0) @ hunched[:, spine]
    walker = transforms._replace(walker, local_rotations=hunched)
    lying = transforms.rotate(walker, transforms.rotation_about([1.0, 0.0, 0.0], 90.0))
    body = build_body(lying)
    copy = own_axes(lying)

    basis = pelvis_basis(copy, canonical, rest_is_a_figure=False)
    rotations, _ = forward_kinematics(copy, joints=canonical)
    up = rotations[:, canonical[CANONICAL_INDEX["pelvis"]]] @ basis[:, 1]  # (F, 3)
    agreement = np.einsum("fa,fa->f", up, body.pelvis_frames[:, :, 1])
    assert float(agreement.min()) > np.cos(np.radians(5.0))
