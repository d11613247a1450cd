"""Left and right (``app/motion/mapping/sides.py``) where the rest pose shows little."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from app.motion.formats import read_bvh
from app.motion.skeleton_map import CANONICAL_INDEX, map_skeleton
from tests.motion.skeleton_trees import Humanoid, synthetic_humanoid
from tests.motion.test_mapping_probes import without

CMU = Path(__file__).parents[1] / "fixtures" / "cmu_mb_02_01_first41.bvh"


def test_a_rest_pose_on_straight_knees_with_no_feet_leaves_the_sides_to_the_names() -> None:
    """The CMU rig with nothing below its ankles (each leg ends at its ankle joint): the
    rest pose's knees are straight, and a straight knee sits a little ahead of or behind its
    leg's line as the rig was drawn, which says nothing of front and back. Read as front and
    back, it made this rig a mirrored capture (left stays left 0 % in a retarget onto it)."""
    motion = read_bvh(CMU.read_bytes())
    for joint in ("LeftToeBase_end", "LeftToeBase", "RightToeBase_end", "RightToeBase"):
        motion = without(motion, motion.skeleton.names.index(joint))
    assert "LeftFoot" in motion.skeleton.names and "LeftToeBase" not in motion.skeleton.names
    mapping = map_skeleton(motion.skeleton)
    assert not mapping.mirrored, mapping.warnings
    names = motion.skeleton.names
    assert names[mapping.joints[CANONICAL_INDEX["l_ankle"]]] == "LeftFoot"
    assert names[mapping.joints[CANONICAL_INDEX["l_shoulder"]]] == "LeftArm"


def test_limbs_set_apart_front_to_back_show_no_side() -> None:
    """A person's hips and shoulders lie side by side (knees and hands may part front to
    back in a stride). A rest pose whose hips and shoulders are set apart mostly front to
    back (a writer's bone-local axes that still pass for a standing figure) with a small
    sideways part of the wrong sign shows no side: the names decide. Read by that sideways
    part, the rig was a mirrored capture."""
    skeleton, truth = synthetic_humanoid(Humanoid())
    parents = skeleton.parents
    world = np.zeros_like(skeleton.offsets)
    for j in range(len(parents)):
        world[j] = skeleton.offsets[j] + (world[parents[j]] if parents[j] >= 0 else 0.0)
    height = float(np.ptp(world[:, 1]))
    sided = np.abs(world[:, 0]) > 1e-9
    sign = np.sign(world[:, 0])
    moved = world.copy()
    moved[sided, 0] *= -0.3  # a little of the other side...
    moved[sided, 2] += 0.06 * height * sign[sided]  # ...and farther apart front to back
    offsets = moved - np.where(parents[:, None] >= 0, moved[np.maximum(parents, 0)], 0.0)
    offsets[0] = moved[0]
    odd = dataclasses.replace(skeleton, offsets=offsets)
    mapping = map_skeleton(odd)
    assert not mapping.mirrored, mapping.warnings
    names = odd.names
    for part in ("l_hip", "l_shoulder", "r_knee", "r_wrist"):
        assert names[mapping.joints[CANONICAL_INDEX[part]]] == truth[part]
