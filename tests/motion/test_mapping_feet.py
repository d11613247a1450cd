"""A heel bone beside the foot (app/motion/mapping/feet.py): game rigs hang a heel from the
ankle, or from the knee at the ankle's place, pointing back; exported with a leaf bone on
every chain end (Blender's FBX writer), or longer than the toes, its end is the farthest
and lowest leaf of the leg and was taken for the toe, the foot pointing backwards and the
sides turned with it. A person's foot points the way the knee bends (issue 20)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from app.motion.body import Body, build_body
from app.motion.mapping.canonical import CANONICAL_JOINTS
from app.motion.mapping.feet import HEEL_ONLY
from app.motion.model import Motion
from tests.motion.canonical import check_canonical_body
from tests.motion.skeleton_trees import Humanoid, synthetic_humanoid
from tests.motion.synthetic import grown, walking

# Heels (metres, Y up, the figure facing +z, 1.7 tall): where each hangs from, its bone,
# and the leaf bone beyond it (None: the heel ends there).
HEELS = {
    # From the knee at the ankle's place, pointing back and down, longer than the foot,
    # with a leaf bone (a small Blender game rig written to FBX).
    "from the knee, leaf bone": ("knee", (0.0, -0.42, -0.01), (0.0, -0.2, -0.2)),
    # From the ankle, longer than the toe chain, back along the floor.
    "from the ankle, longer than the toes": ("ankle", (0.0, -0.06, -0.15), (0.0, 0.0, -0.14)),
    # From the ankle without a leaf bone, reaching farther than the toes.
    "from the ankle, no leaf bone": ("ankle", (0.0, -0.06, -0.3), None),
}


def _with_heels(
    toes: bool, where: str, bone: tuple[float, ...], leaf: tuple[float, ...] | None
) -> tuple[Motion, dict[str, str]]:
    skeleton, truth = synthetic_humanoid(Humanoid(names="anon", toes=toes))
    parents: list[int] = []
    offsets: list[np.ndarray] = []
    for side in "lr":
        parents.append(skeleton.index(truth[f"{side}_{where}"]))
        offsets.append(np.array(bone))
        if leaf is not None:
            parents.append(skeleton.joint_count + len(parents) - 1)
            offsets.append(np.array(leaf))
    return grown(walking(skeleton, truth), parents, offsets), truth


def _mapped(motion: Motion) -> tuple[dict[str, str], Body]:
    body = build_body(motion)
    names = motion.skeleton.names
    return {c: names[j] for c, j in zip(CANONICAL_JOINTS, body.mapping.joints, strict=True)}, body


@pytest.mark.parametrize("kind", HEELS)
def test_a_heel_beside_the_foot_is_not_the_toe(kind: str) -> None:
    motion, truth = _with_heels(True, *HEELS[kind])
    got, body = _mapped(motion)
    names = motion.skeleton.names
    for side in "lr":
        toe_chain = names.index(truth[f"{side}_ankle"]) + 1  # the toe joint below the ankle
        assert got[f"{side}_ankle"] == truth[f"{side}_ankle"], (kind, side)
        assert got[f"{side}_knee"] == truth[f"{side}_knee"], (kind, side)
        assert got[f"{side}_toe"] in (names[toe_chain], names[toe_chain + 1]), (kind, side)
    check_canonical_body(body, kind, upright=True)


def test_a_heel_with_no_toes_is_not_a_toe() -> None:
    # The foot's only branch points back: the ankle holds and stands for the toe.
    motion, truth = _with_heels(False, "ankle", (0.0, -0.03, -0.05), (0.0, -0.02, -0.01))
    got, body = _mapped(motion)
    for side in "lr":
        assert got[f"{side}_knee"] == truth[f"{side}_knee"], side
        assert got[f"{side}_ankle"] == got[f"{side}_toe"] == truth[f"{side}_ankle"], side
        assert body.mapping.how[f"{side}_toe"] == HEEL_ONLY
    check_canonical_body(body, "heel, no toes", upright=True)


def test_a_short_heel_beside_the_toes_leaves_the_foot_alone() -> None:
    # The ordinary game rig: a short heel at the ankle; the toes reach farther and stand.
    motion, truth = _with_heels(True, "ankle", (0.0, -0.03, -0.05), (0.0, -0.02, -0.01))
    got, _ = _mapped(motion)
    names = motion.skeleton.names
    for side in "lr":
        toe = names.index(truth[f"{side}_ankle"]) + 1
        assert got[f"{side}_ankle"] == truth[f"{side}_ankle"], side
        assert got[f"{side}_toe"] in (names[toe], names[toe + 1]), side


def test_knees_bending_backwards_in_a_take_keep_a_foot_long_toe() -> None:
    # A retargeting artefact (a dev clip's knees bend backwards in most frames) turns the
    # shin's front against real toes: a foot as long as a person's is no heel, and small
    # bones on it pointing the other way are no toes.
    skeleton, truth = synthetic_humanoid(Humanoid(names="anon"))
    motion = walking(skeleton, truth)
    rotations = motion.local_rotations.copy()
    for side in "lr":
        knee = skeleton.index(truth[f"{side}_knee"])
        rotations[:, knee] = np.swapaxes(rotations[:, knee], -1, -2)  # the bend reversed
    motion = dataclasses.replace(motion, local_rotations=rotations)
    parents = [skeleton.index(truth[f"{side}_ankle"]) for side in "lr"]
    nub = np.array([0.0, 0.0, -0.04])  # a small bone from the ankle, pointing back
    motion = grown(motion, parents, [nub, nub])
    got, _ = _mapped(motion)
    names = motion.skeleton.names
    for side in "lr":
        toe = names.index(truth[f"{side}_ankle"]) + 1
        assert got[f"{side}_toe"] in (names[toe], names[toe + 1]), side


def test_of_two_end_sites_on_the_ankle_the_one_pointing_with_the_knee_is_the_toe() -> None:
    # A video-pose writer hangs two End Sites of one length on each ankle, toe and heel,
    # the heel last: the farthest point was the heel by the file's order, the rest pose's
    # feet then pointed back and the sides were turned with them.
    skeleton, truth = synthetic_humanoid(Humanoid(names="anon", toes=False))
    motion = walking(skeleton, truth)
    parents = [skeleton.index(truth[f"{side}_ankle"]) for side in "lr" for _ in range(2)]
    toe, heel = np.array([0.0, -0.06, 0.14]), np.array([0.0, -0.06, -0.14])
    motion = grown(motion, parents, [toe, heel, toe, heel])
    ends = motion.skeleton.end_site.copy()
    ends[-4:] = True
    motion = dataclasses.replace(
        motion, skeleton=dataclasses.replace(motion.skeleton, end_site=ends)
    )
    got, body = _mapped(motion)
    names = motion.skeleton.names
    for side, toe_end in zip("lr", names[-4::2], strict=True):
        assert got[f"{side}_ankle"] == truth[f"{side}_ankle"], side
        assert got[f"{side}_toe"] == toe_end, side
    assert not body.mapping.mirrored
    check_canonical_body(body, "two end sites", upright=True)
