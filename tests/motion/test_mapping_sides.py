"""Left and right (``app/motion/mapping/sides.py``) where the rest pose shows little."""

from __future__ import annotations

from pathlib import Path

from app.motion.formats import read_bvh
from app.motion.skeleton_map import CANONICAL_INDEX, map_skeleton
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
