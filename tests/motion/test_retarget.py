"""Retargeting one humanoid's motion onto another's skeleton (app/motion/retarget.py)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from app.motion.body import build_body, pelvis_basis
from app.motion.descriptors.kinetic import KINETIC_JOINTS, mean_energies
from app.motion.formats import read_asf_amc, read_bvh
from app.motion.ground import FOOT_POINTS, ON_FLOOR, canonical_positions
from app.motion.kinematics import forward_kinematics
from app.motion.model import Motion, Skeleton
from app.motion.retarget import axis_change, leg_length, reference_pose, retarget, swing
from app.motion.retarget_quality import LIMB_BONES, retarget_quality
from app.motion.skeleton_map import CANONICAL_INDEX, SkeletonMap, map_skeleton
from app.motion.transforms import change_basis, mirror, rotation_about
from tests.motion.conftest import (
    BANDAI_FIXTURE,
    CMU_AMC_FIXTURE,
    CMU_ASF_FIXTURE,
    CMU_BVH_FIXTURE,
    fixture_bytes,
)
from tests.motion.synthetic import walker_motion, walker_skeleton


def rig_of(motion: Motion) -> tuple[Motion, SkeletonMap]:
    body = build_body(motion)
    assert body.mapping is not None
    rig = reference_pose(motion, body.mapping)
    _, positions = forward_kinematics(rig)
    return rig, map_skeleton(rig.skeleton, poses=[("frame 0", positions[0])])


def mapped(motion: Motion) -> SkeletonMap:
    body = build_body(motion)
    assert body.mapping is not None
    return body.mapping


def bone_angles(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Degrees between ``(..., 3)`` directions."""
    cos = np.sum(a * b, axis=-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def test_swing_is_the_smallest_rotation_between_two_directions() -> None:
    rng = np.random.default_rng(3)
    a, b = rng.normal(size=(200, 3)), rng.normal(size=(200, 3))
    r = swing(a, b)
    np.testing.assert_allclose(
        r @ np.swapaxes(r, 1, 2), np.broadcast_to(np.eye(3), r.shape), atol=1e-12
    )
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-12)
    turned = (r @ a[:, :, None])[:, :, 0]
    np.testing.assert_allclose(bone_angles(turned, b), 0.0, atol=1e-5)  # arccos near 1
    # Smallest: the rotation angle is the angle between the two directions (no twist).
    angles = np.degrees(np.linalg.norm(Rotation.from_matrix(r).as_rotvec(), axis=1))
    np.testing.assert_allclose(angles, bone_angles(a, b), atol=1e-6)
    opposite = swing(np.array([0.0, 1.0, 0.0]), np.array([0.0, -2.0, 0.0]))
    np.testing.assert_allclose(opposite @ [0, 1, 0], [0, -1, 0], atol=1e-12)
    np.testing.assert_allclose(swing(np.zeros(3), np.ones(3)), np.eye(3))


def test_axis_change_is_a_quarter_turn_between_coordinate_axes() -> None:
    y, z = np.array([0.0, 1, 0]), np.array([0.0, 0, 1])
    turn = axis_change(z, y)
    np.testing.assert_array_equal(turn @ z, y)
    np.testing.assert_allclose(np.linalg.det(turn), 1.0)
    np.testing.assert_array_equal(axis_change(y, y), np.eye(3))


def test_onto_its_own_skeleton_the_motion_is_unchanged() -> None:
    source = read_bvh(fixture_bytes(CMU_BVH_FIXTURE))
    rig, rig_map = rig_of(source)
    out = retarget(source, mapped(source), rig, rig_map)
    assert out.skeleton is rig.skeleton
    expected = canonical_positions(source, mapped(source))
    # Every canonical joint where it was; the hands' tips differ: fingers stay at rest.
    body = [i for i, name in enumerate(CANONICAL_INDEX) if not name.endswith("hand_tip")]
    np.testing.assert_allclose(
        canonical_positions(out, rig_map)[:, body], expected[:, body], atol=1e-9 * 170
    )


def _a_pose(skeleton: Skeleton, degrees: float) -> Skeleton:
    """The same skeleton with its arms lowered by ``degrees`` in the rest pose."""
    offsets = skeleton.offsets.copy()
    for side, sign in (("Left", -1.0), ("Right", 1.0)):
        turn = rotation_about(np.array([0.0, 0.0, 1.0]), sign * degrees)
        for name in skeleton.names:
            if name.startswith(side) and any(p in name for p in ("ForeArm", "Hand", "Thumb")):
                offsets[skeleton.index(name)] = turn @ offsets[skeleton.index(name)]
    return dataclasses.replace(skeleton, offsets=offsets)


def test_a_t_pose_capture_drives_an_a_pose_rig_to_the_same_pose() -> None:
    source = walker_motion(frames=60)
    a_pose = _a_pose(walker_skeleton(), 45.0)
    rig_motion = Motion(
        a_pose, 1 / 30, np.zeros((1, 3)), np.tile(np.eye(3), (1, a_pose.joint_count, 1, 1))
    )
    rig, rig_map = rig_of(rig_motion)
    out = retarget(source, mapped(source), rig, rig_map)
    s = canonical_positions(source, mapped(source))
    t = canonical_positions(out, rig_map)
    for a, b in LIMB_BONES:
        sa, sb = s[:, CANONICAL_INDEX[a]], s[:, CANONICAL_INDEX[b]]
        ta, tb = t[:, CANONICAL_INDEX[a]], t[:, CANONICAL_INDEX[b]]
        assert bone_angles(sb - sa, tb - ta).max() < 1e-5, (a, b)
    # The rig's bones keep their lengths, whatever the pose.
    _, positions = forward_kinematics(out)
    parents = out.skeleton.parents
    lengths = np.linalg.norm(positions[:, 1:] - positions[:, parents[1:]], axis=2)
    np.testing.assert_allclose(
        lengths[:, 1:],
        np.broadcast_to(np.linalg.norm(a_pose.offsets[2:], axis=1), lengths[:, 1:].shape),
        atol=1e-9,
    )


def test_a_forearm_twist_stays_a_twist_about_the_same_bone() -> None:
    source = walker_motion(frames=10)
    local = source.local_rotations.copy()
    local[:] = np.eye(3)
    forearm = source.skeleton.index("LeftForeArm")
    along = source.skeleton.offsets[source.skeleton.index("LeftHand")]
    twist = Rotation.from_rotvec(np.outer(np.linspace(0, 1.2, 10), along / np.linalg.norm(along)))
    local[:, forearm] = twist.as_matrix()
    source = dataclasses.replace(source, local_rotations=local)
    a_pose = _a_pose(walker_skeleton(), 40.0)
    rig, rig_map = rig_of(
        Motion(a_pose, 1 / 30, np.zeros((1, 3)), np.tile(np.eye(3), (1, a_pose.joint_count, 1, 1)))
    )
    out = retarget(source, mapped(source), rig, rig_map)
    turned = Rotation.from_matrix(out.local_rotations[:, forearm]).as_rotvec()
    bone = a_pose.offsets[a_pose.index("LeftHand")]
    axis = bone / np.linalg.norm(bone)
    # The forearm only turns about its own (A-pose) direction, by the source's angle.
    np.testing.assert_allclose(np.cross(turned, axis), 0.0, atol=1e-9)
    np.testing.assert_allclose(turned @ axis, np.linspace(0, 1.2, 10), atol=1e-9)


def test_a_z_up_rig_gets_z_up_motion() -> None:
    source = read_bvh(fixture_bytes(CMU_BVH_FIXTURE))
    y_to_z = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # +Y -> +Z
    rig, rig_map = rig_of(change_basis(read_bvh(fixture_bytes(BANDAI_FIXTURE)), y_to_z))
    out = retarget(source, mapped(source), rig, rig_map)
    t = canonical_positions(out, rig_map)
    up = t[:, CANONICAL_INDEX["head"]] - t[:, CANONICAL_INDEX["l_ankle"]]
    assert np.all(up[:, 2] > 0.8 * np.linalg.norm(up, axis=1))
    quality = retarget_quality(source, mapped(source), out, rig_map, skip=1)
    assert quality.direction_ok == 1.0 and quality.left_ok == 1.0


@pytest.mark.parametrize(
    "rig_source",
    ["bandai", "asf", "cmu-bvh"],
)
def test_quality_on_real_rigs(rig_source: str) -> None:
    source = read_asf_amc(fixture_bytes(CMU_ASF_FIXTURE), fixture_bytes(CMU_AMC_FIXTURE))
    rigs = {
        "bandai": lambda: read_bvh(fixture_bytes(BANDAI_FIXTURE)),
        "asf": lambda: read_asf_amc(fixture_bytes(CMU_ASF_FIXTURE), fixture_bytes(CMU_AMC_FIXTURE)),
        "cmu-bvh": lambda: read_bvh(fixture_bytes(CMU_BVH_FIXTURE)),
    }
    rig, rig_map = rig_of(rigs[rig_source]())
    out = retarget(source, mapped(source), rig, rig_map)
    quality = retarget_quality(source, mapped(source), out, rig_map)
    assert quality.finite
    assert quality.bone_error < 1e-9
    assert quality.left_ok == 1.0
    assert quality.feet_error < 0.02
    assert quality.direction_ok >= 0.99
    assert out.skeleton.names == rig.skeleton.names
    np.testing.assert_array_equal(out.skeleton.offsets, rig.skeleton.offsets)


def test_a_mirrored_capture_keeps_left_on_the_left() -> None:
    source = read_bvh(fixture_bytes(CMU_BVH_FIXTURE))
    flipped = mirror(source)  # the joints called left now on the right
    flipped = dataclasses.replace(
        flipped, skeleton=dataclasses.replace(flipped.skeleton, names=source.skeleton.names)
    )
    flipped_map = mapped(flipped)
    assert flipped_map.mirrored
    rig, rig_map = rig_of(read_bvh(fixture_bytes(BANDAI_FIXTURE)))
    out = retarget(flipped, flipped_map, rig, rig_map)
    quality = retarget_quality(flipped, flipped_map, out, rig_map, skip=1)
    assert quality.left_ok == 1.0
    assert not build_body(out).mapping.mirrored  # type: ignore[union-attr]


def test_travel_is_scaled_by_the_legs_and_feet_stay_on_the_floor() -> None:
    source = walker_motion(frames=120)
    big = dataclasses.replace(walker_skeleton(), offsets=walker_skeleton().offsets * 2.0)
    rig, rig_map = rig_of(
        Motion(big, 1 / 30, np.zeros((1, 3)), np.tile(np.eye(3), (1, big.joint_count, 1, 1)))
    )
    out = retarget(source, mapped(source), rig, rig_map)
    s = canonical_positions(source, mapped(source))
    t = canonical_positions(out, rig_map)
    pelvis = CANONICAL_INDEX["pelvis"]
    travel_s = s[-1, pelvis, 2] - s[0, pelvis, 2]
    travel_t = t[-1, pelvis, 2] - t[0, pelvis, 2]
    assert travel_t == pytest.approx(2.0 * travel_s, rel=0.02)
    feet = [CANONICAL_INDEX[n] for n in ("l_ankle", "l_toe", "r_ankle", "r_toe")]
    np.testing.assert_allclose(
        t[:, feet, 1].min(axis=1) - t[:, feet, 1].min(),
        2.0 * (s[:, feet, 1].min(axis=1) - s[:, feet, 1].min()),
        atol=1e-6,
    )


def _long_shins(motion: Motion) -> Motion:
    """``motion`` with shins half as long again (the ankles' offsets)."""
    mapping = mapped(motion)
    offsets = motion.skeleton.offsets.copy()
    for side in ("l", "r"):
        offsets[int(mapping.joints[CANONICAL_INDEX[f"{side}_ankle"]])] *= 1.5
    return dataclasses.replace(
        motion, skeleton=dataclasses.replace(motion.skeleton, offsets=offsets)
    )


def test_a_planted_foot_does_not_slide_on_legs_of_other_proportions() -> None:
    """The same capture on its own skeleton with longer shins: the same directions and the
    travel scaled by the legs used to carry a planted foot over the floor."""
    source = read_bvh(fixture_bytes(BANDAI_FIXTURE))
    rig, rig_map = rig_of(_long_shins(read_bvh(fixture_bytes(BANDAI_FIXTURE))))
    out = retarget(source, mapped(source), rig, rig_map)
    quality = retarget_quality(source, mapped(source), out, rig_map, skip=1)
    assert quality.slide <= quality.source_slide + 0.01, (quality.slide, quality.source_slide)
    assert quality.direction_ok == 1.0 and quality.feet_error < 0.02


def test_a_foot_point_planted_alone_moves_exactly_as_the_source_s() -> None:
    """Onto the CMU subject's proportions: at every frame step where one foot point is on
    the floor in the source (contact is the source's, whether or not the rig's point is
    near its own floor), the pelvis's path makes it move over the floor exactly as the
    source's (scaled). (The legs' hold after it, off here, turns a leg about its hip, which
    moves the foot by its correction only to within 1e-4 of the height per step.)"""
    source = read_bvh(fixture_bytes(BANDAI_FIXTURE))
    rig, rig_map = rig_of(
        read_asf_amc(fixture_bytes(CMU_ASF_FIXTURE), fixture_bytes(CMU_AMC_FIXTURE))
    )
    out = retarget(source, mapped(source), rig, rig_map, hold_feet=False)
    scale = leg_length(rig, rig_map) / leg_length(source, mapped(source))
    feet = list(FOOT_POINTS)
    s = canonical_positions(source, mapped(source))[:, feet] * scale
    t = canonical_positions(out, rig_map)[:, feet]
    near = ON_FLOOR * build_body(out).height

    def planted(points: np.ndarray) -> np.ndarray:
        low = points[..., 1] - points[..., 1].min() < near
        return low[1:] & low[:-1]

    contact = planted(s)
    alone = contact.sum(axis=1) == 1
    assert alone.sum() >= 5, "the walk has steps with one foot point planted"
    moved_s = np.diff(s, axis=0)[alone][contact[alone]][:, [0, 2]]
    moved_t = np.diff(t, axis=0)[alone][contact[alone]][:, [0, 2]]
    np.testing.assert_allclose(moved_t, moved_s, atol=1e-9 * build_body(out).height)


@pytest.mark.parametrize("rig_source", ["asf", "cmu-bvh"])
def test_the_head_turns_as_the_source_s_head_whatever_lies_beyond_it(rig_source: str) -> None:
    """Bandai's head is a joint with nothing beyond it; the CMU rigs' head joint has the top
    of the head beyond it. The head joint used to be only aimed at, never turned: its energy
    (the ``kinetic`` head DOFs, relative to the neck) was 0 on the rig."""
    source = read_bvh(fixture_bytes(BANDAI_FIXTURE))
    rigs = {
        "asf": lambda: read_asf_amc(fixture_bytes(CMU_ASF_FIXTURE), fixture_bytes(CMU_AMC_FIXTURE)),
        "cmu-bvh": lambda: read_bvh(fixture_bytes(CMU_BVH_FIXTURE)),
    }
    rig, rig_map = rig_of(rigs[rig_source]())
    out = retarget(source, mapped(source), rig, rig_map)
    head = KINETIC_JOINTS.index("head")
    source_head = mean_energies(build_body(source))[0][head].sum()  # its three DOFs summed
    assert source_head > 0.05
    assert mean_energies(build_body(out))[0][head].sum() == pytest.approx(source_head, rel=1e-6)


def test_a_clip_bent_over_in_every_frame_stays_upright_on_the_rig() -> None:
    """The Bandai walk with its spine bent 80 degrees forward in every frame (a sneak, a
    crawl): the trunk's mean direction (pelvis -> neck) is nearer the forward axis than the
    up one, the pelvis frame's is not. Until 2026-11-28 the retarget took the source's world
    up from the trunk, so it turned the clip a quarter turn onto the rig: the re-upload's up
    was the rig's forward axis (a real sneak walk onto the Bandai rig was then refused as a
    four-legged animal). Now the rig's up is the output's, as for the upright walk."""
    walk = read_bvh(fixture_bytes(BANDAI_FIXTURE))
    walk_map = mapped(walk)
    spine = int(walk_map.joints[CANONICAL_INDEX["spine"]])
    assert walk.skeleton.parents[spine] == walk_map.joints[CANONICAL_INDEX["pelvis"]]
    # About the body's lateral axis in the pelvis joint's coordinates (the spine's parent).
    lateral = pelvis_basis(walk, walk_map.joints, rest_is_a_figure=False)[:, 0]
    bent = walk.local_rotations.copy()
    bent[:, spine] = Rotation.from_rotvec(np.radians(80.0) * lateral).as_matrix() @ bent[:, spine]
    sneak = dataclasses.replace(walk, local_rotations=bent)
    canonical = canonical_positions(sneak, walk_map)
    trunk = canonical[:, CANONICAL_INDEX["neck"]] - canonical[:, CANONICAL_INDEX["pelvis"]]
    trunk /= np.linalg.norm(trunk, axis=1, keepdims=True)
    assert np.argmax(np.abs(trunk.mean(axis=0))) != 1  # the trunk leans more than 45 deg
    assert build_body(sneak).world_up.tolist() == [0.0, 1.0, 0.0]
    rig, rig_map = rig_of(walk)
    out = retarget(sneak, walk_map, rig, rig_map)
    assert build_body(out).world_up.tolist() == [0.0, 1.0, 0.0]
    assert retarget_quality(sneak, walk_map, out, rig_map).passes()


def test_a_pelvis_turned_back_by_its_children_keeps_the_world_up_on_the_rig() -> None:
    """A pose network's BVH: the CMU capture with its pelvis turned 90 degrees about its
    forward axis and turned back by its children (all at the pelvis), the same world motion.
    The describer reads its axes from the joints; the retarget reads the world's up as the
    describer does, so the output stands on the rig (on the old reading: the pelvis's turned
    up, the world's X, and the output lay on its side)."""
    capture = read_bvh(fixture_bytes(CMU_BVH_FIXTURE))
    turn = rotation_about(np.array([0.0, 0.0, 1.0]), 90.0)
    children = np.flatnonzero(capture.skeleton.parents == 0)
    rotations = capture.local_rotations.copy()
    rotations[:, 0] = rotations[:, 0] @ turn
    rotations[:, children] = turn.T @ rotations[:, children]
    network = dataclasses.replace(capture, local_rotations=rotations)
    assert build_body(network).world_up.tolist() == build_body(capture).world_up.tolist()
    rig, rig_map = rig_of(capture)
    out = retarget(network, mapped(network), rig, rig_map)
    assert build_body(out).world_up.tolist() == build_body(capture).world_up.tolist()


def _buttocks(motion: Motion) -> Motion:
    """The CMU clip with its hip bones split where a DAZ figure splits them: the joint
    between the pelvis and the thigh (``LHipJoint``) moved out to the hip's side, the thigh
    hanging a short way down and back from it; the thighs stay where they were at rest."""
    skeleton = motion.skeleton
    offsets = skeleton.offsets.copy()
    for side in ("L", "R"):
        mid = skeleton.index(f"{side}HipJoint")
        thigh = skeleton.index(f"{'Left' if side == 'L' else 'Right'}UpLeg")
        step = np.array([0.0, -0.1, -0.12]) * np.linalg.norm(offsets[thigh])
        offsets[mid] = offsets[mid] + offsets[thigh] - step
        offsets[thigh] = step
    return dataclasses.replace(motion, skeleton=dataclasses.replace(skeleton, offsets=offsets))


def test_a_rig_s_hip_bones_stay_with_its_pelvis_whatever_the_source_splits() -> None:
    """The pelvis is one rigid bone that rigs split at places of their own. Paired one by
    one, the rig's hip bone (from the pelvis's centre) took the direction of the source's
    buttock-to-thigh step (down and back): both hip joints were brought together and left
    and right told nothing (the CMU ASF rig from a DAZ clip: left stays left 48 %)."""
    source = _buttocks(read_bvh(fixture_bytes(CMU_BVH_FIXTURE)))
    source_map = mapped(source)
    rig, rig_map = rig_of(read_bvh(fixture_bytes(CMU_BVH_FIXTURE)))
    out = retarget(source, source_map, rig, rig_map)
    quality = retarget_quality(source, source_map, out, rig_map, skip=1)
    assert quality.left_ok == 1.0
    # The rig's hips stay as far apart as at its rest, in every frame.
    pair = [rig_map.joints[CANONICAL_INDEX[f"{side}_hip"]] for side in "lr"]
    _, positions = forward_kinematics(out)
    _, rest = forward_kinematics(rig)
    width = np.linalg.norm(positions[:, pair[0]] - positions[:, pair[1]], axis=1)
    np.testing.assert_allclose(
        width, np.linalg.norm(rest[0, pair[0]] - rest[0, pair[1]]), rtol=1e-6
    )
