"""A body read from a take in which no pose is a standing figure (a seated, crouched or
lying take; a pose estimator's first frame for rest pose): the choice of head, hands and
feet that most poses of the take show as a person bent at the hips and knees.

Reached only when the rest pose and every frame offered fail the standing search (and IK-held
feet do not help), so nothing the standing search maps changes. Three readings, each with
its reason in the body:

* **The pose, bent.** A person who sits, crouches, kneels, lies with the knees drawn up or
  crawls bends at the hips and the knees, and the thighs then point anywhere; what stays is
  the lower leg: below the knee a leg that carries the body goes down the trunk, away from
  the head (a seated or crouching person's shins hang under the knees, a kneeling one's lie
  behind them), and the other leg, stretched out, kicking or kneeling, does not point
  back up to the head more than a kneeling shin rises from the floor
  (:data:`_LOWER_LEG_OPPOSITE_SPINE`, :data:`_KNEELING_SHIN_RISE`). Knee and ankle are
  found by where a person's lie along the leg's bones (:data:`_KNEE_SHARE`).
* **The bones, in every pose.** The legs are one leg and its mirror image, bone for bone
  (each joint as far along its leg; a tail or another limb beside a leg is not), and the
  arms at least half as long as the legs (:data:`_ARM_TO_LEG`: face bones or fingers taken
  for arms are not).
* **The world, over the take.** A bent person and a four-legged animal look alike in the
  body's own frame (a fox's shins slant back down its spine as a crouching person's do); the
  world tells them apart. Files are authored with a coordinate axis up, and along it both
  feet are the body's lowest points in most poses (they rest on what the body stands, sits
  or lies on): along such an axis a person's trunk is upright (a seated, kneeling or
  crouching person keeps it over the seat or the feet) or lies level with the feet no lower
  than the pelvis (lying down), while an animal's spine is level with its legs hanging
  below it (:func:`_stands_in_the_world`).

A fourth reading comes last (:func:`map_on_one_leg`): a person **standing on one leg**, the
other foot lifted up to about the hips (a single pose of a kick, a knee raised, a fighting
or flying stance), with mirror-image legs and arms shorter than the legs
(:data:`_ONE_LEG_ARM_TO_LEG`); the lifted leg is mapped as the standing one's mirror image.

One pose can mislead (a leg kicking out, a tumble), so the take votes: the choice read so in
the most poses, at least half of them, is the body, mapped from the first pose that shows it,
with a warning. Only the first limb ends of the standing search are read: a pose that does
not stand tells less, and more candidates (feathers, a creature's head parts) offer more
readings that look like a bent person. What is left is the tie the take cannot break: a
person crawling through a whole take looks like an animal walking, and stays refused.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from functools import partial

import numpy as np

from app.motion.mapping.canonical import SkeletonMap
from app.motion.mapping.hypotheses import (
    _ARM_TO_LEG,
    _MIN_ARM,
    _MIN_LEG,
    _Body,
    _check_pose,
    _Choice,
    _four_legged_choices,
    _Known,
    _NotHumanoid,
    _on_shorter_limbs,
    pair_cost,
    trunk_up,
)
from app.motion.mapping.limbs import _ALIKE
from app.motion.mapping.mapper import _TRIED_CHOICES, _Mapper
from app.motion.mapping.runs import _FOOT_TO_SHIN
from app.motion.mapping.tree import _Tree
from app.motion.mapping.vectors import _length, _unit

# cos of the smallest angle between the spine and a lower leg that carries the body (120
# degrees, as for whole legs in a standing figure: hypotheses._LEGS_OPPOSITE_SPINE); the
# other may be stretched out or kick, but not point back up towards the head...
_LOWER_LEG_OPPOSITE_SPINE = -0.5
# ...more than a kneeling leg's shin does: its knee rests on the floor and its ankle behind
# it at most a foot's length above (the toes tucked under), so along an upright trunk the
# shin rises at most foot : shin of its length (runs._FOOT_TO_SHIN, Drillis & Contini).
_KNEELING_SHIN_RISE = _FOOT_TO_SHIN
# ...and standing on one leg, at most 0.9 of them: with the other foot off the ground, one
# pose of a person (a kick, a knee raised) and of a four-legged animal in a gallop look
# alike, but an animal's fore and hind legs both carry it and are about as long (a dog's or
# a cat's), where a person's arm is shorter than the leg (0.75, Drillis & Contini; cartoon
# rigs with arms as long as the legs are not read so).
_ONE_LEG_ARM_TO_LEG = 0.9
# Where a person's knee and ankle lie along the leg's bones from the pelvis, as shares of
# the way to the toes: (hip offset 0.1 + thigh 0.245) / (that + shin 0.246 + foot 0.152) =
# 0.46 and 0.79 (Drillis & Contini); the joint nearest each is taken for it.
_KNEE_SHARE = 0.46
_ANKLE_SHARE = 0.79
# The six signed coordinate axes, one of which is the world's up.
_AXES = np.vstack([np.eye(3), -np.eye(3)])
# Of the leg's bone path: a foot this near the body's lowest point along up rests on what
# the body stands on, or swings just above it in a step (a walk's swing foot: ~0.2); a lying
# body's feet lie no farther below its pelvis.
_FOOT_ON_FLOOR = 0.25
# cos of the largest angle between an upright trunk and the world's up (35 degrees): a seated,
# kneeling or crouching person keeps the trunk over the seat or the feet, leaning less (a
# creature whose raised head passes for a chest leans 45 degrees and more)...
_UPRIGHT = 0.82
# ...and of the smallest between a lying trunk and up (60 degrees).
_LEVEL = 0.5
# Of the poses read, the share that must show the chosen body.
_TAKE_MAJORITY = 0.5


def _lower_leg(tree: _Tree, pelvis: int, foot: int) -> tuple[int, int]:
    """The knee and the ankle, by where they lie along the leg's bones: the joints of the
    leg chain nearest :data:`_KNEE_SHARE` and :data:`_ANKLE_SHARE` of its bone path from
    the pelvis (the foot's end when the ankle is the knee: a leg without a foot). Kept on
    the tree: every pose and choice of a take asks of the same few legs."""
    key = (pelvis, foot)
    found = tree.lower_legs.get(key)
    if found is None:
        chain = tree.chain(pelvis, foot)[1:]
        total = tree.path[foot] - tree.path[pelvis]
        share = np.array([(tree.path[j] - tree.path[pelvis]) / total for j in chain])
        knee = chain[int(np.argmin(np.abs(share - _KNEE_SHARE)))]
        ankle = chain[int(np.argmin(np.abs(share - _ANKLE_SHARE)))]
        found = tree.lower_legs[key] = (knee, foot if ankle == knee else ankle)
    return found


def _mirror_legs(tree: _Tree, pelvis: int, feet: tuple[int, int]) -> bool:
    """Whether the two legs are one leg and its mirror image, bone for bone: as many bones,
    each joint as far along its leg's bones from the pelvis as its mirror image (within
    :data:`_ALIKE`): a person's are; a tail or a creature's other limb beside a leg is not.

    Where along the leg, not each bone's own length: an auto-rigger places each joint on
    its own side's mesh, and a short bone's end set a little off (a sumo figure's toe joints,
    1.33 and 1.04 beyond ankles 7.5 and 7.1 along legs of 8) changes that bone by a quarter
    but its joint's place along the leg by a few hundredths. Kept on the tree, as
    :func:`_lower_leg`."""
    key = (pelvis, *feet)
    found = tree.mirror_legs.get(key)
    if found is None:
        along = [
            [
                float(tree.path[j] - tree.path[pelvis])
                for j in tree.chain(pelvis, foot)[1:]
                if tree.lengths[j] > 0
            ]
            for foot in feet
        ]
        found = tree.mirror_legs[key] = len(along[0]) == len(along[1]) and all(
            abs(math.log(a / b)) <= _ALIKE for a, b in zip(*along, strict=True)
        )
    return found


def _check_bent(
    tree: _Tree, pose: np.ndarray, extent: float, choice: _Choice, rest: bool
) -> _Body | None:
    """``choice`` as a person whose hips and knees may bend in ``pose``, else None;
    ``rest``: ``pose`` is the rest pose, which is not read kneeling on one knee (a bind pose
    is built with the legs mirror images, so both sides skin alike: a rest pose kneeling on
    one knee is a pose of the take, which the take's frames show too; and an odd rest pose,
    bones in axes of their own, is no figure and must not pass for one)."""
    head, hands, feet, chest, pelvis, leg_lengths, arm_lengths, name_cost = choice
    up = trunk_up(tree, pose, extent, head, chest, pelvis)
    if not _length(up) > 0:
        return None
    if min(leg_lengths) < _MIN_LEG * extent or min(arm_lengths) < _MIN_ARM * extent:
        return None
    if min(arm_lengths) < _ARM_TO_LEG * max(leg_lengths) or not _mirror_legs(tree, pelvis, feet):
        return None
    # How far each lower leg points along the spine (-1: straight down the trunk).
    lower = sorted(
        float(_unit(pose[ankle] - pose[knee]) @ up)
        for knee, ankle in (_lower_leg(tree, pelvis, foot) for foot in feet)
    )
    if lower[0] > _LOWER_LEG_OPPOSITE_SPINE or not lower[1] < (0 if rest else _KNEELING_SHIN_RISE):
        return None
    # The head above where the arms part (the chest, or the shoulders' own bone beside it).
    if float((pose[head] - pose[tree.lca(*hands)]) @ up) <= 0:
        return None
    cost = pair_cost(leg_lengths, arm_lengths, name_cost)
    cost -= 0.5 * (sum(leg_lengths) + sum(arm_lengths)) / extent
    return _Body(head, hands, feet, chest, pelvis, up, cost)


def _stands_in_the_world(tree: _Tree, poses: list[np.ndarray], choice: _Choice) -> bool:
    """Whether ``choice``, read in ``poses`` (``(J, 3)`` each), is a person and not a
    four-legged animal, by the world's vertical: the signed coordinate axis (files are
    authored with one up) along which both feet are the body's lowest points in most
    poses (they rest on what the body stands, sits or lies on, or swing a little above
    it). A person's trunk is upright along it (seated, crouching, kneeling), or lies with
    the feet not hanging below the pelvis (lying down); an animal's spine is level with its
    legs hanging below it."""
    _, _, feet, chest, pelvis, leg_lengths, _, _ = choice
    at = np.stack(poses)  # (P, J, 3)
    near = _FOOT_ON_FLOOR * min(leg_lengths)
    heights = at[:, tree.body_joints] @ _AXES.T  # (P, B, 6)
    lowest = heights.min(axis=1)  # (P, 6)
    # (Of the body's extent along the axis too: along a narrow body's side, every point is
    # near the lowest.)
    rest_on = np.minimum(near, _FOOT_ON_FLOOR * (heights.max(axis=1) - lowest))
    on_floor = np.ones(lowest.shape, dtype=bool)
    for foot in feet:
        on_floor &= at[:, foot] @ _AXES.T <= lowest + rest_on
    spine = at[:, chest] - at[:, pelvis]
    spine /= np.maximum(np.linalg.norm(spine, axis=1, keepdims=True), 1e-300)
    need = _TAKE_MAJORITY * len(poses)
    # Every axis along which the feet rest in most poses: a seated person's feet are also
    # the most forward points, a lying person's maybe the farthest from the head.
    for axis in np.flatnonzero(on_floor.sum(axis=0) >= need):
        up = _AXES[axis]
        rise = spine @ up  # (P,)
        hang = (at[:, [pelvis]] - at[:, list(feet)]) @ up  # (P, 2)
        person = (rise >= _UPRIGHT) | ((np.abs(rise) < _LEVEL) & (hang.max(axis=1) <= near))
        if person.sum() >= need:
            return True
    return False


def map_take(known: _Known, poses: list[tuple[str, np.ndarray]]) -> SkeletonMap:
    """The body most of ``poses`` (``(label, (J, 3))``: the rest pose and the frames read)
    show as a person with bent hips and knees (see the module docstring); else _NotHumanoid.
    """
    return _voted(
        known,
        poses,
        _check_bent,
        in_the_world=True,
        how="no pose shows a standing figure: the body was read from {where}, bent at the "
        "hips and knees (seated, crouching or lying)",
    )


def _check_on_one_leg(
    tree: _Tree, pose: np.ndarray, extent: float, choice: _Choice, rest: bool
) -> _Body | None:
    """``choice`` as a person standing on one leg in ``pose``, the other foot lifted, else
    None: the standing search's test with one foot lifted (hypotheses._LIFTED_FOOT_DROP),
    and the bones of a person (mirror-image legs, arms at least half as long: a tail beside a
    leg, or a creature's feathers for arms, is none; and arms shorter than the legs:
    :data:`_ONE_LEG_ARM_TO_LEG`). ``rest`` changes nothing: a rest pose on one leg is read as
    a frame is (the take votes)."""
    _, _, feet, _, pelvis, leg_lengths, arm_lengths, _ = choice
    if min(arm_lengths) < _ARM_TO_LEG * max(leg_lengths) or not _mirror_legs(tree, pelvis, feet):
        return None
    if max(arm_lengths) > _ONE_LEG_ARM_TO_LEG * min(leg_lengths):
        return None
    body, _, _ = _check_pose(tree, pose, extent, *choice, lifted=True)
    return body


def map_on_one_leg(known: _Known, poses: list[tuple[str, np.ndarray]]) -> SkeletonMap:
    """The body most of ``poses`` (``(label, (J, 3))``) show standing on one leg, the other
    foot lifted (a single pose of a kick, a knee raised, a fighting or flying stance, written
    as the rest pose or as a one-frame clip); else _NotHumanoid. Read after :func:`map_take`:
    the take votes as there, so a pose or two of a walking animal do not decide."""
    return _voted(
        known,
        poses,
        _check_on_one_leg,
        in_the_world=False,
        how="no pose shows a figure standing on both feet: the body was read from {where}, "
        "standing on one leg with the other foot lifted",
    )


def _voted(
    known: _Known,
    poses: list[tuple[str, np.ndarray]],
    check: Callable[[_Tree, np.ndarray, float, _Choice, bool], _Body | None],
    *,
    in_the_world: bool,
    how: str,
) -> SkeletonMap:
    """The choice ``check`` finds in the most of ``poses``, at least half of them (and, with
    ``in_the_world``, a person by the world's vertical: :func:`_stands_in_the_world`), mapped
    from the first pose showing it, with the warning ``how``; else _NotHumanoid."""
    tree = known.tree
    shown: dict[int, list[tuple[int, _Body, float]]] = {}
    for index, (label, pose) in enumerate(poses):
        extent = float(np.linalg.norm(np.ptp(pose[tree.body_joints], axis=0)))
        if not extent > 0:
            continue
        four_legged: list[tuple[_Choice, str]] | None = None
        for number, choice in enumerate(known.choices):
            body = check(tree, pose, extent, choice, label.startswith("rest pose"))
            if body is None:
                continue
            # As in the standing search: an animal on longer limbs than these legs wins.
            if four_legged is None:
                four_legged = _four_legged_choices(known, pose, extent)
            if _on_shorter_limbs(tree, body, four_legged) is None:
                shown.setdefault(number, []).append((index, body, extent))
    need = _TAKE_MAJORITY * len(poses)
    at = [pose for _, pose in poses]
    ranked = sorted(
        (
            number
            for number, seen in shown.items()
            if len(seen) >= need
            and (not in_the_world or _stands_in_the_world(tree, at, known.choices[number]))
        ),
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
                mapping, warnings=(*mapping.warnings, how.format(where=where))
            )
    raise problem
