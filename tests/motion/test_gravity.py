"""The world's vertical of a take that lies along the floor (app/motion/gravity.py)."""

from __future__ import annotations

import dataclasses

import numpy as np

from app.motion import transforms
from app.motion.body import build_body
from app.motion.formats import read_bvh
from app.motion.gravity import floor_spread, rest_up
from app.motion.model import Motion
from app.motion.pipeline import analyse
from app.motion.retarget import world_up
from tests.motion.conftest import CMU_BVH_FIXTURE, fixture_bytes
from tests.motion.test_mapping_probes import rebased

_UP = np.array([0.0, 1.0, 0.0])  # the CMU fixture's rest pose and world: Y up


def _turned(motion: Motion, rotation: np.ndarray) -> Motion:
    """The take turned as a whole by ``rotation`` ``(3, 3)`` about the world's origin; the
    rest pose (the offsets) is left as written."""
    local = motion.local_rotations.copy()
    local[:, 0] = rotation @ local[:, 0]
    return dataclasses.replace(
        motion, local_rotations=local, root_translation=motion.root_translation @ rotation.T
    )


def _on_the_back(motion: Motion) -> Motion:
    """The walk laid on its back on a Y-up floor and dragged head first along it (four
    times as far as it walked; its legs and arms still moving): the take's mean body up
    then points along the floor (-Z), the direction of its travel."""
    root = motion.root_translation.copy()
    travelled = np.linalg.norm(root[:, [0, 2]] - root[0, [0, 2]], axis=1)
    root[:, [0, 2]] = root[0, [0, 2]]
    root[:, 1] += 4 * travelled  # turned below onto -Z, along the head
    lying = _turned(
        dataclasses.replace(motion, root_translation=root),
        np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]),  # Y -> -Z
    )
    body = build_body(lying)
    lowest = (body.positions @ _UP).min()
    root = lying.root_translation.copy()
    root[:, 1] -= lowest  # resting on the floor
    return dataclasses.replace(lying, root_translation=root)


def test_a_take_lying_on_the_floor_keeps_the_rest_pose_s_up() -> None:
    """Before 2026-11-28 the vertical was the axis of the take's mean body up, -Z here: the
    take was stored on its side (its preview standing on the floor's edge, its travel read as
    vertical). Along +Y its lowest point (the back, a swinging hand) keeps about one height;
    along -Z the lowest point is the feet, which travel with the body."""
    walk = read_bvh(fixture_bytes(CMU_BVH_FIXTURE))
    lying = _on_the_back(walk)
    body = build_body(lying)
    assert rest_up(lying.skeleton, body.mapping.joints).tolist() == _UP.tolist()
    on_back, on_back_rests = floor_spread(body.positions, _UP, body.height)
    along_head, along_head_rests = floor_spread(
        body.positions, np.array([0.0, 0.0, -1.0]), body.height
    )
    assert on_back < 0.5 * along_head and on_back_rests >= 0.5 > along_head_rests
    np.testing.assert_array_equal(body.world_up, _UP)
    # The retarget reads the source's vertical as the describer does.
    np.testing.assert_array_equal(world_up(lying, body.mapping), _UP)
    assert all(np.all(np.isfinite(v)) for v in analyse(lying).descriptors.values())


def test_a_take_standing_in_another_world_keeps_its_own_up() -> None:
    """A writer that turns a Y-up rest pose into a Z-up world at the root (the whole take
    turned, travel included): the take stands along +Z, where its feet keep the floor, and
    the rest pose's +Y (along which the walk travels) is not taken."""
    walk = read_bvh(fixture_bytes(CMU_BVH_FIXTURE))
    z_up = _turned(walk, np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]))
    body = build_body(z_up)
    np.testing.assert_array_equal(body.world_up, [0.0, 0.0, 1.0])
    np.testing.assert_array_equal(build_body(walk).world_up, _UP)


def test_one_frame_has_no_floor_to_read() -> None:
    walk = read_bvh(fixture_bytes(CMU_BVH_FIXTURE))
    lying = _on_the_back(walk).slice_frames(0, 1)
    np.testing.assert_array_equal(build_body(lying).world_up, [0.0, 0.0, -1.0])


def _a_fall(walk: Motion, standing: int = 10) -> Motion:
    """The walk's first ``standing`` frames upright, the rest laid on its back and dragged
    (:func:`_on_the_back`): a take that starts standing and lies for most of its frames."""
    lying = _on_the_back(walk)
    return dataclasses.replace(
        walk,
        local_rotations=np.concatenate(
            [walk.local_rotations[:standing], lying.local_rotations[standing:]]
        ),
        root_translation=np.concatenate(
            [walk.root_translation[:standing], lying.root_translation[standing:]]
        ),
    )


def test_a_take_that_stands_for_a_part_reads_its_floor_whatever_its_rest_pose() -> None:
    """A fall whose writer's rest pose lies (every joint's axes turned: the rest pose's
    head -> ankles runs along the take's mean body up, -Z) reads the vertical from the frames
    in which the body stands, as the same take with a standing rest pose does. Before, only a
    standing rest pose named the other axis, and the copy was stored on its side (-Z)."""
    fall = _a_fall(read_bvh(fixture_bytes(CMU_BVH_FIXTURE)))
    turn = transforms.rotation_about([1.0, 0.0, 0.0], 90.0)
    lying_rest = rebased(fall, np.broadcast_to(turn, (fall.skeleton.joint_count, 3, 3)).copy())
    for take in (fall, lying_rest):
        body = build_body(take)
        assert body.pelvis_frames[:, :, 1].mean(axis=0) @ [0.0, 0.0, -1.0] > 0.5
        np.testing.assert_array_equal(body.world_up, _UP)
        np.testing.assert_array_equal(world_up(take, body.mapping), _UP)
    assert rest_up(lying_rest.skeleton, build_body(lying_rest).mapping.joints).tolist() == [
        0.0,
        0.0,
        -1.0,
    ]
