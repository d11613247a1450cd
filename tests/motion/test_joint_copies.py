"""A joint's turn written once per child (Notch's pelvis: ``Root`` still, ``Hip``,
``LeftHip`` and ``RightHip`` on it turning alike), folded back onto the joint."""

from __future__ import annotations

import dataclasses

import numpy as np

from app.motion.formats import read_bvh
from app.motion.joint_copies import folded_copies
from app.motion.kinematics import forward_kinematics
from app.motion.model import Motion, Skeleton
from app.motion.pipeline import analyse
from tests.motion.conftest import BANDAI_FIXTURE, CMU_BVH_FIXTURE, fixture_bytes
from tests.motion.synthetic import below


def turn_on_copies(motion: Motion) -> Motion:
    """``motion`` with the root's turn moved onto a copy joint of no length between the root
    and each of its children, the root held still: the same world positions in every frame,
    written as Notch writes its pelvis."""
    skeleton = motion.skeleton
    parents = skeleton.parents
    order: list[int] = [0]  # old joint per new joint; -1 marks a copy
    for child in np.flatnonzero(parents == 0):
        order += [-1, int(child), *below(skeleton, int(child))]
    new_index = {old: new for new, old in enumerate(order) if old >= 0}
    new_parents, offsets, names, end_site = (
        [-1],
        [skeleton.offsets[0]],
        [skeleton.names[0]],
        [False],
    )
    copy = 0
    for new, old in enumerate(order[1:], start=1):
        if old < 0:
            new_parents.append(0)
            offsets.append(np.zeros(3))
            names.append(f"pelvis_copy{copy}")
            end_site.append(False)
            copy += 1
            continue
        parent = int(parents[old])
        new_parents.append(new - 1 if parent == 0 else new_index[parent])
        offsets.append(skeleton.offsets[old])
        names.append(skeleton.names[old])
        end_site.append(bool(skeleton.end_site[old]))
    rotations = motion.local_rotations
    turn = rotations[:, 0]
    local = np.stack(
        [
            np.broadcast_to(np.eye(3), turn.shape)
            if old == 0
            else turn
            if old < 0
            else rotations[:, old]
            for old in order
        ],
        axis=1,
    )
    translations = motion.local_translations
    if translations is not None:  # the copies sit at the root's place in every frame
        translations = np.stack(
            [
                np.zeros_like(translations[:, 0]) if old < 0 else translations[:, old]
                for old in order
            ],
            axis=1,
        )
    return dataclasses.replace(
        motion,
        skeleton=Skeleton(
            tuple(names), np.array(new_parents), np.array(offsets), np.array(end_site)
        ),
        local_rotations=local,
        local_translations=translations,
    )


def test_the_rewrite_keeps_every_position() -> None:
    motion = read_bvh(fixture_bytes(CMU_BVH_FIXTURE))
    copied = turn_on_copies(motion)
    _, before = forward_kinematics(motion)
    _, after = forward_kinematics(copied)
    kept = [copied.skeleton.names.index(n) for n in motion.skeleton.names]
    np.testing.assert_allclose(after[:, kept], before, atol=1e-9 * np.ptp(before))


def test_a_pelvis_turn_on_its_childrens_copies_describes_as_on_the_pelvis() -> None:
    """Before, the pelvis (where the legs and the spine part: the still root) never turned:
    the body's frame held still, and the descriptors were another clip's."""
    for fixture in (CMU_BVH_FIXTURE, BANDAI_FIXTURE):
        motion = read_bvh(fixture_bytes(fixture))
        plain, copied = analyse(motion), analyse(turn_on_copies(motion))
        for name, vector in plain.descriptors.items():
            np.testing.assert_allclose(copied.descriptors[name], vector, atol=1e-5, err_msg=name)


def test_children_that_turn_apart_or_sit_apart_are_left_alone() -> None:
    """The CMU rig's hips and lower back all sit at the pelvis, each turning its own way:
    nothing to fold (the clip is returned as it is)."""
    motion = read_bvh(fixture_bytes(CMU_BVH_FIXTURE))
    assert folded_copies(motion) is motion
