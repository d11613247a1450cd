"""The trunk's up when the arms branch at the hips (issue 20, held-out round 9).

A sign-language tool writes a skeleton whose root carries three branches at one place, the two
hips and the spine, the spine one bone up to the neck and the arms' first bones (from the
spine joint, as long as it) to the shoulders; its rest pose is every bone along one axis, and
the root never turns. The mapper's trunk ran from the pelvis to the arms' branch point: here
the root's own offset, the same line in every frame whatever the body does, so every pose
read as a body lying along it (refused as four-legged). The body, built below from the
world directions of its bones, is written as that tool writes it.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.spatial.transform import Rotation

from app.motion.formats import read_bvh
from app.motion.pipeline import describable_body
from app.motion.skeleton_map import CANONICAL_INDEX

ALONG = np.array([0.0, 0.0, 1.0])  # every OFFSET of the file lies along +Z
# joint -> (parent, bone length from the parent, the bone's world direction in the pose);
# the figure stands along +Y facing +Z (its left at +X).
UP, DOWN, LEFT, RIGHT, FRONT = (0, 1, 0), (0, -1, 0), (1, 0, 0), (-1, 0, 0), (0, 0, 1)
JOINTS: dict[str, tuple[str | None, float, tuple[float, float, float]]] = {
    "Root": (None, 0.0, UP),
    "Pelvis_R": ("Root", 10.0, FRONT),  # the root's offset: its direction never changes
    "Thigh_R": ("Pelvis_R", 9.0, RIGHT),
    "Shin_R": ("Thigh_R", 50.0, DOWN),
    "Foot_R": ("Shin_R", 41.5, DOWN),
    "Toe_R": ("Foot_R", 18.5, FRONT),
    "Pelvis_L": ("Root", 10.0, FRONT),
    "Thigh_L": ("Pelvis_L", 9.0, LEFT),
    "Shin_L": ("Thigh_L", 50.0, DOWN),
    "Foot_L": ("Shin_L", 41.5, DOWN),
    "Toe_L": ("Foot_L", 18.5, FRONT),
    "Spine": ("Root", 10.0, FRONT),
    "Neck": ("Spine", 52.5, UP),
    "Head": ("Neck", 16.5, UP),
    "Head_top": ("Head", 9.5, UP),
    "Shoulder_R": ("Spine", 52.5, UP),
    "Upperarm_R": ("Shoulder_R", 16.5, RIGHT),
    "Forearm_R": ("Upperarm_R", 26.0, RIGHT),
    "Hand_R": ("Forearm_R", 24.0, RIGHT),
    "Hand_R_top": ("Hand_R", 7.5, RIGHT),
    "Shoulder_L": ("Spine", 52.5, UP),
    "Upperarm_L": ("Shoulder_L", 16.5, LEFT),
    "Forearm_L": ("Upperarm_L", 26.0, LEFT),
    "Hand_L": ("Forearm_L", 24.0, LEFT),
    "Hand_L_top": ("Hand_L", 7.5, LEFT),
}
TIPS = ("Toe_R", "Toe_L", "Head_top", "Hand_R_top", "Hand_L_top")  # written as End Sites


def _world_turn(joint: str) -> Rotation:
    """The joint's world rotation: it turns +Z (its children's OFFSETs) along the bone to
    its one child, or stays (a joint whose children all leave one way)."""
    children = [j for j, (parent, _, _) in JOINTS.items() if parent == joint]
    if not children:
        return Rotation.identity()
    way = np.asarray(JOINTS[children[0]][2], dtype=float)
    if np.allclose(way, ALONG):
        return Rotation.identity()
    turn, _ = Rotation.align_vectors([way], [ALONG])
    return turn


def _bvh(frames: int = 8) -> bytes:
    """The figure as the tool writes it, its arms waving a little from frame to frame."""
    lines = ["HIERARCHY"]
    order = list(JOINTS)

    def block(joint: str, depth: int) -> None:
        pad = "\t" * depth
        parent, length, _ = JOINTS[joint]
        offset = ALONG * length
        if joint in TIPS:
            lines.extend(
                [
                    f"{pad}End Site",
                    f"{pad}{{",
                    f"{pad}\tOFFSET {offset[0]:.6f} {offset[1]:.6f} {offset[2]:.6f}",
                    f"{pad}}}",
                ]
            )
            return
        head = "ROOT" if parent is None else "JOINT"
        channels = "6 Xposition Yposition Zposition" if parent is None else "3"
        lines.extend(
            [
                f"{pad}{head} {joint}",
                f"{pad}{{",
                f"{pad}\tOFFSET {offset[0]:.6f} {offset[1]:.6f} {offset[2]:.6f}",
                f"{pad}\tCHANNELS {channels} Xrotation Yrotation Zrotation",
            ]
        )
        for child in order:
            if JOINTS[child][0] == joint:
                block(child, depth + 1)
        lines.append(f"{pad}}}")

    block("Root", 0)
    moving = [j for j in order if j not in TIPS]
    lines.extend(["MOTION", f"Frames: {frames}", "Frame Time: 0.041667"])
    for frame in range(frames):
        world = {j: _world_turn(j) for j in moving}
        for side in ("R", "L"):  # the forearms wave about the front axis
            wave = Rotation.from_rotvec(np.array(FRONT) * 0.05 * frame * (1 if side == "L" else -1))
            world[f"Forearm_{side}"] = wave * world[f"Forearm_{side}"]
            world[f"Hand_{side}"] = wave * world[f"Hand_{side}"]
        values = [0.0, 101.0, 0.0]
        for joint in moving:
            parent = JOINTS[joint][0]
            local = world[joint] if parent is None else world[parent].inv() * world[joint]
            with warnings.catch_warnings():  # at a quarter turn the angles still give it
                warnings.simplefilter("ignore", UserWarning)
                values.extend(local.as_euler("XYZ", degrees=True))
        lines.append(" ".join(f"{v:.6f}" for v in values))
    return ("\n".join(lines) + "\n").encode()


def test_arms_that_branch_at_the_hips_map_on_a_trunk_that_runs_to_the_neck() -> None:
    motion = read_bvh(_bvh())
    mapping = describable_body(motion).mapping
    assert mapping is not None
    names = motion.skeleton.names
    got = {c: names[mapping.joints[i]] for c, i in CANONICAL_INDEX.items()}
    for side, word in (("l", "L"), ("r", "R")):
        assert got[f"{side}_hip"] == f"Thigh_{word}"
        assert got[f"{side}_knee"] == f"Shin_{word}"
        assert got[f"{side}_ankle"] == f"Foot_{word}"
        assert got[f"{side}_shoulder"] == f"Upperarm_{word}"
        assert got[f"{side}_elbow"] == f"Forearm_{word}"
        assert got[f"{side}_wrist"] == f"Hand_{word}"
    assert got["neck"] == "Neck" and not mapping.mirrored
