"""The trunk's lean survives a retarget (issue 22, the strict round trip).

The retarget aligns the source's and the rig's reference poses; the describer reads the
trunk (pelvis -> neck) in a frame fixed to the pelvis joint (``app.motion.body``). A Bandai
take's rest pose is no standing figure, so its reference pose is the take's first frame;
aligned by that frame's own trunk, a tired walk (leaning forward from its first frame on)
lost its lean in every frame on every rig — the pelvis tilted back by 15-27 degrees, and
the re-upload's nearest clip was an upright walk. Aligned by the pelvis-fixed axes the
describer reads, the rig's pelvis frame is the source's in every frame.
Real files: a Bandai tired walk (../shared/data), the Bandai and CMU fixtures as rigs.

The trunk's chord (``app.motion.retarget_trunk``): where the rig's spine joints sit at other
heights than the source's, bones pointing as the source's add up to another pelvis -> neck;
the rig's spine joint turns so the chord is the source's, the chest and what hangs from it
keep their directions.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from app.motion.body import Body, build_body
from app.motion.formats import read_asf_amc, read_bvh
from app.motion.formats.bvh_writer import write_bvh
from app.motion.ground import canonical_positions
from app.motion.kinematics import forward_kinematics
from app.motion.model import Motion
from app.motion.retarget import retarget
from app.motion.skeleton_map import CANONICAL_INDEX
from app.motion.transforms import rotation_about
from tests.conftest import SharedData
from tests.motion.conftest import (
    BANDAI_FIXTURE,
    CMU_AMC_FIXTURE,
    CMU_ASF_FIXTURE,
    CMU_BVH_FIXTURE,
    fixture_bytes,
)
from tests.motion.test_retarget import mapped, rig_of

RIGS = {
    "bandai": lambda: read_bvh(fixture_bytes(BANDAI_FIXTURE)),
    "cmu asf/amc": lambda: read_asf_amc(
        fixture_bytes(CMU_ASF_FIXTURE), fixture_bytes(CMU_AMC_FIXTURE)
    ),
}


def _trunk(body: Body) -> np.ndarray:
    """``(F, 3)`` unit pelvis -> neck direction in the body's pelvis frame (as ``motion``'s
    limbs block reads it)."""
    pelvis, neck = CANONICAL_INDEX["pelvis"], CANONICAL_INDEX["neck"]
    relative = body.positions[:, neck] - body.positions[:, pelvis]
    local = np.einsum("fj,fjk->fk", relative, body.pelvis_frames)
    return local / np.linalg.norm(local, axis=1, keepdims=True)


def _leaning_walk(shared_data: SharedData) -> Motion:
    path = shared_data("bandai-ds1", "data", "dataset-1_walk_tired_002.bvh")
    motion = read_bvh(path.read_bytes())
    return motion.slice_frames(0, min(motion.frame_count, round(3.0 / motion.frame_time)))


@pytest.mark.parametrize("rig_name", list(RIGS))
def test_a_walk_leaning_from_its_first_frame_keeps_its_lean_on_the_rig(
    shared_data: SharedData, rig_name: str
) -> None:
    source = _leaning_walk(shared_data)
    source_trunk = _trunk(build_body(source))
    # The take leans forward from its first frame on: the case the alignment lost.
    assert source_trunk[0, 2] > 0.2 and source_trunk[:, 2].mean() > 0.2
    rig, rig_map = rig_of(RIGS[rig_name]())
    upload = read_bvh(write_bvh(retarget(source, mapped(source), rig, rig_map)))
    upload_trunk = _trunk(build_body(upload))
    # Before: a mean lean of 0.00 on the Bandai rig and -0.04 on the CMU rig against the
    # source's 0.29 (the sine of the angle forward of the pelvis's up), 17-20 degrees off in
    # the median frame; after, 0.29 and 0.27 (the CMU rig's spine is split at other points,
    # so its pelvis -> neck chord bends a little otherwise), within 2 degrees.
    angles = np.degrees(np.arccos(np.clip(np.sum(upload_trunk * source_trunk, axis=1), -1, 1)))
    assert np.median(angles) < 4.0
    assert abs(upload_trunk[:, 2].mean() - source_trunk[:, 2].mean()) < 0.06


def _bent_back(source: Motion, degrees: float) -> Motion:
    """``source`` bent forward by ``degrees`` in its lower back — the first joint above the
    pelvis towards the neck — about the body's lateral axis, in every frame."""
    mapping = mapped(source)
    pelvis = int(mapping.joints[CANONICAL_INDEX["pelvis"]])
    lower_back = int(mapping.joints[CANONICAL_INDEX["neck"]])
    parents = source.skeleton.parents
    while parents[lower_back] != pelvis:
        lower_back = int(parents[lower_back])
    lateral = build_body(source).pelvis_frames[:, :, 0]  # (F, 3), in world axes
    world, _ = forward_kinematics(source)  # (F, J, 3, 3)
    local = source.local_rotations.copy()
    for f in range(source.frame_count):
        # Forward: the lateral axis points to the body's left; a right-handed turn about it
        # takes the up towards the front.
        turn = rotation_about(lateral[f], degrees)
        local[f, lower_back] = world[f, pelvis].T @ turn @ world[f, pelvis] @ local[f, lower_back]
    return dataclasses.replace(source, local_rotations=local)


def _direction(positions: np.ndarray, start: str, end: str) -> np.ndarray:
    """``(F, 3)`` unit ``start`` -> ``end`` direction in world axes from canonical
    ``positions`` ``(F, C, 3)``."""
    bone = positions[:, CANONICAL_INDEX[end]] - positions[:, CANONICAL_INDEX[start]]
    return bone / np.linalg.norm(bone, axis=1, keepdims=True)


def _degrees(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=-1), -1.0, 1.0)))


def test_a_bent_back_keeps_its_trunk_chord_on_a_rig_with_its_spine_at_other_heights() -> None:
    # The Bandai skeleton's spine and chest joints sit 0.38 and 0.60 of the way up its pelvis
    # -> neck; the CMU MotionBuilder rig's (a T-pose rest pose) 0.50 and 1.0 (its neck sits on
    # its chest). Bent 40 degrees right above the pelvis, each spine bone of the rig points
    # as the source's of the same name, but they added up to a pelvis -> neck 4.6 degrees off
    # the source's in the median frame (5.3 at most); the rig's spine joint turning for the
    # neck brings it within float noise.
    bandai = read_bvh(fixture_bytes(BANDAI_FIXTURE))
    source = _bent_back(bandai, 40.0)
    rig, rig_map = rig_of(read_bvh(fixture_bytes(CMU_BVH_FIXTURE)))
    assert rig_map.pose == "rest pose"
    out = retarget(source, mapped(source), rig, rig_map)
    source_at = canonical_positions(source, mapped(source))
    out_at = canonical_positions(out, rig_map)
    # The bend is there in the source: the chord leans forward of the pelvis's up.
    up = build_body(bandai).pelvis_frames[:, :, 1]
    assert np.all(_degrees(_direction(source_at, "pelvis", "neck"), up) > 20.0)
    chord = _degrees(_direction(out_at, "pelvis", "neck"), _direction(source_at, "pelvis", "neck"))
    assert chord.max() < 0.5
    # The chest and what hangs from it keep the source's directions: the head and arms.
    for start, end in [("neck", "head"), ("l_shoulder", "l_elbow"), ("r_shoulder", "r_elbow")]:
        bone = _degrees(_direction(out_at, start, end), _direction(source_at, start, end))
        assert np.median(bone) < 3.0, (start, end)


def test_a_bent_back_keeps_its_chord_and_its_axes_on_a_rig_whose_rest_is_no_figure() -> None:
    # The Bandai skeleton's rest pose is no figure (its bones lie along each joint's x axis),
    # but its trunk is one straight line along the bone its pelvis carries, so every frame
    # shows the rest's axes by its pelvis (app.motion.body_axes.pelvis_carries). The CMU
    # ASF/AMC fixture bent 25 degrees above its pelvis onto the Bandai fixture rig: before,
    # the chord was not aimed on such a rig, 11.1 degrees off the source's in the median
    # frame (12.0 at most); with the chord aimed but the re-upload's axes voted on by its
    # frames' trunk (which the passed-on lean turns away from the rest's up) they were read
    # from the frames, 4.9 degrees off the source's in every frame. Now both within noise.
    cmu = read_asf_amc(fixture_bytes(CMU_ASF_FIXTURE), fixture_bytes(CMU_AMC_FIXTURE))
    source = _bent_back(cmu, 25.0)
    rig, rig_map = rig_of(read_bvh(fixture_bytes(BANDAI_FIXTURE)))
    assert rig_map.pose != "rest pose"  # read from a frame: the rest pose is no figure
    again = build_body(read_bvh(write_bvh(retarget(source, mapped(source), rig, rig_map))))
    body = build_body(source)
    frames = min(body.frame_count, again.frame_count)
    trace = np.einsum("fab,fab->f", body.pelvis_frames[-frames:], again.pelvis_frames[-frames:])
    axes_off = np.degrees(np.arccos(np.clip((trace - 1.0) / 2.0, -1.0, 1.0)))
    chord_off = _degrees(_trunk(again)[-frames:], _trunk(body)[-frames:])
    assert axes_off.max() < 1e-3, axes_off.max()
    assert chord_off.max() < 0.5, chord_off.max()
