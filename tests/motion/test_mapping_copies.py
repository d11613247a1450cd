"""Limb ends among copies of the limbs and bundles of chains (issue 20): a rig exported with
control copies of every limb (Rigify's ORG-/MCH- chains on the places of its DEF- chain) and
a head carrying hair strands must map like the plain rig (app/motion/mapping/tree.py,
``_extremity_candidates`` with ``copies_last``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from app.motion.formats import read_bvh
from app.motion.mapping.canonical import rest_pose
from app.motion.mapping.tree import _extremity_candidates, _Tree
from app.motion.model import Motion, Skeleton
from app.motion.pipeline import analyse
from app.motion.skeleton_map import CANONICAL_INDEX, CANONICAL_JOINTS
from tests.motion.conftest import BANDAI_FIXTURE, CMU_BVH_FIXTURE, fixture_bytes

FIXTURES = (CMU_BVH_FIXTURE, BANDAI_FIXTURE)


def _motion(fixture: str) -> Motion:
    return read_bvh(fixture_bytes(fixture))


def _mapped(motion: Motion) -> np.ndarray:
    """``(21,)`` the clip's mapped joints."""
    mapping = analyse(motion, descriptors=[]).body.mapping
    assert mapping is not None
    return mapping.joints


def _with_joints(
    motion: Motion,
    sources: list[int],
    parents: list[int],
    names: list[str],
    offsets: list[np.ndarray] | None = None,
) -> Motion:
    """``motion`` with joints added under ``parents``, each moving as joint ``sources[i]``
    (its offset and rotations; -1: the given offset, never turning)."""
    skeleton, frames = motion.skeleton, motion.frame_count
    given = offsets or [np.zeros(3)] * len(sources)
    rest = np.array(
        [skeleton.offsets[s] if s >= 0 else o for s, o in zip(sources, given, strict=True)]
    )
    ends = np.array([bool(skeleton.end_site[s]) if s >= 0 else False for s in sources])
    grown = Skeleton(
        (*skeleton.names, *names),
        np.concatenate([skeleton.parents, parents]),
        np.concatenate([skeleton.offsets, rest.reshape(-1, 3)]),
        np.concatenate([skeleton.end_site, ends]),
    )
    still = np.broadcast_to(np.eye(3), (frames, 3, 3))
    rotations = np.stack(
        [motion.local_rotations[:, s] if s >= 0 else still for s in sources], axis=1
    )
    translations = None
    if motion.local_translations is not None:
        moved = [
            motion.local_translations[:, s] if s >= 0 else np.broadcast_to(r, (frames, 3))
            for s, r in zip(sources, rest, strict=True)
        ]
        translations = np.concatenate([motion.local_translations, np.stack(moved, 1)], axis=1)
    return dataclasses.replace(
        motion,
        skeleton=grown,
        local_rotations=np.concatenate([motion.local_rotations, rotations], axis=1),
        local_translations=translations,
    )


def _path(skeleton: Skeleton, joint: int) -> list[int]:
    """Joints from below the root down to ``joint``."""
    out = []
    while joint > 0:
        out.append(joint)
        joint = int(skeleton.parents[joint])
    return out[::-1]


def _farthest_leaf(skeleton: Skeleton, joint: int) -> int:
    rest = rest_pose(skeleton)
    below = [j for j in range(skeleton.joint_count) if joint in _path(skeleton, j)]
    leaves = [j for j in below if not np.any(skeleton.parents == j)]
    return max(leaves, key=lambda j: float(np.linalg.norm(rest[j] - rest[joint])))


def _with_limb_copies(motion: Motion, copies: int) -> Motion:
    """``motion`` with ``copies`` control chains from the root on the places of its own
    joints, moving as they do: each copies the trunk, the arms down to the wrist (where the
    rig's hand carries on) and the legs down to the toe's end (a leaf on the rig's own), as
    a whole Rigify export carries ORG- and MCH- chains."""
    skeleton = motion.skeleton
    plain = _mapped(motion)
    ends = [int(plain[CANONICAL_INDEX[f"{s}_wrist"]]) for s in "lr"]
    ends += [_farthest_leaf(skeleton, int(plain[CANONICAL_INDEX[f"{s}_ankle"]])) for s in "lr"]
    sources: list[int] = []
    parents: list[int] = []
    names: list[str] = []
    for k in range(copies):
        copy = {0: 0}
        for end in ends:
            for joint in _path(skeleton, end):
                if joint not in copy:
                    copy[joint] = skeleton.joint_count + len(sources)
                    sources.append(joint)
                    parents.append(copy[int(skeleton.parents[joint])])
                    names.append(f"COPY{k}-{skeleton.names[joint]}")
    return _with_joints(motion, sources, parents, names)


@pytest.mark.parametrize("fixture", FIXTURES)
def test_a_rig_with_control_copies_of_its_limbs_maps_like_the_plain_rig(fixture: str) -> None:
    motion = _motion(fixture)
    np.testing.assert_array_equal(_mapped(_with_limb_copies(motion, 2)), _mapped(motion))


def test_copies_give_the_rig_s_own_ends_first() -> None:
    """The toes' three copies are one candidate, the rig's own; the copies' wrists, where
    the rig's hands carry on, come after every end of the rig's own."""
    motion = _motion(CMU_BVH_FIXTURE)
    copied = _with_limb_copies(motion, 2).skeleton
    tree = _Tree(copied)
    plain = set(_extremity_candidates(tree, 12, copies_last=False))
    chosen = _extremity_candidates(tree, 12, copies_last=True)
    own = [j for j in chosen if j < motion.skeleton.joint_count]
    assert len(own) >= 5 and own == chosen[: len(own)], [copied.names[j] for j in chosen]
    mapped = _mapped(motion)
    wrists = {
        f"COPY{k}-{motion.skeleton.names[mapped[CANONICAL_INDEX[f'{side}_wrist']]]}"
        for k in range(2)
        for side in "lr"
    }
    assert {copied.names[j] for j in chosen[len(own) :]} <= wrists
    assert any(j >= motion.skeleton.joint_count for j in plain), "the probe crowds out no end"


def _with_hair(motion: Motion, strands: int, bones: int) -> Motion:
    """``motion`` with two eyes and ``strands`` hair chains of ``bones`` bones each hanging
    side by side from the head's joint down the back, past the shoulders, never moving
    (VRoid's hair and eyes on its head bone)."""
    skeleton = motion.skeleton
    head = int(_mapped(motion)[CANONICAL_INDEX["head"]])
    if not np.any(skeleton.parents == head) or skeleton.end_site[head]:
        head = int(skeleton.parents[head])  # the head's joint, not the end site on it
    height = float(np.ptp(rest_pose(skeleton)[:, 1]))
    parents: list[int] = []
    names: list[str] = []
    offsets: list[np.ndarray] = []
    for side in (-1, 1):
        parents.append(head)
        names.append(f"eye{side}")
        offsets.append(np.array([0.02 * side, 0.02, 0.05]) * height)
    for i in range(strands):
        parent = head
        for k in range(bones):
            step = [0.03 * (i - strands // 2), 0.0, -0.03] if k == 0 else [0.0, -0.1, -0.01]
            parents.append(parent)
            names.append(f"hair{i}_{k}")
            offsets.append(np.array(step) * height)
            parent = skeleton.joint_count + len(names) - 1
    return _with_joints(motion, [-1] * len(names), parents, names, offsets)


def test_strands_of_one_shape_on_one_joint_give_one_candidate() -> None:
    skeleton = _with_hair(_motion(CMU_BVH_FIXTURE), strands=4, bones=4).skeleton
    tree = _Tree(skeleton)
    tips = {j for j, name in enumerate(skeleton.names) if name.endswith("_3")}
    assert len(tips & set(_extremity_candidates(tree, 12, copies_last=False))) > 1, (
        "the probe has no bundle"
    )
    assert len(tips & set(_extremity_candidates(tree, 12, copies_last=True))) == 1


@pytest.mark.parametrize("fixture", FIXTURES)
def test_a_head_with_hair_strands_maps_like_the_plain_rig(fixture: str) -> None:
    """Every joint as without the hair; the head at the head's joint or an eye on it."""
    motion = _motion(fixture)
    plain, hair = _mapped(motion), _mapped(_with_hair(motion, strands=4, bones=4))
    body = [i for i, name in enumerate(CANONICAL_JOINTS) if name != "head"]
    np.testing.assert_array_equal(hair[body], plain[body])
    names = motion.skeleton.names
    head = int(plain[CANONICAL_INDEX["head"]])
    assert hair[CANONICAL_INDEX["head"]] in (head, int(motion.skeleton.parents[head])) or (
        int(hair[CANONICAL_INDEX["head"]]) >= len(names)
    )
