"""A body read from a take in which no pose is a standing figure (a seated, crouched or
lying take; a pose estimator's first frame for rest pose): the choice of head, hands and
feet that the most poses of the take show as a person whose knees may bend.

A standing figure has its feet below the pelvis, the legs opposite the spine. A person who
sits, crouches, kneels, lies with the knees drawn up or crawls bends at the hips and the
knees, and the thighs then point anywhere; what stays is the lower leg: below the knee a
leg that carries the body still goes down, away from the head, along the trunk (the shins of
a seated or crouching person hang under the knees, a kneeling or crawling person's shins lie
behind them, pointing where the pelvis is from the chest), and the other leg, stretched out
or kicking, does not point back up to the head. A four-legged animal's lower legs hang
across its spine, as its whole legs do (:data:`_LOWER_LEG_OPPOSITE_SPINE`). The bone
lengths, the same in every pose, must be a person's: arms at least half as long as the legs
(:data:`_ARM_TO_LEG`). One pose can still mislead (a leg
kicking out, a tumble), so the take votes: the choice read so in the most poses, at least half
of them, is the body, mapped from the first pose that shows it, with a warning.
"""

from __future__ import annotations

import dataclasses
from functools import partial

import numpy as np

from app.motion.mapping.canonical import SkeletonMap
from app.motion.mapping.hypotheses import (
    _MIN_ARM,
    _MIN_LEG,
    _Body,
    _Choice,
    _Known,
    _NotHumanoid,
)
from app.motion.mapping.mapper import _TRIED_CHOICES, _Mapper
from app.motion.mapping.tree import COINCIDENT, _Tree
from app.motion.mapping.vectors import _length, _unit

# cos of the smallest angle between the spine and a lower leg that carries the body (120
# degrees, as for whole legs in a standing figure: hypotheses._LEGS_OPPOSITE_SPINE); the
# other may be stretched out or kick, but not point back up towards the head.
_LOWER_LEG_OPPOSITE_SPINE = -0.5
# A person's arm, collar to fingertip, is about 0.75 of the leg, hip to toe tip, along the
# bones (0.1 + 0.44 against 0.1 + 0.53 + 0.1 of the height, Drillis & Contini); under half,
# the "arms" are face bones or fingers and the "legs" arms.
_ARM_TO_LEG = 0.5
# The lower leg starts at the last joint of the leg chain within this fraction of its bone
# path from the pelvis: a person's knee sits at (hip offset 0.1 + thigh 0.245) / (that + shin
# 0.246 + foot 0.152) = 0.46 of the way to the toes (Drillis & Contini), at 0.38 with the hip
# at the pelvis, and the ankle at 0.78; a twist joint inside the thigh only starts it higher.
_KNEE_SHARE = 0.55
# Of the poses read, the share that must show the chosen body.
_TAKE_MAJORITY = 0.5


def _lower_leg_top(tree: _Tree, pelvis: int, foot: int) -> int:
    """The knee, or a joint above it: the last joint of the leg chain within
    :data:`_KNEE_SHARE` of its bone path."""
    chain = tree.chain(pelvis, foot)
    total = tree.path[foot] - tree.path[pelvis]
    return [j for j in chain if tree.path[j] - tree.path[pelvis] <= _KNEE_SHARE * total][-1]


def _check_bent(tree: _Tree, pose: np.ndarray, extent: float, choice: _Choice) -> _Body | None:
    """``choice`` as a person whose hips and knees may bend in ``pose``, else None."""
    head, hands, feet, chest, pelvis, leg_lengths, arm_lengths, name_cost = choice
    spine = pose[chest] - pose[pelvis]
    if _length(spine) < COINCIDENT * extent:
        spine = pose[head] - pose[pelvis]
    up = _unit(spine)
    if not _length(up) > 0:
        return None
    if min(leg_lengths) < _MIN_LEG * extent or min(arm_lengths) < _MIN_ARM * extent:
        return None
    if min(arm_lengths) < _ARM_TO_LEG * max(leg_lengths):
        return None
    # How far each lower leg points along the spine (-1: straight down the trunk).
    lower = sorted(
        float(_unit(pose[foot] - pose[_lower_leg_top(tree, pelvis, foot)]) @ up) for foot in feet
    )
    if lower[0] > _LOWER_LEG_OPPOSITE_SPINE or not lower[1] < 0:
        return None
    if float((pose[head] - pose[chest]) @ up) <= 0:
        return None
    cost = abs(leg_lengths[0] - leg_lengths[1]) / max(leg_lengths) + abs(
        arm_lengths[0] - arm_lengths[1]
    ) / max(arm_lengths)
    for term in name_cost:
        cost += term
    cost -= 0.5 * (sum(leg_lengths) + sum(arm_lengths)) / extent
    return _Body(head, hands, feet, chest, pelvis, up, cost)


def map_take(known: _Known, poses: list[tuple[str, np.ndarray]]) -> SkeletonMap:
    """The body most of ``poses`` (``(label, (J, 3))``: the rest pose and the frames read)
    show as a person with bent hips and knees (see the module docstring); else _NotHumanoid.
    """
    tree = known.tree
    shown: dict[int, list[tuple[int, _Body, float]]] = {}
    for index, (_, pose) in enumerate(poses):
        extent = float(np.linalg.norm(np.ptp(pose[tree.body_joints], axis=0)))
        if not extent > 0:
            continue
        for number, choice in enumerate(known.choices):
            body = _check_bent(tree, pose, extent, choice)
            if body is not None:
                shown.setdefault(number, []).append((index, body, extent))
    need = _TAKE_MAJORITY * len(poses)
    ranked = sorted(
        (number for number, seen in shown.items() if len(seen) >= need),
        key=lambda number: (-len(shown[number]), sum(b.cost for _, b, _ in shown[number])),
    )
    problem = _NotHumanoid("no pose of the take shows a person, standing or bent")
    for number in ranked[:_TRIED_CHOICES]:
        for index, body, extent in shown[number]:
            label, pose = poses[index]
            others = [p for i, (_, p) in enumerate(poses) if i != index]
            try:
                mapping = _Mapper(tree, pose, extent, body, label, partial(list, others)).run()
            except _NotHumanoid as why:
                problem = why
                continue
            where = "the rest pose" if label.startswith("rest pose") else label
            return dataclasses.replace(
                mapping,
                warnings=(
                    *mapping.warnings,
                    "no pose shows a standing figure: the body was read from "
                    f"{where}, bent at the hips and knees (seated, crouching or lying)",
                ),
            )
    raise problem
