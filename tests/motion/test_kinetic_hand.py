"""``kinetic`` reads the hand where it turns: the palm, the joint a retarget drives (issue 22).

A retarget keeps a rig's fingers at rest, and a rig without fingers has none to curl, so the
wrist's three DOFs must be the whole hand's turn, never a finger's own curl: the hand tip (an
end site or a finger's last joint) takes the palm's frame (:func:`app.motion.hand.palm`).
Real clips from ``tests/fixtures``: the CMU ASF/AMC trial (``rwrist`` -> ``rhand`` ->
``rfingers``, ``rthumb``) and its MotionBuilder BVH (``RightHand`` -> ``RightFingerBase`` ->
``RightHandIndex1``, ``RThumb``), whose hand tips end a finger; the Bandai walk, whose hand
has no joint below the wrist.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from app.motion.body import build_body
from app.motion.descriptors.kinetic import KINETIC_JOINTS, compute_kinetic
from app.motion.descriptors.motion import DESCRIPTOR as MOTION
from app.motion.formats import read_asf_amc, read_bvh
from app.motion.kinematics import forward_kinematics
from app.motion.model import Motion
from app.motion.skeleton_map import CANONICAL_INDEX
from tests.motion.conftest import (
    BANDAI_FIXTURE,
    CMU_AMC_FIXTURE,
    CMU_ASF_FIXTURE,
    CMU_BVH_FIXTURE,
    fixture_bytes,
)

# The wrists' six numbers in the 50-number kinetic vector (3 DOFs each).
WRIST_TERMS = np.array(
    [3 * KINETIC_JOINTS.index(w) + k for w in ("l_wrist", "r_wrist") for k in range(3)]
)
# Each CMU skeleton's palms (left, right): the hand, not the branching joint nor a finger.
PALMS = {"cmu asf/amc": ("lhand", "rhand"), "cmu bvh": ("LeftFingerBase", "RightFingerBase")}


def _fixture(name: str) -> Motion:
    if name == "cmu asf/amc":
        return read_asf_amc(fixture_bytes(CMU_ASF_FIXTURE), fixture_bytes(CMU_AMC_FIXTURE))
    return read_bvh(fixture_bytes({"cmu bvh": CMU_BVH_FIXTURE, "bandai": BANDAI_FIXTURE}[name]))


def _below(motion: Motion, tops: set[int]) -> list[int]:
    """Every joint hanging (at any depth) from one of ``tops``."""
    out = []
    for joint in range(motion.skeleton.joint_count):
        parent = int(motion.skeleton.parents[joint])
        while parent >= 0 and parent not in tops:
            parent = int(motion.skeleton.parents[parent])
        if parent >= 0:
            out.append(joint)
    return out


@pytest.mark.parametrize("name", sorted(PALMS))
def test_the_hand_tips_frame_is_the_palms(name: str) -> None:
    motion = _fixture(name)
    body = build_body(motion)
    rotations, _ = forward_kinematics(motion)
    kept = rotations[body.lead_in_frames : body.lead_in_frames + body.frame_count]
    assert body.mapping is not None
    for side, palm_name in zip("lr", PALMS[name], strict=True):
        tip = CANONICAL_INDEX[f"{side}_hand_tip"]
        palm = motion.skeleton.names.index(palm_name)
        np.testing.assert_allclose(body.rotations[:, tip], kept[:, palm], atol=1e-12)
        # The tip hangs from a finger joint below the palm, whose frame is another one.
        finger = int(motion.skeleton.parents[int(body.mapping.joints[tip])])
        assert finger != palm
        assert np.abs(kept[:, finger] - kept[:, palm]).max() > 1e-3


@pytest.mark.parametrize("name", sorted(PALMS))
def test_fingers_that_curl_change_no_kinetic_or_motion_number(name: str) -> None:
    """The fixtures' fingers keep one pose after the lead-in frame (a constant turn below
    the palm changes no velocity), so they are made to curl: one full curl and back, up to
    90 degrees about the finger joint's own lateral axis, as a grasp would."""
    motion = _fixture(name)
    palms = {motion.skeleton.names.index(p) for p in PALMS[name]}
    fingers = _below(motion, palms)
    angle = np.radians(45.0) * (1.0 - np.cos(np.linspace(0.0, 2.0 * np.pi, motion.frame_count)))
    curl = np.zeros((motion.frame_count, 3, 3))
    curl[:, 0, 0] = 1.0
    curl[:, 1, 1] = curl[:, 2, 2] = np.cos(angle)
    curl[:, 1, 2], curl[:, 2, 1] = -np.sin(angle), np.sin(angle)
    local = motion.local_rotations.copy()
    local[:, fingers] = local[:, fingers] @ curl[:, None]
    curled = dataclasses.replace(motion, local_rotations=local)
    still_hand = compute_kinetic(build_body(motion))
    curling_hand = compute_kinetic(build_body(curled))
    assert still_hand[WRIST_TERMS].max() > 0.01
    np.testing.assert_allclose(curling_hand, still_hand, rtol=1e-9, atol=1e-12)
    # `motion` reads the wrist's energy in its energy and parts blocks: all of it is the same.
    np.testing.assert_allclose(
        MOTION.compute(build_body(curled)), MOTION.compute(build_body(motion)), atol=1e-6
    )


def test_a_hand_without_joints_below_the_wrist_reads_the_wrist_as_before() -> None:
    """The Bandai rig's hand tip is the wrist's End Site: its palm is the wrist itself."""
    body = build_body(_fixture("bandai"))
    for side in "lr":
        tip_frame = body.rotations[:, CANONICAL_INDEX[f"{side}_hand_tip"]]
        wrist_frame = body.rotations[:, CANONICAL_INDEX[f"{side}_wrist"]]
        np.testing.assert_array_equal(tip_frame, wrist_frame)
    assert compute_kinetic(body)[WRIST_TERMS].max() > 0.01
