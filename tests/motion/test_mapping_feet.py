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
from tests.motion.test_mapping_probes import _arrays, kept

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


def test_a_pivot_just_behind_the_ankle_is_not_the_toe() -> None:
    """DAZ Genesis hangs its toes from a metatarsal joint 0.02 of the shin behind and below
    the ankle. As the first joint past the ankle it was taken for the toe joint: on the
    DAZ rig of held-out round 15 the foot pointed back and the figure was stored as a
    mirrored capture; here (two toes branching at it) the code before let the ankle stand
    for the toe. A joint that near is still at the ankle; the toes are the next."""
    skeleton, truth = synthetic_humanoid(Humanoid(names="unity", toes=True))
    motion = walking(skeleton, truth)
    parents, offsets, rotations, translations, names, end_site = _arrays(motion)
    frames = motion.frame_count
    pivot = np.array([0.0, -0.006, -0.006])  # 0.02 of a 0.42-m shin, behind and below
    for side in "lr":
        ankle = names.index(truth[f"{side}_ankle"])
        toe = next(j for j, parent in enumerate(parents) if parent == ankle)
        parents.append(ankle)
        offsets = np.concatenate([offsets, pivot[None]])
        rotations = np.concatenate([rotations, np.broadcast_to(np.eye(3), (frames, 1, 3, 3))], 1)
        translations = np.concatenate([translations, np.broadcast_to(pivot, (frames, 1, 3))], 1)
        names.append(f"{side}_metatarsals")
        end_site.append(False)
        parents[toe] = len(parents) - 1
        offsets[toe] -= pivot
        translations[:, toe] -= pivot
    arrays = (parents, offsets, rotations, translations, names, end_site)
    pivoted = kept(motion, list(range(len(parents))), arrays)
    # A second toe beside the first from the metatarsal joint (DAZ's big toe and small
    # toes): the chain beyond that joint branches, so no single toe tip continues it.
    toes = [
        next(j for j, p in enumerate(pivoted.skeleton.parents) if p == metatarsals)
        for metatarsals in (pivoted.skeleton.index(f"{side}_metatarsals") for side in "lr")
    ]
    count = pivoted.skeleton.joint_count
    beside = [
        pivoted.skeleton.offsets[toe] + (0.03 if toe == toes[0] else -0.03, 0.0, 0.0)
        for toe in toes
    ]
    ends = [pivoted.skeleton.offsets[toe + 1] for toe in toes]  # each toe's own End Site
    pivoted = grown(
        pivoted,
        [
            int(pivoted.skeleton.parents[toes[0]]),
            count,
            int(pivoted.skeleton.parents[toes[1]]),
            count + 2,
        ],
        [beside[0], ends[0], beside[1], ends[1]],
    )
    got, body = _mapped(pivoted)
    for side in "lr":
        # A toe ahead of the foot: neither the metatarsal joint nor the ankle standing in.
        assert got[f"{side}_toe"] not in (f"{side}_metatarsals", truth[f"{side}_ankle"]), side
        assert got[f"{side}_ankle"] == truth[f"{side}_ankle"], side  # by its name
    assert not body.mapping.mirrored
    check_canonical_body(body, "pivot", upright=True)
