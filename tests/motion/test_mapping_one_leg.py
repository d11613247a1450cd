"""A single pose standing on one leg, the other foot lifted (issue 20, item 7;
docs/skeletons.md, "2026-11-27, a single pose on one leg").

A one-frame clip, or a frame written as the rest pose, of a kick or a knee raised shows no
figure on both feet and no bent take: the body is read standing on one leg
(:func:`app.motion.mapping.take.map_on_one_leg`), while four-legged animals stay refused.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from app.errors import MocapError, SkeletonMappingError
from app.motion.formats import read_bvh
from app.motion.formats.gltf import read_gltf
from app.motion.mapping.canonical import rest_pose
from app.motion.model import Motion, Skeleton
from app.motion.pipeline import describable_body
from app.motion.skeleton_map import map_skeleton
from tests.conftest import shared_data_dir
from tests.motion.conftest import BANDAI_FIXTURE, CMU_BVH_FIXTURE, fixture_bytes
from tests.motion.holds import frames_at
from tests.motion.test_mapping_probes import _named_mapping, frame_as_rest
from tests.motion.test_mapping_rest import posed, standing_frames
from tests.motion.test_skeleton_map import _quadruped, _under

_ONE_LEG = "standing on one leg"
# A kick forward: the left thigh turned 75 degrees forward on top of the walk's own stride
# (the ankle then drops 0.2-0.4 of the leg below the pelvis in the fixtures' middle frames,
# where the standing search asks 0.5).
_KICK = (("l_hip", -75.0),)


def _kick(motion: Motion, names: tuple[str, ...]) -> Motion:
    """The middle frame of ``motion`` kicking, written as the rest pose of a one-frame clip
    (a pose estimator's single frame)."""
    middle = frames_at(motion, np.array([motion.frame_count // 2]))
    return frame_as_rest(posed(middle, names, _KICK))


@pytest.mark.parametrize("fixture", [CMU_BVH_FIXTURE, BANDAI_FIXTURE])
def test_a_single_pose_on_one_leg_maps_like_the_rig(fixture: str) -> None:
    motion = read_bvh(fixture_bytes(fixture))
    names, mirrored = _named_mapping(motion)
    kicked = _kick(motion, names)
    assert not standing_frames(kicked, names).any()  # no figure on both feet to read
    mapping = describable_body(kicked).mapping
    assert mapping is not None
    assert tuple(kicked.skeleton.names[j] for j in mapping.joints) == names
    assert mapping.mirrored == mirrored
    assert any(_ONE_LEG in warning for warning in mapping.warnings)


def test_a_quadruped_with_a_hind_leg_lifted_is_refused() -> None:
    """A CMU rig on all fours (:func:`_quadruped`) with its left shin lifted back level, as
    in a gallop: one foot down, one lifted, but the spine level over the legs."""
    on_all_fours = _quadruped(read_bvh(fixture_bytes(CMU_BVH_FIXTURE)).skeleton)
    shin = on_all_fours.index("LeftLeg")
    offsets = on_all_fours.offsets.copy()
    back = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # down -> back
    for j in range(on_all_fours.joint_count):
        if _under(on_all_fours, j, shin) and j != shin:
            offsets[j] = back @ offsets[j]
    lifted = Skeleton(on_all_fours.names, on_all_fours.parents, offsets, on_all_fours.end_site)
    pose = rest_pose(lifted)
    assert pose[on_all_fours.index("LeftFoot"), 1] > pose[on_all_fours.index("RightFoot"), 1]
    with pytest.raises(SkeletonMappingError, match="four-legged"):
        map_skeleton(lifted, [("frame 0", pose)])


_FOX = Path("fbx-gltf/khronos-samples/Fox.glb")


@pytest.mark.skipif(not (shared_data_dir() / _FOX).is_file(), reason=f"no {_FOX} in ../shared/data")
def test_no_frame_of_a_running_fox_is_read_as_a_person_on_one_leg() -> None:
    """Each of 12 frames of the Fox's run, as a one-frame clip written as the rest pose: a
    gallop lifts a hind foot, and the fox's forelegs, as long as its hind legs, are no arms
    (take._ONE_LEG_ARM_TO_LEG). Some such frames were read as a standing person before
    this reading existed (docs/skeletons.md); none is read on one leg."""
    run, _, _ = read_gltf((shared_data_dir() / _FOX).read_bytes(), animation="Run")
    for frame in np.linspace(0, run.frame_count - 1, 12).astype(int):
        try:
            mapping = describable_body(frame_as_rest(frames_at(run, np.array([frame])))).mapping
        except MocapError:
            continue
        assert mapping is not None
        assert not any(_ONE_LEG in warning for warning in mapping.warnings), frame
