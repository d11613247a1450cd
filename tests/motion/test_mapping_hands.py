"""The hand's tip (app/motion/mapping/arms.py): the farthest point beyond the wrist that a
hand can reach. A prop joint at the wrist (Xsens MVN writes one for a held object, reaching
several forearms out) is no finger; a cartoon's big hand still is the hand (issue 20)."""

from __future__ import annotations

import numpy as np

from app.motion.formats import read_bvh
from app.motion.model import Motion
from app.motion.pipeline import analyse
from tests.conftest import FIXTURES_DIR
from tests.motion.synthetic import below, bones_scaled, grown

BVH = FIXTURES_DIR / "cmu_mb_02_01_first41.bvh"


def _tips(motion: Motion) -> dict[str, str]:
    joints = analyse(motion).joint_mapping["joints"]
    return {side: joints[f"{side}_hand_tip"]["joint"] for side in ("l", "r")}


def _arm(motion: Motion, side: str) -> tuple[int, float, float]:
    """The wrist's index, the arm's length (shoulder to wrist) and the hand's (wrist to its
    farthest point) along the bones."""
    skeleton = motion.skeleton
    names = list(skeleton.names)
    wrist = names.index(f"{side}Hand")
    lengths = np.linalg.norm(skeleton.offsets, axis=1)
    arm = float(lengths[wrist] + lengths[names.index(f"{side}ForeArm")])
    hand = 0.0
    for joint in below(skeleton, wrist):
        path, j = 0.0, joint
        while j != wrist:
            path, j = path + float(lengths[j]), int(skeleton.parents[j])
        hand = max(hand, path)
    return wrist, arm, hand


def test_a_prop_held_at_the_wrist_is_not_the_hand() -> None:
    """On the code before, the right hand's tip was the prop's end, three forearms out."""
    motion = read_bvh(BVH.read_bytes())
    plain = _tips(motion)
    wrist = _arm(motion, "Right")[0]
    forearm = float(np.linalg.norm(motion.skeleton.offsets[wrist]))
    held = grown(
        motion,
        [wrist, motion.skeleton.joint_count],
        [np.array([0.0, -0.1, 0.1]) * forearm, np.array([-2.0, -1.0, 2.0]) * forearm],
    )
    assert _tips(held) == plain


def test_a_cartoons_big_hand_keeps_its_tip() -> None:
    """Hands grown to 0.7 of the arm (a cartoon's, as large as any rig of the development
    sets has them) are still hands: their tips stay where they were."""
    motion = read_bvh(BVH.read_bytes())
    plain = _tips(motion)
    for side in ("Left", "Right"):
        wrist, arm, hand = _arm(motion, side)
        motion = bones_scaled(motion, below(motion.skeleton, wrist), 0.7 * arm / hand)
        assert abs(_arm(motion, side)[2] - 0.7 * arm) < 1e-6 * arm
    assert _tips(motion) == plain
