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


def test_knees_bent_out_of_the_legs_plane_show_no_side() -> None:
    """A knee bends about the line across the hips. A pose (a first frame written as the
    rest pose) whose shins lean sideways out of the thighs' line, both to one side, with the
    pelvis turned 30 degrees against the legs, bends its "knees" about the forward axis;
    read as the hinge of a bend, that axis put the left leg on the right (a nameless rig:
    no names to correct it). Those knees now show no side, and the feet decide."""
    skeleton, truth = synthetic_humanoid(Humanoid(names="anon"))
    names, parents = skeleton.names, skeleton.parents
    world = np.zeros_like(skeleton.offsets)
    for j in range(len(parents)):
        world[j] = skeleton.offsets[j] + (world[parents[j]] if parents[j] >= 0 else 0.0)

    def below(joint: int) -> list[int]:
        out, frontier = [joint], [joint]
        while frontier:
            frontier = [j for j in range(len(parents)) if parents[j] in frontier]
            out += frontier
        return out

    def turned(points: np.ndarray, about: np.ndarray, angle: float, axis: int) -> np.ndarray:
        c, s = np.cos(np.radians(angle)), np.sin(np.radians(angle))
        a, b = [(1, 2), (2, 0), (0, 1)][axis]
        moved = points - about
        out = moved.copy()
        out[:, a], out[:, b] = c * moved[:, a] - s * moved[:, b], s * moved[:, a] + c * moved[:, b]
        return out + about

    pelvis = world[names.index(truth["pelvis"])]
    for side in "lr":
        hip, knee = names.index(truth[f"{side}_hip"]), names.index(truth[f"{side}_knee"])
        leg = below(hip)
        spot = turned(world[[hip]], pelvis, 30.0, 1)[0]  # the pelvis turned against the legs
        world[leg] += spot - world[hip]
        shin = below(names.index(truth[f"{side}_ankle"]))
        world[shin] = turned(world[shin], world[knee], 20.0, 2)  # the shin leans to +x
    offsets = world - np.where(parents[:, None] >= 0, world[np.maximum(parents, 0)], 0.0)
    offsets[0] = world[0]
    posed = dataclasses.replace(skeleton, offsets=offsets)
    mapping = map_skeleton(posed)
    assert not mapping.mirrored, mapping.warnings
    for part in ("l_hip", "l_ankle", "r_knee", "l_shoulder", "r_wrist"):
        assert names[mapping.joints[CANONICAL_INDEX[part]]] == truth[part], part
